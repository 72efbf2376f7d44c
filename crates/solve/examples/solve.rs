//! The library's default solve: the patch CSV that `mcrad solve SCENE --rays N --seed S
//! --patches OUT.csv` writes, byte for byte.
//!
//! `cargo run --release -p mcrad-solve --example solve -- scenes/cornell-box.obj --rays 1e6 --seed 0 --patches out.csv`

use clap::Parser;
use mcrad_export::{patch_rows, write_patch_csv};
use std::ops::ControlFlow;

#[derive(Parser)]
struct Args {
    scene: std::path::PathBuf,
    #[arg(long, value_parser = rays)]
    rays: Option<u64>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long)]
    patches: std::path::PathBuf,
}

/// A ray count as `2000000` or `2e6`.
fn rays(s: &str) -> Result<u64, String> {
    match s.parse::<f64>() {
        Ok(x) if x >= 1.0 && x.fract() == 0.0 && x < 1.8e19 => Ok(x as u64),
        _ => Err(format!("'{s}' is not a whole number of rays")),
    }
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let scene = mcrad_scene_io::load(&args.scene)?.scene;
    let mut problem = mcrad_solve::Problem::new(&scene);
    problem.settings.seed = args.seed;
    problem.budget.rays = args.rays;
    let answer = mcrad_solve::solve(&problem, &mut |_| ControlFlow::Continue(()))?;
    let (b, var) = (answer.estimate.radiosity(), answer.estimate.variance());
    let rows = patch_rows(&answer.mesh, &answer.patch, b, var);
    write_patch_csv(std::fs::File::create(&args.patches)?, rows)?;
    Ok(())
}
