//! `cargo xtask experiment speed-vs-error [--quick] [--seeds N] [--scenes a,b] [--methods m,n]
//! [--time S] [--target E] [--sampler random|qmc] [--control-variate off|constant] [--out DIR]`: every Monte Carlo method of the registry (`Method::monte_carlo`) on every experiment scene
//! ([`scenes::SCENES`]), several seeds, error (`rms_rel` against the scene's reference solution)
//! against wall-clock time.
//!
//! Writes `DIR/speed-vs-error.csv` (scene, method, seed, seconds, rays, rms_rel: one row per
//! point), `DIR/speed-vs-error-<scene>.png` (log-log, one curve per method: the median over
//! the seeds with their min-max band) and `DIR/results.md` (setup, the per-scene table of the
//! median time to reach 5%, 2% and 1% rms_rel and rays/s, the plots). `DIR` is `docs/`, or
//! `target/speed-vs-error-quick/` with `--quick` (one seed, 1 s per curve: a check that
//! everything runs, in about two minutes).
//!
//! How each method is measured: [`measure`]. References: `scenes/reference/cornell-box-2k.csv`
//! (reference solver, visibility tolerance 5e-4, from `mcrad solve scenes/cornell-box.obj
//! --method reference --max-edge 0.033 --visibility-tolerance 5e-4 --patches F`); the others
//! by `cargo xtask gen-references` (the reference solver at each scene's visibility
//! tolerance; the 20k Cornell box, beyond the solver's 10k patches, by the mean of two shooting
//! runs of 3e8 rays: see [`scenes::Made`]).

pub mod measure;
pub mod report;
mod results;
pub mod scenes;

use anyhow::{Context, Result, bail};
use mcrad_mc_radiosity::{ControlVariate, Method, Sampler};
use measure::{Limits, Point, Problem, curve};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The run's settings.
pub struct Options {
    /// Seeds `0..seeds`.
    pub seeds: u64,
    /// When a curve stops.
    pub limits: Limits,
    /// Scenes (names of [`scenes::SCENES`]).
    pub scenes: Vec<&'static scenes::ExpScene>,
    /// Methods.
    pub methods: Vec<Method>,
    /// Output directory.
    pub out: PathBuf,
    /// How the runs draw their rays (`--sampler`, default the library's).
    pub sampler: Sampler,
    /// The control variate of patch gathering (`--control-variate`, default the library's).
    pub control_variate: ControlVariate,
}

