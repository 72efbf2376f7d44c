//! `mcrad solve`: flags and files around one call of the library's solve
//! ([`mcrad_solve::solve`]), with a progress bar, the trace, the saved state and signals.

use crate::cli::Solve;
use crate::interrupt;
use crate::output::{Direct, Scenery};
use crate::state;
use crate::trace::Tracer;
use anyhow::{Context, Result, anyhow, bail};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mcrad_export::{patch_rows, per_face, write_patch_csv};
use mcrad_meshing::MeshError;
use mcrad_solve::{Answer, Error as SolveError, Input, MeshPlan, Problem, Progress, Settings};
use std::fs::File;
use std::io::{BufWriter, IsTerminal};
use std::ops::ControlFlow;
use std::path::Path;
use std::sync::Mutex;
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
    // Setup counts against a time budget: its clock starts before loading.
    let clock = Instant::now();
    crate::output::check(args)?;
    args.check_mesh_options().map_err(anyhow::Error::msg)?;
    for warning in args.warnings() {
        eprintln!("warning: {warning}");
    }
    let resumed = match &args.resume {
        Some(path) => Some(state::load(path)?),
        None => None,
    };
    let settings = match &resumed {
        Some(saved) => args.settings_over(saved.settings(), false),
        None => args.settings(),
    };
    let method = settings.method;
    if args.reference.is_some() && matches!(settings.mesh, MeshPlan::Adaptive { .. }) {
        bail!(
            "--reference compares patch by patch with a fixed mesh, and the saved run's mesh is \
             adaptive"
        );
    }
    if settings.deterministic() {
        if args.resume.is_some() {
            bail!("--resume: --method {method} is deterministic, there is no run to continue");
        }
        if args.save.is_some() {
            eprintln!("warning: --save does not apply to --method {method} (deterministic)");
        }
        if args.rays.is_some() || args.time.is_some() {
            eprintln!(
                "warning: --rays and --time do not apply to --method {method}; it runs to its accuracy target"
            );
        }
    }
    let options = mcrad_scene_io::LoadOptions {
        allow_outside_paths: args.allow_outside_paths,
        lights: args.sun.iter().cloned().collect(),
        sky: args.sky()?,
        light_efficacy: args.light_efficacy,
        two_sided: args.two_sided,
        ..Default::default()
    };
    if args.two_sided
        && !args
            .scene
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("obj"))
    {
        bail!(
            "--two-sided applies to OBJ scenes: in glTF each material's doubleSided says which \
             faces are two-sided"
        );
    }
    let mut loaded = mcrad_scene_io::load_with(&args.scene, &options)?;
    for warning in &loaded.warnings {
        eprintln!("warning: {}: {warning}", args.scene.display());
    }
    if args.bake.is_none() {
        // the document and its buffers are for writing a bake back; a solve lets them go
        loaded.gltf = None;
    }
    // `mcrad bake` of an OBJ scene: bake into a glTF document made from it (its polygons fanned
    // into triangles), solved as that document reads back (made and read in memory).
    if args.bake.is_some() && loaded.gltf.is_none() {
        loaded =
            mcrad_bake::gltf_scene(&loaded.scene, loaded.camera.as_ref(), &args.scene, &options)
                .with_context(|| format!("{} as glTF", args.scene.display()))?;
    }

    let load_seconds = clock.elapsed().as_secs_f64();
    let save = args.save.as_ref().filter(|_| !settings.deterministic());
    let scenery = Scenery {
        sky: loaded.scene.sky().cloned(),
        lights: loaded.scene.lights().to_vec(),
        camera: loaded.camera,
        gather: std::sync::OnceLock::new(),
    };
    let image_seconds = |mesh: &mcrad_meshing::Mesh, bvh: &mcrad_raycast::Bvh| {
        let left = args.time.map(|t| t - clock.elapsed().as_secs_f64());
        crate::output::image_seconds(args, &scenery, mesh, bvh, left)
    };
    // A solve hands the scene over, to be dropped once meshed; a bake keeps it to write into.
    let (handed, kept) = match args.bake {
        None => (Mutex::new(Some(loaded.scene)), None),
        Some(_) => (Mutex::new(None), Some(loaded)),
    };
    let problem = Problem {
        input: match &kept {
            Some(loaded) => Input::Scene(&loaded.scene),
            None => Input::SceneOnce(&handed),
        },
        settings,
        budget: args.budget(clock),
        threads: Some(threads),
        resume: resumed.as_ref(),
        cancel: Some(interrupt::cancel_flag()),
        // the closure report is part of the statistics
        closure: args.stats.is_some(),
        // the render, after the solve, is on the same clock
        after: Some(mcrad_solve::AfterSolve(&image_seconds)),
        clustering: args.clusters.into(),
        // the state is only saved, never read here
        keep_state: args.save.is_some(),
    };
    let bar = progress_bar(args.quiet);
    let mut tracer: Option<Tracer> = None;
    let mut failure: Option<anyhow::Error> = None;
    let by_face = settings.mesh == MeshPlan::PerFace;
    let mut observer = |progress: &Progress| match observe(
        args,
        by_face,
        save.map(|p| p.as_path()),
        &bar,
        &mut tracer,
        progress,
    ) {
        Ok(flow) => flow,
        Err(e) => {
            failure = Some(e);
            ControlFlow::Break(())
        }
    };
    let answer = mcrad_solve::solve(&problem, &mut observer);
    if let Some(e) = failure {
        return Err(e);
    }
    let mut answer = answer.map_err(|e| solve_error(e, args, &problem.settings))?;
    for warning in &answer.warnings {
        eprintln!("warning: {warning}");
    }
    let interrupted = interrupt::requested();
    if answer.target_reached && !args.quiet {
        eprintln!(
            "--target-error {}: reached after {} rays",
            problem.budget.target_error.unwrap_or(0.0),
            answer.stats.rays
        );
    }
    if let Some(path) = save {
        match &answer.state {
            Some(state) => state::save(state, path)?,
            // A stopped run of a method whose steps are not answers (a shooting wave, a
            // Jacobi round) lacks part of its light: it is no state to continue.
            None => eprintln!(
                "warning: --save {}: the run of --method {method} stopped before its end and \
                 its solution is incomplete (only the steps of progressive methods are \
                 complete); not saved",
                path.display()
            ),
        }
    }
    finish(
        args,
        &scenery,
        kept.as_ref(),
        &mut answer,
        &bar,
        load_seconds,
    )?;
    if let Some(rounds) = &answer.stats.refinement
        && !args.quiet
    {
        // clusters as elements of transport: how many the method ran on
        let transport = match answer.stats.clusters.and_then(|c| c.transport_elements) {
            Some(n) => format!("; the method ran on {n} elements, small faces in clusters"),
            None => String::new(),
        };
        println!(
            "adaptive mesh: {} elements after {} refinement rounds ({} rays, counted above){transport}",
            answer.stats.patches,
            rounds.iter().filter(|r| r.split > 0).count(),
            rounds.iter().map(|r| r.rays).sum::<u64>()
        );
    }
    if interrupted {
        eprintln!(
            "interrupted: {}the outputs hold the last complete step ({} steps, {} rays{})",
            if answer.cancelled {
                "the step in progress was abandoned; "
            } else {
                ""
            },
            answer.stats.iterations,
            answer.stats.rays,
            if save.is_some() && answer.state.is_some() {
                "; --resume continues it"
            } else {
                ""
            }
        );
        return Ok(Outcome::Interrupted);
    }
    Ok(Outcome::Done)
}

