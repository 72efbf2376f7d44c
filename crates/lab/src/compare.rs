//! Comparing two renders of the same scene for golden-image regression.
//!
//! Monte Carlo renders differ from seed to seed, so a pixel-exact comparison is meaningless and
//! a per-pixel one drowns in noise. The images are compared per tile instead: the mean radiance
//! of each `tile × tile` block and RGB channel, relative to the golden block's mean (plus a
//! floor, so nearly black tiles do not divide by zero). Averaging over a tile keeps systematic
//! changes (a wall a few percent brighter shifts every tile it covers) while it divides the noise
//! by the square root of the pixels and patches the tile covers. The statistic is the largest
//! relative tile difference; the threshold it is held to is measured from the spread between
//! seeds and recorded per scene (`cargo xtask regress --bless`).

use glam::Vec3;
use mcrad_render::Image;

/// The result of comparing an image with its golden.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TileDifference {
    /// The largest `|mean_actual - mean_golden| / (mean_golden + floor)` over tiles and
    /// channels (dimensionless).
    pub max_relative: f32,
    /// The tile where it occurs: its top-left pixel `(x, y)`.
    pub worst_tile: (u32, u32),
    /// The RGB channel where it occurs (0, 1, 2).
    pub worst_channel: usize,
}

/// Why two images cannot be compared.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CompareError {
    /// The sizes differ.
    #[error("image sizes differ: {a:?} vs {b:?}")]
    SizeMismatch {
        /// Width and height of the first image.
        a: (u32, u32),
        /// Width and height of the second image.
        b: (u32, u32),
    },
    /// The tile size is zero.
    #[error("the tile size must be at least 1 pixel")]
    ZeroTile,
}

/// Compares `actual` with `golden` tile by tile (tiles of `tile × tile` pixels; the last row
/// and column of tiles may be smaller). `floor` (radiance, W/(m² sr)) is added to the golden
/// mean in the denominator: differences in tiles darker than it count as absolute ones.
pub fn tile_difference(
    actual: &Image,
    golden: &Image,
    tile: u32,
    floor: f32,
) -> Result<TileDifference, CompareError> {
    same_size(actual, golden)?;
    if tile == 0 {
        return Err(CompareError::ZeroTile);
    }
    let mut worst = TileDifference {
        max_relative: 0.0,
        worst_tile: (0, 0),
        worst_channel: 0,
    };
    for ty in (0..golden.height).step_by(tile as usize) {
        for tx in (0..golden.width).step_by(tile as usize) {
            let (mut a, mut g) = (Vec3::ZERO, Vec3::ZERO);
            let mut n = 0.0f32;
            for y in ty..(ty + tile).min(golden.height) {
                for x in tx..(tx + tile).min(golden.width) {
                    let i = y as usize * golden.width as usize + x as usize;
                    a += actual.pixels[i];
                    g += golden.pixels[i];
                    n += 1.0;
                }
            }
            let rel = (a / n - g / n).abs() / (g / n + Vec3::splat(floor));
            for c in 0..3 {
                if rel[c] > worst.max_relative || rel[c].is_nan() {
                    worst = TileDifference {
                        max_relative: rel[c],
                        worst_tile: (tx, ty),
                        worst_channel: c,
                    };
                }
            }
        }
    }
    Ok(worst)
}

