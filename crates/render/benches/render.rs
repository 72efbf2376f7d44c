//! Wall time of [`render`] for a 512 × 512 image of the Cornell box subdivided to about 100k
//! patches (`Subdivision::MaxEdge(0.0044)` on `scenes/cornell-box.obj`), flat shading, at 1 and
//! 4 samples per pixel, on the current rayon pool (all cores unless `RAYON_NUM_THREADS` says).
//!
//! `cargo bench -p mcrad-render --bench render`. The radiosity is a fixed stand-in
//! (`B = E + 10 rho` W/m²): the render's cost does not depend on the values.

use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use glam::DVec3;
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use mcrad_render::{Camera, RenderSettings, Shading, render};

fn bench(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.obj");
    let scene = mcrad_scene_io::load(&path).expect("bundled scene").scene;
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.0044)).expect("mesh");
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).expect("bvh");
    let camera = Camera::frame_scene(&mesh, &bvh).expect("camera");
    let b: Vec<DVec3> = mesh
        .patches()
        .iter()
        .map(|p| (p.emission + 10.0 * p.reflectance).as_dvec3())
        .collect();
    let mut group = c.benchmark_group(format!(
        "render_512x512_cornell_{}_patches_{}_threads",
        mesh.patches().len(),
        rayon::current_num_threads()
    ));
    group
        .sample_size(20)
        .measurement_time(Duration::from_secs(20));
    for spp in [1, 4] {
        let settings = RenderSettings {
            width: 512,
            height: 512,
            samples_per_pixel: spp,
            sky: None,
            lights: Vec::new(),
            sky_rays: 0,
            gather_rays: 0,
        };
        group.bench_function(format!("flat_{spp}spp"), |bench| {
            bench.iter(|| {
                render(&mesh, &bvh, &camera, Shading::Flat(&b), &settings, &|_| {}).expect("render")
            })
        });
    }
    group.finish();
    black_box(&b);
}

criterion_group!(benches, bench);
criterion_main!(benches);
