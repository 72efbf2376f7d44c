//! The fast caster: an obvhs CWBVH over the canonical-frame triangles.

use std::time::Duration;

use glam::Vec3;
use obvhs::{
    BvhBuildParams,
    cwbvh::{CwBvh, builder::build_cwbvh_from_tris},
    ray::{Ray as ObRay, RayHit},
    rt_triangle::RtTriangle,
    triangle::Triangle,
};

use crate::{
    BuildError, Hit, NO_ID, Ray, RayCaster, SurfacePoint,
    exact,
    frame::{self, CanonicalRay, Frame, WorldRay},
};

/// How much build time to spend on BVH quality (obvhs presets).
///
/// Measured on a 2-core machine for 100k triangles: `Fast` ~60 ms, `Medium` ~70-230 ms,
/// `Slow` ~150-430 ms; traversal differs by about 10%.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BvhPreset {
    /// `BvhBuildParams::fast_build()`: for scenes rebuilt often.
    Fast,
    /// `BvhBuildParams::medium_build()`: the default; about Embree's build time.
    #[default]
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
    /// The hierarchy; its leaves index `tris` and `ids` directly (BVH order).
    cwbvh: CwBvh,
    /// Canonical triangles in BVH order (slot `i` is leaf slot `i`).
    tris: Vec<RtTriangle>,
    /// Caller's primitive id of each slot, in BVH order.
    ids: Vec<u32>,
    /// World <-> canonical map.
    frame: Frame,
    /// World bounds (min, max) of all input vertices.
    bounds: (Vec3, Vec3),
    /// Number of input triangles.
    triangle_count: usize,
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
    /// front), triangle `i` tagged with `ids[i]`, using [`BvhPreset::Medium`].
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
            .iter()
            .map(|t| Triangle {
                v0: frame.to_canonical(t[0]).into(),
                v1: frame.to_canonical(t[1]).into(),
                v2: frame.to_canonical(t[2]).into(),
            })
            .collect();
        let cwbvh = build_cwbvh_from_tris(&canonical, preset.params(), &mut Duration::default());
        // With spatial pre-splits a triangle may appear in several slots; that is fine.
        let tris = cwbvh
            .primitive_indices
            .iter()
            .map(|&i| RtTriangle::from(&canonical[i as usize]))
            .collect();
        let ids = cwbvh.primitive_indices.iter().map(|&i| ids[i as usize]).collect();
        Ok(Bvh { cwbvh, tris, ids, frame, bounds, triangle_count: triangles.len() })
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

    /// [`CANONICAL_EPSILON`](crate::CANONICAL_EPSILON) in scene units: the minimum hit distance
    /// of surface rays and the smallest origin offset.
    pub fn surface_epsilon(&self) -> f32 {
        self.frame.world_epsilon() as f32
    }

    /// Closest hit in canonical units: (BVH slot, t).
    #[inline]
    fn trace(&self, ray: &CanonicalRay, exclude: u32) -> Option<(usize, f32)> {
        let r = ObRay::new(ray.origin, ray.dir, ray.tmin, f32::INFINITY);
        let tmin = ray.tmin;
        let near = |_: f32| false;
        let mut hit = RayHit::none();
        let found = if exclude == NO_ID {
            self.cwbvh.ray_traverse(r, &mut hit, |r, slot| {
                intersect(&self.tris[slot], r, tmin, r.tmax, near)
            })
        } else {
            self.cwbvh.ray_traverse(r, &mut hit, |r, slot| {
                if self.ids[slot] == exclude {
                    f32::INFINITY
                } else {
                    intersect(&self.tris[slot], r, tmin, r.tmax, near)
                }
            })
        };
        found.then_some((hit.primitive_id as usize, hit.t))
    }
}

/// Queries whose origin lies within this distance (canonical units) of a triangle's plane, or
/// whose segment end is this close (in `t`) to the crossing, are re-decided in `f64`
/// (64 surface offsets, about `6e-5` of the scene).
const NEAR: f32 = 1.0 / 16.0;

/// Barycentric slack of the `f32` test below which a near crossing is re-decided in `f64`.
const SLACK: f32 = 1.0 / 256.0;

