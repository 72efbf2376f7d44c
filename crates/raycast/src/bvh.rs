//! The fast caster: obvhs's binary BVH over the canonical-frame triangles, collapsed into
//! mcrad's 16-wide layout ([`crate::wide`]).

use std::{
    cell::{Cell, RefCell},
    ops::Range,
    sync::Arc,
};

use glam::{Vec3, Vec3A};
use obvhs::{
    BvhBuildParams,
    aabb::Aabb,
    bvh2::{Bvh2, reinsertion::ReinsertionOptimizer},
    ploc::PlocBuilder,
    splits::split_aabbs_preset,
    triangle::Triangle,
};
use rayon::prelude::*;

#[cfg(target_arch = "x86_64")]
use crate::traverse::{Avx2, Avx512};
use crate::{
    AnyHit, BuildError, Hit, Ray, RayCaster, SurfacePoint, batch,
    frame::{self, CanonicalRay, CanonicalSegment, Frame},
    query::{Query, crossings, refine},
    traverse::{self, LeafTest, NodeRay, NodeTest, Sse, Stack},
    wide::{self, LANES, Wide},
};
use crate::{NO_ID, chunks};

/// Most triangles built as one binary BVH (see `chunks.rs`): larger scenes are built in
/// chunks of at most this many, so that the build's peak memory is that of a chunk plus the
/// finished BVH. A constant, so that the BVH does not depend on the thread count.
const CHUNK: usize = 1 << 18;

/// How much build time to spend on BVH quality (obvhs presets).
///
/// With this crate's traversal the presets give the same speed on the scenes of the Embree
/// comparison (`benches/embree/`, rooms of 100k and 1M triangles: the same node
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

/// The instruction sets a [`Bvh`]'s traversal is compiled for, slowest first. The answers do
/// not depend on it (the same operations on the same numbers, see [`Bvh::with_simd`]); only
/// the speed does.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Simd {
    /// Four children or triangles per SSE register (glam's `Vec4`; scalar code off x86_64):
    /// every processor.
    Portable,
    /// Eight children per vector operation of the node test with AVX2 and FMA (x86_64
    /// processors that have them).
    Avx2,
    /// All sixteen children of a node in one AVX-512F register, the rest of the traversal as
    /// with AVX2 but with 32 vector registers instead of 16 (x86_64 processors that have
    /// AVX-512F and VL).
    Avx512,
}

/// The traversal a [`Bvh`] runs, holding the proof that the processor can.
#[derive(Clone, Copy, Debug)]
enum NodeTestChoice {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2(Avx2),
    /// The AVX-512 node test (the processor has AVX2 and FMA too).
    #[cfg(target_arch = "x86_64")]
    Avx512(Avx512),
}

impl NodeTestChoice {
    /// The fastest this processor runs, up to `most`.
    fn fastest(most: Simd) -> NodeTestChoice {
        #[cfg(target_arch = "x86_64")]
        if let Some(isa) = Avx2::detect() {
            if most >= Simd::Avx512
                && let Some(isa) = Avx512::detect()
            {
                return NodeTestChoice::Avx512(isa);
            }
            if most >= Simd::Avx2 {
                return NodeTestChoice::Avx2(isa);
            }
        }
        let _ = most;
        NodeTestChoice::Portable
    }
}

/// A bounding volume hierarchy over tagged triangles (obvhs's PLOC build, collapsed into an
/// 16-wide BVH with leaves of 4-triangle packets), built in the canonical frame (see the crate
/// documentation). Immutable once built; `Send + Sync`.
pub struct Bvh {
    /// The hierarchy, with the canonical triangles and their ids in its leaf packets.
    wide: Wide,
    /// The traversal in use.
    node_test: NodeTestChoice,
    /// World <-> canonical map.
    frame: Frame,
    /// World bounds (min, max) of all input vertices.
    bounds: (Vec3, Vec3),
    /// Number of input triangles.
    triangle_count: usize,
    /// The crossings that let rays pass, if any (see [`Bvh::with_any_hit`]).
    any_hit: Option<Arc<dyn AnyHit>>,
    /// The back-side ids of two-sided triangles, if any (see [`Bvh::with_back_sides`]).
    sides: Option<Arc<Sides>>,
}

/// The id tables of two-sided triangles (dense, indexed by id).
#[derive(Debug)]
struct Sides {
    /// `back[id]`: the back-side id of the triangles tagged `id`, or `NO_ID`.
    back: Vec<u32>,
    /// `front[id]`: for a back-side id, the id of its triangles; `NO_ID` for other ids.
    front: Vec<u32>,
}

impl Sides {
    /// The id the triangles of `id` carry: `id` itself unless it is a back-side id.
    #[inline]
    fn triangle_of(&self, id: u32) -> u32 {
        match self.front.get(id as usize) {
            Some(&f) if f != NO_ID => f,
            _ => id,
        }
    }

    /// The back-side id of the triangles tagged `id`, if they are two-sided.
    #[inline]
    fn back_of(&self, id: u32) -> Option<u32> {
        self.back.get(id as usize).copied().filter(|&b| b != NO_ID)
    }
}

impl std::fmt::Debug for Bvh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bvh")
            .field("triangles", &self.triangle_count)
            .field("packets", &self.wide.packets.len())
            .field("nodes", &self.wide.nodes.len())
            .field("stack", &self.wide.stack)
            .field("bounds", &self.bounds)
            .field("scale", &self.frame.scale())
            .field("any_hit", &self.any_hit.is_some())
            .field("two_sided", &self.sides.is_some())
            .finish()
    }
}

impl Bvh {
    /// Builds a BVH over `triangles` (vertices in scene units, counter-clockwise seen from the
    /// front), triangle `i` tagged with `ids[i]`, using [`BvhPreset::Fast`] (the default).
    ///
    /// Errors: empty input, `ids.len() != triangles.len()`, a NaN or infinite vertex, an id
    /// equal to [`NO_ID`](crate::NO_ID), a scene so far from the origin for its size that
    /// `f32` cannot place points on it ([`BuildError::FarFromOrigin`]: farther than about
    /// `2^31` times its extent). Degenerate triangles are accepted (and never hit).
    pub fn build(triangles: &[[Vec3; 3]], ids: &[u32]) -> Result<Bvh, BuildError> {
        Bvh::build_with(triangles, ids, BvhPreset::default())
    }

    /// [`Bvh::build`] with an explicit quality preset. The build runs in parallel on the
    /// current rayon pool. Scenes of more than 2^18 triangles are built in spatially sorted
    /// chunks of at most that many, joined under a common top (so the build's memory beyond
    /// the finished BVH is about that of one chunk); the result does not depend on the thread
    /// count.
    pub fn build_with(
        triangles: &[[Vec3; 3]],
        ids: &[u32],
        preset: BvhPreset,
    ) -> Result<Bvh, BuildError> {
        Bvh::build_from(triangles.len(), |i| triangles[i], ids, preset)
    }