/// The arguments of `cargo xtask experiment speed-vs-error`.
#[derive(Debug, Default, clap::Args)]
pub struct SpeedArgs {
    /// One seed, 1 s per curve, into target/speed-vs-error-quick/: a smoke run
    #[arg(long)]
    pub quick: bool,
    /// Seeds 0..N per scene and method [default: 3, 1 with --quick]
    #[arg(long, value_name = "N")]
    pub seeds: Option<u64>,
    /// Scenes, comma-separated [default: every experiment scene]
    #[arg(long, value_name = "a,b", value_delimiter = ',')]
    pub scenes: Vec<String>,
    /// Monte Carlo methods, comma-separated [default: all of them]
    #[arg(long, value_name = "m,n", value_delimiter = ',')]
    pub methods: Vec<Method>,
    /// Wall-clock seconds per curve [default: 12, 1 with --quick]
    #[arg(long, value_name = "S")]
    pub time: Option<f64>,
    /// The relative error a curve stops at
    #[arg(long, value_name = "E", default_value_t = 0.005)]
    pub target: f64,
    /// How the runs draw their rays [default: the library's]
    #[arg(long, value_name = "random|qmc")]
    pub sampler: Option<Sampler>,
    /// The control variate of patch gathering [default: the library's]
    #[arg(long, value_name = "off|constant")]
    pub control_variate: Option<ControlVariate>,
    /// Output directory [default: docs, target/speed-vs-error-quick with --quick]
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

impl Options {
    /// The settings `args` ask for (the arguments after `speed-vs-error`).
    pub fn parse(root: &Path, args: &SpeedArgs) -> Result<Options> {
        let quick = args.quick;
        let scenes = if args.scenes.is_empty() {
            scenes::SCENES.iter().collect()
        } else {
            args.scenes
                .iter()
                .map(|n| {
                    scenes::SCENES
                        .iter()
                        .find(|s| s.name == n)
                        .with_context(|| format!("unknown scene '{n}'"))
                })
                .collect::<Result<_>>()?
        };
        let methods = if args.methods.is_empty() {
            Method::monte_carlo().collect()
        } else {
            args.methods.clone()
        };
        if let Some(m) = methods
            .iter()
            .find(|m| !Method::monte_carlo().any(|mc| mc == **m))
        {
            bail!("unknown Monte Carlo method '{m}'");
        }
        let o = Options {
            seeds: args.seeds.unwrap_or(if quick { 1 } else { 3 }),
            limits: Limits {
                seconds: args.time.unwrap_or(if quick { 1.0 } else { 12.0 }),
                target: args.target,
                max_points: 24,
            },
            scenes,
            methods,
            out: args.out.clone().unwrap_or_else(|| {
                root.join(if quick {
                    "target/speed-vs-error-quick"
                } else {
                    "docs"
                })
            }),
            sampler: args.sampler.unwrap_or_default(),
            control_variate: args.control_variate.unwrap_or_default(),
        };
        if o.seeds == 0 {
            bail!("--seeds must be at least 1");
        }
        Ok(o)
    }
}

/// One scene's measurements.
pub struct SceneResult {
    /// The scene.
    pub scene: &'static scenes::ExpScene,
    /// Patches after meshing.
    pub patches: usize,
    /// Seconds to load, mesh and build the BVH.
    pub build_seconds: f64,
    /// Per method, per seed: the curve.
    pub curves: Vec<(Method, Vec<Vec<Point>>)>,
}

/// Runs the experiment and writes its outputs.
pub fn run(root: &Path, args: &SpeedArgs) -> Result<()> {
    let options = Options::parse(root, args)?;
    let start = Instant::now();
    let mut results = Vec::new();
    for scene in &options.scenes {
        results.push(measure_scene(root, scene, &options)?);
    }
    let minutes = start.elapsed().as_secs_f64() / 60.0;
    write_outputs(&options, &results, minutes)?;
    eprintln!(
        "speed-vs-error: {minutes:.1} min; wrote speed-vs-error.csv, the plots and results.md in {}",
        options.out.display()
    );
    Ok(())
}

/// Measures every method and seed on one scene, printing a line per curve.
pub fn measure_scene(
    root: &Path,
    scene: &'static scenes::ExpScene,
    options: &Options,
) -> Result<SceneResult> {
    let loaded = scene.load(root)?;
    let reference = scene.reference(root, &loaded.mesh)?;
    let mut problem = Problem::new(&loaded.mesh, &loaded.bvh, reference);
    problem.sampler = options.sampler;
    problem.control_variate = options.control_variate;
    eprintln!(
        "{}: {} patches, built in {:.2} s",
        scene.name,
        problem.mesh.patches().len(),
        loaded.build_seconds
    );
    let mut curves = Vec::new();
    for &method in &options.methods {
        let mut seeds = Vec::new();
        for seed in 0..options.seeds {
            let (points, errors) = curve(&problem, method, seed, &options.limits);
            for e in errors {
                eprintln!("  warning: {}: {e}", scene.name);
            }
            if let Some(last) = points.last() {
                eprintln!(
                    "  {:<22} seed {seed}: {:>2} points, {:>6.2} s, {:>6.1} Mrays, rms_rel {:.4}",
                    method.name(),
                    points.len(),
                    last.seconds,
                    last.rays as f64 / 1e6,
                    last.rms_rel
                );
            }
            seeds.push(points);
        }
        curves.push((method, seeds));
    }
    Ok(SceneResult {
        scene,
        patches: problem.mesh.patches().len(),
        build_seconds: loaded.build_seconds,
        curves,
    })
}

/// Writes the CSV, one plot per scene and results.md into `options.out`.
pub fn write_outputs(options: &Options, results: &[SceneResult], minutes: f64) -> Result<()> {
    std::fs::create_dir_all(&options.out)
        .with_context(|| format!("could not create {}", options.out.display()))?;
    let mut csv = String::from("scene,method,seed,seconds,rays,rms_rel\n");
    for r in results {
        for (method, seeds) in &r.curves {
            for (seed, points) in seeds.iter().enumerate() {
                for p in points {
                    writeln!(
                        csv,
                        "{},{},{seed},{:.6},{},{:.6e}",
                        r.scene.name,
                        method.name(),
                        p.seconds,
                        p.rays,
                        p.rms_rel
                    )?;
                }
            }
        }
    }
    let path = options.out.join("speed-vs-error.csv");
    std::fs::write(&path, csv).with_context(|| format!("could not write {}", path.display()))?;
    for r in results {
        let methods: Vec<(&str, &[Vec<Point>])> = r
            .curves
            .iter()
            .map(|(m, c)| (m.name(), c.as_slice()))
            .collect();
        report::plot(
            &options
                .out
                .join(format!("speed-vs-error-{}.png", r.scene.name)),
            &format!("{}: {} patches", r.scene.name, r.patches),
            options.seeds as usize,
            &methods,
        )?;
    }
    let path = options.out.join("results.md");
    std::fs::write(&path, results::markdown(options, results, minutes))
        .with_context(|| format!("could not write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Cornell box at one patch per face, against its 19-patch reference.
    static TINY: scenes::ExpScene = scenes::ExpScene {
        name: "cornell-faces",
        file: "cornell-box.obj",
        max_edge: None,
        reference: "cornell-box-faces.csv",
        how: scenes::Made::Solver {
            visibility_tolerance: 1e-4,
        },
        what: "the Cornell box, one patch per face",
    };

    #[test]
    fn a_tiny_run_measures_every_method_and_writes_every_output() {
        let dir = tempfile::tempdir().unwrap();
        let options = Options {
            seeds: 2,
            limits: Limits {
                seconds: 0.05,
                target: 0.005,
                max_points: 3,
            },
            scenes: vec![&TINY],
            methods: Method::monte_carlo().collect(),
            out: dir.path().to_path_buf(),
            sampler: Sampler::Qmc,
            control_variate: ControlVariate::Constant,
        };
        let result = measure_scene(&crate::root(), &TINY, &options).unwrap();
        for (method, seeds) in &result.curves {
            assert_eq!(seeds.len(), 2);
            for points in seeds {
                assert!(!points.is_empty(), "{} has no point", method.name());
                // Rays, not seconds: a ladder's rungs are separate runs, and on a loaded machine
                // a bigger rung can take less wall-clock time than the one before.
                assert!(points.windows(2).all(|w| w[0].rays < w[1].rays));
                assert!(points.iter().all(|p| p.seconds > 0.0));
                assert!(points.iter().all(|p| p.rms_rel > 0.0 && p.rms_rel < 1.0));
            }
        }
        write_outputs(&options, &[result], 0.0).unwrap();
        let csv = std::fs::read_to_string(dir.path().join("speed-vs-error.csv")).unwrap();
        let md = std::fs::read_to_string(dir.path().join("results.md")).unwrap();
        for m in Method::monte_carlo() {
            assert!(csv.contains(&format!("cornell-faces,{},1,", m.name())));
            assert!(md.contains(&format!("| `{}` |", m.name())), "{md}");
        }
        assert!(dir.path().join("speed-vs-error-cornell-faces.png").exists());
    }

    #[test]
    fn options_parse_and_reject_unknown_names() {
        let root = crate::root();
        /// The command line `s` after `speed-vs-error`.
        fn args(s: &str) -> Result<SpeedArgs, clap::Error> {
            #[derive(clap::Parser)]
            struct Line {
                #[command(flatten)]
                args: SpeedArgs,
            }
            <Line as clap::Parser>::try_parse_from(std::iter::once("x").chain(s.split(' ')))
                .map(|l| l.args)
        }
        let o = Options::parse(
            &root,
            &args("--quick --scenes cornell-2k --methods shoot,prr").unwrap(),
        )
        .unwrap();
        assert_eq!((o.seeds, o.scenes.len(), o.methods.len()), (1, 1, 2));
        assert!(Options::parse(&root, &args("--scenes nowhere").unwrap()).is_err());
        assert!(args("--methods teleport").is_err());
        assert!(Options::parse(&root, &args("--methods reference").unwrap()).is_err());
        assert!(args("--seeds").is_err());
    }
}