/// The `f32` Möller-Trumbore test (as obvhs's `RtTriangle::intersect`, closed edges), except
/// that a crossing of a plane passing within `NEAR` of the origin (or, for `near_end`, a
/// crossing near the segment's end), within `SLACK` of the triangle, is re-decided exactly.
///
/// Far from the origin `f32` errors only matter on measure-zero sets (shared edges,
/// silhouettes). Next to it they are systematic: an origin on a patch edge next to another
/// surface sits within rounding of that surface's plane, and for a ray almost parallel to a
/// plane the `f32` barycentrics err by about `2^-24 * size / cos`. Returns `t` or `INFINITY`.
#[inline(always)]
fn intersect(
    tri: &RtTriangle,
    r: &ObRay,
    tmin: f32,
    tmax: f32,
    near_end: impl Fn(f32) -> bool,
) -> f32 {
    let c = tri.v0 - r.origin;
    let q = r.direction.cross(c);
    let inv_det = 1.0 / tri.ng.dot(r.direction);
    let u = q.dot(tri.e2) * inv_det;
    let v = q.dot(tri.e1) * inv_det;
    let w = 1.0 - u - v;
    // plane distance of the origin, times |ng|
    let plane = tri.ng.dot(c);
    let t = plane * inv_det;
    let near = plane * plane < NEAR * NEAR * tri.ng.length_squared() || near_end(t);
    if !near {
        return if u >= 0.0 && v >= 0.0 && w >= 0.0 && t >= tmin && t <= tmax {
            t
        } else {
            f32::INFINITY
        };
    }
    if u > -SLACK && v > -SLACK && w > -SLACK {
        return refine(tri, r, tmin, tmax);
    }
    f32::INFINITY
}

/// The exact re-check of [`intersect`] on the same canonical data.
#[cold]
#[inline(never)]
fn refine(tri: &RtTriangle, r: &ObRay, tmin: f32, tmax: f32) -> f32 {
    // RtTriangle: e1 = v0 - v1, e2 = v2 - v0
    let ray = WorldRay {
        origin: r.origin.as_dvec3(),
        dir: r.direction.as_dvec3(),
        tmin: tmin as f64,
        tmax: tmax as f64,
    };
    match exact::intersect(tri.v0.as_dvec3(), -tri.e1.as_dvec3(), tri.e2.as_dvec3(), &ray) {
        Some((t, _)) => (t as f32).clamp(tmin, tmax),
        None => f32::INFINITY,
    }
}

impl RayCaster for Bvh {
    fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let c = self.frame.canonical_ray(ray)?;
        let (slot, t) = self.trace(&c, ray.exclude)?;
        let tri = &self.tris[slot];
        // RtTriangle::ng = (v0 - v1) x (v2 - v0) = -(counter-clockwise normal)
        let front = c.dir.dot(tri.ng) > 0.0;
        let canonical_point = c.origin.as_dvec3() + c.dir.as_dvec3() * t as f64;
        Some(Hit {
            id: self.ids[slot],
            distance: (t as f64 * self.frame.inv_scale()) as f32,
            point: self.frame.to_world(canonical_point),
            front,
        })
    }

    fn occluded(&self, a: &SurfacePoint, b: &SurfacePoint) -> bool {
        let Some(s) = self.frame.canonical_segment(a, b) else {
            return false;
        };
        let r = ObRay::new(s.origin, s.dir, s.tmin, s.tmax);
        let (ia, ib) = (a.id, b.id);
        let (tmin, tmax) = (s.tmin, s.tmax);
        let near = |t: f32| (t - tmax).abs() < NEAR;
        !self.cwbvh.ray_traverse_miss(r, |r, slot| {
            let id = self.ids[slot];
            if id == ia || id == ib {
                f32::INFINITY
            } else {
                intersect(&self.tris[slot], r, tmin, tmax, near)
            }
        })
    }
}

// `Bvh` is shared across threads by reference.
const _: () = {
    const fn send_sync<T: Send + Sync>() {}
    send_sync::<Bvh>();
};
