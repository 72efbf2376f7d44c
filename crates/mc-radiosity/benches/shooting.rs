//! Rays per second of the shooting loop on the Cornell box, next to a bare obvhs closest-hit loop
//! over the very same rays, so the cost of the solver's bookkeeping (sampling, random streams,
//! hit records, the power fold) is the difference.
//!
//! `cargo bench -p mcrad-mc-radiosity --bench shooting` (or `cargo xtask bench`). Each group
//! casts the same number of rays, so criterion's element throughput compares directly:
//! - `shoot`: the whole solver (`Method::Shoot` through `run`, with the `random` sampler, the
//!   shooting estimator's own default), `threshold = 0` so it spends exactly its budget; the
//!   schedule adds only per-patch bookkeeping (the precision check, the variance of unreached
//!   patches) to the shooting loop;
//! - `mcrad_bvh`: `mcrad_raycast::Bvh::closest_hit` over the rays the solver cast (recorded);
//! - `bare_obvhs`: obvhs's CWBVH `ray_traverse` over the same rays, no id filter, no window
//!   rule: the scene centred and scaled by a power of two to an extent of 512-1024 (as mcrad's
//!   frame does, so obvhs's 1e-4 cut-off is as harmless), origins offset by 2^-10 of those units
//!   along the normal. The floor the solver cannot beat.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::{Vec3, Vec3A};
use mcrad_mc_radiosity::{Method, Sampler, ScheduleConfig, run};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::{Bvh, Hit, Ray, RayCaster, SurfacePoint};
use obvhs::{
    BvhBuildParams,
    cwbvh::{CwBvh, builder::build_cwbvh_from_tris},
    ray::{Ray as ObRay, RayHit},
    rt_triangle::RtTriangle,
    triangle::Triangle,
};
use rayon::prelude::*;
use std::ops::ControlFlow;
use std::path::Path;
use std::sync::Mutex;

const RAYS: u64 = 1_000_000;

/// A caster that remembers every ray it is asked to trace.
struct Recorder<'a> {
    bvh: &'a Bvh,
    rays: Mutex<Vec<Ray>>,
}

impl RayCaster for Recorder<'_> {
    fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        self.rays.lock().unwrap().push(*ray);
        self.bvh.closest_hit(ray)
    }
    fn occluded(&self, a: &SurfacePoint, b: &SurfacePoint) -> bool {
        self.bvh.occluded(a, b)
    }
}

struct Bare {
    bvh: CwBvh,
    tris: Vec<RtTriangle>,
    centre: Vec3,
    scale: f32,
}

impl Bare {
    fn new(mesh: &Mesh) -> Bare {
        let (lo, hi) = mesh
            .positions()
            .iter()
            .fold((Vec3::MAX, Vec3::MIN), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
        let centre = (lo + hi) * 0.5;
        let mut scale = 1.0f32;
        while (hi - lo).max_element() * scale < 512.0 {
            scale *= 2.0;
        }
        while (hi - lo).max_element() * scale >= 1024.0 {
            scale *= 0.5;
        }
        let tris: Vec<Triangle> = mesh
            .triangle_positions()
            .iter()
            .map(|t| {
                let [v0, v1, v2] = t.map(|p| Vec3A::from((p - centre) * scale));
                Triangle { v0, v1, v2 }
            })
            .collect();
        let bvh = build_cwbvh_from_tris(
            &tris,
            BvhBuildParams::medium_build(),
            &mut Default::default(),
        );
        let tris = bvh
            .primitive_indices
            .iter()
            .map(|&i| RtTriangle::from(&tris[i as usize]))
            .collect();
        Bare {
            bvh,
            tris,
            centre,
            scale,
        }
    }

    fn closest(&self, o: Vec3, n: Vec3, d: Vec3) -> u32 {
        let o = (o - self.centre) * self.scale + n * (1.0 / 1024.0);
        let ray = ObRay::new(Vec3A::from(o), Vec3A::from(d), 0.0, f32::INFINITY);
        let mut hit = RayHit::none();
        if self
            .bvh
            .ray_traverse(ray, &mut hit, |r, id| self.tris[id].intersect(r))
        {
            hit.primitive_id
        } else {
            u32::MAX
        }
    }
}

fn cornell(subdivision: Subdivision) -> Mesh {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.obj");
    let scene = mcrad_scene_io::load(&path)
        .expect("the bundled Cornell box loads")
        .scene;
    Mesh::build(&scene, subdivision).unwrap()
}

fn bench(c: &mut Criterion) {
    for (name, subdivision) in [
        ("cornell_faces", Subdivision::None),
        ("cornell_100k", Subdivision::MaxEdge(0.0044)),
    ] {
        let mesh = cornell(subdivision);
        let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
        let config = ScheduleConfig {
            rays: RAYS,
            unshot_threshold: 0.0,
            seed: 1,
            sampler: Sampler::Random,
            ..Default::default()
        };
        let recorder = Recorder {
            bvh: &bvh,
            rays: Mutex::new(Vec::new()),
        };
        let shot = run(Method::Shoot, &mesh, &recorder, &config, &mut |_| {
            ControlFlow::Continue(())
        })
        .unwrap();
        let mut rays = recorder.rays.into_inner().unwrap();
        // Rays in a deterministic order (the recording order depends on the threads).
        rays.sort_by_key(|r| r.exclude);
        let bare = Bare::new(&mesh);

        let mut group = c.benchmark_group(format!("{name}_{}patches", mesh.patches().len()));
        group.sample_size(10);
        group.throughput(Throughput::Elements(shot.estimate.rays()));
        group.bench_function("shoot", |b| {
            b.iter(|| {
                run(Method::Shoot, &mesh, &bvh, &config, &mut |_| {
                    ControlFlow::Continue(())
                })
                .unwrap()
                .estimate
                .rays()
            })
        });
        group.bench_function("mcrad_bvh", |b| {
            b.iter(|| {
                rays.par_chunks(4096)
                    .map(|rs| rs.iter().filter(|r| bvh.closest_hit(r).is_some()).count())
                    .sum::<usize>()
            })
        });
        group.bench_function("bare_obvhs", |b| {
            b.iter(|| {
                rays.par_chunks(4096)
                    .map(|rs| {
                        rs.iter()
                            .filter(|r| bare.closest(r.origin, r.origin_normal, r.dir) != u32::MAX)
                            .count()
                    })
                    .sum::<usize>()
            })
        });
        group.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
