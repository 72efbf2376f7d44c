//! The sky: radiance arriving from every direction in which a ray leaves the scene, uniform
//! or read from an equirectangular panorama (OpenEXR or Radiance HDR).
//!
//! **Units.** Radiance `L` in W/(m² sr) per RGB channel: an unobstructed surface facing up
//! under a uniform sky receives `pi L` W/m² from the upper hemisphere.
//!
//! **The map's convention.** `+Y` is up. A pixel's centre `(u, v)` in `[0, 1]²` (`u` along a
//! row from the left, `v` down the columns from the top) looks along the direction of polar
//! angle `theta = pi v` from `+Y` and azimuth `phi = 2 pi (u - 1/2)`:
//! `(sin theta sin phi, cos theta, -sin theta cos phi)`. So the top row is the zenith, the
//! middle row the horizon, the centre column `u = 1/2` looks along `-Z`, `u = 3/4` along `+X`,
//! `u = 1/4` along `-X` and the left and right edges along `+Z` (the panorama as seen from
//! inside, `-Z` ahead and `+X` to the right). A rotation of `angle` turns the map about `+Y`
//! counter-clockwise seen from above (right-handed): at 90 degrees the map's centre column
//! looks along `-X`. The map is piecewise constant (nearest pixel, no filtering).

use crate::error::SceneError;
use glam::DVec3;
use std::f64::consts::{PI, TAU};
use std::path::Path;
use std::sync::Arc;

/// The largest edge of a sky map in pixels (a bound on hostile input).
pub const MAX_SKY_EDGE: u32 = 16_384;

/// The sky: radiance (W/(m² sr) per channel) from the directions in which rays leave the
/// scene. See the module's documentation for the map's convention.
#[derive(Debug, Clone, PartialEq)]
pub enum Sky {
    /// The same radiance from every direction, W/(m² sr) per channel (`>= 0`).
    Uniform(DVec3),
    /// An equirectangular panorama (shared: large).
    Map(Arc<SkyMap>),
}

/// An equirectangular sky map: `width = 2 height` pixels of radiance (W/(m² sr), finite,
/// `>= 0`), rows from the zenith down, with a rotation about `+Y` and the distribution that
/// samples its directions by luminance times `sin theta`.
#[derive(Clone, PartialEq)]
pub struct SkyMap {
    width: u32,
    height: u32,
    texels: Vec<[f32; 3]>,
    rotation: f64,
    /// Cumulative row weights (`height + 1` entries, from 0 to 1).
    rows: Vec<f64>,
    /// Per row, cumulative column weights (`width + 1` entries each, from 0 to 1; a row of
    /// weight zero is left all zero).
    cols: Vec<f64>,
    /// Sum of the weights `luminance sin theta` over the pixels.
    total: f64,
}

impl std::fmt::Debug for SkyMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SkyMap")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("rotation", &self.rotation)
            .finish_non_exhaustive()
    }
}

/// A direction drawn from a sky map: unit direction (the scene's frame) and its density per
/// steradian.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkySample {
    /// Unit direction towards the sky.
    pub direction: DVec3,
    /// Probability density of `direction`, 1/sr (`> 0`).
    pub pdf: f64,
}

/// Relative luminance of a linear RGB value (Rec. 709 weights).
fn luminance(c: [f32; 3]) -> f64 {
    0.2126 * f64::from(c[0]) + 0.7152 * f64::from(c[1]) + 0.0722 * f64::from(c[2])
}

impl std::str::FromStr for Sky {
    type Err = String;

    /// `R,G,B`: a uniform sky of radiance R, G, B W/(m² sr), each finite and `>= 0`.
    fn from_str(s: &str) -> Result<Sky, String> {
        let parts: Vec<f64> = s
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| format!("'{s}' is not R,G,B (radiance in W/(m² sr))"))?;
        match parts[..] {
            [r, g, b] if [r, g, b].iter().all(|x| x.is_finite() && *x >= 0.0) => {
                Ok(Sky::Uniform(DVec3::new(r, g, b)))
            }
            _ => Err(format!(
                "'{s}' is not R,G,B: three finite radiances >= 0 in W/(m² sr)"
            )),
        }
    }
}

