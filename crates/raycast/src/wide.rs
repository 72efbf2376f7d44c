//! mcrad's own 16-wide BVH, made from obvhs's binary BVH: float child boxes in SIMD-ready
//! layout and leaves of triangle packets.
//!
//! obvhs builds the hierarchy (PLOC and reinsertion, see `bvh.rs`); this module only
//! re-arranges it for single-ray traversal on a CPU:
//! * **Nodes** hold up to 16 children with their boxes as `f32` planes, sixteen children per
//!   AVX-512 register, eight per AVX one or four per SSE one ([`Node`]): the slab test of 16
//!   children is a dozen vector operations with no decoding (obvhs's compressed nodes store
//!   8-bit boxes that must be dequantised first). Sixteen children rather than eight make the
//!   tree shallower: a ray visits fewer nodes, and the chain of dependent cache misses from
//!   the root to a leaf is shorter. Measured in one process against the 8-wide tree,
//!   alternating: 12-18% faster on the benchmark's 100k-triangle room, 19-28% on its 1M room,
//!   7% on the Cornell box (AVX-512), and 12% on the 100k room with AVX2 only.
//! * **Leaves** are runs of [`Packet`]s of up to 4 triangles in structure-of-arrays order, so
//!   one vector test intersects 4 triangles (see `query.rs`). The leaves of one node share
//!   packets where they fit ([`Part::pack`]): 57 instead of 69 bytes per triangle on the
//!   benchmark rooms, and 4-8% faster on the 100k one (within 2% on the 1M one), measured
//!   with 8-wide nodes.
//!
//! The collapse of the binary tree is the optimal one for the surface-area heuristic given
//! obvhs's binary tree (Ylitie, Karras and Laine's dynamic programme, see [`Plan`]): for each
//! binary node it finds the cheapest way to spread its subtree over 1 to 16 child slots, so
//! leaves (of up to [`LEAF_MAX`] triangles) and node contents are chosen together. With 8-wide
//! nodes, filling each node greedily instead, by opening the child of largest surface area as
//! Embree's builders do, made 68% more nodes, and rays visited 8% more of them (15.0 against
//! 13.9 per ray on the 100k room) and ran 7-14% slower there and 9-24% slower on the 1M room.
//! Below the top 64 subtrees both the plan and the collapse run in parallel (see
//! [`Wide::new`]).

use glam::{Vec3A, Vec4};
use obvhs::{
    aabb::Aabb,
    bvh2::{Bvh2, node::Bvh2Node},
    triangle::Triangle,
};

use rayon::prelude::*;

use crate::{NO_ID, pages::Pages};

/// Children per node.
pub(crate) const WIDTH: usize = 16;

/// Triangles per packet.
pub(crate) const LANES: usize = 4;

/// Most triangles in one leaf (two packets).
pub(crate) const LEAF_MAX: usize = 8;

/// Flag of an item (a child slot or stack entry) that is a leaf: a run of packets.
pub(crate) const LEAF: u32 = 1 << 31;

/// Bits of a leaf item holding its first packet (the run length minus one sits in bits 29-30).
const PACKET_MASK: u32 = (1 << 29) - 1;

/// Number of packets leaf items can address: the build rejects more.
pub(crate) const MAX_PACKETS: usize = 1 << 29;

/// An empty child slot (its box is empty, so no ray enters it). As a leaf item it would be a
/// run of 4 packets from the last addressable one, which no leaf is (leaves hold at most
/// [`LEAF_MAX`] triangles, two packets).
pub(crate) const EMPTY: u32 = u32::MAX;

/// Surface-area-heuristic cost of testing one packet, relative to testing one node
/// ([`NODE_COST`]).
const PACKET_COST: f32 = 1.0;

/// Surface-area-heuristic cost of testing one 16-wide node, relative to one packet test
/// ([`PACKET_COST`]). A node test takes about as many instructions as a packet test but reads
/// seven cache lines against three. Measured on the benchmark rooms, alternating with the
/// 8-wide tree in one process: 2.4 was fastest on both (100k room +13-18%, 1M room +19-28%);
/// 1.2 gave +4-6% and +2-3%, 0.8 +8% and +7%, 3.2 +8-17% and +11-27%, 4.5 +16% and +9%; 2.0
/// and 2.8 were within 2% of 2.4 on the 100k room. (With 8-wide nodes, four cache lines, 1.0
/// to 1.2 had been fastest.)
const NODE_COST: f32 = 2.4;

/// A node of the 16-wide BVH (448 bytes, seven cache lines).
///
/// `planes[2k][h]` holds the lower bounds on axis `k` (x, y, z) of children `4h..4h+4`, and
/// `planes[2k + 1][h]` their upper bounds, in canonical units; an empty slot has the empty box
/// `[+inf, -inf]`, which every slab test rejects. `items[i]` is child `i`: a node index, or
/// [`LEAF`] with the run of packets (see [`leaf_item`]).
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(64))]
pub(crate) struct Node {
    pub(crate) planes: [[Vec4; WIDTH / 4]; 6],
    pub(crate) items: [u32; WIDTH],
}

