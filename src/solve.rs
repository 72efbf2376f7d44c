//! `mcrad solve`: load, mesh, build the BVH, run the method, write the results.

use crate::cli::{Method, Solve};
use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mcrad_export::{PatchRow, RunStats, write_patch_csv};
use mcrad_mc_radiosity::{ShootConfig, StopReason, shoot};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use std::fs::File;
use std::io::{BufWriter, IsTerminal};
use std::ops::ControlFlow;
use std::path::Path;
use std::time::Instant;

/// Default subdivision: no patch edge longer than this fraction of the bounding-box diagonal.
const DEFAULT_MAX_EDGE_FRACTION: f32 = 1.0 / 20.0;

pub fn run(args: &Solve) -> Result<()> {
    let threads = args
        .threads
        .map(usize::from)
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("could not start the worker threads")?;
    pool.install(|| solve(args, threads))
}

fn solve(args: &Solve, threads: usize) -> Result<()> {
    crate::output::check(args)?;
    let setup = Instant::now();
    let loaded = mcrad_scene_io::load(&args.scene)?;
    for warning in &loaded.warnings {
        eprintln!("warning: {}: {warning}", args.scene.display());
    }
    let scene = &loaded.scene;
    let subdivision = if args.no_subdivide {
        Subdivision::None
    } else {
        Subdivision::MaxEdge(args.max_edge.unwrap_or_else(|| {
            let (lo, hi) = scene
                .positions()
                .iter()
                .fold((glam::Vec3::MAX, glam::Vec3::MIN), |(lo, hi), p| {
                    (lo.min(*p), hi.max(*p))
                });
            lo.distance(hi) * DEFAULT_MAX_EDGE_FRACTION
        }))
    };
    let mesh = Mesh::build(scene, subdivision)?;
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())?;
    let setup_seconds = setup.elapsed().as_secs_f64();

    let bar = progress_bar(args.quiet, args.rays);
    let start = Instant::now();
    let (estimate, stats) = match args.method {
        Method::Shoot => {
            let config = ShootConfig {
                rays: args.rays,
                unshot_threshold: args.unshot_threshold,
                seed: args.seed,
            };
            let shooting = shoot(&mesh, &bvh, &config, &mut |p| {
                bar.set_position(p.rays);
                bar.set_message(format!(
                    "wave {}, {:.2}% unshot",
                    p.waves,
                    100.0 * p.unshot_fraction
                ));
                ControlFlow::Continue(())
            })?;
            (shooting.estimate, shooting.stats)
        }
    };
    let seconds = start.elapsed().as_secs_f64();

    if let Some(path) = &args.patches {
        let rows = mesh.patches().iter().enumerate().map(|(i, p)| PatchRow {
            patch: if args.no_subdivide { p.face } else { i as u32 },
            area: p.area,
            radiosity: estimate.radiosity()[i],
            variance: estimate.variance().map(|v| v[i]),
        });
        write_patch_csv(create(path)?, rows)?;
    }
    let emitted = stats.emitted.x + stats.emitted.y + stats.emitted.z;
    let run = RunStats {
        method: args.method.name().into(),
        patches: mesh.patches().len(),
        rays: stats.rays,
        seconds,
        rays_per_second: stats.rays as f64 / seconds.max(1e-9),
        iterations: stats.waves,
        seed: args.seed,
        threads,
        escaped_rays: stats.escaped_rays,
        unshot_fraction: (stats.unshot.x + stats.unshot.y + stats.unshot.z) / emitted,
        stop: match stats.stop {
            StopReason::Converged => "converged",
            StopReason::BudgetSpent => "budget",
            StopReason::Stopped => "stopped",
        }
        .into(),
        setup_seconds,
    };
    if let Some(path) = &args.stats {
        run.write_json(create(path)?)?;
    }
    crate::output::write(args, &mesh, &bvh, estimate.radiosity(), loaded.camera, &bar)?;
    bar.finish_and_clear();
    if !args.quiet {
        println!(
            "{}: {} patches, {} rays, {:.3} s, {:.2} Mrays/s ({}: {} waves, {:.2}% unshot, {} escaped rays, {} threads)",
            args.scene.display(),
            run.patches,
            run.rays,
            run.seconds,
            run.rays_per_second / 1e6,
            run.method,
            run.iterations,
            100.0 * run.unshot_fraction,
            run.escaped_rays,
            threads
        );
    }
    Ok(())
}

fn create(path: &Path) -> Result<BufWriter<File>> {
    let file =
        File::create(path).with_context(|| format!("could not create {}", path.display()))?;
    Ok(BufWriter::new(file))
}

/// A bar over the ray budget on an interactive terminal; hidden otherwise or with `--quiet`.
fn progress_bar(quiet: bool, rays: u64) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(Some(rays), ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {human_pos}/{human_len} rays, {msg}",
        )
        .expect("a valid template")
        .progress_chars("=> "),
    );
    bar
}
