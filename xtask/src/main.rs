//! Project tasks (matklad's xtask pattern): `cargo xtask <task>`.

mod bake_bench;
mod bake_check;
mod calibrate;
mod experiment;
mod gen_scenes;
mod meshing_exp;
mod path_trace;
mod regress;
mod speed;
mod viewer;

use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use std::process::Command;

const HELP: &str = "\
cargo xtask <task>

tasks:
  ci      what CI runs: cargo fmt --check, clippy -D warnings, cargo doc -D warnings, the
          release test suite
  bench   the shooting and ray-casting benchmarks (criterion), then tables of their medians;
          `bench shooting` or `bench raycast` runs one of them; `bench bake` times mcrad bake
          on a generated 100k-triangle textured glTF of 8,400 instances; `bench first-solution`
          the fixed cost: each stage from the scene file to a 5% solution of a 310-patch box
  regress golden-image regression of the bundled scenes (scenes/golden/);
          `regress --bless` re-renders the goldens and re-measures their noise thresholds
  experiment figure2
          the paper's Figure 2: gathering from refining shooting, with and without the
          ambient term; writes docs/figure2.csv and docs/figure2.png
  experiment speed-vs-error [--quick] [--seeds N] [--scenes a,b] [--methods m,n]
                            [--time S] [--target E] [--sampler random|qmc]
                            [--control-variate off|constant] [--out DIR]
          every method on every experiment scene, error against time; writes
          docs/speed-vs-error.csv, docs/speed-vs-error-<scene>.png, docs/results.md
          (--quick: 1 seed, 1 s per curve, into target/speed-vs-error-quick/)
  experiment meshing [--quick] [--scenes cornell,table-room,boxes-room] [--times 2.5,5,10]
                     [--spp N] [--out DIR]
          uniform meshes of several sizes against adaptive, image error against a path-traced
          ground truth and per-face rms_rel, against --time; writes
          docs/meshing-experiment.md, .csv and a plot per scene (caches in target/meshing/)
  calibrate [--seeds K] [--rays N] [--cases a,b] [--methods m,n] [--limit S]
            [--sampler random|qmc]
          every Monte Carlo method on furnaces and a tiny-light room, K seeds: mean z²,
          spread/reported variance, power bias, budget use; writes docs/calibration.md
  gen-scenes
          writes the generated experiment scenes scenes/boxes-room.obj and
          scenes/table-room.obj (+ .mtl), and scenes/cornell-box.gltf (+ .bin) from the OBJ
  bake-check [--seeds K] [--rays N]
          a textured Cornell-style room baked from K seeds of combined and from the reference
          solver: per face, the baked texels' error against the variance the bake reports
  viewer-check [--docs]
          bakes scenes/cornell-box.gltf (mcrad bake), renders the GLB with three.js in headless
          Chromium (Debian's chromium; npm installs three in xtask/viewer) and compares it with
          mcrad's render of the same solution; --docs updates docs/bake-cornell.png
  image-error IMAGE.exr REFERENCE.exr [DIFFERENCE.png] [--reference-error ERROR.exr]
          img_rel = sqrt(sum (I - R)^2 / sum R^2) over the pixels that see no emitter (nor
          have a neighbour that does), and the same over the darkest third of them; with the
          reference's standard error per pixel, its noise is subtracted (sum se^2)
  path-trace SCENE --camera SPEC --size WxH --spp N [--seed S] --out R.exr [--error E.exr]
          an independent diffuse path tracer (mcrad_lab::pathtrace): the ground truth of a
          picture, and its standard error per pixel (R.error.exr)
  gen-references [scene ...]
          reference solutions of the experiment scenes (default: all but cornell-2k)
          into scenes/reference/
";

fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run() -> Result<()> {
    let task = std::env::args().nth(1);
    match task.as_deref() {
        Some("ci") => ci(),
        Some("bench") if std::env::args().nth(2).as_deref() == Some("bake") => {
            cargo(&["build", "--release", "--bin", "mcrad"])?;
            bake_bench::run(&root(), &target_dir().join("release/mcrad"))
        }
        Some("bench") if std::env::args().nth(2).as_deref() == Some("first-solution") => {
            bench_first_solution()
        }
        Some("bench") => {
            let which = std::env::args().nth(2);
            if which.as_deref() != Some("raycast") {
                bench()?;
            }
            if which.as_deref() != Some("shooting") {
                bench_raycast()?;
            }
            Ok(())
        }
        Some("regress") => {
            let bless = std::env::args().nth(2).as_deref() == Some("--bless");
            cargo(&["build", "--release", "--bin", "mcrad"])?;
            regress::run(&root(), &target_dir().join("release/mcrad"), bless)
        }
        Some("experiment") if std::env::args().nth(2).as_deref() == Some("speed-vs-error") => {
            let args: Vec<String> = std::env::args().skip(3).collect();
            speed::run(&root(), &args)
        }
        Some("experiment") if std::env::args().nth(2).as_deref() == Some("meshing") => {
            cargo(&["build", "--release", "--bin", "mcrad"])?;
            let args: Vec<String> = std::env::args().skip(3).collect();
            meshing_exp::run(&root(), &target_dir().join("release/mcrad"), &args)
        }
        Some("experiment") => experiment::run(&root(), std::env::args().nth(2).as_deref()),
        Some("calibrate") => calibrate::run(&root(), &std::env::args().skip(2).collect::<Vec<_>>()),
        Some("gen-scenes") => {
            gen_scenes::run(&root())?;
            viewer::write_cornell_gltf(&root())
        }
        Some("bake-check") => {
            bake_check::run(&root(), &std::env::args().skip(2).collect::<Vec<_>>())
        }
        Some("viewer-check") => {
            let docs = std::env::args().nth(2).as_deref() == Some("--docs");
            cargo(&["build", "--release", "--bin", "mcrad"])?;
            viewer::run(&root(), &target_dir().join("release/mcrad"), docs)
        }
        Some("image-error") => {
            path_trace::run_image_error(&std::env::args().skip(2).collect::<Vec<_>>())
        }
        Some("path-trace") => {
            path_trace::run_path_trace(&std::env::args().skip(2).collect::<Vec<_>>())
        }
        Some("gen-references") => {
            let names: Vec<String> = std::env::args().skip(2).collect();
            speed::scenes::generate(&root(), &names)
        }
        Some("help" | "-h" | "--help") | None => {
            print!("{HELP}");
            Ok(())
        }
        Some(other) => bail!("unknown task '{other}'\n\n{HELP}"),
    }
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
