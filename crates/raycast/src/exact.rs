//! The exact (`f64`) ray-triangle test and the rules that decide which crossings count; shared
//! by the oracle and the BVH's re-check of crossings next to a query's end points.

use glam::DVec3;

use crate::frame::WorldRay;

/// A ray's crossing of a triangle's plane, in `f64`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Crossing {
    /// Distance along the (unit) direction from the origin.
    pub t: f64,
    /// The ray arrives against the counter-clockwise normal (it hits the front side).
    pub front: bool,
    /// Barycentrics of the crossing point for `v1` and `v2` (`P = v0 + u e1 + v e2`).
    u: f64,
    v: f64,
    /// The triangle's edges, for distances to its boundary.
    e1: DVec3,
    e2: DVec3,
}

impl Crossing {
    /// The crossing point lies in the closed triangle.
    #[inline]
    pub(crate) fn inside(&self) -> bool {
        self.u >= 0.0 && self.v >= 0.0 && self.u + self.v <= 1.0
    }

    /// The crossing point lies within `margin` of the closed triangle (in its plane).
    pub(crate) fn within(&self, margin: f64) -> bool {
        if self.inside() {
            return true;
        }
        // barycentric * 2 area / opposite edge = distance to that edge's line (inside > 0)
        let twice_area = self.e1.cross(self.e2).length();
        let w = 1.0 - self.u - self.v;
        w * twice_area >= -margin * (self.e2 - self.e1).length()
            && self.u * twice_area >= -margin * self.e2.length()
            && self.v * twice_area >= -margin * self.e1.length()
    }
}

/// Möller-Trumbore in `f64` on the triangle `v0, v0 + e1, v0 + e2`, without the inside test:
/// `None` only for degenerate triangles and rays parallel to the plane.
#[inline]
pub(crate) fn crossing(
    v0: DVec3,
    e1: DVec3,
    e2: DVec3,
    origin: DVec3,
    dir: DVec3,
) -> Option<Crossing> {
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - v0;
    let q = s.cross(e1);
    let t = e2.dot(q) * inv;
    // det = e1 . (d x e2) = d . (e2 x e1) = -d . n  with n = e1 x e2
    Some(Crossing {
        t,
        front: det > 0.0,
        u: s.dot(p) * inv,
        v: dir.dot(q) * inv,
        e1,
        e2,
    })
}

/// Whether a ray's crossing counts, and at what distance.
///
/// Beyond the `window` around the origin, a crossing inside the (closed) triangle counts.
/// Inside the window the origin is within rounding of the surface, so side and position are
/// unreliable and the decision rests on orientation: a front-facing crossing within half a
/// window of the triangle counts at distance `max(t, 0)` (the ray walks into a surface it
/// starts on, e.g. the wall at the foot of which it leaves the floor), a back-facing one never
/// does (the ray leaves a surface it starts on). Half a window, because a lifted origin next
/// to a convex edge is a full window off the neighbouring face.
#[inline]
pub(crate) fn ray_rule(c: &Crossing, window: f64) -> Option<f64> {
    if c.t >= window {
        c.inside().then_some(c.t)
    } else if c.t > -window && c.front && c.within(0.5 * window) {
        Some(c.t.max(0.0))
    } else {
        None
    }
}

/// Whether a segment's crossing blocks it: [`ray_rule`] at the start, its mirror image at the
/// end (only a crossing the segment arrives at from behind blocks there), the closed triangle
/// in between.
#[inline]
pub(crate) fn segment_rule(c: &Crossing, seg: &WorldRay) -> bool {
    let t = c.t;
    if t <= -seg.window_start || t >= seg.len + seg.window_end {
        false
    } else if t < seg.window_start {
        c.front && c.within(0.5 * seg.window_start)
    } else if t > seg.len - seg.window_end {
        !c.front && c.within(0.5 * seg.window_end)
    } else {
        c.inside()
    }
}

/// Exact closest-hit candidate of one triangle for a ray: `(distance, front)`.
#[inline]
pub(crate) fn ray_candidate(v0: DVec3, e1: DVec3, e2: DVec3, r: &WorldRay) -> Option<(f64, bool)> {
    let c = crossing(v0, e1, e2, r.origin, r.dir)?;
    ray_rule(&c, r.window_start).map(|d| (d, c.front))
}