    /// [`Bvh::build`] over indexed triangles: triangle `i` has the vertices
    /// `positions[triangles[i][k]]` (scene units) and the id `ids[i]`. The same BVH as
    /// [`Bvh::build`] of those vertices, built without a copy of them (36 bytes per triangle
    /// less at the build's peak).
    ///
    /// Errors: those of [`Bvh::build`], and a vertex index past `positions`
    /// ([`BuildError::VertexIndex`]).
    pub fn build_indexed(
        positions: &[Vec3],
        triangles: &[[u32; 3]],
        ids: &[u32],
    ) -> Result<Bvh, BuildError> {
        for (triangle, t) in triangles.iter().enumerate() {
            if let Some(&index) = t.iter().find(|&&v| v as usize >= positions.len()) {
                return Err(BuildError::VertexIndex {
                    triangle,
                    index,
                    positions: positions.len(),
                });
            }
        }
        Bvh::build_from(
            triangles.len(),
            |i| triangles[i].map(|v| positions[v as usize]),
            ids,
            BvhPreset::default(),
        )
    }

    /// [`Bvh::build_with`] of the `count` triangles `triangle(i)`.
    fn build_from(
        count: usize,
        triangle: impl Fn(usize) -> [Vec3; 3] + Sync,
        ids: &[u32],
        preset: BvhPreset,
    ) -> Result<Bvh, BuildError> {
        Bvh::build_chunked(count, triangle, ids, preset, CHUNK)
    }

    /// [`Bvh::build_from`] in chunks of at most `chunk` triangles (more than 8; see
    /// `chunks.rs`); a scene of at most one chunk is built as one.
    fn build_chunked(
        count: usize,
        triangle: impl Fn(usize) -> [Vec3; 3] + Sync,
        ids: &[u32],
        preset: BvhPreset,
        chunk: usize,
    ) -> Result<Bvh, BuildError> {
        let bounds = frame::validate_with(count, &triangle, ids)?;
        let frame = Frame::new(bounds.0, bounds.1);
        frame.check_lift(bounds.0, bounds.1)?;
        let pad = frame.max_lift(bounds.0, bounds.1) as f32;
        let wide = if count > chunk {
            chunks::build(count, &triangle, ids, &frame, pad, preset.params(), chunk)
        } else {
            let canonical: Vec<Triangle> = (0..count)
                .into_par_iter()
                .map(&triangle)
                .map(|t| Triangle {
                    v0: frame.canonical(t[0]).into(),
                    v1: frame.canonical(t[1]).into(),
                    v2: frame.canonical(t[2]).into(),
                })
                .collect();
            let bvh2 = build_bvh2_padded(&canonical, preset.params(), pad);
            let collapsed = Wide::collapse(&bvh2, &canonical, ids);
            // The binary BVH and the triangles go before the wide one is joined and copied
            // onto its pages (about 115 bytes a triangle less at the build's peak).
            drop((bvh2, canonical));
            collapsed.assemble()
        };
        if wide.packets.len() > wide::MAX_PACKETS {
            return Err(BuildError::TooManyTriangles {
                slots: wide.packets.len() * LANES,
            });
        }
        Ok(Bvh {
            wide,
            node_test: NodeTestChoice::fastest(Simd::Avx512),
            frame,
            bounds,
            triangle_count: count,
            any_hit: None,
            sides: None,
        })
    }

    /// This BVH with an any-hit test: every crossing that would count (the closest so far, or
    /// a blocker of a segment) is first offered to `test`, and ignored where it lets the ray
    /// pass (see [`AnyHit`]). A BVH without one (the default) pays nothing for it.
    pub fn with_any_hit(self, test: Arc<dyn AnyHit>) -> Bvh {
        Bvh {
            any_hit: Some(test),
            ..self
        }
    }

    /// This BVH with two-sided triangles: each pair `(front, back)` makes the triangles tagged
    /// `front` two-sided, their back side a surface of its own with id `back`. A ray that
    /// arrives on the back of such a triangle reports [`Hit::id`] `back` and [`Hit::front`]
    /// `true` (it meets the front of the back side); a ray or segment end that excludes either
    /// id excludes both (a ray leaving one side never hits the other). The triangles stay one
    /// per surface in the hierarchy, so the two sides never race for a hit. The any-hit test,
    /// if any, is asked with the triangles' id (`front`). A BVH without pairs pays nothing;
    /// with them, two table look-ups per query (8 bytes per id up to the largest).
    ///
    /// Errors ([`BuildError::BadBackSide`]): an id equal to [`NO_ID`](crate::NO_ID), a pair of
    /// equal ids, an id in two pairs, an id beyond `4 * triangle_count + 1024`. An empty
    /// list leaves the BVH one-sided.
    pub fn with_back_sides(self, pairs: &[(u32, u32)]) -> Result<Bvh, BuildError> {
        if pairs.is_empty() {
            return Ok(Bvh {
                sides: None,
                ..self
            });
        }
        let limit = 4 * self.triangle_count as u64 + 1024;
        let mut len = 0usize;
        for (pair, &(front, back)) in pairs.iter().enumerate() {
            let bad = |reason| BuildError::BadBackSide {
                pair,
                front,
                back,
                reason,
            };
            if front == NO_ID || back == NO_ID {
                return Err(bad("an id is NO_ID"));
            }
            if front == back {
                return Err(bad("the two ids are equal"));
            }
            if u64::from(front.max(back)) >= limit {
                return Err(bad("an id is beyond 4 * triangles + 1024"));
            }
            len = len.max(front.max(back) as usize + 1);
        }
        let mut sides = Sides {
            back: vec![NO_ID; len],
            front: vec![NO_ID; len],
        };
        for (pair, &(front, back)) in pairs.iter().enumerate() {
            let (f, b) = (front as usize, back as usize);
            if sides.back[f] != NO_ID
                || sides.front[f] != NO_ID
                || sides.back[b] != NO_ID
                || sides.front[b] != NO_ID
            {
                return Err(BuildError::BadBackSide {
                    pair,
                    front,
                    back,
                    reason: "an id is in two pairs",
                });
            }
            sides.back[f] = back;
            sides.front[b] = front;
        }
        Ok(Bvh {
            sides: Some(Arc::new(sides)),
            ..self
        })
    }

    /// This BVH with the portable node test (four children at a time, SSE on x86_64) even
    /// where the processor runs a faster one: for tests and comparisons. The answers are the
    /// same; only the speed differs. The same as `with_simd(Simd::Portable)`.
    pub fn with_portable_node_test(self) -> Bvh {
        self.with_simd(Simd::Portable)
    }

    /// This BVH with the fastest traversal this processor runs among those up to `most` (a
    /// new BVH gets the fastest of all): for tests and comparisons. The answers are the same;
    /// only the speed differs.
    pub fn with_simd(self, most: Simd) -> Bvh {
        Bvh {
            node_test: NodeTestChoice::fastest(most),
            ..self
        }
    }

    /// The instruction sets the traversal runs on.
    pub fn simd(&self) -> Simd {
        match self.node_test {
            NodeTestChoice::Portable => Simd::Portable,
            #[cfg(target_arch = "x86_64")]
            NodeTestChoice::Avx2(_) => Simd::Avx2,
            #[cfg(target_arch = "x86_64")]
            NodeTestChoice::Avx512(_) => Simd::Avx512,
        }
    }

