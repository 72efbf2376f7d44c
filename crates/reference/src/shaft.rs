//! Shaft culling: is any surface inside the convex hull of two polygons?
//!
//! Two patches see each other wholly when nothing lies between them: no surface meets the
//! interior of the *shaft*, the convex hull of the two (clipped) polygons (Haines and Wallace
//! 1991). The occluders are the input faces, rebuilt as the convex hull of their patches
//! (coplanar by construction), under a bounding-volume hierarchy. A face meets the shaft when
//! its outline, clipped to the shaft's supporting planes, keeps a point deeper inside than the
//! geometry tolerance: contact (a wall the shaft runs along, a face through a shared edge)
//! does not count. A non-convex face is represented by its convex hull, which can only report
//! more faces (the pair then falls back to shadow rays: slower, never wrong).

use super::form_factor::clip_above;
use glam::DVec3;

/// A plane `n · x = d`; the shaft lies on the side `n · x - d <= 0`.
#[derive(Debug, Clone, Copy)]
struct Plane {
    n: DVec3,
    d: f64,
}

/// One occluder: a face's convex outline and plane.
#[derive(Debug, Clone)]
struct Occluder {
    face: u32,
    normal: DVec3,
    offset: f64,
    outline: Vec<DVec3>,
    lo: DVec3,
    hi: DVec3,
}

/// A node of the hierarchy: its box, and either two children or a range of occluders.
#[derive(Debug, Clone)]
struct Node {
    lo: DVec3,
    hi: DVec3,
    /// Leaf: `(first, count)` into `Occluders::items`; inner: `count == 0`, children `first`
    /// and `first + 1`.
    first: u32,
    count: u32,
}

/// The scene's faces as occluders.
#[derive(Debug, Clone)]
pub(crate) struct Occluders {
    items: Vec<Occluder>,
    nodes: Vec<Node>,
    eps: f64,
}

/// Inputs per face: its id, unit normal, plane offset, and the corners of all its patches.
pub(crate) struct FaceInput {
    pub face: u32,
    pub normal: DVec3,
    pub offset: f64,
    pub points: Vec<DVec3>,
}

const LEAF: usize = 4;

