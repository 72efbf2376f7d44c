//! Project tasks (matklad's xtask pattern): `cargo xtask <task>`.

mod atrium;
mod bake_bench;
mod bake_check;
mod calibrate;
mod experiment;
mod gen_scenes;
mod meshing_exp;
mod path_trace;
mod regress;
mod scale_bench;
mod speed;
mod viewer;

use anyhow::{Context, Result, bail};
use clap::{CommandFactory, Parser, Subcommand, ValueEnum};
use std::path::{Path, PathBuf};
use std::process::Command;

/// mcrad's project tasks.
#[derive(Debug, Parser)]
#[command(
    name = "cargo xtask",
    bin_name = "cargo xtask",
    subcommand_value_name = "TASK",
    subcommand_help_heading = "Tasks"
)]
struct Cli {
    #[command(subcommand)]
    task: Option<Task>,
}

/// One task.
#[derive(Debug, Subcommand)]
enum Task {
    /// What CI runs: cargo fmt --check, clippy -D warnings, cargo doc -D warnings, the release
    /// test suite
    Ci,
    /// The shooting and ray-casting benchmarks (criterion), then tables of their medians
    Bench {
        /// Only one benchmark [default: shooting and raycast]
        #[arg(value_enum)]
        which: Option<Bench>,
    },
    /// Golden-image regression of the bundled scenes (scenes/golden/)
    Regress {
        /// Re-renders the goldens and re-measures their noise thresholds
        #[arg(long)]
        bless: bool,
    },
    /// The experiments: the paper's Figure 2, speed against error, meshing
    Experiment {
        #[command(subcommand)]
        experiment: Experiment,
    },
    /// Every Monte Carlo method on furnaces and a tiny-light room, K seeds: mean z², spread /
    /// reported variance, power bias, budget use; writes docs/calibration.md
    Calibrate(calibrate::CalibrateArgs),
    /// Writes the generated experiment scenes scenes/boxes-room.obj and scenes/table-room.obj
    /// (+ .mtl), and scenes/cornell-box.gltf (+ .bin) from the OBJ; and the atrium (about 100k
    /// triangles, or --triangles N) into target/scenes/
    GenScenes(gen_scenes::GenScenesArgs),
    /// The generated atrium at several sizes (--triangles 1e5,1e6,...), one mcrad solve each:
    /// load, mesh and BVH, solve and render times and peak memory; writes docs/scale-bench.csv
    /// and .png
    ScaleBench(scale_bench::ScaleBenchArgs),
    /// Runs a command and writes its peak resident memory and wall-clock time (scale-bench's
    /// measurement of one run)
    #[command(hide = true)]
    PeakRss(scale_bench::PeakRssArgs),
    /// A textured Cornell-style room baked from K seeds of a method and from the reference
    /// solver: per face, the baked texels' error against the variance the bake reports
    BakeCheck(bake_check::BakeCheckArgs),
    /// Bakes scenes/cornell-box.gltf (mcrad bake), renders the GLB with three.js in headless
    /// Chromium (Debian's chromium; npm installs three in xtask/viewer) and compares it with
    /// mcrad's render of the same solution
    ViewerCheck {
        /// Updates docs/bake-cornell.png
        #[arg(long)]
        docs: bool,
    },
    /// img_rel = sqrt(sum (I - R)^2 / sum R^2) over the pixels that see no emitter (nor have a
    /// neighbour that does), and the same over the darkest third of them; with the reference's
    /// standard error per pixel, its noise is subtracted (sum se^2)
    ImageError(path_trace::ImageErrorArgs),
    /// An independent diffuse path tracer (mcrad_lab::pathtrace): the ground truth of a
    /// picture, and its standard error per pixel (R.error.exr)
    PathTrace(path_trace::PathTraceArgs),
    /// Reference solutions of the experiment scenes into scenes/reference/
    GenReferences {
        /// The scenes [default: all but cornell-2k]
        scenes: Vec<String>,
    },
}

/// One of the benchmarks of `cargo xtask bench`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Bench {
    /// crates/mc-radiosity/benches/shooting.rs
    Shooting,
    /// crates/raycast/benches/scenes.rs
    Raycast,
    /// Times mcrad bake on a generated 100k-triangle textured glTF of 8,400 instances
    Bake,
    /// The fixed cost: each stage from the scene file to a 5% solution of a 310-patch box
    /// (crates/mc-radiosity/benches/first_solution.rs)
    FirstSolution,
}

