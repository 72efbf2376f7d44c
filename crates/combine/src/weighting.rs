//! Weightings and the one merge of two estimates.
//!
//! A [`Weighting`] says, per patch `i` and RGB channel `c`, how much of the merge comes from each
//! of two independent estimates; [`merge`] applies it. Every weighting goes through the same
//! loop, so a new rule is one `impl Weighting`.

use crate::estimate::{Estimate, EstimateError};
use glam::DVec3;

/// One side of a merge: an estimate and, optionally, the variance a weighting should take for
/// it instead of the estimate's own (per patch and channel, (W/m²)²; e.g. the *expected*
/// variances of [`crate::expected`], which do not come from the samples being weighted).
#[derive(Debug, Clone, Copy)]
pub struct Operand<'a> {
    /// The estimate merged.
    pub estimate: &'a Estimate,
    /// The variance to weight by, one entry per patch, or `None` (a weighting that needs it
    /// reports [`EstimateError::MissingVariance`]).
    pub expected: Option<&'a [DVec3]>,
}

impl<'a> Operand<'a> {
    /// An estimate with the variance to weight it by (one per patch, (W/m²)²).
    pub fn with_expected(estimate: &'a Estimate, expected: &'a [DVec3]) -> Operand<'a> {
        Operand {
            estimate,
            expected: Some(expected),
        }
    }

    /// Rays behind the estimate.
    fn rays(&self) -> u64 {
        self.estimate.rays()
    }
}

impl<'a> From<&'a Estimate> for Operand<'a> {
    fn from(estimate: &'a Estimate) -> Operand<'a> {
        Operand {
            estimate,
            expected: None,
        }
    }
}

/// How two independent estimates `X_a`, `X_b` of the same radiosity are weighted.
///
/// **What a weight means.** The merge of patch `i`, channel `c` is
/// `w X_a + (1 - w) X_b` with `w = weight(a, b, i, c)` in `[0, 1]`: the two weights are `w` and
/// `1 - w`, so they **sum to 1** by construction and the merge is a convex combination.
///
/// **Invariants** every implementation keeps (and [`merge`] relies on):
/// - `w` is in `[0, 1]` and finite;
/// - an operand with zero rays behind it gets weight 0 when the other has rays (it carries no
///   information);
/// - the weights do not depend on the values being merged. Then two *unbiased* inputs give an
///   *unbiased* merge, `E[w X_a + (1 - w) X_b] = w E[X_a] + (1 - w) E[X_b]`; a weighting that
///   reads the estimates' own sample variances ([`InverseVariance`]) breaks this condition
///   wherever the variance is correlated with the value (shot noise: see [`crate::expected`]);
/// - since the weights sum to 1, self-emission `E_i`, exact and the same in both, passes through:
///   `w (E + a) + (1 - w)(E + b) = E + w a + (1 - w) b`.
pub trait Weighting {
    /// Checks that the operands carry what this weighting reads (variances of the right
    /// length); [`merge`] calls it once before any [`Weighting::weight`].
    fn check(&self, a: &Operand, b: &Operand) -> Result<(), EstimateError> {
        let _ = (a, b);
        Ok(())
    }

    /// The weight `w` of `a` for patch `patch`, channel `channel` (0, 1, 2 for R, G, B); `b`
    /// gets `1 - w`.
    fn weight(&self, a: &Operand, b: &Operand, patch: usize, channel: usize) -> f64;
}

impl<W: Weighting + ?Sized> Weighting for &W {
    fn check(&self, a: &Operand, b: &Operand) -> Result<(), EstimateError> {
        (**self).check(a, b)
    }

    fn weight(&self, a: &Operand, b: &Operand, patch: usize, channel: usize) -> f64 {
        (**self).weight(a, b, patch, channel)
    }
}

/// Weights proportional to the rays behind each estimate: `w_a = n_a / (n_a + n_b)`, `1/2` when
/// both are zero. The right rule for estimates whose variance falls as `1/n` with the same
/// constant; Feda and Purgathofer's progressive ray refinement (PRR) and progressive gathering
/// merge their passes this way (Balog, sections 2.1-2.2). Merging the means of `n_a` and `n_b`
/// samples gives the mean of all `n_a + n_b`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ByRays;

