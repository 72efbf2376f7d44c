//! Sampling warps, each a triple: sample, density, inverse.
//!
//! Densities are stated with respect to their measure: solid angle (per steradian) for
//! directions, area for points, counting measure for discrete choices.

use glam::{Vec2, Vec3};
#[cfg(test)]
use std::f32::consts::{FRAC_1_PI, PI};

/// An orthonormal frame around a unit normal (Duff et al. 2017, branchless).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// First tangent (unit).
    pub tangent: Vec3,
    /// Second tangent (unit), `normal × tangent`.
    pub bitangent: Vec3,
    /// The unit normal: local `+z`.
    pub normal: Vec3,
}

impl Frame {
    /// The frame whose local `+z` is the unit vector `n`.
    pub fn from_normal(n: Vec3) -> Frame {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        Frame {
            tangent: Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
            bitangent: Vec3::new(b, sign + n.y * n.y * a, -n.y),
            normal: n,
        }
    }

    /// Local coordinates to world.
    #[inline]
    pub fn to_world(self, v: Vec3) -> Vec3 {
        self.tangent * v.x + self.bitangent * v.y + self.normal * v.z
    }

    /// World coordinates to local.
    #[cfg(test)]
    #[inline]
    pub fn to_local(self, v: Vec3) -> Vec3 {
        Vec3::new(
            v.dot(self.tangent),
            v.dot(self.bitangent),
            v.dot(self.normal),
        )
    }
}

/// A cosine-distributed direction about local `+z` (Malley's method: a uniform disk point in
/// polar form, `r = sqrt(u.x)`, `phi = 2 pi u.y`, lifted to the hemisphere, `z = sqrt(1 - u.x)`).
/// Density [`cosine_hemisphere_pdf`]. The polar form has no branch and no division, which matters
/// in the shooting loop; the concentric map's better stratification does not, as the samples are
/// independent.
#[cfg(test)]
#[inline]
pub fn cosine_hemisphere(u: Vec2) -> Vec3 {
    let r = u.x.sqrt();
    let (sin, cos) = (2.0 * PI * u.y).sin_cos();
    Vec3::new(r * cos, r * sin, (1.0 - u.x).max(0.0).sqrt())
}

/// A cosine-distributed direction about local `+z`, like [`cosine_hemisphere`], from a uniform
/// disk point found by rejection from the square `[-1, 1]²` (accepted with probability `pi/4`,
/// so 2.5 uniforms on average). No trigonometry: this is the shooting loop's sampler. Same
/// density, [`cosine_hemisphere_pdf`]; no inverse (the number of uniforms it uses varies).
#[inline]
pub fn cosine_hemisphere_rejection(mut uniform: impl FnMut() -> f32) -> Vec3 {
    loop {
        let (x, y) = (2.0 * uniform() - 1.0, 2.0 * uniform() - 1.0);
        let r2 = x * x + y * y;
        if r2 <= 1.0 {
            return Vec3::new(x, y, (1.0 - r2).sqrt());
        }
    }
}

/// A cosine-distributed direction about local `+z` from a point of the unit square by Shirley
/// and Chiu's concentric map to the disk, lifted to the hemisphere (Malley's method). Same
/// density as [`cosine_hemisphere`], [`cosine_hemisphere_pdf`]. The map keeps areas and
/// aspect ratios nearly (it sends the square's concentric squares to the disk's concentric
/// rings), so stratified square points give stratified directions: the quasi-Monte Carlo
/// sampler's map.
#[inline]
pub fn cosine_hemisphere_concentric(u: Vec2) -> Vec3 {
    use std::f32::consts::FRAC_PI_4;
    let (a, b) = (2.0 * u.x - 1.0, 2.0 * u.y - 1.0);
    let (r, phi) = if a == 0.0 && b == 0.0 {
        return Vec3::Z;
    } else if a.abs() > b.abs() {
        (a, FRAC_PI_4 * (b / a))
    } else {
        (b, 2.0 * FRAC_PI_4 - FRAC_PI_4 * (a / b))
    };
    let (sin, cos) = phi.sin_cos();
    let (x, y) = (r * cos, r * sin);
    Vec3::new(x, y, (1.0 - x * x - y * y).max(0.0).sqrt())
}

/// Density of [`cosine_hemisphere`] per steradian: `cos(theta) / pi` above the surface, 0 below.
#[cfg(test)]
#[inline]
pub fn cosine_hemisphere_pdf(local_dir: Vec3) -> f32 {
    local_dir.z.max(0.0) * FRAC_1_PI
}

/// Inverse of [`cosine_hemisphere`]: the square point that maps to `local_dir` (`z >= 0`).
#[cfg(test)]
pub fn cosine_hemisphere_inverse(local_dir: Vec3) -> Vec2 {
    let phi = local_dir.y.atan2(local_dir.x);
    let v = phi / (2.0 * PI);
    Vec2::new(
        (local_dir.x * local_dir.x + local_dir.y * local_dir.y).min(1.0),
        if v < 0.0 { v + 1.0 } else { v },
    )
}

