//! The seeded scenes and rays of the ray-casting benchmarks (`benches/scenes.rs`) and of the
//! `cast` example: a Cornell box (32 triangles) and closed, tessellated rooms full of randomly
//! rotated boxes and a few geodesic spheres (`cluttered_room`), built with the generator and
//! seeds of the stand-alone Embree comparison (`rbench gen`, see `benches/embree/`), so
//! that they are the same triangles.
#![allow(dead_code)]

use glam::{Mat4, Quat, Vec3, vec3};
use mcrad_raycast::{Ray, SurfacePoint};

/// Side of the rooms (scene units).
const ROOM: f32 = 5.0;

/// splitmix-seeded xorshift*: the generator of the stand-alone benchmark, so that the scenes
/// are the same triangles.
pub struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Rng {
        let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        Rng((z ^ (z >> 31)) | 1)
    }
    fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in [0, 1).
    fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }
    fn below(&mut self, n: usize) -> usize {
        ((self.next_u64() >> 11) % n as u64) as usize
    }
}

pub type Tri = [Vec3; 3];

/// Quad p0..p3 (counter-clockwise from the front) cut into n x n cells.
pub fn quad(out: &mut Vec<Tri>, p: [Vec3; 4], n: usize) {
    let at = |u: f32, v: f32| p[0].lerp(p[1], u).lerp(p[3].lerp(p[2], u), v);
    let nf = n as f32;
    for j in 0..n {
        for i in 0..n {
            let (u0, u1) = (i as f32 / nf, (i + 1) as f32 / nf);
            let (v0, v1) = (j as f32 / nf, (j + 1) as f32 / nf);
            let (a, b, c, d) = (at(u0, v0), at(u1, v0), at(u1, v1), at(u0, v1));
            out.push([a, b, c]);
            out.push([a, c, d]);
        }
    }
}

/// The unit cube transformed by `m`, outward faces cut n x n, with or without its bottom.
pub fn cube(out: &mut Vec<Tri>, m: Mat4, bottom: bool, n: usize) {
    let c = |x: f32, y: f32, z: f32| m.transform_point3(vec3(x, y, z));
    let (l, h) = (-0.5, 0.5);
    quad(out, [c(h, l, h), c(h, l, l), c(h, h, l), c(h, h, h)], n);
    quad(out, [c(l, l, l), c(l, l, h), c(l, h, h), c(l, h, l)], n);
    quad(out, [c(l, h, h), c(h, h, h), c(h, h, l), c(l, h, l)], n);
    if bottom {
        quad(out, [c(l, l, l), c(h, l, l), c(h, l, h), c(l, l, h)], n);
    }
    quad(out, [c(l, l, h), c(h, l, h), c(h, h, h), c(l, h, h)], n);
    quad(out, [c(h, l, l), c(l, l, l), c(l, h, l), c(h, h, l)], n);
}