impl Sky {
    /// The radiance arriving along unit direction `direction` (pointing away from the
    /// scene, towards the sky), W/(m² sr) per channel.
    pub fn radiance(&self, direction: DVec3) -> DVec3 {
        match self {
            Sky::Uniform(l) => *l,
            Sky::Map(map) => map.radiance(direction),
        }
    }

    /// `Err(reason)` when the uniform radiance is negative or not finite (a map is checked
    /// when it is made).
    pub fn check(&self) -> Result<(), String> {
        match self {
            Sky::Uniform(l) if !(l.is_finite() && l.min_element() >= 0.0) => {
                Err(format!("radiance {l} W/(m² sr) is negative or not finite"))
            }
            _ => Ok(()),
        }
    }

    /// Whether the sky gives no light at all (zero radiance everywhere).
    pub fn is_dark(&self) -> bool {
        match self {
            Sky::Uniform(l) => l.max_element() <= 0.0,
            Sky::Map(map) => map.texels.iter().all(|t| t.iter().all(|&c| c <= 0.0)),
        }
    }

    /// Reads an equirectangular map (`.exr`, or `.hdr` Radiance RGBE; by extension) turned by
    /// `rotation` radians about `+Y` (see the module's convention). Errors
    /// ([`SceneError::BadSky`]): a missing or unreadable file, an unknown extension, a width
    /// that is not twice the height, an edge beyond [`MAX_SKY_EDGE`], a negative or non-finite
    /// pixel (named by column and row), a non-finite rotation.
    pub fn load_map(path: &Path, rotation: f64) -> Result<Sky, SceneError> {
        let fail = |reason: String| SceneError::BadSky {
            path: path.to_path_buf(),
            reason,
        };
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        let (width, height, texels) = match ext.as_deref() {
            Some("exr") => read_exr(path).map_err(fail)?,
            Some("hdr") => read_hdr(path).map_err(fail)?,
            _ => {
                return Err(fail(
                    "the sky map must be an OpenEXR (.exr) or Radiance HDR (.hdr) file".into(),
                ));
            }
        };
        SkyMap::new(width, height, texels, rotation)
            .map(|m| Sky::Map(Arc::new(m)))
            .map_err(fail)
    }
}

fn read_exr(path: &Path) -> Result<(u32, u32, Vec<[f32; 3]>), String> {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |size, _| {
            let (w, h) = (size.width(), size.height());
            let fits = w <= 2 * MAX_SKY_EDGE as usize && h <= MAX_SKY_EDGE as usize;
            (
                w,
                if fits {
                    vec![[0.0; 3]; w * h]
                } else {
                    Vec::new()
                },
            )
        },
        |(width, texels): &mut (usize, Vec<[f32; 3]>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            if let Some(t) = texels.get_mut(pos.y() * *width + pos.x()) {
                *t = [r, g, b];
            }
        },
    )
    .map_err(|e| format!("could not read it as OpenEXR: {e}"))?;
    let size = image.layer_data.size;
    let (_, texels) = image.layer_data.channel_data.pixels;
    let (w, h) = (size.width(), size.height());
    if texels.len() != w * h {
        return Err(format!(
            "{w} x {h} pixels: at most {} x {MAX_SKY_EDGE}",
            2 * MAX_SKY_EDGE
        ));
    }
    Ok((w as u32, h as u32, texels))
}

