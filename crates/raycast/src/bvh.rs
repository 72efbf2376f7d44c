//! The fast caster: an obvhs CWBVH over the canonical-frame triangles.

use std::cell::Cell;

use glam::{Vec3, Vec3A};
use obvhs::{
    BvhBuildParams,
    aabb::Aabb,
    bvh2::reinsertion::ReinsertionOptimizer,
    cwbvh::{CwBvh, bvh2_to_cwbvh::bvh2_to_cwbvh},
    ploc::PlocBuilder,
    rt_triangle::RtTriangle,
    splits::split_aabbs_preset,
    triangle::Triangle,
};
use rayon::prelude::*;

use crate::{
    BuildError, Hit, Ray, RayCaster, SurfacePoint, batch, exact,
    frame::{self, CanonicalRay, CanonicalSegment, Frame, WorldRay},
    traverse::{self, NodeRay},
    tri::Tri,
};

/// How much build time to spend on BVH quality (obvhs presets).
///
/// With this crate's traversal the presets give the same speed on the scenes of the Embree
/// comparison (`/work/shared/bench/raycast`, rooms of 100k and 1M triangles: the same node
/// visits and triangle tests per ray within 3%, the same Mrays/s within noise), while `Fast`
/// builds about 15% faster than `Medium` (1M triangles, 2 threads). Hits do not depend on the
/// preset: padded boxes and the order-independent tie rule make the closest hit that of all
/// triangles, whatever the tree.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BvhPreset {
    /// `BvhBuildParams::fast_build()`: the default.
    #[default]
    Fast,
    /// `BvhBuildParams::medium_build()`: a longer PLOC search and more reinsertion.
    Medium,
    /// `BvhBuildParams::slow_build()`: spatial pre-splits of large triangles (a triangle may
    /// sit in several leaves), for long runs on scenes with big triangles.
    Slow,
}

impl BvhPreset {
    fn params(self) -> BvhBuildParams {
        match self {
            BvhPreset::Fast => BvhBuildParams::fast_build(),
            BvhPreset::Medium => BvhBuildParams::medium_build(),
            BvhPreset::Slow => BvhBuildParams::slow_build(),
        }
    }
}

/// A bounding volume hierarchy over tagged triangles (obvhs 8-wide compressed BVH), built in
/// the canonical frame (see the crate documentation). Immutable once built; `Send + Sync`.
pub struct Bvh {
    /// The hierarchy; its leaves index `tris` directly (BVH order). Its `primitive_indices`
    /// are dropped after the build.
    cwbvh: CwBvh,
    /// Canonical triangles with their ids, in BVH order (slot `i` is leaf slot `i`).
    tris: Vec<Tri>,
    /// World <-> canonical map.
    frame: Frame,
    /// World bounds (min, max) of all input vertices.
    bounds: (Vec3, Vec3),
    /// Number of input triangles.
    triangle_count: usize,
    /// Traversal stack entries needed (see [`traverse::stack_bound`]).
    stack: usize,
}

impl std::fmt::Debug for Bvh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bvh")
            .field("triangles", &self.triangle_count)
            .field("slots", &self.tris.len())
            .field("nodes", &self.cwbvh.nodes.len())
            .field("bounds", &self.bounds)
            .field("scale", &self.frame.scale())
            .finish()
    }
}

impl Bvh {
    /// Builds a BVH over `triangles` (vertices in scene units, counter-clockwise seen from the
    /// front), triangle `i` tagged with `ids[i]`, using [`BvhPreset::Fast`] (the default).
    ///
    /// Errors: empty input, `ids.len() != triangles.len()`, a NaN or infinite vertex, an id
    /// equal to [`NO_ID`]. Degenerate triangles are accepted (and never hit).
    pub fn build(triangles: &[[Vec3; 3]], ids: &[u32]) -> Result<Bvh, BuildError> {
        Bvh::build_with(triangles, ids, BvhPreset::default())
    }