const _: () = assert!(size_of::<Node>() == 28 * WIDTH);

impl Node {
    /// A node with no children.
    pub(crate) fn empty() -> Node {
        let lo = [Vec4::INFINITY; WIDTH / 4];
        let hi = [Vec4::NEG_INFINITY; WIDTH / 4];
        Node {
            planes: [lo, hi, lo, hi, lo, hi],
            items: [EMPTY; WIDTH],
        }
    }

    /// Child `i`'s box and item.
    pub(crate) fn child(&self, i: usize) -> (Aabb, u32) {
        let (h, lane) = (i / 4, i % 4);
        let corner = |side: usize| {
            Vec3A::new(
                self.planes[side][h][lane],
                self.planes[2 + side][h][lane],
                self.planes[4 + side][h][lane],
            )
        };
        (Aabb::new(corner(0), corner(1)), self.items[i])
    }

    /// Sets child `i` to `item` with box `aabb`.
    pub(crate) fn set(&mut self, i: usize, aabb: &Aabb, item: u32) {
        let (h, lane) = (i / 4, i % 4);
        for k in 0..3 {
            self.planes[2 * k][h][lane] = aabb.min[k];
            self.planes[2 * k + 1][h][lane] = aabb.max[k];
        }
        self.items[i] = item;
    }
}

/// Up to four canonical-frame triangles in structure-of-arrays order (160 bytes): lane `j`
/// holds `v0`, `e1 = v0 - v1` and `e2 = v2 - v0` (obvhs's `RtTriangle` edges, so that
/// `e1 x e2` is minus the counter-clockwise normal) and the caller's id. Unused lanes hold
/// the triangle with all vertices at the origin and id [`NO_ID`](crate::NO_ID): its determinant is 0, so
/// the packet test computes NaN barycentrics and distances for it, which no test passes (see
/// `query::crossings`), like any degenerate input triangle.
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(32))]
pub(crate) struct Packet {
    pub(crate) v0: [Vec4; 3],
    pub(crate) e1: [Vec4; 3],
    pub(crate) e2: [Vec4; 3],
    pub(crate) ids: [u32; LANES],
}

const _: () = assert!(size_of::<Packet>() == 160);

/// One triangle of a packet, as scalar vectors (the data of the exact re-check).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Lane {
    pub(crate) v0: Vec3A,
    pub(crate) e1: Vec3A,
    pub(crate) e2: Vec3A,
}

impl Packet {
    fn empty() -> Packet {
        Packet {
            v0: [Vec4::ZERO; 3],
            e1: [Vec4::ZERO; 3],
            e2: [Vec4::ZERO; 3],
            ids: [NO_ID; LANES],
        }
    }

    /// Puts triangle `t` (canonical) with `id` in lane `j`.
    fn set(&mut self, j: usize, t: &Triangle, id: u32) {
        let (e1, e2) = (t.v0 - t.v1, t.v2 - t.v0);
        for k in 0..3 {
            self.v0[k][j] = t.v0[k];
            self.e1[k][j] = e1[k];
            self.e2[k][j] = e2[k];
        }
        self.ids[j] = id;
    }

    /// Lane `j`.
    #[inline(always)]
    pub(crate) fn lane(&self, j: usize) -> Lane {
        // (through arrays: `Vec4`'s indexing was not inlined)
        let at =
            |v: &[Vec4; 3]| Vec3A::new(v[0].to_array()[j], v[1].to_array()[j], v[2].to_array()[j]);
        Lane {
            v0: at(&self.v0),
            e1: at(&self.e1),
            e2: at(&self.e2),
        }
    }
}

/// The item of a leaf: `packets` (1 to 4) packets from `first` on.
fn leaf_item(first: usize, packets: usize) -> u32 {
    LEAF | (((packets - 1) as u32) << 29) | first as u32
}

/// The packets of a leaf item.
#[inline(always)]
pub(crate) fn packets(item: u32) -> std::ops::Range<usize> {
    let first = (item & PACKET_MASK) as usize;
    first..first + ((item >> 29) & 3) as usize + 1
}

/// The 16-wide BVH, in memory of its own (on huge pages where the system has them, see
/// [`Pages`]).
#[derive(Clone, Debug)]
pub(crate) struct Wide {
    /// Nodes; the root is node 0.
    pub(crate) nodes: Pages<Node>,
    /// Triangle packets in leaf order.
    pub(crate) packets: Pages<Packet>,
    /// Traversal stack entries a query needs: a traversal keeps the nearest hit child of a
    /// node and pushes the others, so the stack holds pending siblings of the current node's
    /// ancestors; while a node's hit children are sorted they all sit on it. So this is the
    /// largest, over nodes, of the node's children count plus the children counts minus one
    /// of its ancestors.
    pub(crate) stack: usize,
}

/// A wide BVH while the collapse grows it (or one subtree of it, with local indices), with
/// the fields of [`Wide`].
pub(crate) struct Part {
    pub(crate) nodes: Vec<Node>,
    pub(crate) packets: Vec<Packet>,
    pub(crate) stack: usize,
}

