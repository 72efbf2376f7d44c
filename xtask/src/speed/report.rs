//! From measured curves to the report: crossing times, median curves, the table and plots.

use super::measure::Point;
use anyhow::Result;
use mcrad_lab::plot::{PlotSpec, Series, line_plot};
use std::path::Path;

/// The error levels of the table.
pub const LEVELS: [f64; 3] = [0.05, 0.02, 0.01];

/// When a curve reached an error level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Crossing {
    /// Interpolated log-log between the two points around the level (seconds).
    At(f64),
    /// The first point was already below the level: at most this many seconds.
    AtMost(f64),
    /// Not reached; extrapolated from the last point by `rms_rel ∝ 1/sqrt(t)` (seconds).
    Extrapolated(f64),
    /// Not reached and not falling like `1/sqrt(t)`: the curve ended at this many seconds.
    Never(f64),
}

impl Crossing {
    /// The value to sort by (never reached sorts last).
    fn key(self) -> f64 {
        match self {
            Crossing::At(t) | Crossing::AtMost(t) | Crossing::Extrapolated(t) => t,
            Crossing::Never(t) => f64::INFINITY + t,
        }
    }

    /// A table cell of a crossing in rays, in millions.
    pub fn rays_cell(self) -> String {
        let m = |r: f64| format!("{:.2}M", r / 1e6);
        match self {
            Crossing::At(r) => m(r),
            Crossing::AtMost(r) => format!("≤ {}", m(r)),
            Crossing::Extrapolated(r) => format!("~{}*", m(r)),
            Crossing::Never(r) => format!("> {}", m(r)),
        }
    }

    /// A table cell.
    pub fn cell(self) -> String {
        match self {
            Crossing::At(t) => seconds(t),
            Crossing::AtMost(t) => format!("≤ {}", seconds(t)),
            Crossing::Extrapolated(t) => format!("~{}*", seconds(t)),
            Crossing::Never(t) => format!("> {}", seconds(t)),
        }
    }
}

/// Seconds with two or three significant digits.
fn seconds(t: f64) -> String {
    if t >= 100.0 {
        format!("{t:.0} s")
    } else if t >= 10.0 {
        format!("{t:.1} s")
    } else if t >= 0.01 {
        format!("{t:.2} s")
    } else {
        format!("{t:.3} s")
    }
}

/// When the curve (points in time order) first reaches `level`.
///
/// Between two points the error is interpolated linearly in `(log t, log rms_rel)`. A curve
/// that never reaches the level is extrapolated from its last point by `rms_rel ∝ 1/sqrt(t)` if
/// its last two points fall at least like `t^-0.3` (a curve that has levelled off is not).
pub fn crossing(points: &[Point], level: f64) -> Option<Crossing> {
    crossing_by(points, level, |p| p.seconds)
}

/// [`crossing`] in rays instead of seconds: how many rays the curve needed to reach `level`
/// (the same interpolation and extrapolation, with rays for seconds).
pub fn rays_crossing(points: &[Point], level: f64) -> Option<Crossing> {
    crossing_by(points, level, |p| p.rays as f64)
}

/// [`crossing`] along the axis `at` (seconds or rays) of the points.
fn crossing_by(points: &[Point], level: f64, at: impl Fn(&Point) -> f64) -> Option<Crossing> {
    let first = points.first()?;
    if first.rms_rel <= level {
        return Some(Crossing::AtMost(at(first)));
    }
    for w in points.windows(2) {
        let (a, b) = (w[0], w[1]);
        if b.rms_rel <= level {
            let (la, lb) = (a.rms_rel.ln(), b.rms_rel.ln());
            let (ta, tb) = (at(&a).ln(), at(&b).ln());
            let f = if la > lb {
                (la - level.ln()) / (la - lb)
            } else {
                1.0
            };
            return Some(Crossing::At((ta + f * (tb - ta)).exp()));
        }
    }
    let last = *points.last()?;
    let falling = points.len() >= 2 && {
        let a = points[points.len() - 2];
        let slope = (last.rms_rel / a.rms_rel).ln() / (at(&last) / at(&a)).ln();
        slope <= -0.3
    };
    Some(if falling {
        Crossing::Extrapolated(at(&last) * (last.rms_rel / level).powi(2))
    } else {
        Crossing::Never(at(&last))
    })
}

/// The median (middle, by time; the upper middle of an even count) of the seeds' crossings.
pub fn median_crossing(curves: &[Vec<Point>], level: f64) -> Option<Crossing> {
    median_of(curves.iter().filter_map(|p| crossing(p, level)).collect())
}

/// [`median_crossing`] in rays ([`rays_crossing`]).
pub fn median_rays_crossing(curves: &[Vec<Point>], level: f64) -> Option<Crossing> {
    median_of(
        curves
            .iter()
            .filter_map(|p| rays_crossing(p, level))
            .collect(),
    )
}

/// The median crossing (the upper middle of an even count).
fn median_of(mut c: Vec<Crossing>) -> Option<Crossing> {
    c.sort_by(|a, b| a.key().total_cmp(&b.key()));
    c.get(c.len() / 2).copied()
}