/// An image of `|actual - golden|` per pixel and channel, scaled so the largest difference is 1
/// (a picture of where two renders differ).
pub fn difference_image(actual: &Image, golden: &Image) -> Result<Image, CompareError> {
    same_size(actual, golden)?;
    let diff: Vec<Vec3> = actual
        .pixels
        .iter()
        .zip(&golden.pixels)
        .map(|(a, g)| (*a - *g).abs())
        .collect();
    let max = diff.iter().map(|d| d.max_element()).fold(0.0f32, f32::max);
    let scale = if max > 0.0 { 1.0 / max } else { 1.0 };
    Ok(Image {
        width: golden.width,
        height: golden.height,
        pixels: diff.into_iter().map(|d| d * scale).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: u32, h: u32, f: impl Fn(u32, u32) -> Vec3) -> Image {
        Image {
            width: w,
            height: h,
            pixels: (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| f(x, y))
                .collect(),
        }
    }

    #[test]
    fn a_brighter_region_is_found_and_noise_averages_out() {
        let golden = image(64, 64, |_, _| Vec3::splat(1.0));
        // +-10% pixel noise (a checkerboard) averages to zero over an 8 x 8 tile.
        let noisy = image(64, 64, |x, y| {
            Vec3::splat(if (x + y) % 2 == 0 { 1.1 } else { 0.9 })
        });
        let d = tile_difference(&noisy, &golden, 8, 0.01).unwrap();
        assert!(d.max_relative < 1e-5, "{d:?}");
        // A region 4% brighter in red.
        let shifted = image(64, 64, |x, y| {
            if x >= 40 && y < 16 {
                Vec3::new(1.04, 1.0, 1.0)
            } else {
                Vec3::ONE
            }
        });
        let d = tile_difference(&shifted, &golden, 8, 0.01).unwrap();
        assert!((d.max_relative - 0.04 / 1.01).abs() < 1e-5, "{d:?}");
        assert_eq!(
            (d.worst_tile.0 >= 40, d.worst_tile.1 < 16, d.worst_channel),
            (true, true, 0)
        );
        let diff = difference_image(&shifted, &golden).unwrap();
        assert_eq!(diff.pixels[63].x, 1.0);
        assert_eq!(diff.pixels[64 * 63].x, 0.0);
    }

    #[test]
    fn sizes_must_match() {
        let a = image(4, 4, |_, _| Vec3::ONE);
        let b = image(4, 5, |_, _| Vec3::ONE);
        assert!(tile_difference(&a, &b, 2, 0.0).is_err());
        assert!(tile_difference(&a, &a, 0, 0.0).is_err());
        assert!(difference_image(&a, &b).is_err());
    }
}

/// The image error of a render against a converged picture of the same camera (issue 15):
/// `img_rel = sqrt( sum_px,c (I - R)² / sum_px,c R² )` over the pixels that see no emitter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageError {
    /// `img_rel` over every pixel kept (dimensionless).
    pub relative: f64,
    /// The same over the darkest third of the pixels kept (by the reference's luminance).
    pub dark_third: f64,
    /// Pixels kept: those that see no emitter and have no such neighbour.
    pub pixels: usize,
}

/// [`ImageError`] of `actual` against `reference`. A pixel "sees an emitter" when the
/// reference's luminance there is at least `emitter_fraction` of its largest (emitters are far
/// brighter than what they light); such pixels and their eight neighbours are left out, since
/// there the difference is the pixel filter's coverage of a light's edge, not the solution.
pub fn image_error(
    actual: &Image,
    reference: &Image,
    emitter_fraction: f32,
) -> Result<ImageError, CompareError> {
    image_error_against_noisy(actual, reference, None, emitter_fraction)
}

/// [`image_error`] against a reference that is itself an estimate with standard error
/// `reference_error` per pixel and channel (a path-traced picture,
/// [`pathtrace`](crate::pathtrace)): the reference's own noise adds `sum σ²` to
/// `sum (I - R)²` on average, so it is subtracted,
///
/// `img_rel = sqrt( max(0, sum (I - R)² - sum σ²) / sum R² )`,
///
/// an estimate of the error against the noiseless picture (`sum R²` keeps its own tiny bias
/// `sum σ²`, which is subtracted too). Without `reference_error` this is [`image_error`].
pub fn image_error_against_noisy(
    actual: &Image,
    reference: &Image,
    reference_error: Option<&Image>,
    emitter_fraction: f32,
) -> Result<ImageError, CompareError> {
    if let Some(e) = reference_error {
        same_size(e, reference)?;
    }
    same_size(actual, reference)?;
    let lum = |p: Vec3| mcrad_render::luminance(p);
    let kept = scored_pixels(reference, emitter_fraction);
    let error = |pixels: &[usize]| {
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for &i in pixels {
            let (a, r) = (actual.pixels[i].as_dvec3(), reference.pixels[i].as_dvec3());
            let noise = reference_error.map_or(0.0, |e| e.pixels[i].as_dvec3().length_squared());
            num += (a - r).length_squared() - noise;
            den += r.length_squared() - noise;
        }
        if den > 0.0 {
            (num.max(0.0) / den).sqrt()
        } else {
            0.0
        }
    };
    let relative = error(&kept);
    let mut by_luminance = kept.clone();
    by_luminance.sort_by(|&a, &b| {
        lum(reference.pixels[a])
            .total_cmp(&lum(reference.pixels[b]))
            .then(a.cmp(&b))
    });
    let dark_third = error(&by_luminance[..by_luminance.len() / 3]);
    Ok(ImageError {
        relative,
        dark_third,
        pixels: kept.len(),
    })
}

