//! Charts: connected sets of coplanar triangles of one placed primitive, each flattened onto
//! its plane at a fixed texel size.

use glam::{DVec2, DVec3, Vec3};

/// A chart: triangles of one placed primitive that share edges and lie in one plane, with the
/// plane's frame.
#[derive(Debug, Clone)]
pub(crate) struct Chart {
    /// Which placed primitive (index into `GltfSource::instances`).
    pub instance: usize,
    /// Its triangles (indices into the instance's triangle list).
    pub triangles: Vec<u32>,
    /// Frame origin in scene units (a vertex of the chart).
    pub origin: DVec3,
    /// Unit axes of the plane: `u`, `v` and the front normal `n = u × v`.
    pub axes: [DVec3; 3],
    /// The chart's extent in the plane, in texels: the smallest corner `min` of its bounding box
    /// (so that a point `p` sits at `(p - origin)·u / texel - min.x`, likewise for `v`).
    pub min: DVec2,
    /// Width and height of the bounding box, in texels (`>= 0`).
    pub size: DVec2,
}

impl Chart {
    /// The chart-plane coordinates of `p`, in texels from the bounding box's corner.
    pub fn flatten(&self, p: DVec3, texel: f64) -> DVec2 {
        let d = p - self.origin;
        DVec2::new(d.dot(self.axes[0]), d.dot(self.axes[1])) / texel - self.min
    }

    /// The point of the plane at chart coordinates `q` (texels from the corner).
    #[cfg(test)]
    pub fn lift(&self, q: DVec2, texel: f64) -> DVec3 {
        let q = (q + self.min) * texel;
        self.origin + self.axes[0] * q.x + self.axes[1] * q.y
    }
}

/// Union-find with path halving.
struct Sets(Vec<u32>);

impl Sets {
    fn find(&mut self, mut x: u32) -> u32 {
        while self.0[x as usize] != x {
            let parent = self.0[self.0[x as usize] as usize];
            self.0[x as usize] = parent;
            x = parent;
        }
        x
    }

    fn union(&mut self, a: u32, b: u32) {
        let (a, b) = (self.find(a), self.find(b));
        if a != b {
            // the smaller root wins: the result does not depend on the order of unions
            let (lo, hi) = (a.min(b), a.max(b));
            self.0[hi as usize] = lo;
        }
    }
}

/// The charts of one placed primitive whose triangle `k` has world corners `corners[k]`
/// (`None`: a degenerate triangle, left out) and vertex indices `triangles[k]`. Triangles join
/// a chart when they share an edge (two vertex indices) and their planes agree: normals within
/// about 0.5° and the other triangle's corners within `1e-3` of its size from the first's
/// plane (texels are placed on each triangle's own corners, so a slight fold does not matter). Charts come in the order of their first triangle.
pub(crate) fn charts_of(
    instance: usize,
    triangles: &[[u32; 3]],
    corners: &[Option<[Vec3; 3]>],
    texel: f64,
) -> Vec<Chart> {
    let normal = |k: usize| -> Option<DVec3> {
        let [a, b, c] = corners[k]?.map(|p| p.as_dvec3());
        (b - a).cross(c - a).try_normalize()
    };
    let normals: Vec<Option<DVec3>> = (0..triangles.len()).map(normal).collect();
    let mut sets = Sets((0..triangles.len() as u32).collect());
    let mut edges: std::collections::HashMap<(u32, u32), u32> = Default::default();
    for (k, t) in triangles.iter().enumerate() {
        let Some(n) = normals[k] else { continue };
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            let key = (a.min(b), a.max(b));
            match edges.get(&key) {
                Some(&other) => {
                    let o = other as usize;
                    let m = normals[o].expect("only triangles with normals are recorded");
                    let [p, ..] = corners[k].expect("has a normal").map(|p| p.as_dvec3());
                    let other = corners[o].expect("has a normal").map(|p| p.as_dvec3());
                    let scale = other.iter().map(|c| (c - p).length()).fold(texel, f64::max);
                    let off = other
                        .iter()
                        .map(|q| (q - p).dot(n).abs())
                        .fold(0.0, f64::max);
                    if n.dot(m) > 0.99996 && off <= 1e-3 * scale {
                        sets.union(k as u32, o as u32);
                    }
                }
                None => {
                    edges.insert(key, k as u32);
                }
            }
        }
    }
    let mut index_of_root: std::collections::HashMap<u32, usize> = Default::default();
    let mut charts: Vec<Chart> = Vec::new();
    for k in 0..triangles.len() {
        let Some(n) = normals[k] else { continue };
        let root = sets.find(k as u32);
        let c = *index_of_root.entry(root).or_insert_with(|| {
            let [a, b, _] = corners[k].expect("has a normal").map(|p| p.as_dvec3());
            let u = (b - a).normalize();
            let v = n.cross(u);
            charts.push(Chart {
                instance,
                triangles: Vec::new(),
                origin: a,
                axes: [u, v, n],
                min: DVec2::ZERO,
                size: DVec2::ZERO,
            });
            charts.len() - 1
        });
        charts[c].triangles.push(k as u32);
    }
    for chart in &mut charts {
        let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for &k in &chart.triangles {
            for p in corners[k as usize].expect("charted triangles have corners") {
                let q = chart.flatten(p.as_dvec3(), texel);
                lo = lo.min(q);
                hi = hi.max(q);
            }
        }
        chart.min = lo;
        chart.size = hi - lo;
    }
    charts
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quad_is_one_chart_and_a_folded_pair_is_two() {
        let p = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 1.0),
        ];
        let tris = [[0, 1, 2], [0, 2, 3], [3, 2, 4]];
        let corners: Vec<Option<[Vec3; 3]>> = tris
            .iter()
            .map(|t| Some(t.map(|i| p[i as usize])))
            .collect();
        let charts = charts_of(0, &tris, &corners, 0.25);
        assert_eq!(charts.len(), 2);
        assert_eq!(charts[0].triangles, vec![0, 1]);
        assert_eq!(charts[1].triangles, vec![2]);
        // the quad is 2 x 1 units: 8 x 4 texels of 0.25
        let s = charts[0].size;
        assert!((s.x - 8.0).abs() < 1e-9 && (s.y - 4.0).abs() < 1e-9, "{s}");
        // flatten and lift are inverse on the plane
        let x = DVec3::new(1.3, 0.4, 0.0);
        let back = charts[0].lift(charts[0].flatten(x, 0.25), 0.25);
        assert!((back - x).length() < 1e-12);
        // a degenerate triangle makes no chart
        let corners = vec![Some([p[0], p[1], p[1]])];
        assert!(charts_of(0, &[[0, 1, 1]], &corners, 0.25).is_empty());
    }
}
