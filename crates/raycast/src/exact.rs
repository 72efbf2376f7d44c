//! The `f64` ray-triangle test shared by the oracle and the BVH's near-origin re-check.

use glam::DVec3;

use crate::frame::WorldRay;

/// Möller-Trumbore in `f64` with closed edges, on the triangle `v0, v0 + e1, v0 + e2`:
/// `(t, front)` for `t` in `[tmin, tmax]`, `front` when the ray arrives against the
/// counter-clockwise normal `e1 × e2`. Degenerate triangles and rays in the triangle's plane
/// never hit.
#[inline]
pub(crate) fn intersect(v0: DVec3, e1: DVec3, e2: DVec3, r: &WorldRay) -> Option<(f64, bool)> {
    let p = r.dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = r.origin - v0;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = r.dir.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    if !(t >= r.tmin && t <= r.tmax) {
        return None;
    }
    // det = e1 . (d x e2) = d . (e2 x e1) = -d . n  with n = e1 x e2
    Some((t, det > 0.0))
}
