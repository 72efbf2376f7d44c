//! A render's image error split into noise and bias, from two runs that differ only in their
//! seed.
//!
//! One render's error against the truth `R` is `e² = b² + s²`: `b` what every seed shares (the
//! mesh's discretization, a biased estimator), `s` what changes from seed to seed (Monte Carlo
//! noise). With two independent renders `A` and `B` of the same settings, per pixel (or per
//! block of pixels averaged first) and channel,
//!
//! - `E (A - B)² = 2 s²`, so `s² ≈ (A - B)² / 2`;
//! - `E ((A + B) / 2 - R)² = b² + s² / 2 + σ²` (`σ`: the reference's own standard error), so
//!   `b² ≈ ((A + B) / 2 - R)² - (A - B)² / 4 - σ²`.
//!
//! Summed over the pixels [`image_error`](crate::compare::image_error) scores and divided by
//! `sum R²`, as the image error is. Averaging blocks of `k × k` pixels first shows the scale
//! of each part: noise that is independent from pixel to pixel falls as `1 / k`, a bias shared
//! by a whole region does not. What the two renders share besides the solution's bias also
//! counts as bias: mcrad's pixel samples do not depend on the seed, so their anti-aliasing
//! error is in `b`.

use glam::DVec3;
use mcrad_render::Image;

use crate::compare::{CompareError, same_size, scored_pixels};

/// One render's relative image error and its two parts (dimensionless, relative to the
/// reference's root mean square over the scored pixels), at one block size; `error² = noise² +
/// bias²` up to the clamp of each estimate at zero.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorSplit {
    /// The side of the square blocks averaged before comparing, pixels (1: per pixel).
    pub block: u32,
    /// One render's error against the truth, `sqrt(noise² + bias²)`.
    pub error: f64,
    /// The part that changes with the seed (one render's Monte Carlo noise).
    pub noise: f64,
    /// The part both renders share (the reference's noise taken out).
    pub bias: f64,
}

