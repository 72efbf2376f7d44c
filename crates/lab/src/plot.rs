//! Line plots as PNG, for experiments: one or more series of `(x, y)` points, each optionally
//! with a shaded band (e.g. the spread over seeds), linear or logarithmic axes, a legend.
//!
//! Text is drawn with DejaVu Sans embedded in the binary (the `dejavu` crate through plotters'
//! `ab_glyph` backend), so plotting needs no system fonts.
//!
//! ```no_run
//! use mcrad_lab::plot::{PlotSpec, Series, line_plot};
//! let spec = PlotSpec {
//!     title: "error".into(),
//!     x_label: "rays".into(),
//!     y_label: "rms_rel".into(),
//!     log_x: true,
//!     log_y: true,
//!     series: vec![Series {
//!         name: "shooting".into(),
//!         points: vec![(1e2, 0.5), (1e3, 0.16), (1e4, 0.05)],
//!         band: None,
//!     }],
//! };
//! line_plot(std::path::Path::new("error.png"), &spec).unwrap();
//! ```

use plotters::coord::Shift;
use plotters::coord::ranged1d::{KeyPointHint, NoDefaultFormatting, Ranged, ValueFormatter};
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

/// Width of the PNG in pixels.
pub const WIDTH: u32 = 900;
/// Height of the PNG in pixels.
pub const HEIGHT: u32 = 600;

/// The font family name the embedded font is registered under.
const FONT: &str = "sans-serif";

/// Colours of the series, in order (Tableau 10); repeated past ten series.
const COLOURS: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// What to plot.
#[derive(Debug, Clone, PartialEq)]
pub struct PlotSpec {
    /// Caption above the chart.
    pub title: String,
    /// Description of the x axis.
    pub x_label: String,
    /// Description of the y axis.
    pub y_label: String,
    /// Logarithmic x axis (every x must then be `> 0`).
    pub log_x: bool,
    /// Logarithmic y axis (every y, and every band edge, must then be `> 0`).
    pub log_y: bool,
    /// The curves, drawn in order, each in its own colour and named in the legend.
    pub series: Vec<Series>,
}

/// One curve.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Name in the legend.
    pub name: String,
    /// Points `(x, y)`, joined in the order given, each marked with a dot.
    pub points: Vec<(f64, f64)>,
    /// Optional band `(x, lo, hi)` shaded in the series' colour (e.g. min and max over seeds).
    pub band: Option<Vec<(f64, f64, f64)>>,
}

/// Why a plot could not be drawn.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// No data, a value that cannot be placed on its axis, or the image could not be drawn or
    /// encoded.
    #[error("could not plot: {reason}")]
    Plot {
        /// What is wrong, with the offending series and value.
        reason: String,
    },
    /// The PNG could not be written.
    #[error("could not write the plot: {reason}")]
    Io {
        /// The underlying error.
        reason: std::io::Error,
    },
}

fn plot_error(reason: impl Into<String>) -> PlotError {
    PlotError::Plot {
        reason: reason.into(),
    }
}

/// Writes `spec` as a PNG of [`WIDTH`] × [`HEIGHT`] pixels to `path`.
///
/// Errors: no point at all, a non-finite value, a non-positive value on a logarithmic axis
/// ([`PlotError::Plot`], naming the series and the value), or the file cannot be written
/// ([`PlotError::Io`]).
pub fn line_plot(path: &Path, spec: &PlotSpec) -> Result<(), PlotError> {
    let (x_range, y_range) = ranges(spec)?;
    register_font()?;
    let mut buffer = vec![0u8; (WIDTH * HEIGHT * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (WIDTH, HEIGHT)).into_drawing_area();
        let axis = |(lo, hi): (f64, f64)| Axis { lo, hi };
        let (x, y) = (axis(x_range), axis(y_range));
        let legend = legend_corner(spec, x_range, y_range);
        match (spec.log_x, spec.log_y) {
            (false, false) => draw(&root, spec, legend, x.linear(), y.linear()),
            (false, true) => draw(&root, spec, legend, x.linear(), y.log()),
            (true, false) => draw(&root, spec, legend, x.log(), y.linear()),
            (true, true) => draw(&root, spec, legend, x.log(), y.log()),
        }
        .map_err(|e| plot_error(format!("drawing failed: {e}")))?;
        root.present()
            .map_err(|e| plot_error(format!("drawing failed: {e}")))?;
    }
    let image = image::RgbImage::from_raw(WIDTH, HEIGHT, buffer)
        .expect("the buffer holds WIDTH × HEIGHT RGB pixels");
    image
        .save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| match e {
            image::ImageError::IoError(source) => PlotError::Io { reason: source },
            other => plot_error(format!("could not encode {}: {other}", path.display())),
        })
}