impl ByRays {
    /// The weight of `rays_a` rays against `rays_b`.
    fn of(rays_a: u64, rays_b: u64) -> f64 {
        let total = rays_a as f64 + rays_b as f64;
        if total == 0.0 {
            0.5
        } else {
            rays_a as f64 / total
        }
    }
}

impl Weighting for ByRays {
    fn weight(&self, a: &Operand, b: &Operand, _: usize, _: usize) -> f64 {
        ByRays::of(a.rays(), b.rays())
    }
}

/// Inverse-variance weights `w_a = V_b / (V_a + V_b)` (so `w ∝ 1/V`) from variances `V_a`,
/// `V_b` per patch and channel, the minimum-variance merge of two independent estimates:
/// `Var = 1 / (1/V_a + 1/V_b)`. An operand with zero rays gets weight 0; where both variances
/// are zero the weights fall back to [`ByRays`].
fn inverse(rays_a: u64, var_a: f64, rays_b: u64, var_b: f64) -> f64 {
    if rays_a == 0 {
        return 0.0;
    }
    if rays_b == 0 {
        return 1.0;
    }
    let total = var_a + var_b;
    if total > 0.0 {
        var_b / total
    } else {
        ByRays::of(rays_a, rays_b)
    }
}

/// Checks that `v` has one entry per patch of `of`.
fn check_len(v: &[DVec3], of: &Estimate) -> Result<(), EstimateError> {
    if v.len() != of.len() {
        return Err(EstimateError::VarianceLength {
            patches: of.len(),
            variances: v.len(),
        });
    }
    Ok(())
}

/// Inverse-variance weights (`w_a = V_b / (V_a + V_b)`, `1/2` by rays where both are zero) from the
/// estimates' *own* (estimated, sample) variances. Minimum variance when the variances are
/// exact; with sample variances correlated with the values it biases the merge (see
/// [`crate::expected`]) — [`InverseExpectedVariance`] is the unbiased alternative.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct InverseVariance;

impl Weighting for InverseVariance {
    fn check(&self, a: &Operand, b: &Operand) -> Result<(), EstimateError> {
        match (a.estimate.variance(), b.estimate.variance()) {
            (Some(_), Some(_)) => Ok(()),
            _ => Err(EstimateError::MissingVariance),
        }
    }

    fn weight(&self, a: &Operand, b: &Operand, patch: usize, channel: usize) -> f64 {
        let var = |o: &Operand| o.estimate.variance().map_or(0.0, |v| v[patch][channel]);
        inverse(a.rays(), var(a), b.rays(), var(b))
    }
}

/// Inverse-variance weights from the variances each [`Operand`] carries in `expected`, not from
/// the samples being weighted: `w_a = W_b / (W_a + W_b)`. With `W` from a model that does not
/// read the merged values (the previous solution as a proxy, [`crate::expected`]) the weights
/// are independent of the values and the merge of unbiased inputs is unbiased. This is what the
/// combined method (Algorithm 4) weights by.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct InverseExpectedVariance;

impl Weighting for InverseExpectedVariance {
    fn check(&self, a: &Operand, b: &Operand) -> Result<(), EstimateError> {
        for o in [a, b] {
            check_len(
                o.expected.ok_or(EstimateError::MissingVariance)?,
                o.estimate,
            )?;
        }
        Ok(())
    }

    fn weight(&self, a: &Operand, b: &Operand, patch: usize, channel: usize) -> f64 {
        let var = |o: &Operand| o.expected.map_or(0.0, |v| v[patch][channel]);
        inverse(a.rays(), var(a), b.rays(), var(b))
    }
}

/// Merges two independent estimates of the same patches with `weighting`: per patch `i` and
/// channel `c`, `w X_a + (1 - w) X_b` with `w = weighting.weight(a, b, i, c)`. The result's rays
/// are the sum; its variance, when both estimates have one, is `w² V_a + (1 - w)² V_b` with the
/// estimates' own `V` (their best estimate of their noise), else `None`.
///
/// Errors: patch counts differ, or the weighting lacks what it reads
/// ([`Weighting::check`]).
pub fn merge<'a>(
    a: impl Into<Operand<'a>>,
    b: impl Into<Operand<'a>>,
    weighting: &(impl Weighting + ?Sized),
) -> Result<Estimate, EstimateError> {
    let (a, b) = (a.into(), b.into());
    let w = weights(&a, &b, weighting)?;
    merge_weighted(a.estimate, b.estimate, &w)
}

