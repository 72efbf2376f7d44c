//! Single-ray traversal of the 16-wide BVH ([`crate::wide`]).
//!
//! Every stack entry carries the distance at which the ray enters its box: children are
//! visited nearest first and entries farther than the closest hit so far are dropped without
//! touching their memory. Leaves are entries too, so their packets are tested in distance
//! order. The child nodes and packets a node test finds are prefetched at once: on a large
//! scene each is a cache miss, and they are independent loads.
//!
//! The slab test ([`NodeTest`]) runs on all sixteen children at once with AVX-512, on eight at
//! a time with AVX2 and FMA where the processor has those, otherwise on four per SSE register
//! (through glam's `Vec4`), with the reciprocal direction of `obvhs::ray::safe_inverse` (no
//! infinities, so an empty box `[+inf, -inf]` never passes and no lane computes a NaN).

use std::ops::Range;

use glam::{Vec3A, Vec4};
use obvhs::ray::safe_inverse;

use crate::wide::{LEAF, Node, Packet, WIDTH, packets};

/// A ray as the node test sees it: origin, reciprocal direction, and the interval of `t`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct NodeRay {
    /// `-origin * inv`, per axis: the plane `q` is reached at `q * inv + offset`.
    offset: [f32; 3],
    inv: [f32; 3],
    /// Index in [`Node::planes`] of the near and far plane on each axis (lower bounds for a
    /// positive direction, upper bounds for a negative one).
    near: [usize; 3],
    far: [usize; 3],
    tmin: f32,
    tmax: f32,
}

impl NodeRay {
    /// The ray `origin + t * dir` for `t` in `[tmin, tmax]`.
    #[inline(always)]
    pub(crate) fn new(origin: Vec3A, dir: Vec3A, tmin: f32, tmax: f32) -> NodeRay {
        let inv = Vec3A::new(
            safe_inverse(dir.x),
            safe_inverse(dir.y),
            safe_inverse(dir.z),
        );
        let offset = -origin * inv;
        let neg = [inv.x < 0.0, inv.y < 0.0, inv.z < 0.0];
        NodeRay {
            offset: offset.into(),
            inv: inv.into(),
            near: [0, 1, 2].map(|k| 2 * k + neg[k] as usize),
            far: [0, 1, 2].map(|k| 2 * k + 1 - neg[k] as usize),
            tmin,
            tmax,
        }
    }
}

/// A stack entry: the distance at which the ray enters the box, and a node index or a leaf.
pub(crate) type Entry = (f32, u32);

/// A traversal stack: entries `0..len` for a `len` of at least [`crate::wide::Wide::stack`],
/// which no traversal exceeds.
pub(crate) trait Stack {
    /// Entry `i`, for `i < len`.
    fn at(&mut self, i: usize) -> &mut Entry;
}

/// An array of a power-of-two length `N`: entry `i` is the one at `i mod N`, which is `i`
/// itself for every `i` a traversal uses (no bounds check, and no unsafe code: an index past
/// `N` could only wrap around, never leave the array).
impl<const N: usize> Stack for [Entry; N] {
    #[inline(always)]
    fn at(&mut self, i: usize) -> &mut Entry {
        const { assert!(N.is_power_of_two()) };
        &mut self[i & (N - 1)]
    }
}

/// A buffer of any length, bounds checked.
impl Stack for [Entry] {
    #[inline(always)]
    fn at(&mut self, i: usize) -> &mut Entry {
        &mut self[i]
    }
}

/// A node test: the children of `node` whose box the ray enters before `tmax`, with their
/// entry distances (lane `i` for child `i`) and the mask of them (bit `i` for child `i`).
///
/// Implemented for SSE ([`Sse`], every target through glam's `Vec4`), for AVX2 with FMA
/// ([`Avx2`]) and for AVX-512 ([`Avx512`], x86_64 processors that have them). All compute
/// `q * inv + offset` per plane, the last two with one rounding instead of two (the same
/// numbers), so entry distances may differ in the last bit; what is hit does not depend on it
/// (boxes are padded, see `bvh.rs`, and the closest hit is that of all triangles whatever the
/// visiting order).
pub(crate) trait NodeTest: Copy {
    /// The test of `node`.
    fn intersect(self, node: &Node, ray: &NodeRay, tmax: f32) -> ([f32; WIDTH], u32);

