//! `mcrad solve`: load, mesh, build the BVH, run the method, write the results.

use crate::cli::Solve;
use crate::trace::Tracer;
use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mcrad_export::{PatchRow, RunStats, write_patch_csv};
use mcrad_mc_radiosity::adaptive::{AdaptiveConfig, Refined, refine};
use mcrad_mc_radiosity::schedule::{self, Kind, Solution};
use mcrad_meshing::{
    AdaptiveBounds, AdaptiveMesh, DEFAULT_COARSE_EDGE_FRACTION, Mesh, Subdivision,
};
use mcrad_raycast::Bvh;
use std::fs::File;
use std::io::{BufWriter, IsTerminal};
use std::ops::ControlFlow;
use std::path::Path;
use std::time::Instant;

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
    args.check_mesh_options().map_err(anyhow::Error::msg)?;
    for warning in args.warnings() {
        eprintln!("warning: {warning}");
    }
    let setup = Instant::now();
    let loaded = mcrad_scene_io::load(&args.scene)?;
    for warning in &loaded.warnings {
        eprintln!("warning: {}: {warning}", args.scene.display());
    }
    let scene = &loaded.scene;
    let mut config = args.schedule_config();
    let (mesh, refinement) = if args.adaptive() {
        let (mesh, refined) = adaptive_mesh(args, scene, config.rays)?;
        if config.rays != u64::MAX {
            // The method gets what the refinement left, and at least half the budget.
            config.rays = config
                .rays
                .saturating_sub(refined.rays)
                .max(config.rays / 2)
                .max(1);
        }
        (mesh, Some(refined))
    } else {
        let subdivision = if args.no_subdivide {
            Subdivision::None
        } else {
            args.max_edge
                .map_or_else(|| Subdivision::default_for(scene), Subdivision::MaxEdge)
        };
        (Mesh::build(scene, subdivision)?, None)
    };
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())?;
    let mut tracer = match (&args.reference, &args.trace) {
        (Some(reference), Some(trace)) => {
            Some(Tracer::new(&mesh, reference, trace, args.no_subdivide)?)
        }
        _ => None,
    };
    let setup_seconds = setup.elapsed().as_secs_f64();

    let rays = config.rays;
    let method = args.method();
    // The reference solver runs to its accuracy target: no budget, no deadline.
    let deterministic = method.kind() == Kind::Deterministic;
    if deterministic && (args.rays.is_some() || args.time.is_some()) {
        eprintln!(
            "warning: --rays and --time do not apply to --method {method}; it runs to its accuracy target"
        );
    }
    let deadline = if deterministic { None } else { args.time };
    let bar = progress_bar(args.quiet, if deterministic { u64::MAX } else { rays });
    let start = Instant::now();
    let mut trace_error = None;
    let solution: Solution = schedule::run(method, &mesh, &bvh, &config, &mut |step| {
        let seconds = start.elapsed().as_secs_f64();
        bar.set_position(step.rays.min(rays));
        bar.set_message(format!("step {}", step.index));
        if let Some(t) = tracer.as_mut()
            && let Err(e) = t.record(seconds, step.rays, step.radiosity)
        {
            trace_error = Some(e);
            return ControlFlow::Break(());
        }
        if let Some(budget) = deadline {
            // Setup counts against the budget: the time left is measured from the start of
            // loading. At the speed of the run so far, size the rest to what fits.
            let left = budget - setup.elapsed().as_secs_f64();
            let fits = rays_that_fit(left, seconds, step.rays);
            if fits == 0 {
                return ControlFlow::Break(());
            }
            if step.next_rays > fits {
                step.limit_rays_left(fits);
            }
        }
        ControlFlow::Continue(())
    })?;
    if let Some(e) = trace_error {
        return Err(e);
    }
    let seconds = start.elapsed().as_secs_f64();
    let estimate = &solution.estimate;
    let refinement_rays = refinement.as_ref().map_or(0, |r| r.rays);
    let run = RunStats {
        method,
        patches: mesh.patches().len(),
        rays: estimate.rays() + refinement_rays,
        seconds,
        rays_per_second: estimate.rays() as f64 / seconds.max(1e-9),
        iterations: solution.steps,
        seed: args.seed,
        threads,
        escaped_rays: solution.escaped_rays,
        unshot_fraction: solution.unshot_fraction,
        stop: solution.stop,
        setup_seconds,
    };
    finish(args, &loaded, &mesh, &bvh, &solution, &run, &bar)?;
    if let Some(r) = refinement
        && !args.quiet
    {
        println!(
            "adaptive mesh: {} elements after {} refinement rounds ({} rays, counted above)",
            run.patches,
            r.rounds.iter().filter(|r| r.split > 0).count(),
            r.rays
        );
    }
    Ok(())
}

