//! Uniform subdivision of faces into patches that share their edge points.

use crate::build::{Mesh, PatchTemplate};
use glam::{DVec3, Vec3};
use std::collections::HashMap;

/// What a [`Cutter`] cuts into: vertices it reads and appends, patches it appends (a [`Mesh`],
/// or the leaves of an adaptive mesh's start).
pub(crate) trait Target {
    /// Position of vertex `i`.
    fn position(&self, i: u32) -> Vec3;
    /// Appends a vertex and returns its index.
    fn push_position(&mut self, p: Vec3) -> u32;
    /// Appends a convex planar polygon patch of corners `corners` (counter-clockwise), and
    /// right after it its back side when the template is two-sided.
    fn push_patch(&mut self, corners: &[u32], t: &PatchTemplate);
}

impl Target for Mesh {
    fn position(&self, i: u32) -> Vec3 {
        Mesh::position(self, i)
    }
    fn push_position(&mut self, p: Vec3) -> u32 {
        Mesh::push_position(self, p)
    }
    fn push_patch(&mut self, corners: &[u32], t: &PatchTemplate) {
        Mesh::push_patch(self, corners, t);
    }
}

/// Cuts faces into patches, remembering the points it made on face edges so that a neighbouring
/// face cutting the same edge into the same number of pieces reuses them.
#[derive(Default)]
pub(crate) struct Cutter {
    /// `(lower vertex, higher vertex, step from the lower one, steps)` -> vertex index.
    edge_points: HashMap<(u32, u32, u32, u32), u32>,
    /// A face (or fan triangle) whose pieces would be smaller than this (`sqrt(area)`, scene
    /// units) is kept whole.
    min_size: f64,
    /// How many were kept whole.
    kept_whole: usize,
}

/// Number of pieces an edge of `length` is cut into so no piece is longer than `max_edge`.
fn pieces(length: f64, max_edge: f32) -> u32 {
    ((length / max_edge as f64).ceil() as u32).max(1)
}

impl Cutter {
    /// A cutter that keeps whole the faces (and fan triangles) whose pieces would be smaller
    /// than `min_size` (`sqrt(area)`, scene units).
    pub fn keeping_whole_below(min_size: f64) -> Cutter {
        Cutter {
            min_size,
            ..Cutter::default()
        }
    }

    /// How many faces (and fan triangles) were kept whole.
    pub fn kept_whole(&self) -> usize {
        self.kept_whole
    }

    /// Whether a polygon of `area` cut into `pieces` would have pieces below the minimum size;
    /// counts it when it is to be kept whole.
    fn keep_whole(&mut self, area: f64, pieces: u32) -> bool {
        let keep = keeps_whole(area, pieces, self.min_size);
        self.kept_whole += usize::from(keep);
        keep
    }

    /// Cuts one face (corner indices counter-clockwise) into patches of `mesh`.
    pub fn cut_face(
        &mut self,
        mesh: &mut impl Target,
        corners: &[u32],
        max_edge: f32,
        t: &PatchTemplate,
    ) {
        let pos: Vec<DVec3> = corners
            .iter()
            .map(|&i| mesh.position(i).as_dvec3())
            .collect();
        if corners.len() == 4 && is_convex(&pos) {
            self.cut_quad(
                mesh,
                [corners[0], corners[1], corners[2], corners[3]],
                max_edge,
                t,
            );
        } else {
            for w in corners[1..].windows(2) {
                self.cut_triangle(mesh, [corners[0], w[0], w[1]], max_edge, t);
            }
        }
    }

    /// The point `k/n` of the way from vertex `a` to vertex `b`, computed the same way from
    /// either end so both faces of an edge get the same vertex.
    fn edge_point(&mut self, mesh: &mut impl Target, a: u32, b: u32, k: u32, n: u32) -> u32 {
        if k == 0 {
            return a;
        }
        if k == n {
            return b;
        }
        let (lo, hi, k) = if a < b { (a, b, k) } else { (b, a, n - k) };
        if let Some(&v) = self.edge_points.get(&(lo, hi, k, n)) {
            return v;
        }
        let p = mesh
            .position(lo)
            .as_dvec3()
            .lerp(mesh.position(hi).as_dvec3(), k as f64 / n as f64);
        let v = mesh.push_position(p.as_vec3());
        self.edge_points.insert((lo, hi, k, n), v);
        v
    }

    /// Cuts triangle `abc` into `n²` similar triangles, `n` set by its longest edge.
    fn cut_triangle(
        &mut self,
        mesh: &mut impl Target,
        [a, b, c]: [u32; 3],
        max_edge: f32,
        t: &PatchTemplate,
    ) {
        let (pa, pb, pc) = (
            mesh.position(a).as_dvec3(),
            mesh.position(b).as_dvec3(),
            mesh.position(c).as_dvec3(),
        );
        let (n, area) = triangle_cut(pa, pb, pc, max_edge);
        if self.keep_whole(area, n * n) {
            mesh.push_patch(&[a, b, c], t);
            return;
        }
        // Grid point (i, j) = a + (b - a) i/n + (c - a) j/n for i + j <= n, row-major in j.
        let mut grid = vec![0u32; ((n + 1) * (n + 2) / 2) as usize];
        // Rows j = 0..=n hold n+1, n, ..., 1 points.
        let row_start: Vec<usize> = (0..=n)
            .scan(0usize, |s, j| {
                let r = *s;
                *s += (n + 1 - j) as usize;
                Some(r)
            })
            .collect();
        for j in 0..=n {
            for i in 0..=(n - j) {
                let v = if j == 0 {
                    self.edge_point(mesh, a, b, i, n)
                } else if i == 0 {
                    self.edge_point(mesh, a, c, j, n)
                } else if i + j == n {
                    self.edge_point(mesh, b, c, j, n)
                } else {
                    let p =
                        pa + (pb - pa) * (i as f64 / n as f64) + (pc - pa) * (j as f64 / n as f64);
                    mesh.push_position(p.as_vec3())
                };
                grid[row_start[j as usize] + i as usize] = v;
            }
        }
        let g = |i: u32, j: u32| grid[row_start[j as usize] + i as usize];
        for j in 0..n {
            for i in 0..(n - j) {
                mesh.push_patch(&[g(i, j), g(i + 1, j), g(i, j + 1)], t);
                if i + j + 1 < n {
                    mesh.push_patch(&[g(i + 1, j), g(i + 1, j + 1), g(i, j + 1)], t);
                }
            }
        }
    }

