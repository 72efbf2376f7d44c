//! Single-thread throughput of [`Bvh::closest_hit`] and [`Bvh::occluded`] next to a bare obvhs
//! CWBVH loop over the very same rays, so the cost of the canonical frame, the surface offsets,
//! the window rule and the id filter is the difference.
//!
//! `cargo bench -p mcrad-raycast --bench closest_hit`. Two scenes: a Cornell-like box (36
//! triangles) and a seeded closed room full of boxes (about 100k triangles). Rays are what the
//! shooting solver casts: origins uniform on a random triangle, cosine directions about its
//! normal, `Ray::from_surface`. In each group the ids compare directly (same rays, element
//! throughput):
//! - `closest_hit/mcrad`: `Bvh::closest_hit`;
//! - `closest_hit/obvhs`: obvhs's CWBVH (`build_cwbvh_from_tris`, `medium_build`) `ray_traverse`
//!   with `RtTriangle::intersect` in BVH order, origins offset by `1e-4 * normal`, `tmin = 0`, no
//!   id filter: the floor. Both loops start from the same `Ray` values, so making obvhs's ray
//!   (offset, `Ray::new` and its reciprocal direction) is timed too;
//! - `occluded/mcrad` and `occluded/obvhs`: the same for segments between two surface points
//!   (`ray_traverse_miss`, `tmax` the segment's length less `1e-4`).

use std::f32::consts::TAU;
use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, SamplingMode, Throughput, criterion_group, criterion_main};
use glam::{Mat3, Vec3, Vec3A, vec3};
use mcrad_raycast::{Bvh, Ray, RayCaster, SurfacePoint};
use obvhs::{
    BvhBuildParams,
    cwbvh::{CwBvh, builder::build_cwbvh_from_tris},
    ray::{Ray as ObRay, RayHit},
    rt_triangle::RtTriangle,
    triangle::Triangle,
};
use rand_core::Rng as _;
use rand_pcg::Pcg32;

/// Origin offset of the bare obvhs rays (scene units).
const BARE_OFFSET: f32 = 1e-4;

struct Rng(Pcg32);

impl Rng {
    fn new(seed: u64) -> Rng {
        Rng(Pcg32::new(seed, 0x0a02_bdbf_7bb3_c0a7))
    }
    /// Uniform in [0, 1).
    fn f32(&mut self) -> f32 {
        (self.0.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }
    fn below(&mut self, n: usize) -> usize {
        ((self.0.next_u32() as u64 * n as u64) >> 32) as usize
    }
}

/// Triangles (counter-clockwise from the front) and one id per patch.
#[derive(Default)]
struct Scene {
    tris: Vec<[Vec3; 3]>,
    ids: Vec<u32>,
    next_id: u32,
}

impl Scene {
    /// Quad p0..p3 cut into n x n cells; one patch per cell when `cell_ids`, else one in all.
    fn quad(&mut self, p: [Vec3; 4], n: usize, cell_ids: bool) {
        let at = |u: f32, v: f32| p[0].lerp(p[1], u).lerp(p[3].lerp(p[2], u), v);
        let whole = self.next_id;
        self.next_id += 1;
        let nf = n as f32;
        for j in 0..n {
            for i in 0..n {
                let (u0, u1) = (i as f32 / nf, (i + 1) as f32 / nf);
                let (v0, v1) = (j as f32 / nf, (j + 1) as f32 / nf);
                let (a, b, c, d) = (at(u0, v0), at(u1, v0), at(u1, v1), at(u0, v1));
                let id = if cell_ids {
                    self.next_id += 1;
                    self.next_id - 1
                } else {
                    whole
                };
                self.tris.extend([[a, b, c], [a, c, d]]);
                self.ids.extend([id, id]);
            }
        }
    }

    /// The box `center + rot * [-half, half]`, normals `outward` or inward, faces cut n x n.
    fn cuboid(
        &mut self,
        center: Vec3,
        half: Vec3,
        rot: Mat3,
        outward: bool,
        n: usize,
        cells: bool,
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
            self.quad(f, n, cells);
        }
    }

    fn normal(&self, i: usize) -> Vec3 {
        let [a, b, c] = self.tris[i];
        (b - a).cross(c - a).normalize()
    }
}

