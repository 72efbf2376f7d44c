//! Solves the Cornell box (one patch per face) with a few Monte Carlo methods of the registry on
//! a budget of 200 000 rays each, and measures each against the deterministic reference with
//! `rms_rel`. An observer sees every complete intermediate solution and could stop the run.
//!
//! `cargo run --release -p mcrad-mc-radiosity --example methods`

use mcrad_combine::rms_rel;
use mcrad_mc_radiosity::{Method, ScheduleConfig, run};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use mcrad_reference::ReferenceConfig;
use std::ops::ControlFlow;
use std::path::Path;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.obj");
    let scene = mcrad_scene_io::load(&path)?.scene;
    let mesh = Mesh::build(&scene, Subdivision::None)?;
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())?;
    let config = ScheduleConfig {
        rays: 200_000,
        seed: 1,
        // Only Method::Reference reads this: a quick, rougher reference.
        reference: ReferenceConfig {
            visibility_tolerance: 2e-3,
            ..ReferenceConfig::default()
        },
        ..ScheduleConfig::default()
    };

    let reference = run(Method::Reference, &mesh, &bvh, &config, &mut |_| {
        ControlFlow::Continue(())
    })?;
    let exact = reference.estimate.radiosity();
    let area: Vec<f64> = mesh.patches().iter().map(|p| p.area).collect();
    let emission: Vec<_> = mesh
        .patches()
        .iter()
        .map(|p| p.emission.as_dvec3())
        .collect();
    println!(
        "{} patches; reference floor (patch 0): B = {:.3} W/m²",
        mesh.patches().len(),
        exact[0]
    );

    for method in [Method::Shoot, Method::Prr, Method::Combined] {
        let start = Instant::now();
        let mut steps = 0;
        let solution = run(method, &mesh, &bvh, &config, &mut |_step| {
            // `step.radiosity` is the solution so far, after `step.rays` rays.
            steps += 1;
            ControlFlow::Continue(())
        })?;
        let b = solution.estimate.radiosity();
        println!(
            "{:<8} ({}): {} rays in {} steps, {:.0} ms, stop: {}; floor B = {:.3} W/m², \
             rms_rel {:.3}",
            method.name(),
            method.paper().unwrap_or("-"),
            solution.estimate.rays(),
            steps,
            start.elapsed().as_secs_f64() * 1e3,
            solution.stop,
            b[0],
            rms_rel(&area, &emission, b, exact),
        );
    }
    Ok(())
}
