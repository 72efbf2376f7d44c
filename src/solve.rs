//! `mcrad solve`: load, mesh, build the BVH, run the method, write the results.

use crate::cli::Solve;
use crate::interrupt;
use crate::state::{Identity, RunState, piece_seed};
use crate::trace::Tracer;
use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mcrad_combine::Estimate;
use mcrad_export::{PatchRow, RunStats, write_patch_csv};
use mcrad_mc_radiosity::{
    AdaptiveConfig, Error as SolveError, Kind, Refined, Solution, StopReason, refine,
};
use mcrad_meshing::{
    AdaptiveBounds, AdaptiveMesh, DEFAULT_COARSE_EDGE_FRACTION, Mesh, MeshError, Subdivision,
};
use mcrad_raycast::Bvh;
use std::fs::File;
use std::io::{BufWriter, IsTerminal};
use std::ops::ControlFlow;
use std::path::Path;
use std::time::Instant;

/// How a solve ended, when it did not fail.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// The run ended by itself (budget, convergence, `--time`).
    Done,
    /// A signal stopped the run; the outputs of its last complete solution were written.
    Interrupted,
}

pub fn run(args: &Solve) -> Result<Outcome> {
    interrupt::install();
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

fn solve(args: &Solve, threads: usize) -> Result<Outcome> {
    crate::output::check(args)?;
    args.check_mesh_options().map_err(anyhow::Error::msg)?;
    for warning in args.warnings() {
        eprintln!("warning: {warning}");
    }
    let method = args.method();
    if method.kind() == Kind::Deterministic {
        if args.resume.is_some() {
            bail!("--resume: --method {method} is deterministic, there is no run to continue");
        }
        if args.save.is_some() {
            eprintln!("warning: --save does not apply to --method {method} (deterministic)");
        }
    }
    let setup = Instant::now();
    let options = mcrad_scene_io::LoadOptions {
        allow_outside_paths: args.allow_outside_paths,
        ..Default::default()
    };
    let mut loaded = mcrad_scene_io::load_with(&args.scene, &options)?;
    for warning in &loaded.warnings {
        eprintln!("warning: {}: {warning}", args.scene.display());
    }
    if args.bake.is_none() {
        // the document and its buffers are for writing a bake back; a solve lets them go
        loaded.gltf = None;
    }
    // `mcrad bake` of an OBJ scene: bake into a glTF document made from it (its polygons fanned
    // into triangles), solved as that document reads back.
    let _converted = match (&args.bake, &loaded.gltf) {
        (Some(_), None) => {
            let dir = tempfile::tempdir().context("could not make a temporary folder")?;
            let glb = dir.path().join("scene.glb");
            std::fs::write(
                &glb,
                mcrad_bake::glb_from_scene(&loaded.scene, loaded.camera.as_ref()),
            )
            .with_context(|| format!("could not write {}", glb.display()))?;
            let camera = loaded.camera;
            loaded = mcrad_scene_io::load_with(&glb, &options)
                .with_context(|| format!("{} as glTF", args.scene.display()))?;
            loaded.camera = loaded.camera.or(camera);
            Some(dir)
        }
        _ => None,
    };
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
        // the reference solver refuses a large mesh: stop building it there
        let max_patches = match method.kind() {
            Kind::Deterministic => config.reference.max_patches,
            _ => usize::MAX,
        };
        let mesh = Mesh::build_at_most(scene, subdivision, max_patches)
            .map_err(|e| mesh_error(e, args, subdivision))
            .with_context(|| args.scene.display().to_string())?;
        (mesh, None)
    };
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())
        .with_context(|| args.scene.display().to_string())?;
    let mut tracer = match (&args.reference, &args.trace) {
        (Some(reference), Some(trace)) => {
            Some(Tracer::new(&mesh, reference, trace, args.no_subdivide)?)
        }
        _ => None,
    };
    let identity = Identity {
        scene: &args.scene,
        mesh: &mesh,
        patch: patch_numbers(args, &mesh),
        seed: args.seed,
        options: args.state_options(),
    };
    let resumed = match &args.resume {
        Some(path) => {
            let state = RunState::load(path)?;
            state.check_continues(&identity, path)?;
            Some(state)
        }
        None => None,
    };
    let save = args
        .save
        .as_ref()
        .filter(|_| method.kind() != Kind::Deterministic);
    let setup_seconds = setup.elapsed().as_secs_f64();

    // A continuation is an independent run with its own streams (piece number > 0).
    let piece = resumed.as_ref().map_or(0, |s| s.pieces);
    config.seed = piece_seed(args.seed, piece);
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
    let mut save_error = None;
    // Whether the steps are complete solutions (they carry a variance): then the last one is
    // an answer even when the run is stopped.
    let mut complete_steps = false;
    // The last step, kept for a signal that abandons the next one.
    let mut last_step: Option<Solution> = None;
    // `mcrad bake --target-error`: stop once the texels' error is that small.
    let target_error = args.bake.as_ref().and_then(|b| b.target_error);
    let mut target_reached = false;
    let result = mcrad_mc_radiosity::run_cancellable(
        method,
        &mesh,
        &bvh,
        &config,
        interrupt::cancel_flag(),
        &mut |step| {
            let seconds = start.elapsed().as_secs_f64();
            bar.set_position(step.rays.min(rays));
            bar.set_message(format!("step {}", step.index));
            complete_steps = step.variance.is_some();
            // The solution so far: this run's step, merged with the saved pieces when it continues
            // them (the trace and the state show the whole run).
            let wanted =
                (resumed.is_some() && tracer.is_some()) || (save.is_some() && complete_steps);
            let so_far = wanted
                .then(|| {
                    let e = Estimate::new(
                        step.radiosity.to_vec(),
                        step.variance.map(<[_]>::to_vec),
                        step.rays,
                    )?;
                    state_after(&identity, resumed.as_ref(), &e, step.index, 0)
                })
                .transpose();
            let so_far = match so_far {
                Ok(s) => s,
                Err(e) => {
                    save_error = Some(e);
                    return ControlFlow::Break(());
                }
            };
            if let Some(t) = tracer.as_mut() {
                let recorded = match (&so_far, resumed.is_some()) {
                    (Some(state), true) => state
                        .estimate()
                        .and_then(|e| t.record(seconds, e.rays(), e.radiosity())),
                    _ => t.record(seconds, step.rays, step.radiosity),
                };
                if let Err(e) = recorded {
                    trace_error = Some(e);
                    return ControlFlow::Break(());
                }
            }
            if let (Some(path), Some(state)) = (save, &so_far)
                && complete_steps
                && let Err(e) = state.save(path)
            {
                save_error = Some(e);
                return ControlFlow::Break(());
            }
            if let Ok(estimate) = Estimate::new(
                step.radiosity.to_vec(),
                step.variance.map(<[_]>::to_vec),
                step.rays,
            ) {
                last_step = Some(Solution {
                    estimate,
                    steps: step.index,
                    escaped_rays: 0,
                    unshot_fraction: f64::NAN,
                    stop: StopReason::Stopped,
                });
                interrupt::step_kept();
            }
            if interrupt::requested() {
                return ControlFlow::Break(());
            }
            if let (Some(target), Some(variance)) = (target_error, step.variance)
                && answer_error_p95(
                    &mesh,
                    refinement.as_ref(),
                    step.radiosity,
                    variance,
                    step.rays,
                ) <= target
            {
                target_reached = true;
                return ControlFlow::Break(());
            }
            if let Some(budget) = deadline {
                // Setup counts against the budget: the time left is measured from the start of
                // loading. At the speed of the run so far, size the rest to what fits.
                let left = budget - setup.elapsed().as_secs_f64();
                // Time up is a budget spent, not an interruption: the run finishes as at the
                // end of a ray budget (a shooting extrapolates what it could not shoot).
                let fits = rays_that_fit(left, seconds, step.rays);
                if step.next_rays > fits {
                    step.limit_rays_left(fits);
                }
            }
            ControlFlow::Continue(())
        },
    );
    // A signal that abandoned a step: the answer is the last complete one.
    let abandoned = matches!(result, Err(SolveError::Cancelled));
    let solution = match result {
        Err(SolveError::Cancelled) => last_step
            .take()
            .context("interrupted before the first step completed: nothing to write")?,
        other => other?,
    };
    if let Some(e) = trace_error {
        return Err(e);
    }
    if let Some(e) = save_error {
        return Err(e);
    }
    let interrupted = interrupt::requested();
    if target_reached && !args.quiet {
        eprintln!(
            "--target-error {}: reached after {} rays",
            target_error.unwrap_or(0.0),
            solution.estimate.rays()
        );
    }
    let seconds = start.elapsed().as_secs_f64();
    let piece_rays = solution.estimate.rays();
    // The answer: this run, merged with the saved pieces when it continues them.
    let state = state_after(
        &identity,
        resumed.as_ref(),
        &solution.estimate,
        solution.steps,
        solution.escaped_rays,
    )?;
    let estimate = match resumed {
        Some(_) => state.estimate()?,
        None => solution.estimate.clone(),
    };
    let solved_rays = estimate.rays();
    // An adaptive mesh's answer pools what the refinement learnt of each element with the
    // method's solution (a continued run's pieces are the method's alone).
    let estimate = match (&refinement, &resumed) {
        (Some(r), None) => {
            let all = vec![true; mesh.patches().len()];
            mcrad_mc_radiosity::pool(&mesh, &estimate, &r.pooled, &all)?
        }
        _ => estimate,
    };
    if let Some(path) = save {
        // A stopped run of a method whose steps are not answers (a shooting wave, a Jacobi
        // round) lacks part of its light: it is no state to continue.
        if solution.stop == StopReason::Stopped && !complete_steps {
            eprintln!(
                "warning: --save {}: the run of --method {method} stopped before its end and \
                 its solution is incomplete (only the steps of progressive methods are \
                 complete); not saved",
                path.display()
            );
        } else {
            state.save(path)?;
        }
    }
    let refinement_rays = refinement.as_ref().map_or(0, |r| r.rays);
    let run = RunStats {
        method,
        patches: mesh.patches().len(),
        rays: solved_rays + refinement_rays,
        seconds,
        rays_per_second: piece_rays as f64 / seconds.max(1e-9),
        iterations: state.steps,
        seed: args.seed,
        threads,
        // Not counted by the steps: unknown when a step was abandoned.
        escaped_rays: (!abandoned).then_some(state.escaped_rays),
        unshot_fraction: (!abandoned).then_some(solution.unshot_fraction),
        stop: solution.stop,
        setup_seconds,
        sampler: args.sampler,
        refinement: refinement.as_ref().map(|r| r.rounds.clone()),
    };
    finish(
        args,
        &loaded,
        &mesh,
        &bvh,
        &estimate,
        &identity.patch,
        &run,
        &bar,
    )?;
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
    if interrupted {
        eprintln!(
            "interrupted: {}the outputs hold the last complete step ({} steps, {} rays{})",
            if abandoned {
                "the step in progress was abandoned; "
            } else {
                ""
            },
            state.steps,
            solved_rays,
            if save.is_some() && (complete_steps || solution.stop != StopReason::Stopped) {
                "; --resume continues it"
            } else {
                ""
            }
        );
        return Ok(Outcome::Interrupted);
    }
    Ok(Outcome::Done)
}

