//! The experiment's scenes and their reference solutions.

use anyhow::{Context, Result, bail};
use glam::DVec3;
use mcrad_mc_radiosity::reference::{ReferenceConfig, reference};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
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
    /// Visibility tolerance the reference was (or is) made with.
    pub visibility_tolerance: f64,
    /// One line for docs/results.md.
    pub what: &'static str,
}

/// Every scene, in report order.
pub const SCENES: [ExpScene; 4] = [
    ExpScene {
        name: "cornell-2k",
        file: "cornell-box.obj",
        max_edge: Some(0.033),
        reference: "cornell-box-2k.csv",
        visibility_tolerance: 5e-4,
        what: "the Cornell box at about 2k patches",
    },
    ExpScene {
        name: "cornell-20k",
        file: "cornell-box.obj",
        max_edge: Some(0.01),
        reference: "cornell-box-20k.csv",
        visibility_tolerance: 2e-3,
        what: "the Cornell box at about 20k patches",
    },
    ExpScene {
        name: "small-light",
        file: "cornell-small-light.obj",
        max_edge: Some(0.033),
        reference: "cornell-small-light-2k.csv",
        visibility_tolerance: 5e-4,
        what: "the Cornell box lit by a light of 1/16 the area and 16x the radiosity",
    },
    ExpScene {
        name: "boxes-room",
        file: "boxes-room.obj",
        max_edge: Some(0.15),
        reference: "boxes-room.csv",
        visibility_tolerance: 2e-3,
        what: "a room with a few hundred small boxes (many small patches), two ceiling lights",
    },
];

/// The largest mesh the references are made for (the solver's default stops at 10k; the
/// 20k Cornell box takes about 20 minutes and 7 GB).
pub const MAX_REFERENCE_PATCHES: usize = 25_000;

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
        let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())?;
        Ok(Loaded {
            mesh,
            bvh,
            build_seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// The reference radiosity in mesh order.
    pub fn reference(&self, root: &Path, mesh: &Mesh) -> Result<Vec<DVec3>> {
        let path = root.join("scenes/reference").join(self.reference);
        let rows = mcrad_export::read_patch_csv(&path).with_context(|| {
            format!(
                "no reference for {} (make it with `cargo xtask gen-references {}`)",
                self.name, self.name
            )
        })?;
        if rows.len() != mesh.patches().len() {
            bail!(
                "{} has {} rows but the mesh of {} has {} patches",
                path.display(),
                rows.len(),
                self.name,
                mesh.patches().len()
            );
        }
        Ok(rows.iter().map(|r| r.radiosity).collect())
    }
}

/// `cargo xtask gen-references [names]`: solves the named scenes (all but cornell-2k, which
/// has its own, if none are named) with the reference solver and writes their CSVs.
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
        eprintln!("{}: {n} patches, reference solver ...", s.name);
        let start = Instant::now();
        let done = AtomicUsize::new(0);
        let config = ReferenceConfig {
            max_patches: MAX_REFERENCE_PATCHES,
            visibility_tolerance: s.visibility_tolerance,
            ..ReferenceConfig::default()
        };
        let progress = |rows: usize| {
            let tenth = rows * 10 / n.max(1);
            if done.fetch_max(tenth, Ordering::Relaxed) < tenth {
                eprintln!(
                    "  {}0% of the form-factor rows, {:.0} s",
                    tenth,
                    start.elapsed().as_secs_f64()
                );
            }
        };
        let r = reference(&loaded.mesh, &loaded.bvh, &config, &progress)?;
        let path = root.join("scenes/reference").join(s.reference);
        let file = std::fs::File::create(&path)
            .with_context(|| format!("could not write {}", path.display()))?;
        let rows = r
            .estimate
            .radiosity()
            .iter()
            .zip(loaded.mesh.patches())
            .enumerate()
            .map(|(i, (b, p))| mcrad_export::PatchRow {
                patch: i as u32,
                area: p.area,
                radiosity: *b,
                variance: None,
            });
        mcrad_export::write_patch_csv(std::io::BufWriter::new(file), rows)?;
        eprintln!(
            "{}: wrote {} in {:.0} s (residual {:.1e})",
            s.name,
            path.display(),
            start.elapsed().as_secs_f64(),
            r.stats.residual
        );
    }
    Ok(())
}
