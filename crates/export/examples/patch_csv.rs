//! Solves the Cornell box briefly (shooting, one patch per face, 200 000 rays), writes the
//! per-patch CSV `patch,area,r,g,b,var_r,var_g,var_b` to the temporary directory and reads it
//! back: the numbers round-trip exactly.
//!
//! `cargo run --release -p mcrad-export --example patch_csv`

use mcrad_export::{PatchRow, read_patch_csv, write_patch_csv};
use mcrad_mc_radiosity::{Method, ScheduleConfig, run};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use std::io::BufWriter;
use std::ops::ControlFlow;
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let scene_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.obj");
    let scene = mcrad_scene_io::load(&scene_path)?.scene;
    let mesh = Mesh::build(&scene, Subdivision::None)?;
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())?;
    let config = ScheduleConfig {
        rays: 200_000,
        ..ScheduleConfig::default()
    };
    let solution = run(Method::Shoot, &mesh, &bvh, &config, &mut |_| {
        ControlFlow::Continue(())
    })?;
    let estimate = &solution.estimate;

    // One row per patch; with no subdivision the patch number is the input face's.
    let rows: Vec<PatchRow> = mesh
        .patches()
        .iter()
        .enumerate()
        .map(|(i, p)| PatchRow {
            patch: p.face,
            area: p.area,
            radiosity: estimate.radiosity()[i],
            variance: estimate.variance().map(|v| v[i]),
            face: None,
        })
        .collect();
    let path = std::env::temp_dir().join(format!("mcrad-patches-{}.csv", std::process::id()));
    write_patch_csv(BufWriter::new(std::fs::File::create(&path)?), rows.clone())?;
    let text = std::fs::read_to_string(&path)?;
    println!("wrote {} ({} bytes), starting:", path.display(), text.len());
    for line in text.lines().take(3) {
        println!("  {line}");
    }

    let back = read_patch_csv(&path)?;
    std::fs::remove_file(&path)?;
    println!(
        "read back {} rows, identical to those written: {}",
        back.len(),
        back == rows
    );
    if let Some(row) = back.first() {
        println!(
            "face {}: area {:.4} units², B = {:.3} W/m²",
            row.patch, row.area, row.radiosity
        );
    }
    Ok(())
}
