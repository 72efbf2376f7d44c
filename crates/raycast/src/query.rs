//! The triangle test of the fast caster: four triangles of a [`Packet`] against a ray or
//! segment at once, with the window rules of [`crate::exact`] at the query's end points.

use glam::{Vec3A, Vec4};

use crate::{
    exact,
    frame::WorldRay,
    wide::{LANES, Lane, Packet},
};

/// Crossings of a plane passing within this distance (canonical units) of a query's origin,
/// or this close (in `t`) to a segment's end, are re-decided in `f64` (64 surface offsets,
/// about `6e-5` of the scene), and always within twice the query's windows.
const NEAR: f32 = 1.0 / 16.0;

/// Barycentric slack of the `f32` test within which a near crossing is re-decided in `f64`.
const SLACK: f32 = 1.0 / 256.0;

/// A ray (`len` infinite) or segment in canonical units, with the windows at its ends (see
/// [`exact::ray_rule`]) and the distances within which crossings are re-decided exactly.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Query {
    pub(crate) origin: Vec3A,
    pub(crate) dir: Vec3A,
    len: f32,
    window_start: f32,
    window_end: f32,
    /// The same numbers splatted over the lanes of a packet test.
    lanes: QueryLanes,
}

/// [`Query`]'s numbers in all four lanes.
#[derive(Clone, Copy, Debug)]
struct QueryLanes {
    origin: [Vec4; 3],
    dir: [Vec4; 3],
    len: Vec4,
    window_start2: Vec4,
    window_end2: Vec4,
    window_start_half: Vec4,
    window_end_half: Vec4,
    near_start2: Vec4,
    near_end: Vec4,
}

impl Query {
    /// The length of the query (infinite: a ray).
    #[cfg(test)]
    pub(crate) fn len(&self) -> f32 {
        self.len
    }

    /// The query from `origin` along the unit `dir` for `t` in `(0, len)` (`len` infinite: a
    /// ray), with windows of half-width `window_start` and `window_end` at its ends.
    #[inline(always)]
    pub(crate) fn new(
        origin: Vec3A,
        dir: Vec3A,
        len: f32,
        window_start: f32,
        window_end: f32,
    ) -> Query {
        let near_start = NEAR.max(2.0 * window_start);
        let near_end = NEAR.max(2.0 * window_end);
        let lanes = QueryLanes {
            origin: [0, 1, 2].map(|k| Vec4::splat(origin[k])),
            dir: [0, 1, 2].map(|k| Vec4::splat(dir[k])),
            len: Vec4::splat(len),
            window_start2: Vec4::splat(2.0 * window_start),
            window_end2: Vec4::splat(2.0 * window_end),
            window_start_half: Vec4::splat(0.5 * window_start),
            window_end_half: Vec4::splat(0.5 * window_end),
            near_start2: Vec4::splat(near_start * near_start),
            near_end: Vec4::splat(near_end),
        };
        Query {
            origin,
            dir,
            len,
            window_start,
            window_end,
            lanes,
        }
    }
}

/// What a packet test found: the distance of each lane's plane crossing, the lanes whose
/// triangle the query meets from the front (`det > 0`, see [`exact::crossing`]), the lanes
/// whose crossing counts as it is (`hot`), and the lanes whose crossing must be re-decided by
/// [`refine`] (`cold`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Crossings {
    pub(crate) t: [f32; LANES],
    pub(crate) front: u32,
    pub(crate) hot: u32,
    pub(crate) cold: u32,
}