/// The relative noise of a noisy picture with standard error `error` per pixel and channel,
/// `sqrt( sum σ² / sum R² )` over the pixels [`image_error_against_noisy`] scores (those that
/// see no emitter and neighbour none, by `emitter_fraction`): the image error a perfect render
/// would measure against `reference` before the noise is subtracted. Over every pixel the
/// emitters' `R²` would swamp the sum (the Cornell box at 1,024 paths per pixel: 0.77% over
/// every pixel, 2.2% over the scored ones).
pub fn relative_noise(
    reference: &Image,
    error: &Image,
    emitter_fraction: f32,
) -> Result<f64, CompareError> {
    same_size(error, reference)?;
    let (mut noise, mut signal) = (0.0f64, 0.0f64);
    for i in scored_pixels(reference, emitter_fraction) {
        noise += error.pixels[i].as_dvec3().length_squared();
        signal += reference.pixels[i].as_dvec3().length_squared();
    }
    Ok(if signal > 0.0 {
        (noise / signal).sqrt()
    } else {
        0.0
    })
}

/// A render's reported error per pixel against the error measured on it (the check of
/// issue 35 item 6): over the pixels [`image_error`] scores where the report is positive
/// (pixels that see a surface), the median and 95th percentile of each, and the 95th
/// percentiles of the report's other two channels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorCheck {
    /// Pixels counted.
    pub pixels: usize,
    /// The reported relative error's median (dimensionless).
    pub reported_median: f64,
    /// The reported relative error's 95th percentile.
    pub reported_p95: f64,
    /// The measured relative error's median.
    pub measured_median: f64,
    /// The measured relative error's 95th percentile.
    pub measured_p95: f64,
    /// The 95th percentile of the report's second channel (`--error-image`: the noise part).
    pub second_p95: f64,
    /// The 95th percentile of the report's third channel (`--error-image`: the mesh part).
    pub third_p95: f64,
}

/// [`ErrorCheck`] of `actual` against `reference` (standard error `reference_error` per pixel
/// and channel, subtracted) for the reported relative error `reported` (its first channel,
/// per pixel). The measured error of a pixel is in the convention of the reported one
/// (`sqrt(sum_c δ_c²) / sum_c R_c`, as `relative_error` of `mcrad-combine`):
///
/// `m = sqrt( max(0, sum_c (I_c - R_c)² - sum_c σ_c²) ) / sum_c R_c`,
///
/// the reference's noise taken out of each pixel's squared difference on average.
pub fn error_check(
    actual: &Image,
    reference: &Image,
    reference_error: Option<&Image>,
    reported: &Image,
    emitter_fraction: f32,
) -> Result<ErrorCheck, CompareError> {
    same_size(actual, reference)?;
    same_size(reported, reference)?;
    if let Some(e) = reference_error {
        same_size(e, reference)?;
    }
    let (mut said, mut seen) = (Vec::new(), Vec::new());
    let (mut second, mut third) = (Vec::new(), Vec::new());
    for i in scored_pixels(reference, emitter_fraction) {
        let r = f64::from(reported.pixels[i].x);
        let sum = reference.pixels[i].as_dvec3().element_sum();
        if r.is_nan() || sum.is_nan() || r <= 0.0 || sum <= 0.0 {
            continue;
        }
        let (a, b) = (actual.pixels[i].as_dvec3(), reference.pixels[i].as_dvec3());
        let noise = reference_error.map_or(0.0, |e| e.pixels[i].as_dvec3().length_squared());
        said.push(r);
        second.push(f64::from(reported.pixels[i].y));
        third.push(f64::from(reported.pixels[i].z));
        seen.push(((a - b).length_squared() - noise).max(0.0).sqrt() / sum);
    }
    let quantile = |v: &mut Vec<f64>, q: f64| {
        v.sort_by(f64::total_cmp);
        if v.is_empty() {
            0.0
        } else {
            v[((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1]
        }
    };
    Ok(ErrorCheck {
        pixels: said.len(),
        reported_median: quantile(&mut said, 0.5),
        reported_p95: quantile(&mut said, 0.95),
        measured_median: quantile(&mut seen, 0.5),
        measured_p95: quantile(&mut seen, 0.95),
        second_p95: quantile(&mut second, 0.95),
        third_p95: quantile(&mut third, 0.95),
    })
}

/// The emitter mask's usual fraction: a pixel whose luminance, or a neighbour's, is at least
/// half the reference's brightest sees an emitter and is left out of the image error.
pub const EMITTER_FRACTION: f32 = 0.5;

/// The pixels the image error scores: those that see no emitter and neighbour none (see
/// [`image_error`]), in pixel order.
pub(crate) fn scored_pixels(reference: &Image, emitter_fraction: f32) -> Vec<usize> {
    let left_out = near_emitters(reference, emitter_fraction);
    (0..left_out.len()).filter(|&i| !left_out[i]).collect()
}

/// `Ok` when `a` and `b` have the same size, else [`CompareError::SizeMismatch`].
pub(crate) fn same_size(a: &Image, b: &Image) -> Result<(), CompareError> {
    if (a.width, a.height) == (b.width, b.height) {
        Ok(())
    } else {
        Err(CompareError::SizeMismatch {
            a: (a.width, a.height),
            b: (b.width, b.height),
        })
    }
}

/// Per pixel, whether it sees an emitter or neighbours one: the reference's luminance there or
/// at one of its eight neighbours is at least `emitter_fraction` of its largest.
fn near_emitters(reference: &Image, emitter_fraction: f32) -> Vec<bool> {
    let (w, h) = (reference.width as usize, reference.height as usize);
    let lum = |p: Vec3| mcrad_render::luminance(p);
    let brightest = reference.pixels.iter().map(|&p| lum(p)).fold(0.0, f32::max);
    let emitter: Vec<bool> = reference
        .pixels
        .iter()
        .map(|&p| brightest > 0.0 && lum(p) >= emitter_fraction * brightest)
        .collect();
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            (y.saturating_sub(1)..(y + 2).min(h))
                .any(|yy| (x.saturating_sub(1)..(x + 2).min(w)).any(|xx| emitter[yy * w + xx]))
        })
        .collect()
}