/// A uniform point of a triangle as barycentric weights `(b1, b2)` of its second and third
/// vertices: `P = (1 - b1 - b2) v0 + b1 v1 + b2 v2`. Density `1 / area` per unit area.
#[inline]
pub fn uniform_triangle(u: Vec2) -> Vec2 {
    let su = u.x.sqrt();
    Vec2::new(su * (1.0 - u.y), su * u.y)
}

/// Density of [`uniform_triangle`] per unit area for a triangle of `area`.
#[cfg(test)]
#[inline]
pub fn uniform_triangle_pdf(area: f32) -> f32 {
    1.0 / area
}

/// Inverse of [`uniform_triangle`].
#[cfg(test)]
pub fn uniform_triangle_inverse(b: Vec2) -> Vec2 {
    let su = b.x + b.y;
    if su <= 0.0 {
        return Vec2::ZERO;
    }
    Vec2::new(su * su, b.y / su)
}

/// A discrete distribution over `0..n` proportional to non-negative weights, sampled by
/// inverting its cumulative sums (kept in f64).
#[derive(Debug, Clone, PartialEq)]
pub struct Discrete {
    cdf: Vec<f64>,
}

impl Discrete {
    /// The distribution with `P(i) = w_i / sum w`; `None` when no weight is positive or one is
    /// negative or not finite.
    pub fn new(weights: &[f64]) -> Option<Discrete> {
        if weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return None;
        }
        let mut total = 0.0;
        let mut cdf: Vec<f64> = weights
            .iter()
            .map(|w| {
                total += w;
                total
            })
            .collect();
        if total <= 0.0 {
            return None;
        }
        cdf.iter_mut().for_each(|c| *c /= total);
        Some(Discrete { cdf })
    }

    /// The index whose cumulative interval holds `u` in `[0, 1)` (never an index of weight 0).
    pub fn sample(&self, u: f64) -> usize {
        self.cdf
            .partition_point(|&c| c <= u)
            .min(self.cdf.len() - 1)
    }

    /// Probability of index `i`.
    pub fn pmf(&self, i: usize) -> f64 {
        self.cdf[i] - if i == 0 { 0.0 } else { self.cdf[i - 1] }
    }

    /// The sub-interval of `[0, 1)` that maps to index `i` (the inverse of [`Discrete::sample`]).
    pub fn inverse(&self, i: usize) -> std::ops::Range<f64> {
        (if i == 0 { 0.0 } else { self.cdf[i - 1] })..self.cdf[i]
    }
}

/// Rounds `x >= 0` to `floor(x)` or `floor(x) + 1` with the probability that keeps the mean
/// exact: `E[round(x)] = x` for `u` uniform in `[0, 1)`.
#[inline]
pub fn stochastic_round(x: f64, u: f64) -> u64 {
    let f = x.floor();
    f as u64 + u64::from(u < x - f)
}

#[cfg(test)]
pub(crate) mod chi2 {
    //! Pearson's chi-square test with pooled cells (Mitsuba's `chi2.py` recipe).
    use statrs::distribution::{ChiSquared, ContinuousCDF};

    /// Fails when the observed counts are unlikely (p < `alpha`) under the expected ones. Cells
    /// with expectation below 5 are pooled. On failure the table is returned.
    pub fn test(observed: &[f64], expected: &[f64], alpha: f64) -> Result<f64, String> {
        let (mut stat, mut cells) = (0.0, 0usize);
        let (mut pool_o, mut pool_e) = (0.0, 0.0);
        for (&o, &e) in observed.iter().zip(expected) {
            if e < 5.0 {
                pool_o += o;
                pool_e += e;
            } else {
                stat += (o - e) * (o - e) / e;
                cells += 1;
            }
        }
        if pool_e >= 5.0 {
            stat += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
            cells += 1;
        } else if pool_o > 0.0 && pool_e == 0.0 {
            return Err(format!("{pool_o} samples fell where the density is zero"));
        }
        let dof = (cells - 1) as f64;
        let p = 1.0 - ChiSquared::new(dof).unwrap().cdf(stat);
        if p < alpha {
            let table: Vec<String> = observed
                .iter()
                .zip(expected)
                .map(|(o, e)| format!("{o:.0}/{e:.1}"))
                .collect();
            return Err(format!(
                "chi2 = {stat:.1}, dof = {dof}, p = {p:.2e}; observed/expected: {}",
                table.join(" ")
            ));
        }
        Ok(p)
    }
}

#[cfg(test)]
pub(crate) mod tests_support {
    use glam::Vec2;