/// The lanes of `lanes` (a bit mask) of packet `p` against query `q`, in canonical units;
/// `None` when no crossing counts or needs a re-check (the common case).
/// The tests compare barycentrics and distance scaled by `det^2` (no division; canonical
/// coordinates below 1024 keep the products far from `f32` overflow): a lane whose determinant
/// is 0 (a degenerate triangle, or an unused lane) is in neither mask, as its scaled
/// barycentrics are all 0, which is not above `-SLACK * 0`, and its window bound is 0.
///
/// `SEGMENT` is `false` for a ray (`len` infinite, no end window), which drops the tests at the
/// end: `|t - len| < 2 * window_end` never holds for it, and `|t - len| >= near_end` holds for
/// every `t` that can reach that test.
///
/// Per lane this is obvhs's `f32` Möller-Trumbore (`RtTriangle::intersect`, closed edges) for
/// crossings away from the query's end points. Next to them `f32` errors are systematic rather
/// than measure-zero: an origin on a patch edge next to another surface sits within rounding of
/// that surface's plane, and for a ray almost parallel to a plane the `f32` barycentrics err by
/// about `2^-24 * size / cos`. So a crossing of a plane that passes near the origin (or near
/// the segment's end), within `SLACK` of the triangle or within the windows, is marked cold:
/// [`refine`] re-decides it with the rules of [`exact::ray_rule`] and
/// [`exact::segment_rule`].
#[inline(always)]
pub(crate) fn crossings<const SEGMENT: bool>(
    p: &Packet,
    q: &Query,
    lanes: u32,
) -> Option<Crossings> {
    let l = &q.lanes;
    let [dx, dy, dz] = l.dir;
    let [e1x, e1y, e1z] = p.e1;
    let [e2x, e2y, e2z] = p.e2;
    // c = v0 - origin, r = dir x c, ng = e1 x e2
    let (cx, cy, cz) = (
        p.v0[0] - l.origin[0],
        p.v0[1] - l.origin[1],
        p.v0[2] - l.origin[2],
    );
    let (rx, ry, rz) = (dy * cz - dz * cy, dz * cx - dx * cz, dx * cy - dy * cx);
    let (nx, ny, nz) = (
        e1y * e2z - e1z * e2y,
        e1z * e2x - e1x * e2z,
        e1x * e2y - e1y * e2x,
    );
    let det = nx * dx + ny * dy + nz * dz;
    // Every test is on the barycentrics and distance times det^2 (no division, no sign
    // extraction): u' = u det^2 = (r . e2) det, likewise v', w', t'.
    let d2 = det * det;
    let u = (rx * e2x + ry * e2y + rz * e2z) * det;
    let v = (rx * e1x + ry * e1y + rz * e1z) * det;
    let w = d2 - u - v;
    // signed distance of the origin to the plane, times |ng|
    let plane = nx * cx + ny * cy + nz * cz;
    let t = plane * det;
    let slack = d2 * Vec4::splat(-SLACK);
    let maybe = (u.cmpgt(slack) & v.cmpgt(slack) & w.cmpgt(slack)).bitmask();
    // clearly outside (the common case): only the windows look beyond the triangle
    let mut in_window = t.abs().cmplt(l.window_start2 * d2).bitmask();
    let len = l.len * d2;
    if SEGMENT {
        in_window |= (t - len).abs().cmplt(l.window_end2 * d2).bitmask();
    }
    if lanes & (maybe | in_window) == 0 {
        return None;
    }
    let mut near = (plane * plane)
        .cmplt(l.near_start2 * (nx * nx + ny * ny + nz * nz))
        .bitmask();
    if SEGMENT {
        near |= (t - len).abs().cmplt(l.near_end * d2).bitmask();
    }
    let zero = Vec4::ZERO;
    let inside = (u.cmpge(zero) & v.cmpge(zero) & w.cmpge(zero)) & (t.cmpgt(zero) & t.cmplt(len));
    let mut cold = lanes & ((!maybe & in_window) | (maybe & near));
    if cold != 0 {
        // what the window rules reject whatever the exact numbers (the `f32` side is wrong
        // only for a ray almost parallel to the plane, the distance by rounding): well behind
        // the start, or past the end; leaving the start's window backwards (`front` is
        // `det > 0`), or arriving in the end's window front first
        let mut rejected =
            t.cmple(-l.window_start2 * d2) | (t.cmplt(l.window_start_half * d2) & det.cmple(zero));
        if SEGMENT {
            rejected |= t.cmpge(len + l.window_end2 * d2)
                | (t.cmpgt(len - l.window_end_half * d2) & det.cmpgt(zero));
        }
        cold &= !rejected.bitmask();
    }
    let hot = lanes & maybe & !near & inside.bitmask();
    (hot | cold != 0).then(|| Crossings {
        t: (plane / det).to_array(),
        front: det.cmpgt(zero).bitmask(),
        hot,
        cold,
    })
}

/// The exact re-check of a cold crossing (see [`crossings`]) on the same canonical data, by
/// the rules of [`exact::ray_rule`] and [`exact::segment_rule`]: the distance of a crossing
/// that counts (0 for a segment's blocker) and whether the query meets the triangle's front,
/// or `None`.
#[cold]
#[inline(never)]
pub(crate) fn refine(tri: &Lane, q: &Query) -> Option<(f32, bool)> {
    let ray = WorldRay {
        origin: q.origin.as_dvec3(),
        dir: q.dir.as_dvec3(),
        len: q.len as f64,
        window_start: q.window_start as f64,
        window_end: q.window_end as f64,
    };
    // e1 = v0 - v1, e2 = v2 - v0
    let (v0, e1, e2) = (tri.v0.as_dvec3(), -tri.e1.as_dvec3(), tri.e2.as_dvec3());
    if q.len.is_finite() {
        exact::blocker(v0, e1, e2, &ray).map(|(_, front)| (0.0, front))
    } else {
        exact::ray_candidate(v0, e1, e2, &ray).map(|(t, front)| (t as f32, front))
    }
}