/// Exact blocker test of one triangle for a segment: `(t, front)` when it blocks.
#[inline]
pub(crate) fn blocker(v0: DVec3, e1: DVec3, e2: DVec3, seg: &WorldRay) -> Option<(f64, bool)> {
    let c = crossing(v0, e1, e2, seg.origin, seg.dir)?;
    segment_rule(&c, seg).then_some((c.t, c.front))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(tri: [DVec3; 3], o: DVec3, d: DVec3) -> Option<(f64, bool)> {
        let c = crossing(tri[0], tri[1] - tri[0], tri[2] - tri[0], o, d)?;
        (c.inside() && c.t >= 0.0).then_some((c.t, c.front))
    }

    #[test]
    fn moller_trumbore_orientation_edges_and_planes() {
        let tri = [DVec3::ZERO, DVec3::X, DVec3::Y]; // normal +Z
        let above = DVec3::new(0.25, 0.25, 1.0);
        assert_eq!(hit(tri, above, -DVec3::Z), Some((1.0, true)));
        assert_eq!(
            hit(tri, DVec3::new(0.25, 0.25, -2.0), DVec3::Z),
            Some((2.0, false))
        );
        // exactly on an edge and on a vertex: closed triangle
        assert!(hit(tri, DVec3::new(0.5, 0.0, 1.0), -DVec3::Z).is_some());
        assert!(hit(tri, DVec3::new(0.0, 1.0, 1.0), -DVec3::Z).is_some());
        assert!(hit(tri, DVec3::new(0.6, 0.6, 1.0), -DVec3::Z).is_none());
        // in the plane: no crossing; behind: no hit
        assert!(crossing(tri[0], tri[1], tri[2], DVec3::new(-1.0, 0.2, 0.0), DVec3::X).is_none());
        assert!(hit(tri, above, DVec3::Z).is_none());
        // degenerate
        let line = [DVec3::ZERO, DVec3::X, DVec3::X * 2.0];
        assert!(crossing(line[0], line[1], line[2], above, -DVec3::Z).is_none());
    }

    #[test]
    fn within_measures_distance_to_the_triangle() {
        let tri = [DVec3::ZERO, DVec3::X * 2.0, DVec3::Y * 2.0];
        let at = |x: f64, y: f64| {
            crossing(tri[0], tri[1], tri[2], DVec3::new(x, y, 1.0), -DVec3::Z).unwrap()
        };
        assert!(at(-0.09, 0.5).within(0.1) && !at(-0.11, 0.5).within(0.1));
        assert!(at(0.5, -0.09).within(0.1) && !at(0.5, -0.11).within(0.1));
        let d = 0.09 * std::f64::consts::SQRT_2;
        assert!(at(1.0 + d / 2.0, 1.0 + d / 2.0).within(0.1));
        assert!(!at(1.0 + 0.08, 1.0 + 0.08).within(0.1));
    }

    #[test]
    fn window_rules() {
        let w = 0.01;
        let tri = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let c = |z: f64, d: DVec3| {
            crossing(tri[0], tri[1], tri[2], DVec3::new(0.25, 0.25, z), d).unwrap()
        };
        // beyond the window: either side
        assert_eq!(ray_rule(&c(0.5, -DVec3::Z), w), Some(0.5));
        assert_eq!(ray_rule(&c(-0.5, DVec3::Z), w), Some(0.5));
        // inside the window: front only, distance clamped at 0
        assert_eq!(ray_rule(&c(0.005, -DVec3::Z), w), Some(0.005));
        assert_eq!(ray_rule(&c(-0.005, -DVec3::Z), w), Some(0.0));
        assert_eq!(ray_rule(&c(-0.005, DVec3::Z), w), None);
        assert_eq!(ray_rule(&c(0.02, DVec3::Z), w), None);
        // near an edge inside the window: half a window of slack
        let edge = |x: f64| {
            crossing(
                tri[0],
                tri[1],
                tri[2],
                DVec3::new(x, 0.25, 0.001),
                -DVec3::Z,
            )
            .unwrap()
        };
        assert!(ray_rule(&edge(-0.004), w).is_some() && ray_rule(&edge(-0.006), w).is_none());
        let seg = |z: f64, d: DVec3| WorldRay {
            origin: DVec3::new(0.25, 0.25, z),
            dir: d,
            len: 1.0,
            window_start: w,
            window_end: 2.0 * w,
        };
        let blocks = |s: &WorldRay| blocker(tri[0], tri[1] - tri[0], tri[2] - tri[0], s).is_some();
        assert!(blocks(&seg(0.5, -DVec3::Z)) && blocks(&seg(-0.5, DVec3::Z)));
        assert!(blocks(&seg(0.005, -DVec3::Z)) && !blocks(&seg(-0.005, DVec3::Z)));
        // at the end: only arriving from behind
        assert!(blocks(&seg(-1.01, DVec3::Z)) && !blocks(&seg(1.01, -DVec3::Z)));
        assert!(!blocks(&seg(-1.03, DVec3::Z)) && !blocks(&seg(0.02, DVec3::Z)));
    }
}