    /// The test of `node` without the entry distances: the mask of the hit children, and the
    /// mask of those among them whose stretch of the ray (from entering the box to leaving it)
    /// holds `t`.
    fn holding(self, node: &Node, ray: &NodeRay, tmax: f32, t: f32) -> (u32, u32);

    /// The children of `node` that are inner nodes (not leaves, not empty), as a mask (bit `i`
    /// for child `i`): those whose item has the [`LEAF`] bit clear.
    #[inline(always)]
    fn inner(self, node: &Node) -> u32 {
        // the LEAF bit is the sign bit: four items at a time as the signs of floats
        let mut leaves = 0;
        for (q, four) in node.items.chunks_exact(4).enumerate() {
            let bits = Vec4::new(
                f32::from_bits(four[0]),
                f32::from_bits(four[1]),
                f32::from_bits(four[2]),
                f32::from_bits(four[3]),
            );
            leaves |= bits.is_negative_bitmask() << (4 * q);
        }
        !leaves & ((1 << WIDTH) - 1)
    }
}

/// The node test on four children at a time, with SSE on x86_64 (scalar elsewhere).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sse;

impl Sse {
    /// Entry and exit distances of the four children of quarter `h` (children `4h..4h + 4`).
    #[inline(always)]
    fn quarter(node: &Node, ray: &NodeRay, tmax: f32, h: usize) -> (Vec4, Vec4) {
        let p = &node.planes;
        let at = |plane: usize, k: usize| {
            p[plane][h] * Vec4::splat(ray.inv[k]) + Vec4::splat(ray.offset[k])
        };
        let enter = at(ray.near[0], 0)
            .max(at(ray.near[1], 1))
            .max(at(ray.near[2], 2).max(Vec4::splat(ray.tmin)));
        let leave = at(ray.far[0], 0)
            .min(at(ray.far[1], 1))
            .min(at(ray.far[2], 2).min(Vec4::splat(tmax)));
        (enter, leave)
    }
}

impl NodeTest for Sse {
    #[inline(always)]
    fn intersect(self, node: &Node, ray: &NodeRay, tmax: f32) -> ([f32; WIDTH], u32) {
        let mut enter = [0.0; WIDTH];
        let mut mask = 0;
        for h in 0..WIDTH / 4 {
            let (a, b) = Sse::quarter(node, ray, tmax, h);
            enter[4 * h..4 * h + 4].copy_from_slice(&a.to_array());
            mask |= a.cmple(b).bitmask() << (4 * h);
        }
        (enter, mask)
    }

    #[inline(always)]
    fn holding(self, node: &Node, ray: &NodeRay, tmax: f32, t: f32) -> (u32, u32) {
        let t = Vec4::splat(t);
        let (mut mask, mut hold) = (0, 0);
        for h in 0..WIDTH / 4 {
            let (a, b) = Sse::quarter(node, ray, tmax, h);
            mask |= a.cmple(b).bitmask() << (4 * h);
            hold |= (a.cmple(t) & b.cmpge(t)).bitmask() << (4 * h);
        }
        (mask, hold & mask)
    }
}

/// The node test on eight children at a time, with AVX2 and FMA. Only [`Avx2::detect`] makes
/// one, so holding one proves the processor has them.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub(crate) struct Avx2(());