/// The 95th percentile, by area, of the patches' relative standard error of incident
/// irradiance ([`mcrad_bake::relative_error`]): what `--target-error` holds the bake to (texels
/// take their patches' errors, and cover the surfaces in proportion to area).
/// [`irradiance_error_p95`] of the answer a step would give: on an adaptive mesh, the step
/// pooled with what the refinement learnt (as the answer is), else the step itself.
fn answer_error_p95(
    mesh: &Mesh,
    refinement: Option<&Refined>,
    radiosity: &[glam::DVec3],
    variance: &[glam::DVec3],
    rays: u64,
) -> f64 {
    let pooled = refinement.and_then(|r| {
        let step = Estimate::new(radiosity.to_vec(), Some(variance.to_vec()), rays).ok()?;
        let all = vec![true; mesh.patches().len()];
        mcrad_mc_radiosity::pool(mesh, &step, &r.pooled, &all).ok()
    });
    match pooled
        .as_ref()
        .and_then(|p| Some((p.radiosity(), p.variance()?)))
    {
        Some((b, v)) => irradiance_error_p95(mesh, b, v),
        None => irradiance_error_p95(mesh, radiosity, variance),
    }
}

fn irradiance_error_p95(mesh: &Mesh, radiosity: &[glam::DVec3], variance: &[glam::DVec3]) -> f64 {
    let patches = mesh.patches();
    let errors: Vec<f64> = patches
        .iter()
        .enumerate()
        .map(|(i, p)| mcrad_bake::relative_error(radiosity[i], p.emission.as_dvec3(), variance[i]))
        .collect();
    let areas: Vec<f64> = patches.iter().map(|p| p.area).collect();
    mcrad_bake::weighted_quantile(&errors, &areas, 0.95).unwrap_or(f64::INFINITY)
}