fn read_hdr(path: &Path) -> Result<(u32, u32, Vec<[f32; 3]>), String> {
    let file = std::fs::File::open(path).map_err(|e| format!("could not open it: {e}"))?;
    let decoder = image::codecs::hdr::HdrDecoder::new(std::io::BufReader::new(file))
        .map_err(|e| format!("could not read it as Radiance HDR: {e}"))?;
    let meta = decoder.metadata();
    if meta.width > 2 * MAX_SKY_EDGE || meta.height > MAX_SKY_EDGE {
        return Err(format!(
            "{} x {} pixels: at most {} x {MAX_SKY_EDGE}",
            meta.width,
            meta.height,
            2 * MAX_SKY_EDGE
        ));
    }
    let image = image::DynamicImage::from_decoder(decoder)
        .map_err(|e| format!("could not read it as Radiance HDR: {e}"))?
        .into_rgb32f();
    let (w, h) = image.dimensions();
    let texels = image.pixels().map(|p| p.0).collect();
    Ok((w, h, texels))
}

impl SkyMap {
    /// A map of `width x height` pixels (`texels` row by row from the top), turned by
    /// `rotation` radians about `+Y`. `Err(reason)` unless `width = 2 height >= 2`, both
    /// within [`MAX_SKY_EDGE`] (width up to twice it), `texels` has `width height` entries,
    /// each channel finite and `>= 0`, and `rotation` is finite.
    pub fn new(
        width: u32,
        height: u32,
        texels: Vec<[f32; 3]>,
        rotation: f64,
    ) -> Result<SkyMap, String> {
        if height == 0 || width != 2 * height || height > MAX_SKY_EDGE {
            return Err(format!(
                "{width} x {height} pixels: an equirectangular map is twice as wide as high, \
                 at most {} x {MAX_SKY_EDGE}",
                2 * MAX_SKY_EDGE
            ));
        }
        if texels.len() != width as usize * height as usize {
            return Err(format!("{} pixels for {width} x {height}", texels.len()));
        }
        if let Some(k) = texels
            .iter()
            .position(|t| !t.iter().all(|c| c.is_finite() && *c >= 0.0))
        {
            let t = texels[k];
            return Err(format!(
                "pixel (column {}, row {}) is ({}, {}, {}): each channel must be finite and >= 0 \
                 W/(m² sr)",
                k % width as usize,
                k / width as usize,
                t[0],
                t[1],
                t[2]
            ));
        }
        if !rotation.is_finite() {
            return Err(format!("rotation {rotation} is not finite"));
        }
        let (w, h) = (width as usize, height as usize);
        let mut rows = vec![0.0; h + 1];
        let mut cols = vec![0.0; h * (w + 1)];
        for j in 0..h {
            let sin = (PI * (j as f64 + 0.5) / h as f64).sin();
            let c = &mut cols[j * (w + 1)..(j + 1) * (w + 1)];
            for i in 0..w {
                c[i + 1] = c[i] + luminance(texels[j * w + i]) * sin;
            }
            let row = c[w];
            if row > 0.0 {
                c.iter_mut().for_each(|x| *x /= row);
            }
            rows[j + 1] = rows[j] + row;
        }
        let total = rows[h];
        if total > 0.0 {
            rows.iter_mut().for_each(|x| *x /= total);
        }
        Ok(SkyMap {
            width,
            height,
            texels,
            rotation,
            rows,
            cols,
            total,
        })
    }

    /// Width in pixels (twice the height).
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The pixels' radiance (W/(m² sr) per channel), row by row from the zenith.
    pub fn texels(&self) -> &[[f32; 3]] {
        &self.texels
    }

    /// The rotation about `+Y`, radians (counter-clockwise seen from above).
    pub fn rotation(&self) -> f64 {
        self.rotation
    }

    /// The pixel (column, row) the unit direction `d` (scene frame) looks at, and the
    /// direction's `sin theta` in the map's frame.
    fn pixel(&self, d: DVec3) -> (usize, usize, f64) {
        let (s, c) = (-self.rotation).sin_cos();
        let (x, z) = (c * d.x + s * d.z, -s * d.x + c * d.z);
        let y = d.y.clamp(-1.0, 1.0);
        let u = 0.5 + x.atan2(-z) / TAU;
        let v = y.acos() / PI;
        let (w, h) = (self.width as usize, self.height as usize);
        let i = ((u * w as f64).floor().max(0.0) as usize).min(w - 1);
        let j = ((v * h as f64).floor().max(0.0) as usize).min(h - 1);
        (i, j, (1.0 - y * y).max(0.0).sqrt())
    }