/// A wide BVH collapsed but not yet joined ([`Wide::collapse`]): the top nodes, and the
/// subtrees below them with the top node each goes into, in a fixed order.
pub(crate) struct Collapsed {
    top: Part,
    parts: Vec<(usize, Part)>,
}

impl Collapsed {
    /// The wide BVH: the parts joined into the top, in order, each freed as it is joined, in
    /// arrays reserved to their final size, then copied onto their pages.
    pub(crate) fn assemble(self) -> Wide {
        let wide = self.join();
        Wide {
            nodes: Pages::copy_of(&wide.nodes),
            packets: Pages::copy_of(&wide.packets),
            stack: wide.stack,
        }
    }

    /// The parts joined into the top, in order, each freed as it is joined, in arrays
    /// reserved to their final size.
    fn join(self) -> Part {
        let Collapsed {
            top: mut wide,
            parts,
        } = self;
        let nodes: usize = parts
            .iter()
            .map(|(_, p)| p.nodes.len().saturating_sub(1))
            .sum();
        let packets: usize = parts.iter().map(|(_, p)| p.packets.len()).sum();
        wide.nodes.reserve_exact(nodes);
        wide.packets.reserve_exact(packets);
        for (node, part) in parts {
            wide.join(node, part);
        }
        wide
    }
}

/// What the collapse decided for a binary node, from the [`Costs`] of its subtree (the optimal
/// collapse of Ylitie, Karras and Laine 2017, "Efficient incoherent ray traversal on GPUs
/// through compressed wide BVHs"). 19 bytes, 38 MB for the two million binary nodes of a
/// million triangles: the [`Costs`] (80 bytes each) are dropped once the parent is planned.
#[derive(Clone, Copy)]
pub(crate) struct Plan {
    /// One slot: the subtree becomes one leaf (else one wide node).
    leaf: bool,
    /// `split[i - 1]` for `i >= 2`: the best `i` slots take `k` from the left child and
    /// `i - k` from the right, or (0) `i - 1` slots are as good.
    pub(crate) split: [u8; WIDTH],
    /// As a wide node: its slots (2 to [`WIDTH`]) ...
    pub(crate) children: u8,
    /// ... and how many of them come from the left child.
    pub(crate) left: u8,
}

/// The surface-area-heuristic costs of a binary node's subtree as child slots of a wide node.
#[derive(Clone, Copy)]
pub(crate) struct Costs {
    /// Triangles below.
    pub(crate) count: u32,
    /// `cost[i - 1]`: the cost of the best `i` slots or fewer (surface area times
    /// [`PACKET_COST`] per packet and [`NODE_COST`] per wide node, summed).
    pub(crate) cost: [f32; WIDTH],
    /// The most slots that are cheaper than fewer: `cost[i - 1]` is the same for every
    /// `i >= useful`.
    pub(crate) useful: usize,
}

impl Plan {
    /// The plan of a binary leaf of `count` triangles and surface area `area`.
    fn leaf(count: u32, area: f32) -> (Plan, Costs) {
        let plan = Plan {
            leaf: true,
            split: [0; WIDTH],
            children: 0,
            left: 0,
        };
        let cost = PACKET_COST * count.div_ceil(LANES as u32) as f32 * area;
        (
            plan,
            Costs {
                count,
                cost: [cost; WIDTH],
                useful: 1,
            },
        )
    }

    /// The plan of an inner binary node of surface area `area` whose children's subtrees cost
    /// `l` and `r`.
    pub(crate) fn inner(area: f32, l: &Costs, r: &Costs) -> (Plan, Costs) {
        let count = l.count + r.count;
        // distribute[j]: the best j slots, some from each child. More than `useful` slots of a
        // child cost as much as `useful` (its costs do not increase with the slots), so only
        // the useful ones are tried: near the leaves, where most binary nodes are, that is
        // one or two instead of up to 15.
        let mut distribute = [(f32::INFINITY, 0u8); WIDTH + 1];
        let most = WIDTH.min(l.useful + r.useful);
        let (mut children, mut left, mut below) = (0u8, 0u8, f32::INFINITY);
        for (j, slot) in distribute.iter_mut().enumerate().take(most + 1).skip(2) {
            let mut best = (f32::INFINITY, 0u8);
            for k in j.saturating_sub(r.useful).max(1)..=l.useful.min(j - 1) {
                let c = l.cost[k - 1] + r.cost[j - k - 1];
                // (the first split is taken even at an infinite cost: overflowing areas must
                // still give a valid plan)
                if c < best.0 || best.1 == 0 {
                    best = (c, k as u8);
                }
            }
            *slot = best;
            if best.0 < below || children == 0 {
                (children, left, below) = (j as u8, best.1, best.0);
            }
        }
        let as_node = NODE_COST * area + below;
        let as_leaf = if count as usize <= LEAF_MAX {
            PACKET_COST * count.div_ceil(LANES as u32) as f32 * area
        } else {
            f32::INFINITY
        };
        let mut plan = Plan {
            // (a leaf holds at most LEAF_MAX triangles even when both costs are infinite)
            leaf: count as usize <= LEAF_MAX && as_leaf <= as_node,
            split: [0; WIDTH],
            children,
            left,
        };
        let mut costs = Costs {
            count,
            cost: [as_leaf.min(as_node); WIDTH],
            useful: 1,
        };
        for (i, &(c, k)) in distribute.iter().enumerate().take(most + 1).skip(2) {
            if c < costs.cost[i - 2] {
                costs.cost[i - 1] = c;
                costs.useful = i;
                plan.split[i - 1] = k;
            } else {
                costs.cost[i - 1] = costs.cost[i - 2];
            }
        }
        // (no more slots are useful: they cost as much as `most`)
        let last = costs.cost[most - 1];
        costs.cost[most..].fill(last);
        (plan, costs)
    }
}

