//! Ray casting against tagged triangles: closest hit and point-to-point visibility.
//!
//! This crate knows nothing of radiosity. It holds triangles, each tagged with a caller's `u32`
//! id (many triangles may share one id: a polygonal patch made of several coplanar triangles),
//! and answers two questions through the [`RayCaster`] trait: *what does this ray hit first?*
//! and *is anything between these two surface points?* [`Bvh`] answers them fast (obvhs's
//! PLOC build, collapsed into this crate's 16-wide BVH with 4-triangle leaf packets and walked
//! by its own SIMD traversal: see *Speed* below);
//! [`BruteForce`] answers them slowly in `f64` and is the test oracle.
//! Both report hits on either side of a triangle ([`Hit::front`] tells which) and never report
//! the id a query excludes.
//!
//! Distances, points and bounds are in **scene units** (whatever the input uses), and a
//! distance is Euclidean: the casters normalise directions.
//!
//! # The canonical frame
//!
//! obvhs 0.4 has unit-dependent behaviour (measured in the Embree comparison, `benches/embree/`): its CWBVH
//! node test clamps the entry distance to `t >= 1e-4` whatever the ray's `tmin`, so hits closer
//! than `1e-4` *units* are lost (a Cornell box modelled in metres at millimetre scale loses
//! hits, one in kilometres does not); and a ray starting on its own triangle with `tmin = 0`
//! hits it again 35-79% of the time, while any fixed offset is too large for a small scene or
//! too small for a big one.
//!
//! So [`Bvh::build`] maps the scene into a *canonical frame*: it translates by the centre of
//! the bounding box (rounded to `f32`) and scales by a power of two `s` so that the largest side
//! lies in `[512, 1024)`. A power-of-two scale is exact, and the map is evaluated with one
//! rounding to `f32` (in `f64`, or in `f32` on the hot path of a query, which gives the same
//! point since centre and scale are exact in `f32`), so the same world point always lands on the
//! same canonical point (shared vertices stay shared). Queries move their origin into the frame
//! (a unit direction is unchanged; canonical `t` = `distance * s`) and hits come back in world
//! units. A scene in millimetres and the same scene in kilometres see the same canonical
//! numbers, and the obvhs cut-off is about `1e-7` of the scene.
//!
//! # Surface offsets and the window around an origin
//!
//! A ray from [`Ray::from_surface`] (and each end of an [`RayCaster::occluded`] query) is
//! lifted off its surface along the given normal by
//! `lift(p) = max(CANONICAL_EPSILON, 2^-21 * max|p_i| * s)` canonical units, `p` the world
//! point: the lift is added to the canonical point (rounded like a vertex) and the sum rounded
//! to `f32` once more. [`CANONICAL_EPSILON`] is `2^-10` canonical units, about `1e-6` of the scene:
//! * 16 ulps of the largest canonical coordinate (an `f32` ulp at 512 is `2^-14`), well above
//!   the rounding of a point and of a plane test at that magnitude (a few ulps), so a lifted
//!   origin is above its own plane and those of coplanar neighbours;
//! * about 10 times the obvhs node cut-off `1e-4`;
//! * obvhs replaces a direction component `|d| <= f32::EPSILON` by `±1/f32::EPSILON` in its box
//!   test, so a ray drifts off its line by `1.2e-7 * t`, at most `2.1e-4` across the canonical
//!   diagonal (1774): the offset keeps a ray that runs along the surface it leaves inside the
//!   boxes it must enter;
//! * still small: a patch of `1e-6` of the scene's area (side `1e-3` of its extent, about one
//!   canonical unit) is a thousand offsets wide.
//!
//! The second term only matters far from the world origin, where a point given in world `f32`
//! is only known to half an ulp of its largest coordinate (`6e-4` of the extent for a scene
//! `1e4` extents away, far more than `CANONICAL_EPSILON`). The caster cannot recover what the
//! input lost, but the lift (4 such ulps) keeps such origins above their surface, so that rays
//! from a finely cut floor do not hit the coplanar neighbours of their patch. Within about two
//! extents of the world origin the lift is exactly `CANONICAL_EPSILON`.
//!
//! The lift cannot move an origin off *every* surface it is on: at the foot of a wall, the
//! floor point lifted along the floor's normal still lies in the wall's plane, within rounding.
//! A minimum hit distance would let a ray heading into the wall pass through it (and leave a
//! closed room); none would let a ray leaving the wall hit its back at distance 0. So within a
//! *window* of `lift(p)` around the origin (in `t`) the decision rests on orientation: a
//! front-facing crossing within half a window of a triangle counts, at distance `max(t, 0)`;
//! a back-facing one does not. Beyond the window a crossing counts on either side. A segment's
//! end gets the mirror-image rule. Crossings next to an end point are decided in `f64` (the
//! `f32` test's barycentrics err by about `2^-24 * size / cos` for a ray almost parallel to a
//! plane). The same rules, in world `f64`, make the [`BruteForce`] oracle.
//!
//! # Other obvhs pitfalls handled here
//!
//! * The traversal starts two windows behind the origin, so that boxes holding crossings in the
//!   window are entered whatever the rounding of the box test (obvhs's own traversal also
//!   skipped boxes entered before `t = 1e-4`; ours does not).
//! * Primitive boxes are padded by the scene's largest window: a ray from the very corner of a
//!   room touches the flat box of a wall only in a point, which the `f32` box test may miss.
//! * A `-0.0` direction component makes obvhs's box test swap entry and exit (`-Vec3::Y` missed
//!   everything); directions are cleaned of them.
//! * The `±f32::EPSILON` drift above makes an axis-parallel ray from a camera far away miss the
//!   scene: an origin far outside the scene's box is first moved along the ray to near the box.
//! * An infinite vertex panics the obvhs build: builds reject non-finite vertices first.
//! * obvhs keeps its traversal stack in 32 fixed entries, which a pathologically deep BVH could
//!   overflow; our traversal sizes its stack from the hierarchy (the most pending siblings
//!   along any root-to-leaf path).
//!
//! # Speed
//!
//! The fast path is memory- and instruction-bound on large scenes (see `PERFORMANCE.md` for
//! measurements against Embree). [`Bvh`] keeps obvhs's builder (PLOC and reinsertion over
//! padded triangle boxes) and re-arranges its binary tree for single-ray traversal on a CPU:
//! * a 16-wide BVH with `f32` child boxes in structure-of-arrays order (448-byte nodes): the
//!   slab test of all 16 children is one AVX-512 sequence where the processor has it, two
//!   AVX2/FMA halves where it has those (detected at build time; the whole traversal is
//!   compiled for it), or four SSE quarters. Sixteen children rather than eight make the tree
//!   shallower, so a ray waits for fewer dependent cache misses on its way to a leaf;
//! * leaves of 4-triangle packets (160 bytes with their ids), tested 4 at a time, which the
//!   leaves of one node share where they fit; the leaves and the nodes' contents are the
//!   optimal collapse of obvhs's binary tree for the surface-area heuristic;
//! * children visited nearest first, every stack entry carrying its entry distance so that
//!   subtrees behind the closest hit so far are dropped without being fetched; the nearest hit
//!   child goes on without touching the stack; any-hit queries skip the sorting;
//! * the nodes and packets a node test finds are prefetched at once;
//! * nodes and packets sit on 2 MiB pages where the system offers transparent huge pages
//!   (a large scene's visits would otherwise mostly miss the address-translation cache too);
//! * on processors with AVX-512F/VL the node test is one AVX-512 register and the rest of the
//!   traversal is compiled for their 32 vector registers ([`Simd`], [`Bvh::with_simd`]).
//!
//! Memory: about 53 bytes per triangle on large scenes ([`Bvh::memory_bytes`]). Among
//! crossings at exactly the same distance the lowest id wins, so the answer does not depend on
//! the visiting order (nor on the instruction sets: every [`Simd`] level gives the same hits). The closest-hit batch
//! ([`RayCaster::closest_hit_batch`]) visits its rays sorted by origin and direction, which
//! keeps the caches warm on large scenes (same answers as one by one).
//!
//! # Watertightness is counted, not promised
//!
//! Away from its end points a ray is tested with `f32` Möller-Trumbore (obvhs's arithmetic,
//! four triangles at a time, with comparisons scaled by the determinant instead of a
//! division), which is not watertight: a ray can slip through the shared edge of two
//! triangles. Measured with obvhs
//! alone: about one ray in three million inside a closed, tessellated room escapes. The test
//! suite bounds the escape fraction at `1e-5` for rays from uniform surface points and from
//! interior points of closed boxes. Callers that need a hit (radiosity in a closed scene) must
//! count a miss as a rare event, not treat it as impossible.
//!
//! # Example
//!
//! ```
//! use glam::Vec3;
//! use mcrad_raycast::{Bvh, Ray, RayCaster, SurfacePoint};
//!
//! // a unit square on the floor (id 7, facing +Y) and one at height 1 facing down (id 8)
//! let (a, b, c, d) = (Vec3::ZERO, Vec3::X, Vec3::new(1.0, 0.0, 1.0), Vec3::Z);
//! let up = Vec3::Y;
//! let tris = [[a, d, c], [a, c, b], [a + up, b + up, c + up], [a + up, c + up, d + up]];
//! let bvh = Bvh::build(&tris, &[7, 7, 8, 8]).unwrap();
//!
//! let ray = Ray::from_surface(Vec3::new(0.5, 0.0, 0.5), Vec3::Y, Vec3::Y, 7);
//! let hit = bvh.closest_hit(&ray).unwrap();
//! assert_eq!(hit.id, 8);
//! assert!(hit.front && (hit.distance - 1.0).abs() < 1e-5);
//!
//! let p = SurfacePoint::new(Vec3::new(0.2, 0.0, 0.2), Vec3::Y, 7);
//! let q = SurfacePoint::new(Vec3::new(0.8, 1.0, 0.8), -Vec3::Y, 8);
//! assert!(!bvh.occluded(&p, &q));
//! ```
#![deny(missing_docs)]

