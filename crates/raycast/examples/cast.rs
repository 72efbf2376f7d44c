//! Casts the seeded rays of the ray-casting benchmark on one scene, one thread, and prints
//! Mrays/s, the BVH's size, build time and the build's peak memory (what the process held at
//! its most during the build, less what it held before, per triangle; Linux): a quick look, and a fixed workload to count
//! instructions with `valgrind --tool=callgrind` (which, unlike a clock, does not depend on
//! what else the machine is doing).
//!
//! `cargo run --release -p mcrad-raycast --example cast -- SCENE QUERY RAYS`, with SCENE one of
//! `cornell`, `room100k`, `room1m`, `room10m` (a room of ten million triangles, for the build's
//! peak memory), QUERY `closest`, `batch`, `occluded` or `lifted` (closest
//! hit with the origins raised 1e-3 off the surface, as the Embree comparison's ray files
//! have them). `PRESET=medium` or `PRESET=slow` picks the build preset; `SIMD=portable`,
//! `SIMD=avx2` or `SIMD=avx512` caps the traversal's instruction sets (see `Bvh::with_simd`).
//!
//! `AB=portable|avx2|avx512` compares the default traversal with the capped one instead: the
//! rays are cast in chunks of 20k, alternating between the two, and the ratio of their times is
//! printed (alternating within one process keeps the machine's drift out of the ratio).

use std::time::Instant;

use mcrad_raycast::{Bvh, RayCaster, Simd};

#[path = "../benches/common/scenes.rs"]
mod scenes;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scene = args.first().map_or("room100k", String::as_str);
    let query = args.get(1).map_or("closest", String::as_str);
    let rays: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(200_000);
    let tris = match scene {
        "cornell" => scenes::cornell(),
        "room100k" => scenes::cluttered_room(100_000, 1),
        "room1m" => scenes::cluttered_room(1_000_000, 2),
        "room10m" => scenes::cluttered_room(10_000_000, 3),
        other => {
            eprintln!("error: unknown scene {other:?} (cornell, room100k, room1m, room10m)");
            std::process::exit(2);
        }
    };
    let ids: Vec<u32> = (0..tris.len() as u32).collect();
    let resident = status_kb("VmRSS");
    let start = Instant::now();
    let preset = match std::env::var("PRESET").as_deref() {
        Ok("medium") => mcrad_raycast::BvhPreset::Medium,
        Ok("slow") => mcrad_raycast::BvhPreset::Slow,
        _ => mcrad_raycast::BvhPreset::Fast,
    };
    let bvh = Bvh::build_with(&tris, &ids, preset).expect("the seeded scenes are valid");
    let build = start.elapsed().as_secs_f64();
    // the build's peak above what the process held before it (the scene included)
    let peak = status_kb("VmHWM")
        .zip(resident)
        .map(|(hwm, before)| (hwm.saturating_sub(before) * 1024) as f64 / tris.len() as f64);
    let simd = |var: &str| match std::env::var(var).as_deref() {
        Ok("portable") => Some(Simd::Portable),
        Ok("avx2") => Some(Simd::Avx2),
        Ok("avx512") => Some(Simd::Avx512),
        _ => None,
    };
    let bvh = match simd("SIMD") {
        Some(most) => bvh.with_simd(most),
        None => bvh,
    };
    let surface = scenes::surface_rays(&tris, rays, 42);
    let pairs = scenes::point_pairs(&tris, rays, 43);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    if let Some(most) = simd("AB") {
        let other = Bvh::build_with(&tris, &ids, preset)
            .expect("the seeded scenes are valid")
            .with_simd(most);
        let (mut a, mut b) = (0.0, 0.0);
        pool.install(|| {
            for chunk in surface.chunks(20_000) {
                for (bvh, time) in [(&bvh, &mut a), (&other, &mut b)] {
                    let start = Instant::now();
                    let hits = chunk
                        .iter()
                        .filter(|r| bvh.closest_hit(r).is_some())
                        .count();
                    *time += start.elapsed().as_secs_f64();
                    std::hint::black_box(hits);
                }
            }
        });
        println!(
            "{scene} closest: {:?} {:.3} Mrays/s, {:?} {:.3} Mrays/s, ratio {:.3}",
            bvh.simd(),
            rays as f64 / a / 1e6,
            other.simd(),
            rays as f64 / b / 1e6,
            a / b,
        );
        return;
    }
    let start = Instant::now();
    let found = pool.install(|| match query {
        "closest" => surface
            .iter()
            .filter(|r| bvh.closest_hit(r).is_some())
            .count(),
        "batch" => {
            let mut hits = vec![None; surface.len()];
            bvh.closest_hit_batch(&surface, &mut hits);
            hits.iter().filter(|h| h.is_some()).count()
        }
        "occluded" => pairs.iter().filter(|(p, q)| bvh.occluded(p, q)).count(),
        "lifted" => surface
            .iter()
            .filter(|r| {
                let mut r = **r;
                r.origin += r.origin_normal * 1e-3;
                bvh.closest_hit(&r).is_some()
            })
            .count(),
        other => {
            eprintln!("error: unknown query {other:?} (closest, batch, occluded, lifted)");
            std::process::exit(2);
        }
    });
    let seconds = start.elapsed().as_secs_f64();
    println!(
        "{scene} {query}: {:.3} Mrays/s ({found} of {rays} hit), {} triangles, {} nodes, \
         {:.1} bytes/triangle, build {:.1} ms, build peak {} bytes/triangle",
        rays as f64 / seconds / 1e6,
        tris.len(),
        bvh.node_count(),
        bvh.memory_bytes() as f64 / tris.len() as f64,
        build * 1e3,
        peak.map_or("?".to_string(), |p| format!("{p:.0}")),
    );
}

/// A memory figure of this process in KiB (`VmRSS`: resident now, `VmHWM`: the most resident
/// so far), where the system tells it (Linux).
fn status_kb(field: &str) -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with(field))?;
    line.split_whitespace().nth(1)?.parse().ok()
}
