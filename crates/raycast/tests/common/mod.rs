//! Seeded scenes, ray generators and the BVH-vs-oracle comparison shared by the integration
//! tests. Every triangle is wound counter-clockwise seen from the side that faces the room
//! (walls: inward, boxes: outward).
#![allow(dead_code)]

use glam::{Mat3, Vec3, vec3};
use mcrad_raycast::{BruteForce, Hit, Ray, RayCaster, SurfacePoint};
use rand_core::Rng as _;
use rand_pcg::Pcg32;
use std::f32::consts::TAU;

/// A seeded random stream.
pub struct Rng(Pcg32);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(Pcg32::new(seed, 0x0a02_bdbf_7bb3_c0a7))
    }
    /// Uniform in [0, 1).
    pub fn f32(&mut self) -> f32 {
        (self.0.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }
    pub fn below(&mut self, n: usize) -> usize {
        ((self.0.next_u32() as u64 * n as u64) >> 32) as usize
    }
}

/// Triangles with their ids (one id per patch).
#[derive(Clone, Default)]
pub struct Scene {
    pub tris: Vec<[Vec3; 3]>,
    pub ids: Vec<u32>,
    next_id: u32,
}

impl Scene {
    /// A new id for the next patch.
    pub fn new_id(&mut self) -> u32 {
        self.next_id += 1;
        self.next_id - 1
    }

    /// Quad p0..p3 (counter-clockwise from the front) cut into n x n cells; each cell is one
    /// patch (two triangles, one id) when `cell_ids`, else the whole quad is one patch.
    pub fn quad(&mut self, p: [Vec3; 4], n: usize, cell_ids: bool) {
        let at = |u: f32, v: f32| p[0].lerp(p[1], u).lerp(p[3].lerp(p[2], u), v);
        let whole = self.new_id();
        let nf = n as f32;
        for j in 0..n {
            for i in 0..n {
                let (u0, u1) = (i as f32 / nf, (i + 1) as f32 / nf);
                let (v0, v1) = (j as f32 / nf, (j + 1) as f32 / nf);
                let (a, b, c, d) = (at(u0, v0), at(u1, v0), at(u1, v1), at(u0, v1));
                let id = if cell_ids { self.new_id() } else { whole };
                self.tris.push([a, b, c]);
                self.tris.push([a, c, d]);
                self.ids.extend([id, id]);
            }
        }
    }

    /// The box `center + rot * ([-h, h] per axis)`; `outward` normals (an obstacle) or inward
    /// (a room). Faces cut n x n.
    pub fn cuboid(
        &mut self,
        center: Vec3,
        half: Vec3,
        rot: Mat3,
        outward: bool,
        n: usize,
        cell_ids: bool,
    ) {
        let c = |x: f32, y: f32, z: f32| center + rot * (half * vec3(x, y, z));
        let faces = [
            [
                c(1., -1., 1.),
                c(1., -1., -1.),
                c(1., 1., -1.),
                c(1., 1., 1.),
            ],
            [
                c(-1., -1., -1.),
                c(-1., -1., 1.),
                c(-1., 1., 1.),
                c(-1., 1., -1.),
            ],
            [
                c(-1., 1., 1.),
                c(1., 1., 1.),
                c(1., 1., -1.),
                c(-1., 1., -1.),
            ],
            [
                c(-1., -1., -1.),
                c(1., -1., -1.),
                c(1., -1., 1.),
                c(-1., -1., 1.),
            ],
            [
                c(-1., -1., 1.),
                c(1., -1., 1.),
                c(1., 1., 1.),
                c(-1., 1., 1.),
            ],
            [
                c(1., -1., -1.),
                c(-1., -1., -1.),
                c(-1., 1., -1.),
                c(1., 1., -1.),
            ],
        ];
        for mut f in faces {
            if !outward {
                f.reverse();
            }
            self.quad(f, n, cell_ids);
        }
    }

    /// Every vertex mapped by `f` (ids unchanged).
    pub fn map(&self, f: impl Fn(Vec3) -> Vec3) -> Scene {
        Scene {
            tris: self.tris.iter().map(|t| t.map(&f)).collect(),
            ..self.clone()
        }
    }

    pub fn normal(&self, i: usize) -> Vec3 {
        let [a, b, c] = self.tris[i];
        (b - a).cross(c - a).normalize()
    }
}