/// The patch numbers `--patches` writes, in mesh order: the input face with
/// `--no-subdivide`, else the patch's index.
fn patch_numbers(args: &Solve, mesh: &Mesh) -> Vec<u32> {
    mesh.patches()
        .iter()
        .enumerate()
        .map(|(i, p)| if args.no_subdivide { p.face } else { i as u32 })
        .collect()
}

/// The state after a run whose solution is `estimate` (`steps` steps, `escaped_rays` escaped
/// rays): the saved state `resumed` continued by it, or the first piece.
fn state_after(
    id: &Identity,
    resumed: Option<&RunState>,
    estimate: &Estimate,
    steps: u32,
    escaped_rays: u64,
) -> Result<RunState> {
    match resumed {
        Some(state) => state.continued(estimate, steps, escaped_rays),
        None => Ok(RunState::new(id, estimate, 1, steps, escaped_rays)),
    }
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

/// The adaptive mesh of `--mesh adaptive`: the scene cut to the diagonal / 40 (half the
/// uniform default's edge) when that takes at most 1 / [`START_SHARE`] of `--max-patches` (the
/// rest is the refinement's), else to the uniform default when that fits `--max-patches`, else one
/// element per face (every start within the elements the ray budget pays
/// [`START_RAYS_PER_ELEMENT`] for); refined with a quarter of the ray budget and of the time
/// (`--time`).
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
    let affordable = usize::try_from(rays / START_RAYS_PER_ELEMENT).unwrap_or(usize::MAX);
    let fits = |mesh: &AdaptiveMesh, share: usize| {
        mesh.len() <= (bounds.max_patches / share).min(affordable)
    };
    let diagonal = scene.bounds().diagonal() as f32;
    let mut mesh = AdaptiveMesh::new(
        scene,
        Subdivision::MaxEdge(diagonal * DEFAULT_COARSE_EDGE_FRACTION),
        bounds,
    )?;
    if !fits(&mesh, START_SHARE) {
        mesh = AdaptiveMesh::new(scene, Subdivision::default_for(scene), bounds)?;
    }
    if !fits(&mesh, 1) {
        mesh = AdaptiveMesh::new(scene, Subdivision::None, bounds)?;
    }
    let config = AdaptiveConfig {
        rays: if rays == u64::MAX {
            u64::MAX
        } else {
            (rays / 4).max(1)
        },
        seconds: args.time.map(|t| t / 4.0),
        seed: args.seed,
        ..Default::default()
    };
    let refined = refine(&mut mesh, &config)?;
    let unrefinable = refined.unrefinable();
    if unrefinable > 0 {
        eprintln!(
            "warning: {unrefinable} elements could not be split into valid elements (slivers, \
             or faces too small for f32 coordinates at the scene's size); kept as they are"
        );
    }
    Ok((mesh.into_mesh(), refined))
}