/// The experiments of `cargo xtask experiment`.
#[derive(Debug, Subcommand)]
enum Experiment {
    /// The paper's Figure 2: gathering from refining shooting, with and without the ambient
    /// term; writes docs/figure2.csv and docs/figure2.png
    Figure2,
    /// Every method on every experiment scene, error against time; writes
    /// docs/speed-vs-error.csv, docs/speed-vs-error-SCENE.png, docs/results.md
    SpeedVsError(speed::SpeedArgs),
    /// Uniform meshes of several sizes against adaptive, image error against a path-traced
    /// ground truth and per-face rms_rel, against --time; writes docs/meshing-experiment.md,
    /// .csv and a plot per scene (caches in target/meshing/)
    Meshing(meshing_exp::MeshingArgs),
}

fn main() -> std::process::ExitCode {
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    let Some(task) = cli.task else {
        Cli::command().print_help()?;
        return Ok(());
    };
    match task {
        Task::Ci => ci(),
        Task::Bench {
            which: Some(Bench::Bake),
        } => {
            cargo(&["build", "--release", "--bin", "mcrad"])?;
            bake_bench::run(&root(), &target_dir().join("release/mcrad"))
        }
        Task::Bench {
            which: Some(Bench::FirstSolution),
        } => bench_first_solution(),
        Task::Bench { which } => {
            if which != Some(Bench::Raycast) {
                bench()?;
            }
            if which != Some(Bench::Shooting) {
                bench_raycast()?;
            }
            Ok(())
        }
        Task::Regress { bless } => {
            cargo(&["build", "--release", "--bin", "mcrad"])?;
            regress::run(&root(), &target_dir().join("release/mcrad"), bless)
        }
        Task::Experiment { experiment } => match experiment {
            Experiment::Figure2 => experiment::figure2(&root()),
            Experiment::SpeedVsError(args) => speed::run(&root(), &args),
            Experiment::Meshing(args) => {
                cargo(&["build", "--release", "--bin", "mcrad"])?;
                meshing_exp::run(&root(), &target_dir().join("release/mcrad"), &args)
            }
        },
        Task::Calibrate(args) => calibrate::run(&root(), &args),
        Task::ScaleBench(args) => scale_bench::run(&root(), &args),
        Task::PeakRss(args) => scale_bench::peak_rss(&args),
        Task::GenScenes(args) => {
            if !args.atrium_only {
                gen_scenes::run(&root())?;
                viewer::write_cornell_gltf(&root())?;
            }
            gen_scenes::write_atrium(&root(), &args).map(drop)
        }
        Task::BakeCheck(args) => bake_check::run(&root(), &args),
        Task::ViewerCheck { docs } => {
            cargo(&["build", "--release", "--bin", "mcrad"])?;
            viewer::run(&root(), &target_dir().join("release/mcrad"), docs)
        }
        Task::ImageError(args) => path_trace::run_image_error(&args),
        Task::PathTrace(args) => path_trace::run_path_trace(&args),
        Task::GenReferences { scenes } => speed::scenes::generate(&root(), &scenes),
    }
}

/// `method` on the fixed `mesh` through the library's solve ([`mcrad_solve::solve`], as
/// `mcrad solve` runs it), with `config`'s budget, seed and method settings; `observer` sees
/// each step.
fn solve_fixed(
    method: mcrad_mc_radiosity::Method,
    mesh: &mcrad_meshing::Mesh,
    config: &mcrad_mc_radiosity::ScheduleConfig,
    observer: &mut mcrad_solve::Observer,
) -> Result<mcrad_solve::Answer, mcrad_solve::Error> {
    solve_input(
        method,
        mcrad_solve::Input::Mesh(mesh),
        mcrad_solve::MeshPlan::PerFace,
        config,
        observer,
    )
}

/// The library's solve of `input` meshed by `plan` (not used for a mesh) with `config`'s
/// settings and ray budget, as [`solve_fixed`].
fn solve_input(
    method: mcrad_mc_radiosity::Method,
    input: mcrad_solve::Input<'_>,
    plan: mcrad_solve::MeshPlan,
    config: &mcrad_mc_radiosity::ScheduleConfig,
    observer: &mut mcrad_solve::Observer,
) -> Result<mcrad_solve::Answer, mcrad_solve::Error> {
    let problem = mcrad_solve::Problem {
        input,
        settings: mcrad_solve::Settings {
            method,
            mesh: plan,
            seed: config.seed,
            sampler: config.sampler,
            control_variate: config.control_variate,
            ambient: config.ambient,
            unshot_threshold: config.unshot_threshold,
            visibility_tolerance: config.reference.visibility_tolerance,
        },
        budget: mcrad_solve::Budget {
            rays: Some(config.rays),
            ..Default::default()
        },
        threads: None,
        resume: None,
        cancel: None,
        closure: false,
        after: None,
        clustering: mcrad_solve::Clustering::default(),
        keep_state: false,
    };
    mcrad_solve::solve(&problem, observer)
}