/// The adaptive mesh of `--mesh adaptive`: the scene cut as the uniform default (the diagonal
/// / 20), refined with a quarter of the ray budget (a million rays with `--time` alone).
fn adaptive_mesh(
    args: &Solve,
    scene: &mcrad_scene_io::Scene,
    rays: u64,
) -> Result<(Mesh, Refined)> {
    let mut bounds = AdaptiveBounds::default_for(scene);
    bounds.max_patches = args.max_patches;
    if let Some(min_edge) = args.min_edge {
        bounds.min_edge = min_edge;
    }
    let coarse =
        Subdivision::MaxEdge(scene.bounds().diagonal() as f32 * DEFAULT_COARSE_EDGE_FRACTION);
    let mut mesh = AdaptiveMesh::new(scene, coarse, bounds)?;
    if mesh.len() > bounds.max_patches {
        mesh = AdaptiveMesh::new(scene, Subdivision::None, bounds)?;
    }
    let config = AdaptiveConfig {
        rays: if rays == u64::MAX {
            1_000_000
        } else {
            (rays / 4).max(1)
        },
        seed: args.seed,
        ..Default::default()
    };
    let refined = refine(&mut mesh, &config)?;
    let unrefinable = refined.unrefinable();
    if unrefinable > 0 {
        eprintln!(
            "warning: {unrefinable} elements could not be split into valid elements (slivers, \
             tiny faces or coordinates far from the origin); kept as they are"
        );
    }
    Ok((mesh.into_mesh(), refined))
}

/// The share of the time left a `--time` run plans to fill: the rest absorbs the per-step
/// work that does not scale with rays and the writing of the outputs.
const TIME_FILL: f64 = 0.97;

/// The rays that fit in `left` seconds at the speed of a run that cast `rays` rays in
/// `seconds` seconds, with [`TIME_FILL`]'s margin (0 when no time is left).
fn rays_that_fit(left: f64, seconds: f64, rays: u64) -> u64 {
    if left <= 0.0 {
        return 0;
    }
    if rays == 0 {
        return u64::MAX;
    }
    let per_ray = seconds / rays as f64;
    if per_ray <= 0.0 {
        return u64::MAX;
    }
    (TIME_FILL * left / per_ray).min(u64::MAX as f64) as u64
}

/// Writes the outputs of a finished solve and prints the summary.
fn finish(
    args: &Solve,
    loaded: &mcrad_scene_io::Loaded,
    mesh: &Mesh,
    bvh: &Bvh,
    solution: &Solution,
    run: &RunStats,
    bar: &ProgressBar,
) -> Result<()> {
    let estimate = &solution.estimate;

    if let Some(path) = &args.patches {
        let rows = mesh.patches().iter().enumerate().map(|(i, p)| PatchRow {
            patch: if args.no_subdivide { p.face } else { i as u32 },
            area: p.area,
            radiosity: estimate.radiosity()[i],
            variance: estimate.variance().map(|v| v[i]),
            face: Some(p.face),
        });
        if args.per_face {
            write_patch_csv(create(path)?, per_face(rows))?;
        } else {
            write_patch_csv(create(path)?, rows)?;
        }
    }
    if let Some(path) = &args.stats {
        run.write_json(create(path)?)?;
    }
    crate::output::write(args, mesh, bvh, estimate.radiosity(), loaded.camera, bar)?;
    bar.finish_and_clear();
    if !args.quiet {
        println!(
            "{}: {} patches, {} rays, {:.3} s, {:.2} Mrays/s ({}: {} steps, {:.2}% unshot, {} escaped rays, {} threads)",
            args.scene.display(),
            run.patches,
            run.rays,
            run.seconds,
            run.rays_per_second / 1e6,
            run.method,
            run.iterations,
            100.0 * run.unshot_fraction,
            run.escaped_rays,
            run.threads
        );
    }
    Ok(())
}

/// One row per input face, in face order: the area-weighted means `sum A_i B_i / sum A_i` of
/// its patches' rows, with the variance of that mean `sum (A_i / A)² V_i` (patches taken as
/// independent) and the face's area; `patch` is the face number, `face` is `None` (today's
/// header).
fn per_face(rows: impl Iterator<Item = PatchRow>) -> Vec<PatchRow> {
    use std::collections::BTreeMap;
    // face -> (area, sum A B, sum A² V, every patch had a variance)
    let mut faces: BTreeMap<u32, (f64, glam::DVec3, glam::DVec3, bool)> = BTreeMap::new();
    for r in rows {
        let face = r.face.unwrap_or(r.patch);
        let e = faces
            .entry(face)
            .or_insert((0.0, glam::DVec3::ZERO, glam::DVec3::ZERO, true));
        e.0 += r.area;
        e.1 += r.area * r.radiosity;
        match r.variance {
            Some(v) => e.2 += r.area * r.area * v,
            None => e.3 = false,
        }
    }
    faces
        .into_iter()
        .map(|(face, (area, sum, var, has_var))| PatchRow {
            patch: face,
            area,
            radiosity: sum / area,
            variance: has_var.then(|| var / (area * area)),
            face: None,
        })
        .collect()
}

pub fn create(path: &Path) -> Result<BufWriter<File>> {
    let file =
        File::create(path).with_context(|| format!("could not create {}", path.display()))?;
    Ok(BufWriter::new(file))
}

/// A bar over the ray budget on an interactive terminal; hidden otherwise or with `--quiet`.
fn progress_bar(quiet: bool, rays: u64) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let length = (rays != u64::MAX).then_some(rays);
    let bar = ProgressBar::with_draw_target(length, ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {human_pos}/{human_len} rays, {msg}",
        )
        .expect("a valid template")
        .progress_chars("=> "),
    );
    bar
}