    /// Number of input triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangle_count
    }

    /// Bounds `(min, max)` of all input vertices, in scene units.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    /// Number of 16-wide BVH nodes (a size and quality statistic).
    pub fn node_count(&self) -> usize {
        self.wide.nodes.len()
    }

    /// Bytes of memory the caster holds for intersection: the BVH nodes (448 bytes each, up
    /// to 16 children) and the triangle packets (160 bytes per 4 triangles, ids included),
    /// allocated to their exact size (the page alignment of large arrays reserves address
    /// space, not memory), plus the struct itself. Divide by
    /// [`Bvh::triangle_count`] for the footprint per triangle. The per-thread traversal stack
    /// (a few hundred bytes) is not counted.
    pub fn memory_bytes(&self) -> usize {
        size_of_val(self) + self.wide.memory_bytes()
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

    /// The [`Hit`] of canonical ray `c` at canonical distance `t` from its lifted origin.
    #[inline]
    fn hit(&self, c: &CanonicalRay, t: f32, id: u32, front: bool) -> Hit {
        let canonical_point = c.origin.as_dvec3() + c.dir.as_dvec3() * t as f64;
        Hit {
            id,
            distance: ((c.skip + t as f64) * self.frame.inv_scale()) as f32,
            point: self.frame.world(canonical_point),
            front,
        }
    }

    /// Closest hit in canonical units: (distance from the lifted origin, the triangle's id,
    /// whether the ray meets its front).
    #[inline]
    fn trace(&self, ray: &CanonicalRay, exclude: u32) -> Option<(f32, u32, bool)> {
        self.run(Closest { ray, exclude })
    }

    /// Runs `task` with the fastest node test this processor runs, on a traversal stack of at
    /// least `self.wide.stack` entries: an array of [`TINY_STACK`] entries on the call stack,
    /// or this thread's array of [`SMALL_STACK`] entries when that is enough (arrays index
    /// without bounds checks, see [`traverse::Stack`]), otherwise a per-thread buffer, reused,
    /// so that no query allocates.
    ///
    /// The thread's array is not cleared between queries: a traversal reads only the entries
    /// it has pushed. (Zeroing a fresh array of 128 entries on the call stack for every query,
    /// 1 KiB on the rooms, was a `memset` call per query; on small scenes zeroing 32 entries
    /// costs less than the thread-local array's borrow, 2-3% of a Cornell box query.) A query
    /// that runs inside another on the same thread (an [`AnyHit`] test that casts rays) finds
    /// the array taken and zeroes one of its own.
    #[inline(always)]
    fn run<T: Task>(&self, task: T) -> T::Out {
        if self.wide.stack <= TINY_STACK {
            return self.run_on(task, &mut [(0.0, 0); TINY_STACK]);
        }
        if self.wide.stack <= SMALL_STACK {
            return ARRAY.with(|cell| match cell.try_borrow_mut() {
                Ok(mut stack) => self.run_on(task, &mut *stack),
                Err(_) => self.run_on(task, &mut [(0.0, 0); SMALL_STACK]),
            });
        }
        STACK.with(|cell| {
            let mut buffer = cell.take();
            if buffer.len() < self.wide.stack {
                buffer.resize(self.wide.stack, (0.0, 0));
            }
            let result = self.run_on(task, &mut buffer[..]);
            cell.set(buffer);
            result
        })
    }

    /// [`Bvh::run`] on `stack`.
    #[inline(always)]
    fn run_on<T: Task>(&self, task: T, stack: &mut (impl Stack + ?Sized)) -> T::Out {
        match self.node_test {
            // SAFETY: an `Avx512` exists only when the processor has AVX2, FMA, AVX-512F and
            // VL (`Avx512::detect`), the features `run_avx512` is compiled for; an `Avx2` only
            // when it has AVX2 and FMA, those of `run_avx2`.
            #[cfg(target_arch = "x86_64")]
            #[allow(unsafe_code)]
            NodeTestChoice::Avx512(isa) => unsafe { self.run_avx512(isa, task, stack) },
            // SAFETY: as above.
            #[cfg(target_arch = "x86_64")]
            #[allow(unsafe_code)]
            NodeTestChoice::Avx2(isa) => unsafe { self.run_avx2(isa, task, stack) },
            NodeTestChoice::Portable => task.run(self, Sse, stack),
        }
    }

    /// [`Task::run`] compiled for AVX2 and FMA with AVX-512F and VL as well: the AVX-512 node
    /// test, and the rest with 32 vector registers to hold it instead of 16.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma,avx512f,avx512vl")]
    fn run_avx512<T: Task>(
        &self,
        isa: Avx512,
        task: T,
        stack: &mut (impl Stack + ?Sized),
    ) -> T::Out {
        task.run(self, isa, stack)
    }

    /// [`Task::run`] compiled for AVX2 and FMA (the whole traversal is inlined here).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn run_avx2<T: Task>(&self, isa: Avx2, task: T, stack: &mut (impl Stack + ?Sized)) -> T::Out {
        task.run(self, isa, stack)
    }
}

/// A query [`Bvh::run`] compiles once per node test and stack (a trait rather than a closure:
/// a closure could be generic over neither, nor inherit the entry points' target features).
trait Task {
    /// The answer.
    type Out;
    /// The query on `bvh` with node test `isa` and a stack of at least `bvh.wide.stack`
    /// entries.
    fn run(self, bvh: &Bvh, isa: impl NodeTest, stack: &mut (impl Stack + ?Sized)) -> Self::Out;
}

/// The closest hit of `ray`, never `exclude` (see [`Bvh::trace`]).
struct Closest<'a> {
    ray: &'a CanonicalRay,
    exclude: u32,
}

impl Task for Closest<'_> {
    type Out = Option<(f32, u32, bool)>;

    #[inline(always)]
    fn run(self, bvh: &Bvh, isa: impl NodeTest, stack: &mut (impl Stack + ?Sized)) -> Self::Out {
        let CanonicalRay {
            origin,
            dir,
            window,
            ..
        } = *self.ray;
        // Start the traversal behind the origin so that the boxes of crossings in the window
        // around it are entered whatever the rounding. Returned values are `t + shift`.
        let shift = 2.0 * window;
        let r = NodeRay::new(origin - dir * shift, dir, 0.0, f32::INFINITY);
        let q = Query::new(origin, dir, f32::INFINITY, window, 0.0);
        let (nodes, packets) = bvh.wide.slices();
        let mut leaves = Leaves {
            packets,
            q: &q,
            shift,
            ids: (self.exclude, self.exclude),
            any_hit: bvh.any_hit.as_deref().map(|t| (t, &bvh.frame)),
            few: false,
            tested: 0,
        };
        let best = traverse::closest(isa, nodes, packets, &r, stack, &mut leaves);
        best.found()
            .then_some(((best.t - shift).max(0.0), best.key, best.front))
    }
}

impl CanonicalSegment {
    /// The query of this segment, the node ray its traversal follows and that ray's start
    /// `shift` behind the origin (canonical units): as in `Closest`, the traversal starts
    /// behind the origin so that the boxes of crossings in the window around it are entered
    /// whatever the rounding, and a blocker reports `shift` (below the node ray's `tmax`).
    #[inline(always)]
    fn traversal(&self) -> (Query, NodeRay, f32) {
        let CanonicalSegment {
            origin,
            dir,
            len,
            window_start,
            window_end,
        } = *self;
        let q = Query::new(origin, dir, len, window_start, window_end);
        let shift = 2.0 * window_start;
        let r = NodeRay::new(
            origin - dir * shift,
            dir,
            0.0,
            len + window_end + 2.0 * shift,
        );
        (q, r, shift)
    }
}