/// Subtrees the top of the collapse hands to the rayon pool (a fixed number, so that the
/// layout does not depend on the thread count).
const TOP_JOBS: usize = 64;

/// The inputs of the collapse.
struct Collapse<'a> {
    bvh2: &'a Bvh2,
    plans: &'a [Plan],
    tris: &'a [Triangle],
    ids: &'a [u32],
}

/// A wide node still to fill: from binary node `binary` into `node`, whose ancestors leave
/// `load` entries on the traversal stack.
#[derive(Clone, Copy)]
struct Pending {
    binary: usize,
    node: usize,
    load: usize,
}

impl Collapse<'_> {
    /// Fills `pending.node` of `part` (its children chosen from the binary subtree), appending
    /// its leaves' packets and empty nodes for its inner children, which go to `todo`.
    fn fill(&self, part: &mut Part, pending: Pending, todo: &mut Vec<Pending>) {
        let (bvh2, plans) = (self.bvh2, self.plans);
        let mut children = [0usize; WIDTH];
        let b = pending.binary;
        let n = if plans[b].leaf {
            children[0] = b;
            1
        } else {
            let plan = &plans[b];
            spread(
                bvh2,
                plans,
                b,
                plan.left as usize,
                plan.children as usize,
                &mut children,
            )
        };
        // the node's children go on top of the siblings of its ancestors
        part.stack = part.stack.max(pending.load + n);
        let load = pending.load + n - 1;
        // the leaves' triangles, packed together (see `Part::pack`)
        let mut prims = [[0u32; LEAF_MAX]; WIDTH];
        let mut counts = [0usize; WIDTH];
        for (i, &c) in children[..n].iter().enumerate() {
            if plans[c].leaf {
                counts[i] = collect_prims(bvh2, c, &mut prims[i]);
            }
        }
        let leaves = part.pack(&prims, &counts[..n], self.tris, self.ids);
        // inner children get consecutive node indices, so siblings share pages
        for (i, &c) in children[..n].iter().enumerate() {
            let item = if plans[c].leaf {
                leaves[i]
            } else {
                let node = part.nodes.len();
                part.nodes.push(Node::empty());
                todo.push(Pending {
                    binary: c,
                    node,
                    load,
                });
                node as u32
            };
            part.nodes[pending.node].set(i, &bvh2.nodes[c].aabb, item);
        }
    }

    /// The part of the wide BVH below `root`: its node 0 is `root.node`'s (indices local).
    fn part(&self, root: Pending) -> Part {
        let mut part = Part {
            nodes: vec![Node::empty()],
            packets: Vec::new(),
            stack: 0,
        };
        let mut todo = vec![Pending { node: 0, ..root }];
        while let Some(pending) = todo.pop() {
            self.fill(&mut part, pending, &mut todo);
        }
        part
    }
}

/// Writes the best `i` slots (or fewer, see [`Plan::split`]) of binary node `b` to `out`;
/// returns how many.
fn slots(bvh2: &Bvh2, plans: &[Plan], b: usize, i: usize, out: &mut [usize]) -> usize {
    let mut i = i;
    while i > 1 && plans[b].split[i - 1] == 0 {
        i -= 1;
    }
    if i == 1 {
        out[0] = b;
        return 1;
    }
    spread(bvh2, plans, b, plans[b].split[i - 1] as usize, i, out)
}

/// Writes the best `k` slots of inner binary node `b`'s left child and the best `i - k` of its
/// right child (or fewer, see [`slots`]) to `out`; returns how many.
fn spread(bvh2: &Bvh2, plans: &[Plan], b: usize, k: usize, i: usize, out: &mut [usize]) -> usize {
    let first = bvh2.nodes[b].first_index as usize;
    let n = slots(bvh2, plans, first, k, out);
    n + slots(bvh2, plans, first + 1, i - k, &mut out[n..])
}

impl Wide {
    /// The nodes and packets as slices, for a query to take once (each look through
    /// [`Pages`] checks the bounds and alignment of its map).
    #[inline(always)]
    pub(crate) fn slices(&self) -> (&[Node], &[Packet]) {
        (&self.nodes, &self.packets)
    }

    /// The 16-wide BVH of `bvh2`, whose leaves index `tris` (and `ids`) through
    /// `bvh2.primitive_indices`, built on the current rayon pool: the top nodes in breadth-
    /// first order until there is work for every thread, then the subtrees below them in
    /// parallel, joined in a fixed order (the result does not depend on the thread count).
    #[cfg(test)]
    pub(crate) fn new(bvh2: &Bvh2, tris: &[Triangle], ids: &[u32]) -> Wide {
        Wide::collapse(bvh2, tris, ids).assemble()
    }

