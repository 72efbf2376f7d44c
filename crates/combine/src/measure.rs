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
}