/// After each step: the progress bar, the trace, the saved state, and a signal's stop.
/// (`by_face`: the trace matches the reference by input face, one patch per face.)
fn observe(
    args: &Solve,
    by_face: bool,
    save: Option<&Path>,
    bar: &ProgressBar,
    tracer: &mut Option<Tracer>,
    progress: &Progress,
) -> Result<ControlFlow<()>> {
    if progress.step == 1 && progress.budget_rays != u64::MAX {
        bar.set_length(progress.budget_rays);
    }
    bar.set_position(progress.rays.min(progress.budget_rays));
    bar.set_message(format!("step {}", progress.step));
    if let (Some(reference), Some(trace)) = (&args.reference, &args.trace) {
        if tracer.is_none() {
            *tracer = Some(Tracer::new(progress.mesh(), reference, trace, by_face)?);
        }
        // the answer so far: this piece merged with the saved ones when it continues them
        let answer = progress.answer()?;
        if let Some(t) = tracer.as_mut() {
            t.record(progress.seconds, answer.rays(), answer.radiosity())?;
        }
    }
    if let Some(path) = save
        && let Some(state) = progress.state()?
    {
        state::save(&state, path)?;
    }
    interrupt::step_kept();
    Ok(if interrupt::requested() {
        ControlFlow::Break(())
    } else {
        ControlFlow::Continue(())
    })
}