/// Registers the embedded DejaVu Sans as [`FONT`] (once per process).
fn register_font() -> Result<(), PlotError> {
    static REGISTER: Once = Once::new();
    let mut ok = true;
    REGISTER.call_once(|| {
        ok = plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular())
            .is_ok();
    });
    if ok {
        Ok(())
    } else {
        Err(plot_error("the embedded font could not be loaded"))
    }
}

/// One axis's extent.
struct Axis {
    lo: f64,
    hi: f64,
}

impl Axis {
    fn linear(&self) -> plotters::coord::types::RangedCoordf64 {
        (self.lo..self.hi).into()
    }

    fn log(&self) -> LogAxis {
        LogAxis {
            lo: self.lo,
            hi: self.hi,
        }
    }
}

/// A logarithmic axis whose ticks are 1-2-5 (or 1..9, or 1-3, or whole decades) times powers of
/// ten, whichever is the densest set that fits the labels asked for. (plotters' own log axis
/// labels only the powers of ten and what lies above the first one, which leaves a range inside
/// one decade with one label or none.)
#[derive(Debug, Clone, Copy)]
struct LogAxis {
    lo: f64,
    hi: f64,
}

impl LogAxis {
    /// Every `m × 10^k` in the range for the mantissas `m`, with `k` stepping by `step` decades.
    fn ticks(&self, mantissas: &[f64], step: i32) -> Vec<f64> {
        let first = self.lo.log10().floor() as i32;
        let last = self.hi.log10().ceil() as i32;
        let mut out = Vec::new();
        for k in (first..=last).filter(|k| k.rem_euclid(step) == 0) {
            for m in mantissas {
                let v = m * 10f64.powi(k);
                if v >= self.lo && v <= self.hi {
                    out.push(v);
                }
            }
        }
        out
    }
}

impl Ranged for LogAxis {
    type FormatOption = NoDefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        let t = (value.ln() - self.lo.ln()) / (self.hi.ln() - self.lo.ln());
        limit.0 + (t * f64::from(limit.1 - limit.0)).round() as i32
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        let max = hint.max_num_points().max(1);
        let sets: [(&[f64], i32); 5] = [
            (&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0], 1),
            (&[1.0, 2.0, 5.0], 1),
            (&[1.0, 3.0], 1),
            (&[1.0], 1),
            (&[1.0], 2),
        ];
        // Light grid lines may use every integer mantissa; labels the densest of the others
        // that fits (1..9 would crowd the top of each decade).
        let start = usize::from(!hint.weight().allow_light_points());
        for &(mantissas, step) in &sets[start..] {
            let t = self.ticks(mantissas, step);
            if t.len() <= max && t.len() >= 2 {
                return t;
            }
        }
        let mut step = 3;
        loop {
            let t = self.ticks(&[1.0], step);
            if t.len() <= max {
                return t;
            }
            step += 1;
        }
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.lo..self.hi
    }
}

impl ValueFormatter<f64> for LogAxis {
    fn format(value: &f64) -> String {
        tick(*value)
    }
}

/// The data extent of every point and band edge, padded (5% of the span on a linear axis, 10%
/// of a decade on a logarithmic one), checked for finiteness and positivity on log axes.
#[allow(clippy::type_complexity)]
fn ranges(spec: &PlotSpec) -> Result<((f64, f64), (f64, f64)), PlotError> {
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    for s in &spec.series {
        for &(x, y) in &s.points {
            xs.push((x, &s.name));
            ys.push((y, &s.name));
        }
        for &(x, lo, hi) in s.band.iter().flatten() {
            xs.push((x, &s.name));
            ys.push((lo, &s.name));
            ys.push((hi, &s.name));
        }
    }
    if xs.is_empty() {
        return Err(plot_error(
            "there is nothing to plot: no series has a point",
        ));
    }
    let extent = |values: &[(f64, &String)], log: bool, axis: &str| {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for &(v, name) in values {
            if !v.is_finite() || (log && v <= 0.0) {
                let need = if log {
                    "finite and > 0 (log scale)"
                } else {
                    "finite"
                };
                return Err(plot_error(format!(
                    "series '{name}' has {axis} = {v}; {axis} must be {need}"
                )));
            }
            lo = lo.min(v);
            hi = hi.max(v);
        }
        Ok(if log {
            let pad = 10f64.powf(0.1);
            (lo / pad, hi * pad)
        } else {
            let span = if hi > lo { hi - lo } else { lo.abs().max(1.0) };
            (lo - 0.05 * span, hi + 0.05 * span)
        })
    };
    Ok((extent(&xs, spec.log_x, "x")?, extent(&ys, spec.log_y, "y")?))
}