/// The weights [`merge`] gives `a` (dimensionless, per patch and channel, `w` of
/// `w X_a + (1 - w) X_b`), after its checks: for a caller that reads them, or makes the
/// merge's variance another way, before [`merge_weighted`].
///
/// Errors: as [`merge`]'s.
pub fn weights(
    a: &Operand,
    b: &Operand,
    weighting: &(impl Weighting + ?Sized),
) -> Result<Vec<DVec3>, EstimateError> {
    let (ea, eb) = (a.estimate, b.estimate);
    if ea.len() != eb.len() {
        return Err(EstimateError::PatchCountMismatch {
            a: ea.len(),
            b: eb.len(),
        });
    }
    weighting.check(a, b)?;
    Ok((0..ea.len())
        .map(|i| {
            DVec3::new(
                weighting.weight(a, b, i, 0),
                weighting.weight(a, b, i, 1),
                weighting.weight(a, b, i, 2),
            )
        })
        .collect())
}

/// [`merge`] with the weights of `a` given per patch and channel (`weights`, dimensionless,
/// one per patch, [`weights`]): `w X_a + (1 - w) X_b`, rays summed, variance
/// `w² V_a + (1 - w)² V_b` where both have one.
///
/// Errors: patch counts of `a`, `b` and `weights` differ.
pub fn merge_weighted(
    ea: &Estimate,
    eb: &Estimate,
    weights: &[DVec3],
) -> Result<Estimate, EstimateError> {
    for n in [eb.len(), weights.len()] {
        if n != ea.len() {
            return Err(EstimateError::PatchCountMismatch { a: ea.len(), b: n });
        }
    }
    let own = match (ea.variance(), eb.variance()) {
        (Some(va), Some(vb)) => Some((va, vb)),
        _ => None,
    };
    let n = ea.len();
    let mut value = Vec::with_capacity(n);
    let mut variance = own.map(|_| Vec::with_capacity(n));
    for (i, w) in weights.iter().enumerate() {
        let (mut x, mut v) = (DVec3::ZERO, DVec3::ZERO);
        let (var_a, var_b) = own.map_or((DVec3::ZERO, DVec3::ZERO), |(va, vb)| (va[i], vb[i]));
        for c in 0..3 {
            let wa = w[c];
            let wb = 1.0 - wa;
            x[c] = wa * ea.radiosity()[i][c] + wb * eb.radiosity()[i][c];
            v[c] = wa * wa * var_a[c] + wb * wb * var_b[c];
        }
        value.push(x);
        if let Some(out) = variance.as_mut() {
            out.push(v);
        }
    }
    Estimate::new(value, variance, ea.rays() + eb.rays())
}

#[cfg(test)]
mod tests {
    use super::*;
    use mcrad_random::Stream;

    fn est(values: &[f64], var: Option<&[f64]>, rays: u64) -> Estimate {
        Estimate::new(
            values.iter().map(|&x| DVec3::splat(x)).collect(),
            var.map(|v| v.iter().map(|&x| DVec3::splat(x)).collect()),
            rays,
        )
        .unwrap()
    }

    /// A standard normal draw (Box-Muller).
    fn normal(s: &mut Stream) -> f64 {
        let (u, v) = (1.0 - s.uniform_f64(), s.uniform_f64());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }

    /// The weights of `w` for one patch of `a` and `b` (expected variances `ea`, `eb`).
    fn weight_of(w: &dyn Weighting, a: &Estimate, ea: &[DVec3], b: &Estimate, eb: &[DVec3]) -> f64 {
        w.weight(
            &Operand::with_expected(a, ea),
            &Operand::with_expected(b, eb),
            0,
            0,
        )
    }

    const ALL: [&dyn Weighting; 3] = [&ByRays, &InverseVariance, &InverseExpectedVariance];

