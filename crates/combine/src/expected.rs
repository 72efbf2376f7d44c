//! Expected variances: the variances inverse-variance weights should use.
//!
//! **Why not the estimates' own variances.** An estimate's sample variance is computed from the
//! same samples as its value and is correlated with it. For a shooting estimate, `B = E + h x / A`
//! for `h` hits of deposit `x`, and its variance `h x² / A²` grows with `h`: a patch that caught
//! more rays than its share gets a higher value *and* a lower weight, one that caught fewer a
//! lower value and a higher weight, so the merge is biased low. A gathering estimate from a few
//! rays that all saw the same value reports a variance of zero and would take all the weight.
//! Measured on the Cornell box at 1940 patches, 600k rays, merging mcrad's shooting and gathering
//! with their own variances left the faces' mean radiosity 0.5-3.8% low (mean z² 21.9 over 12
//! seeds); with the expected variances below, no bias is measurable (mean z² 2.5, no face beyond
//! 4 standard errors; `crates/mc-radiosity/tests/methods.rs`). The unit tests here show both on
//! Poisson counts.
//!
//! **The models.** Both scale with a *proxy* of the reflected radiosity `R_i` (W/m²) that does
//! not come from the samples being weighted (the previous combined solution):
//!
//! - shot noise ([`shot_noise`]): hits of mean deposit `m_i` (W) on a patch of area `A_i` have
//!   variance `m_i R_i / A_i`, with `m_i` what the estimator deposits per hit (shooting with
//!   constant energy per ray: `rho_i` times that energy), known before any ray lands. Estimated
//!   from the deposits themselves, `m_i = sum x² / sum x`, it still followed the patch's luck
//!   where passes of different energies per ray merge (how many hits each pass gave), and the
//!   merge came out biased: `combined` at rho 0.99 and 0.999, -0.052% and -0.057% of the power
//!   (4.6 and 3.7 standard errors over 32 seeds of `cargo xtask calibrate`); with the known
//!   deposit, -0.007% and +0.015% (0.6 and 1.1);
//! - pooled relative variance ([`pooled_relative`]): a gather's variance relative to its value
//!   squared, pooled over a group of patches (an input face), times `R_i²`.

use glam::DVec3;

/// The expected shot-noise variance of a sum of deposits, `m R / A` per channel ((W/m²)²):
/// `deposit` is the mean deposit per hit `m` (W, known from how the estimate is made, not from
/// its samples), `proxy` the reflected radiosity to scale with (W/m², negative values count as
/// 0) and `area` the patch area (> 0).
pub fn shot_noise(deposit: DVec3, area: f64, proxy: DVec3) -> DVec3 {
    deposit * proxy.max(DVec3::ZERO) / area
}

/// Relative variances pooled over groups: for each group `g`,
/// `k_g = sum_{i in g} variance_i / sum_{i in g} value_i²` per channel (0 where the group's
/// values are all 0), with `group[i]` the group of item `i`. The expected variance of item `i`
/// is then `k_{group[i]} R_i²` for a proxy `R_i` of its value.
///
/// `variance` ((W/m²)²) and `value` (W/m², negative values count as 0) have one entry per item,
/// as does `group`; the result has `max(group) + 1` entries.
pub fn pooled_relative(group: &[usize], variance: &[DVec3], value: &[DVec3]) -> Vec<DVec3> {
    let groups = group.iter().map(|g| g + 1).max().unwrap_or(0);
    pooled_relative_of(
        groups,
        group
            .iter()
            .zip(variance)
            .zip(value)
            .map(|((g, v), x)| (*g, *v, *x)),
    )
}