/// The corner of the chart for the legend: the one whose box (the outer 45% of the width, 30%
/// of the height) holds the fewest points and band edges, upper corners first on a tie.
fn legend_corner(spec: &PlotSpec, x: (f64, f64), y: (f64, f64)) -> SeriesLabelPosition {
    let unit = |v: f64, (lo, hi): (f64, f64), log: bool| {
        if log {
            (v.ln() - lo.ln()) / (hi.ln() - lo.ln())
        } else {
            (v - lo) / (hi - lo)
        }
    };
    let mut at: Vec<(f64, f64)> = Vec::new();
    for s in &spec.series {
        at.extend(s.points.iter().copied());
        for &(bx, lo, hi) in s.band.iter().flatten() {
            at.push((bx, lo));
            at.push((bx, hi));
        }
    }
    let corners = [
        (SeriesLabelPosition::UpperRight, true, true),
        (SeriesLabelPosition::UpperLeft, false, true),
        (SeriesLabelPosition::LowerRight, true, false),
        (SeriesLabelPosition::LowerLeft, false, false),
    ];
    let count = |right: bool, upper: bool| {
        at.iter()
            .filter(|&&(px, py)| {
                let (u, v) = (unit(px, x, spec.log_x), unit(py, y, spec.log_y));
                (if right { u > 0.55 } else { u < 0.45 }) && (if upper { v > 0.7 } else { v < 0.3 })
            })
            .count()
    };
    let mut best = (usize::MAX, SeriesLabelPosition::UpperRight);
    for (position, right, upper) in corners {
        let n = count(right, upper);
        if n < best.0 {
            best = (n, position);
        }
    }
    best.1
}

/// A compact tick label: `1k`, `300k`, `1M` from 1000 up, three significant digits at most.
fn tick(v: f64) -> String {
    let a = v.abs();
    let (scaled, suffix) = if a >= 1e9 {
        (v / 1e9, "G")
    } else if a >= 1e6 {
        (v / 1e6, "M")
    } else if a >= 1e3 {
        (v / 1e3, "k")
    } else {
        (v, "")
    };
    if scaled == 0.0 {
        return "0".into();
    }
    let precision = (2 - scaled.abs().log10().floor() as i32).max(0) as usize;
    let mut digits = format!("{scaled:.precision$}");
    if digits.contains('.') {
        digits = digits
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_string();
    }
    format!("{digits}{suffix}")
}

type DrawResult = Result<(), Box<dyn std::error::Error>>;