    /// The parts of [`Wide::new`]: what needs `bvh2` and `tris`, so that a caller may free
    /// them (and the collapse's plans go) before [`Collapsed::assemble`] joins the parts and
    /// copies them onto their pages.
    pub(crate) fn collapse(bvh2: &Bvh2, tris: &[Triangle], ids: &[u32]) -> Collapsed {
        let (plans, _) = plan(bvh2);
        Wide::collapse_planned(bvh2, &plans, tris, ids)
    }

    /// One chunk of a larger scene (see `chunks.rs`): the wide BVH of `bvh2` as [`Wide::new`]
    /// builds it, with its root's box and costs for the top above the chunks.
    pub(crate) fn chunk(bvh2: &Bvh2, tris: &[Triangle], ids: &[u32]) -> Chunk {
        let (plans, costs) = plan(bvh2);
        let part = Wide::collapse_planned(bvh2, &plans, tris, ids).join();
        let root = &bvh2.nodes[0];
        // the root is always a wide node, holding the plan's slots (one leaf if the plan
        // makes the whole chunk a leaf)
        let below = if plans[0].leaf {
            costs.cost[0]
        } else {
            costs.cost[WIDTH - 1]
        };
        let slots = part.nodes[0]
            .items
            .iter()
            .filter(|&&item| item != EMPTY)
            .count();
        Chunk {
            // (in maps of their own where they are large, given back to the system when the
            // top has copied them: freed heap memory may stay with the process)
            nodes: Pages::copy_of(&part.nodes),
            packets: Pages::copy_of(&part.packets),
            stack: part.stack,
            aabb: root.aabb,
            count: costs.count,
            as_node: NODE_COST * area(root) + below,
            below,
            slots,
        }
    }

    /// [`Wide::collapse`] with the plans made.
    fn collapse_planned(bvh2: &Bvh2, plans: &[Plan], tris: &[Triangle], ids: &[u32]) -> Collapsed {
        let collapse = Collapse {
            bvh2,
            plans,
            tris,
            ids,
        };
        let mut wide = Part {
            nodes: vec![Node::empty()],
            packets: Vec::new(),
            stack: 0,
        };
        // breadth first over the top (the order of `todo` is fixed: no thread count in it)
        let mut todo = std::collections::VecDeque::from([Pending {
            binary: 0,
            node: 0,
            load: 0,
        }]);
        let mut next = Vec::with_capacity(WIDTH);
        while todo.len() < TOP_JOBS {
            let Some(pending) = todo.pop_front() else {
                break;
            };
            collapse.fill(&mut wide, pending, &mut next);
            todo.extend(next.drain(..));
        }
        let parts: Vec<(usize, Part)> = todo
            .par_iter()
            .map(|&pending| (pending.node, collapse.part(pending)))
            .collect();
        Collapsed { top: wide, parts }
    }

    /// Bytes held by nodes and packets.
    pub(crate) fn memory_bytes(&self) -> usize {
        size_of_val(&self.nodes[..]) + size_of_val(&self.packets[..])
    }
}

impl Part {
    /// Puts `part` (the subtree of node `at`, with local indices) into this BVH.
    fn join(&mut self, at: usize, part: Part) {
        // local node 0 is `at`, local node k > 0 goes to `base + k - 1`
        let base = self.nodes.len() as u32;
        let first_packet = self.packets.len() as u32;
        let remap = |mut node: Node| {
            for item in &mut node.items {
                if *item == EMPTY {
                } else if *item & LEAF != 0 {
                    *item += first_packet;
                } else {
                    *item += base - 1;
                }
            }
            node
        };
        let mut nodes = part.nodes.into_iter();
        if let Some(root) = nodes.next() {
            self.nodes[at] = remap(root);
        }
        self.nodes.extend(nodes.map(remap));
        self.packets.extend(part.packets);
        self.stack = self.stack.max(part.stack);
    }

