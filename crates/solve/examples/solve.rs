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
    #[arg(long, value_parser = |s: &str| s.parse::<f64>().map(|x| x as u64))]
    rays: Option<u64>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long)]
    patches: std::path::PathBuf,
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
