//! Our own traversal of obvhs's compressed 8-wide nodes ([`CwBvhNode`]).
//!
//! obvhs's `ray_traverse` visits children in ray-octant order and keeps no distances on its
//! stack, so a subtree found behind the closest hit so far is still fetched (a cache miss per
//! 80-byte node on large scenes) before it is rejected. Here every stack entry carries the
//! distance at which the ray enters its box: children are visited nearest first and entries
//! farther than the closest hit are dropped without touching their memory. Leaves are entries
//! too, so their triangles are tested in distance order.
//!
//! The box test is obvhs's (dequantised child boxes, `obvhs::ray::safe_inverse` reciprocals of
//! the direction) without its `t >= 1e-4` entry clamp: it enters a superset of the boxes
//! obvhs enters, so every hit it could find is still reached.

use glam::Vec3A;
use obvhs::{cwbvh::node::CwBvhNode, ray::safe_inverse};

/// Flag of a stack entry that is a leaf (a run of triangle slots) rather than a node.
const LEAF: u32 = 1 << 31;
/// Bits of a leaf entry holding its first slot (the count sits in bits 29-30).
const SLOT_MASK: u32 = (1 << 29) - 1;
/// Number of triangle slots a leaf entry can address: the build rejects more.
pub(crate) const MAX_SLOTS: usize = 1 << 29;

/// A ray as the node test sees it: origin, reciprocal direction, and the interval of `t`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct NodeRay {
    origin: Vec3A,
    inv: Vec3A,
    /// Which axes have a negative direction (the near side of a box is then its max side).
    neg: [bool; 3],
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
        NodeRay {
            origin,
            inv,
            neg: [inv.x < 0.0, inv.y < 0.0, inv.z < 0.0],
            tmin,
            tmax,
        }
    }
}

/// A stack entry: the distance at which the ray enters the box, and a node index or a leaf.
pub(crate) type Entry = (f32, u32);

/// Upper bound of the stack depth a traversal of `nodes` needs (each node pushes at most 8
/// entries and pops one), from the depth of the hierarchy.
pub(crate) fn stack_bound(nodes: &[CwBvhNode]) -> usize {
    if nodes.is_empty() {
        return 1;
    }
    let mut max_depth = 1;
    let mut todo = vec![(0u32, 1usize)];
    while let Some((index, depth)) = todo.pop() {
        max_depth = max_depth.max(depth);
        let node = &nodes[index as usize];
        for rank in 0..node.imask.count_ones() {
            todo.push((node.child_base_idx + rank, depth + 1));
        }
    }
    7 * max_depth + 8
}

/// The near and far planes of a slab: `(lo, hi)`, swapped for a negative direction.
#[inline(always)]
fn pick<'a>(neg: bool, lo: &'a [u8; 8], hi: &'a [u8; 8]) -> (&'a [u8; 8], &'a [u8; 8]) {
    if neg { (hi, lo) } else { (lo, hi) }
}

/// The hit children of `node` for a ray whose closest hit so far is at `tmax`, as stack
/// entries (entry distance, node index or leaf) in `out`; returns how many.
#[inline(always)]
fn intersect_node(node: &CwBvhNode, ray: &NodeRay, tmax: f32, out: &mut [Entry; 8]) -> usize {
    let e = Vec3A::new(
        f32::from_bits((node.e[0] as u32) << 23),
        f32::from_bits((node.e[1] as u32) << 23),
        f32::from_bits((node.e[2] as u32) << 23),
    );
    // child box planes are `p + e * q`: the ray reaches plane `q` at `q * a + b`
    let a = e * ray.inv;
    let b = (Vec3A::from(node.p) - ray.origin) * ray.inv;
    let (xn, xf) = pick(ray.neg[0], &node.child_min_x, &node.child_max_x);
    let (yn, yf) = pick(ray.neg[1], &node.child_min_y, &node.child_max_y);
    let (zn, zf) = pick(ray.neg[2], &node.child_min_z, &node.child_max_z);
    let (near, far, a, b) = ([xn, yn, zn], [xf, yf, zf], a.into(), b.into());
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    // SAFETY: `slab_test` is safe code whose only requirement is the SSE2 target feature,
    // which this build enables (the `cfg` above; every x86_64 target has it).
    #[allow(unsafe_code)]
    let (enter, mut mask) = unsafe { slab_test(&node.child_meta, near, far, a, b, ray.tmin, tmax) };
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    let (enter, mut mask) = slab_test(&node.child_meta, near, far, a, b, ray.tmin, tmax);
    let mut n = 0;
    while mask != 0 {
        let i = mask.trailing_zeros();
        mask &= mask - 1;
        let meta = node.child_meta[i as usize];
        let item = if node.imask & (1 << i) != 0 {
            node.child_base_idx + (node.imask as u32 & ((1 << i) - 1)).count_ones()
        } else {
            let count = (meta & 0b1110_0000).count_ones();
            LEAF | ((count - 1) << 29) | (node.primitive_base_idx + (meta & 0b1_1111) as u32)
        };
        out[n] = (enter[i as usize], item);
        n += 1;
    }
    n
}

