//! The state of a run that `--save` writes and `--resume` continues: the solution so far
//! (radiosity, variance, rays, per patch in mesh order) and what it must agree with to be
//! continued (the mesh's fingerprint, the method and its seed-independent options, the seed,
//! mcrad's version).
//!
//! **Why a continuation is an independent run.** A piece `p >= 1` of a run is a complete run of
//! its own budget with its own random streams, seeded by [`piece_seed`] (the run's seed and the
//! piece number, so no stream is used twice), and is merged with the saved solution by rays
//! ([`mcrad_combine::ByRays`]). Both are unbiased estimates of the same radiosity, the weights
//! `n_a / (n_a + n_b)` are fixed by the ray counts and do not read the values, so the merge is
//! unbiased; the ray counts add up. Nothing of the interrupted run's samplers has to be
//! restored, which is what keeps the state small and the format simple. ARCHITECTURE.md argues
//! per method why rays, not the estimates' own variances, are the weights.
//!
//! The file is CBOR (serde, `ciborium`): f64 values read back bit for bit. It is written to a
//! temporary file in the same folder and renamed over the old state, so a state on disk is
//! always a complete one, whenever the process stops.

use anyhow::{Context, Result, bail, ensure};
use glam::DVec3;
use mcrad_combine::{ByRays, Estimate, merge};
use mcrad_meshing::Mesh;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;

/// The version of the state's layout; a state of another layout is refused.
const FORMAT: u32 = 1;

/// Seed tag of the pieces of a resumed run (see [`piece_seed`]).
const PIECE_TAG: u64 = 0x7069_6563_6500_0000; // "piece"

/// The seed of piece `piece` of a run seeded `seed`: the seed itself for the first piece (so
/// `--save` does not change a run's answer), else one derived from the seed and the piece
/// number through `mcrad_random::derive_seed`, a stream family no other piece uses.
pub fn piece_seed(seed: u64, piece: u32) -> u64 {
    if piece == 0 {
        seed
    } else {
        mcrad_random::derive_seed(seed, PIECE_TAG + u64::from(piece))
    }
}

/// The options a state must agree on to be continued, besides the mesh and the seed: each a
/// name (`method`, `subdivision`, ...) and the option as the command line says it
/// (`--method prr`, `--max-edge 0.1`, ...).
pub type Options = Vec<(String, String)>;

/// A saved run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunState {
    /// [`FORMAT`] when written.
    format: u32,
    /// The `mcrad` version that wrote it.
    version: String,
    /// [`fingerprint`] of the mesh solved.
    fingerprint: u64,
    /// The scene file's name, for messages.
    scene: String,
    /// The seed of the run (piece `p` runs with [`piece_seed`]`(seed, p)`).
    pub seed: u64,
    /// What must agree to continue the run (see [`Options`]).
    options: Options,
    /// Pieces merged into this state: the next piece's number.
    pub pieces: u32,
    /// Steps taken over all pieces.
    pub steps: u32,
    /// Rays that hit nothing, over all pieces.
    pub escaped_rays: u64,
    /// Rays cast over all pieces (the estimate's work).
    pub rays: u64,
    /// The patch numbers written to `--patches` (mesh order; input faces with `--no-subdivide`).
    pub patch: Vec<u32>,
    /// Patch areas, scene units².
    pub area: Vec<f64>,
    /// Radiosity per patch and channel, W/m².
    radiosity: Vec<[f64; 3]>,
    /// Estimated variance per patch and channel, (W/m²)²; `None` where the method has none.
    variance: Option<Vec<[f64; 3]>>,
}

/// What a run knows about itself that its state records.
pub struct Identity<'a> {
    /// The scene file.
    pub scene: &'a Path,
    /// The mesh solved.
    pub mesh: &'a Mesh,
    /// The patch numbers of `--patches`, mesh order.
    pub patch: Vec<u32>,
    /// The run's seed.
    pub seed: u64,
    /// What must agree to continue it.
    pub options: Options,
}

impl RunState {
    /// The state of a run of `id` whose solution so far is `estimate`, after `pieces` pieces,
    /// `steps` steps and `escaped_rays` escaped rays.
    pub fn new(
        id: &Identity,
        estimate: &Estimate,
        pieces: u32,
        steps: u32,
        escaped_rays: u64,
    ) -> RunState {
        let arrays = |v: &[DVec3]| v.iter().map(|x| x.to_array()).collect();
        RunState {
            format: FORMAT,
            version: env!("CARGO_PKG_VERSION").to_string(),
            fingerprint: fingerprint(id.mesh),
            scene: id.scene.file_name().map_or_else(
                || id.scene.display().to_string(),
                |n| n.display().to_string(),
            ),
            seed: id.seed,
            options: id.options.clone(),
            pieces,
            steps,
            escaped_rays,
            rays: estimate.rays(),
            patch: id.patch.clone(),
            area: id.mesh.patches().iter().map(|p| p.area).collect(),
            radiosity: arrays(estimate.radiosity()),
            variance: estimate.variance().map(arrays),
        }
    }

    /// The saved solution.
    pub fn estimate(&self) -> Result<Estimate> {
        let vecs = |v: &[[f64; 3]]| v.iter().map(|&x| DVec3::from_array(x)).collect();
        Ok(Estimate::new(
            vecs(&self.radiosity),
            self.variance.as_deref().map(vecs),
            self.rays,
        )?)
    }

    /// The saved solution as the rows of a patch CSV.
    pub fn rows(&self) -> Vec<mcrad_export::PatchRow> {
        (0..self.patch.len())
            .map(|i| mcrad_export::PatchRow {
                patch: self.patch[i],
                area: self.area[i],
                radiosity: DVec3::from_array(self.radiosity[i]),
                variance: self.variance.as_ref().map(|v| DVec3::from_array(v[i])),
                // A state keeps patch numbers, not input faces.
                face: None,
            })
            .collect()
    }