/// A count written as an integer or in floating point (`2e6`), as the tasks' `--rays` take it.
fn parse_count(s: &str) -> Result<u64> {
    let x: f64 = s
        .parse()
        .with_context(|| format!("'{s}' is not a number"))?;
    if !(x >= 0.0 && x <= u64::MAX as f64) {
        bail!("'{s}' is not a count");
    }
    Ok(x as u64)
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives in the workspace")
        .to_path_buf()
}

/// Cargo's target directory: `CARGO_TARGET_DIR` when set (relative to the workspace root),
/// else `target/` in the workspace.
fn target_dir() -> PathBuf {
    match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) => root().join(dir),
        None => root().join("target"),
    }
}

fn cargo(args: &[&str]) -> Result<()> {
    eprintln!("$ cargo {}", args.join(" "));
    let status = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .args(args)
        .current_dir(root())
        .status()
        .context("could not run cargo")?;
    if !status.success() {
        bail!("cargo {} failed ({status})", args.join(" "));
    }
    Ok(())
}

fn ci() -> Result<()> {
    cargo(&["fmt", "--all", "--", "--check"])?;
    cargo(&[
        "clippy",
        "--workspace",
        "--all-targets",
        "--release",
        "--",
        "-D",
        "warnings",
    ])?;
    cargo(&[
        "doc",
        "--workspace",
        "--no-deps",
        "--config",
        "build.rustdocflags=[\"-D\", \"warnings\"]",
    ])?;
    cargo(&["test", "--workspace", "--release"])
}

/// Runs the shooting benchmark and prints, per scene, each variant's median throughput and the
/// solver's ratio to the bare obvhs loop.
fn bench() -> Result<()> {
    cargo(&["bench", "-p", "mcrad-mc-radiosity", "--bench", "shooting"])?;
    let dir = target_dir().join("criterion");
    let mut groups: Vec<PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| format!("no criterion results in {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("shoot").is_dir())
        .collect();
    groups.sort();
    println!("| scene | shoot Mrays/s | mcrad Bvh Mrays/s | bare obvhs Mrays/s | shoot / bare |");
    println!("|---|---|---|---|---|");
    for g in groups {
        let rate = |f: &str| throughput(&g.join(f));
        let (shoot, mine, bare) = (rate("shoot")?, rate("mcrad_bvh")?, rate("bare_obvhs")?);
        println!(
            "| {} | {shoot:.2} | {mine:.2} | {bare:.2} | {:.2} |",
            g.file_name().unwrap_or_default().to_string_lossy(),
            shoot / bare
        );
    }
    Ok(())
}

/// Runs the ray-casting benchmark (`crates/raycast/benches/scenes.rs`) and prints, per scene,
/// the median throughputs of closest-hit (one by one and batched) and occlusion queries, the
/// BVH build time and its memory per triangle.
fn bench_raycast() -> Result<()> {
    cargo(&["bench", "-p", "mcrad-raycast", "--bench", "scenes"])?;
    let dir = target_dir().join("criterion");
    let memory: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("raycast-memory.json"))
            .context("the benchmark wrote no raycast-memory.json")?,
    )?;
    println!();
    println!(
        "| scene | triangles | closest Mrays/s | closest_batch Mrays/s | occluded Mrays/s | build ms | BVH bytes/triangle |"
    );
    println!("|---|---|---|---|---|---|---|");
    for scene in ["cornell", "room100k", "room1m"] {
        let g = dir.join(format!("raycast-{scene}"));
        let rate = |f: &str| throughput(&g.join(f));
        let tris = memory[scene]["triangles"].as_f64().unwrap_or(f64::NAN);
        let bytes = memory[scene]["bytes"].as_f64().unwrap_or(f64::NAN);
        // build throughput is in triangles per microsecond: time = triangles / rate
        let build_ms = tris / rate("build")? * 1e-3;
        println!(
            "| {scene} | {tris} | {:.2} | {:.2} | {:.2} | {build_ms:.1} | {:.1} |",
            rate("closest")?,
            rate("closest_batch")?,
            rate("occluded")?,
            bytes / tris
        );
    }
    Ok(())
}

/// Median throughput of one criterion benchmark in million elements per second.
fn throughput(bench: &Path) -> Result<f64> {
    let median_ns = median_ns(bench)?;
    let elements = criterion_json(bench, "benchmark.json")?["throughput"]["Elements"]
        .as_f64()
        .context("benchmark.json has no element throughput")?;
    Ok(elements / median_ns * 1e3)
}

/// One of the JSON files criterion wrote for the newest run of `bench`.
fn criterion_json(bench: &Path, name: &str) -> Result<serde_json::Value> {
    let p = bench.join("new").join(name);
    let text =
        std::fs::read_to_string(&p).with_context(|| format!("could not read {}", p.display()))?;
    Ok(serde_json::from_str(&text)?)
}