/// A library error as the command line says it: meshing errors with advice that names only
/// the flags the user gave.
fn solve_error(e: SolveError, args: &Solve, settings: &Settings) -> anyhow::Error {
    let scene = args.scene.display();
    match e {
        SolveError::CancelledEarly => {
            anyhow!("interrupted before the first step completed: nothing to write")
        }
        // the adaptive mesh's start (the old message had no advice either)
        SolveError::Mesh { source, .. } if matches!(settings.mesh, MeshPlan::Adaptive { .. }) => {
            anyhow!("{scene}: {source}")
        }
        SolveError::Mesh { source, max_edge } => {
            let advice = match (args.max_edge, max_edge) {
                (Some(_), _) => "choose a larger --max-edge".to_string(),
                (None, Some(l)) => format!(
                    "the default subdivision cuts edges longer than the bounding-box diagonal / \
                     {} = {l} scene units; pass a larger --max-edge, or --no-subdivide",
                    1.0 / mcrad_meshing::DEFAULT_MAX_EDGE_FRACTION
                ),
                (None, None) => "use a scene with fewer faces".to_string(),
            };
            match source {
                MeshError::PatchLimit { limit } => anyhow!(
                    "{scene}: --method reference accepts at most {limit} patches and this mesh \
                     has more (its form factors take work and memory that grow as the square of \
                     the patch count); {advice}"
                ),
                e => anyhow!("{scene}: {e}; {advice}"),
            }
        }
        SolveError::Memory { .. } => anyhow!(
            "{scene}: {e} (--max-memory {}{})",
            problem_limit(args),
            if args.max_memory.is_none() {
                ", the default: the machine's RAM less a tenth"
            } else {
                ""
            }
        ),
        SolveError::Disagree { .. }
        | SolveError::StateMesh { .. }
        | SolveError::StateReplay(_)
        | SolveError::StateVersion { .. } => {
            let state = args.resume.as_deref().unwrap_or(Path::new("the state"));
            anyhow!("--resume {}: {e}", state.display())
        }
        e => anyhow::Error::new(e).context(scene.to_string()),
    }
}

/// The memory limit of `args` as given (or the default's bytes).
fn problem_limit(args: &Solve) -> String {
    match args.budget(Instant::now()).memory {
        Some(bytes) => bytes.to_string(),
        None => "none".to_string(),
    }
}

