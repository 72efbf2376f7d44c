//! `cargo xtask experiment <name>`: experiments that reproduce the paper's figures.
//!
//! `figure2` (Balog, section 3.1, Figure 2): one precise gathering round (the same rays per
//! patch for every point) from shooting solutions of growing quality, with and without the
//! ambient term, measured against the deterministic reference solution on the Cornell box (one
//! patch per face). Two sweeps:
//!
//! - **refining**: one shooting run (budget [`REFINING_BUDGET`], no unshot threshold) stopped
//!   after each of its first [`REFINING_WAVES`] waves, so the gathering starts from a solution
//!   that still holds 40% of the emitted power unshot, then 20%, 10%, ... (the paper's "refining
//!   shooting solution" while little power has been shot);
//! - **budgets**: complete shooting runs of 1e2 ... 1e6 rays stopping at 1% unshot (the paper's
//!   threshold).
//!
//! Writes `docs/figure2.csv` (one row per point and seed), `docs/figure2.png` (refining:
//! rms_rel against the unshot power left), `docs/figure2-reflected.png` (refining: reflected
//! power against the reference's) and `docs/figure2-budgets.png` (budgets: rms_rel against
//! shooting rays), and prints both tables in Markdown.

use anyhow::{Context, Result};
use glam::DVec3;
use mcrad_lab::plot::{PlotSpec, Series, line_plot};
use mcrad_lab::trace::Reference;
use mcrad_mc_radiosity::{Method, Sampler, ScheduleConfig, Solution, gather_from};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use mcrad_reference::{ReferenceConfig, reference};
use std::fmt::Write as _;
use std::ops::ControlFlow;
use std::path::Path;
use std::time::Instant;

/// Budgets of the complete runs (rays): 1e2, 3e2, 1e3, ..., 1e6.
const BUDGETS: [u64; 9] = [
    100, 300, 1_000, 3_000, 10_000, 30_000, 100_000, 300_000, 1_000_000,
];
/// Complete runs stop at this fraction of the emitted power left unshot (the paper's 1%).
const UNSHOT_THRESHOLD: f64 = 0.01;
/// Budget of the refining run; its energy per ray is set by it, its waves are the snapshots.
const REFINING_BUDGET: u64 = 100_000;
/// Snapshots of the refining run: after waves 1..=REFINING_WAVES (unshot 43% down to ~0.1%).
const REFINING_WAVES: u32 = 10;
/// Gathering rays per patch, the same for every point.
const GATHER_RAYS: u32 = 20_000;
/// Seeds per point.
const SEEDS: u64 = 5;

/// Which sweep a point belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Sweep {
    Refining,
    Budgets,
}

impl Sweep {
    fn name(self) -> &'static str {
        match self {
            Sweep::Refining => "refining",
            Sweep::Budgets => "budgets",
        }
    }
}

/// One measured point.
struct Row {
    sweep: Sweep,
    /// Rays the shooting actually cast.
    shooting_rays: u64,
    /// The shooting run's budget.
    budget: u64,
    /// Waves the shooting ran.
    waves: u32,
    ambient: bool,
    seed: u64,
    rms_rel: f64,
    reflected_ratio: f64,
    /// Unshot power left by the shooting, as a fraction of the emitted power (channels summed).
    unshot: f64,
}

/// `sum_i A_i sum_c (B_ic - E_ic)`: the reflected power (W, channels summed).
fn reflected(mesh: &Mesh, radiosity: &[DVec3]) -> f64 {
    mesh.patches()
        .iter()
        .zip(radiosity)
        .map(|(p, b)| p.area * (*b - p.emission.as_dvec3()).element_sum())
        .sum()
}

/// The scene and what every point needs.
struct Setup {
    mesh: Mesh,
    bvh: Bvh,
    exact: Reference,
    exact_reflected: f64,
}

impl Setup {
    /// Shooting (the estimators' `random` sampler) with `config`, stopped after wave
    /// `stop_after` if given; with `ambient` the ambient term is added to its answer.
    fn shoot(
        &self,
        config: &ScheduleConfig,
        stop_after: Option<u32>,
        ambient: bool,
    ) -> Result<Solution> {
        let config = ScheduleConfig {
            ambient,
            sampler: Sampler::Random,
            ..config.clone()
        };
        Ok(mcrad_mc_radiosity::run(
            Method::Shoot,
            &self.mesh,
            &self.bvh,
            &config,
            &mut |step| match stop_after {
                Some(k) if step.index >= k => ControlFlow::Break(()),
                _ => ControlFlow::Continue(()),
            },
        )?)
    }

