//! `mcrad solve`: load, mesh, build the BVH, run the method, write the results.

use crate::cli::Solve;
use crate::trace::Tracer;
use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mcrad_export::{PatchRow, RunStats, write_patch_csv};
use mcrad_mc_radiosity::schedule::{self, Kind, Solution};
use mcrad_meshing::{Mesh, MeshError, Subdivision};
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
    for warning in args.warnings() {
        eprintln!("warning: {warning}");
    }
    let setup = Instant::now();
    let options = mcrad_scene_io::LoadOptions {
        allow_outside_paths: args.allow_outside_paths,
        ..Default::default()
    };
    let loaded = mcrad_scene_io::load_with(&args.scene, &options)?;
    for warning in &loaded.warnings {
        eprintln!("warning: {}: {warning}", args.scene.display());
    }
    let scene = &loaded.scene;
    let subdivision = if args.no_subdivide {
        Subdivision::None
    } else {
        args.max_edge
            .map_or_else(|| Subdivision::default_for(scene), Subdivision::MaxEdge)
    };
    let method = args.method();
    // the reference solver refuses a large mesh: stop building it there
    let max_patches = match method.kind() {
        Kind::Deterministic => args.schedule_config().reference.max_patches,
        _ => usize::MAX,
    };
    let mesh = Mesh::build_at_most(scene, subdivision, max_patches)
        .map_err(|e| mesh_error(e, args, subdivision))
        .with_context(|| args.scene.display().to_string())?;
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())
        .with_context(|| args.scene.display().to_string())?;
    let mut tracer = match (&args.reference, &args.trace) {
        (Some(reference), Some(trace)) => {
            Some(Tracer::new(&mesh, reference, trace, args.no_subdivide)?)
        }
        _ => None,
    };
    let setup_seconds = setup.elapsed().as_secs_f64();

    let config = args.schedule_config();
    let rays = config.rays;
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
    let run = RunStats {
        method,
        patches: mesh.patches().len(),
        rays: estimate.rays(),
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
    finish(args, &loaded, &mesh, &bvh, &solution, &run, &bar)
}

/// A meshing error with advice that names only the flags the user gave: `--max-edge` is
/// suggested as a change of the user's own value, or as an alternative to the default
/// subdivision (whose edge length is said).
fn mesh_error(e: MeshError, args: &Solve, subdivision: Subdivision) -> anyhow::Error {
    let advice = match (args.max_edge, subdivision) {
        (Some(_), _) => "choose a larger --max-edge".to_string(),
        (None, Subdivision::MaxEdge(l)) => format!(
            "the default subdivision cuts edges longer than the bounding-box diagonal / {} = {l} \
             scene units; pass a larger --max-edge, or --no-subdivide",
            1.0 / mcrad_meshing::DEFAULT_MAX_EDGE_FRACTION
        ),
        (None, _) => "use a scene with fewer faces".to_string(),
    };
    match e {
        MeshError::PatchLimit { limit } => anyhow::anyhow!(
            "--method reference accepts at most {limit} patches and this mesh has more (its \
             form factors take work and memory that grow as the square of the patch count); \
             {advice}"
        ),
        e => anyhow::anyhow!("{e}; {advice}"),
    }
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
        });
        write_patch_csv(create(path)?, rows)?;
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