    /// [`Bvh::build`] with an explicit quality preset. The build runs in parallel on the
    /// current rayon pool.
    pub fn build_with(
        triangles: &[[Vec3; 3]],
        ids: &[u32],
        preset: BvhPreset,
    ) -> Result<Bvh, BuildError> {
        let bounds = frame::validate(triangles, ids)?;
        let frame = Frame::new(bounds.0, bounds.1);
        let canonical: Vec<Triangle> = triangles
            .par_iter()
            .map(|t| Triangle {
                v0: frame.canonical(t[0]).into(),
                v1: frame.canonical(t[1]).into(),
                v2: frame.canonical(t[2]).into(),
            })
            .collect();
        let pad = frame.max_lift(bounds.0, bounds.1) as f32;
        let mut cwbvh = build_cwbvh_padded(&canonical, preset.params(), pad);
        if cwbvh.primitive_indices.len() > traverse::MAX_SLOTS {
            return Err(BuildError::TooManyTriangles {
                slots: cwbvh.primitive_indices.len(),
            });
        }
        // With spatial pre-splits a triangle may appear in several slots; that is fine.
        let tris = cwbvh
            .primitive_indices
            .par_iter()
            .map(|&i| Tri::new(&RtTriangle::from(&canonical[i as usize]), ids[i as usize]))
            .collect();
        // The leaves index `tris` directly: the map back to input order is not needed.
        cwbvh.primitive_indices = Vec::new();
        cwbvh.nodes.shrink_to_fit();
        let stack = traverse::stack_bound(&cwbvh.nodes);
        Ok(Bvh {
            stack,
            cwbvh,
            tris,
            frame,
            bounds,
            triangle_count: triangles.len(),
        })
    }

    /// Number of input triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangle_count
    }

    /// Bounds `(min, max)` of all input vertices, in scene units.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    /// Number of 8-wide BVH nodes (a size and quality statistic).
    pub fn node_count(&self) -> usize {
        self.cwbvh.nodes.len()
    }

    /// Bytes of memory the caster holds for intersection: the BVH nodes (80 bytes each), the
    /// triangle records (64 bytes per leaf slot, id included) and any index arrays (none are
    /// kept after the build), counted by allocated capacity, plus the struct itself. Divide by
    /// [`Bvh::triangle_count`] for the footprint per triangle (about 72 bytes). The per-thread
    /// traversal stack (a few hundred bytes) is not counted.
    pub fn memory_bytes(&self) -> usize {
        use std::mem::size_of_val;
        size_of_val(self)
            + self.cwbvh.nodes.capacity() * size_of::<obvhs::cwbvh::node::CwBvhNode>()
            + self.cwbvh.primitive_indices.capacity() * size_of::<u32>()
            + self
                .cwbvh
                .exact_node_aabbs
                .as_ref()
                .map_or(0, |v| v.capacity() * size_of::<Aabb>())
            + self.tris.capacity() * size_of::<Tri>()
    }

    /// Whether nodes and triangles are small enough to stay in the caches, where sorting a
    /// batch costs more than it saves.
    fn fits_in_cache(&self) -> bool {
        self.memory_bytes() <= batch::CACHED_BYTES
    }

    /// [`CANONICAL_EPSILON`](crate::CANONICAL_EPSILON) in scene units: the smallest origin
    /// offset and window (about `1e-6` of the scene's largest extent).
    pub fn surface_epsilon(&self) -> f32 {
        self.frame.world_epsilon() as f32
    }

    /// Closest hit in canonical units: (BVH slot, distance from the lifted origin).
    #[inline]
    fn trace(&self, ray: &CanonicalRay, exclude: u32) -> Option<(usize, f32)> {
        let CanonicalRay {
            origin,
            dir,
            window,
            ..
        } = *ray;
        // Start the traversal behind the origin so that the boxes of crossings in the window
        // around it are entered whatever the rounding. Returned values are `t + shift`.
        let shift = 2.0 * window;
        let r = NodeRay::new(origin - dir * shift, dir, 0.0, f32::INFINITY);
        let q = Query::new(origin, dir, f32::INFINITY, window, 0.0);
        let test = |slot: usize| {
            let tri = &self.tris[slot];
            let id = tri.id();
            if id == exclude {
                (f32::INFINITY, id)
            } else {
                let t = candidate::<false>(tri, &q).map_or(f32::INFINITY, |t| t + shift);
                (t, id)
            }
        };
        let found = self
            .with_stack(|stack| traverse::closest(&self.cwbvh.nodes, &self.tris, &r, stack, test));
        found.map(|(slot, t)| (slot, (t - shift).max(0.0)))
    }

    /// Runs `f` with a traversal stack of at least `self.stack` entries: a per-thread buffer,
    /// reused, so that no query allocates or clears one.
    #[inline(always)]
    fn with_stack<R>(&self, f: impl FnOnce(&mut [traverse::Entry]) -> R) -> R {
        STACK.with(|cell| {
            let mut stack = cell.take();
            if stack.len() < self.stack {
                stack.resize(self.stack, (0.0, 0));
            }
            let result = f(&mut stack);
            cell.set(stack);
            result
        })
    }
}