/// The slab test of 8 quantised boxes: `near[k][i] * a[k] + b[k]` is where the ray reaches the
/// near plane of child `i` on axis `k` (likewise `far`). Returns the entry distances and the
/// mask of children whose interval `[max(near, tmin), min(far, tmax)]` is not empty, leaving
/// out empty slots (`meta` 0: their boxes are meaningless).
///
/// Every lane computes `q as f32 * a + b` (a product, then a sum: no fused multiply-add), the
/// arithmetic of obvhs's own node test, so the same boxes are hit on every target.
#[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
#[target_feature(enable = "sse2")]
#[inline]
fn slab_test(
    meta: &[u8; 8],
    near: [&[u8; 8]; 3],
    far: [&[u8; 8]; 3],
    a: [f32; 3],
    b: [f32; 3],
    tmin: f32,
    tmax: f32,
) -> ([f32; 8], u32) {
    use std::arch::x86_64::*;
    let planes = |q: &[u8; 8], k: usize| {
        let zero = _mm_setzero_si128();
        let words = _mm_unpacklo_epi8(_mm_cvtsi64_si128(i64::from_le_bytes(*q)), zero);
        let lo = _mm_cvtepi32_ps(_mm_unpacklo_epi16(words, zero));
        let hi = _mm_cvtepi32_ps(_mm_unpackhi_epi16(words, zero));
        let (a, b) = (_mm_set1_ps(a[k]), _mm_set1_ps(b[k]));
        (
            _mm_add_ps(_mm_mul_ps(lo, a), b),
            _mm_add_ps(_mm_mul_ps(hi, a), b),
        )
    };
    let (xn, yn, zn) = (planes(near[0], 0), planes(near[1], 1), planes(near[2], 2));
    let (xf, yf, zf) = (planes(far[0], 0), planes(far[1], 1), planes(far[2], 2));
    let (t0, t1) = (_mm_set1_ps(tmin), _mm_set1_ps(tmax));
    let enter = |x, y, z| _mm_max_ps(_mm_max_ps(x, y), _mm_max_ps(z, t0));
    let leave = |x, y, z| _mm_min_ps(_mm_min_ps(x, y), _mm_min_ps(z, t1));
    let (e0, e1) = (enter(xn.0, yn.0, zn.0), enter(xn.1, yn.1, zn.1));
    let (l0, l1) = (leave(xf.0, yf.0, zf.0), leave(xf.1, yf.1, zf.1));
    let hit = _mm_movemask_ps(_mm_cmple_ps(e0, l0)) | (_mm_movemask_ps(_mm_cmple_ps(e1, l1)) << 4);
    let meta = _mm_cvtsi64_si128(i64::from_le_bytes(*meta));
    let empty = _mm_movemask_epi8(_mm_cmpeq_epi8(meta, _mm_setzero_si128())) & 0xff;
    let mask = hit & !empty;
    let (e0, e1) = (glam::Vec4::from(e0), glam::Vec4::from(e1));
    let mut entries = [0.0; 8];
    entries[..4].copy_from_slice(&e0.to_array());
    entries[4..].copy_from_slice(&e1.to_array());
    (entries, mask as u32)
}

/// [`slab_test`] without SIMD intrinsics (same arithmetic).
#[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
#[inline(always)]
fn slab_test(
    meta: &[u8; 8],
    near: [&[u8; 8]; 3],
    far: [&[u8; 8]; 3],
    a: [f32; 3],
    b: [f32; 3],
    tmin: f32,
    tmax: f32,
) -> ([f32; 8], u32) {
    let mut entries = [0.0; 8];
    let mut mask = 0;
    for i in 0..8 {
        let t = |q: &[u8; 8], k: usize| q[i] as f32 * a[k] + b[k];
        let enter = t(near[0], 0)
            .max(t(near[1], 1))
            .max(t(near[2], 2))
            .max(tmin);
        let leave = t(far[0], 0).min(t(far[1], 1)).min(t(far[2], 2)).min(tmax);
        entries[i] = enter;
        mask |= ((enter <= leave && meta[i] != 0) as u32) << i;
    }
    (entries, mask)
}