/// A Cornell-like box: unit room open at the front, ceiling light, two rotated blocks standing
/// on the floor, each wall one patch (two triangles).
pub fn cornell() -> Scene {
    let mut s = Scene::default();
    let p = vec3;
    s.quad(
        [p(0., 0., 0.), p(0., 0., 1.), p(1., 0., 1.), p(1., 0., 0.)],
        1,
        false,
    ); // floor
    s.quad(
        [p(0., 1., 0.), p(1., 1., 0.), p(1., 1., 1.), p(0., 1., 1.)],
        1,
        false,
    ); // ceiling
    s.quad(
        [p(0., 0., 0.), p(1., 0., 0.), p(1., 1., 0.), p(0., 1., 0.)],
        1,
        false,
    ); // back
    s.quad(
        [p(0., 0., 0.), p(0., 1., 0.), p(0., 1., 1.), p(0., 0., 1.)],
        1,
        false,
    ); // left
    s.quad(
        [p(1., 0., 0.), p(1., 0., 1.), p(1., 1., 1.), p(1., 1., 0.)],
        1,
        false,
    ); // right
    let y = 0.999;
    s.quad(
        [
            p(0.4, y, 0.4),
            p(0.6, y, 0.4),
            p(0.6, y, 0.6),
            p(0.4, y, 0.6),
        ],
        1,
        false,
    ); // light
    let ry = |deg: f32| Mat3::from_rotation_y(deg.to_radians());
    s.cuboid(
        vec3(0.66, 0.15, 0.65),
        vec3(0.15, 0.15, 0.15),
        ry(-17.5),
        true,
        1,
        false,
    );
    s.cuboid(
        vec3(0.33, 0.3, 0.35),
        vec3(0.15, 0.3, 0.15),
        ry(17.5),
        true,
        1,
        false,
    );
    s
}

/// A closed room 4 x 3 x 5 with cell patches on the walls and `n_boxes` boxes: some standing
/// on the floor (coplanar contact), some against a wall, some floating and rotated.
pub fn room_with_boxes(seed: u64, n_boxes: usize) -> Scene {
    let mut rng = Rng::new(seed);
    let mut s = Scene::default();
    let size = vec3(4.0, 3.0, 5.0);
    s.cuboid(size * 0.5, size * 0.5, Mat3::IDENTITY, false, 4, true);
    for k in 0..n_boxes {
        let half = vec3(
            rng.range(0.1, 0.5),
            rng.range(0.1, 0.5),
            rng.range(0.1, 0.5),
        );
        let (center, rot) = match k % 3 {
            0 => {
                let c = vec3(rng.range(0.6, 3.4), half.y, rng.range(0.6, 4.4));
                (c, Mat3::from_rotation_y(rng.range(0.0, TAU)))
            }
            1 => (
                vec3(half.x, rng.range(0.6, 2.4), rng.range(0.6, 4.4)),
                Mat3::IDENTITY,
            ),
            _ => {
                let c = vec3(
                    rng.range(0.6, 3.4),
                    rng.range(0.6, 2.4),
                    rng.range(0.6, 4.4),
                );
                let r = Mat3::from_euler(
                    glam::EulerRot::YXZ,
                    rng.range(0.0, TAU),
                    rng.range(0.0, TAU),
                    rng.range(0.0, TAU),
                );
                (c, r)
            }
        };
        let n = 1 + rng.below(3);
        s.cuboid(center, half, rot, true, n, rng.below(2) == 0);
    }
    s
}

/// A closed box (inward normals) of random size, orientation and position, faces cut `n x n`.
pub fn random_closed_box(seed: u64, n: usize) -> Scene {
    let mut rng = Rng::new(seed);
    let mut s = Scene::default();
    let half = vec3(
        rng.range(0.2, 3.0),
        rng.range(0.2, 3.0),
        rng.range(0.2, 3.0),
    );
    let center = vec3(
        rng.range(-5.0, 5.0),
        rng.range(-5.0, 5.0),
        rng.range(-5.0, 5.0),
    );
    let rot = Mat3::from_euler(
        glam::EulerRot::YXZ,
        rng.range(0.0, TAU),
        rng.range(0.0, TAU),
        rng.range(0.0, TAU),
    );
    s.cuboid(center, half, rot, false, n, rng.below(2) == 0);
    s
}

/// Duff et al. 2017 orthonormal basis around a unit vector.
pub fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        vec3(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        vec3(b, sign + n.y * n.y * a, -n.y),
    )
}

/// Cosine-distributed direction about `n`.
pub fn cosine_dir(n: Vec3, rng: &mut Rng) -> Vec3 {
    let (t, b) = basis(n);
    let r = rng.f32().sqrt();
    let phi = std::f32::consts::TAU * rng.f32();
    let z = (1.0 - r * r).max(0.0).sqrt();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * z).normalize()
}