/// Whether a triangle with neither id `ia` nor `ib` blocks the canonical segment `segment`.
struct Blocked<'a> {
    segment: &'a CanonicalSegment,
    ia: u32,
    ib: u32,
    /// Whether a BVH of at most [`FEW_PACKETS`] packets tests each packet once (always, but
    /// for the tests that compare with and without).
    once: bool,
}

impl Task for Blocked<'_> {
    type Out = bool;

    #[inline(always)]
    fn run(self, bvh: &Bvh, isa: impl NodeTest, stack: &mut (impl Stack + ?Sized)) -> bool {
        let (q, r, shift) = self.segment.traversal();
        let (nodes, packets) = bvh.wide.slices();
        let mut leaves = Leaves {
            packets,
            q: &q,
            shift,
            ids: (self.ia, self.ib),
            any_hit: bvh.any_hit.as_deref().map(|t| (t, &bvh.frame)),
            few: self.once && packets.len() <= FEW_PACKETS,
            tested: 0,
        };
        let mid = shift + 0.5 * self.segment.len;
        traverse::any(isa, nodes, packets, &r, mid, stack, &mut leaves)
    }
}

/// Entries of the traversal stack array on the call stack (see [`Bvh::run`]): the exact bound
/// of the Cornell box is 15.
const TINY_STACK: usize = 32;

/// Entries of the traversal stack array of each thread (see [`Bvh::run`]): the exact bound of
/// the rooms of the Embree comparison is 91 (100k triangles) and 121 (1M).
const SMALL_STACK: usize = 128;

thread_local! {
    /// The traversal stack of this thread's queries (see [`Bvh::run`]).
    static ARRAY: RefCell<[traverse::Entry; SMALL_STACK]> =
        const { RefCell::new([(0.0, 0); SMALL_STACK]) };
    /// The traversal stack of this thread's queries on deep hierarchies (see [`Bvh::run`]).
    static STACK: Cell<Vec<traverse::Entry>> = const { Cell::new(Vec::new()) };
}

/// The binary part of `obvhs::cwbvh::builder::build_cwbvh_from_tris` (optional spatial
/// pre-splits, PLOC, reinsertion) with every primitive box padded by `pad` canonical units.
///
/// The padding is the largest window of the scene (see [`exact::ray_rule`]): a ray starting
/// exactly at a corner of flat, axis-aligned boxes (a room's corner) only touches them in a
/// point, which the `f32` slab test may miss, and would then leave through the wall it starts
/// on. Padded, every box whose triangle is crossed within a window holds a stretch of the ray
/// of at least half a window. The cost is nil for scenes near the origin (`2^-10` canonical
/// units).
pub(crate) fn build_bvh2_padded(triangles: &[Triangle], params: BvhBuildParams, pad: f32) -> Bvh2 {
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
    bvh2
}

impl RayCaster for Bvh {
    fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let c = self.frame.canonical_ray(ray)?;
        let Some(sides) = &self.sides else {
            let (t, id, front) = self.trace(&c, ray.exclude)?;
            return Some(self.hit(&c, t, id, front));
        };
        let (t, id, front) = self.trace(&c, sides.triangle_of(ray.exclude))?;
        Some(match sides.back_of(id) {
            Some(back) if !front => self.hit(&c, t, back, true),
            _ => self.hit(&c, t, id, front),
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

    // `occluded_batch` is the trait's loop: sorting the pairs like `closest_hit_batch` sorts its
    // rays (by the first point and the direction to the second) made the 100k room's batches
    // 16-23% slower than one by one, and gained 0-7% on the 1M room (three runs of the Embree
    // comparison): the sort costs as much as a fast occlusion query gains from it.

    fn occluded(&self, a: &SurfacePoint, b: &SurfacePoint) -> bool {
        self.blocked(a, b, true)
    }
}

impl Bvh {
    /// [`RayCaster::occluded`]; `once` as in [`Blocked`].
    #[inline(always)]
    fn blocked(&self, a: &SurfacePoint, b: &SurfacePoint, once: bool) -> bool {
        let Some(s) = self.frame.canonical_segment(a, b) else {
            return false;
        };
        let (ia, ib) = match &self.sides {
            None => (a.id, b.id),
            Some(sides) => (sides.triangle_of(a.id), sides.triangle_of(b.id)),
        };
        self.run(Blocked {
            segment: &s,
            ia,
            ib,
            once,
        })
    }
}

/// Most packets (of 4 triangles) a BVH may have for an occlusion query to remember which it
/// has tested: on so small a scene the few nodes have many leaves, which share packets (see
/// `wide::Part::pack`), and a segment that passes several of them would test a shared packet
/// again. (The Cornell box: 32 triangles, one node of 16 leaves in 9 packets.)
const FEW_PACKETS: usize = 64;

/// The packet tests of one query.
struct Leaves<'a> {
    packets: &'a [wide::Packet],
    q: &'a Query,
    /// How far the traversal starts behind the query's origin (added to crossing distances).
    shift: f32,
    /// The ids that never count (a ray's `exclude` twice, or a segment's two end points').
    ids: (u32, u32),
    /// The BVH's any-hit test and the frame that places its points.
    any_hit: Option<(&'a dyn AnyHit, &'a Frame)>,
    /// Whether the BVH has at most [`FEW_PACKETS`] packets, so that `tested` can record them.
    few: bool,
    /// The packets this query has tested, bit `p` for packet `p` (when `few`).
    tested: u64,
}

impl LeafTest for Leaves<'_> {
    #[inline(always)]
    fn closest(&mut self, run: Range<usize>, best: &mut traverse::Best) {
        for packet in &self.packets[run] {
            self.closest_in(packet, best);
        }
    }

    #[inline(always)]
    fn any(&mut self, run: Range<usize>) -> bool {
        if self.few {
            // Leaves of one node share packets: test each packet once per query.
            for p in run {
                let bit = 1u64 << (p & 63);
                if self.tested & bit != 0 {
                    continue;
                }
                self.tested |= bit;
                if self.any_in(&self.packets[p]) {
                    return true;
                }
            }
            return false;
        }
        // (a loop rather than `Iterator::any`, which the compiler did not inline into the
        // traversal)
        for packet in &self.packets[run] {
            if self.any_in(packet) {
                return true;
            }
        }
        false
    }
}

