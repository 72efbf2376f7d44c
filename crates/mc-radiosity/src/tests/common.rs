//! Scenes and helpers shared by the estimator tests (each test crate uses a part of them).

use crate::{Method, ScheduleConfig, run};
use glam::{DVec3, Vec3};
use mcrad_meshing::Mesh;
use mcrad_raycast::Bvh;
use mcrad_scene_io::{Face, Material, Scene};
use std::ops::ControlFlow;

pub fn material(name: &str, rho: f32, e: f32) -> Material {
    Material {
        name: name.into(),
        reflectance: Vec3::splat(rho),
        emission: Vec3::splat(e),
    }
}

pub fn quad(vertices: [u32; 4], material: u32, source: u32) -> Face {
    Face {
        vertices: vertices.to_vec(),
        material,
        source,
    }
}

/// The six inward-facing faces of an axis-aligned box `[0, s]³` (counter-clockwise seen from
/// inside), each with the material index given.
pub fn box_faces(s: f32, positions: &mut Vec<Vec3>, faces: &mut Vec<Face>, materials: [u32; 6]) {
    let base = positions.len() as u32;
    for z in [0.0, s] {
        for y in [0.0, s] {
            for x in [0.0, s] {
                positions.push(Vec3::new(x, y, z));
            }
        }
    }
    // Vertex (x, y, z) bits: index = x + 2y + 4z. Quads listed CCW seen from inside.
    let quads = [
        [1, 3, 2, 0], // z = 0, normal +z
        [6, 7, 5, 4], // z = s, normal -z
        [4, 5, 1, 0], // y = 0, normal +y
        [3, 7, 6, 2], // y = s, normal -y
        [2, 6, 4, 0], // x = 0, normal +x
        [5, 7, 3, 1], // x = s, normal -x
    ];
    for (q, m) in quads.iter().zip(materials) {
        let source = faces.len() as u32;
        faces.push(quad(q.map(|i| base + i), m, source));
    }
}

pub fn furnace(rho: f32) -> Scene {
    let (mut p, mut f) = (Vec::new(), Vec::new());
    box_faces(1.0, &mut p, &mut f, [0; 6]);
    Scene::new(p, f, vec![material("furnace", rho, 1.0)])
        .unwrap()
        .0
}

pub fn bvh(mesh: &Mesh) -> Bvh {
    Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap()
}

/// Two parallel unit squares one unit apart: a lamp at `z = 0` facing +z (patch 0: E = 1,
/// rho = 0) and a grey receiver at `z = 1` facing -z (patch 1: rho = 0.5), whose form factor to
/// the lamp is 0.199825.
pub fn parallel_squares() -> Scene {
    let positions = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(1.0, 0.0, 1.0),
        Vec3::new(1.0, 1.0, 1.0),
        Vec3::new(0.0, 1.0, 1.0),
    ];
    let faces = vec![quad([0, 1, 2, 3], 0, 0), quad([4, 7, 6, 5], 1, 1)];
    Scene::new(
        positions,
        faces,
        vec![material("lamp", 0.0, 1.0), material("grey", 0.5, 0.0)],
    )
    .unwrap()
    .0
}

/// Mean and standard error of the mean of `xs` (at least two values).
pub fn mean_se(xs: &[f64]) -> (f64, f64) {
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// `f` run on a pool of `threads` threads (for same-seed-same-answer tests).
pub fn on_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

/// `(B, var B)` of one run of `method` with `config`, run to the end.
pub fn estimate(
    method: Method,
    mesh: &Mesh,
    bvh: &Bvh,
    config: &ScheduleConfig,
) -> (Vec<DVec3>, Vec<DVec3>) {
    let e = run(
        method,
        mesh,
        bvh,
        config,
        &mut |_| ControlFlow::Continue(()),
    )
    .unwrap()
    .estimate;
    let v = e.variance().expect("a variance").to_vec();
    (e.radiosity().to_vec(), v)
}

/// Pooled over patches and channels: the spread of `B` between runs (sample variance) over the
/// mean variance the runs reported, for runs of `(B, var B)`; 1 when the variances are true.
pub fn spread_over_reported<'a>(runs: impl IntoIterator<Item = (&'a [DVec3], &'a [DVec3])>) -> f64 {
    let runs: Vec<(&[DVec3], &[DVec3])> = runs.into_iter().collect();
    let n = runs.len() as f64;
    let (mut spread, mut reported) = (0.0, 0.0);
    for i in 0..runs[0].0.len() {
        for c in 0..3 {
            let mean = runs.iter().map(|r| r.0[i][c]).sum::<f64>() / n;
            spread += runs.iter().map(|r| (r.0[i][c] - mean).powi(2)).sum::<f64>() / (n - 1.0);
            reported += runs.iter().map(|r| r.1[i][c]).sum::<f64>() / n;
        }
    }
    spread / reported
}