    /// Shoots with `config` (stopped after wave `stop_after` if given) and gathers once from
    /// the result without and with the ambient term; two rows.
    fn measure(
        &self,
        sweep: Sweep,
        seed: u64,
        config: &ScheduleConfig,
        stop_after: Option<u32>,
    ) -> Result<[Row; 2]> {
        let row = |with: bool| -> Result<Row> {
            let shooting = self.shoot(config, stop_after, with)?;
            // The gathering's rays depend on the seed only: the same rays gather from every
            // snapshot, with and without the term (common random numbers), so the curves differ
            // by their input, not by the gathering's noise.
            let round = gather_from(
                &self.mesh,
                &self.bvh,
                shooting.estimate.radiosity(),
                GATHER_RAYS,
                seed,
                Sampler::Random,
            )?;
            let b = round.radiosity();
            Ok(Row {
                sweep,
                shooting_rays: shooting.estimate.rays(),
                budget: config.rays,
                waves: shooting.steps,
                ambient: with,
                seed,
                rms_rel: self.exact.rms_rel(b),
                reflected_ratio: reflected(&self.mesh, b) / self.exact_reflected,
                unshot: shooting.unshot_fraction,
            })
        };
        Ok([row(false)?, row(true)?])
    }
}

/// Runs Figure 2 from the workspace `root` and writes docs/figure2.csv and docs/figure2.png.
pub fn figure2(root: &Path) -> Result<()> {
    let start = Instant::now();
    let scene_path = root.join("scenes/cornell-box.obj");
    let scene = mcrad_scene_io::load(&scene_path)
        .with_context(|| format!("could not load {}", scene_path.display()))?
        .scene;
    let mesh = Mesh::build(&scene, Subdivision::None)?;
    let bvh = mesh.caster()?;
    let reference = reference(&mesh, &bvh, &ReferenceConfig::default(), &|_| {})?;
    let exact = reference.estimate.radiosity().to_vec();
    let setup = Setup {
        exact_reflected: reflected(&mesh, &exact),
        exact: Reference::new(&mesh, exact)?,
        mesh,
        bvh,
    };
    eprintln!(
        "cornell-box: {} patches; reference solution in {:.1} s (residual {:.1e})",
        setup.mesh.patches().len(),
        start.elapsed().as_secs_f64(),
        reference.stats.residual
    );

    let mut rows = Vec::new();
    for seed in 0..SEEDS {
        // The refining run is deterministic per seed: stopping it after wave k gives exactly
        // its state at that point, so each snapshot reruns it up to there.
        let config = ScheduleConfig {
            rays: REFINING_BUDGET,
            unshot_threshold: 0.0,
            seed,
            ..Default::default()
        };
        for k in 1..=REFINING_WAVES {
            rows.extend(setup.measure(Sweep::Refining, seed, &config, Some(k))?);
        }
        for &budget in &BUDGETS {
            let config = ScheduleConfig {
                rays: budget,
                unshot_threshold: UNSHOT_THRESHOLD,
                seed,
                ..Default::default()
            };
            rows.extend(setup.measure(Sweep::Budgets, seed, &config, None)?);
        }
    }
    let docs = root.join("docs");
    std::fs::create_dir_all(&docs)?;
    write_csv(&docs.join("figure2.csv"), &rows)?;
    plots(&docs, &rows)?;
    println!("{}", table(&rows, Sweep::Refining));
    println!("{}", table(&rows, Sweep::Budgets));
    eprintln!(
        "figure2: {} points × {SEEDS} seeds, {GATHER_RAYS} gathering rays per patch, in {:.1} s; \
         wrote docs/figure2.csv, docs/figure2.png, docs/figure2-reflected.png, \
         docs/figure2-budgets.png",
        rows.len() as u64 / SEEDS,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

fn write_csv(path: &Path, rows: &[Row]) -> Result<()> {
    let mut csv = String::from(
        "shooting_rays,ambient,seed,rms_rel,reflected_ratio,sweep,budget,waves,unshot_fraction\n",
    );
    for r in rows {
        writeln!(
            csv,
            "{},{},{},{:.6},{:.6},{},{},{},{:.6}",
            r.shooting_rays,
            r.ambient,
            r.seed,
            r.rms_rel,
            r.reflected_ratio,
            r.sweep.name(),
            r.budget,
            r.waves,
            r.unshot
        )?;
    }
    std::fs::write(path, csv).with_context(|| format!("could not write {}", path.display()))
}

/// The points of a sweep, in order: (budget, waves) of each, seeds and ambient aside.
fn points(rows: &[Row], sweep: Sweep) -> Vec<(u64, u32)> {
    let mut keys: Vec<(u64, u32)> = Vec::new();
    for r in rows.iter().filter(|r| r.sweep == sweep) {
        let key = match sweep {
            Sweep::Refining => (r.budget, r.waves),
            Sweep::Budgets => (r.budget, 0),
        };
        if !keys.contains(&key) {
            keys.push(key);
        }
    }
    keys
}

/// Mean, minimum and maximum of `value` over the seeds of one point and ambient setting.
fn stats(
    rows: &[Row],
    sweep: Sweep,
    key: (u64, u32),
    ambient: bool,
    value: impl Fn(&Row) -> f64,
) -> (f64, f64, f64) {
    let v: Vec<f64> = rows
        .iter()
        .filter(|r| r.sweep == sweep && r.ambient == ambient && r.budget == key.0)
        .filter(|r| sweep == Sweep::Budgets || r.waves == key.1)
        .map(value)
        .collect();
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (mean, lo, hi)
}

/// One curve of a sweep: x and y are seed means, the band spans the seeds' min to max of y.
fn series(
    rows: &[Row],
    sweep: Sweep,
    ambient: bool,
    x: fn(&Row) -> f64,
    y: fn(&Row) -> f64,
) -> Series {
    let s: Vec<(f64, (f64, f64, f64))> = points(rows, sweep)
        .into_iter()
        .map(|key| {
            let xm = stats(rows, sweep, key, ambient, x).0;
            (xm, stats(rows, sweep, key, ambient, y))
        })
        .collect();
    Series {
        name: format!(
            "{} ambient term (mean; band: min-max of {SEEDS} seeds)",
            if ambient { "with" } else { "without" }
        ),
        points: s.iter().map(|&(x, (m, _, _))| (x, m)).collect(),
        band: Some(s.iter().map(|&(x, (_, lo, hi))| (x, lo, hi)).collect()),
    }
}

fn plots(docs: &Path, rows: &[Row]) -> Result<()> {
    let unshot_pct = |r: &Row| 100.0 * r.unshot;
    let rays = |r: &Row| r.shooting_rays as f64;
    let rms = |r: &Row| r.rms_rel;
    let refl = |r: &Row| r.reflected_ratio;
    let both = |sweep, x, y| {
        vec![
            series(rows, sweep, false, x, y),
            series(rows, sweep, true, x, y),
        ]
    };
    let unshot_label = "power left unshot by the shooting when gathering starts (% of emitted)";
    line_plot(
        &docs.join("figure2.png"),
        &PlotSpec {
            title: format!(
                "Cornell box: one gathering round ({GATHER_RAYS} rays/patch) from refining shooting"
            ),
            x_label: unshot_label.into(),
            y_label: "rms_rel of the gathered solution".into(),
            log_x: true,
            log_y: true,
            series: both(Sweep::Refining, unshot_pct, rms),
        },
    )?;
    line_plot(
        &docs.join("figure2-reflected.png"),
        &PlotSpec {
            title: "Reflected power of the gathered solution / the reference's".into(),
            x_label: unshot_label.into(),
            y_label: "reflected power ratio".into(),
            log_x: true,
            log_y: false,
            series: both(Sweep::Refining, unshot_pct, refl),
        },
    )?;
    line_plot(
        &docs.join("figure2-budgets.png"),
        &PlotSpec {
            title: format!(
                "Complete shooting runs (stop at 1% unshot), then gathering ({GATHER_RAYS} rays/patch)"
            ),
            x_label: "shooting rays cast".into(),
            y_label: "rms_rel of the gathered solution".into(),
            log_x: true,
            log_y: true,
            series: both(Sweep::Budgets, rays, rms),
        },
    )?;
    Ok(())
}

/// A Markdown table of one sweep: per point the shooting rays and unshot power (seed means) and
/// both settings' rms_rel and reflected-power ratio, as mean (min–max over the seeds).
fn table(rows: &[Row], sweep: Sweep) -> String {
    let first = match sweep {
        Sweep::Refining => "| waves ",
        Sweep::Budgets => "| budget ",
    };
    let mut t = format!(
        "{first}| shooting rays | unshot left | rms_rel without | rms_rel with | \
         reflected without | reflected with |\n|---:|---:|---:|---:|---:|---:|---:|\n"
    );
    let cell = |(m, lo, hi): (f64, f64, f64)| format!("{m:.3} ({lo:.3}–{hi:.3})");
    for key in points(rows, sweep) {
        let mean = |f: fn(&Row) -> f64| stats(rows, sweep, key, false, f).0;
        let first = match sweep {
            Sweep::Refining => key.1.to_string(),
            Sweep::Budgets => key.0.to_string(),
        };
        let _ = writeln!(
            t,
            "| {first} | {:.0} | {:.2}% | {} | {} | {} | {} |",
            mean(|r| r.shooting_rays as f64),
            100.0 * mean(|r| r.unshot),
            cell(stats(rows, sweep, key, false, |r| r.rms_rel)),
            cell(stats(rows, sweep, key, true, |r| r.rms_rel)),
            cell(stats(rows, sweep, key, false, |r| r.reflected_ratio)),
            cell(stats(rows, sweep, key, true, |r| r.reflected_ratio)),
        );
    }
    t
}
