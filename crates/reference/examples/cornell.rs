//! Solves the Cornell box deterministically, one patch per face (the command line's
//! `--no-subdivide`): explicit form factors, then Gauss-Seidel. Prints the work, the estimated
//! accuracy and the mean radiosity of each material.
//!
//! `cargo run --release -p mcrad-reference --example cornell`

use glam::DVec3;
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use mcrad_reference::{ReferenceConfig, reference};
use std::path::Path;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.obj");
    let scene = mcrad_scene_io::load(&path)?.scene;
    let mesh = Mesh::build(&scene, Subdivision::None)?;
    // Visibility is cast through the BVH; its ids are patch indices.
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())?;
    // The default targets are a reference's (1e-4 of each row); a looser visibility target is
    // much quicker where a rougher answer will do (here about 50 times).
    let config = ReferenceConfig {
        visibility_tolerance: 2e-3,
        ..ReferenceConfig::default()
    };
    let start = Instant::now();
    let result = reference(&mesh, &bvh, &config, &|_rows_done| {})?;
    let stats = &result.stats;
    println!(
        "{} patches in {:.2} s: {} shadow rays, {} Gauss-Seidel sweeps, residual {:.1e}",
        stats.patches,
        start.elapsed().as_secs_f64(),
        stats.form_factors.rays,
        stats.iterations,
        stats.residual,
    );
    println!(
        "largest estimated row error: quadrature {:.1e}, visibility {:.1e}",
        stats.form_factors.max_quadrature_error, stats.form_factors.max_visibility_error,
    );
    // Area-weighted mean radiosity per material (with no subdivision, patch i is face i).
    for (m, material) in scene.materials().iter().enumerate() {
        let (mut power, mut area) = (DVec3::ZERO, 0.0);
        for (patch, b) in mesh.patches().iter().zip(result.estimate.radiosity()) {
            if patch.material as usize == m {
                power += patch.area * *b;
                area += patch.area;
            }
        }
        println!("  {:<5} mean B = {:.3} W/m²", material.name, power / area);
    }
    Ok(())
}