fn draw<X, Y>(
    root: &DrawingArea<BitMapBackend, Shift>,
    spec: &PlotSpec,
    legend: SeriesLabelPosition,
    x: X,
    y: Y,
) -> DrawResult
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(root)
        .caption(&spec.title, (FONT, 24))
        .margin(20)
        .x_label_area_size(55)
        .y_label_area_size(75)
        .build_cartesian_2d(x, y)?;
    let formatter = |v: &f64| tick(*v);
    chart
        .configure_mesh()
        .x_desc(&spec.x_label)
        .y_desc(&spec.y_label)
        .x_label_formatter(&formatter)
        .y_label_formatter(&formatter)
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 18))
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(200, 200, 200))
        .draw()?;
    for (k, s) in spec.series.iter().enumerate() {
        if let Some(band) = &s.band {
            let colour = COLOURS[k % COLOURS.len()];
            let mut outline: Vec<(f64, f64)> = band.iter().map(|&(x, lo, _)| (x, lo)).collect();
            outline.extend(band.iter().rev().map(|&(x, _, hi)| (x, hi)));
            chart.draw_series(std::iter::once(Polygon::new(
                outline,
                colour.mix(0.18).filled(),
            )))?;
        }
    }
    for (k, s) in spec.series.iter().enumerate() {
        let colour = COLOURS[k % COLOURS.len()];
        chart
            .draw_series(LineSeries::new(
                s.points.iter().copied(),
                colour.stroke_width(2),
            ))?
            .label(&s.name)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(3))
            });
        chart.draw_series(s.points.iter().map(|&p| Circle::new(p, 4, colour.filled())))?;
    }
    chart
        .configure_series_labels()
        .position(legend)
        .label_font((FONT, 16))
        .background_style(WHITE.mix(0.9))
        .border_style(RGBColor(120, 120, 120))
        .margin(10)
        .draw()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> PlotSpec {
        let xs: [f64; 5] = [1e2, 3e2, 1e3, 3e3, 1e4];
        PlotSpec {
            title: "test plot".into(),
            x_label: "rays".into(),
            y_label: "error".into(),
            log_x: true,
            log_y: true,
            series: vec![
                Series {
                    name: "falling".into(),
                    points: xs.iter().map(|&x| (x, 10.0 / x.sqrt())).collect(),
                    band: Some(
                        xs.iter()
                            .map(|&x| (x, 8.0 / x.sqrt(), 12.0 / x.sqrt()))
                            .collect(),
                    ),
                },
                Series {
                    name: "flat".into(),
                    points: xs.iter().map(|&x| (x, 0.2)).collect(),
                    band: None,
                },
            ],
        }
    }

    #[test]
    fn writes_a_png_of_the_right_size_that_is_not_blank() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("plot.png");
        line_plot(&path, &spec()).unwrap();
        let image = image::open(&path).unwrap().to_rgb8();
        assert_eq!(image.dimensions(), (WIDTH, HEIGHT));
        let white = image.pixels().filter(|p| p.0 == [255, 255, 255]).count();
        let total = (WIDTH * HEIGHT) as usize;
        // Mostly background, but axes, grid, text, curves and bands cover a fair share.
        assert!(
            white < total * 97 / 100,
            "{white} of {total} pixels are white"
        );
        assert!(white > total / 2, "{white} of {total} pixels are white");
        // Both series' colours appear (the curves are drawn), and so does dark text.
        for c in [COLOURS[0], COLOURS[1]] {
            let n = image.pixels().filter(|p| p.0 == [c.0, c.1, c.2]).count();
            assert!(n > 500, "colour {c:?} covers only {n} pixels");
        }
        let dark = image
            .pixels()
            .filter(|p| p.0.iter().all(|&v| v < 80))
            .count();
        assert!(dark > 500, "only {dark} dark pixels: no text or axes?");
    }

    #[test]
    fn the_title_is_rendered_as_text() {
        let dir = tempfile::tempdir().unwrap();
        let (with, without) = (dir.path().join("a.png"), dir.path().join("b.png"));
        line_plot(&with, &spec()).unwrap();
        line_plot(
            &without,
            &PlotSpec {
                title: String::new(),
                ..spec()
            },
        )
        .unwrap();
        let (a, b) = (image::open(&with).unwrap(), image::open(&without).unwrap());
        assert_ne!(a.as_bytes(), b.as_bytes());
    }

    #[test]
    fn linear_axes_work_too() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("linear.png");
        let spec = PlotSpec {
            log_x: false,
            log_y: false,
            ..spec()
        };
        line_plot(&path, &spec).unwrap();
        assert_eq!(image::open(&path).unwrap().width(), WIDTH);
    }

    #[test]
    fn bad_input_is_an_error_naming_the_series_and_value() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.png");
        let mut bad = spec();
        bad.series[1].points[2].1 = 0.0;
        let err = line_plot(&path, &bad).unwrap_err().to_string();
        assert!(err.contains("'flat'") && err.contains("y = 0"), "{err}");
        let empty = PlotSpec {
            series: vec![],
            ..spec()
        };
        let err = line_plot(&path, &empty).unwrap_err().to_string();
        assert!(err.contains("nothing to plot"), "{err}");
        assert!(!path.exists());
    }

    #[test]
    fn ten_series_get_ten_distinct_colours() {
        for (i, a) in COLOURS.iter().enumerate() {
            for b in &COLOURS[i + 1..] {
                assert_ne!(a, b);
            }
        }
    }

    #[test]
    fn ticks_are_compact() {
        assert_eq!(tick(100.0), "100");
        assert_eq!(tick(1000.0), "1k");
        assert_eq!(tick(300_000.0), "300k");
        assert_eq!(tick(1e6), "1M");
        assert_eq!(tick(0.05), "0.05");
        assert_eq!(tick(0.0123), "0.0123");
        assert_eq!(tick(1.5), "1.5");
        assert_eq!(tick(0.0), "0");
    }
}
