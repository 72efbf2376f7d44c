//! Weighting rules and the merge of two estimates.

use crate::estimate::{Estimate, EstimateError};
use glam::DVec3;

/// How two independent estimates of the same radiosity are weighted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rule {
    /// Weights proportional to the rays behind each estimate: `w_a = n_a / (n_a + n_b)`.
    /// The right rule for estimates whose variance falls as `1/n` with the same constant
    /// (progressive ray refinement, progressive gathering).
    ByWork,
    /// Per patch and channel, weights proportional to `1/V`: `w_a = V_b / (V_a + V_b)`, the
    /// minimum-variance unbiased merge. A channel where both variances are zero falls back to
    /// [`Rule::ByWork`].
    InverseVariance,
}

/// The weights of one patch and channel: `w_a + w_b = 1`, both in `[0, 1]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Weights {
    /// Weight of the first estimate.
    pub a: f64,
    /// Weight of the second estimate.
    pub b: f64,
}

impl Rule {
    /// Weights for merging a value backed by `rays_a` rays and variance `var_a` with one backed by
    /// `rays_b` and `var_b`. Zero rays get zero weight; when both have zero rays the weights are
    /// `(1/2, 1/2)`.
    pub fn weights(self, rays_a: u64, var_a: f64, rays_b: u64, var_b: f64) -> Weights {
        let by_work = || {
            let total = rays_a as f64 + rays_b as f64;
            if total == 0.0 {
                Weights { a: 0.5, b: 0.5 }
            } else {
                let a = rays_a as f64 / total;
                Weights { a, b: 1.0 - a }
            }
        };
        match self {
            Rule::ByWork => by_work(),
            Rule::InverseVariance => {
                if rays_a == 0 {
                    return Weights { a: 0.0, b: 1.0 };
                }
                if rays_b == 0 {
                    return Weights { a: 1.0, b: 0.0 };
                }
                let total = var_a + var_b;
                if total > 0.0 {
                    let a = var_b / total;
                    Weights { a, b: 1.0 - a }
                } else {
                    by_work()
                }
            }
        }
    }
}

/// Merges two independent estimates of the same patches with `rule`. The result's rays are the
/// sum, and its variance (when both have one) is `w_a² V_a + w_b² V_b`.
pub fn merge(a: &Estimate, b: &Estimate, rule: Rule) -> Result<Estimate, EstimateError> {
    if a.len() != b.len() {
        return Err(EstimateError::PatchCountMismatch {
            a: a.len(),
            b: b.len(),
        });
    }
    let (va, vb) = match (a.variance(), b.variance()) {
        (Some(va), Some(vb)) => (Some(va), Some(vb)),
        _ if rule == Rule::InverseVariance => return Err(EstimateError::MissingVariance),
        _ => (None, None),
    };
    let n = a.len();
    let mut value = Vec::with_capacity(n);
    let mut variance = va.map(|_| Vec::with_capacity(n));
    for i in 0..n {
        let var_a = va.map_or(DVec3::ZERO, |v| v[i]);
        let var_b = vb.map_or(DVec3::ZERO, |v| v[i]);
        let mut x = DVec3::ZERO;
        let mut v = DVec3::ZERO;
        for c in 0..3 {
            let w = rule.weights(a.rays(), var_a[c], b.rays(), var_b[c]);
            x[c] = w.a * a.radiosity()[i][c] + w.b * b.radiosity()[i][c];
            v[c] = w.a * w.a * var_a[c] + w.b * w.b * var_b[c];
        }
        value.push(x);
        if let Some(out) = variance.as_mut() {
            out.push(v);
        }
    }
    Estimate::new(value, variance, a.rays() + b.rays())
}