#[cfg(target_arch = "x86_64")]
impl Avx2 {
    /// `Some` when this processor runs AVX2 and FMA.
    pub(crate) fn detect() -> Option<Avx2> {
        (is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")).then_some(Avx2(()))
    }
}

#[cfg(target_arch = "x86_64")]
impl Avx2 {
    /// Entry and exit distances of the eight children of half `h` (children `8h..8h + 8`).
    ///
    /// # Safety
    /// The processor must have AVX2 and FMA (and the caller be compiled for them, or this is
    /// slow).
    #[inline(always)]
    #[allow(unsafe_code)]
    unsafe fn half(
        node: &Node,
        ray: &NodeRay,
        tmax: f32,
        h: usize,
    ) -> (std::arch::x86_64::__m256, std::arch::x86_64::__m256) {
        use std::arch::x86_64::*;
        // SAFETY: the caller guarantees the features; `plane_times` reads 8 floats of a plane
        // row of `node` (in bounds, any alignment accepted by `loadu`).
        // (no closures here: they would not inherit the target features)
        unsafe {
            let ix = _mm256_set1_ps(ray.inv[0]);
            let iy = _mm256_set1_ps(ray.inv[1]);
            let iz = _mm256_set1_ps(ray.inv[2]);
            let ox = _mm256_set1_ps(ray.offset[0]);
            let oy = _mm256_set1_ps(ray.offset[1]);
            let oz = _mm256_set1_ps(ray.offset[2]);
            let p = &node.planes;
            let enter = _mm256_max_ps(
                _mm256_max_ps(
                    plane_times(&p[ray.near[0]], h, ix, ox),
                    plane_times(&p[ray.near[1]], h, iy, oy),
                ),
                _mm256_max_ps(
                    plane_times(&p[ray.near[2]], h, iz, oz),
                    _mm256_set1_ps(ray.tmin),
                ),
            );
            let leave = _mm256_min_ps(
                _mm256_min_ps(
                    plane_times(&p[ray.far[0]], h, ix, ox),
                    plane_times(&p[ray.far[1]], h, iy, oy),
                ),
                _mm256_min_ps(plane_times(&p[ray.far[2]], h, iz, oz), _mm256_set1_ps(tmax)),
            );
            (enter, leave)
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl NodeTest for Avx2 {
    /// Meant to be inlined into a function compiled with `#[target_feature(enable =
    /// "avx2,fma")]` (see `Bvh::trace`); elsewhere each intrinsic is a call.
    #[inline(always)]
    fn intersect(self, node: &Node, ray: &NodeRay, tmax: f32) -> ([f32; WIDTH], u32) {
        use std::arch::x86_64::*;
        let mut enter_out = [0.0f32; WIDTH];
        // SAFETY: `self` exists only if `Avx2::detect` found AVX2 and FMA on this processor, so
        // the intrinsics' target features are present (and `Avx2::half`'s). Each store writes
        // 8 floats of `enter_out` (a bounds-checked slice).
        #[allow(unsafe_code)]
        let mask = unsafe {
            let mut mask = 0;
            for h in 0..WIDTH / 8 {
                let (enter, leave) = Avx2::half(node, ray, tmax, h);
                _mm256_storeu_ps(enter_out[8 * h..8 * h + 8].as_mut_ptr(), enter);
                let hits = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(enter, leave)) as u32;
                mask |= hits << (8 * h);
            }
            mask
        };
        (enter_out, mask)
    }

    /// As [`Avx2::intersect`].
    #[inline(always)]
    fn holding(self, node: &Node, ray: &NodeRay, tmax: f32, t: f32) -> (u32, u32) {
        use std::arch::x86_64::*;
        // SAFETY: as in `intersect`.
        #[allow(unsafe_code)]
        unsafe {
            let t = _mm256_set1_ps(t);
            let (mut mask, mut hold) = (0, 0);
            for h in 0..WIDTH / 8 {
                let (enter, leave) = Avx2::half(node, ray, tmax, h);
                let hits = _mm256_cmp_ps::<_CMP_LE_OQ>(enter, leave);
                let holds = _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LE_OQ>(enter, t),
                    _mm256_cmp_ps::<_CMP_GE_OQ>(leave, t),
                );
                mask |= (_mm256_movemask_ps(hits) as u32) << (8 * h);
                hold |= (_mm256_movemask_ps(holds) as u32) << (8 * h);
            }
            (mask, hold & mask)
        }
    }

    #[inline(always)]
    fn inner(self, node: &Node) -> u32 {
        use std::arch::x86_64::*;
        // SAFETY: as in `intersect`; each load reads 8 of the 16 items of `node` (in bounds,
        // any alignment accepted by `loadu`).
        #[allow(unsafe_code)]
        let leaves = unsafe {
            // the sign bit of an item is the LEAF bit
            let lo = _mm256_loadu_ps(node.items[..8].as_ptr().cast::<f32>());
            let hi = _mm256_loadu_ps(node.items[8..].as_ptr().cast::<f32>());
            _mm256_movemask_ps(lo) as u32 | (_mm256_movemask_ps(hi) as u32) << 8
        };
        !leaves & 0xffff
    }
}

/// The node test on all sixteen children at once, with AVX-512F. Only [`Avx512::detect`]
/// makes one, so holding one proves the processor has AVX-512F and VL as well as AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub(crate) struct Avx512(());

#[cfg(target_arch = "x86_64")]
impl Avx512 {
    /// `Some` when this processor runs AVX-512F and VL, AVX2 and FMA.
    pub(crate) fn detect() -> Option<Avx512> {
        (Avx2::detect().is_some()
            && is_x86_feature_detected!("avx512f")
            && is_x86_feature_detected!("avx512vl"))
        .then_some(Avx512(()))
    }
}

#[cfg(target_arch = "x86_64")]
impl Avx512 {
    /// Entry and exit distances of the sixteen children.
    ///
    /// # Safety
    /// The processor must have AVX-512F (and the caller be compiled for it, or this is slow).
    #[inline(always)]
    #[allow(unsafe_code)]
    unsafe fn whole(
        node: &Node,
        ray: &NodeRay,
        tmax: f32,
    ) -> (std::arch::x86_64::__m512, std::arch::x86_64::__m512) {
        use std::arch::x86_64::*;
        // SAFETY: the caller guarantees the feature; `plane_times16` reads the 16 floats of one
        // plane row of `node` (64 bytes, in bounds, any alignment accepted by `loadu`).
        // (no closures here: they would not inherit the target features)
        unsafe {
            let ix = _mm512_set1_ps(ray.inv[0]);
            let iy = _mm512_set1_ps(ray.inv[1]);
            let iz = _mm512_set1_ps(ray.inv[2]);
            let ox = _mm512_set1_ps(ray.offset[0]);
            let oy = _mm512_set1_ps(ray.offset[1]);
            let oz = _mm512_set1_ps(ray.offset[2]);
            let p = &node.planes;
            let enter = _mm512_max_ps(
                _mm512_max_ps(
                    plane_times16(&p[ray.near[0]], ix, ox),
                    plane_times16(&p[ray.near[1]], iy, oy),
                ),
                _mm512_max_ps(
                    plane_times16(&p[ray.near[2]], iz, oz),
                    _mm512_set1_ps(ray.tmin),
                ),
            );
            let leave = _mm512_min_ps(
                _mm512_min_ps(
                    plane_times16(&p[ray.far[0]], ix, ox),
                    plane_times16(&p[ray.far[1]], iy, oy),
                ),
                _mm512_min_ps(plane_times16(&p[ray.far[2]], iz, oz), _mm512_set1_ps(tmax)),
            );
            (enter, leave)
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl NodeTest for Avx512 {
    /// Meant to be inlined into a function compiled with `#[target_feature(enable =
    /// "avx2,fma,avx512f,avx512vl")]` (see `Bvh::trace`); elsewhere each intrinsic is a call.
    #[inline(always)]
    fn intersect(self, node: &Node, ray: &NodeRay, tmax: f32) -> ([f32; WIDTH], u32) {
        use std::arch::x86_64::*;
        let mut enter_out = [0.0f32; WIDTH];
        // SAFETY: `self` exists only if `Avx512::detect` found AVX-512F on this processor, so
        // the intrinsics' target features are present (and `Avx512::whole`'s). The store
        // writes the 16 floats of `enter_out`.
        #[allow(unsafe_code)]
        let mask = unsafe {
            let (enter, leave) = Avx512::whole(node, ray, tmax);
            _mm512_storeu_ps(enter_out.as_mut_ptr(), enter);
            _mm512_cmp_ps_mask::<_CMP_LE_OQ>(enter, leave) as u32
        };
        (enter_out, mask)
    }

    /// As [`Avx512::intersect`].
    #[inline(always)]
    fn holding(self, node: &Node, ray: &NodeRay, tmax: f32, t: f32) -> (u32, u32) {
        use std::arch::x86_64::*;
        // SAFETY: as in `intersect`.
        #[allow(unsafe_code)]
        unsafe {
            let t = _mm512_set1_ps(t);
            let (enter, leave) = Avx512::whole(node, ray, tmax);
            let mask = _mm512_cmp_ps_mask::<_CMP_LE_OQ>(enter, leave) as u32;
            let hold = (_mm512_cmp_ps_mask::<_CMP_LE_OQ>(enter, t)
                & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(leave, t)) as u32;
            (mask, hold & mask)
        }
    }

    #[inline(always)]
    fn inner(self, node: &Node) -> u32 {
        use std::arch::x86_64::*;
        // SAFETY: as in `intersect`; the load reads the 16 items of `node` (64 bytes, in
        // bounds, any alignment accepted by `loadu`).
        #[allow(unsafe_code)]
        unsafe {
            // items below 2^31 as signed integers: the LEAF bit clear
            let items = _mm512_loadu_si512(node.items.as_ptr().cast());
            _mm512_cmpge_epi32_mask(items, _mm512_setzero_si512()) as u32
        }
    }
}

/// `plane * inv + offset` in 16 lanes (a whole plane row), rounded once.
///
/// # Safety
/// The processor must have AVX-512F (and the caller be compiled for it, or this is slow).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(unsafe_code)]
unsafe fn plane_times16(
    plane: &[Vec4; WIDTH / 4],
    inv: std::arch::x86_64::__m512,
    offset: std::arch::x86_64::__m512,
) -> std::arch::x86_64::__m512 {
    use std::arch::x86_64::*;
    // SAFETY: the caller guarantees the feature; the load reads the 64 bytes of `plane`.
    unsafe { _mm512_fmadd_ps(_mm512_loadu_ps(plane.as_ptr().cast::<f32>()), inv, offset) }
}

/// `plane * inv + offset` in the 8 lanes of half `h` (0 or 1) of a plane row, rounded once.
///
/// # Safety
/// The processor must have AVX2 and FMA (and the caller be compiled for them, or this is slow).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(unsafe_code)]
unsafe fn plane_times(
    plane: &[Vec4; WIDTH / 4],
    h: usize,
    inv: std::arch::x86_64::__m256,
    offset: std::arch::x86_64::__m256,
) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    let half = &plane[2 * h..2 * h + 2];
    // SAFETY: the caller guarantees the features; the load reads the 32 bytes of `half`.
    unsafe { _mm256_fmadd_ps(_mm256_loadu_ps(half.as_ptr().cast::<f32>()), inv, offset) }
}

/// Asks the CPU to start loading the cache lines of `item` (a node, or a leaf's first packet)
/// while the traversal goes on. A second packet (a leaf of five to eight triangles) is not
/// prefetched: its loads follow the first packet's test closely anyway, and checking the
/// count cost more than it saved.
#[inline(always)]
fn prefetch_item(nodes: &[Node], packs: &[Packet], item: u32) {
    // (address arithmetic only: no bounds checks, nothing is dereferenced)
    if item & LEAF == 0 {
        // a node: seven aligned lines
        let node = nodes.as_ptr().wrapping_add(item as usize).cast::<i8>();
        for line in 0..size_of::<Node>() / 64 {
            prefetch(node.wrapping_add(64 * line));
        }
    } else {
        // packets are 160 bytes at 32-byte alignment: three lines from the start cover one
        let first = packs
            .as_ptr()
            .wrapping_add(packets(item).start)
            .cast::<i8>();
        for line in 0..3 {
            prefetch(first.wrapping_add(64 * line));
        }
    }
}

/// A prefetch hint for the cache line holding `p`.
#[inline(always)]
fn prefetch(p: *const i8) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: `_mm_prefetch` only hints the cache: it never faults, whatever the address, and
    // has no effect the program can observe. Its only requirement is the SSE target feature,
    // which every x86_64 target has.
    #[allow(unsafe_code)]
    unsafe {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<_MM_HINT_T0>(p);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// The closest crossing found so far: distance, tie-break key (the triangle's id; `u32::MAX`,
/// which no triangle has: none) and whether the ray meets the triangle's front.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Best {
    pub(crate) t: f32,
    pub(crate) key: u32,
    pub(crate) front: bool,
}

impl Best {
    /// No crossing yet; only crossings before `tmax` will count.
    fn new(tmax: f32) -> Best {
        Best {
            t: tmax,
            key: u32::MAX,
            front: false,
        }
    }

    /// Keeps the crossing at `t` (key `key`, `front`) if it is closer, or as close with a
    /// lower key: crossings clamped to distance 0 at a ray's origin tie exactly, and the rule
    /// makes the result independent of the visiting order.
    #[inline(always)]
    pub(crate) fn offer(&mut self, t: f32, key: u32, front: bool) {
        if t < self.t || (t == self.t && self.key != u32::MAX && key < self.key) {
            *self = Best { t, key, front };
        }
    }

    /// Whether a crossing was kept.
    pub(crate) fn found(&self) -> bool {
        self.key != u32::MAX
    }
}

/// The leaf test of a traversal, on the run of packets of a leaf item (see
/// [`crate::wide::packets`]).
pub(crate) trait LeafTest {
    /// Offers the crossings of packets `run` that count to `best` (closest hit).
    fn closest(&mut self, run: Range<usize>, best: &mut Best);
    /// Whether a crossing of packets `run` counts (any hit).
    fn any(&mut self, run: Range<usize>) -> bool;
}

/// The hit children of a node test (`mask` of them, entry distances `enter`), prefetched: the
/// nearest is returned, the others are pushed on the stack nearest last (popped first).
#[inline(always)]
fn visit_hits(
    nodes: &[Node],
    packs: &[Packet],
    node: &Node,
    enter: [f32; WIDTH],
    mut mask: u32,
    stack: &mut (impl Stack + ?Sized),
    sp: &mut usize,
) -> Option<Entry> {
    if mask == 0 {
        return None;
    }
    let i = mask.trailing_zeros() as usize & (WIDTH - 1);
    mask &= mask - 1;
    let first = (enter[i], node.items[i]);
    prefetch_item(nodes, packs, first.1);
    if mask == 0 {
        return Some(first);
    }
    let i = mask.trailing_zeros() as usize & (WIDTH - 1);
    mask &= mask - 1;
    let second = (enter[i], node.items[i]);
    prefetch_item(nodes, packs, second.1);
    let (near, far) = if second.0 < first.0 {
        (second, first)
    } else {
        (first, second)
    };
    if mask == 0 {
        *stack.at(*sp) = far;
        *sp += 1;
        return Some(near);
    }
    // three or more: sorted insertion by decreasing distance above `start`
    let start = *sp;
    *stack.at(start) = far;
    *stack.at(start + 1) = near;
    *sp += 2;
    while mask != 0 {
        let i = mask.trailing_zeros() as usize & (WIDTH - 1);
        mask &= mask - 1;
        let item = node.items[i];
        prefetch_item(nodes, packs, item);
        let t = enter[i];
        let mut j = *sp;
        while j > start && stack.at(j - 1).0 < t {
            *stack.at(j) = *stack.at(j - 1);
            j -= 1;
        }
        *stack.at(j) = (t, item);
        *sp += 1;
    }
    *sp -= 1;
    Some(*stack.at(*sp))
}

/// Closest hit: `leaves.closest` offers the crossings of each packet reached to the best so
/// far. Returns the best crossing before `ray.tmax`. `stack` has at least
/// [`crate::wide::Wide::stack`] entries.
#[inline(always)]
pub(crate) fn closest(
    isa: impl NodeTest,
    nodes: &[Node],
    packs: &[Packet],
    ray: &NodeRay,
    stack: &mut (impl Stack + ?Sized),
    leaves: &mut impl LeafTest,
) -> Best {
    let mut walk = Walk::new(ray);
    while walk.step(isa, nodes, packs, ray, stack, leaves) {}
    walk.best
}

/// A closest-hit traversal in progress, advanced one node or leaf at a time by
/// [`Walk::step`]. (Written as a state machine, the loop compiles to 5% fewer instructions per
/// ray than as one function. Interleaving the steps of four rays, to overlap their cache
/// misses, was tried: 40% more instructions per ray and slower on every benchmark scene.)
#[derive(Clone, Copy, Debug)]
struct Walk {
    /// The closest crossing so far.
    best: Best,
    /// Entries on the stack.
    sp: usize,
    /// The item to visit next without going through the stack.
    next: Option<Entry>,
}

impl Walk {
    /// The traversal of `ray`, at the root.
    #[inline(always)]
    fn new(ray: &NodeRay) -> Walk {
        Walk {
            best: Best::new(ray.tmax),
            sp: 0,
            next: Some((ray.tmin, 0)),
        }
    }

    /// Visits the next node or leaf of the traversal of `ray` (on its own `stack`); `false`
    /// when there is none left, and `best` is the closest hit.
    #[inline(always)]
    fn step(
        &mut self,
        isa: impl NodeTest,
        nodes: &[Node],
        packs: &[Packet],
        ray: &NodeRay,
        stack: &mut (impl Stack + ?Sized),
        leaves: &mut impl LeafTest,
    ) -> bool {
        let item = match self.next.take() {
            Some((_, item)) => item,
            None => loop {
                if self.sp == 0 {
                    return false;
                }
                self.sp -= 1;
                let (t, item) = *stack.at(self.sp);
                if t <= self.best.t {
                    break item;
                }
            },
        };
        if item & LEAF != 0 {
            leaves.closest(packets(item), &mut self.best);
            return true;
        }
        let node = &nodes[item as usize];
        let (enter, mask) = isa.intersect(node, ray, self.best.t);
        self.next = visit_hits(nodes, packs, node, enter, mask, stack, &mut self.sp);
        true
    }
}

/// Any hit: `true` as soon as `leaves.any` is for a packet reached. `mid` is the node ray's
/// distance to the middle of the segment. `stack` as for [`closest`].
///
/// Children are not sorted by distance: any blocker will do, and a blocker is likeliest
/// where the segment is farthest from its ends, which sit on surfaces facing the segment's
/// free space (or, for a segment that leaves an end below its surface, at the far side of
/// the solid it enters, which the segment's other children reach as well). The child visited
/// next is the first inner node (in slot order) whose stretch of the segment holds its middle,
/// else the first leaf that holds it, else the first inner node, else the first leaf; the
/// others are pushed in slot order, those that hold the middle last (so popped first). Every
/// one of them is prefetched at once, the one visited next first, so that its lines do not
/// queue behind the others'. Going down an inner node first gives the packets of the leaves
/// met on the way time to arrive before they are tested.
///
/// Measured in one process against the version before, which went down the first inner node
/// in slot order (alternating chunks of 30k segment pairs of the Embree comparison's rooms,
/// median ratio over chunks): 1.20-1.30 times as fast on mcrad's own pairs and the facing
/// ones, 1.08-1.16 on Embree's segments (see `PERFORMANCE.md`, *Occlusion*). Orders tried
/// before that one: the first leaf or node in slot order, 2% slower; the nearest child first
/// (the closest-hit order) visits 16% fewer nodes and 6% fewer packets and is 23% slower; the
/// children that hold an end point of the segment first, 15% fewer nodes, 8-14% slower; the
/// last child first (Embree's order) and the pushed children popped first slot first, 6-7%
/// more packets, 1-3% slower; prefetching only the two or four children popped first (and the
/// next one at each pop), 3-7% slower.
#[inline(always)]
pub(crate) fn any(
    isa: impl NodeTest,
    nodes: &[Node],
    packs: &[Packet],
    ray: &NodeRay,
    mid: f32,
    stack: &mut (impl Stack + ?Sized),
    leaves: &mut impl LeafTest,
) -> bool {
    let mut sp = 0;
    let mut next = Some(0u32);
    loop {
        let item = match next.take() {
            Some(item) => item,
            None => {
                if sp == 0 {
                    return false;
                }
                sp -= 1;
                stack.at(sp).1
            }
        };
        if item & LEAF != 0 {
            if leaves.any(packets(item)) {
                return true;
            }
            continue;
        }
        let node = &nodes[item as usize];
        let (mut mask, hold) = isa.holding(node, ray, ray.tmax, mid);
        if mask == 0 {
            continue;
        }
        let inner = mask & isa.inner(node);
        let pick = if inner & hold != 0 {
            inner & hold
        } else if hold != 0 {
            hold
        } else if inner != 0 {
            inner
        } else {
            mask
        };
        let i = pick.trailing_zeros() as usize & (WIDTH - 1);
        mask &= !(1 << i);
        let first = node.items[i];
        prefetch_item(nodes, packs, first);
        // those that do not hold the midpoint first, so that those that do are popped first
        for mut part in [mask & !hold, mask & hold] {
            while part != 0 {
                let i = part.trailing_zeros() as usize & (WIDTH - 1);
                part &= part - 1;
                let item = node.items[i];
                prefetch_item(nodes, packs, item);
                *stack.at(sp) = (0.0, item);
                sp += 1;
            }
        }
        next = Some(first);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use obvhs::aabb::Aabb;

    /// The three node tests find the same inner children: those whose item is a node index
    /// (not a leaf, not an empty slot).
    #[test]
    fn inner_children_are_the_node_items_on_every_instruction_set() {
        let mut next = crate::testing::uniforms(5);
        for _ in 0..1000 {
            let mut node = Node::empty();
            let mut expected = 0;
            for (i, item) in node.items.iter_mut().enumerate() {
                let r = next();
                *item = if r < 0.3 {
                    u32::MAX
                } else if r < 0.6 {
                    crate::wide::LEAF | (next() * (1 << 29) as f32) as u32
                } else {
                    expected |= 1 << i;
                    (next() * (1u32 << 31) as f32) as u32 & !LEAF
                };
            }
            assert_eq!(Sse.inner(&node), expected);
            #[cfg(target_arch = "x86_64")]
            if let Some(avx2) = Avx2::detect() {
                assert_eq!(avx2.inner(&node), expected);
                if let Some(avx512) = Avx512::detect() {
                    assert_eq!(avx512.inner(&node), expected);
                }
            }
        }
    }

    /// Every node test finds the children that an `f64` slab test finds (where that is not
    /// within rounding of a box's edge), and the fused ones (AVX2, AVX-512) the very same
    /// children at the very same distances; all three find the same children holding a given
    /// distance, whose boxes hold the ray's point there.
    #[test]
    fn node_tests_agree_with_each_other_and_with_f64() {
        let mut next = crate::testing::uniforms(7);
        let (mut checked, mut hits, mut holds) = (0, 0, 0);
        for round in 0..1000 {
            let mut node = Node::empty();
            let mut boxes = [None; WIDTH];
            // some slots stay empty
            for (i, slot) in boxes.iter_mut().enumerate() {
                if (i + round) % 5 == 4 {
                    continue;
                }
                let lo = Vec3A::new(next(), next(), next()) * 200.0 - 100.0;
                let size = Vec3A::new(next(), next(), next()) * 100.0;
                let aabb = Aabb::new(lo, lo + size);
                node.set(i, &aabb, i as u32);
                *slot = Some(aabb);
            }
            let origin = Vec3A::new(next(), next(), next()) * 300.0 - 150.0;
            // towards the middle of the boxes
            let target = Vec3A::new(next(), next(), next()) * 80.0 - 40.0;
            let dir = (target - origin).normalize();
            let tmax = if round % 3 == 0 { f32::INFINITY } else { 150.0 };
            let ray = NodeRay::new(origin, dir, 0.0, tmax);
            let (enter, mask) = Sse.intersect(&node, &ray, tmax);
            for (i, slot) in boxes.iter().enumerate() {
                let Some(aabb) = slot else {
                    assert_eq!(mask >> i & 1, 0, "empty slot {i} hit");
                    continue;
                };
                // the f64 slab test
                let (mut t0, mut t1) = (0.0f64, tmax as f64);
                for k in 0..3 {
                    let inv = 1.0 / (dir[k] as f64);
                    let a = (aabb.min[k] as f64 - origin[k] as f64) * inv;
                    let b = (aabb.max[k] as f64 - origin[k] as f64) * inv;
                    t0 = t0.max(a.min(b));
                    t1 = t1.min(a.max(b));
                }
                if (t1 - t0).abs() < 1e-3 {
                    continue;
                }
                checked += 1;
                let hit = t0 <= t1;
                hits += hit as usize;
                assert_eq!(mask >> i & 1 == 1, hit, "round {round} child {i}");
                if hit {
                    assert!((enter[i] as f64 - t0).abs() < 1e-3, "{} {t0}", enter[i]);
                }
            }
            // the children whose stretch holds `t`: the same on every instruction set, and
            // those of the `f64` test away from rounding
            let t = next() * 200.0;
            let (hit, hold) = Sse.holding(&node, &ray, tmax, t);
            assert_eq!(hit, mask, "round {round}: holding");
            assert_eq!(hold & !mask, 0);
            for (i, slot) in boxes.iter().enumerate() {
                let Some(aabb) = slot else { continue };
                if hold >> i & 1 == 1 {
                    let p = (origin + dir * t).as_dvec3();
                    let outside = (aabb.min.as_dvec3() - p)
                        .max(p - aabb.max.as_dvec3())
                        .max_element();
                    assert!(outside < 1e-3, "round {round} child {i}: {outside}");
                    holds += 1;
                }
            }
            #[cfg(target_arch = "x86_64")]
            if let Some(avx2) = Avx2::detect() {
                assert_eq!(
                    avx2.holding(&node, &ray, tmax, t),
                    (hit, hold),
                    "round {round}"
                );
                if let Some(avx512) = Avx512::detect() {
                    assert_eq!(avx512.holding(&node, &ray, tmax, t), (hit, hold));
                }
                let fused = avx2.intersect(&node, &ray, tmax);
                assert_eq!(fused.1, mask, "round {round}: AVX2 and SSE");
                if let Some(avx512) = Avx512::detect() {
                    let wide = avx512.intersect(&node, &ray, tmax);
                    assert_eq!(wide.1, fused.1, "round {round}: AVX-512 and AVX2");
                    for i in 0..WIDTH {
                        if fused.1 >> i & 1 == 1 {
                            assert_eq!(wide.0[i].to_bits(), fused.0[i].to_bits());
                        }
                    }
                }
            }
        }
        assert!(
            checked > 10000 && hits > 800 && holds > 80,
            "{checked} checked, {hits} hits, {holds} holding"
        );
    }
}
