//! The fixed cost of a solve (issue 17, item 5): how long from the scene file to the first useful
//! solution on a small scene, and which stage takes it.
//!
//! `cargo bench -p mcrad-mc-radiosity --bench first_solution`. The scene is the bundled Cornell
//! box cut to about 300 patches. "Useful" is measured, not assumed: at setup the bench finds the
//! smallest budget of the form `1000 * 2^k` rays at which `combined` has `rms_rel <= 5%` against
//! the reference solver on the same mesh (mean over three seeds, printed once), and the groups
//! time, with the thread pool already running:
//! - `load`: reading and validating the OBJ and MTL;
//! - `mesh`: cutting the faces into patches;
//! - `bvh`: building the ray caster;
//! - `solve`: `combined` with that budget;
//! - `file_to_solution`: the four in a row, what a caller waits for;
//! - `solve_1000_rays`: `combined` with 1000 rays, nearly all of it the schedule's own overhead
//!   (passes, thread dispatch, allocation).

use criterion::{Criterion, criterion_group, criterion_main};
use mcrad_mc_radiosity::{Method, ScheduleConfig, Solution, run};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use std::hint::black_box;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

/// The Cornell box's patch edge (m) giving about 300 patches.
const MAX_EDGE: f32 = 0.09;
/// The error that makes a solution useful: 5% `rms_rel`.
const USEFUL: f64 = 0.05;

fn scene_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.obj")
}

fn load() -> mcrad_scene_io::Scene {
    mcrad_scene_io::load(&scene_path())
        .expect("the bundled Cornell box loads")
        .scene
}

fn mesh(scene: &mcrad_scene_io::Scene) -> Mesh {
    Mesh::build(scene, Subdivision::MaxEdge(MAX_EDGE)).expect("the Cornell box meshes")
}

fn bvh(mesh: &Mesh) -> Bvh {
    Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).expect("the BVH builds")
}

fn solve(method: Method, mesh: &Mesh, bvh: &Bvh, rays: u64, seed: u64) -> Solution {
    let config = ScheduleConfig {
        rays,
        seed,
        ..ScheduleConfig::default()
    };
    run(method, mesh, bvh, &config, &mut |_| {
        ControlFlow::Continue(())
    })
    .expect("the Cornell box solves")
}

/// The smallest budget `1000 * 2^k` whose `combined` solutions have a mean `rms_rel` of at most
/// [`USEFUL`] over three seeds, and that mean.
fn useful_budget(mesh: &Mesh, bvh: &Bvh) -> (u64, f64) {
    let config = ScheduleConfig {
        reference: mcrad_reference::ReferenceConfig {
            visibility_tolerance: 5e-4,
            ..Default::default()
        },
        ..ScheduleConfig::default()
    };
    let reference = run(Method::Reference, mesh, bvh, &config, &mut |_| {
        ControlFlow::Continue(())
    })
    .expect("the reference solver solves the Cornell box");
    let patches = mesh.patches();
    let area: Vec<f64> = patches.iter().map(|p| p.area).collect();
    let emission: Vec<_> = patches.iter().map(|p| p.emission.as_dvec3()).collect();
    let mut rays = 1000;
    loop {
        let error = (0..3)
            .map(|seed| {
                let run = solve(Method::Combined, mesh, bvh, rays, seed);
                mcrad_combine::rms_rel(
                    &area,
                    &emission,
                    run.estimate.radiosity(),
                    reference.estimate.radiosity(),
                )
            })
            .sum::<f64>()
            / 3.0;
        if error <= USEFUL || rays >= 1 << 30 {
            return (rays, error);
        }
        rays *= 2;
    }
}

fn bench(c: &mut Criterion) {
    let scene = load();
    let patches = mesh(&scene);
    let caster = bvh(&patches);
    let (rays, error) = useful_budget(&patches, &caster);
    eprintln!(
        "first_solution: {} patches, {rays} rays give rms_rel {:.2}% (mean of 3 seeds)",
        patches.patches().len(),
        error * 100.0
    );
    let mut group = c.benchmark_group(format!("cornell_{}patches", patches.patches().len()));
    group.bench_function("load", |b| b.iter(load));
    group.bench_function("mesh", |b| b.iter(|| mesh(black_box(&scene))));
    group.bench_function("bvh", |b| b.iter(|| bvh(&patches)));
    group.bench_function("solve", |b| {
        b.iter(|| {
            solve(Method::Combined, &patches, &caster, rays, 0)
                .estimate
                .rays()
        })
    });
    group.bench_function("solve_1000_rays", |b| {
        b.iter(|| {
            solve(Method::Combined, &patches, &caster, 1000, 0)
                .estimate
                .rays()
        })
    });
    group.bench_function("file_to_solution", |b| {
        b.iter(|| {
            let scene = load();
            let mesh = mesh(black_box(&scene));
            let bvh = bvh(&mesh);
            solve(Method::Combined, &mesh, &bvh, rays, 0)
                .estimate
                .rays()
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
