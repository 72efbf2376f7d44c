//! The build of large scenes in chunks, so that its peak memory is bounded by a chunk's
//! working set plus the finished BVH, not by the whole scene's binary tree.
//!
//! The triangles are ordered along a Morton curve of their centroids (10 bits per axis in a
//! cube around the scene) and the ordered run is cut where the curve leaves an octree cell
//! (the highest bit in which the run's first and last codes differ; in the middle when they do
//! not differ), again and again, until every piece holds at most the chunk size: spatially
//! compact pieces, and a binary tree above them. Each piece is built and collapsed as a scene
//! of its own would be (obvhs's binary BVH, the optimal collapse), and its binary tree,
//! canonical triangles and plans are freed before the next one. The binary tree above the
//! pieces is then collapsed by the same dynamic programme, where a piece fills either one
//! child slot (its root node) or as many as its root has children (its root opened into the
//! node above), and the pieces are copied onto the final pages one by one, each freed once
//! copied.
//!
//! The chunk size is a constant, not a number of threads, so the BVH does not depend on the
//! thread count; scenes of at most one chunk are built as one, as before chunking.

use std::collections::VecDeque;

use glam::{DVec3, Vec3};
use obvhs::{BvhBuildParams, aabb::Aabb, triangle::Triangle};
use rayon::prelude::*;

use crate::{
    frame::Frame,
    pages::Pages,
    wide::{Chunk, Costs, EMPTY, LEAF, Node, Plan, WIDTH, Wide},
};

/// Bits per axis of the Morton codes that order the triangles.
const BITS: u32 = 10;

/// A node of the binary tree above the chunks.
enum Top {
    /// Chunk `k` (in chunk order).
    Chunk(usize),
    /// Nodes `[0]` and `[1]` of the top tree.
    Inner([usize; 2]),
}

/// How one child slot (or several) of a top wide node is filled.
#[derive(Clone, Copy)]
enum Slot {
    /// A top binary node that becomes a wide node of its own.
    Node(usize),
    /// Chunk `k`'s root node.
    Chunk(usize),
    /// Chunk `k`'s root's children (as many slots as it has), all leaves (see
    /// [`Chunk::openable`]).
    Open(usize),
}

/// The wide BVH of the `count` triangles `triangle(i)` (world units; `frame` maps them to
/// the canonical frame, where their boxes are padded by `pad`), tagged `ids[i]`, built with
/// obvhs's `params` in chunks of at most `chunk` triangles (`chunk > 8`; see the module
/// documentation).
pub(crate) fn build(
    count: usize,
    triangle: &(impl Fn(usize) -> [Vec3; 3] + Sync),
    ids: &[u32],
    frame: &Frame,
    pad: f32,
    params: BvhBuildParams,
    chunk: usize,
) -> Wide {
    let (order, ranges, top) = split(count, triangle, frame, chunk);
    let chunks: Vec<Chunk> = ranges
        .iter()
        .map(|range| {
            let members = &order[range.clone()];
            let tris: Vec<Triangle> = members
                .par_iter()
                .map(|&i| {
                    let t = triangle(i as usize);
                    Triangle {
                        v0: frame.canonical(t[0]).into(),
                        v1: frame.canonical(t[1]).into(),
                        v2: frame.canonical(t[2]).into(),
                    }
                })
                .collect();
            let local_ids: Vec<u32> = members.iter().map(|&i| ids[i as usize]).collect();
            let bvh2 = crate::bvh::build_bvh2_padded(&tris, params, pad);
            Wide::chunk(&bvh2, &tris, &local_ids)
        })
        .collect();
    drop(order);
    join(chunks, &top)
}

/// The triangles in Morton order, the ranges of that order that make the chunks, and the
/// binary tree above them (its root is node 0).
fn split(
    count: usize,
    triangle: &(impl Fn(usize) -> [Vec3; 3] + Sync),
    frame: &Frame,
    chunk: usize,
) -> (Vec<u32>, Vec<std::ops::Range<usize>>, Vec<Top>) {
    // the canonical frame is centred on the scene, its largest extent in [512, 1024): cells
    // of one canonical unit from -512 on
    let cells = f64::from(1u32 << BITS);
    // the Morton code above, the triangle below: sorting orders by code, then by index
    let mut keys: Vec<u64> = (0..count)
        .into_par_iter()
        .map(|i| {
            let [a, b, c] = triangle(i).map(|v| frame.canonical(v).as_dvec3());
            let cell = (a + b + c) / 3.0 + DVec3::splat(cells / 2.0);
            let q = |x: f64| (x.floor().clamp(0.0, cells - 1.0)) as u32;
            (u64::from(morton(q(cell.x), q(cell.y), q(cell.z))) << 32) | i as u64
        })
        .collect();
    keys.par_sort_unstable();
    let mut ranges = Vec::new();
    let mut top = Vec::new();
    cut(&keys, 0..count, chunk, &mut ranges, &mut top);
    let order = keys.into_iter().map(|k| k as u32).collect();
    (order, ranges, top)
}

