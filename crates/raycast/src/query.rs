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
    /// Crossings farther than this from their triangle (in its plane) never count: the largest
    /// window, twice the largest margin of the rules, plus `2^-8` of it for the rounding of
    /// [`far_outside`]'s own products.
    far: Vec4,
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
            far: Vec4::splat(window_start.max(window_end) * (1.0 + 1.0 / 256.0)),
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

/// The lanes of packet `p` whose id is neither of `exclude` against query `q`, in canonical
/// units; `None` when no crossing counts or needs a re-check (the common case).
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
/// [`exact::segment_rule`]. Cold crossings those rules reject whatever the exact numbers are
/// dropped first: behind the start or past the end, leaving the start or arriving at the end
/// on the wrong side, and crossings certainly farther from their triangle than the rules look
/// ([`Outside::beyond`]; most are the coplanar neighbours of an end's triangle, crossed within
/// the window by a segment leaving that end below its surface).
#[inline(always)]
pub(crate) fn crossings<const SEGMENT: bool>(
    p: &Packet,
    q: &Query,
    exclude: (u32, u32),
) -> Option<Crossings> {
    let l = &q.lanes;
    let o = Outside::of(p, q);
    let ([cx, cy, cz], [nx, ny, nz], ru, rv, det) = (o.c, o.n, o.ru, o.rv, o.det);
    // Every test is on the barycentrics and distance times det^2 (no division, no sign
    // extraction): u' = u det^2 = (r . e2) det, likewise v', w', t'.
    let d2 = det * det;
    let u = ru * det;
    let v = rv * det;
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
    if maybe | in_window == 0 {
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
    let mut cold = (!maybe & in_window) | (maybe & near);
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
        // (only where the `f32` test finds the crossing outside the triangle by more than
        // `SLACK`: near or inside it, as the crossings of a near plane within `SLACK` are,
        // the bound rarely drops a lane, and the Cornell box's re-checks are such)
        let outside = cold & !maybe;
        if outside != 0 {
            cold &= !(far_outside(p, q) & outside);
        }
    }
    let mut hot = maybe & !near & inside.bitmask();
    if hot | cold == 0 {
        return None;
    }
    // the lanes that count: not the excluded ids
    let keep = !excluded(p, exclude.0, exclude.1);
    hot &= keep;
    cold &= keep;
    (hot | cold != 0).then(|| Crossings {
        t: (plane / det).to_array(),
        front: det.cmpgt(zero).bitmask(),
        hot,
        cold,
    })
}

/// The lanes of packet `p` whose crossing with query `q` lies certainly farther from the
/// triangle than the rules of [`exact`] look ([`Outside::beyond`]): lanes [`refine`] would
/// reject. Apart from the packet test so that the numbers it needs are computed again here
/// instead of being kept, spilled, through every packet test for this rare case.
#[cold]
#[inline(never)]
fn far_outside(p: &Packet, q: &Query) -> u32 {
    Outside::of(p, q).beyond(q.lanes.far)
}

/// A packet test's numbers for [`Outside::beyond`]: `c = v0 - origin`, the edges, `n = e1 x e2`,
/// `ru = (dir x c) . e2`, `rv = (dir x c) . e1` and `det = n . dir`, as [`crossings`] computes
/// them in `f32`.
struct Outside {
    c: [Vec4; 3],
    e1: [Vec4; 3],
    e2: [Vec4; 3],
    n: [Vec4; 3],
    ru: Vec4,
    rv: Vec4,
    det: Vec4,
}

/// The unit roundoff of `f32`, `2^-24`.
const ROUNDOFF: f32 = 1.0 / (1u32 << 24) as f32;

impl Outside {
    /// The numbers of packet `p` against query `q`.
    #[inline(always)]
    fn of(p: &Packet, q: &Query) -> Outside {
        let l = &q.lanes;
        let [dx, dy, dz] = l.dir;
        let [e1x, e1y, e1z] = p.e1;
        let [e2x, e2y, e2z] = p.e2;
        // c = v0 - origin, r = dir x c, n = e1 x e2
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
        Outside {
            c: [cx, cy, cz],
            e1: p.e1,
            e2: p.e2,
            n: [nx, ny, nz],
            ru: rx * e2x + ry * e2y + rz * e2z,
            rv: rx * e1x + ry * e1y + rz * e1z,
            det: nx * dx + ny * dy + nz * dz,
        }
    }