mod batch;
mod brute;
mod bvh;
mod chunks;
mod error;
mod exact;
mod frame;
mod pages;
mod query;
mod renumbered;
mod traverse;
mod wide;

/// Helpers of the unit tests.
#[cfg(test)]
mod testing {
    use rand_core::Rng as _;
    use rand_pcg::Pcg32;

    /// A seeded stream of floats uniform in `[0, 1)`.
    pub(crate) fn uniforms(seed: u64) -> impl FnMut() -> f32 {
        let mut rng = Pcg32::new(seed, 0x0a02_bdbf_7bb3_c0a7);
        move || (rng.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }
}

use glam::Vec3;

pub use brute::BruteForce;
pub use bvh::{Bvh, BvhPreset, Simd};
pub use error::BuildError;
pub use renumbered::Renumbered;

/// The "no primitive" id: rays that exclude nothing, points on no surface. No triangle may carry
/// it ([`BuildError::ReservedId`]).
pub const NO_ID: u32 = u32::MAX;

/// The surface offset of ray origins near the world origin, and the half-width of the window
/// around them, in canonical units (`2^-10`, about `1e-6` of the scene's largest extent). See
/// the crate documentation for why this value and how it grows far from the world origin.
pub const CANONICAL_EPSILON: f32 = 1.0 / 1024.0;

/// A ray; distances along it are in scene units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Start point (scene units). For a surface ray: the point on the surface, not yet offset.
    pub origin: Vec3,
    /// Direction; should be a unit vector (the casters normalise it anyway, so hit distances are
    /// Euclidean). A zero or non-finite direction hits nothing. A direction (or normal) that is
    /// already unit to `f32` precision (squared length within `4 * f32::EPSILON` of 1, which is
    /// as close as `normalize` gets) is used as it is, so unit input costs no normalisation.
    pub dir: Vec3,
    /// Unit geometric normal of the surface the ray leaves, or `Vec3::ZERO` for a free point
    /// (a non-finite normal counts as zero). A non-zero normal makes the caster lift the origin
    /// along it (see the crate documentation).
    pub origin_normal: Vec3,
    /// Primitive id never reported as the hit ([`NO_ID`]: none).
    pub exclude: u32,
}