/// Where and which way `actual` departs from `reference`, for the eye: red where the render is
/// brighter, blue where it is darker, with the intensity `|L_I - L_R| / (full_scale * mean L_R)`
/// (luminances, the mean over the pixels [`image_error`] keeps, clamped to 1), so a pixel's
/// brightness is its share of the squared error; the pixels `image_error` leaves out (emitters
/// and their neighbours) are mid grey.
pub fn signed_difference_image(
    actual: &Image,
    reference: &Image,
    emitter_fraction: f32,
    full_scale: f32,
) -> Result<Image, CompareError> {
    same_size(actual, reference)?;
    let lum = |p: Vec3| mcrad_render::luminance(p);
    let left_out = near_emitters(reference, emitter_fraction);
    let (mut sum, mut count) = (0.0f64, 0usize);
    for (i, &p) in reference.pixels.iter().enumerate() {
        if !left_out[i] {
            sum += f64::from(lum(p));
            count += 1;
        }
    }
    let scale = if count > 0 && sum > 0.0 {
        1.0 / (full_scale * (sum / count as f64) as f32)
    } else {
        1.0
    };
    let pixels = (0..left_out.len())
        .map(|i| {
            if left_out[i] {
                return Vec3::splat(0.5);
            }
            let d = (lum(actual.pixels[i]) - lum(reference.pixels[i])) * scale;
            if d >= 0.0 {
                Vec3::new(d.min(1.0), 0.0, 0.0)
            } else {
                Vec3::new(0.0, 0.0, (-d).min(1.0))
            }
        })
        .collect();
    Ok(Image {
        width: reference.width,
        height: reference.height,
        pixels,
    })
}

#[cfg(test)]
mod image_error_tests {
    use super::*;