/// [`ErrorSplit`] of two renders `a` and `b` (the same settings, different seeds) against
/// `reference` with standard error `reference_error` per pixel and channel (or an exact
/// reference), over the pixels that see no emitter (`emitter_fraction`, as
/// [`image_error`](crate::compare::image_error)), with the pixels averaged over blocks of
/// `block × block` first (a block's scored pixels only; the picture's last row and column of
/// blocks may be smaller).
///
/// Errors: images of different sizes, a block of 0 pixels ([`CompareError::ZeroTile`]).
pub fn error_split(
    a: &Image,
    b: &Image,
    reference: &Image,
    reference_error: Option<&Image>,
    emitter_fraction: f32,
    block: u32,
) -> Result<ErrorSplit, CompareError> {
    same_size(a, reference)?;
    same_size(b, reference)?;
    if let Some(e) = reference_error {
        same_size(e, reference)?;
    }
    if block == 0 {
        return Err(CompareError::ZeroTile);
    }
    let (w, k) = (reference.width as usize, block as usize);
    let blocks_x = w.div_ceil(k);
    // per block: the sums of a, b, the reference and the reference's variance, and the count
    let blocks = blocks_x * (reference.height as usize).div_ceil(k);
    let mut sums = vec![(DVec3::ZERO, DVec3::ZERO, DVec3::ZERO, 0.0f64, 0usize); blocks];
    for i in scored_pixels(reference, emitter_fraction) {
        let s = &mut sums[(i / w) / k * blocks_x + (i % w) / k];
        s.0 += a.pixels[i].as_dvec3();
        s.1 += b.pixels[i].as_dvec3();
        s.2 += reference.pixels[i].as_dvec3();
        s.3 += reference_error.map_or(0.0, |e| e.pixels[i].as_dvec3().length_squared());
        s.4 += 1;
    }
    // each block weighs by its pixels: at a block of 1 this is the image error's sums
    let (mut noise, mut bias, mut signal) = (0.0f64, 0.0f64, 0.0f64);
    for &(sa, sb, sr, var, n) in sums.iter().filter(|s| s.4 > 0) {
        let n = n as f64;
        let (ma, mb, mr) = (sa / n, sb / n, sr / n);
        // the block mean's variance is the pixels' over n²
        let var = var / (n * n);
        let spread = (ma - mb).length_squared();
        noise += n * spread / 2.0;
        bias += n * (((ma + mb) / 2.0 - mr).length_squared() - spread / 4.0 - var);
        signal += n * (mr.length_squared() - var);
    }
    let relative = |x: f64| {
        if signal > 0.0 {
            (x.max(0.0) / signal).sqrt()
        } else {
            0.0
        }
    };
    let (noise, bias) = (relative(noise), relative(bias));
    Ok(ErrorSplit {
        block,
        error: noise.hypot(bias),
        noise,
        bias,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use mcrad_random::Stream;

    /// A standard normal deviate (Box-Muller).
    fn normal(rng: &mut Stream) -> f64 {
        let (u, v) = (1.0 - rng.uniform_f64(), rng.uniform_f64());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }

    fn image(w: u32, h: u32, f: impl FnMut(usize) -> Vec3) -> Image {
        Image {
            width: w,
            height: h,
            pixels: (0..(w * h) as usize).map(f).collect(),
        }
    }

    /// Two renders `R (1 + beta) + sigma g` with independent normal `g` per pixel and channel,
    /// against an exact grey reference (no emitter: every pixel scored) and against a noisy
    /// one with its error image: the split finds `beta` and `sigma`, and averaging blocks of
    /// 2 x 2 halves the noise and keeps the bias.
    #[test]
    fn the_split_finds_a_shared_bias_and_independent_noise() {
        let (w, h, beta, sigma) = (200u32, 200u32, 0.03, 0.05);
        let truth = image(w, h, |_| Vec3::ONE);
        let mut rng = Stream::new(7, 0, 0, 0);
        let render = |rng: &mut Stream| {
            image(w, h, |_| {
                Vec3::ONE * (1.0 + beta) as f32
                    + Vec3::new(normal(rng) as f32, normal(rng) as f32, normal(rng) as f32)
                        * sigma as f32
            })
        };
        let (a, b) = (render(&mut rng), render(&mut rng));
        // 120k samples of (A - B)²: the noise's relative standard error is about
        // 1 / sqrt(2 * 120k / 2) = 0.3%; the bias's is sigma / sqrt(2 * 120k) / beta = 0.3%
        let close = |got: f64, want: f64| (got / want - 1.0).abs() < 0.02;
        let s = error_split(&a, &b, &truth, None, 2.0, 1).unwrap();
        assert!(close(s.noise, sigma), "{s:?}");
        assert!(close(s.bias, beta), "{s:?}");
        assert!(close(s.error, beta.hypot(sigma)), "{s:?}");
        let s2 = error_split(&a, &b, &truth, None, 2.0, 2).unwrap();
        assert!(close(s2.noise, sigma / 2.0), "{s2:?}");
        assert!(close(s2.bias, beta), "{s2:?}");
        // a reference with noise of its own, and its standard error: the same bias
        let tau = 0.04f32;
        let noisy = image(w, h, |_| {
            Vec3::ONE
                + Vec3::new(
                    normal(&mut rng) as f32,
                    normal(&mut rng) as f32,
                    normal(&mut rng) as f32,
                ) * tau
        });
        let err = image(w, h, |_| Vec3::splat(tau));
        let s = error_split(&a, &b, &noisy, Some(&err), 2.0, 1).unwrap();
        assert!((s.bias / beta - 1.0).abs() < 0.05, "{s:?}");
        // without the error image the reference's noise would count as bias
        let s = error_split(&a, &b, &noisy, None, 2.0, 1).unwrap();
        assert!(s.bias > 1.3 * beta, "{s:?}");
    }

    #[test]
    fn mismatched_sizes_and_empty_blocks_are_refused() {
        let (a, b) = (image(4, 4, |_| Vec3::ONE), image(4, 3, |_| Vec3::ONE));
        assert!(error_split(&a, &b, &a, None, 0.5, 1).is_err());
        assert!(error_split(&a, &a, &a, None, 0.5, 0).is_err());
        let s = error_split(&a, &a, &a, None, 2.0, 3).unwrap();
        assert_eq!((s.noise, s.bias, s.error), (0.0, 0.0, 0.0));
    }
}