/// Cuts `range` of the sorted `keys` (see [`split`]) into chunks, appending them to `ranges`
/// and the tree above them to `top`; returns the index of its top node.
fn cut(
    keys: &[u64],
    range: std::ops::Range<usize>,
    chunk: usize,
    ranges: &mut Vec<std::ops::Range<usize>>,
    top: &mut Vec<Top>,
) -> usize {
    let at = top.len();
    if range.len() <= chunk {
        top.push(Top::Chunk(ranges.len()));
        ranges.push(range);
        return at;
    }
    top.push(Top::Inner([0, 0]));
    let (first, last) = (keys[range.start] >> 32, keys[range.end - 1] >> 32);
    let middle = if first == last {
        range.start + range.len() / 2
    } else {
        // the first code with the highest differing bit set (the codes agree above it)
        let bit = 63 - (first ^ last).leading_zeros();
        let run = &keys[range.clone()];
        range.start + run.partition_point(|&k| (k >> 32) >> bit & 1 == 0)
    };
    let left = cut(keys, range.start..middle, chunk, ranges, top);
    let right = cut(keys, middle..range.end, chunk, ranges, top);
    top[at] = Top::Inner([left, right]);
    at
}

/// The Morton code of cell `(x, y, z)` ([`BITS`] bits each): their bits interleaved.
fn morton(x: u32, y: u32, z: u32) -> u32 {
    let spread = |v: u32| {
        let mut v = v & 0x3ff;
        v = (v | (v << 16)) & 0x0300_00ff;
        v = (v | (v << 8)) & 0x0300_f00f;
        v = (v | (v << 4)) & 0x030c_30c3;
        (v | (v << 2)) & 0x0924_9249
    };
    (spread(x) << 2) | (spread(y) << 1) | spread(z)
}

/// The wide BVH of the chunks under the binary tree `top`: the top collapsed by the optimal
/// collapse's programme, then the chunks copied below it onto the final pages in order.
fn join(chunks: Vec<Chunk>, top: &[Top]) -> Wide {
    // boxes, plans and costs of the top, children before parents
    let mut boxes = vec![Aabb::INVALID; top.len()];
    let mut plans: Vec<Option<Plan>> = vec![None; top.len()];
    let mut costs: Vec<Option<Costs>> = vec![None; top.len()];
    for b in (0..top.len()).rev() {
        // (`cut` numbers every node before its subtree)
        match top[b] {
            Top::Chunk(k) => {
                boxes[b] = chunks[k].aabb;
                costs[b] = Some(chunks[k].costs());
            }
            Top::Inner([l, r]) => {
                boxes[b] = boxes[l].union(&boxes[r]);
                let (Some(cl), Some(cr)) = (&costs[l], &costs[r]) else {
                    unreachable!("children come after their parent");
                };
                let (p, c) = Plan::inner(boxes[b].half_area().max(0.0), cl, cr);
                plans[b] = Some(p);
                costs[b] = Some(c);
            }
        }
    }
    let plan = |b: usize| plans[b].expect("inner top nodes are planned");
    // the top's wide nodes, breadth first: their binary node and their slots
    let mut wide_top: Vec<(usize, Vec<Slot>)> = Vec::new();
    let mut todo = VecDeque::from([(0usize, 0usize)]);
    let mut stack = 0;
    while let Some((b, load)) = todo.pop_front() {
        let mut slots = Vec::with_capacity(WIDTH);
        let p = plan(b);
        let Top::Inner([l, r]) = top[b] else {
            unreachable!("the top's wide nodes are inner nodes");
        };
        place(top, &plans, &chunks, l, p.left as usize, &mut slots);
        place(
            top,
            &plans,
            &chunks,
            r,
            (p.children - p.left) as usize,
            &mut slots,
        );
        let n: usize = slots
            .iter()
            .map(|s| match *s {
                Slot::Open(k) => chunks[k].slots,
                _ => 1,
            })
            .sum();
        stack = stack.max(load + n);
        for s in &slots {
            match *s {
                Slot::Node(c) => todo.push_back((c, load + n - 1)),
                Slot::Chunk(k) => stack = stack.max(load + n - 1 + chunks[k].stack),
                // (its leaves are slots of this node)
                Slot::Open(_) => {}
            }
        }
        wide_top.push((b, slots));
    }
    // where each chunk's nodes and packets go: local node j at `node_base[k] + j` (an opened
    // chunk's one node goes, and its leaves are in the node above)
    let opened: Vec<bool> = {
        let mut opened = vec![false; chunks.len()];
        for (_, slots) in &wide_top {
            for s in slots {
                if let Slot::Open(k) = *s {
                    opened[k] = true;
                }
            }
        }
        opened
    };
    let mut node_base = Vec::with_capacity(chunks.len());
    let mut packet_base = Vec::with_capacity(chunks.len());
    let (mut nodes, mut packets) = (wide_top.len(), 0);
    for (k, c) in chunks.iter().enumerate() {
        node_base.push(nodes);
        packet_base.push(packets);
        nodes += c.nodes.len() - usize::from(opened[k]);
        packets += c.packets.len();
    }
    // local item -> global item of chunk k
    let remap = |k: usize, item: u32| -> u32 {
        if item == EMPTY {
            EMPTY
        } else if item & LEAF != 0 {
            item + packet_base[k] as u32
        } else {
            (node_base[k] + item as usize) as u32
        }
    };
    let mut out_nodes: Pages<Node> = Pages::zeroed(nodes);
    let mut out_packets = Pages::zeroed(packets);
    // the top's wide nodes
    let index: std::collections::HashMap<usize, usize> = wide_top
        .iter()
        .enumerate()
        .map(|(i, (b, _))| (*b, i))
        .collect();
    for (i, (_, slots)) in wide_top.iter().enumerate() {
        let mut node = Node::empty();
        let mut at = 0;
        for s in slots {
            match *s {
                Slot::Node(c) => {
                    node.set(at, &boxes[c], index[&c] as u32);
                    at += 1;
                }
                Slot::Chunk(k) => {
                    node.set(at, &chunks[k].aabb, node_base[k] as u32);
                    at += 1;
                }
                Slot::Open(k) => {
                    let root = &chunks[k].nodes[0];
                    for j in (0..WIDTH).filter(|&j| root.items[j] != EMPTY) {
                        let (aabb, item) = root.child(j);
                        node.set(at, &aabb, remap(k, item));
                        at += 1;
                    }
                }
            }
        }
        out_nodes[i] = node;
    }
    // the chunks, each freed once copied
    for (k, c) in chunks.into_iter().enumerate() {
        if !opened[k] {
            let to = &mut out_nodes[node_base[k]..node_base[k] + c.nodes.len()];
            for (slot, node) in to.iter_mut().zip(c.nodes.iter()) {
                let mut node = *node;
                for item in &mut node.items {
                    *item = remap(k, *item);
                }
                *slot = node;
            }
        }
        out_packets[packet_base[k]..packet_base[k] + c.packets.len()].copy_from_slice(&c.packets);
    }
    Wide {
        nodes: out_nodes,
        packets: out_packets,
        stack,
    }
}