thread_local! {
    /// The traversal stack of this thread's queries (see [`Bvh::with_stack`]).
    static STACK: Cell<Vec<traverse::Entry>> = const { Cell::new(Vec::new()) };
}

/// `obvhs::cwbvh::builder::build_cwbvh_from_tris` (PLOC, reinsertion, BVH2 -> CWBVH, optional
/// spatial pre-splits) with every primitive box padded by `pad` canonical units.
///
/// The padding is the largest window of the scene (see [`exact::ray_rule`]): a ray starting
/// exactly at a corner of flat, axis-aligned boxes (a room's corner) only touches them in a
/// point, which the `f32` slab test may miss, and would then leave through the wall it starts
/// on. Padded, every box whose triangle is crossed within a window holds a stretch of the ray
/// of at least half a window. The cost is nil for scenes near the origin (`2^-10` canonical
/// units).
fn build_cwbvh_padded(triangles: &[Triangle], params: BvhBuildParams, pad: f32) -> CwBvh {
    let mut aabbs: Vec<Aabb> = triangles.par_iter().map(Triangle::aabb).collect();
    let mut indices: Vec<u32> = (0..triangles.len() as u32).collect();
    if params.pre_split {
        let half_areas = aabbs.iter().map(Aabb::half_area);
        let largest = half_areas.clone().fold(0.0f32, f32::max);
        let average = half_areas.sum::<f32>() / triangles.len() as f32;
        split_aabbs_preset(&mut aabbs, &mut indices, triangles, average, largest);
    }
    let pad = Vec3A::splat(pad);
    aabbs
        .par_iter_mut()
        .for_each(|aabb| *aabb = Aabb::new(aabb.min - pad, aabb.max + pad));
    let mut bvh2 = PlocBuilder::with_capacity(aabbs.len()).build(
        params.ploc_search_distance,
        &aabbs,
        indices,
        params.sort_precision,
        params.search_depth_threshold,
    );
    bvh2.uses_spatial_splits = params.pre_split;
    ReinsertionOptimizer::default().run(&mut bvh2, params.reinsertion_batch_ratio, None);
    // children are not put in ray-octant order: our traversal sorts them by distance per ray
    bvh2_to_cwbvh(&bvh2, params.max_prims_per_leaf.clamp(1, 3), false, false)
}

/// Crossings of a plane passing within this distance (canonical units) of a query's origin,
/// or this close (in `t`) to a segment's end, are re-decided in `f64` (64 surface offsets,
/// about `6e-5` of the scene), and always within twice the query's windows.
const NEAR: f32 = 1.0 / 16.0;

/// Barycentric slack of the `f32` test within which a near crossing is re-decided in `f64`.
const SLACK: f32 = 1.0 / 256.0;

/// A ray (`len` infinite) or segment in canonical units, with the windows at its ends (see
/// [`exact::ray_rule`]) and the distances within which crossings are re-decided exactly.
#[derive(Clone, Copy, Debug)]
struct Query {
    origin: Vec3A,
    dir: Vec3A,
    len: f32,
    window_start: f32,
    window_end: f32,
    near_start: f32,
    near_end: f32,
}

