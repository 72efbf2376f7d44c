//! The exact form factor from a point to a polygon (Lambert's contour integral), and clipping
//! of a polygon against a plane.
//!
//! For a differential area at `x` with unit normal `n` and a planar polygon `P` lying wholly on
//! the front side of the tangent plane of `x` (`(v - x) · n >= 0` for every vertex `v`),
//!
//! ```text
//! F_{x→P} = ∫_P cos θ_x cos θ_y / (π r²) dA_y = 1/(2π) | Σ_k β_k n · γ_k |,
//! ```
//!
//! where, with `r_k = v_k - x`, `β_k = ∠(r_k, r_{k+1})` is the angle edge `k` subtends at `x`
//! (radians) and `γ_k = (r_k × r_{k+1}) / |r_k × r_{k+1}|` the unit normal of the plane through
//! `x` and that edge (Lambert 1760; Baum, Rushmeier and Winget 1989). The formula follows from
//! Stokes' theorem applied to the projected solid angle, so it needs the polygon above the
//! horizon of `x`: a polygon that straddles the tangent plane is first clipped to its part in
//! front ([`point_polygon_form_factor`] does that), because the part behind sends nothing to
//! `x` (the kernel is `max(cos θ_x, 0)`).

use glam::DVec3;
use std::f64::consts::TAU;

/// The form factor from a differential area at `x` (scene units) with normal `n` to the planar
/// polygon `polygon` (scene units; vertices in order around it, either orientation):
/// `F = ∫_P max(cos θ_x, 0) cos θ_y / (π r²) dA_y`, dimensionless, in `[0, 1]`.
///
/// `cos θ_x = n · (y - x) / r` with `n` normalised here, and `cos θ_y = |n_P · (y - x)| / r`:
/// which side of the polygon faces `x` is the caller's business (a radiosity patch receives on
/// its front only). Only the part of the polygon in front of the tangent plane at `x`
/// (`(y - x) · n > 0`) counts; the polygon is clipped to it and the rest is ignored. The
/// polygon must be planar and simple (convex, or clipped to a single piece by the tangent
/// plane); fewer than three vertices, a zero or non-finite `n`, or a point in the polygon's
/// plane give 0.
///
/// Exact to rounding: Lambert's contour integral `1/(2π) |Σ_k β_k n · γ_k|` over the edges of
/// the clipped polygon (module documentation).
pub fn point_polygon_form_factor(x: DVec3, n: DVec3, polygon: &[DVec3]) -> f64 {
    let n = n.normalize_or_zero();
    if n == DVec3::ZERO || polygon.len() < 3 {
        return 0.0;
    }
    let mut clipped = Vec::with_capacity(polygon.len() + 1);
    clip_above(polygon, n, n.dot(x), 0.0, &mut clipped);
    contour(x, n, &clipped)
}

/// Lambert's contour sum `1/(2π) |Σ_k β_k n · γ_k|` for a polygon already wholly on the front
/// side of the tangent plane at `x` (unit normal `n`). Edges through `x` (zero cross product)
/// contribute nothing.
#[inline]
pub(crate) fn contour(x: DVec3, n: DVec3, polygon: &[DVec3]) -> f64 {
    let Some(last) = polygon.last() else {
        return 0.0;
    };
    let mut prev = *last - x;
    let mut sum = 0.0;
    for v in polygon {
        let r = *v - x;
        let c = prev.cross(r);
        let len = c.length();
        if len > 0.0 {
            // β = atan2(|a × b|, a · b) is accurate for small and for near-π angles alike.
            sum += len.atan2(prev.dot(r)) * n.dot(c) / len;
        }
        prev = r;
    }
    (sum / TAU).abs()
}