/// The finer start (the diagonal / 40) is taken when it holds at most `1 / START_SHARE` of
/// `--max-patches`. Half: at 1e8 rays, `--max-patches 8000` on the Cornell box measured 0.82%
/// image error starting at / 40 (3,518 elements) against 1.30% starting at the uniform default
/// (943), whose large elements the refinement's marks leave as they are where the light bends
/// gently; on the table room the same budget gave 0.60% against 1.02% (render --spp 256).
const START_SHARE: usize = 2;

/// The fewest rays of the budget per element of an adaptive run's starting mesh: a finer start
/// would leave the refinement's rounds and the method too few rays per element (a budget of
/// 3e4 rays could not pay for one round on the Cornell box's 17,000 starting elements).
const START_RAYS_PER_ELEMENT: u64 = 16;

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
#[allow(clippy::too_many_arguments)]
fn finish(
    args: &Solve,
    loaded: &mcrad_scene_io::Loaded,
    mesh: &Mesh,
    bvh: &Bvh,
    estimate: &Estimate,
    patch: &[u32],
    run: &RunStats,
    bar: &ProgressBar,
) -> Result<()> {
    if let Some(path) = &args.patches {
        let rows = mesh.patches().iter().enumerate().map(|(i, p)| PatchRow {
            patch: patch[i],
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
    crate::output::write(args, mesh, bvh, estimate.radiosity(), loaded.camera, bar)?;
    let baked = match &args.bake {
        Some(target) => Some(crate::output::bake(
            args, target, loaded, mesh, bvh, estimate, bar,
        )?),
        None => None,
    };
    if let Some(path) = &args.stats {
        match &baked {
            // the run's statistics and, under "bake", what the bake wrote
            Some(summary) => {
                let mut json = serde_json::to_value(run).context("the run statistics")?;
                json["bake"] = summary.clone();
                let mut out = create(path)?;
                serde_json::to_writer_pretty(&mut out, &json).context("the run statistics")?;
                std::io::Write::write_all(&mut out, b"\n")
                    .and_then(|()| std::io::Write::flush(&mut out))?;
            }
            None => run.write_json(create(path)?)?,
        }
    }
    bar.finish_and_clear();
    if !args.quiet {
        println!(
            "{}: {} patches, {} rays, {:.3} s, {:.2} Mrays/s ({}: {} steps, {}% unshot, {} escaped rays, {} sampler, {} threads)",
            args.scene.display(),
            run.patches,
            run.rays,
            run.seconds,
            run.rays_per_second / 1e6,
            run.method,
            run.iterations,
            run.unshot_fraction
                .map_or_else(|| "?".to_string(), |u| format!("{:.2}", 100.0 * u)),
            run.escaped_rays
                .map_or_else(|| "?".to_string(), |n| n.to_string()),
            run.sampler,
            run.threads
        );
        if let Some(summary) = &baked {
            println!("{}", crate::output::bake_line(summary));
        }
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