    /// The radiance along unit direction `d` (scene frame), W/(m² sr) per channel.
    pub fn radiance(&self, d: DVec3) -> DVec3 {
        let (i, j, _) = self.pixel(d);
        let t = self.texels[j * self.width as usize + i];
        DVec3::new(f64::from(t[0]), f64::from(t[1]), f64::from(t[2]))
    }

    /// The density per steradian with which [`SkyMap::sample`] draws unit direction `d`: in
    /// proportion to the pixel's luminance (0 for a black map or pixel, or at a pole).
    pub fn pdf(&self, d: DVec3) -> f64 {
        let (i, j, sin) = self.pixel(d);
        if self.total <= 0.0 || sin <= 0.0 {
            return 0.0;
        }
        let (w, h) = (self.width as usize, self.height as usize);
        let sin_c = (PI * (j as f64 + 0.5) / h as f64).sin();
        let weight = luminance(self.texels[j * w + i]) * sin_c;
        weight * (w * h) as f64 / self.total / (2.0 * PI * PI * sin)
    }

    /// A direction drawn with `u` in `[0, 1)²` in proportion to luminance times solid angle
    /// (a piecewise-constant density over the pixels, `sin theta` the Jacobian of the
    /// equirectangular map); `None` for a black map or a draw at a pole.
    pub fn sample(&self, u: [f64; 2]) -> Option<SkySample> {
        if self.total <= 0.0 {
            return None;
        }
        let (w, h) = (self.width as usize, self.height as usize);
        let (j, fv) = search(&self.rows, u[0]);
        let (i, fu) = search(&self.cols[j * (w + 1)..(j + 1) * (w + 1)], u[1]);
        let theta = PI * (j as f64 + fv) / h as f64;
        let phi = TAU * ((i as f64 + fu) / w as f64 - 0.5);
        let (st, ct) = theta.sin_cos();
        if st <= 0.0 {
            return None;
        }
        let local = DVec3::new(st * phi.sin(), ct, -st * phi.cos());
        let (s, c) = self.rotation.sin_cos();
        let direction = DVec3::new(
            c * local.x + s * local.z,
            local.y,
            -s * local.x + c * local.z,
        );
        let pdf = self.pdf(direction);
        (pdf > 0.0).then_some(SkySample { direction, pdf })
    }
}

