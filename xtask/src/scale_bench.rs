//! `cargo xtask scale-bench`: the generated atrium ([`crate::atrium`]) at several triangle
//! counts, each solved once by `mcrad solve` (a child process, default settings, a ray budget
//! and a render): load, mesh and BVH, solve and render times and the peak resident memory, into
//! a CSV and a plot (issue 35, item 7).
//!
//! Each run's peak memory is measured by a child `xtask peak-rss` that runs `mcrad` and reads
//! the peak of its own children (`getrusage`), so the numbers are the same for any `mcrad`
//! binary, an older one included (`--mcrad`, for side-by-side tables).

use anyhow::{Context, Result, bail};
use mcrad_lab::plot::{PlotSpec, Series, line_plot};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// The options of `cargo xtask scale-bench`.
#[derive(Debug, clap::Args)]
pub struct ScaleBenchArgs {
    /// Triangle counts of the atriums, comma-separated (each from 30000 to 1e7)
    #[arg(long, value_delimiter = ',', default_value = "1e5,3e5,1e6",
          value_parser = crate::parse_count)]
    pub triangles: Vec<u64>,
    /// Rays of each solve (`mcrad solve --rays`)
    #[arg(long, default_value = "2e6", value_parser = crate::parse_count)]
    pub rays: u64,
    /// Worker threads of each solve [default: all cores]
    #[arg(long)]
    pub threads: Option<u16>,
    /// Pixels of the render (WxH); `none` for no render
    #[arg(long, default_value = "256x256")]
    pub size: String,
    /// The `mcrad` binary [default: the one next to this xtask]
    #[arg(long, value_name = "PATH")]
    pub mcrad: Option<PathBuf>,
    /// Output stem: writes STEM.csv and STEM.png
    #[arg(long, value_name = "STEM", default_value = "docs/scale-bench")]
    pub out: PathBuf,
}

/// The options of the hidden `xtask peak-rss`.
#[derive(Debug, clap::Args)]
pub struct PeakRssArgs {
    /// Writes `{"peak_rss_bytes": N, "wall_seconds": S}` here
    #[arg(long, value_name = "F.json")]
    pub out: PathBuf,
    /// The command and its arguments
    #[arg(trailing_var_arg = true, allow_hyphen_values = true, required = true)]
    pub command: Vec<String>,
}

/// Runs `args.command`, then writes its peak resident memory (the largest of this process's
/// waited-for children, `getrusage(RUSAGE_CHILDREN)`: run it as its own process, one command
/// each) and its wall-clock time.
pub fn peak_rss(args: &PeakRssArgs) -> Result<()> {
    let start = Instant::now();
    let status = Command::new(&args.command[0])
        .args(&args.command[1..])
        .status()
        .with_context(|| format!("could not run {}", args.command[0]))?;
    let wall = start.elapsed().as_secs_f64();
    if !status.success() {
        bail!("{} failed: {status}", args.command.join(" "));
    }
    let usage = nix::sys::resource::getrusage(nix::sys::resource::UsageWho::RUSAGE_CHILDREN)
        .context("getrusage")?;
    // Linux reports ru_maxrss in KiB
    let json = serde_json::json!({
        "peak_rss_bytes": usage.max_rss() as u64 * 1024,
        "wall_seconds": wall,
    });
    std::fs::write(&args.out, json.to_string())
        .with_context(|| format!("could not write {}", args.out.display()))
}

/// One size's measurements.
struct Row {
    triangles: u64,
    elements: u64,
    load: Option<f64>,
    setup: f64,
    solve: f64,
    render: Option<f64>,
    wall: f64,
    peak: u64,
}

