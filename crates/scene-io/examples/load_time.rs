//! Times loading a scene (reading, parsing, validating and repairing it into a `Scene`) and
//! prints one line: the wall-clock seconds, faces, vertices and warnings. The
//! timings of issue 35's "Loading" item (docs/atrium.md) were taken with it.
//!
//! `cargo run --release -p mcrad-scene-io --example load_time -- SCENE [RUNS]` (`RUNS` loads in
//! one process, default 1, each timed; the loader's threads are rayon's, `RAYON_NUM_THREADS`).

use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args_os().skip(1);
    let path = PathBuf::from(args.next().ok_or("usage: load_time SCENE [RUNS]")?);
    let runs: usize = match args.next() {
        Some(n) => n.to_str().ok_or("RUNS is a number")?.parse()?,
        None => 1,
    };
    for _ in 0..runs {
        let clock = Instant::now();
        let loaded = mcrad_scene_io::load(&path)?;
        let seconds = clock.elapsed().as_secs_f64();
        println!(
            "load {seconds:.3} s: {} faces, {} vertices, {} warnings",
            loaded.scene.faces().len(),
            loaded.scene.positions().len(),
            loaded.warnings.len()
        );
    }
    Ok(())
}