/// Clips the convex polygon `polygon` to the half-space `n · v - d > 0` (Sutherland-Hodgman),
/// writing the result to `out` (cleared first). Signed distances within `eps` of zero count as
/// on the plane: such vertices are kept, and an edge from one to a vertex on either side is not
/// cut. `out` is empty when no vertex is more than `eps` in front; it is `polygon` itself when
/// none is more than `eps` behind.
pub(crate) fn clip_above(polygon: &[DVec3], n: DVec3, d: f64, eps: f64, out: &mut Vec<DVec3>) {
    out.clear();
    let signed = |v: DVec3| {
        let s = n.dot(v) - d;
        if s.abs() <= eps { 0.0 } else { s }
    };
    let (mut front, mut behind) = (false, false);
    for v in polygon {
        let s = signed(*v);
        front |= s > 0.0;
        behind |= s < 0.0;
    }
    if !front {
        return;
    }
    if !behind {
        out.extend_from_slice(polygon);
        return;
    }
    let Some(last) = polygon.last() else {
        return;
    };
    let (mut a, mut sa) = (*last, signed(*last));
    for &b in polygon {
        let sb = signed(b);
        if (sa > 0.0 && sb < 0.0) || (sa < 0.0 && sb > 0.0) {
            out.push(a + (b - a) * (sa / (sa - sb)));
        }
        if sb >= 0.0 {
            out.push(b);
        }
        (a, sa) = (b, sb);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Form factor from a point on the axis of a parallel rectangle `a x b` at distance `c`,
    /// the point under one corner (Howell's catalogue, configuration B-3 per corner).
    fn corner_parallel(a: f64, b: f64, c: f64) -> f64 {
        let (x, y) = (a / c, b / c);
        let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
        (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / TAU
    }

    #[test]
    fn point_under_the_centre_of_a_parallel_square() {
        // Four corner rectangles of 0.5 x 0.5 at distance 1.
        let exact = 4.0 * corner_parallel(0.5, 0.5, 1.0);
        let square = [
            DVec3::new(-0.5, -0.5, 1.0),
            DVec3::new(0.5, -0.5, 1.0),
            DVec3::new(0.5, 0.5, 1.0),
            DVec3::new(-0.5, 0.5, 1.0),
        ];
        let f = point_polygon_form_factor(DVec3::ZERO, DVec3::Z, &square);
        assert!((f - exact).abs() < 1e-14, "{f} vs {exact}");
        assert!((exact - 0.239_456_470_460_773_5).abs() < 1e-12, "{exact}");
        // Orientation does not matter, nor does the normal's length.
        let reversed: Vec<DVec3> = square.iter().rev().copied().collect();
        let g = point_polygon_form_factor(DVec3::ZERO, 3.0 * DVec3::Z, &reversed);
        assert!((g - f).abs() < 1e-15);
        // Off-centre: a point under a corner.
        let f = point_polygon_form_factor(DVec3::new(-0.5, -0.5, 0.0), DVec3::Z, &square);
        assert!((f - corner_parallel(1.0, 1.0, 1.0)).abs() < 1e-14);
    }

    #[test]
    fn perpendicular_rectangle_from_a_point_on_its_base_line() {
        // A point at distance s from the base edge of a perpendicular rectangle, opposite the
        // middle of a base of width 2w and height h (Howell B-5 per half): per half,
        // F = (atan(w/s) - s/sqrt(s² + h²) atan(w / sqrt(s² + h²))) / (2π).
        let (s, w, h): (f64, f64, f64) = (0.3, 0.5, 0.8);
        let rho = (s * s + h * h).sqrt();
        let half = ((w / s).atan() - s / rho * (w / rho).atan()) / TAU;
        let wall = [
            DVec3::new(-w, s, 0.0),
            DVec3::new(w, s, 0.0),
            DVec3::new(w, s, h),
            DVec3::new(-w, s, h),
        ];
        let f = point_polygon_form_factor(DVec3::ZERO, DVec3::Z, &wall);
        assert!((f - 2.0 * half).abs() < 1e-14, "{f} vs {}", 2.0 * half);
    }

    #[test]
    fn a_polygon_straddling_the_horizon_is_clipped() {
        // The same wall extended to z = -0.7: only the part above the tangent plane counts.
        let (s, w, h): (f64, f64, f64) = (0.3, 0.5, 0.8);
        let upper = [
            DVec3::new(-w, s, 0.0),
            DVec3::new(w, s, 0.0),
            DVec3::new(w, s, h),
            DVec3::new(-w, s, h),
        ];
        let straddling = [
            DVec3::new(-w, s, -0.7),
            DVec3::new(w, s, -0.7),
            DVec3::new(w, s, h),
            DVec3::new(-w, s, h),
        ];
        let f = point_polygon_form_factor(DVec3::ZERO, DVec3::Z, &upper);
        let g = point_polygon_form_factor(DVec3::ZERO, DVec3::Z, &straddling);
        assert!((f - g).abs() < 1e-14, "{f} vs {g}");
        // Wholly below: nothing.
        let below: Vec<DVec3> = upper.iter().map(|v| *v - DVec3::Z * 2.0).collect();
        assert_eq!(
            point_polygon_form_factor(DVec3::ZERO, DVec3::Z, &below),
            0.0
        );
        // A tilted triangle cut by the horizon, against brute-force quadrature.
        let tri = [
            DVec3::new(-0.4, 0.2, -0.5),
            DVec3::new(0.6, 0.5, 0.4),
            DVec3::new(-0.2, 0.9, 0.7),
        ];
        let f = point_polygon_form_factor(DVec3::ZERO, DVec3::Z, &tri);
        let brute = brute_force(DVec3::ZERO, DVec3::Z, &tri, 2000);
        assert!((f - brute).abs() < 2e-5, "{f} vs {brute}");
    }

    /// Midpoint rule on an n x n grid of the triangle's parameter square (Duffy map).
    fn brute_force(x: DVec3, n: DVec3, tri: &[DVec3; 3], k: usize) -> f64 {
        let np = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
        let (area2, unit) = (np.length(), np.normalize());
        let mut sum = 0.0;
        for a in 0..k {
            for b in 0..k {
                let (u, v) = ((a as f64 + 0.5) / k as f64, (b as f64 + 0.5) / k as f64);
                let y = tri[0] + (tri[1] - tri[0]) * u + (tri[2] - tri[1]) * (u * v);
                let jac = area2 * u / (k * k) as f64;
                let d = y - x;
                let r2 = d.length_squared();
                let cx = (n.dot(d) / r2.sqrt()).max(0.0);
                let cy = unit.dot(d).abs() / r2.sqrt();
                sum += cx * cy / (std::f64::consts::PI * r2) * jac;
            }
        }
        sum
    }

    #[test]
    fn clipping_keeps_on_plane_vertices_and_cuts_crossing_edges() {
        let square = [
            DVec3::new(0.0, 0.0, -1.0),
            DVec3::new(1.0, 0.0, -1.0),
            DVec3::new(1.0, 0.0, 1.0),
            DVec3::new(0.0, 0.0, 1.0),
        ];
        let mut out = Vec::new();
        clip_above(&square, DVec3::Z, 0.0, 1e-12, &mut out);
        assert_eq!(out.len(), 4);
        let area = (out[2] - out[0]).cross(out[3] - out[1]).length() / 2.0;
        assert!((area - 1.0).abs() < 1e-15);
        clip_above(&square, DVec3::Z, -1.0, 1e-12, &mut out);
        assert_eq!(out, square, "touching from above: unchanged");
        clip_above(&square, DVec3::Z, 1.0, 1e-12, &mut out);
        assert!(out.is_empty(), "touching from below: empty");
    }
}
