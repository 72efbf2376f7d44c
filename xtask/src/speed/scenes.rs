//! The experiment's scenes and their reference solutions.

use anyhow::{Context, Result};
use glam::DVec3;
use mcrad_lab::trace::{Numbering, Reference};
use mcrad_mc_radiosity::{Method, ScheduleConfig, run};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use mcrad_reference::{ReferenceConfig, reference};
use std::ops::ControlFlow;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

/// One scene of the experiment.
pub struct ExpScene {
    /// Short name: CSV column, plot file `docs/speed-vs-error-<name>.png`, `--scenes`.
    pub name: &'static str,
    /// Scene file under `scenes/`.
    pub file: &'static str,
    /// Subdivision: no patch edge longer than this (m); `None`: one patch per face.
    pub max_edge: Option<f32>,
    /// Reference solution under `scenes/reference/` (patch CSV in mesh order).
    pub reference: &'static str,
    /// How the reference is made.
    pub how: Made,
    /// One line for docs/results.md.
    pub what: &'static str,
}

/// How a reference solution is made.
#[derive(Debug, Clone, Copy)]
pub enum Made {
    /// The deterministic reference solver at this visibility tolerance (its quadrature and
    /// residual at their defaults).
    Solver {
        /// Visibility error per row relative to the row sum (one standard deviation).
        visibility_tolerance: f64,
    },
    /// Too big for the reference solver: the mean of two shooting runs of `rays` rays each
    /// (unshot threshold 1e-5) with `seeds`, seeds no experiment run uses.
    Shooting {
        /// Rays per run.
        rays: u64,
        /// The runs' seeds.
        seeds: [u64; 2],
        /// The mean's own rms_rel noise, `rms_rel(run 1, run 2) / 2` (printed by
        /// `gen-references`, recorded here).
        noise: f64,
    },
}

impl Made {
    /// One line for results.md.
    pub fn describe(&self) -> String {
        match *self {
            Made::Solver {
                visibility_tolerance,
            } => format!("reference solver, visibility tolerance {visibility_tolerance:e}"),
            Made::Shooting { rays, seeds, noise } => format!(
                "mean of two shooting runs of {:.0e} rays (seeds {} and {}, unshot threshold \
                 1e-5); its own noise: {:.2}% rms_rel",
                rays as f64,
                seeds[0],
                seeds[1],
                100.0 * noise
            ),
        }
    }
}

/// The noise of the 20k Cornell reference, from `cargo xtask gen-references cornell-20k`.
pub const CORNELL_20K_NOISE: f64 = 0.0051;

/// Every scene, in report order.
pub const SCENES: [ExpScene; 4] = [
    ExpScene {
        name: "cornell-2k",
        file: "cornell-box.obj",
        max_edge: Some(0.033),
        reference: "cornell-box-2k.csv",
        how: Made::Solver {
            visibility_tolerance: 5e-4,
        },
        what: "the Cornell box at about 2k patches",
    },
    ExpScene {
        name: "cornell-20k",
        file: "cornell-box.obj",
        max_edge: Some(0.01),
        reference: "cornell-box-20k.csv",
        how: Made::Shooting {
            rays: 300_000_000,
            seeds: [1_000_000, 1_000_001],
            noise: CORNELL_20K_NOISE,
        },
        what: "the Cornell box at about 20k patches",
    },
    ExpScene {
        name: "small-light",
        file: "cornell-small-light.obj",
        max_edge: Some(0.033),
        reference: "cornell-small-light-2k.csv",
        how: Made::Solver {
            visibility_tolerance: 5e-4,
        },
        what: "the Cornell box lit by a light of 1/16 the area and 16x the radiosity",
    },
    ExpScene {
        name: "boxes-room",
        file: "boxes-room.obj",
        max_edge: Some(0.15),
        reference: "boxes-room.csv",
        how: Made::Solver {
            visibility_tolerance: 2e-3,
        },
        what: "a room with a few hundred small boxes (many small patches), two ceiling lights",
    },
];

/// A loaded scene: mesh, BVH and the reference.
pub struct Loaded {
    /// The subdivided mesh.
    pub mesh: Mesh,
    /// Its BVH.
    pub bvh: Bvh,
    /// Seconds to load, mesh and build the BVH.
    pub build_seconds: f64,
}