/// Geodesic sphere: an icosahedron subdivided `sub` times, outward faces.
pub fn icosphere(out: &mut Vec<Tri>, center: Vec3, radius: f32, sub: u32) {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let v = [
        vec3(-1., t, 0.),
        vec3(1., t, 0.),
        vec3(-1., -t, 0.),
        vec3(1., -t, 0.),
        vec3(0., -1., t),
        vec3(0., 1., t),
        vec3(0., -1., -t),
        vec3(0., 1., -t),
        vec3(t, 0., -1.),
        vec3(t, 0., 1.),
        vec3(-t, 0., -1.),
        vec3(-t, 0., 1.),
    ];
    let f: [[usize; 3]; 20] = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    let mut tris: Vec<Tri> = f.iter().map(|t| t.map(|i| v[i].normalize())).collect();
    for _ in 0..sub {
        let mut next = Vec::with_capacity(tris.len() * 4);
        for [a, b, c] in tris {
            let ab = ((a + b) * 0.5).normalize();
            let bc = ((b + c) * 0.5).normalize();
            let ca = ((c + a) * 0.5).normalize();
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        tris = next;
    }
    out.extend(tris.into_iter().map(|t| t.map(|p| center + p * radius)));
}

/// The six walls of the room (inward faces), cut n x n; without the front wall if `open`.
pub fn room(out: &mut Vec<Tri>, n: usize, open: bool) {
    let p = |x: f32, y: f32, z: f32| vec3(x, y, z) * ROOM;
    quad(
        out,
        [p(0., 0., 0.), p(0., 0., 1.), p(1., 0., 1.), p(1., 0., 0.)],
        n,
    );
    quad(
        out,
        [p(0., 1., 0.), p(1., 1., 0.), p(1., 1., 1.), p(0., 1., 1.)],
        n,
    );
    quad(
        out,
        [p(0., 0., 0.), p(1., 0., 0.), p(1., 1., 0.), p(0., 1., 0.)],
        n,
    );
    quad(
        out,
        [p(0., 0., 0.), p(0., 1., 0.), p(0., 1., 1.), p(0., 0., 1.)],
        n,
    );
    quad(
        out,
        [p(1., 0., 0.), p(1., 0., 1.), p(1., 1., 1.), p(1., 1., 0.)],
        n,
    );
    if !open {
        quad(
            out,
            [p(0., 0., 1.), p(0., 1., 1.), p(1., 1., 1.), p(1., 0., 1.)],
            n,
        );
    }
}

/// The classic Cornell box: open front, two blocks without bottoms, a light: 32 triangles.
pub fn cornell() -> Vec<Tri> {
    let mut t = Vec::new();
    room(&mut t, 1, true);
    let r = ROOM;
    let block = |s: Vec3, angle: f32, at: Vec3| {
        Mat4::from_scale_rotation_translation(
            s * r,
            Quat::from_rotation_y(angle.to_radians()),
            at * r,
        )
    };
    cube(
        &mut t,
        block(Vec3::splat(0.3), -17.5, vec3(0.66, 0.15, 0.65)),
        false,
        1,
    );
    cube(
        &mut t,
        block(vec3(0.3, 0.6, 0.3), 17.5, vec3(0.33, 0.3, 0.35)),
        false,
        1,
    );
    let y = r * 0.999;
    let l = |x: f32, z: f32| vec3(x * r, y, z * r);
    quad(
        &mut t,
        [l(0.4, 0.4), l(0.6, 0.4), l(0.6, 0.6), l(0.4, 0.6)],
        1,
    );
    t
}

/// A closed tessellated room, 4 geodesic spheres and about 1500 randomly rotated boxes, about
/// `target` triangles.
// (6.283, not TAU: the stand-alone benchmark's value, so that the scenes are the same)
#[allow(clippy::approx_constant)]
pub fn cluttered_room(target: usize, seed: u64) -> Vec<Tri> {
    let mut rng = Rng::new(seed);
    let mut t = Vec::with_capacity(target + 1024);
    let n = (((target as f32) * 0.12 / 12.0).sqrt().round() as usize).max(1);
    room(&mut t, n, false);
    let sphere_budget = target as f32 * 0.08 / 4.0;
    let sub = ((sphere_budget / 20.0).ln() / 4f32.ln()).floor().max(0.0) as u32;
    for _ in 0..4 {
        let rad = rng.range(0.25, 0.6);
        let c = vec3(
            rng.range(rad, ROOM - rad),
            rng.range(rad, ROOM - rad),
            rng.range(rad, ROOM - rad),
        );
        icosphere(&mut t, c, rad, sub);
    }
    let remaining = target.saturating_sub(t.len()) as f32;
    let k = ((remaining / (12.0 * 1500.0)).sqrt().round() as usize).max(1);
    while t.len() + 12 * k * k <= target {
        let s = vec3(
            rng.range(0.05, 0.6),
            rng.range(0.05, 0.6),
            rng.range(0.05, 0.6),
        );
        let q = Quat::from_euler(
            glam::EulerRot::YXZ,
            rng.range(0.0, 6.283),
            rng.range(0.0, 6.283),
            rng.range(0.0, 6.283),
        );
        let p = vec3(
            rng.range(0.4, ROOM - 0.4),
            rng.range(0.4, ROOM - 0.4),
            rng.range(0.4, ROOM - 0.4),
        );
        cube(
            &mut t,
            Mat4::from_scale_rotation_translation(s, q, p),
            true,
            k,
        );
    }
    t
}

pub fn normal(t: &Tri) -> Vec3 {
    (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero()
}

/// A uniform point of triangle `i` with its surface data (id = triangle index).
pub fn surface_point(tris: &[Tri], rng: &mut Rng) -> SurfacePoint {
    let i = rng.below(tris.len());
    let t = &tris[i];
    let (mut u, mut v) = (rng.f32(), rng.f32());
    if u + v > 1.0 {
        (u, v) = (1.0 - u, 1.0 - v);
    }
    let p = t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v;
    SurfacePoint::new(p, normal(t), i as u32)
}

/// Cosine-weighted unit direction about `n` (Malley's method).
pub fn cosine_dir(n: Vec3, rng: &mut Rng) -> Vec3 {
    let (t, b) = n.any_orthonormal_pair();
    let r = rng.f32().sqrt();
    let phi = std::f32::consts::TAU * rng.f32();
    let z = (1.0 - r * r).max(0.0).sqrt();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * z).normalize()
}

pub fn surface_rays(tris: &[Tri], n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let p = surface_point(tris, &mut rng);
            Ray::from_surface(p.point, p.normal, cosine_dir(p.normal, &mut rng), p.id)
        })
        .collect()
}

pub fn point_pairs(tris: &[Tri], n: usize, seed: u64) -> Vec<(SurfacePoint, SurfacePoint)> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| (surface_point(tris, &mut rng), surface_point(tris, &mut rng)))
        .collect()
}