/// Appends to `slots` the best `i` slots (or fewer) of top node `b`.
fn place(
    top: &[Top],
    plans: &[Option<Plan>],
    chunks: &[Chunk],
    b: usize,
    i: usize,
    slots: &mut Vec<Slot>,
) {
    match top[b] {
        Top::Chunk(k) => slots.push(if chunks[k].openable() && i >= chunks[k].slots {
            Slot::Open(k)
        } else {
            Slot::Chunk(k)
        }),
        Top::Inner([l, r]) => {
            let plan = plans[b].expect("inner top nodes are planned");
            let mut i = i;
            while i > 1 && plan.split[i - 1] == 0 {
                i -= 1;
            }
            if i == 1 {
                slots.push(Slot::Node(b));
            } else {
                let k = plan.split[i - 1] as usize;
                place(top, plans, chunks, l, k, slots);
                place(top, plans, chunks, r, i - k, slots);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_codes_interleave_the_bits() {
        assert_eq!(morton(1, 0, 0), 4);
        assert_eq!(morton(0, 1, 0), 2);
        assert_eq!(morton(0, 0, 1), 1);
        assert_eq!(morton(1023, 1023, 1023), (1 << 30) - 1);
        assert_eq!(morton(2, 0, 0), 32);
    }

    #[test]
    fn cuts_hold_at_most_a_chunk_and_cover_the_order() {
        // codes clustered: equal runs longer than a chunk, and single outliers
        let mut keys: Vec<u64> = (0..1000u64)
            .map(|i| ((i % 7 + (i / 300) * 1000) << 32) | i)
            .collect();
        keys.sort_unstable();
        let (mut ranges, mut top) = (Vec::new(), Vec::new());
        cut(&keys, 0..keys.len(), 64, &mut ranges, &mut top);
        let mut next = 0;
        for r in &ranges {
            assert_eq!(r.start, next);
            assert!(!r.is_empty() && r.len() <= 64, "{r:?}");
            next = r.end;
        }
        assert_eq!(next, keys.len());
        assert_eq!(top.len(), 2 * ranges.len() - 1);
    }
}