impl Query {
    fn new(origin: Vec3A, dir: Vec3A, len: f32, window_start: f32, window_end: f32) -> Query {
        let near_start = NEAR.max(2.0 * window_start);
        let near_end = NEAR.max(2.0 * window_end);
        Query {
            origin,
            dir,
            len,
            window_start,
            window_end,
            near_start,
            near_end,
        }
    }
}

/// One triangle against a query, in canonical units: the distance of a crossing that counts,
/// or `None`.
///
/// `SEGMENT` is `false` for a ray (`len` infinite, no end window), which drops the tests at the
/// end: `|t - len| < 2 * window_end` never holds for it, and `|t - len| >= near_end` holds for
/// every `t` that can reach that test (finite or `-inf`; a `+inf` is rejected either way).
///
/// This is obvhs's `f32` Möller-Trumbore (`RtTriangle::intersect`, closed edges) for crossings
/// away from the query's end points. Next to them `f32` errors are systematic rather than
/// measure-zero: an origin on a patch edge next to another surface sits within rounding of
/// that surface's plane, and for a ray almost parallel to a plane the `f32` barycentrics err by
/// about `2^-24 * size / cos`. So a crossing of a plane that passes near the origin (or near
/// the segment's end), within `SLACK` of the triangle or within the windows, is re-decided
/// exactly with the rules of [`exact::ray_rule`] and [`exact::segment_rule`].
#[inline(always)]
fn candidate<const SEGMENT: bool>(tri: &Tri, q: &Query) -> Option<f32> {
    let ng = tri.ng();
    let c = tri.v0() - q.origin;
    let r = q.dir.cross(c);
    let inv_det = 1.0 / ng.dot(q.dir);
    let u = r.dot(tri.e2()) * inv_det;
    let v = r.dot(tri.e1()) * inv_det;
    let w = 1.0 - u - v;
    // signed distance of the origin to the plane, times |ng|
    let plane = ng.dot(c);
    let t = plane * inv_det;
    if !((u > -SLACK) & (v > -SLACK) & (w > -SLACK)) {
        // clearly outside (the common case): only the windows look beyond the triangle
        let in_window =
            t.abs() < 2.0 * q.window_start || (SEGMENT && (t - q.len).abs() < 2.0 * q.window_end);
        return if in_window {
            near_end_point(tri, q, t)
        } else {
            None
        };
    }
    let near_plane = plane * plane < q.near_start * q.near_start * ng.length_squared();
    if !near_plane && (!SEGMENT || (t - q.len).abs() >= q.near_end) {
        // |t| >= near_start > window_start, |t - len| >= near_end: no window rule applies
        let inside = u >= 0.0 && v >= 0.0 && w >= 0.0;
        return (inside && t > 0.0 && t < q.len).then_some(t);
    }
    near_end_point(tri, q, t)
}

/// [`candidate`] for a crossing near one of the query's end points (or of a plane passing near
/// its origin). Skips what the rules reject whatever the exact numbers: crossings well behind
/// the start or past the end, back-facing ones in the start's window and front-facing ones in
/// the end's window (the `f32` side is wrong only when the ray is almost parallel to the
/// plane). Re-decides the rest exactly.
#[cold]
#[inline(never)]
fn near_end_point(tri: &Tri, q: &Query, t: f32) -> Option<f32> {
    let (ws, we) = (q.window_start, q.window_end);
    if t <= -2.0 * ws || t >= q.len + 2.0 * we {
        return None;
    }
    // RtTriangle::ng is minus the counter-clockwise normal
    let front = tri.ng().dot(q.dir) > 0.0;
    let in_start = t < 2.0 * ws;
    let in_end = t > q.len - 2.0 * we;
    if (in_start && !front && t < 0.5 * ws) || (in_end && front && t > q.len - 0.5 * we) {
        return None;
    }
    refine(tri, q)
}