/// A direction almost in the plane of `n`: `n` component `1e-2 .. 1e-6` before normalising.
pub fn grazing_dir(n: Vec3, rng: &mut Rng) -> Vec3 {
    let (t, b) = basis(n);
    let phi = std::f32::consts::TAU * rng.f32();
    let lift = 10f32.powf(-rng.range(2.0, 6.0));
    (t * phi.cos() + b * phi.sin() + n * lift).normalize()
}

/// Where on a triangle an origin is sampled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spot {
    /// Uniform over the triangle.
    Uniform,
    /// Uniform on one of its edges (shared with a neighbour patch or a wall corner).
    Edge,
    /// One of its vertices.
    Corner,
}

/// A point of triangle `tri` of the scene.
pub fn point_on(s: &Scene, tri: usize, spot: Spot, rng: &mut Rng) -> Vec3 {
    let [a, b, c] = s.tris[tri];
    match spot {
        Spot::Uniform => {
            let (mut u, mut v) = (rng.f32(), rng.f32());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            a + (b - a) * u + (c - a) * v
        }
        Spot::Edge => {
            let t = rng.f32();
            match rng.below(3) {
                0 => a.lerp(b, t),
                1 => b.lerp(c, t),
                _ => c.lerp(a, t),
            }
        }
        Spot::Corner => [a, b, c][rng.below(3)],
    }
}

/// A seeded surface ray: triangle uniform by index, origin at `spot`, cosine direction (or a
/// grazing one), leaving the front side.
pub fn surface_ray(s: &Scene, spot: Spot, grazing: bool, rng: &mut Rng) -> Ray {
    let tri = rng.below(s.tris.len());
    let n = s.normal(tri);
    let p = point_on(s, tri, spot, rng);
    let d = if grazing {
        grazing_dir(n, rng)
    } else {
        cosine_dir(n, rng)
    };
    Ray::from_surface(p, n, d, s.ids[tri])
}

/// A seeded surface point (any spot) for visibility queries.
pub fn surface_point(s: &Scene, rng: &mut Rng) -> SurfacePoint {
    let tri = rng.below(s.tris.len());
    let spot = match rng.below(8) {
        0 => Spot::Edge,
        1 => Spot::Corner,
        _ => Spot::Uniform,
    };
    SurfacePoint::new(point_on(s, tri, spot, rng), s.normal(tri), s.ids[tri])
}

/// Relative tie tolerance: two candidates closer than this (relative to the nearest distance)
/// are a genuine tie.
pub const TIE: f32 = 1e-5;

/// How a caster's answer compares with the oracle's.
#[derive(Clone, Debug, PartialEq)]
pub enum Verdict {
    /// Same id and side (or both miss), distances within 1e-4 relative (or one surface
    /// offset, for hits next to the origin).
    Same,
    /// Different id, but the oracle also hits that id within [`TIE`] of its nearest distance
    /// (or one surface offset).
    Tie,
    /// Different, but the oracle itself changes its answer when the origin moves by at most half
    /// a surface offset (see [`probes`]): the query is decided below the resolution of the
    /// canonical frame (origins on a patch edge meeting another surface, rays grazing an edge).
    Unstable,
    /// Anything else.
    Wrong(String),
}

/// The 26 unit directions towards the faces, edges and corners of a cube.
fn directions() -> impl Iterator<Item = Vec3> {
    (0..27).filter(|&k| k != 13).map(|k| {
        let c = |i: i32| (i % 3 - 1) as f32;
        vec3(c(k), c(k / 3), c(k / 9)).normalize()
    })
}

/// Variants of a surface point that probe the stability of a query: the point moved in 26
/// directions by half a surface offset and by 1/16 of one (never below two ulps of its largest
/// coordinate: smaller moves are rounded away), and its normal tilted in 26 directions by 0.3
/// down to 0.003, which moves the lifted origin (computed in `f64`) by fractions of an offset
/// finer than `f32` could place the point.
pub fn probes(oracle: &BruteForce, p: &SurfacePoint) -> Vec<SurfacePoint> {
    let floor = p.point.abs().max_element() * 2f32.powi(-22);
    let eps = oracle.surface_epsilon();
    let mut out = Vec::new();
    for step in [0.5 * eps, eps / 16.0] {
        let step = step.max(floor);
        out.extend(directions().map(|d| SurfacePoint {
            point: p.point + d * step,
            ..*p
        }));
    }
    if p.normal != Vec3::ZERO {
        for tilt in [0.3, 0.1, 0.03, 0.01, 0.003] {
            out.extend(directions().map(|d| SurfacePoint {
                normal: (p.normal + d * tilt).normalize(),
                ..*p
            }));
        }
    }
    out
}