/// Writes the outputs of a finished solve and prints the summary (`kept`: the loaded scene, for
/// a bake).
fn finish(
    args: &Solve,
    scenery: &Scenery,
    kept: Option<&mcrad_scene_io::Loaded>,
    answer: &mut Answer,
    bar: &ProgressBar,
    load_seconds: f64,
) -> Result<()> {
    if let Some(path) = &args.patches {
        let rows = patch_rows(
            &answer.mesh,
            &answer.patch,
            answer.estimate.radiosity(),
            answer.estimate.variance(),
        );
        if args.per_face {
            write_patch_csv(
                create(path)?,
                per_face(rows, answer.face_correlation.as_deref()),
            )?;
        } else {
            write_patch_csv(create(path)?, rows)?;
        }
    }
    // With per-pixel direct light, the solution's own direct part is taken out of it. What
    // the outputs below no longer read goes (at 10^7 patches, hundreds of MiB each); a bake
    // reads it all.
    let direct = if args.bake.is_some() {
        crate::output::drawn_direct(args, answer)
    } else {
        answer.face_correlation = None;
        crate::output::take_drawn_direct(args, answer)
    };
    let render = Instant::now();
    let gather_rays = crate::output::gather_rays(args, scenery, &answer.mesh, answer.stats.rays);
    let lighting = |direct| crate::output::Lighting {
        sky: scenery.sky.clone(),
        lights: &scenery.lights,
        direct,
        gather_rays,
    };
    // A render alone (no GLB, error image or bake) reads the radiosity less the direct light
    // it draws per sample, and nothing else: made in place of the answer's, whose variances go
    // (the answer's estimate is not read past here).
    // (A final gather reads the whole solution.)
    let alone = args.gltf.is_none()
        && args.error_image.is_none()
        && args.bake.is_none()
        && gather_rays == 0;
    match direct {
        Some(h) if alone => {
            let (mut drawn, variance, _) = std::mem::take(&mut answer.estimate).into_parts();
            drop(variance);
            crate::output::take_out_direct(&answer.mesh, &mut drawn, &h);
            drop(h);
            crate::output::write(
                args,
                &answer.mesh,
                &answer.bvh,
                &drawn,
                lighting(Direct::PerSampleTakenOut),
                scenery.camera,
                bar,
            )?;
        }
        direct => {
            let (mesh, estimate) = (&answer.mesh, &answer.estimate);
            let per_sample = match direct.as_deref() {
                Some(h) => Direct::PerSample(h),
                None => Direct::InSolution,
            };
            let gathered = crate::output::write(
                args,
                mesh,
                &answer.bvh,
                estimate.radiosity(),
                lighting(per_sample),
                scenery.camera,
                bar,
            )?;
            crate::output::write_error_image(
                args,
                mesh,
                &answer.bvh,
                estimate.radiosity(),
                estimate.variance(),
                direct.as_deref(),
                scenery.camera,
                gathered.as_ref(),
            )?;
        }
    }
    let render_seconds = render.elapsed().as_secs_f64();
    let run = &answer.stats;
    let baked = match (&args.bake, kept) {
        (Some(target), Some(loaded)) => {
            Some(crate::output::bake(args, target, loaded, answer, bar)?)
        }
        _ => None,
    };
    if let Some(path) = &args.stats {
        let mut out = create(path)?;
        // the run's statistics, the process's (load and render times, peak memory) and, under
        // "bake", what the bake wrote
        let mut json = serde_json::to_value(run).context("the run statistics")?;
        json["load_seconds"] = load_seconds.into();
        json["render_seconds"] = render_seconds.into();
        json["gather_rays"] = gather_rays.into();
        if let Some(bytes) = peak_resident_bytes() {
            json["peak_rss_bytes"] = bytes.into();
        }
        if let Some(summary) = &baked {
            json["bake"] = summary.clone();
        }
        serde_json::to_writer_pretty(&mut out, &json).context("the run statistics")?;
        std::io::Write::write_all(&mut out, b"\n")
            .and_then(|()| std::io::Write::flush(&mut out))
            .with_context(|| format!("could not write {}", path.display()))?;
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
        if let Some(path) = &args.image {
            println!(
                "{}: {}x{}, {} samples a pixel, {}, {render_seconds:.1} s",
                path.display(),
                args.size.0,
                args.size.1,
                args.spp,
                match gather_rays {
                    0 => "the solution shown where a camera ray lands".to_string(),
                    n => format!("a final gather of {n} rays a sample"),
                }
            );
        }
        if let Some(summary) = &baked {
            println!("{}", crate::output::bake_line(summary));
        }
    }
    Ok(())
}

/// The process's peak resident memory so far (bytes): `VmHWM` of `/proc/self/status`; `None`
/// where it cannot be read.
fn peak_resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let kib: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kib * 1024)
}

pub fn create(path: &Path) -> Result<BufWriter<File>> {
    let file =
        File::create(path).with_context(|| format!("could not create {}", path.display()))?;
    Ok(BufWriter::new(file))
}

/// A bar over the method's ray budget on an interactive terminal; hidden otherwise or with
/// `--quiet`.
fn progress_bar(quiet: bool) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {human_pos}/{human_len} rays, {msg}",
        )
        .expect("a valid template")
        .progress_chars("=> "),
    );
    bar
}
