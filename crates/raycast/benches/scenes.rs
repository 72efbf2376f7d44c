//! Ray-casting throughput and BVH build time on three seeded scenes of increasing size:
//! `cornell` (32 triangles), `room100k` and `room1m` (a closed, tessellated room full of
//! randomly rotated boxes and a few geodesic spheres: about 100k and 1M triangles). They are
//! the scenes of the stand-alone Embree comparison (`rbench gen`, see `benches/embree/`),
//! rebuilt here with the same generator and seeds.
//!
//! `cargo bench -p mcrad-raycast --bench scenes` (or `cargo xtask bench`, which prints the
//! table). Per scene, criterion group `raycast-<scene>`:
//! - `closest`: [`Bvh::closest_hit`] of surface rays (origin uniform on a random triangle,
//!   cosine direction about its normal, [`Ray::from_surface`]), one at a time, in random order;
//! - `closest_batch`: the same rays through [`RayCaster::closest_hit_batch`] (sorted inside);
//! - `occluded`: [`RayCaster::occluded`] between two random surface points;
//! - `build`: [`Bvh::build`] on the current rayon pool (all cores).
//!
//! Throughputs are in rays (elements) per second. The memory of each BVH
//! ([`Bvh::memory_bytes`]) is written to `target/criterion/raycast-memory.json`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, SamplingMode, Throughput, criterion_group, criterion_main};
use mcrad_raycast::{Bvh, RayCaster};

#[path = "common/scenes.rs"]
mod scenes;
use scenes::{Tri, cluttered_room, cornell, point_pairs, surface_rays};

fn bench_scene(c: &mut Criterion, name: &str, tris: &[Tri], rays: usize, memory: &mut Vec<String>) {
    let ids: Vec<u32> = (0..tris.len() as u32).collect();
    let bvh = Bvh::build(tris, &ids).unwrap();
    memory.push(format!(
        "\"{name}\": {{\"triangles\": {}, \"bytes\": {}}}",
        tris.len(),
        bvh.memory_bytes()
    ));
    let surface = surface_rays(tris, rays, 42);
    let pairs = point_pairs(tris, rays, 43);
    let mut hits = vec![None; rays];

    let mut g = c.benchmark_group(format!("raycast-{name}"));
    g.sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(2))
        .throughput(Throughput::Elements(rays as u64));
    g.bench_function("closest", |b| {
        b.iter(|| {
            surface
                .iter()
                .filter(|r| bvh.closest_hit(r).is_some())
                .count()
        })
    });
    g.bench_function("closest_batch", |b| {
        b.iter(|| bvh.closest_hit_batch(black_box(&surface), &mut hits))
    });
    g.bench_function("occluded", |b| {
        b.iter(|| pairs.iter().filter(|(p, q)| bvh.occluded(p, q)).count())
    });
    g.throughput(Throughput::Elements(tris.len() as u64));
    g.bench_function("build", |b| {
        b.iter(|| Bvh::build(black_box(tris), &ids).unwrap())
    });
    g.finish();
}

fn benches(c: &mut Criterion) {
    let mut memory = Vec::new();
    bench_scene(c, "cornell", &cornell(), 100_000, &mut memory);
    bench_scene(
        c,
        "room100k",
        &cluttered_room(100_000, 1),
        20_000,
        &mut memory,
    );
    bench_scene(
        c,
        "room1m",
        &cluttered_room(1_000_000, 2),
        20_000,
        &mut memory,
    );
    let target = std::env::var_os("CARGO_TARGET_DIR").map_or_else(
        || std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target"),
        std::path::PathBuf::from,
    );
    let dir = target.join("criterion");
    let json = format!("{{{}}}\n", memory.join(", "));
    if std::fs::create_dir_all(&dir).is_ok() {
        let _ = std::fs::write(dir.join("raycast-memory.json"), json);
    }
}

criterion_group!(scenes, benches);
criterion_main!(scenes);
