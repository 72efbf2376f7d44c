//! Single-ray traversal of the 8-wide BVH ([`crate::wide`]).
//!
//! Every stack entry carries the distance at which the ray enters its box: children are
//! visited nearest first and entries farther than the closest hit so far are dropped without
//! touching their memory. Leaves are entries too, so their packets are tested in distance
//! order. The child nodes and packets a node test finds are prefetched at once: on a large
//! scene each is a cache miss, and they are independent loads.
//!
//! The slab test runs on four children per SSE register (through glam's `Vec4`), with the
//! reciprocal direction of `obvhs::ray::safe_inverse` (no infinities, so an empty box
//! `[+inf, -inf]` never passes and no lane computes a NaN).

use glam::{Vec3A, Vec4};
use obvhs::ray::safe_inverse;

use crate::wide::{LEAF, Node, WIDTH, packets};

/// A ray as the node test sees it: origin, reciprocal direction, and the interval of `t`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct NodeRay {
    /// `-origin * inv`, per axis, in all lanes: the plane `q` is reached at `q * inv + this`.
    offset: [Vec4; 3],
    inv: [Vec4; 3],
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
            offset: [0, 1, 2].map(|k| Vec4::splat(offset[k])),
            inv: [0, 1, 2].map(|k| Vec4::splat(inv[k])),
            near: [0, 1, 2].map(|k| 2 * k + neg[k] as usize),
            far: [0, 1, 2].map(|k| 2 * k + 1 - neg[k] as usize),
            tmin,
            tmax,
        }
    }
}

/// A stack entry: the distance at which the ray enters the box, and a node index or a leaf.
pub(crate) type Entry = (f32, u32);

/// The children of `node` whose box the ray enters before `tmax`: their entry distances
/// and the mask of them (bit `i` for child `i`).
#[inline(always)]
fn intersect_node(node: &Node, ray: &NodeRay, tmax: f32) -> ([Vec4; 2], u32) {
    let t0 = Vec4::splat(ray.tmin);
    let t1 = Vec4::splat(tmax);
    let p = &node.planes;
    let half = |h: usize| {
        let at = |plane: usize, k: usize| p[plane][h] * ray.inv[k] + ray.offset[k];
        let enter = at(ray.near[0], 0)
            .max(at(ray.near[1], 1))
            .max(at(ray.near[2], 2).max(t0));
        let leave = at(ray.far[0], 0)
            .min(at(ray.far[1], 1))
            .min(at(ray.far[2], 2).min(t1));
        (enter, enter.cmple(leave).bitmask())
    };
    let (e0, m0) = half(0);
    let (e1, m1) = half(1);
    ([e0, e1], m0 | (m1 << 4))
}

/// Asks the CPU to start loading the cache lines of `item` (a node, or a leaf's packets)
/// while the traversal goes on.
#[inline(always)]
fn prefetch_item<P>(nodes: &[Node], packs: &[P], item: u32) {
    // (address arithmetic only: no bounds checks, nothing is dereferenced)
    let (first, bytes) = if item & LEAF == 0 {
        let node = nodes.as_ptr().wrapping_add(item as usize);
        (node.cast::<i8>(), size_of::<Node>())
    } else {
        let run = packets(item);
        let first = packs.as_ptr().wrapping_add(run.start);
        (first.cast::<i8>(), run.len() * size_of::<P>())
    };
    let mut offset = 0;
    while offset < bytes {
        prefetch(first.wrapping_add(offset));
        offset += 64;
    }
    prefetch(first.wrapping_add(bytes - 1));
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

/// The closest crossing found so far: distance, tie-break key and slot (`usize::MAX`: none).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Best {
    pub(crate) t: f32,
    pub(crate) key: u32,
    pub(crate) slot: usize,
}

impl Best {
    /// No crossing yet; only crossings before `tmax` will count.
    fn new(tmax: f32) -> Best {
        Best {
            t: tmax,
            key: u32::MAX,
            slot: usize::MAX,
        }
    }

    /// Keeps the crossing at `t` (key `key`, slot `slot`) if it is closer, or as close with a
    /// lower key: crossings clamped to distance 0 at a ray's origin tie exactly, and the rule
    /// makes the result independent of the visiting order.
    #[inline(always)]
    pub(crate) fn offer(&mut self, t: f32, key: u32, slot: usize) {
        if t < self.t || (t == self.t && self.slot != usize::MAX && key < self.key) {
            *self = Best { t, key, slot };
        }
    }
}

/// The hit children of a node test, nearest last, pushed on the stack.
#[inline(always)]
fn push_hits<P>(
    nodes: &[Node],
    packs: &[P],
    node: &Node,
    enter: [Vec4; 2],
    mut mask: u32,
    stack: &mut [Entry],
    sp: &mut usize,
) {
    let enter: [f32; WIDTH] = {
        let (a, b) = (enter[0].to_array(), enter[1].to_array());
        [a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3]]
    };
    let start = *sp;
    while mask != 0 {
        let i = mask.trailing_zeros() as usize;
        mask &= mask - 1;
        let item = node.items[i];
        prefetch_item(nodes, packs, item);
        // insertion by decreasing distance (the nearest is popped first)
        let t = enter[i];
        let mut j = *sp;
        while j > start && stack[j - 1].0 < t {
            stack[j] = stack[j - 1];
            j -= 1;
        }
        stack[j] = (t, item);
        *sp += 1;
    }
}

/// Closest hit: `test(packet, &mut best)` offers the packet's crossings to `best`. Returns the
/// best crossing before `ray.tmax`. `stack` has at least [`crate::wide::Wide::stack`] entries.
#[inline(always)]
pub(crate) fn closest<P>(
    nodes: &[Node],
    packs: &[P],
    ray: &NodeRay,
    stack: &mut [Entry],
    mut test: impl FnMut(usize, &mut Best),
) -> Best {
    let mut best = Best::new(ray.tmax);
    let mut sp = 0;
    let mut current = 0u32;
    loop {
        let node = &nodes[current as usize];
        let (enter, mask) = intersect_node(node, ray, best.t);
        push_hits(nodes, packs, node, enter, mask, stack, &mut sp);
        loop {
            if sp == 0 {
                return best;
            }
            sp -= 1;
            let (t, item) = stack[sp];
            if t > best.t {
                continue;
            }
            if item & LEAF == 0 {
                current = item;
                break;
            }
            for p in packets(item) {
                test(p, &mut best);
            }
        }
    }
}

/// Any hit: `true` as soon as `test(packet)` does. Visits children nearest first too (a
/// blocker near the start ends the search early). `stack` as for [`closest`].
#[inline(always)]
pub(crate) fn any<P>(
    nodes: &[Node],
    packs: &[P],
    ray: &NodeRay,
    stack: &mut [Entry],
    mut test: impl FnMut(usize) -> bool,
) -> bool {
    let mut sp = 0;
    let mut current = 0u32;
    loop {
        let node = &nodes[current as usize];
        let (enter, mask) = intersect_node(node, ray, ray.tmax);
        push_hits(nodes, packs, node, enter, mask, stack, &mut sp);
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
            if packets(item).any(&mut test) {
                return true;
            }
        }
    }
}