impl Ray {
    /// A ray from a free point (a camera): `origin_normal = ZERO`, `exclude = NO_ID`.
    pub fn new(origin: Vec3, dir: Vec3) -> Ray {
        Ray {
            origin,
            dir,
            origin_normal: Vec3::ZERO,
            exclude: NO_ID,
        }
    }

    /// A ray leaving the surface of primitive `id` at `point` (scene units), where `normal` is
    /// the unit geometric normal of that surface (`dir · normal > 0` expected). The caster
    /// offsets the origin along `normal` by its own epsilon and never reports `id` as the hit.
    pub fn from_surface(point: Vec3, normal: Vec3, dir: Vec3, id: u32) -> Ray {
        Ray {
            origin: point,
            dir,
            origin_normal: normal,
            exclude: id,
        }
    }
}

/// A surface point for visibility queries.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePoint {
    /// Position (scene units).
    pub point: Vec3,
    /// Unit geometric normal of the surface, on the side the segment leaves from (or arrives
    /// at), or `Vec3::ZERO` for a free point (no offset).
    pub normal: Vec3,
    /// Primitive id of the surface ([`NO_ID`] for a free point); never counts as a blocker.
    pub id: u32,
}

impl SurfacePoint {
    /// A point on the surface of primitive `id` with unit geometric normal `normal`.
    pub fn new(point: Vec3, normal: Vec3, id: u32) -> SurfacePoint {
        SurfacePoint { point, normal, id }
    }