    /// Reads a state written by [`RunState::save`].
    pub fn load(path: &Path) -> Result<RunState> {
        let file = std::fs::File::open(path)
            .with_context(|| format!("could not read the saved state {}", path.display()))?;
        let state: RunState =
            ciborium::from_reader(std::io::BufReader::new(file)).map_err(|e| match e {
                ciborium::de::Error::Io(e) => {
                    anyhow::anyhow!("could not read the saved state {}: {e}", path.display())
                }
                _ => anyhow::anyhow!(
                    "{} is not a state saved by mcrad --save (or it is damaged)",
                    path.display()
                ),
            })?;
        ensure!(
            state.format == FORMAT,
            "{} has state format {}, this mcrad reads format {FORMAT}",
            path.display(),
            state.format
        );
        let n = state.patch.len();
        ensure!(
            state.area.len() == n
                && state.radiosity.len() == n
                && state.variance.as_ref().is_none_or(|v| v.len() == n),
            "{} is damaged: its per-patch lists differ in length",
            path.display()
        );
        Ok(state)
    }

    /// Writes the state atomically: to a temporary file in `path`'s folder, flushed to disk,
    /// then renamed over `path`.
    pub fn save(&self, path: &Path) -> Result<()> {
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let fail = || format!("could not write the state {}", path.display());
        let mut builder = tempfile::Builder::new();
        // A temporary file is private (0600); the state is an ordinary file (0666 less the
        // umask, as `File::create` makes it), readable where the outputs are.
        #[cfg(unix)]
        builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
        let mut tmp = builder
            .prefix(".mcrad-state")
            .tempfile_in(dir)
            .with_context(fail)?;
        {
            let mut out = std::io::BufWriter::new(tmp.as_file_mut());
            ciborium::into_writer(self, &mut out).with_context(fail)?;
            out.flush().with_context(fail)?;
        }
        tmp.as_file().sync_all().with_context(fail)?;
        tmp.persist(path).map_err(|e| e.error).with_context(fail)?;
        Ok(())
    }

    /// Checks that this state can be continued by the run `id` (same mcrad version, mesh,
    /// options and seed); the error names what differs. `path` is the state's file.
    pub fn check_continues(&self, id: &Identity, path: &Path) -> Result<()> {
        let file = path.display();
        let version = env!("CARGO_PKG_VERSION");
        ensure!(
            self.version == version,
            "{file} was saved by mcrad {}, this is mcrad {version}: a run can only be continued \
             by the version that started it",
            self.version
        );
        for (what, saved) in &self.options {
            let now = id.options.iter().find(|(w, _)| w == what).map(|(_, v)| v);
            if now != Some(saved) {
                bail!(
                    "{file} was saved with {saved}, this run has {}: resume with the {what} of \
                     the saved run",
                    now.map_or("none", String::as_str)
                );
            }
        }
        ensure!(
            self.fingerprint == fingerprint(id.mesh) && self.patch == id.patch,
            "{file} was saved for another scene or mesh ({}, {} patches; this run: {}, {} \
             patches): resume with the scene file and mesh options of the saved run",
            self.scene,
            self.patch.len(),
            id.scene.display(),
            id.mesh.patches().len()
        );
        ensure!(
            self.seed == id.seed,
            "{file} was saved with --seed {}, this run has --seed {}: resume with the seed of the \
             saved run (each piece derives its own random streams from it)",
            self.seed,
            id.seed
        );
        Ok(())
    }

    /// This state with `piece`, the solution of the next piece (an independent run), merged in
    /// by rays: the state after one more piece.
    pub fn continued(&self, piece: &Estimate, steps: u32, escaped_rays: u64) -> Result<RunState> {
        let merged = merge(&self.estimate()?, piece, &ByRays)
            .context("the saved solution and the new piece do not merge")?;
        let arrays = |v: &[DVec3]| v.iter().map(|x| x.to_array()).collect();
        Ok(RunState {
            pieces: self.pieces + 1,
            steps: self.steps + steps,
            escaped_rays: self.escaped_rays + escaped_rays,
            rays: merged.rays(),
            radiosity: arrays(merged.radiosity()),
            variance: merged.variance().map(arrays),
            ..self.clone()
        })
    }
}

/// A 64-bit FNV-1a hash of what a solution depends on in the mesh: every patch's area,
/// reflectance, emission and input face, the mesh's local origin (when not zero) and every triangle's corners
/// (relative to it), as their bit patterns.
/// Two meshes with the same fingerprint solve the same problem (up to a 2^-64 collision); any
/// change of the scene file, its materials or the mesh options changes it.
pub fn fingerprint(mesh: &Mesh) -> u64 {
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0100_0000_01b3;
    let mut h = OFFSET;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h = (h ^ u64::from(b)).wrapping_mul(PRIME);
        }
    };
    eat(&(mesh.patches().len() as u64).to_le_bytes());
    if mesh.origin() != glam::Vec3::ZERO {
        // (a mesh around the world origin keeps the fingerprint states saved before had)
        for x in mesh.origin().to_array() {
            eat(&x.to_le_bytes());
        }
    }
    for p in mesh.patches() {
        eat(&p.area.to_le_bytes());
        for v in [p.reflectance, p.emission] {
            for x in v.to_array() {
                eat(&x.to_le_bytes());
            }
        }
        eat(&p.face.to_le_bytes());
    }
    for t in mesh.triangle_positions() {
        for corner in t {
            for x in corner.to_array() {
                eat(&x.to_le_bytes());
            }
        }
    }
    h
}