/// The median time of the newest run of the criterion benchmark `bench`, in nanoseconds.
fn median_ns(bench: &Path) -> Result<f64> {
    criterion_json(bench, "estimates.json")?["median"]["point_estimate"]
        .as_f64()
        .context("estimates.json has no median")
}

/// Runs the fixed-cost benchmark (`crates/mc-radiosity/benches/first_solution.rs`) and prints
/// the median time of each stage from the scene file to the first solution of 5% error.
fn bench_first_solution() -> Result<()> {
    cargo(&[
        "bench",
        "-p",
        "mcrad-mc-radiosity",
        "--bench",
        "first_solution",
    ])?;
    let dir = target_dir().join("criterion");
    let mut groups: Vec<PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| format!("no criterion results in {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("solve_1000_rays").is_dir())
        .collect();
    groups.sort();
    let stages = [
        "load",
        "mesh",
        "bvh",
        "solve",
        "file_to_solution",
        "solve_1000_rays",
    ];
    println!(
        "| scene | {} |",
        stages.map(|s| format!("{s} (ms)")).join(" | ")
    );
    println!("|---|{}", "---:|".repeat(stages.len()));
    for g in groups {
        let times = stages
            .iter()
            .map(|s| Ok(format!("{:.3}", median_ns(&g.join(s))? * 1e-6)))
            .collect::<Result<Vec<_>>>()?;
        println!(
            "| {} | {} |",
            g.file_name().unwrap_or_default().to_string_lossy(),
            times.join(" | ")
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every spelling of a task that the documentation uses still parses (values made up
    /// where it has placeholders), and no arguments is no task (the help).
    #[test]
    fn documented_invocations_parse() {
        Cli::command().debug_assert();
        let lines = [
            "ci",
            "bench",
            "bench shooting",
            "bench raycast",
            "bench bake",
            "bench first-solution",
            "regress",
            "regress --bless",
            "experiment figure2",
            "experiment speed-vs-error",
            "experiment speed-vs-error --quick",
            "experiment speed-vs-error --scenes small-light,cornell-2k --methods combined,shoot,prr \
             --seeds 3 --target 0.01 --time 20 --sampler random",
            "experiment speed-vs-error --scenes cornell-2k,small-light,boxes-room,cornell-20k \
             --methods combined --seeds 3 --time 10 --target 0.01 --sampler qmc \
             --control-variate constant --out somewhere",
            "experiment meshing",
            "experiment meshing --quick --scenes cornell,table-room,boxes-room --times 2.5,5,10 \
             --spp 16 --curve-rays 1e8 --out docs",
            "calibrate",
            "calibrate --seeds 16 --rays 2e5 --cases furnace-0.5 --methods prr,combined \
             --limit 20 --sampler qmc --out docs/calibration.md",
            "gen-scenes",
            "gen-scenes --atrium-only --triangles 1e6 --glb --no-sky-panel --out somewhere",
            "scale-bench",
            "scale-bench --triangles 1e5,1e6 --rays 2e6 --threads 2 --size none --mcrad old/mcrad \
             --out somewhere",
            "peak-rss --out p.json -- true",
            "bake-check",
            "bake-check --seeds 8 --rays 2e6 --method combined",
            "viewer-check",
            "viewer-check --docs",
            "image-error A.exr B.exr",
            "image-error A.exr B.exr diff.png",
            "image-error IMAGE.exr R.exr --reference-error R.error.exr",
            "image-error IMAGE.exr R.exr --reference-error R.error.exr --second IMAGE2.exr",
            "path-trace scenes/cornell-box.obj --camera eye=0.278,0.273,-0.8,look=0.278,0.273,0,fov=39.3 \
             --size 256x256 --spp 16 --out R.exr",
            "path-trace s.obj --camera eye=0,0,1,look=0,0,0,fov=40 --size 32x24 --spp 4 --seed 3 \
             --out R.exr --error E.exr",
            "gen-references",
            "gen-references cornell-20k small-light",
        ];
        for line in lines {
            let words = line.split_whitespace();
            let cli = Cli::try_parse_from(std::iter::once("xtask").chain(words));
            assert!(
                cli.as_ref().is_ok_and(|c| c.task.is_some()),
                "{line}: {cli:?}"
            );
        }
        assert!(Cli::try_parse_from(["xtask"]).unwrap().task.is_none());
        for bad in [
            "nothing",
            "bench everything",
            "regress --blessed",
            "calibrate --rays x",
        ] {
            let words = bad.split_whitespace();
            assert!(
                Cli::try_parse_from(std::iter::once("xtask").chain(words)).is_err(),
                "{bad}"
            );
        }
    }
}