    /// A point on no surface (a light or eye position): no offset, no excluded id.
    pub fn free(point: Vec3) -> SurfacePoint {
        SurfacePoint {
            point,
            normal: Vec3::ZERO,
            id: NO_ID,
        }
    }
}

/// The closest hit of a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Primitive id of the triangle hit.
    pub id: u32,
    /// Distance from the ray's (offset) origin to the hit, in scene units. For a surface ray
    /// this differs from the distance to [`Ray::origin`] by at most the offset (about `1e-6` of
    /// the scene's extent); a surface the ray starts on and walks into is hit at distance 0.
    pub distance: f32,
    /// The hit point, in scene units.
    pub point: Vec3,
    /// `true` when the ray arrives on the front side: `dir · n < 0`, with `n` the triangle's
    /// geometric normal `(v1 - v0) × (v2 - v0)` (counter-clockwise vertices seen from the
    /// front). Back-face hits are reported too; what to do with them is the caller's business.
    pub front: bool,
}

/// An any-hit test ([`Bvh::with_any_hit`]): the crossings of some triangles let a ray pass
/// (cut-out or translucent surfaces), and the ray goes on as if they were not there, for the
/// closest hit and for occlusion alike.
///
/// The answer must depend on the arguments alone (a random choice drawn from a hash of them, not
/// from a shared generator), so that the same ray gets the same hits on any thread.
pub trait AnyHit: Send + Sync {
    /// Whether the ray (or segment) along the unit `dir` passes the triangle of id `id` that it
    /// crosses at `point` (scene units). Cheap for ids that never pass: it is asked for every
    /// crossing that would otherwise count.
    fn passes(&self, id: u32, point: Vec3, dir: Vec3) -> bool;
}

/// The small visibility interface estimators use (implemented by [`Bvh`] and [`BruteForce`]).
///
/// Both methods take `&self` and the implementors are `Sync`: share one caster across threads.
pub trait RayCaster: Sync {
    /// The closest hit along the ray, whichever side it arrives on, or `None` when it escapes
    /// (or is degenerate: zero or non-finite direction or origin). Never reports `ray.exclude`.
    fn closest_hit(&self, ray: &Ray) -> Option<Hit>;

    /// `true` when something blocks the segment between `a` and `b` (neither `a.id` nor `b.id`
    /// counts as a blocker; both ends are offset like surface-ray origins). Coincident or
    /// non-finite end points are not occluded. Orientation is not checked: a segment that
    /// leaves `a` below its surface is blocked only if another primitive is in the way.
    fn occluded(&self, a: &SurfacePoint, b: &SurfacePoint) -> bool;

    /// [`RayCaster::closest_hit`] for each ray, written to `hits` (`hits[i]` for `rays[i]`;
    /// only the first `min(rays.len(), hits.len())` pairs are processed).
    fn closest_hit_batch(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        for (ray, hit) in rays.iter().zip(hits) {
            *hit = self.closest_hit(ray);
        }
    }

    /// [`RayCaster::occluded`] for each pair, written to `out` (only the first
    /// `min(pairs.len(), out.len())` pairs are processed).
    fn occluded_batch(&self, pairs: &[(SurfacePoint, SurfacePoint)], out: &mut [bool]) {
        for ((a, b), o) in pairs.iter().zip(out) {
            *o = self.occluded(a, b);
        }
    }
}