    /// The lanes whose line meets the triangle's plane certainly farther than `far` from the
    /// triangle (bit `j` for lane `j`), whatever the `f32` rounding: crossings [`refine`] rejects.
    ///
    /// With exact arithmetic on the same `f32` inputs, `ru`, `rv` and `det - ru - rv` are the
    /// barycentrics of the crossing for `v1`, `v2` and `v0` times `det`, and barycentric `b`
    /// of a vertex is `b |n| / |e|` from the line of the opposite edge `e` (outside where
    /// negative). So a lane is beyond `far` when, for some vertex, `b det` and `det` certainly
    /// differ in sign and `(|b det| - err) |n|_low > far |e|_high (|det| + err_det)`: the
    /// distance to that edge's line, a lower bound of the distance to the triangle, exceeds
    /// `far`. The bounds (`|x|_1` the sum of absolute values):
    /// - `|n|_low = max |n_k| - 8 u |e1|_1 |e2|_1`, as `|n| >= max |n_k|` and each `n_k` is
    ///   within `2u` of its two products (`u` = [`ROUNDOFF`]);
    /// - `det` within `16 u |e1|_1 |e2|_1` (the error of `n`, then a dot product: about `6u`);
    /// - `ru` within `16 u |e2|_1 |c|_1` and `rv` within `16 u |e1|_1 |c|_1` (the rounding of
    ///   `c`, of `dir x c` and of the dot product, each direction component at most 1: about
    ///   `6u`);
    /// - `det - ru - rv` within the sum of those and `4u (|det| + |ru| + |rv|)` for its two
    ///   subtractions;
    /// - `|e|_high` the sum of absolute values (`|e3|_1 <= |e1|_1 + |e2|_1` for the third edge
    ///   `e1 + e2`).
    ///
    /// The bounds are two to three times the worst case, so their own rounding (a few `u`)
    /// cannot undercut them, and `far` carries `2^-8` of slack for the rounding of the final
    /// products. Where any of them is in doubt (`det` or `|n|` within its error of 0, a
    /// barycentric's sign within its error) the lane is kept. Where they hold, the `f64` re-check
    /// on the same inputs is accurate to far better than a factor of 2 (its relative error is
    /// below `2^-29` where `f32` is sure to `2^-20`), so it finds the crossing outside the
    /// margins of its rules (half a window, or the closed triangle), as `far` is twice the
    /// largest margin.
    #[inline(always)]
    fn beyond(&self, far: Vec4) -> u32 {
        let l1 = |v: &[Vec4; 3]| v[0].abs() + v[1].abs() + v[2].abs();
        let (a1, a2, ac) = (l1(&self.e1), l1(&self.e2), l1(&self.c));
        let [nx, ny, nz] = self.n;
        let s12 = a1 * a2;
        let n_low = nx.abs().max(ny.abs()).max(nz.abs()) - Vec4::splat(8.0 * ROUNDOFF) * s12;
        let err_det = Vec4::splat(16.0 * ROUNDOFF) * s12;
        let err_u = Vec4::splat(16.0 * ROUNDOFF) * (a2 * ac);
        let err_v = Vec4::splat(16.0 * ROUNDOFF) * (a1 * ac);
        let (det, ru, rv) = (self.det, self.ru, self.rv);
        let rw = det - ru - rv;
        let err_w = err_det
            + err_u
            + err_v
            + Vec4::splat(4.0 * ROUNDOFF) * (det.abs() + ru.abs() + rv.abs());
        let bound = far * (det.abs() + err_det);
        let zero = Vec4::ZERO;
        // barycentric `b det` with error `err`, opposite edge of length at most `edge`
        let outside = |b: Vec4, err: Vec4, edge: Vec4| {
            (b * det).cmplt(zero) & ((b.abs() - err) * n_low).cmpgt(bound * edge)
        };
        let sure = det.abs().cmpgt(err_det) & n_low.cmpgt(zero);
        (sure & (outside(ru, err_u, a2) | outside(rv, err_v, a1) | outside(rw, err_w, a1 + a2)))
            .bitmask()
    }
}