    /// Appends packets holding the leaves of one node, leaf `i` being triangles
    /// `prims[i][..counts[i]]` (none where `counts[i]` is 0); returns the leaves' items.
    ///
    /// Leaves share packets where they fit (a leaf of 3 triangles and one of 1 fill a packet;
    /// a leaf of 5 leaves 3 lanes of its second packet to others): a leaf's item is the run of
    /// packets holding its triangles, and testing them may also test a sibling leaf's, which
    /// is as good a crossing as any (the closest hit is the closest of all triangles, and any
    /// blocker blocks). Largest leaves first, each small one into the fullest packet it fits.
    fn pack(
        &mut self,
        prims: &[[u32; LEAF_MAX]; WIDTH],
        counts: &[usize],
        tris: &[Triangle],
        ids: &[u32],
    ) -> [u32; WIDTH] {
        let mut items = [EMPTY; WIDTH];
        let mut order: [usize; WIDTH] = std::array::from_fn(|i| i);
        let order = &mut order[..counts.len()];
        order.sort_by_key(|&i| std::cmp::Reverse(counts[i]));
        let base = self.packets.len();
        // lanes used in each packet of this node (at most one packet per leaf and lane group)
        let mut used = [0usize; WIDTH * LEAF_MAX / LANES];
        let mut packets = 0;
        for &i in order.iter().filter(|&&i| counts[i] > 0) {
            let leaf = &prims[i][..counts[i]];
            let fits = (0..packets)
                .filter(|&p| leaf.len() <= LANES && used[p] + leaf.len() <= LANES)
                .max_by_key(|&p| (used[p], std::cmp::Reverse(p)));
            let (first, lane) = match fits {
                Some(p) => (p, used[p]),
                None => {
                    packets += leaf.len().div_ceil(LANES);
                    (packets - leaf.len().div_ceil(LANES), 0)
                }
            };
            while self.packets.len() < base + packets {
                self.packets.push(Packet::empty());
            }
            for (k, &t) in leaf.iter().enumerate() {
                let (p, j) = (first + (lane + k) / LANES, (lane + k) % LANES);
                self.packets[base + p].set(j, &tris[t as usize], ids[t as usize]);
                used[p] = used[p].max(j + 1);
            }
            items[i] = leaf_item(base + first, (lane + leaf.len()).div_ceil(LANES));
        }
        items
    }
}

/// The triangles (input indices) below binary node `b`, written to `out`; returns how many
/// (the plans make leaves of at most [`LEAF_MAX`]).
fn collect_prims(bvh2: &Bvh2, b: usize, out: &mut [u32; LEAF_MAX]) -> usize {
    let mut todo = [0usize; LEAF_MAX];
    todo[0] = b;
    let (mut pending, mut n) = (1, 0);
    while pending > 0 {
        pending -= 1;
        let node = &bvh2.nodes[todo[pending]];
        let first = node.first_index as usize;
        if node.prim_count == 0 {
            // (a subtree of at most LEAF_MAX leaves has fewer pending nodes than that)
            todo[pending] = first + 1;
            todo[pending + 1] = first;
            pending += 2;
        } else {
            for &p in &bvh2.primitive_indices[first..first + node.prim_count as usize] {
                out[n] = p;
                n += 1;
            }
        }
    }
    n
}

/// The plan of every binary node (see [`Plan`]). Binary leaves (one triangle each from obvhs's
/// PLOC) are leaves; an inner node becomes a leaf of at most [`LEAF_MAX`] triangles when
/// that costs no more than a wide node. The subtrees below the top [`TOP_JOBS`] nodes
/// (breadth first) are planned in parallel.
fn plan(bvh2: &Bvh2) -> (Vec<Plan>, Costs) {
    let n = bvh2.nodes.len();
    let (empty, none) = Plan::leaf(0, 0.0);
    let mut plans = vec![empty; n];
    if n == 0 {
        return (plans, none);
    }
    // the top, breadth first (children after parents), and the subtree roots below it
    let mut top = Vec::new();
    let mut roots = std::collections::VecDeque::from([0usize]);
    while roots.len() < TOP_JOBS {
        let Some(b) = roots.pop_front() else { break };
        let node = &bvh2.nodes[b];
        if node.prim_count == 0 {
            top.push(b);
            let first = node.first_index as usize;
            roots.extend([first, first + 1]);
        } else {
            roots.push_back(b);
            if roots.iter().all(|&r| bvh2.nodes[r].prim_count != 0) {
                break;
            }
        }
    }
    let parts: Vec<(Vec<(u32, Plan)>, Costs)> = roots
        .par_iter()
        .map(|&root| plan_subtree(bvh2, root))
        .collect();
    // the costs of the top nodes and of the roots below them (a few hundred at most)
    let mut costs = std::collections::HashMap::new();
    for (&root, (part, root_costs)) in roots.iter().zip(parts) {
        for (b, p) in part {
            plans[b as usize] = p;
        }
        costs.insert(root, root_costs);
    }
    for &b in top.iter().rev() {
        let node = &bvh2.nodes[b];
        let first = node.first_index as usize;
        let (p, c) = Plan::inner(area(node), &costs[&first], &costs[&(first + 1)]);
        plans[b] = p;
        costs.insert(b, c);
    }
    let root = costs[&0];
    (plans, root)
}

/// The plans of the binary subtree of `root`, node by node, and the costs of `root`'s.
fn plan_subtree(bvh2: &Bvh2, root: usize) -> (Vec<(u32, Plan)>, Costs) {
    // pre-order, the right child first; walked backwards every node comes after its subtree,
    // whose costs are then on top of `done`, the right child's above the left's
    let mut order = Vec::new();
    let mut todo = vec![root];
    while let Some(b) = todo.pop() {
        order.push(b);
        let node = &bvh2.nodes[b];
        if node.prim_count == 0 {
            let first = node.first_index as usize;
            todo.extend([first, first + 1]);
        }
    }
    let mut done: Vec<Costs> = Vec::new();
    let mut out = Vec::with_capacity(order.len());
    for &b in order.iter().rev() {
        let node = &bvh2.nodes[b];
        let (plan, costs) = if node.prim_count != 0 {
            Plan::leaf(node.prim_count, area(node))
        } else {
            let (r, l) = (done.pop(), done.pop());
            let (Some(r), Some(l)) = (r, l) else {
                unreachable!("an inner node comes after its two subtrees");
            };
            Plan::inner(area(node), &l, &r)
        };
        done.push(costs);
        out.push((b as u32, plan));
    }
    let Some(costs) = done.pop() else {
        unreachable!("a subtree has a root");
    };
    (out, costs)
}