impl Leaves<'_> {
    /// [`LeafTest::closest`] for one packet.
    #[inline(always)]
    fn closest_in(&self, packet: &wide::Packet, best: &mut traverse::Best) {
        let Some(c) = crossings::<false>(packet, self.q, self.ids) else {
            return;
        };
        let mut hot = c.hot;
        while hot != 0 {
            let j = hot.trailing_zeros() as usize;
            hot &= hot - 1;
            let t = c.t[j] + self.shift;
            if self.any_hit.is_some() && (t > best.t || self.passes(packet.ids[j], c.t[j])) {
                continue;
            }
            best.offer(t, packet.ids[j], c.front >> j & 1 != 0);
        }
        let mut cold = c.cold;
        while cold != 0 {
            let j = cold.trailing_zeros() as usize;
            cold &= cold - 1;
            if let Some((t, front)) = refine(&packet.lane(j), self.q) {
                if self.any_hit.is_some()
                    && (t + self.shift > best.t || self.passes(packet.ids[j], c.t[j]))
                {
                    continue;
                }
                best.offer(t + self.shift, packet.ids[j], front);
            }
        }
    }

    /// [`LeafTest::any`] for one packet.
    #[inline(always)]
    fn any_in(&self, packet: &wide::Packet) -> bool {
        let Some(c) = crossings::<true>(packet, self.q, self.ids) else {
            return false;
        };
        let blocks = |j: usize| self.any_hit.is_none() || !self.passes(packet.ids[j], c.t[j]);
        let mut hot = c.hot;
        if hot != 0 && self.any_hit.is_none() {
            return true;
        }
        while hot != 0 {
            let j = hot.trailing_zeros() as usize;
            hot &= hot - 1;
            if blocks(j) {
                return true;
            }
        }
        let mut cold = c.cold;
        while cold != 0 {
            let j = cold.trailing_zeros() as usize;
            cold &= cold - 1;
            if refine(&packet.lane(j), self.q).is_some() && blocks(j) {
                return true;
            }
        }
        false
    }

    /// Whether the any-hit test lets the query pass triangle `id`, crossed at canonical
    /// distance `t` from the query's origin.
    #[cold]
    #[inline(never)]
    fn passes(&self, id: u32, t: f32) -> bool {
        let Some((test, frame)) = self.any_hit else {
            return false;
        };
        let point = self.q.origin.as_dvec3() + self.q.dir.as_dvec3() * f64::from(t);
        test.passes(id, frame.world(point), Vec3::from(self.q.dir))
    }
}