    #[test]
    fn weights_lie_in_the_unit_interval_and_zero_rays_get_zero_weight() {
        for w in ALL {
            for (na, va, nb, vb) in [
                (3, 1.0, 7, 2.0),
                (0, 1.0, 5, 1.0),
                (5, 0.0, 0, 0.0),
                (1, 0.0, 1, 0.0),
                (2, 0.0, 9, 3.0),
            ] {
                let (a, b) = (est(&[1.0], Some(&[va]), na), est(&[2.0], Some(&[vb]), nb));
                let (ea, eb) = ([DVec3::splat(va)], [DVec3::splat(vb)]);
                let wa = weight_of(w, &a, &ea, &b, &eb);
                assert!((0.0..=1.0).contains(&wa), "{wa}");
                // The merge's weights are wa and 1 - wa: they sum to 1, seen on the values
                // 1 and 2 (and on an estimate of the constant 1 on both sides).
                let one = est(&[1.0], Some(&[va]), na);
                let m = merge(
                    Operand::with_expected(&one, &ea),
                    Operand::with_expected(&est(&[1.0], Some(&[vb]), nb), &eb),
                    &w,
                )
                .unwrap();
                assert_eq!(m.radiosity()[0].x, 1.0);
                if na == 0 && nb > 0 {
                    assert_eq!(wa, 0.0);
                }
                if nb == 0 && na > 0 {
                    assert_eq!(wa, 1.0);
                }
            }
        }
    }

    #[test]
    fn by_rays_weights_are_the_ray_shares_exactly() {
        for (na, nb) in [(1u64, 3u64), (1000, 24), (7, 7), (1 << 40, 1)] {
            let (a, b) = (est(&[0.0], None, na), est(&[0.0], None, nb));
            let w = ByRays.weight(&(&a).into(), &(&b).into(), 0, 0);
            assert_eq!(w, na as f64 / (na + nb) as f64);
        }
        let zero = est(&[0.0], None, 0);
        assert_eq!(ByRays.weight(&(&zero).into(), &(&zero).into(), 0, 0), 0.5);
    }

    #[test]
    fn by_rays_merge_equals_the_mean_of_all_samples() {
        // Means of 3 and of 5 samples, merged by rays, equal the mean of all 8.
        let s = [1.0, 4.0, 2.0, 8.0, 3.0, 0.5, 7.0, 6.0];
        let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len() as f64;
        let a = est(&[mean(&s[..3])], None, 3);
        let b = est(&[mean(&s[3..])], None, 5);
        let m = merge(&a, &b, &ByRays).unwrap();
        assert!((m.radiosity()[0].x - mean(&s)).abs() < 1e-12);
        assert_eq!(m.rays(), 8);
        assert_eq!(m.variance(), None);
    }