/// Unit room open at the front, a ceiling light, two rotated blocks: 36 triangles.
fn cornell() -> Scene {
    let mut s = Scene::default();
    let p = vec3;
    let y = 0.999;
    for q in [
        [p(0., 0., 0.), p(0., 0., 1.), p(1., 0., 1.), p(1., 0., 0.)],
        [p(0., 1., 0.), p(1., 1., 0.), p(1., 1., 1.), p(0., 1., 1.)],
        [p(0., 0., 0.), p(1., 0., 0.), p(1., 1., 0.), p(0., 1., 0.)],
        [p(0., 0., 0.), p(0., 1., 0.), p(0., 1., 1.), p(0., 0., 1.)],
        [p(1., 0., 0.), p(1., 0., 1.), p(1., 1., 1.), p(1., 1., 0.)],
        [
            p(0.4, y, 0.4),
            p(0.6, y, 0.4),
            p(0.6, y, 0.6),
            p(0.4, y, 0.6),
        ],
    ] {
        s.quad(q, 1, false);
    }
    let ry = |deg: f32| Mat3::from_rotation_y(deg.to_radians());
    let half = vec3(0.15, 0.15, 0.15);
    s.cuboid(vec3(0.66, 0.15, 0.65), half, ry(-17.5), true, 1, false);
    let half = vec3(0.15, 0.3, 0.15);
    s.cuboid(vec3(0.33, 0.3, 0.35), half, ry(17.5), true, 1, false);
    s
}

/// A closed 4 x 3 x 5 room with `n_boxes` boxes standing, leaning on a wall or floating
/// (rotated), faces cut 1-3 times per side.
fn room_with_boxes(seed: u64, n_boxes: usize) -> Scene {
    let mut rng = Rng::new(seed);
    let mut s = Scene::default();
    let size = vec3(4.0, 3.0, 5.0);
    s.cuboid(size * 0.5, size * 0.5, Mat3::IDENTITY, false, 4, true);
    for k in 0..n_boxes {
        let half = vec3(
            rng.range(0.02, 0.2),
            rng.range(0.02, 0.2),
            rng.range(0.02, 0.2),
        );
        let (center, rot) = match k % 3 {
            0 => {
                let c = vec3(rng.range(0.3, 3.7), half.y, rng.range(0.3, 4.7));
                (c, Mat3::from_rotation_y(rng.range(0.0, TAU)))
            }
            1 => (
                vec3(half.x, rng.range(0.3, 2.7), rng.range(0.3, 4.7)),
                Mat3::IDENTITY,
            ),
            _ => {
                let c = vec3(
                    rng.range(0.3, 3.7),
                    rng.range(0.3, 2.7),
                    rng.range(0.3, 4.7),
                );
                let (a, b, g) = (
                    rng.range(0.0, TAU),
                    rng.range(0.0, TAU),
                    rng.range(0.0, TAU),
                );
                (c, Mat3::from_euler(glam::EulerRot::YXZ, a, b, g))
            }
        };
        let n = 1 + rng.below(3);
        s.cuboid(center, half, rot, true, n, rng.below(2) == 0);
    }
    s
}

/// Cosine-distributed unit direction about the unit normal `n`.
fn cosine_dir(n: Vec3, rng: &mut Rng) -> Vec3 {
    let sign = 1f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let t = vec3(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let bt = vec3(b, sign + n.y * n.y * a, -n.y);
    let r = rng.f32().sqrt();
    let phi = std::f32::consts::TAU * rng.f32();
    let z = (1.0 - r * r).max(0.0).sqrt();
    (t * (r * phi.cos()) + bt * (r * phi.sin()) + n * z).normalize()
}

/// A uniform point on a random triangle (by index), with that triangle's normal and id.
fn surface_point(s: &Scene, rng: &mut Rng) -> SurfacePoint {
    let tri = rng.below(s.tris.len());
    let [a, b, c] = s.tris[tri];
    let (mut u, mut v) = (rng.f32(), rng.f32());
    if u + v > 1.0 {
        (u, v) = (1.0 - u, 1.0 - v);
    }
    SurfacePoint::new(a + (b - a) * u + (c - a) * v, s.normal(tri), s.ids[tri])
}

fn surface_rays(s: &Scene, n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let p = surface_point(s, &mut rng);
            Ray::from_surface(p.point, p.normal, cosine_dir(p.normal, &mut rng), p.id)
        })
        .collect()
}