/// Runs the benchmark of `args` (paths relative to `root`).
pub fn run(root: &Path, args: &ScaleBenchArgs) -> Result<()> {
    let me = std::env::current_exe().context("the xtask's own path")?;
    let mcrad = match &args.mcrad {
        Some(p) => p.clone(),
        None => me.with_file_name("mcrad"),
    };
    if !mcrad.is_file() {
        bail!(
            "{} is not built: cargo build --release -p mcrad (or pass --mcrad)",
            mcrad.display()
        );
    }
    let work = root.join("target/scale-bench");
    std::fs::create_dir_all(&work)?;
    let mut rows = Vec::new();
    for &triangles in &args.triangles {
        let scene = crate::gen_scenes::write_atrium(
            root,
            &crate::gen_scenes::GenScenesArgs {
                triangles,
                no_sky_panel: false,
                glb: false,
                atrium_only: true,
                out: None,
            },
        )?;
        let (stats, peak) = (work.join("stats.json"), work.join("peak.json"));
        let mut command = vec![
            mcrad.to_string_lossy().into_owned(),
            "solve".into(),
            scene.to_string_lossy().into_owned(),
            "--rays".into(),
            args.rays.to_string(),
            "--stats".into(),
            stats.to_string_lossy().into_owned(),
            "--quiet".into(),
        ];
        if let Some(t) = args.threads {
            command.extend(["--threads".into(), t.to_string()]);
        }
        if args.size != "none" {
            command.extend([
                "--image".into(),
                work.join(format!("atrium-{triangles}.png"))
                    .to_string_lossy()
                    .into_owned(),
                "--camera".into(),
                crate::atrium::CAMERA.into(),
                "--size".into(),
                args.size.clone(),
            ]);
        }
        let status = Command::new(&me)
            .arg("peak-rss")
            .arg("--out")
            .arg(&peak)
            .arg("--")
            .args(&command)
            .status()
            .context("could not run xtask peak-rss")?;
        if !status.success() {
            bail!("the solve of {} failed", scene.display());
        }
        let read = |p: &Path| -> Result<serde_json::Value> {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("could not read {}", p.display()))?;
            Ok(serde_json::from_str(&text)?)
        };
        let (s, p) = (read(&stats)?, read(&peak)?);
        let number = |v: &serde_json::Value, key: &str| v[key].as_f64();
        let load = number(&s, "load_seconds");
        let row = Row {
            triangles: crate::atrium::Tessellation::for_triangles(triangles, true).triangles(true),
            elements: s["patches"].as_u64().unwrap_or(0),
            load,
            // setup_seconds counts from before loading
            setup: number(&s, "setup_seconds").unwrap_or(f64::NAN) - load.unwrap_or(0.0),
            solve: number(&s, "seconds").unwrap_or(f64::NAN),
            render: number(&s, "render_seconds"),
            wall: number(&p, "wall_seconds").unwrap_or(f64::NAN),
            peak: p["peak_rss_bytes"].as_u64().unwrap_or(0),
        };
        eprintln!(
            "{} triangles: {} elements, peak {:.1} MiB ({:.0} bytes per element), wall {:.1} s",
            row.triangles,
            row.elements,
            row.peak as f64 / (1 << 20) as f64,
            row.peak as f64 / row.elements.max(1) as f64,
            row.wall
        );
        rows.push(row);
    }
    write_outputs(root, args, &rows)
}

fn write_outputs(root: &Path, args: &ScaleBenchArgs, rows: &[Row]) -> Result<()> {
    let opt = |x: Option<f64>| x.map_or(String::new(), |x| format!("{x:.3}"));
    let mut csv = String::from(
        "triangles,elements,load_s,mesh_bvh_s,solve_s,render_s,wall_s,peak_rss_bytes,bytes_per_element\n",
    );
    for r in rows {
        writeln!(
            csv,
            "{},{},{},{:.3},{:.3},{},{:.3},{},{:.0}",
            r.triangles,
            r.elements,
            opt(r.load),
            r.setup,
            r.solve,
            opt(r.render),
            r.wall,
            r.peak,
            r.peak as f64 / r.elements.max(1) as f64
        )?;
    }
    let stem = root.join(&args.out);
    let csv_path = stem.with_extension("csv");
    std::fs::write(&csv_path, csv)
        .with_context(|| format!("could not write {}", csv_path.display()))?;
    eprintln!("wrote {}", csv_path.display());
    let series = |name: &str, f: &dyn Fn(&Row) -> Option<f64>| Series {
        name: name.into(),
        points: rows
            .iter()
            .filter_map(|r| f(r).filter(|y| *y > 0.0).map(|y| (r.triangles as f64, y)))
            .collect(),
        band: None,
    };
    let spec = PlotSpec {
        title: format!(
            "The generated atrium, mcrad solve --rays {:.0e}: seconds and peak memory",
            args.rays as f64
        ),
        x_label: "input triangles".into(),
        y_label: "seconds; peak memory in GiB".into(),
        log_x: true,
        log_y: true,
        series: vec![
            series("load (s)", &|r| r.load),
            series("mesh and BVH (s)", &|r| Some(r.setup)),
            series("solve (s)", &|r| Some(r.solve)),
            series("render (s)", &|r| r.render),
            series("wall clock (s)", &|r| Some(r.wall)),
            series("peak RSS (GiB)", &|r| {
                Some(r.peak as f64 / (1u64 << 30) as f64)
            }),
        ]
        .into_iter()
        .filter(|s| !s.points.is_empty())
        .collect(),
    };
    let png = stem.with_extension("png");
    line_plot(&png, &spec)?;
    eprintln!("wrote {}", png.display());
    Ok(())
}