/// The median of `values` (the mean of the middle two of an even count); NaN when empty.
pub fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    match n {
        0 => f64::NAN,
        _ if n % 2 == 1 => values[n / 2],
        _ => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

/// Rays per second of the seeds' longest points (median over seeds).
pub fn rays_per_second(curves: &[Vec<Point>]) -> f64 {
    let mut r: Vec<f64> = curves
        .iter()
        .filter_map(|c| c.last())
        .map(|p| p.rays as f64 / p.seconds)
        .collect();
    median(&mut r)
}

/// One method's plotted curve: point `k` is the median over the seeds that have a `k`-th point
/// of its seconds and of its rms_rel; the band spans their rms_rel from min to max. (Seeds
/// share their points' ray counts, so the `k`-th points belong together.)
pub fn median_series(name: &str, curves: &[Vec<Point>]) -> Series {
    let len = curves.iter().map(Vec::len).max().unwrap_or(0);
    let (mut points, mut band) = (Vec::new(), Vec::new());
    for k in 0..len {
        let at: Vec<Point> = curves.iter().filter_map(|c| c.get(k).copied()).collect();
        let t = median(&mut at.iter().map(|p| p.seconds).collect::<Vec<_>>());
        let e = median(&mut at.iter().map(|p| p.rms_rel).collect::<Vec<_>>());
        let lo = at.iter().map(|p| p.rms_rel).fold(f64::INFINITY, f64::min);
        let hi = at.iter().map(|p| p.rms_rel).fold(0.0, f64::max);
        points.push((t, e));
        band.push((t, lo, hi));
    }
    Series {
        name: name.to_string(),
        points,
        band: Some(band),
    }
}

/// Draws one scene's plot: rms_rel against seconds, log-log, one median curve per method.
pub fn plot(
    path: &Path,
    title: &str,
    seeds: usize,
    methods: &[(&str, &[Vec<Point>])],
) -> Result<()> {
    let series: Vec<Series> = methods
        .iter()
        .filter(|(_, c)| c.iter().any(|p| !p.is_empty()))
        .map(|(name, curves)| median_series(name, curves))
        .collect();
    line_plot(
        path,
        &PlotSpec {
            title: title.to_string(),
            x_label: "seconds (wall clock, from the start of the run)".into(),
            y_label: if seeds == 1 {
                "rms_rel (one seed)".into()
            } else {
                format!("rms_rel (median of {seeds} seeds; band: min-max)")
            },
            log_x: true,
            log_y: true,
            series,
        },
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(seconds: f64, rms_rel: f64) -> Point {
        Point {
            seconds,
            rays: 0,
            rms_rel,
        }
    }

    #[test]
    fn crossings_interpolate_log_log() {
        // rms_rel = 0.1 / sqrt(t): 1% at t = 100; the points straddle it.
        let c = [p(1.0, 0.1), p(16.0, 0.025), p(256.0, 0.1 / 16.0)];
        match crossing(&c, 0.01) {
            Some(Crossing::At(t)) => assert!((t - 100.0).abs() < 1e-9, "{t}"),
            other => panic!("{other:?}"),
        }
        // Below the level from the start, and extrapolated past the end.
        assert_eq!(crossing(&c, 0.2), Some(Crossing::AtMost(1.0)));
        match crossing(&c, 0.001) {
            Some(Crossing::Extrapolated(t)) => assert!((t - 256.0 * 39.0625).abs() < 1e-6),
            other => panic!("{other:?}"),
        }
        // A curve that has levelled off is not extrapolated.
        let flat = [p(1.0, 0.05), p(2.0, 0.049)];
        assert_eq!(crossing(&flat, 0.01), Some(Crossing::Never(2.0)));
        assert_eq!(crossing(&[], 0.01), None);
    }

    #[test]
    fn rays_crossings_follow_the_rays_not_the_seconds() {
        // The same errors at 1000 rays per unit of time, then a slow-down: 1% at 1e5 rays.
        let mut c = [p(1.0, 0.1), p(16.0, 0.025), p(256.0, 0.1 / 16.0)];
        for (k, q) in c.iter_mut().enumerate() {
            q.rays = [1_000, 16_000, 256_000][k];
            q.seconds *= 3.0;
        }
        match rays_crossing(&c, 0.01) {
            Some(Crossing::At(r)) => assert!((r - 1e5).abs() < 1e-6, "{r}"),
            other => panic!("{other:?}"),
        }
        assert_eq!(
            median_rays_crossing(&[c.to_vec()], 0.2),
            Some(Crossing::AtMost(1000.0))
        );
        assert_eq!(Crossing::At(2.5e6).rays_cell(), "2.50M");
    }

    #[test]
    fn the_median_crossing_is_the_middle_seed() {
        let seeds = vec![
            vec![p(1.0, 0.1), p(2.0, 0.005)],
            vec![p(1.0, 0.1), p(4.0, 0.005)],
            vec![p(1.0, 0.1), p(2.0, 0.099)],
        ];
        // Crossings of 1%: about 1.7 s, 3.0 s, never: the median is the second.
        match median_crossing(&seeds, 0.01) {
            Some(Crossing::At(t)) => assert!(t > 2.0 && t < 4.0, "{t}"),
            other => panic!("{other:?}"),
        }
        assert_eq!(median(&mut [3.0, 1.0, 2.0, 10.0]), 2.5);
        let s = median_series("m", &seeds);
        assert_eq!(s.points.len(), 2);
        assert_eq!(s.points[1].0, 2.0);
        assert_eq!(s.band.unwrap()[1], (2.0, 0.005, 0.099));
    }
}