/// The surface area (halved) of a binary node's box.
fn area(node: &Bvh2Node) -> f32 {
    node.aabb.half_area().max(0.0)
}

/// The wide BVH of one chunk of a larger scene (see `chunks.rs`), with what the top above the
/// chunks needs to place it: as one child slot (its root node) or opened (its root's children
/// as slots of a top node).
pub(crate) struct Chunk {
    /// The chunk's wide nodes (local indices; its root is node 0) ...
    pub(crate) nodes: Pages<Node>,
    /// ... its packets (local indices) ...
    pub(crate) packets: Pages<Packet>,
    /// ... and its traversal stack bound (see [`Wide::stack`]).
    pub(crate) stack: usize,
    /// The box of the chunk's triangles (padded, canonical units).
    pub(crate) aabb: Aabb,
    /// Triangles in the chunk.
    pub(crate) count: u32,
    /// The surface-area-heuristic cost of the chunk as one child slot (its root node).
    pub(crate) as_node: f32,
    /// The cost of its root's children as slots of the node above (`as_node` without the
    /// root's own test).
    pub(crate) below: f32,
    /// Children of its root node.
    pub(crate) slots: usize,
}

impl Chunk {
    /// Whether the top may open the chunk's root into the node above: only a chunk of one
    /// node (its root's children all leaves: the small pieces of a cut), whose nodes then
    /// all go. (A chunk of more nodes has a full root wherever it has 16 slots' worth of
    /// subtrees, which a node above could only hold alone.)
    pub(crate) fn openable(&self) -> bool {
        self.nodes.len() == 1
    }