impl Occluders {
    /// The occluders of the given faces; `eps` is the geometry tolerance (scene units).
    pub fn new(faces: Vec<FaceInput>, eps: f64) -> Occluders {
        let mut items: Vec<Occluder> = faces
            .into_iter()
            .map(|f| {
                let outline = convex_outline(&f.points, f.normal);
                let (mut lo, mut hi) =
                    (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
                for p in &outline {
                    lo = lo.min(*p);
                    hi = hi.max(*p);
                }
                Occluder {
                    face: f.face,
                    normal: f.normal,
                    offset: f.offset,
                    outline,
                    lo,
                    hi,
                }
            })
            .filter(|o| o.outline.len() >= 3)
            .collect();
        let mut nodes = Vec::new();
        if !items.is_empty() {
            nodes.push(Node {
                lo: DVec3::ZERO,
                hi: DVec3::ZERO,
                first: 0,
                count: 0,
            });
            let n = items.len();
            build(&mut items, &mut nodes, 0, 0, n);
        }
        Occluders { items, nodes, eps }
    }

    /// The faces (other than `skip`) that meet the interior of the convex hull of `a` and
    /// `b`, each clipped to it (convex polygons, scene units), appended to `out`.
    pub fn in_shaft(&self, a: &[DVec3], b: &[DVec3], skip: [u32; 2], out: &mut Vec<Vec<DVec3>>) {
        if self.nodes.is_empty() {
            return;
        }
        let shaft = Shaft::new(a, b, self.eps);
        let mut stack = vec![0usize];
        while let Some(k) = stack.pop() {
            let node = &self.nodes[k];
            if !shaft.may_meet_box(node.lo, node.hi) {
                continue;
            }
            if node.count == 0 {
                stack.push(node.first as usize);
                stack.push(node.first as usize + 1);
                continue;
            }
            let range = node.first as usize..(node.first + node.count) as usize;
            for o in &self.items[range] {
                if !skip.contains(&o.face)
                    && let Some(clipped) = shaft.meet(o)
                {
                    out.push(clipped);
                }
            }
        }
    }
}

/// Builds the subtree of `items[start..end]` into `nodes[k]` (median split on the longest axis).
fn build(items: &mut [Occluder], nodes: &mut Vec<Node>, k: usize, start: usize, end: usize) {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for o in &items[start..end] {
        lo = lo.min(o.lo);
        hi = hi.max(o.hi);
    }
    nodes[k].lo = lo;
    nodes[k].hi = hi;
    if end - start <= LEAF {
        nodes[k].first = start as u32;
        nodes[k].count = (end - start) as u32;
        return;
    }
    let extent = hi - lo;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let key = |o: &Occluder| (o.lo[axis] + o.hi[axis]) * 0.5;
    items[start..end].sort_by(|a, b| key(a).total_cmp(&key(b)));
    let mid = (start + end) / 2;
    let first = nodes.len();
    nodes[k].first = first as u32;
    nodes[k].count = 0;
    for _ in 0..2 {
        nodes.push(Node {
            lo: DVec3::ZERO,
            hi: DVec3::ZERO,
            first: 0,
            count: 0,
        });
    }
    build(items, nodes, first, start, mid);
    build(items, nodes, first + 1, mid, end);
}

/// The convex outline of coplanar points (normal `n`), counter-clockwise about `n`
/// (Andrew's monotone chain in the plane).
fn convex_outline(points: &[DVec3], n: DVec3) -> Vec<DVec3> {
    let u = n.any_orthonormal_vector();
    let v = n.cross(u);
    let mut pts: Vec<(f64, f64, DVec3)> = points.iter().map(|p| (p.dot(u), p.dot(v), *p)).collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    pts.dedup_by(|a, b| a.0 == b.0 && a.1 == b.1);
    if pts.len() < 3 {
        return pts.into_iter().map(|p| p.2).collect();
    }
    let cross = |o: &(f64, f64, DVec3), a: &(f64, f64, DVec3), b: &(f64, f64, DVec3)| {
        (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
    };
    let mut hull: Vec<(f64, f64, DVec3)> = Vec::with_capacity(2 * pts.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &(f64, f64, DVec3)>> = if pass == 0 {
            Box::new(pts.iter())
        } else {
            Box::new(pts.iter().rev())
        };
        for p in iter {
            while hull.len() >= start + 2
                && cross(&hull[hull.len() - 2], &hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(*p);
        }
        hull.pop();
    }
    hull.into_iter().map(|p| p.2).collect()
}

/// The convex hull of two convex polygons, as its supporting planes.
struct Shaft {
    points: Vec<DVec3>,
    planes: Vec<Plane>,
    lo: DVec3,
    hi: DVec3,
    eps: f64,
}

impl Shaft {
    fn new(a: &[DVec3], b: &[DVec3], eps: f64) -> Shaft {
        let points: Vec<DVec3> = a.iter().chain(b).copied().collect();
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for p in &points {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        let mut shaft = Shaft {
            points,
            planes: Vec::new(),
            lo,
            hi,
            eps,
        };
        // Every facet of the hull holds an edge of one polygon and a vertex of the other, or is
        // the plane of one polygon (Newell normal, through its centroid).
        for poly in [a, b] {
            let mut twice = DVec3::ZERO;
            for (k, p) in poly.iter().enumerate() {
                twice += p.cross(poly[(k + 1) % poly.len()]);
            }
            if let Some(n) = twice.try_normalize() {
                let c = poly.iter().sum::<DVec3>() / poly.len() as f64;
                shaft.support(n, c);
            }
        }
        for (p, q) in [(a, b), (b, a)] {
            for k in 0..p.len() {
                let (e0, e1) = (p[k], p[(k + 1) % p.len()]);
                for v in q {
                    if let Some(n) = (e1 - e0).cross(*v - e0).try_normalize() {
                        shaft.support(n, e0);
                    }
                }
            }
        }
        shaft
    }

    /// Adds the plane through `p` with normal `±n` if every point lies on one side of it
    /// (within `eps`), oriented so that they are behind it.
    fn support(&mut self, n: DVec3, p: DVec3) {
        let d = n.dot(p);
        let (mut above, mut below) = (false, false);
        for q in &self.points {
            let s = n.dot(*q) - d;
            above |= s > self.eps;
            below |= s < -self.eps;
        }
        match (above, below) {
            (false, _) => self.planes.push(Plane { n, d }),
            (true, false) => self.planes.push(Plane { n: -n, d: -d }),
            (true, true) => {}
        }
    }

    /// False when the box `[lo, hi]` lies outside the shaft (a separating shaft plane or box
    /// face).
    fn may_meet_box(&self, lo: DVec3, hi: DVec3) -> bool {
        let e = self.eps;
        if lo.cmpgt(self.hi + DVec3::splat(-e)).any() || hi.cmplt(self.lo + DVec3::splat(e)).any() {
            return false;
        }
        self.planes.iter().all(|pl| {
            // The box corner deepest behind the plane.
            let corner = DVec3::select(pl.n.cmpge(DVec3::ZERO), lo, hi);
            pl.n.dot(corner) - pl.d < -e
        })
    }

    /// The occluder's outline clipped to the shaft, or `None` when it misses the interior: the
    /// clipped outline is empty or lies within `eps` of the shaft's boundary (contact).
    fn meet(&self, o: &Occluder) -> Option<Vec<DVec3>> {
        let e = self.eps;
        if !self.may_meet_box(o.lo, o.hi) {
            return None;
        }
        // Quick rejections: a shaft plane with the whole outline outside, or the occluder's
        // plane with the whole shaft on one side.
        if self
            .planes
            .iter()
            .any(|pl| o.outline.iter().all(|q| pl.n.dot(*q) - pl.d >= -e))
        {
            return None;
        }
        let (mut above, mut below) = (false, false);
        for p in &self.points {
            let s = o.normal.dot(*p) - o.offset;
            above |= s > e;
            below |= s < -e;
        }
        if !(above && below) {
            return None;
        }
        // Exact: the outline clipped to the shaft, and whether any of it is deeper than eps.
        let (mut poly, mut out) = (o.outline.clone(), Vec::with_capacity(o.outline.len() + 8));
        for pl in &self.planes {
            clip_above(&poly, -pl.n, -pl.d, e, &mut out);
            std::mem::swap(&mut poly, &mut out);
            if poly.is_empty() {
                return None;
            }
        }
        let depth = |x: DVec3| {
            self.planes
                .iter()
                .map(|pl| pl.d - pl.n.dot(x))
                .fold(f64::INFINITY, f64::min)
        };
        let centroid = poly.iter().sum::<DVec3>() / poly.len() as f64;
        (depth(centroid) > e || poly.iter().any(|x| depth(*x) > e)).then_some(poly)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(z: f64, x0: f64, x1: f64, y0: f64, y1: f64) -> Vec<DVec3> {
        vec![
            DVec3::new(x0, y0, z),
            DVec3::new(x1, y0, z),
            DVec3::new(x1, y1, z),
            DVec3::new(x0, y1, z),
        ]
    }

    fn face(id: u32, points: Vec<DVec3>) -> FaceInput {
        let n = (points[1] - points[0])
            .cross(points[2] - points[0])
            .normalize();
        FaceInput {
            face: id,
            normal: n,
            offset: n.dot(points[0]),
            points,
        }
    }

    #[test]
    fn a_blocker_between_two_squares_is_found_and_one_beside_them_is_not() {
        let (a, b) = (
            square(0.0, 0.0, 1.0, 0.0, 1.0),
            square(1.0, 0.0, 1.0, 0.0, 1.0),
        );
        let between = Occluders::new(vec![face(7, square(0.5, 0.4, 0.6, 0.4, 0.6))], 1e-9);
        let found = |o: &Occluders, a: &[DVec3], b: &[DVec3], skip: [u32; 2]| {
            let mut out = Vec::new();
            o.in_shaft(a, b, skip, &mut out);
            out
        };
        let hit = found(&between, &a, &b, [0, 1]);
        assert_eq!(hit.len(), 1);
        assert_eq!(hit[0].len(), 4, "the blocker lies wholly inside: {hit:?}");
        assert!(
            found(&between, &a, &b, [7, 1]).is_empty(),
            "skipped faces do not count"
        );
        let beside = Occluders::new(vec![face(7, square(0.5, 1.2, 1.6, 0.4, 0.6))], 1e-9);
        assert!(found(&beside, &a, &b, [0, 1]).is_empty());
        // A wall the shaft runs along (x = 0) only touches it.
        let wall = vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(0.0, 1.0, 1.0),
            DVec3::new(0.0, 0.0, 1.0),
        ];
        let touching = Occluders::new(vec![face(7, wall)], 1e-9);
        assert!(found(&touching, &a, &b, [0, 1]).is_empty());
        // A face made of many patches is one occluder with the hull as outline, and the
        // hierarchy finds it among many others.
        let mut faces: Vec<FaceInput> = (0..50)
            .map(|k| {
                face(
                    10 + k,
                    square(0.5, 3.0 + k as f64, 3.5 + k as f64, 0.0, 1.0),
                )
            })
            .collect();
        let mut pts = square(0.5, 0.9, 0.95, 0.9, 0.95);
        pts.extend(square(0.5, 0.95, 0.99, 0.9, 0.95));
        faces.push(face(99, pts));
        let many = Occluders::new(faces, 1e-9);
        assert_eq!(found(&many, &a, &b, [0, 1]).len(), 1);
        assert!(found(&many, &a, &square(1.0, 0.0, 0.5, 0.0, 0.5), [0, 1]).is_empty());
    }
}