/// The exact re-check of [`candidate`] on the same canonical data.
#[cold]
#[inline(never)]
fn refine(tri: &Tri, q: &Query) -> Option<f32> {
    let ray = WorldRay {
        origin: q.origin.as_dvec3(),
        dir: q.dir.as_dvec3(),
        len: q.len as f64,
        window_start: q.window_start as f64,
        window_end: q.window_end as f64,
    };
    // RtTriangle: e1 = v0 - v1, e2 = v2 - v0
    let (v0, e1, e2) = (
        tri.v0().as_dvec3(),
        -tri.e1().as_dvec3(),
        tri.e2().as_dvec3(),
    );
    if q.len.is_finite() {
        exact::blocker(v0, e1, e2, &ray).map(|_| 0.0)
    } else {
        exact::ray_candidate(v0, e1, e2, &ray).map(|(t, _)| t as f32)
    }
}

impl RayCaster for Bvh {
    fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let c = self.frame.canonical_ray(ray)?;
        let (slot, t) = self.trace(&c, ray.exclude)?;
        let tri = &self.tris[slot];
        // RtTriangle::ng = (v0 - v1) x (v2 - v0) = -(counter-clockwise normal)
        let front = c.dir.dot(tri.ng()) > 0.0;
        let canonical_point = c.origin.as_dvec3() + c.dir.as_dvec3() * t as f64;
        Some(Hit {
            id: tri.id(),
            distance: ((c.skip + t as f64) * self.frame.inv_scale()) as f32,
            point: self.frame.world(canonical_point),
            front,
        })
    }

    /// [`RayCaster::closest_hit`] for each ray, visited in a cache-friendly order (sorted by
    /// origin and direction, see the `batch` module) for batches of 256 rays or more on scenes
    /// whose BVH outgrows the caches (over 2 MiB, about 30k triangles); the results are the
    /// same as one by one.
    fn closest_hit_batch(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        let n = rays.len().min(hits.len());
        if n < batch::MIN_SORTED || self.fits_in_cache() {
            for (ray, hit) in rays.iter().zip(hits) {
                *hit = self.closest_hit(ray);
            }
            return;
        }
        let keys = rays[..n]
            .iter()
            .map(|r| batch::key(self.bounds, r.origin, r.dir));
        for i in batch::order(keys) {
            let i = i as usize;
            hits[i] = self.closest_hit(&rays[i]);
        }
    }

    /// [`RayCaster::occluded`] for each pair, in the cache-friendly order of
    /// [`Bvh::closest_hit_batch`] (by the first point and the direction to the second).
    fn occluded_batch(&self, pairs: &[(SurfacePoint, SurfacePoint)], out: &mut [bool]) {
        let n = pairs.len().min(out.len());
        if n < batch::MIN_SORTED || self.fits_in_cache() {
            for ((a, b), o) in pairs.iter().zip(out) {
                *o = self.occluded(a, b);
            }
            return;
        }
        let keys = pairs[..n]
            .iter()
            .map(|(a, b)| batch::key(self.bounds, a.point, b.point - a.point));
        for i in batch::order(keys) {
            let i = i as usize;
            out[i] = self.occluded(&pairs[i].0, &pairs[i].1);
        }
    }

    fn occluded(&self, a: &SurfacePoint, b: &SurfacePoint) -> bool {
        let Some(s) = self.frame.canonical_segment(a, b) else {
            return false;
        };
        let CanonicalSegment {
            origin,
            dir,
            len,
            window_start,
            window_end,
        } = s;
        let q = Query::new(origin, dir, len, window_start, window_end);
        // as in `trace`: start behind the origin; any blocker reports `shift` (< tmax)
        let shift = 2.0 * window_start;
        let r = NodeRay::new(
            origin - dir * shift,
            dir,
            0.0,
            len + window_end + 2.0 * shift,
        );
        let (ia, ib) = (a.id, b.id);
        let test = |slot: usize| {
            let id = self.tris[slot].id();
            id != ia && id != ib && candidate::<true>(&self.tris[slot], &q).is_some()
        };
        self.with_stack(|stack| traverse::any(&self.cwbvh.nodes, &self.tris, &r, stack, test))
    }
}

// `Bvh` is shared across threads by reference.
const _: () = {
    const fn send_sync<T: Send + Sync>() {}
    send_sync::<Bvh>();
};