// `Bvh` is shared across threads by reference.
const _: () = {
    const fn send_sync<T: Send + Sync>() {}
    send_sync::<Bvh>();
};

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed room (each wall cut `4 x 4`) holding `boxes` randomly turned boxes (each face
    /// cut `2 x 2`): mostly closed surfaces, like the benchmark rooms, at a test's size.
    fn room_of_boxes(boxes: usize, seed: u64) -> Vec<[Vec3; 3]> {
        let mut next = crate::testing::uniforms(seed);
        let mut tris = Vec::new();
        // the unit cube's faces, counter-clockwise seen from outside, cut n x n
        let mut cube = |m: &dyn Fn(Vec3) -> Vec3, n: usize, inward: bool| {
            let c = |x: f32, y: f32, z: f32| m(Vec3::new(x, y, z));
            let (l, h) = (-0.5, 0.5);
            let faces = [
                [c(h, l, h), c(h, l, l), c(h, h, l), c(h, h, h)],
                [c(l, l, l), c(l, l, h), c(l, h, h), c(l, h, l)],
                [c(l, h, h), c(h, h, h), c(h, h, l), c(l, h, l)],
                [c(l, l, l), c(h, l, l), c(h, l, h), c(l, l, h)],
                [c(l, l, h), c(h, l, h), c(h, h, h), c(l, h, h)],
                [c(h, l, l), c(l, l, l), c(l, h, l), c(h, h, l)],
            ];
            for p in faces {
                let at = |u: f32, v: f32| p[0].lerp(p[1], u).lerp(p[3].lerp(p[2], u), v);
                for j in 0..n {
                    for i in 0..n {
                        let (u0, u1) = (i as f32 / n as f32, (i + 1) as f32 / n as f32);
                        let (v0, v1) = (j as f32 / n as f32, (j + 1) as f32 / n as f32);
                        let (a, b, c, d) = (at(u0, v0), at(u1, v0), at(u1, v1), at(u0, v1));
                        if inward {
                            tris.extend([[a, c, b], [a, d, c]]);
                        } else {
                            tris.extend([[a, b, c], [a, c, d]]);
                        }
                    }
                }
            }
        };
        cube(&|p| p * 4.0, 4, true);
        for _ in 0..boxes {
            let size = Vec3::new(next(), next(), next()) * 0.4 + 0.05;
            let axis = (Vec3::new(next(), next(), next()) - 0.5).normalize_or(Vec3::Y);
            let turn = glam::Quat::from_axis_angle(axis, next() * std::f32::consts::TAU);
            let at = (Vec3::new(next(), next(), next()) - 0.5) * 3.4;
            cube(&|p| at + turn * (p * size), 2, false);
        }
        tris
    }

    /// Occlusion by the closest-hit traversal: [`traverse::closest`] (children nearest first,
    /// entries behind the nearest blocker so far dropped) with the segment's blocker rule,
    /// each blocking crossing offered at its distance. Until a blocker is found it visits
    /// every leaf the segment reaches, so it finds one exactly when one exists.
    struct ClosestBlocked<'a> {
        segment: &'a CanonicalSegment,
        ia: u32,
        ib: u32,
    }

    impl Task for ClosestBlocked<'_> {
        type Out = bool;

        fn run(self, bvh: &Bvh, isa: impl NodeTest, stack: &mut (impl Stack + ?Sized)) -> bool {
            let (q, r, shift) = self.segment.traversal();
            let (nodes, packets) = bvh.wide.slices();
            let mut blockers = Blockers(Leaves {
                packets,
                q: &q,
                shift,
                ids: (self.ia, self.ib),
                any_hit: None,
                few: false,
                tested: 0,
            });
            traverse::closest(isa, nodes, packets, &r, stack, &mut blockers).found()
        }
    }

    /// The leaf test of [`ClosestBlocked`]: the crossings that block the segment (the lanes
    /// [`Leaves::any_in`] would stop at), offered at their distance.
    struct Blockers<'a>(Leaves<'a>);

    impl LeafTest for Blockers<'_> {
        fn closest(&mut self, run: Range<usize>, best: &mut traverse::Best) {
            let l = &self.0;
            for packet in &l.packets[run] {
                let Some(c) = crossings::<true>(packet, l.q, l.ids) else {
                    continue;
                };
                for j in 0..LANES {
                    let blocks = if c.hot >> j & 1 != 0 {
                        true
                    } else {
                        c.cold >> j & 1 != 0 && refine(&packet.lane(j), l.q).is_some()
                    };
                    if blocks {
                        // (a cold crossing's `f32` distance may lie past the end: clamped
                        // into the segment, where the traversal keeps it)
                        let t = (c.t[j] + l.shift).clamp(0.0, l.q.len());
                        best.offer(t, packet.ids[j], false);
                    }
                }
            }
        }

        fn any(&mut self, _: Range<usize>) -> bool {
            unreachable!("only the closest-hit traversal runs this test")
        }
    }

    /// The any-hit traversal (inner nodes first, no sorting, stopping at the first blocker)
    /// gives every segment the answer of the closest-hit traversal, on each instruction set,
    /// on a room of boxes whose segments are mostly blocked (as the benchmark's), between
    /// surface points (either side of their surface) and free points.
    #[test]
    fn occlusion_agrees_with_the_closest_hit_traversal_on_every_segment() {
        let tris = room_of_boxes(400, 21);
        let ids: Vec<u32> = (0..tris.len() as u32).collect();
        let mut next = crate::testing::uniforms(22);
        let mut point = |k: usize| {
            if k % 7 == 3 {
                return SurfacePoint::free((Vec3::new(next(), next(), next()) - 0.5) * 3.9);
            }
            let i = (next() * tris.len() as f32) as usize % tris.len();
            let [a, b, c] = tris[i];
            let (mut u, mut v) = (next(), next());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let normal = (b - a).cross(c - a).normalize();
            SurfacePoint::new(a + (b - a) * u + (c - a) * v, normal, i as u32)
        };
        let pairs: Vec<(SurfacePoint, SurfacePoint)> = (0..20_000)
            .map(|k| (point(2 * k), point(2 * k + 1)))
            .collect();
        for simd in [Simd::Portable, Simd::Avx2, Simd::Avx512] {
            let bvh = Bvh::build(&tris, &ids).unwrap().with_simd(simd);
            assert!(bvh.wide.packets.len() > FEW_PACKETS);
            let mut blocked = 0;
            for (k, (a, b)) in pairs.iter().enumerate() {
                let by_closest = bvh.frame.canonical_segment(a, b).is_some_and(|s| {
                    bvh.run(ClosestBlocked {
                        segment: &s,
                        ia: a.id,
                        ib: b.id,
                    })
                });
                let occluded = bvh.occluded(a, b);
                assert_eq!(occluded, by_closest, "{simd:?}: pair {k}: {a:?} {b:?}");
                blocked += usize::from(occluded);
            }
            // most segments are blocked, but not all
            assert!((14_000..19_900).contains(&blocked), "{simd:?}: {blocked}");
        }
    }

    /// A uniform point of a triangle of `tris` drawn with `next`'s uniforms (the triangle, then
    /// the point), with the triangle's index and its unnormalised normal `(b - a) x (c - a)`.
    fn on_some_triangle(tris: &[[Vec3; 3]], next: &mut impl FnMut() -> f32) -> (usize, Vec3, Vec3) {
        let i = (next() * tris.len() as f32) as usize % tris.len();
        let [a, b, c] = tris[i];
        let (mut u, mut v) = (next(), next());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        (i, a + (b - a) * u + (c - a) * v, (b - a).cross(c - a))
    }

    /// A soup of `n` triangles: clusters of small ones (many sharing a Morton cell, so some
    /// cuts fall in the middle of equal codes) and a few large ones across the scene.
    fn soup(n: usize, seed: u64) -> Vec<[Vec3; 3]> {
        let mut next = crate::testing::uniforms(seed);
        let centres: Vec<Vec3> = (0..12)
            .map(|_| Vec3::new(next(), next(), next()) * 10.0)
            .collect();
        (0..n)
            .map(|k| {
                let (c, size) = if k % 97 == 0 {
                    (Vec3::new(next(), next(), next()) * 10.0, 4.0)
                } else {
                    let c = centres[(next() * 12.0) as usize % 12];
                    (c + (Vec3::new(next(), next(), next()) - 0.5) * 2.0, 0.3)
                };
                let mut corner = || c + (Vec3::new(next(), next(), next()) - 0.5) * size;
                [corner(), corner(), corner()]
            })
            .collect()
    }

    /// The exact traversal stack bound of `wide` (see [`Wide::stack`]) below `item`, whose
    /// ancestors leave `load` entries.
    fn stack_bound(wide: &Wide, item: u32, load: usize) -> usize {
        let node = &wide.nodes[item as usize];
        let children: Vec<u32> = node
            .items
            .iter()
            .copied()
            .filter(|&i| i != wide::EMPTY)
            .collect();
        let n = children.len();
        children
            .iter()
            .filter(|&&i| i & wide::LEAF == 0)
            .map(|&i| stack_bound(wide, i, load + n - 1))
            .fold(load + n, usize::max)
    }

    /// Built in chunks of 64 to 512 triangles, the BVH holds every triangle once, its stack
    /// bound is exact, and it gives the closest hits (id and distance) and the occlusion
    /// answers of the brute-force oracle, and the very hits of the BVH built as one.
    #[test]
    fn chunked_builds_give_the_oracle_s_answers() {
        for (n, chunk, seed) in [
            (3000, 64, 1),
            (4000, 200, 2),
            (2500, 512, 3),
            (5000, 333, 4),
        ] {
            let tris = soup(n, seed);
            let ids: Vec<u32> = (0..n as u32).map(|i| i * 3 + 1).collect();
            let whole = Bvh::build(&tris, &ids).unwrap();
            let bvh = Bvh::build_chunked(n, |i| tris[i], &ids, BvhPreset::Fast, chunk).unwrap();
            let oracle = crate::BruteForce::build(&tris, &ids).unwrap();
            let what = format!("{n} triangles, chunks of {chunk}");
            let mut stored: Vec<u32> = bvh
                .wide
                .packets
                .iter()
                .flat_map(|p| p.ids)
                .filter(|&id| id != NO_ID)
                .collect();
            stored.sort_unstable();
            assert_eq!(stored, ids, "{what}");
            assert_eq!(bvh.wide.stack, stack_bound(&bvh.wide, 0, 0), "{what}");
            assert!(bvh.wide.stack <= 128, "{what}");
            let mut next = crate::testing::uniforms(seed + 100);
            let mut hits = 0;
            for k in 0..3000usize {
                let dir = (Vec3::new(next(), next(), next()) - 0.5).normalize_or(Vec3::X);
                let ray = if k.is_multiple_of(2) {
                    Ray::new(Vec3::new(next(), next(), next()) * 10.0, dir)
                } else {
                    let (i, x, normal) = on_some_triangle(&tris, &mut next);
                    let normal = normal.normalize_or(Vec3::Y);
                    let dir = if dir.dot(normal) < 0.0 { -dir } else { dir };
                    Ray::from_surface(x, normal, dir, ids[i])
                };
                let hit = bvh.closest_hit(&ray);
                assert_eq!(hit, whole.closest_hit(&ray), "{what}: {ray:?}");
                if ray.origin_normal == Vec3::ZERO {
                    // free rays: no tie or surface rule in play
                    let best = oracle.hits_along(&ray).first().copied();
                    let same = match (hit, best) {
                        (None, None) => true,
                        (Some(h), Some(b)) => {
                            h.id == b.id && (h.distance - b.distance).abs() <= 1e-4 * b.distance
                        }
                        _ => false,
                    };
                    assert!(
                        same,
                        "{what}: {ray:?}: {hit:?} against the oracle's {best:?}"
                    );
                }
                hits += usize::from(hit.is_some());
            }
            assert!((500..2990).contains(&hits), "{what}: {hits} hits");
            let (mut blocked, mut differ) = (0, 0);
            for k in 0..3000 {
                let mut point = |m: usize| {
                    if m.is_multiple_of(3) {
                        return SurfacePoint::free(Vec3::new(next(), next(), next()) * 10.0);
                    }
                    let (i, x, normal) = on_some_triangle(&tris, &mut next);
                    SurfacePoint::new(x, normal.normalize_or_zero(), ids[i])
                };
                let (a, b) = (point(k), point(k + 1));
                let occluded = bvh.occluded(&a, &b);
                assert_eq!(occluded, whole.occluded(&a, &b), "{what}: {a:?} {b:?}");
                blocked += usize::from(occluded);
                differ += usize::from(occluded != oracle.occluded(&a, &b));
            }
            assert!((300..2900).contains(&blocked), "{what}: {blocked} blocked");
            assert!(differ <= 3, "{what}: {differ} differ from the oracle");
        }
    }

    /// A scene whose triangles nearly all share one Morton cell (cut in the middle of equal
    /// codes), built in chunks with every preset, gives the hits and occlusion answers of the
    /// BVH built as one.
    #[test]
    fn chunked_builds_of_one_cell_give_the_same_answers() {
        // a cluster of 1 x 1 x 1 far from one large triangle, so the cluster is a few cells
        let mut tris: Vec<[Vec3; 3]> = soup(3000, 5).iter().map(|t| t.map(|v| v * 0.1)).collect();
        tris.push([
            Vec3::splat(500.0),
            Vec3::new(520.0, 500.0, 500.0),
            Vec3::splat(510.0),
        ]);
        let n = tris.len();
        let ids: Vec<u32> = (0..n as u32).collect();
        let mut next = crate::testing::uniforms(77);
        let rays: Vec<Ray> = (0..2000)
            .map(|_| {
                let from = Vec3::new(next(), next(), next()) * 3.0 - 1.0;
                let [a, b, c] = tris[(next() * 3000.0) as usize % 3000];
                Ray::new(from, ((a + b + c) / 3.0 - from).normalize())
            })
            .collect();
        let pairs: Vec<(SurfacePoint, SurfacePoint)> = (0..2000)
            .map(|_| {
                let mut p = || SurfacePoint::free(Vec3::new(next(), next(), next()) * 1.2 - 0.1);
                (p(), p())
            })
            .collect();
        for (preset, chunk) in [
            (BvhPreset::Fast, 100),
            (BvhPreset::Medium, 250),
            (BvhPreset::Slow, 500),
        ] {
            let whole = Bvh::build_with(&tris, &ids, preset).unwrap();
            let bvh = Bvh::build_chunked(n, |i| tris[i], &ids, preset, chunk).unwrap();
            let hits = rays.iter().filter(|r| {
                let hit = bvh.closest_hit(r);
                assert_eq!(
                    hit,
                    whole.closest_hit(r),
                    "{preset:?}, chunks of {chunk}: {r:?}"
                );
                hit.is_some()
            });
            assert!(hits.count() > 1000, "{preset:?}");
            for (a, b) in &pairs {
                assert_eq!(
                    bvh.occluded(a, b),
                    whole.occluded(a, b),
                    "{preset:?}: {a:?} {b:?}"
                );
            }
        }
    }

    /// A chunked build is the same BVH, node for node and packet for packet, on 1 and 3
    /// threads, and a scene of one chunk is built as before chunking.
    #[test]
    fn chunked_builds_do_not_depend_on_the_thread_count() {
        let tris = soup(4000, 9);
        let ids: Vec<u32> = (0..tris.len() as u32).collect();
        let build = |threads: usize, chunk: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    Bvh::build_chunked(tris.len(), |i| tris[i], &ids, BvhPreset::Fast, chunk)
                        .unwrap()
                })
        };
        let bytes = |bvh: &Bvh| {
            let nodes: &[u8] = bytemuck::cast_slice(&bvh.wide.nodes[..]);
            let packets: &[u8] = bytemuck::cast_slice(&bvh.wide.packets[..]);
            (nodes.to_vec(), packets.to_vec(), bvh.wide.stack)
        };
        for chunk in [64, 300] {
            let (one, three) = (build(1, chunk), build(3, chunk));
            assert!(one.node_count() > 64, "chunks of {chunk}");
            assert!(bytes(&one) == bytes(&three), "chunks of {chunk}");
        }
        // one chunk: the BVH of the build without chunks
        let whole = Bvh::build(&tris, &ids).unwrap();
        assert!(bytes(&build(3, tris.len())) == bytes(&whole));
        assert!(bytes(&build(3, tris.len() - 1)) != bytes(&whole));
    }

    /// A grid of `n x n` unit quads on the floor and a ceiling above, and rays from the floor.
    fn floor_and_rays(n: usize) -> (Bvh, Vec<Ray>) {
        let mut tris = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let (x, z) = (i as f32, j as f32);
                let (a, b) = (Vec3::new(x, 0.0, z), Vec3::new(x + 1.0, 0.0, z));
                let (c, d) = (Vec3::new(x + 1.0, 0.0, z + 1.0), Vec3::new(x, 0.0, z + 1.0));
                tris.extend([[a, d, c], [a, c, b]]);
                let up = Vec3::Y * (1.0 + (i + j) as f32 * 0.01);
                tris.extend([[a + up, b + up, c + up], [a + up, c + up, d + up]]);
            }
        }
        let ids: Vec<u32> = (0..tris.len() as u32).collect();
        let bvh = Bvh::build(&tris, &ids).unwrap();
        let rays = (0..2000)
            .map(|k| {
                let (u, v) = ((k % 97) as f32 / 97.0, (k % 89) as f32 / 89.0);
                let p = Vec3::new(u * n as f32, 0.0, v * n as f32);
                let dir = Vec3::new(u - 0.5, 1.0, v - 0.5).normalize();
                let id = 4
                    * ((p.x as u32).min(n as u32 - 1) * n as u32 + (p.z as u32).min(n as u32 - 1));
                Ray::from_surface(p, Vec3::Y, dir, id)
            })
            .collect();
        (bvh, rays)
    }

    /// Occlusion on scenes of at most `FEW_PACKETS` packets tests each packet once per query:
    /// the same answers as testing every leaf's packets (and the oracle's), on triangle soups
    /// of either side of the threshold, with end points on triangles and free ones.
    #[test]
    fn testing_each_packet_once_gives_the_same_occlusion() {
        let mut next = crate::testing::uniforms(11);
        let mut few = 0;
        for n in [8usize, 32, 64, 128, 200, 256, 400] {
            let mut tris = Vec::with_capacity(n);
            for _ in 0..n {
                let c = Vec3::new(next(), next(), next()) * 4.0;
                let mut corner = || c + (Vec3::new(next(), next(), next()) - 0.5) * 1.5;
                tris.push([corner(), corner(), corner()]);
            }
            let ids: Vec<u32> = (0..n as u32).collect();
            let bvh = Bvh::build(&tris, &ids).unwrap();
            let oracle = crate::BruteForce::build(&tris, &ids).unwrap();
            few += usize::from(bvh.wide.packets.len() <= FEW_PACKETS);
            let mut point = |k: usize| {
                if k.is_multiple_of(5) {
                    return SurfacePoint::free(Vec3::new(next(), next(), next()) * 4.0);
                }
                let (i, x, normal) = on_some_triangle(&tris, &mut next);
                SurfacePoint::new(x, normal.normalize_or_zero(), i as u32)
            };
            let (mut blocked, mut differ) = (0, 0);
            for k in 0..4000 {
                let (a, b) = (point(k), point(k + 1));
                let once = bvh.blocked(&a, &b, true);
                assert_eq!(once, bvh.blocked(&a, &b, false), "{n} triangles, pair {k}");
                blocked += usize::from(once);
                differ += usize::from(once != oracle.occluded(&a, &b));
            }
            assert!((100..3900).contains(&blocked), "{n} triangles: {blocked}");
            assert!(
                differ <= 4,
                "{n} triangles: {differ} differ from the oracle"
            );
        }
        // both sides of the threshold were tested
        assert!((1..7).contains(&few), "{few}");
    }

    #[test]
    fn two_sided_triangles_report_their_back_id_and_exclude_both_sides() {
        // a unit square at y = 0 (ids 7, back 8) over a floor at y = -1 (id 3, one-sided,
        // facing up)
        let (a, b) = (Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0));
        let (c, d) = (Vec3::new(1.0, 0.0, 1.0), Vec3::new(0.0, 0.0, 1.0));
        let down = Vec3::new(0.0, -1.0, 0.0);
        let tris = [[a, d, c], [a, c, b], [a + down, d + down, c + down]];
        let one = Bvh::build(&tris, &[7, 7, 3]).unwrap();
        let two = Bvh::build(&tris, &[7, 7, 3])
            .unwrap()
            .with_back_sides(&[(7, 8)])
            .unwrap();
        let p = Vec3::new(0.3, 0.0, 0.6);
        let from_below = Ray::new(p - Vec3::Y * 0.5, Vec3::Y);
        let from_above = Ray::new(p + Vec3::Y * 0.5, -Vec3::Y);
        let hit = |bvh: &Bvh, r: &Ray| bvh.closest_hit(r).map(|h| (h.id, h.front));
        assert_eq!(hit(&one, &from_below), Some((7, false)));
        assert_eq!(hit(&two, &from_below), Some((8, true)));
        assert_eq!(hit(&one, &from_above), Some((7, true)));
        assert_eq!(hit(&two, &from_above), Some((7, true)));
        // leaving the back side downwards: the floor, never its own front
        let leave_back = Ray::from_surface(p, -Vec3::Y, -Vec3::Y, 8);
        assert_eq!(hit(&two, &leave_back), Some((3, true)));
        let leave_front = Ray::from_surface(p, Vec3::Y, Vec3::Y, 7);
        assert_eq!(hit(&two, &leave_front), None);
        // grazing rays leaving either side at a slant
        for k in 1..50 {
            let dir = Vec3::new(1.0, -0.02 * k as f32, 0.3).normalize();
            let h = two.closest_hit(&Ray::from_surface(p, -Vec3::Y, dir, 8));
            assert!(h.is_none_or(|h| h.id == 3), "{dir}: {h:?}");
        }
        // occlusion: a back-side point to the floor below is clear, the plane blocks a free
        // point below from one above, and the back id names the triangle as an end point
        let floor = SurfacePoint::new(p + down, Vec3::Y, 3);
        let back = SurfacePoint::new(p, -Vec3::Y, 8);
        assert!(!two.occluded(&back, &floor));
        assert!(!one.occluded(&SurfacePoint::new(p, -Vec3::Y, 7), &floor));
        let above = SurfacePoint::free(p + Vec3::Y);
        assert!(two.occluded(&floor, &above));
        assert!(!two.occluded(&SurfacePoint::new(p, Vec3::Y, 8), &above));
        // bad pairs are refused
        let bad = |pairs: &[(u32, u32)]| {
            Bvh::build(&tris, &[7, 7, 3])
                .unwrap()
                .with_back_sides(pairs)
        };
        assert!(matches!(
            bad(&[(7, 7)]),
            Err(BuildError::BadBackSide { .. })
        ));
        assert!(matches!(
            bad(&[(7, 8), (3, 8)]),
            Err(BuildError::BadBackSide { .. })
        ));
        assert!(matches!(
            bad(&[(7, NO_ID)]),
            Err(BuildError::BadBackSide { .. })
        ));
        assert!(matches!(
            bad(&[(7, 1 << 20)]),
            Err(BuildError::BadBackSide { .. })
        ));
    }

    /// An any-hit test that casts rays on another BVH (on the same thread) while a query on the
    /// thread's stack array is running: the nested query finds the array taken and uses one of
    /// its own, and both give the answers they give one after the other.
    #[test]
    fn nested_queries_take_a_stack_of_their_own() {
        /// Lets the upper floor pass where a ray down from the crossing, on `floor`, meets an
        /// even triangle; records whether the thread's array was taken meanwhile.
        struct Down {
            floor: Bvh,
            taken: std::sync::atomic::AtomicUsize,
        }
        impl AnyHit for Down {
            fn passes(&self, id: u32, point: Vec3, _dir: Vec3) -> bool {
                if ARRAY.with(|cell| cell.try_borrow_mut().is_err()) {
                    self.taken
                        .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
                id % 4 >= 2
                    && self
                        .floor
                        .closest_hit(&Ray::new(point, -Vec3::Y))
                        .is_some_and(|h| h.id % 2 == 0)
            }
        }
        let middle = |mut bvh: Bvh| {
            // a bound that takes the thread's array (the floors' own is below 32)
            assert!(bvh.wide.stack <= TINY_STACK);
            bvh.wide.stack = SMALL_STACK;
            bvh
        };
        let (outer, rays) = floor_and_rays(12);
        let (floor, _) = floor_and_rays(12);
        let (reference, _) = floor_and_rays(12);
        let down = Arc::new(Down {
            floor: middle(floor),
            taken: Default::default(),
        });
        let outer = middle(outer).with_any_hit(down.clone());
        let (plain, _) = floor_and_rays(12);
        let reference = reference.with_any_hit(Arc::new(Down {
            floor: plain,
            taken: Default::default(),
        }));
        let mut passed = 0;
        for r in &rays {
            let (a, b) = (outer.closest_hit(r), reference.closest_hit(r));
            assert_eq!(a, b, "{r:?}");
            // (a ray that passes the upper floor escapes)
            passed += usize::from(a.is_none());
            let p = SurfacePoint::new(r.origin, Vec3::Y, r.exclude);
            let q = SurfacePoint::free(r.origin + r.dir * 3.0);
            assert_eq!(outer.occluded(&p, &q), reference.occluded(&p, &q), "{r:?}");
        }
        let taken = down.taken.load(std::sync::atomic::Ordering::Relaxed);
        assert!(
            passed > 100 && taken > 1000,
            "{passed} passed, {taken} nested"
        );
    }

    #[test]
    fn deep_hierarchies_take_the_thread_local_stack_with_the_same_answers() {
        let (bvh, rays) = floor_and_rays(12);
        assert!(bvh.wide.stack <= 128, "stack bound {}", bvh.wide.stack);
        let mut deep = Bvh {
            wide: bvh.wide.clone(),
            ..bvh
        };
        // a bound above the largest array makes every query use the per-thread buffer
        deep.wide.stack = 1000;
        let (shallow, _) = floor_and_rays(12);
        let mut hits = 0;
        for r in &rays {
            let (a, b) = (shallow.closest_hit(r), deep.closest_hit(r));
            assert_eq!(a, b, "{r:?}");
            hits += a.is_some() as usize;
        }
        assert!(hits > 1000, "{hits} hits");
        STACK.with(|cell| {
            let stack = cell.take();
            assert!(
                stack.len() >= 1000,
                "the buffer has {} entries",
                stack.len()
            );
            cell.set(stack);
        });
    }
}