/// Compares `hit` (from a caster under test) with the oracle's view of `ray`.
pub fn judge(oracle: &BruteForce, ray: &Ray, hit: Option<Hit>) -> Verdict {
    if hit.is_some_and(|h| h.id == ray.exclude) {
        return Verdict::Wrong(format!("own id reported: {hit:?} for {ray:?}"));
    }
    let all = oracle.hits_along(ray);
    let eps = oracle.surface_epsilon();
    match (hit, all.first()) {
        (None, None) => return Verdict::Same,
        (Some(h), Some(best)) => {
            if h.id == best.id {
                let dt = (h.distance - best.distance).abs();
                if dt <= 1e-4 * best.distance + eps {
                    if h.front != best.front {
                        return Verdict::Wrong(format!(
                            "side {h:?} vs oracle {best:?} for {ray:?}"
                        ));
                    }
                    return Verdict::Same;
                }
            } else {
                // (plus one surface offset: hits at distance ~0 on two surfaces meeting at the
                // origin are ties too)
                let tol = TIE * best.distance + eps;
                if all
                    .iter()
                    .any(|o| o.id == h.id && (o.distance - best.distance).abs() <= tol)
                {
                    return Verdict::Tie;
                }
            }
        }
        _ => {}
    }
    // Different: is the oracle itself undecided within half a surface offset of the origin?
    let key = |h: Option<Hit>| h.map(|h| (h.id, h.distance));
    let reference = key(all.first().copied());
    let gap = match (hit, reference) {
        (Some(h), Some((_, d))) => (h.distance - d).abs(),
        _ => f32::INFINITY,
    };
    let from = SurfacePoint::new(ray.origin, ray.origin_normal, ray.exclude);
    for p in probes(oracle, &from) {
        let moved = Ray {
            origin: p.point,
            origin_normal: p.normal,
            ..*ray
        };
        let other = key(oracle.closest_hit(&moved));
        let flips = match (other, reference) {
            (Some((i, d)), Some((j, e))) => i != j || (d - e).abs() >= gap,
            (None, None) => false,
            _ => true,
        };
        if flips {
            return Verdict::Unstable;
        }
    }
    Verdict::Wrong(format!(
        "hit {hit:?} vs oracle {:?} for {ray:?}",
        &all[..all.len().min(3)]
    ))
}

/// Compares an occlusion answer with the oracle's.
pub fn judge_occlusion(
    oracle: &BruteForce,
    a: &SurfacePoint,
    b: &SurfacePoint,
    occluded: bool,
) -> Verdict {
    let reference = oracle.occluded(a, b);
    if reference == occluded {
        return Verdict::Same;
    }
    for moved in probes(oracle, a) {
        if oracle.occluded(&moved, b) != reference {
            return Verdict::Unstable;
        }
    }
    for moved in probes(oracle, b) {
        if oracle.occluded(a, &moved) != reference {
            return Verdict::Unstable;
        }
    }
    Verdict::Wrong(format!(
        "occluded {occluded} vs oracle {reference} for {a:?} -> {b:?}, blockers {:?}",
        oracle.blockers(a, b)
    ))
}

/// Counts of a comparison run.
#[derive(Clone, Debug, Default)]
pub struct Tally {
    pub same: usize,
    pub ties: usize,
    pub unstable: usize,
    pub wrong: Vec<String>,
}

impl Tally {
    pub fn add(&mut self, v: Verdict) {
        match v {
            Verdict::Same => self.same += 1,
            Verdict::Tie => self.ties += 1,
            Verdict::Unstable => self.unstable += 1,
            Verdict::Wrong(s) => self.wrong.push(s),
        }
    }
    pub fn total(&self) -> usize {
        self.same + self.ties + self.unstable + self.wrong.len()
    }
}

/// Checks every ray on `caster` against the oracle.
pub fn compare(caster: &dyn RayCaster, oracle: &BruteForce, rays: &[Ray]) -> Tally {
    let mut tally = Tally::default();
    for r in rays {
        tally.add(judge(oracle, r, caster.closest_hit(r)));
    }
    tally
}

/// Checks every visibility pair on `caster` against the oracle.
pub fn compare_occlusion(
    caster: &dyn RayCaster,
    oracle: &BruteForce,
    pairs: &[(SurfacePoint, SurfacePoint)],
) -> Tally {
    let mut tally = Tally::default();
    for (a, b) in pairs {
        tally.add(judge_occlusion(oracle, a, b, caster.occluded(a, b)));
    }
    tally
}