    /// The chunk's costs as 1 to [`WIDTH`] child slots (see [`Costs`]): its root node, or, if
    /// it is [`openable`](Chunk::openable), its root's children from `slots` slots on.
    pub(crate) fn costs(&self) -> Costs {
        let mut cost = [self.as_node; WIDTH];
        let mut useful = 1;
        if self.openable() {
            cost[self.slots - 1..].fill(self.below);
            useful = self.slots;
        }
        Costs {
            count: self.count,
            cost,
            useful,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Half the surface area of child `i`'s box in `node`, by `Aabb::half_area`'s formula.
    fn child_area(node: &Node, i: usize) -> f32 {
        let (h, lane) = (i / 4, i % 4);
        let d = [0, 1, 2].map(|k| node.planes[2 * k + 1][h][lane] - node.planes[2 * k][h][lane]);
        (d[0] + d[1]) * d[2] + d[0] * d[1]
    }

    /// The surface-area-heuristic cost of the subtree of `item` (a child of box area `area`),
    /// by the cost model of [`Plan`].
    fn cost_of(wide: &Wide, item: u32, area: f32) -> f64 {
        if item & LEAF != 0 {
            return (PACKET_COST * packets(item).len() as f32 * area) as f64;
        }
        let node = &wide.nodes[item as usize];
        let below: f64 = (0..WIDTH)
            .filter(|&i| node.items[i] != EMPTY)
            .map(|i| cost_of(wide, node.items[i], child_area(node, i)))
            .sum();
        (NODE_COST * area) as f64 + below
    }

    #[test]
    fn the_collapse_is_the_planned_optimum() {
        // a jumble of small triangles: leaves of every size and nodes of every width
        let mut next = crate::testing::uniforms(12345);
        let tris: Vec<Triangle> = (0..3000)
            .map(|_| {
                let c = Vec3A::new(next(), next(), next()) * 100.0;
                let mut corner = || c + Vec3A::new(next(), next(), next()) * 3.0;
                Triangle {
                    v0: corner(),
                    v1: corner(),
                    v2: corner(),
                }
            })
            .collect();
        let ids: Vec<u32> = (0..tris.len() as u32).collect();
        let aabbs: Vec<Aabb> = tris.iter().map(Triangle::aabb).collect();
        let bvh2 = obvhs::ploc::PlocBuilder::with_capacity(aabbs.len()).build(
            obvhs::ploc::PlocSearchDistance::Minimum,
            &aabbs,
            ids.clone(),
            obvhs::ploc::SortPrecision::U64,
            1,
        );
        let wide = Wide::new(&bvh2, &tris, &ids);
        let (root_plans, root) = plan_subtree(&bvh2, 0);
        assert!(!root_plans.last().is_some_and(|(_, p)| p.leaf));
        let optimum = root.cost[0] as f64;
        let built = cost_of(&wide, 0, area(&bvh2.nodes[0]));
        assert!(
            (built - optimum).abs() <= 1e-4 * optimum,
            "built {built}, planned {optimum}"
        );
        // and every other choice of the root's slots costs at least as much
        let first = bvh2.nodes[0].first_index as usize;
        let (left, right) = (
            plan_subtree(&bvh2, first).1,
            plan_subtree(&bvh2, first + 1).1,
        );
        for j in 2..=WIDTH {
            for k in 1..j {
                let other =
                    NODE_COST * area(&bvh2.nodes[0]) + left.cost[k - 1] + right.cost[j - k - 1];
                assert!(other >= root.cost[0], "{j} slots, {k} left: {other}");
            }
        }
        // nodes are well filled: fewer than one per 4 triangles
        assert!(
            wide.nodes.len() * 4 < tris.len(),
            "{} nodes",
            wide.nodes.len()
        );
    }

    #[test]
    fn infinite_costs_still_give_valid_plans() {
        // boxes whose surface areas overflow f32: every cost is infinite, and the plan must
        // still make leaves of at most LEAF_MAX triangles and wide nodes of 2+ slots
        let (_, leaf) = Plan::leaf(4, f32::INFINITY);
        let mut below = leaf;
        for level in 0..6 {
            let (plan, costs) = Plan::inner(f32::INFINITY, &below, &leaf);
            assert!(
                !plan.leaf || costs.count as usize <= LEAF_MAX,
                "level {level}: a leaf of {} triangles",
                costs.count
            );
            if !plan.leaf {
                assert!(plan.children >= 2 && plan.left >= 1, "level {level}");
            }
            below = costs;
        }
        assert!(below.count as usize > LEAF_MAX);
    }

    #[test]
    fn sibling_leaves_share_packets() {
        let tris: Vec<Triangle> = (0..40)
            .map(|i| {
                let c = Vec3A::splat(i as f32);
                Triangle {
                    v0: c,
                    v1: c + Vec3A::X,
                    v2: c + Vec3A::Y,
                }
            })
            .collect();
        let ids: Vec<u32> = (100..140).collect();
        for sizes in [
            &[3, 1, 2, 2][..],
            &[5, 3, 1, 8, 2, 2, 1, 4],
            &[1, 1, 1, 1, 1, 1, 1, 1],
            &[6, 6],
            &[0, 4, 0, 7],
        ] {
            let mut prims = [[0u32; LEAF_MAX]; WIDTH];
            let mut next = 0;
            for (i, &n) in sizes.iter().enumerate() {
                for slot in &mut prims[i][..n] {
                    *slot = next;
                    next += 1;
                }
            }
            let mut part = Part {
                nodes: Vec::new(),
                packets: vec![Packet::empty()],
                stack: 0,
            };
            let items = part.pack(&prims, sizes, &tris, &ids);
            // every leaf finds all its triangles in its packets
            for (i, &n) in sizes.iter().enumerate() {
                if n == 0 {
                    assert_eq!(items[i], EMPTY);
                    continue;
                }
                let lanes: Vec<u32> = packets(items[i])
                    .flat_map(|p| part.packets[p].ids)
                    .collect();
                assert!(packets(items[i]).start >= 1, "{sizes:?}: an earlier packet");
                assert!(packets(items[i]).len() <= n.div_ceil(LANES), "{sizes:?}");
                for &t in &prims[i][..n] {
                    assert!(lanes.contains(&ids[t as usize]), "{sizes:?} leaf {i}");
                }
            }
            // each triangle is stored once, and the packets are as few as the lanes allow
            let stored: Vec<u32> = part.packets[1..]
                .iter()
                .flat_map(|p| p.ids)
                .filter(|&id| id != NO_ID)
                .collect();
            let total: usize = sizes.iter().sum();
            assert_eq!(stored.len(), total, "{sizes:?}");
            let mut unique = stored.clone();
            unique.sort();
            unique.dedup();
            assert_eq!(unique.len(), total, "{sizes:?}");
            let packed = part.packets.len() - 1;
            assert!(
                packed <= total.div_ceil(LANES) + 1,
                "{sizes:?}: {packed} packets"
            );
        }
    }

    #[test]
    fn leaf_items_round_trip() {
        for (first, n) in [(0, 1), (5, 2), (MAX_PACKETS - 4, 4)] {
            let item = leaf_item(first, n);
            assert!(item & LEAF != 0);
            assert_eq!(packets(item), first..first + n);
        }
    }

    #[test]
    fn lanes_round_trip() {
        let t = Triangle {
            v0: Vec3A::new(1.0, 2.0, 3.0),
            v1: Vec3A::new(4.0, 5.0, 7.0),
            v2: Vec3A::new(-1.0, 0.5, 2.0),
        };
        let mut p = Packet::empty();
        p.set(2, &t, 0x8000_0000);
        let lane = p.lane(2);
        assert_eq!(lane.v0, t.v0);
        assert_eq!(lane.e1, t.v0 - t.v1);
        assert_eq!(lane.e2, t.v2 - t.v0);
        assert_eq!(p.ids[2], 0x8000_0000);
        assert_eq!(p.ids[0], NO_ID);
    }
}
