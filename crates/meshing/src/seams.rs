//! T-vertices on patch edges, for output that must not crack (a GLB's triangles).

use crate::adaptive::midpoint;
use crate::build::Mesh;
use glam::Vec3;
use std::collections::HashSet;

/// The points that lie on the edges of patches as other patches' corners (T-vertices), per
/// edge: see [`Mesh::edge_points`].
///
/// Invariants: the points of each edge are strictly inside it, in order from its first corner,
/// with parameters in `(0, 1)` ascending.
#[derive(Debug, Clone, PartialEq)]
pub struct EdgePoints {
    /// Per global corner `c` (the edge from corner `c` of its patch to the next), its points are
    /// `points[first[c]..first[c + 1]]`.
    first: Vec<u32>,
    points: Vec<(f64, Vec3)>,
}

impl EdgePoints {
    /// The T-vertices on the edge that leaves global corner `corner` (see
    /// [`Mesh::corner_offset`]) towards the next corner of its patch: `(t, position)` with `t`
    /// the fraction of the way along the edge, ascending.
    pub fn on_edge(&self, corner: usize) -> &[(f64, Vec3)] {
        &self.points[self.first[corner] as usize..self.first[corner + 1] as usize]
    }

    /// Whether no edge has a T-vertex.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

impl Mesh {
    /// The T-vertices of every patch edge: corners of other patches at the edge's midpoint, and
    /// recursively at the midpoints of its halves (the points an
    /// [`AdaptiveMesh`](crate::AdaptiveMesh)'s refinement puts on a coarser neighbour's edge).
    /// A writer of triangles that includes them in the patch's polygon has no T-junctions, so
    /// no cracks where a coarse element meets finer ones; with values interpolated linearly
    /// along the edge (as [`Mesh::seamless_corner_radiosity`] gives the finer side), no seams
    /// either. Points at other fractions of an edge are not looked for.
    pub fn edge_points(&self) -> EdgePoints {
        let key = |p: Vec3| p.to_array().map(|c| (c + 0.0).to_bits());
        let corners: HashSet<[u32; 3]> = self
            .patches()
            .iter()
            .flat_map(|p| self.corners(p).iter())
            .map(|&v| key(self.positions()[v as usize]))
            .collect();
        let mut first = Vec::with_capacity(self.corner_count() + 1);
        let mut points = Vec::new();
        for patch in self.patches() {
            let c = self.corners(patch);
            for k in 0..c.len() {
                first.push(points.len() as u32);
                let a = self.positions()[c[k] as usize];
                let b = self.positions()[c[(k + 1) % c.len()] as usize];
                collect(&corners, &key, (0.0, a), (1.0, b), 0, &mut points);
            }
        }
        first.push(points.len() as u32);
        EdgePoints { first, points }
    }
}

/// Appends, in order, the corner points at the recursive midpoints of the piece `a`–`b`.
fn collect(
    corners: &HashSet<[u32; 3]>,
    key: &impl Fn(Vec3) -> [u32; 3],
    a: (f64, Vec3),
    b: (f64, Vec3),
    depth: u32,
    out: &mut Vec<(f64, Vec3)>,
) {
    let m = midpoint(a.1, b.1);
    if depth > 48 || m == a.1 || m == b.1 || !corners.contains(&key(m)) {
        return;
    }
    let m = ((a.0 + b.0) * 0.5, m);
    collect(corners, key, a, m, depth + 1, out);
    out.push(m);
    collect(corners, key, m, b, depth + 1, out);
}