/// Merges two independent estimates of the same patches by inverse variance, the weights taken
/// from *other* variances than the estimates' own: `weigh_a` and `weigh_b` (one per patch,
/// (W/m²)², e.g. the expected variances of [`crate::expected`]), so the weights need not be
/// computed from the samples they weight. Per patch and channel `w_a = Wb / (Wa + Wb)`
/// ([`Rule::InverseVariance`]'s weights for `Wa`, `Wb`); the result's variance is
/// `w_a² V_a + w_b² V_b` with the estimates' own `V` (their best estimate of their noise), and its
/// rays the sum.
///
/// Errors: patch counts differ, a variance vector has the wrong length, or an estimate has no
/// variance.
pub fn merge_weighted(
    a: &Estimate,
    b: &Estimate,
    weigh_a: &[DVec3],
    weigh_b: &[DVec3],
) -> Result<Estimate, EstimateError> {
    if a.len() != b.len() {
        return Err(EstimateError::PatchCountMismatch {
            a: a.len(),
            b: b.len(),
        });
    }
    for w in [weigh_a, weigh_b] {
        if w.len() != a.len() {
            return Err(EstimateError::VarianceLength {
                patches: a.len(),
                variances: w.len(),
            });
        }
    }
    let (Some(va), Some(vb)) = (a.variance(), b.variance()) else {
        return Err(EstimateError::MissingVariance);
    };
    let n = a.len();
    let (mut value, mut variance) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for i in 0..n {
        let (mut x, mut v) = (DVec3::ZERO, DVec3::ZERO);
        for c in 0..3 {
            let w = Rule::InverseVariance.weights(a.rays(), weigh_a[i][c], b.rays(), weigh_b[i][c]);
            x[c] = w.a * a.radiosity()[i][c] + w.b * b.radiosity()[i][c];
            v[c] = w.a * w.a * va[i][c] + w.b * w.b * vb[i][c];
        }
        value.push(x);
        variance.push(v);
    }
    Estimate::new(value, Some(variance), a.rays() + b.rays())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn est(values: &[f64], var: Option<&[f64]>, rays: u64) -> Estimate {
        Estimate::new(
            values.iter().map(|&x| DVec3::splat(x)).collect(),
            var.map(|v| v.iter().map(|&x| DVec3::splat(x)).collect()),
            rays,
        )
        .unwrap()
    }

    #[test]
    fn weights_sum_to_one_and_zero_work_gets_zero_weight() {
        for rule in [Rule::ByWork, Rule::InverseVariance] {
            for (na, va, nb, vb) in [
                (3, 1.0, 7, 2.0),
                (0, 1.0, 5, 1.0),
                (5, 0.0, 0, 0.0),
                (1, 0.0, 1, 0.0),
            ] {
                let w = rule.weights(na, va, nb, vb);
                assert!((w.a + w.b - 1.0).abs() < 1e-15, "{rule:?} {w:?}");
                assert!((0.0..=1.0).contains(&w.a));
                if na == 0 {
                    assert_eq!(w.a, 0.0, "{rule:?}");
                }
                if nb == 0 {
                    assert_eq!(w.b, 0.0, "{rule:?}");
                }
            }
        }
    }

    #[test]
    fn by_work_merge_equals_serial_accumulation_of_the_samples() {
        // Means of 3 and of 5 samples, merged by work, equal the mean of all 8.
        let s = [1.0, 4.0, 2.0, 8.0, 3.0, 0.5, 7.0, 6.0];
        let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len() as f64;
        let a = est(&[mean(&s[..3])], None, 3);
        let b = est(&[mean(&s[3..])], None, 5);
        let m = merge(&a, &b, Rule::ByWork).unwrap();
        assert!((m.radiosity()[0].x - mean(&s)).abs() < 1e-12);
        assert_eq!(m.rays(), 8);
    }

    #[test]
    fn inverse_variance_merge_minimises_variance() {
        let a = est(&[10.0], Some(&[1.0]), 4);
        let b = est(&[13.0], Some(&[2.0]), 4);
        let m = merge(&a, &b, Rule::InverseVariance).unwrap();
        // w_a = 2/3, w_b = 1/3: value 11, variance 4/9 + 2/9 = 2/3 < min(1, 2).
        assert!((m.radiosity()[0].x - 11.0).abs() < 1e-12);
        assert!((m.variance().unwrap()[0].x - 2.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn emission_passes_through_a_merge_exactly() {
        // Reflected parts 1 and 3 on an emitter of 1000 W/m²: the merge is 1000 + the merged
        // reflected part, whatever the weights.
        let a = est(&[1001.0], Some(&[1.0]), 4);
        let b = est(&[1003.0], Some(&[3.0]), 4);
        for rule in [Rule::ByWork, Rule::InverseVariance] {
            let w = rule.weights(4, 1.0, 4, 3.0);
            let m = merge(&a, &b, rule).unwrap();
            assert!((m.radiosity()[0].x - (1000.0 + w.a * 1.0 + w.b * 3.0)).abs() < 1e-12);
        }
    }

    #[test]
    fn weighted_merge_takes_weights_from_the_given_variances_and_reports_its_own() {
        let a = est(&[10.0], Some(&[4.0]), 4);
        let b = est(&[13.0], Some(&[1.0]), 4);
        // Weigh as if a had variance 1 and b 2: w_a = 2/3.
        let m = merge_weighted(&a, &b, &[DVec3::ONE], &[DVec3::splat(2.0)]).unwrap();
        assert!((m.radiosity()[0].x - 11.0).abs() < 1e-12);
        // Reported: (2/3)² 4 + (1/3)² 1 = 17/9.
        assert!((m.variance().unwrap()[0].x - 17.0 / 9.0).abs() < 1e-12);
        assert_eq!(m.rays(), 8);
        assert!(merge_weighted(&a, &b, &[], &[DVec3::ONE]).is_err());
        assert!(merge_weighted(&a, &est(&[1.0], None, 1), &[DVec3::ONE], &[DVec3::ONE]).is_err());
    }

    #[test]
    fn merging_checks_shapes() {
        let a = est(&[1.0, 2.0], None, 1);
        let b = est(&[1.0], None, 1);
        assert!(matches!(
            merge(&a, &b, Rule::ByWork),
            Err(EstimateError::PatchCountMismatch { .. })
        ));
        let c = est(&[1.0, 2.0], None, 1);
        assert_eq!(
            merge(&a, &c, Rule::InverseVariance),
            Err(EstimateError::MissingVariance)
        );
        assert!(Estimate::new(vec![DVec3::NAN], None, 1).is_err());
        assert!(Estimate::new(vec![DVec3::ONE], Some(vec![]), 1).is_err());
    }
}