/// [`pooled_relative`] over `groups` groups from the items `(group, variance, value)` in
/// order, without arrays of them: the result has `groups` entries (each item's group below
/// it). The same sums in the same order, so the same result bit for bit.
pub fn pooled_relative_of(
    groups: usize,
    items: impl IntoIterator<Item = (usize, DVec3, DVec3)>,
) -> Vec<DVec3> {
    // One array of (variance, square) sums, turned into the result in place.
    let mut sums = vec![(DVec3::ZERO, DVec3::ZERO); groups];
    for (g, v, x) in items {
        let x = x.max(DVec3::ZERO);
        let s = &mut sums[g];
        s.0 += v;
        s.1 += x * x;
    }
    sums.iter()
        .map(|(v, s)| DVec3::select(s.cmpgt(DVec3::ZERO), *v / *s, DVec3::ZERO))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Estimate, InverseVariance, merge};

    /// A seeded PCG stream for the tests' Poisson draws.
    struct Rng(rand_pcg::Pcg32);

    impl Rng {
        fn uniform(&mut self) -> f64 {
            use rand_core::Rng as _;
            (self.0.next_u64() >> 11) as f64 / (1u64 << 53) as f64
        }

        /// Poisson(lambda) by multiplying uniforms (small lambda).
        fn poisson(&mut self, lambda: f64) -> u64 {
            let (limit, mut p, mut k) = ((-lambda).exp(), self.uniform(), 0);
            while p > limit {
                p *= self.uniform();
                k += 1;
            }
            k
        }
    }

    fn one(x: f64, v: f64) -> Estimate {
        Estimate::new(vec![DVec3::splat(x)], Some(vec![DVec3::splat(v)]), 1).unwrap()
    }

    /// Two independent shot-noise estimates of `R = 1` W/m² (area 1): `h x` with
    /// `h ~ Poisson(1/x)`, deposits `x = 0.25` and `0.125`. Merged by inverse variance, over
    /// many trials: with their own variances `h x²` the mean is clearly low; with the expected
    /// variance at the true value it is unbiased.
    #[test]
    fn own_variances_bias_the_merge_and_expected_ones_do_not() {
        let mut rng = Rng(rand_pcg::Pcg32::new(7, 0x0a02_bdbf_7bb3_c0a7));
        let (trials, xa, xb) = (40_000, 0.25, 0.125);
        let (mut own, mut expected) = (0.0, 0.0);
        for _ in 0..trials {
            let (ha, hb) = (rng.poisson(1.0 / xa) as f64, rng.poisson(1.0 / xb) as f64);
            let (a, b) = (ha * xa, hb * xb);
            let m = merge(
                &one(a, ha * xa * xa),
                &one(b, hb * xb * xb),
                &InverseVariance,
            )
            .unwrap();
            own += m.radiosity()[0].x;
            let va = shot_noise(DVec3::splat(xa), 1.0, DVec3::ONE);
            let vb = shot_noise(DVec3::splat(xb), 1.0, DVec3::ONE);
            let m = merge(&one(a, va.x), &one(b, vb.x), &InverseVariance).unwrap();
            expected += m.radiosity()[0].x;
        }
        let (own, expected) = (own / trials as f64, expected / trials as f64);
        // The merged estimate's standard error over the trials: sqrt(1/12 / 40000) = 0.0014.
        let se = (1.0f64 / (1.0 / (xa) + 1.0 / (xb)) / trials as f64).sqrt();
        assert!(own < 1.0 - 10.0 * se, "own variances: mean {own}");
        assert!(
            (expected - 1.0).abs() < 4.0 * se,
            "expected variances: mean {expected}"
        );
    }

    #[test]
    fn shot_noise_is_the_deposit_times_the_proxy_over_the_area() {
        // Deposits of 0.5 W on 2 m² at a proxy of 1 W/m²: 0.5 * 1 / 2.
        let v = shot_noise(DVec3::splat(0.5), 2.0, DVec3::ONE);
        assert_eq!(v, DVec3::splat(0.25));
        // A proxy of zero light (or below): zero variance.
        let v = shot_noise(DVec3::ONE, 1.0, DVec3::splat(-1.0));
        assert_eq!(v, DVec3::ZERO);
    }

    #[test]
    fn pooled_relative_variance_covers_items_with_zero_sample_variance() {
        // Group 0: values 1 and 3 with variances 0.5 and 0 (all samples alike): k = 0.5 / 10.
        // Group 1: all dark.
        let k = pooled_relative(
            &[0, 0, 1],
            &[DVec3::splat(0.5), DVec3::ZERO, DVec3::ZERO],
            &[DVec3::ONE, DVec3::splat(3.0), DVec3::ZERO],
        );
        assert_eq!(k.len(), 2);
        assert!((k[0] - DVec3::splat(0.05)).abs().max_element() < 1e-15);
        assert_eq!(k[1], DVec3::ZERO);
    }
}