    #[test]
    fn inverse_variance_merge_is_exact_on_known_variances() {
        let a = est(&[10.0], Some(&[1.0]), 4);
        let b = est(&[13.0], Some(&[2.0]), 4);
        let m = merge(&a, &b, &InverseVariance).unwrap();
        // w_a = 2/3, w_b = 1/3: value 11, variance 4/9 + 2/9 = 2/3 = 1 / (1/1 + 1/2).
        assert!((m.radiosity()[0].x - 11.0).abs() < 1e-12);
        assert!((m.variance().unwrap()[0].x - 2.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn a_zero_variance_input_dominates() {
        let a = est(&[10.0], Some(&[0.0]), 4);
        let b = est(&[13.0], Some(&[5.0]), 400);
        for (x, y) in [(&a, &b), (&b, &a)] {
            let m = merge(x, y, &InverseVariance).unwrap();
            assert_eq!(m.radiosity()[0].x, 10.0);
            assert_eq!(m.variance().unwrap()[0].x, 0.0);
            let (ex, ey) = (x.variance().unwrap(), y.variance().unwrap());
            let m = merge(
                Operand::with_expected(x, ex),
                Operand::with_expected(y, ey),
                &InverseExpectedVariance,
            )
            .unwrap();
            assert_eq!(m.radiosity()[0].x, 10.0);
        }
    }

    #[test]
    fn expected_variance_weights_come_from_the_operands_not_the_estimates() {
        let a = est(&[10.0], Some(&[4.0]), 4);
        let b = est(&[13.0], Some(&[1.0]), 4);
        // Weigh as if a had variance 1 and b 2: w_a = 2/3.
        let (wa, wb) = ([DVec3::ONE], [DVec3::splat(2.0)]);
        let m = merge(
            Operand::with_expected(&a, &wa),
            Operand::with_expected(&b, &wb),
            &InverseExpectedVariance,
        )
        .unwrap();
        assert!((m.radiosity()[0].x - 11.0).abs() < 1e-12);
        // Reported: (2/3)² 4 + (1/3)² 1 = 17/9, from the estimates' own variances.
        assert!((m.variance().unwrap()[0].x - 17.0 / 9.0).abs() < 1e-12);
        assert_eq!(m.rays(), 8);
        assert_eq!(
            merge(&a, &b, &InverseExpectedVariance),
            Err(EstimateError::MissingVariance)
        );
        assert!(matches!(
            merge(
                Operand::with_expected(&a, &[]),
                Operand::with_expected(&b, &wb),
                &InverseExpectedVariance
            ),
            Err(EstimateError::VarianceLength { .. })
        ));
    }

    /// Many independent draws `X_a ~ N(m, va)`, `X_b ~ N(m, vb)` (fixed seed), merged by
    /// inverse variance with the true variances: the merge's mean is `m` and its empirical
    /// variance `1 / (1/va + 1/vb)`, each within 5 standard errors.
    #[test]
    fn inverse_variance_merge_reaches_the_minimum_variance() {
        let (mean, va, vb, n): (f64, f64, f64, usize) = (3.0, 4.0, 0.5, 40_000);
        let target = 1.0 / (1.0 / va + 1.0 / vb);
        let mut s = Stream::new(19, 0, 0, 0);
        let (mut sum, mut sum2) = (0.0, 0.0);
        for _ in 0..n {
            let a = est(&[mean + va.sqrt() * normal(&mut s)], Some(&[va]), 10);
            let b = est(&[mean + vb.sqrt() * normal(&mut s)], Some(&[vb]), 10);
            let x = merge(&a, &b, &InverseVariance).unwrap();
            assert!((x.variance().unwrap()[0].x - target).abs() < 1e-12);
            let x = x.radiosity()[0].x;
            sum += x;
            sum2 += x * x;
        }
        let m = sum / n as f64;
        let var = (sum2 - n as f64 * m * m) / (n - 1) as f64;
        assert!(
            (m - mean).abs() < 5.0 * (target / n as f64).sqrt(),
            "mean {m}"
        );
        // The sample variance of n normal draws has standard error var sqrt(2 / (n - 1)).
        let se = target * (2.0 / (n - 1) as f64).sqrt();
        assert!(
            (var - target).abs() < 5.0 * se,
            "variance {var} vs {target}"
        );
        // By rays (equal rays) the variance would be (va + vb) / 4, clearly more.
        assert!((va + vb) / 4.0 > target + 20.0 * se);
    }

    #[test]
    fn emission_passes_through_a_merge_exactly() {
        // Reflected parts 1 and 3 on an emitter of 1000 W/m²: the merge is 1000 + the merged
        // reflected part, whatever the weights.
        let a = est(&[1001.0], Some(&[1.0]), 4);
        let b = est(&[1003.0], Some(&[3.0]), 4);
        let (ea, eb) = ([DVec3::ONE], [DVec3::splat(3.0)]);
        for w in ALL {
            let wa = weight_of(w, &a, &ea, &b, &eb);
            let m = merge(
                Operand::with_expected(&a, &ea),
                Operand::with_expected(&b, &eb),
                &w,
            )
            .unwrap();
            assert!((m.radiosity()[0].x - (1000.0 + wa * 1.0 + (1.0 - wa) * 3.0)).abs() < 1e-12);
        }
    }

    #[test]
    fn merging_checks_shapes() {
        let a = est(&[1.0, 2.0], None, 1);
        let b = est(&[1.0], None, 1);
        assert!(matches!(
            merge(&a, &b, &ByRays),
            Err(EstimateError::PatchCountMismatch { .. })
        ));
        let c = est(&[1.0, 2.0], None, 1);
        assert_eq!(
            merge(&a, &c, &InverseVariance),
            Err(EstimateError::MissingVariance)
        );
        assert!(Estimate::new(vec![DVec3::NAN], None, 1).is_err());
        assert!(Estimate::new(vec![DVec3::ONE], Some(vec![]), 1).is_err());
    }
}