impl ExpScene {
    /// Loads and meshes the scene and builds its BVH.
    pub fn load(&self, root: &Path) -> Result<Loaded> {
        let start = Instant::now();
        let path = root.join("scenes").join(self.file);
        let scene = mcrad_scene_io::load(&path)
            .with_context(|| format!("could not load {}", path.display()))?
            .scene;
        let subdivision = self
            .max_edge
            .map_or(Subdivision::None, Subdivision::MaxEdge);
        let mesh = Mesh::build(&scene, subdivision)?;
        let bvh = mesh.caster()?;
        Ok(Loaded {
            mesh,
            bvh,
            build_seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// The reference solution of `mesh` (its CSV's rows numbered in mesh order).
    pub fn reference(&self, root: &Path, mesh: &Mesh) -> Result<Reference> {
        let path = root.join("scenes/reference").join(self.reference);
        let rows = mcrad_export::read_patch_csv(&path).with_context(|| {
            format!(
                "no reference for {} (make it with `cargo xtask gen-references {}`)",
                self.name, self.name
            )
        })?;
        Reference::from_rows(mesh, &rows, Numbering::Index)
            .with_context(|| format!("{} against the mesh of {}", path.display(), self.name))
    }
}

/// `cargo xtask gen-references [names]`: makes the references of the named scenes (all but
/// cornell-2k, which has its own, if none are named) as their [`Made`] says and writes their
/// CSVs (a few minutes each for the solver; about 15 minutes on 2 cores for the 20k box).
pub fn generate(root: &Path, names: &[String]) -> Result<()> {
    for s in SCENES.iter().filter(|s| {
        if names.is_empty() {
            s.name != "cornell-2k"
        } else {
            names.iter().any(|n| n == s.name)
        }
    }) {
        let loaded = s.load(root)?;
        let n = loaded.mesh.patches().len();
        let start = Instant::now();
        eprintln!("{}: {n} patches, {} ...", s.name, s.how.describe());
        let radiosity = match s.how {
            Made::Solver {
                visibility_tolerance,
            } => solver(&loaded, visibility_tolerance)?,
            Made::Shooting { rays, seeds, .. } => shooting(&loaded, rays, seeds)?,
        };
        let path = root.join("scenes/reference").join(s.reference);
        let file = std::fs::File::create(&path)
            .with_context(|| format!("could not write {}", path.display()))?;
        let rows = radiosity
            .iter()
            .zip(loaded.mesh.patches())
            .enumerate()
            .map(|(i, (b, p))| mcrad_export::PatchRow {
                patch: i as u32,
                area: p.area,
                radiosity: *b,
                variance: None,
                face: None,
            });
        mcrad_export::write_patch_csv(std::io::BufWriter::new(file), rows)?;
        eprintln!(
            "{}: wrote {} in {:.0} s",
            s.name,
            path.display(),
            start.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

/// The reference solver's solution, printing progress by tenths of the rows.
fn solver(loaded: &Loaded, visibility_tolerance: f64) -> Result<Vec<DVec3>> {
    let n = loaded.mesh.patches().len();
    let start = Instant::now();
    let done = AtomicUsize::new(0);
    let config = ReferenceConfig {
        visibility_tolerance,
        ..ReferenceConfig::default()
    };
    let progress = |rows: usize| {
        let tenth = rows * 10 / n.max(1);
        if done.fetch_max(tenth, Ordering::Relaxed) < tenth {
            eprintln!(
                "  {tenth}0% of the form-factor rows, {:.0} s",
                start.elapsed().as_secs_f64()
            );
        }
    };
    let r = reference(&loaded.mesh, &loaded.bvh, &config, &progress)?;
    eprintln!("  residual {:.1e}", r.stats.residual);
    Ok(r.estimate.radiosity().to_vec())
}

/// The mean of two shooting runs; prints its noise estimate `rms_rel(a, b) / 2` (the
/// difference of two runs has twice a run's variance, the mean half of it).
fn shooting(loaded: &Loaded, rays: u64, seeds: [u64; 2]) -> Result<Vec<DVec3>> {
    let mut runs = Vec::new();
    for seed in seeds {
        let config = ScheduleConfig {
            rays,
            seed,
            unshot_threshold: 1e-5,
            ambient: false,
            first_pass_rays: None,
            ..Default::default()
        };
        let s = run(
            Method::Shoot,
            &loaded.mesh,
            &loaded.bvh,
            &config,
            &mut |_| ControlFlow::Continue(()),
        )?;
        runs.push(s.estimate.radiosity().to_vec());
    }
    let mean: Vec<DVec3> = runs[0]
        .iter()
        .zip(&runs[1])
        .map(|(a, b)| 0.5 * (a + b))
        .collect();
    // rms_rel of run a against run b, with the mean's reflected light as the denominator.
    let diff: Vec<DVec3> = runs[0]
        .iter()
        .zip(&runs[1])
        .zip(&mean)
        .map(|((a, b), m)| m + (a - b))
        .collect();
    let noise = Reference::new(&loaded.mesh, mean.clone())?.rms_rel(&diff) / 2.0;
    eprintln!("  the mean's own noise: {:.3}% rms_rel", 100.0 * noise);
    Ok(mean)
}