    /// Cuts a convex quad `v0 v1 v2 v3` into an `n_u × n_v` bilinear grid of quads.
    fn cut_quad(&mut self, mesh: &mut impl Target, v: [u32; 4], max_edge: f32, t: &PatchTemplate) {
        let p = v.map(|i| mesh.position(i).as_dvec3());
        let (nu, nv, area) = quad_cut(&p, max_edge);
        if self.keep_whole(area, nu * nv) {
            mesh.push_patch(&v, t);
            return;
        }
        let mut grid = vec![0u32; ((nu + 1) * (nv + 1)) as usize];
        for j in 0..=nv {
            for i in 0..=nu {
                let id = if j == 0 {
                    self.edge_point(mesh, v[0], v[1], i, nu)
                } else if j == nv {
                    self.edge_point(mesh, v[3], v[2], i, nu)
                } else if i == 0 {
                    self.edge_point(mesh, v[0], v[3], j, nv)
                } else if i == nu {
                    self.edge_point(mesh, v[1], v[2], j, nv)
                } else {
                    let (s, tt) = (i as f64 / nu as f64, j as f64 / nv as f64);
                    let q = p[0] * ((1.0 - s) * (1.0 - tt))
                        + p[1] * (s * (1.0 - tt))
                        + p[2] * (s * tt)
                        + p[3] * ((1.0 - s) * tt);
                    mesh.push_position(q.as_vec3())
                };
                grid[(j * (nu + 1) + i) as usize] = id;
            }
        }
        let g = |i: u32, j: u32| grid[(j * (nu + 1) + i) as usize];
        for j in 0..nv {
            for i in 0..nu {
                mesh.push_patch(&[g(i, j), g(i + 1, j), g(i + 1, j + 1), g(i, j + 1)], t);
            }
        }
    }
}

/// Whether a polygon of `area` (scene units²) cut into `pieces` would have pieces below
/// `min_size` (`sqrt(area)`, scene units): it is then kept whole.
fn keeps_whole(area: f64, pieces: u32, min_size: f64) -> bool {
    pieces > 1 && area / f64::from(pieces) < min_size * min_size
}

/// The pieces per edge `n` that triangle `abc` is cut into (`n²` triangles, by its longest
/// edge) and its area (scene units²).
fn triangle_cut(pa: DVec3, pb: DVec3, pc: DVec3, max_edge: f32) -> (u32, f64) {
    let longest = pa.distance(pb).max(pb.distance(pc)).max(pc.distance(pa));
    (
        pieces(longest, max_edge),
        (pb - pa).cross(pc - pa).length() / 2.0,
    )
}

/// The grid `n_u × n_v` that convex quad `p` is cut into and its area (scene units²).
fn quad_cut(p: &[DVec3; 4], max_edge: f32) -> (u32, u32, f64) {
    let nu = pieces(p[0].distance(p[1]).max(p[3].distance(p[2])), max_edge);
    let nv = pieces(p[0].distance(p[3]).max(p[1].distance(p[2])), max_edge);
    let area = ((p[1] - p[0]).cross(p[2] - p[0]) + (p[2] - p[0]).cross(p[3] - p[0])).length() / 2.0;
    (nu, nv, area)
}

/// The patches (one side) [`Cutter::cut_face`] makes of a face of corner positions `pos`
/// (counter-clockwise, in the mesh's local frame, as `f64` from its `f32` positions) with
/// edges of at most `max_edge`, keeping whole what would be cut below `min_size`; without
/// making them.
pub(crate) fn count_face(pos: &[DVec3], max_edge: f32, min_size: f64) -> u64 {
    let pieces_or_whole = |area: f64, pieces: u32| {
        if keeps_whole(area, pieces, min_size) {
            1
        } else {
            u64::from(pieces)
        }
    };
    if let [p0, p1, p2, p3] = *pos
        && is_convex(pos)
    {
        let (nu, nv, area) = quad_cut(&[p0, p1, p2, p3], max_edge);
        return pieces_or_whole(area, nu * nv);
    }
    pos[1..]
        .windows(2)
        .map(|w| {
            let (n, area) = triangle_cut(pos[0], w[0], w[1], max_edge);
            pieces_or_whole(area, n * n)
        })
        .sum()
}

/// True when the polygon turns the same way at every corner (strictly convex, any winding).
fn is_convex(p: &[DVec3]) -> bool {
    let n = p.len();
    let normal: DVec3 = (0..n).map(|i| p[i].cross(p[(i + 1) % n])).sum();
    (0..n).all(|i| {
        let (a, b, c) = (p[i], p[(i + 1) % n], p[(i + 2) % n]);
        (b - a).cross(c - b).dot(normal) > 0.0
    })
}