    #[test]
    fn image_error_is_relative_and_leaves_emitters_out() {
        // A 6 × 6 reference of radiance 1, 2 and 3 by rows, and one emitter pixel.
        let mut reference = Image {
            width: 6,
            height: 6,
            pixels: (0..36)
                .map(|i| Vec3::splat(1.0 + (i / 12) as f32))
                .collect(),
        };
        reference.pixels[0] = Vec3::splat(100.0);
        let brighter = Image {
            pixels: reference.pixels.iter().map(|&p| p * 1.1).collect(),
            ..reference.clone()
        };
        let e = image_error(&brighter, &reference, 0.5).unwrap();
        assert!((e.relative - 0.1).abs() < 1e-6, "{e:?}");
        assert!((e.dark_third - 0.1).abs() < 1e-6, "{e:?}");
        assert_eq!(e.pixels, 36 - 4);
        // A wrong emitter pixel does not count; a wrong dark pixel counts in the dark third.
        let mut wrong = reference.clone();
        wrong.pixels[0] = Vec3::ZERO;
        wrong.pixels[2] = Vec3::splat(2.0);
        let e = image_error(&wrong, &reference, 0.5).unwrap();
        assert!(e.relative > 0.0 && e.dark_third > e.relative, "{e:?}");
        assert_eq!(
            image_error(&reference, &reference, 0.5).unwrap().relative,
            0.0
        );
    }

    #[test]
    fn relative_noise_is_over_the_scored_pixels() {
        // A reference of radiance 2 with one emitter pixel of 1000 in a corner; standard
        // error 0.1 everywhere: over the 32 scored pixels sqrt(32 · 3 · 0.01 / (32 · 3 · 4)) =
        // 5%, where the emitter's R² would make it 0.5%.
        let mut reference = Image {
            width: 6,
            height: 6,
            pixels: vec![Vec3::splat(2.0); 36],
        };
        reference.pixels[0] = Vec3::splat(1000.0);
        let error = Image {
            pixels: vec![Vec3::splat(0.1); 36],
            ..reference.clone()
        };
        let n = relative_noise(&reference, &error, 0.5).unwrap();
        assert!((n - 0.05).abs() < 1e-6, "{n}");
        let small = Image {
            width: 5,
            ..error.clone()
        };
        assert!(relative_noise(&reference, &small, 0.5).is_err());
    }

    #[test]
    fn the_noise_of_a_path_traced_reference_is_subtracted() {
        // A flat truth T = 1; the reference is T plus noise of standard deviation 0.05 per
        // pixel and channel (alternating signs, exactly ±0.05), the render is
        // T * 1.02. Against the noisy reference the plain error is sqrt(0.02² + 0.05²) = 5.4%;
        // told the reference's standard error, 2%.
        let (w, h) = (40, 40);
        let truth = Vec3::ONE;
        let sign = |i: usize, c: usize| if (i + c).is_multiple_of(2) { 1.0 } else { -1.0 };
        let reference = Image {
            width: w,
            height: h,
            pixels: (0..(w * h) as usize)
                .map(|i| truth + 0.05 * Vec3::new(sign(i, 0), sign(i, 1), sign(i, 2)))
                .collect(),
        };
        let noise = Image {
            width: w,
            height: h,
            pixels: vec![Vec3::splat(0.05); (w * h) as usize],
        };
        let render = Image {
            width: w,
            height: h,
            pixels: vec![truth * 1.02; (w * h) as usize],
        };
        let plain = image_error(&render, &reference, 2.0).unwrap().relative;
        let fair = image_error_against_noisy(&render, &reference, Some(&noise), 2.0)
            .unwrap()
            .relative;
        assert!((plain - 0.054).abs() < 0.003, "{plain}");
        assert!((fair - 0.02).abs() < 0.002, "{fair}");
        let small = Image {
            width: 2,
            height: 2,
            pixels: vec![Vec3::ONE; 4],
        };
        assert!(image_error_against_noisy(&render, &reference, Some(&small), 2.0).is_err());
    }

    #[test]
    fn signed_difference_is_red_when_brighter_blue_when_darker_grey_at_emitters() {
        let mut reference = Image {
            width: 8,
            height: 8,
            pixels: vec![Vec3::splat(1.0); 64],
        };
        reference.pixels[0] = Vec3::splat(100.0); // an emitter
        let mut actual = reference.clone();
        actual.pixels[40] = Vec3::splat(1.05);
        actual.pixels[50] = Vec3::splat(0.9);
        let d = signed_difference_image(&actual, &reference, 0.5, 0.1).unwrap();
        assert_eq!(d.pixels[0], Vec3::splat(0.5));
        assert_eq!(d.pixels[9], Vec3::splat(0.5));
        assert!(d.pixels[40].x > 0.4 && d.pixels[40].x < 0.6 && d.pixels[40].z == 0.0);
        assert!(d.pixels[50].z == 1.0 && d.pixels[50].x == 0.0);
        assert_eq!(d.pixels[30], Vec3::ZERO);
    }
}