/// The cell `k` of the cumulative weights `cdf` (from 0 to 1) that `u` falls in, and where
/// in it (`[0, 1)`); cells of weight zero are never chosen.
fn search(cdf: &[f64], u: f64) -> (usize, f64) {
    let n = cdf.len() - 1;
    let k = cdf.partition_point(|&c| c <= u).clamp(1, n) - 1;
    let span = cdf[k + 1] - cdf[k];
    let f = if span > 0.0 {
        ((u - cdf[k]) / span).clamp(0.0, 1.0 - f64::EPSILON)
    } else {
        0.5
    };
    (k, f)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `2h x h` map, black but for pixel `(i, j)` of radiance 1.
    fn spot(h: u32, i: u32, j: u32, rotation: f64) -> SkyMap {
        let mut t = vec![[0.0; 3]; (2 * h * h) as usize];
        t[(j * 2 * h + i) as usize] = [1.0, 1.0, 1.0];
        SkyMap::new(2 * h, h, t, rotation).unwrap()
    }

    #[test]
    fn the_centre_column_looks_along_minus_z_and_three_quarters_along_plus_x() {
        let h = 8;
        // horizon rows are h/2 - 1 and h/2: take the one just above the horizon
        let horizon = DVec3::new(0.0, 0.05, -1.0).normalize();
        assert_eq!(spot(h, h, h / 2 - 1, 0.0).radiance(horizon).x, 1.0);
        let east = DVec3::new(1.0, 0.05, 0.0).normalize();
        assert_eq!(spot(h, 3 * h / 2, h / 2 - 1, 0.0).radiance(east).x, 1.0);
        assert_eq!(spot(h, 3 * h / 2, h / 2 - 1, 0.0).radiance(horizon).x, 0.0);
        let west = DVec3::new(-1.0, 0.05, 0.0).normalize();
        assert_eq!(spot(h, h / 2, h / 2 - 1, 0.0).radiance(west).x, 1.0);
        // the top row is the zenith
        assert_eq!(spot(h, 3, 0, 0.0).radiance(DVec3::Y).x, 0.0);
        let mut all = vec![[0.0; 3]; (2 * h * h) as usize];
        all[..(2 * h) as usize].fill([2.0; 3]);
        let top = SkyMap::new(2 * h, h, all, 0.0).unwrap();
        assert_eq!(top.radiance(DVec3::Y).x, 2.0);
        // turned by 90 degrees counter-clockwise from above, the centre looks along -X
        let turned = spot(h, h, h / 2 - 1, std::f64::consts::FRAC_PI_2);
        assert_eq!(turned.radiance(west).x, 1.0);
        assert_eq!(turned.radiance(horizon).x, 0.0);
    }

    #[test]
    fn samples_land_in_their_pixel_and_the_density_integrates_to_one() {
        let map = spot(8, 11, 2, 0.7);
        for k in 0..100 {
            let u = [(k as f64 + 0.5) / 100.0, ((k * 37) % 100) as f64 / 100.0];
            let s = map.sample(u).unwrap();
            assert_eq!(map.radiance(s.direction).x, 1.0);
            assert!((s.pdf - map.pdf(s.direction)).abs() < 1e-9 * s.pdf);
        }
        // a smooth map: the density over a fine grid of directions integrates to 1
        let h = 16u32;
        let t: Vec<[f32; 3]> = (0..2 * h * h)
            .map(|k| [1.0 + (k % 7) as f32, 0.5, (k % 3) as f32])
            .collect();
        let map = SkyMap::new(2 * h, h, t, 0.3).unwrap();
        let n = 800;
        let mut integral = 0.0;
        for a in 0..n {
            let theta = PI * (a as f64 + 0.5) / n as f64;
            for b in 0..2 * n {
                let phi = TAU * (b as f64 + 0.5) / (2 * n) as f64;
                let d = DVec3::new(
                    theta.sin() * phi.cos(),
                    theta.cos(),
                    theta.sin() * phi.sin(),
                );
                integral += map.pdf(d) * theta.sin();
            }
        }
        integral *= PI / n as f64 * TAU / (2 * n) as f64;
        assert!((integral - 1.0).abs() < 5e-3, "{integral}");
    }

    #[test]
    fn bad_maps_are_refused() {
        assert!(SkyMap::new(4, 4, vec![[0.0; 3]; 16], 0.0).is_err());
        let mut t = vec![[0.0; 3]; 8];
        t[5] = [0.0, f32::NAN, 0.0];
        let e = SkyMap::new(4, 2, t, 0.0).unwrap_err();
        assert!(e.contains("column 1, row 1"), "{e}");
        let mut t = vec![[0.0; 3]; 8];
        t[0] = [-1.0, 0.0, 0.0];
        assert!(SkyMap::new(4, 2, t, 0.0).is_err());
        let e = Sky::load_map(Path::new("/nonexistent/sky.exr"), 0.0).unwrap_err();
        assert!(e.to_string().contains("sky.exr"), "{e}");
        assert!(Sky::Uniform(DVec3::new(1.0, -1.0, 0.0)).check().is_err());
    }
}