    /// Which of the `2n²` cells `(i, j, up/down)` of the unit barycentric grid of step `1/n`
    /// holds `(b1, b2)`; the cells inside the triangle are congruent, of area `1/n²` each.
    pub fn sub_triangle(b: Vec2, n: usize) -> usize {
        let (x, y) = (b.x * n as f32, b.y * n as f32);
        let (i, j) = (
            (x.floor() as usize).min(n - 1),
            (y.floor() as usize).min(n - 1),
        );
        let down = usize::from(x - i as f32 + y - j as f32 > 1.0 && i + j + 1 < n);
        (2 * (j * n + i) + down).min(2 * n * n - 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mcrad_random::Stream;

    /// alpha for one chi-square test: with fixed seeds the tests are deterministic, and a correct
    /// sampler fails a fresh seed with probability 1e-4.
    const ALPHA: f64 = 1e-4;
    const SAMPLES: usize = 1_000_000;

    fn u2(s: &mut Stream) -> Vec2 {
        Vec2::new(s.uniform(), s.uniform())
    }

    #[test]
    fn cosine_hemisphere_matches_its_density() {
        cosine_sampler_matches_its_density(|s| cosine_hemisphere(u2(s)));
    }

    #[test]
    fn cosine_hemisphere_concentric_matches_its_density() {
        cosine_sampler_matches_its_density(|s| cosine_hemisphere_concentric(u2(s)));
    }

    #[test]
    fn cosine_hemisphere_by_rejection_matches_its_density() {
        cosine_sampler_matches_its_density(|s| cosine_hemisphere_rejection(|| s.uniform()));
    }

    fn cosine_sampler_matches_its_density(mut sample: impl FnMut(&mut Stream) -> Vec3) {
        let (nt, np) = (16usize, 32usize);
        let mut obs = vec![0.0; nt * np];
        let mut s = Stream::new(1, 0, 0, 0);
        for _ in 0..SAMPLES {
            let d = sample(&mut s);
            assert!((d.length() - 1.0).abs() < 1e-5 && d.z >= 0.0);
            let t = ((d.z.clamp(0.0, 1.0).acos() / std::f32::consts::FRAC_PI_2) * nt as f32)
                .min(nt as f32 - 1.0) as usize;
            let phi = d.y.atan2(d.x) + std::f32::consts::PI;
            let p =
                ((phi / (2.0 * std::f32::consts::PI)) * np as f32).min(np as f32 - 1.0) as usize;
            obs[t * np + p] += 1.0;
        }
        // P(theta in [a, b]) = sin²b - sin²a for the density cos(theta)/pi.
        let exp: Vec<f64> = (0..nt * np)
            .map(|k| {
                let (a, b) = ((k / np) as f64, (k / np + 1) as f64);
                let w = std::f64::consts::FRAC_PI_2 / nt as f64;
                ((b * w).sin().powi(2) - (a * w).sin().powi(2)) / np as f64 * SAMPLES as f64
            })
            .collect();
        chi2::test(&obs, &exp, ALPHA).unwrap();
    }

    #[test]
    fn cosine_hemisphere_pdf_integrates_to_one_and_inverse_round_trips() {
        // Midpoint rule over (theta, phi): integral of pdf * sin(theta).
        let n = 400;
        let mut total = 0.0f64;
        for i in 0..n {
            let theta = (i as f64 + 0.5) / n as f64 * std::f64::consts::FRAC_PI_2;
            let d = Vec3::new(theta.sin() as f32, 0.0, theta.cos() as f32);
            total += cosine_hemisphere_pdf(d) as f64
                * theta.sin()
                * (std::f64::consts::FRAC_PI_2 / n as f64)
                * 2.0
                * std::f64::consts::PI;
        }
        assert!((total - 1.0).abs() < 1e-4, "{total}");
        assert_eq!(cosine_hemisphere_pdf(Vec3::new(0.0, 0.6, -0.8)), 0.0);
        let mut s = Stream::new(2, 0, 0, 0);
        for _ in 0..10_000 {
            let u = u2(&mut s);
            let back = cosine_hemisphere_inverse(cosine_hemisphere(u));
            assert!((back - u).abs().max_element() < 2e-3, "{u} -> {back}");
        }
    }

    #[test]
    fn frame_is_orthonormal_for_any_normal() {
        let mut s = Stream::new(3, 0, 0, 0);
        let normals = (0..10_000)
            .map(|_| {
                let u = u2(&mut s);
                let z = 1.0 - 2.0 * u.x;
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = 2.0 * std::f32::consts::PI * u.y;
                Vec3::new(r * phi.cos(), r * phi.sin(), z)
            })
            .chain([Vec3::Z, -Vec3::Z, Vec3::X, -Vec3::Y]);
        for n in normals {
            let f = Frame::from_normal(n);
            assert!(f.tangent.dot(f.bitangent).abs() < 1e-5);
            assert!(f.tangent.dot(n).abs() < 1e-5 && f.bitangent.dot(n).abs() < 1e-5);
            assert!(
                (f.tangent.length() - 1.0).abs() < 1e-5
                    && (f.bitangent.length() - 1.0).abs() < 1e-5
            );
            let v = Vec3::new(0.3, -0.2, 0.9);
            assert!((f.to_local(f.to_world(v)) - v).length() < 1e-5);
        }
    }

    use super::tests_support::sub_triangle;

    #[test]
    fn uniform_triangle_matches_its_density() {
        let n = 20;
        let mut obs = vec![0.0; 2 * n * n];
        let mut s = Stream::new(4, 0, 0, 0);
        for _ in 0..SAMPLES {
            let b = uniform_triangle(u2(&mut s));
            assert!(b.x >= 0.0 && b.y >= 0.0 && b.x + b.y <= 1.0 + 1e-6);
            obs[sub_triangle(b, n)] += 1.0;
        }
        // Cells (i, j, down) exist only inside the triangle: n² of them, each 1/n² of the area.
        let exp: Vec<f64> = (0..2 * n * n)
            .map(|k| {
                let (cell, down) = (k / 2, k % 2);
                let (i, j) = (cell % n, cell / n);
                let inside = if down == 0 { i + j < n } else { i + j + 1 < n };
                if inside {
                    SAMPLES as f64 / (n * n) as f64
                } else {
                    0.0
                }
            })
            .collect();
        chi2::test(&obs, &exp, ALPHA).unwrap();
        assert_eq!(uniform_triangle_pdf(0.5), 2.0);
        for _ in 0..10_000 {
            let u = u2(&mut s);
            let back = uniform_triangle_inverse(uniform_triangle(u));
            assert!((back - u).abs().max_element() < 1e-4, "{u} -> {back}");
        }
    }

    #[test]
    fn discrete_matches_its_weights() {
        let w: Vec<f64> = (0..50)
            .map(|i| {
                if i % 7 == 3 {
                    0.0
                } else {
                    1.0 + (i * i % 13) as f64
                }
            })
            .collect();
        let d = Discrete::new(&w).unwrap();
        let total: f64 = w.iter().sum();
        let mut obs = vec![0.0; w.len()];
        let mut s = Stream::new(5, 0, 0, 0);
        for _ in 0..SAMPLES {
            let i = d.sample(s.uniform_f64());
            assert!(w[i] > 0.0, "sampled index {i} of weight 0");
            obs[i] += 1.0;
        }
        let exp: Vec<f64> = w.iter().map(|x| x / total * SAMPLES as f64).collect();
        chi2::test(&obs, &exp, ALPHA).unwrap();
        for (i, &wi) in w.iter().enumerate() {
            assert!((d.pmf(i) - wi / total).abs() < 1e-12);
            let r = d.inverse(i);
            if wi > 0.0 {
                assert_eq!(d.sample(r.start), i);
            }
        }
        assert!(Discrete::new(&[0.0, 0.0]).is_none());
        assert!(Discrete::new(&[1.0, f64::NAN]).is_none());
        assert!(Discrete::new(&[1.0, -1.0]).is_none());
    }

    #[test]
    fn stochastic_round_is_unbiased() {
        // The extra unit is a Bernoulli(frac x) draw; Pearson's statistic over independent
        // Bernoulli cells, (O - T f)² / (T f (1 - f)), is chi-square with one dof per cell.
        let xs: Vec<f64> = (0..40)
            .map(|i| i as f64 * 0.37 + 0.013 * (i * i) as f64)
            .collect();
        let trials = 20_000usize;
        let mut s = Stream::new(6, 0, 0, 0);
        let mut extra = vec![0.0; xs.len()];
        for _ in 0..trials {
            for (k, &x) in xs.iter().enumerate() {
                let n = stochastic_round(x, s.uniform_f64());
                assert!(n == x.floor() as u64 || n == x.floor() as u64 + 1);
                extra[k] += (n - x.floor() as u64) as f64;
            }
        }
        let mut stat = 0.0;
        let mut dof = 0.0;
        for (k, &x) in xs.iter().enumerate() {
            let f = x - x.floor();
            if f > 1e-9 {
                let e = trials as f64 * f;
                stat += (extra[k] - e).powi(2) / (e * (1.0 - f));
                dof += 1.0;
            } else {
                assert_eq!(extra[k], 0.0);
            }
        }
        let p = 1.0
            - statrs::distribution::ContinuousCDF::cdf(
                &statrs::distribution::ChiSquared::new(dof).unwrap(),
                stat,
            );
        assert!(p > ALPHA, "chi2 {stat} dof {dof} p {p}");
    }
}
