//! The error measure used everywhere (tests, traces, experiments).

use glam::DVec3;

/// The relative RMS error of `values` against `reference`, weighted by area, over the reflected
/// light only:
///
/// `rms_rel = sqrt( sum_i A_i sum_c (B_ic - R_ic)² / sum_i A_i sum_c (R_ic - E_ic)² )`
///
/// with `A_i` the patch areas (scene units²), `E_i` the emission, `B_i` the values and `R_i` the
/// reference (all W/m²). The denominator leaves out emission, which every method knows
/// exactly, so a bright emitter cannot hide errors elsewhere. Dimensionless; `NaN` when the
/// reference reflects nothing. The slices must have equal lengths.
pub fn rms_rel(area: &[f64], emission: &[DVec3], values: &[DVec3], reference: &[DVec3]) -> f64 {
    assert!(
        area.len() == emission.len() && area.len() == values.len() && area.len() == reference.len(),
        "rms_rel needs one area, emission, value and reference per patch"
    );
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..area.len() {
        let d = values[i] - reference[i];
        let r = reference[i] - emission[i];
        num += area[i] * d.length_squared();
        den += area[i] * r.length_squared();
    }
    (num / den).sqrt()
}

/// The relative standard error of a patch's incident irradiance `H = (B - E) / rho`:
/// `sqrt(sum_c var(B_c)) / sum_c (B_c - E_c)` over the RGB channels (`rho` cancels; the variance
/// of `B` is that of its reflected part, `E` being exact). `b`, `e` in W/m², `variance` in
/// (W/m²)²; dimensionless. Infinite where no light arrives (`B = E`) and the variance is not
/// 0; 0 where both are 0.
pub fn relative_error(b: DVec3, e: DVec3, variance: DVec3) -> f64 {
    let reflected = (b - e).element_sum();
    let sd = variance.max(DVec3::ZERO).element_sum().sqrt();
    if sd == 0.0 {
        0.0
    } else if reflected > 0.0 {
        sd / reflected
    } else {
        f64::INFINITY
    }
}

/// The `q`-quantile (in `[0, 1]`) of `values` weighted by `weights` (the smallest value whose
/// cumulative weight reaches `q` of the total); `None` when the total weight is not positive.
pub fn weighted_quantile(values: &[f64], weights: &[f64], q: f64) -> Option<f64> {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let total: f64 = weights.iter().sum();
    if total.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let mut sum = 0.0;
    for &i in &order {
        sum += weights[i];
        if sum >= q * total {
            return Some(values[i]);
        }
    }
    order.last().map(|&i| values[i])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn measures_reflected_light_only() {
        let area = [1.0, 3.0];
        let e = [DVec3::splat(10.0), DVec3::ZERO];
        let r = [DVec3::splat(10.0), DVec3::splat(2.0)];
        // Exact values: no error. A 10% error on the reflector: 0.1 exactly.
        assert_eq!(rms_rel(&area, &e, &r, &r), 0.0);
        let b = [DVec3::splat(10.0), DVec3::splat(2.2)];
        assert!((rms_rel(&area, &e, &b, &r) - 0.1).abs() < 1e-12);
        // An error on the emitter counts against the reflected light (here 3 x 4 = 12).
        let c = [DVec3::splat(11.0), DVec3::splat(2.0)];
        assert!((rms_rel(&area, &e, &c, &r) - (3.0f64 / 36.0).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn relative_errors_and_weighted_quantiles() {
        let b = DVec3::new(3.0, 2.0, 1.0);
        let e = DVec3::ZERO;
        assert_eq!(relative_error(b, e, DVec3::new(9.0, 16.0, 11.0)), 1.0);
        assert_eq!(relative_error(e, e, DVec3::ONE), f64::INFINITY);
        assert_eq!(relative_error(e, e, DVec3::ZERO), 0.0);
        let v = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(weighted_quantile(&v, &[1.0; 4], 0.5), Some(2.0));
        assert_eq!(weighted_quantile(&v, &[1.0; 4], 0.95), Some(4.0));
        assert_eq!(
            weighted_quantile(&v, &[0.0, 0.0, 10.0, 1.0], 0.5),
            Some(3.0)
        );
        assert_eq!(weighted_quantile(&v, &[0.0; 4], 0.5), None);
    }
}