/// Asks the CPU to start loading the cache lines of `item` (a node, or a leaf's triangles)
/// while the traversal goes on: the entries of a node's hit children are independent loads,
/// and on a large scene each is a cache miss of up to a few hundred nanoseconds.
#[inline(always)]
fn prefetch_item<T>(nodes: &[CwBvhNode], leaves: &[T], item: u32) {
    // (address arithmetic only: no bounds checks, nothing is dereferenced)
    let (first, bytes) = if item & LEAF == 0 {
        let node = nodes.as_ptr().wrapping_add(item as usize);
        (node.cast::<i8>(), size_of::<CwBvhNode>())
    } else {
        let run = slots(item);
        let first = leaves.as_ptr().wrapping_add(run.start);
        (first.cast::<i8>(), run.len() * size_of::<T>())
    };
    prefetch_lines(first, bytes);
}

/// Prefetches the cache lines of `bytes` bytes from `first` (up to 192 bytes: an 80-byte node
/// spans 2 or 3 lines, a leaf's run of 64-byte, line-aligned triangles 1 to 3).
#[inline(always)]
fn prefetch_lines(first: *const i8, bytes: usize) {
    prefetch(first);
    if bytes > 64 {
        // (for up to 192 bytes these three addresses touch every line)
        prefetch(first.wrapping_add(64));
        prefetch(first.wrapping_add(bytes - 1));
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

/// The slots of a leaf entry.
#[inline(always)]
fn slots(item: u32) -> std::ops::Range<usize> {
    let first = (item & SLOT_MASK) as usize;
    first..first + ((item >> 29) & 3) as usize + 1
}

/// Closest hit: `test(slot)` returns the distance of a crossing that counts (or `INFINITY`)
/// and a tie-break key; the smallest distance below `ray.tmax` wins, the lowest key among
/// equal distances (crossings clamped to distance 0 at a ray's origin tie exactly), so that
/// the result does not depend on the visiting order, which the rounding of entry distances
/// may change. `stack` has at least [`stack_bound`] entries.
#[inline(always)]
pub(crate) fn closest<T>(
    nodes: &[CwBvhNode],
    leaves: &[T],
    ray: &NodeRay,
    stack: &mut [Entry],
    mut test: impl FnMut(usize) -> (f32, u32),
) -> Option<(usize, f32)> {
    let mut best: Option<(usize, u32)> = None;
    let mut best_t = ray.tmax;
    let mut sp = 0;
    let mut kids = [(0.0f32, 0u32); 8];
    let mut current = 0u32;
    loop {
        let n = intersect_node(&nodes[current as usize], ray, best_t, &mut kids);
        for &(_, item) in &kids[..n] {
            prefetch_item(nodes, leaves, item);
        }
        sort_far_to_near(&mut kids[..n]);
        stack[sp..sp + n].copy_from_slice(&kids[..n]);
        sp += n;
        loop {
            if sp == 0 {
                return best.map(|(slot, _)| (slot, best_t));
            }
            sp -= 1;
            let (t, item) = stack[sp];
            if t > best_t {
                continue;
            }
            if item & LEAF == 0 {
                current = item;
                break;
            }
            for slot in slots(item) {
                let (t, key) = test(slot);
                // on a tie the lowest key wins, whatever order the boxes were visited in
                if t < best_t || (t == best_t && best.is_some_and(|(_, k)| key < k)) {
                    best_t = t;
                    best = Some((slot, key));
                }
            }
        }
    }
}

/// Any hit: `true` as soon as `test(slot)` does. Visits children nearest first too (a
/// blocker near the start ends the search early). `stack` as for [`closest`].
#[inline(always)]
pub(crate) fn any<T>(
    nodes: &[CwBvhNode],
    leaves: &[T],
    ray: &NodeRay,
    stack: &mut [Entry],
    mut test: impl FnMut(usize) -> bool,
) -> bool {
    let mut sp = 0;
    let mut kids = [(0.0f32, 0u32); 8];
    let mut current = 0u32;
    loop {
        let n = intersect_node(&nodes[current as usize], ray, ray.tmax, &mut kids);
        for &(_, item) in &kids[..n] {
            prefetch_item(nodes, leaves, item);
        }
        sort_far_to_near(&mut kids[..n]);
        stack[sp..sp + n].copy_from_slice(&kids[..n]);
        sp += n;
        loop {
            if sp == 0 {
                return false;
            }
            sp -= 1;
            let item = stack[sp].1;
            if item & LEAF == 0 {
                current = item;
                break;
            }
            if slots(item).any(&mut test) {
                return true;
            }
        }
    }
}

/// Insertion sort of a node's hit children by decreasing entry distance (the nearest is pushed
/// last and popped first).
#[inline(always)]
fn sort_far_to_near(kids: &mut [Entry]) {
    for i in 1..kids.len() {
        let mut j = i;
        while j > 0 && kids[j - 1].0 < kids[j].0 {
            kids.swap(j - 1, j);
            j -= 1;
        }
    }
}