fn point_pairs(s: &Scene, n: usize, seed: u64) -> Vec<(SurfacePoint, SurfacePoint)> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| (surface_point(s, &mut rng), surface_point(s, &mut rng)))
        .collect()
}

/// obvhs alone, in world units.
struct Bare {
    bvh: CwBvh,
    tris: Vec<RtTriangle>,
}

impl Bare {
    fn new(s: &Scene) -> Bare {
        let tris: Vec<Triangle> = s
            .tris
            .iter()
            .map(|t| Triangle {
                v0: t[0].into(),
                v1: t[1].into(),
                v2: t[2].into(),
            })
            .collect();
        let bvh = build_cwbvh_from_tris(
            &tris,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        let tris = bvh
            .primitive_indices
            .iter()
            .map(|&i| RtTriangle::from(&tris[i as usize]))
            .collect();
        Bare { bvh, tris }
    }

    /// The closest hit of a surface ray: (BVH slot, distance).
    #[inline]
    fn closest_hit(&self, r: &Ray) -> Option<(u32, f32)> {
        let o = r.origin + r.origin_normal * BARE_OFFSET;
        let ray = ObRay::new(o.into(), r.dir.into(), 0.0, f32::INFINITY);
        let mut hit = RayHit::none();
        self.bvh
            .ray_traverse(ray, &mut hit, |r, slot| self.tris[slot].intersect(r))
            .then_some((hit.primitive_id, hit.t))
    }

    /// Whether anything is between two surface points (both offset).
    #[inline]
    fn occluded(&self, a: &SurfacePoint, b: &SurfacePoint) -> bool {
        let pa = a.point + a.normal * BARE_OFFSET;
        let pb = b.point + b.normal * BARE_OFFSET;
        let d: Vec3A = (pb - pa).into();
        let len = d.length();
        let ray = ObRay::new(pa.into(), d / len, 0.0, len - BARE_OFFSET);
        !self
            .bvh
            .ray_traverse_miss(ray, |r, slot| self.tris[slot].intersect(r))
    }
}

fn bench_scene(c: &mut Criterion, name: &str, s: &Scene, rays: usize) {
    let bvh = Bvh::build(&s.tris, &s.ids).unwrap();
    let bare = Bare::new(s);
    let surface = surface_rays(s, rays, 7);
    let pairs = point_pairs(s, rays, 11);

    let mut g = c.benchmark_group(name);
    g.sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3))
        .throughput(Throughput::Elements(rays as u64));
    g.bench_function("closest_hit/mcrad", |b| {
        b.iter(|| {
            let mut sum = 0.0f32;
            for r in &surface {
                if let Some(h) = bvh.closest_hit(black_box(r)) {
                    sum += h.distance;
                }
            }
            sum
        })
    });
    g.bench_function("closest_hit/obvhs", |b| {
        b.iter(|| {
            let mut sum = 0.0f32;
            for r in &surface {
                if let Some((_, t)) = bare.closest_hit(black_box(r)) {
                    sum += t;
                }
            }
            sum
        })
    });
    g.bench_function("occluded/mcrad", |b| {
        b.iter(|| {
            pairs
                .iter()
                .filter(|(p, q)| bvh.occluded(black_box(p), black_box(q)))
                .count()
        })
    });
    g.bench_function("occluded/obvhs", |b| {
        b.iter(|| {
            pairs
                .iter()
                .filter(|(p, q)| bare.occluded(black_box(p), black_box(q)))
                .count()
        })
    });
    g.finish();
}

fn benches(c: &mut Criterion) {
    bench_scene(c, "cornell_36", &cornell(), 500_000);
    let room = room_with_boxes(3, 1800);
    let name = format!("room_{}k", room.tris.len() / 1000);
    bench_scene(c, &name, &room, 100_000);
}

criterion_group!(closest_hit, benches);
criterion_main!(closest_hit);