/// The lanes of `packet` whose id is `a` or `b`, as a bit mask.
#[inline(always)]
fn excluded(packet: &Packet, a: u32, b: u32) -> u32 {
    let mut mask = 0;
    for (j, &id) in packet.ids.iter().enumerate() {
        mask |= (((id == a) | (id == b)) as u32) << j;
    }
    mask
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

#[cfg(test)]
mod tests {
    use glam::Vec3A;

    use super::*;
    use crate::wide::LANES;

    /// `Outside::beyond` drops only crossings that `refine` rejects, on segments and rays whose
    /// crossing lies within or near a window, just outside a triangle or its coplanar
    /// neighbours, from steep to grazing, near the scene's centre or its corner.
    #[test]
    fn far_outside_crossings_are_rejected_by_the_exact_rules() {
        let mut next = crate::testing::uniforms(35);
        let mut unit = move || next();
        let (mut dropped, mut close, mut counted, mut counted_outside) = (0, 0, 0, 0);
        for round in 0..200_000 {
            let window = match round % 4 {
                0 => 0.0,
                1 | 2 => CANONICAL_WINDOW,
                _ => CANONICAL_WINDOW * 16.0 * unit(),
            };
            let size = (2.0f32).powf(-12.0 + 18.0 * unit());
            let centre = (Vec3A::new(unit(), unit(), unit()) * 2.0 - 1.0) * 600.0 * unit();
            let normal = (Vec3A::new(unit(), unit(), unit()) * 2.0 - 1.0)
                .try_normalize()
                .unwrap_or(Vec3A::Z);
            let (ta, tb) = normal.any_orthonormal_pair();
            // four coplanar triangles around the centre (some slivers), or a tilted one
            let mut tris = [[Vec3A::ZERO; 3]; LANES];
            for (j, tri) in tris.iter_mut().enumerate() {
                let in_plane = |a: f32, b: f32| centre + (ta * a + tb * b) * size;
                let (x, y) = (unit() * 4.0 - 2.0, unit() * 4.0 - 2.0);
                let sliver = if unit() < 0.2 { 1e-3 } else { 1.0 };
                *tri = [
                    in_plane(x, y),
                    in_plane(x + 1.0 + unit(), y + sliver * unit()),
                    in_plane(x + unit(), y + sliver * (1.0 + unit())),
                ];
                if j == 3 && unit() < 0.3 {
                    tri[2] += normal * size * (unit() - 0.5);
                }
            }
            // a crossing point on or near an edge of the first triangle (within a few windows),
            // or anywhere around
            let [a, b, c] = tris[0];
            let (from, to) = match round % 3 {
                0 => (a, b),
                1 => (b, c),
                _ => (c, a),
            };
            let on_edge = from.lerp(to, unit());
            let out = (to - from).cross(normal).normalize_or_zero();
            let point = if unit() < 0.8 {
                on_edge + out * window.max(1e-4) * (unit() * 4.0 - 1.5)
            } else {
                centre + (ta * unit() + tb * unit()) * size * 3.0
            };
            // steep to grazing, either side
            let cos = (2.0f32).powf(-14.0 * unit()) * if unit() < 0.5 { -1.0 } else { 1.0 };
            let side = ta * (unit() - 0.5) + tb * (unit() - 0.5);
            let dir =
                (normal * cos + side.normalize_or_zero() * (1.0 - cos * cos).sqrt()).normalize();
            // the crossing near the start, or near the end, at a few windows from it
            let len = if round % 5 == 0 {
                f32::INFINITY
            } else {
                8.0 * window + 300.0 * unit()
            };
            let along = window.max(1e-4) * (unit() * 6.0 - 3.0);
            let origin = if len.is_finite() && unit() < 0.4 {
                point - dir * (len + along)
            } else {
                point - dir * along
            };
            let q = Query::new(
                origin,
                dir,
                len,
                window,
                if len.is_finite() { window } else { 0.0 },
            );
            let mut p = Packet {
                v0: [Vec4::ZERO; 3],
                e1: [Vec4::ZERO; 3],
                e2: [Vec4::ZERO; 3],
                ids: [0; LANES],
            };
            for (j, [v0, v1, v2]) in tris.iter().enumerate() {
                let (e1, e2) = (*v0 - *v1, *v2 - *v0);
                for k in 0..3 {
                    p.v0[k][j] = v0[k];
                    p.e1[k][j] = e1[k];
                    p.e2[k][j] = e2[k];
                }
            }
            let far = Outside::of(&p, &q).beyond(q.lanes.far);
            for j in 0..LANES {
                let exact = refine(&p.lane(j), &q);
                // the exact distance of the line's crossing from the triangle, where it crosses
                let lane = p.lane(j);
                let (v0, e1, e2) = (lane.v0.as_dvec3(), -lane.e1.as_dvec3(), lane.e2.as_dvec3());
                let crossing = exact::crossing(v0, e1, e2, q.origin.as_dvec3(), q.dir.as_dvec3());
                let outside_by = |margin: f64| crossing.is_some_and(|c| !c.within(margin));
                if far >> j & 1 != 0 {
                    assert!(
                        exact.is_none(),
                        "round {round} lane {j}: dropped, but the exact rules count it"
                    );
                    dropped += 1;
                    close += usize::from(!outside_by(4.0 * f64::from(window.max(1e-4))));
                } else if exact.is_some() {
                    counted += 1;
                    counted_outside += usize::from(crossing.is_some_and(|c| !c.inside()));
                }
            }
        }
        // the test sees both sides of the bound, and crossings just outside it
        assert!(
            dropped > 100_000 && close > 10_000 && counted > 30_000 && counted_outside > 5_000,
            "{dropped} dropped ({close} within 4 windows), {counted} counted \
             ({counted_outside} outside their triangle)"
        );
    }

    /// The window of origins near the scene's centre (`CANONICAL_EPSILON`).
    const CANONICAL_WINDOW: f32 = crate::CANONICAL_EPSILON;
}
