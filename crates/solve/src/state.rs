//! The state of a run, to save and continue: the solution so far (radiosity, variance, rays per
//! patch in mesh order), the settings and the mesh that made it.
//!
//! **Why a continuation is an independent run.** A piece `p >= 1` of a run is a complete run of
//! its own budget with its own random streams, seeded by [`piece_seed`] (the run's seed and the
//! piece number, so no stream is used twice), and is merged with the saved solution by rays
//! ([`mcrad_combine::ByRays`]). Both are unbiased estimates of the same radiosity and the
//! weights `n_a / (n_a + n_b)` are fixed by the work, not read from the values, so the merge is
//! unbiased; the ray counts add up. Nothing of the interrupted run's samplers has to be
//! restored, which keeps the state small and its format simple.
//!
//! An adaptive mesh is saved as its [`History`] (its start and the leaves each refinement
//! split) and made anew from the scene on resuming; the mesh's fingerprint, saved too, proves
//! it is the same mesh. The format is CBOR (serde, `ciborium`): f64 values read back bit for
//! bit.

use crate::{Error, MeshPlan, Settings};
use glam::DVec3;
use mcrad_combine::{ByRays, Estimate, merge};
use mcrad_mc_radiosity::{ControlVariate, Method, Sampler};
use mcrad_meshing::{History, Mesh};
use serde::{Deserialize, Serialize};
use std::io::{Read, Write};

/// The version of the state's layout; a state of another layout is refused.
const FORMAT: u32 = 3;

/// Seed tag of the pieces of a resumed run (see [`piece_seed`]).
const PIECE_TAG: u64 = 0x7069_6563_6500_0000; // "piece"

/// The seed of piece `piece` of a run seeded `seed`: the seed itself for the first piece (so
/// saving a run does not change its answer), else one derived from the seed and the piece
/// number through `mcrad_random::derive_seed`, a stream family no other piece uses.
pub fn piece_seed(seed: u64, piece: u32) -> u64 {
    if piece == 0 {
        seed
    } else {
        mcrad_random::derive_seed(seed, PIECE_TAG + u64::from(piece))
    }
}

/// A saved run: what [`crate::Problem::resume`] continues.
///
/// Invariants: the per-patch lists have one entry per patch of the mesh whose fingerprint it
/// holds; radiosity in W/m², variance in (W/m²)².
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunState {
    /// [`FORMAT`] when written.
    format: u32,
    /// The mcrad version that wrote it.
    version: String,
    /// [`fingerprint`] of the mesh solved.
    fingerprint: u64,
    /// [`lighting_fingerprint`] of the lights and sky the run was lit by.
    lighting: u64,
    /// The settings of the run.
    settings: SavedSettings,
    /// How the adaptive mesh was made (`None` for the other plans).
    history: Option<SavedHistory>,
    /// Pieces merged into this state: the next piece's number.
    pieces: u32,
    /// Steps taken over all pieces.
    steps: u32,
    /// Rays that hit nothing, over all pieces.
    escaped_rays: u64,
    /// Rays cast over all pieces (the estimate's work).
    rays: u64,
    /// The patch numbers of the answer (mesh order; input faces for one patch per face).
    patch: Vec<u32>,
    /// Patch areas, scene units².
    area: Vec<f64>,
    /// Radiosity per patch and channel, W/m².
    radiosity: Vec<[f64; 3]>,
    /// Estimated variance per patch and channel, (W/m²)²; `None` where the method has none.
    variance: Option<Vec<[f64; 3]>>,
}

/// [`Settings`] by name, as saved.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct SavedSettings {
    method: String,
    mesh: MeshPlan,
    seed: u64,
    sampler: String,
    control_variate: String,
    ambient: bool,
    unshot_threshold: f64,
    visibility_tolerance: f64,
}

/// [`History`] as saved.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct SavedHistory {
    start: Option<f32>,
    splits: Vec<Vec<u32>>,
}

impl From<&Settings> for SavedSettings {
    fn from(s: &Settings) -> Self {
        SavedSettings {
            method: s.method.name().to_string(),
            mesh: s.mesh,
            seed: s.seed,
            sampler: s.sampler.name().to_string(),
            control_variate: s.control_variate.name().to_string(),
            ambient: s.ambient,
            unshot_threshold: s.unshot_threshold,
            visibility_tolerance: s.visibility_tolerance,
        }
    }
}

impl SavedSettings {
    /// The settings, or `None` when a name is not one this mcrad knows.
    fn settings(&self) -> Option<Settings> {
        Some(Settings {
            method: self.method.parse::<Method>().ok()?,
            mesh: self.mesh,
            seed: self.seed,
            sampler: [Sampler::Random, Sampler::Qmc]
                .into_iter()
                .find(|s| s.name() == self.sampler)?,
            control_variate: [ControlVariate::Off, ControlVariate::Constant]
                .into_iter()
                .find(|c| c.name() == self.control_variate)?,
            ambient: self.ambient,
            unshot_threshold: self.unshot_threshold,
            visibility_tolerance: self.visibility_tolerance,
        })
    }
}

/// What a run knows of itself that its state records.
pub(crate) struct Identity<'a> {
    pub mesh: &'a Mesh,
    pub history: Option<&'a History>,
    pub settings: &'a Settings,
    pub patch: &'a [u32],
    /// [`lighting_fingerprint`] of the run's lights and sky.
    pub lighting: u64,
}

impl RunState {
    /// The state of the run `id` whose solution so far is `estimate`, after `pieces` pieces,
    /// `steps` steps and `escaped_rays` escaped rays.
    pub(crate) fn new(
        id: &Identity,
        estimate: &Estimate,
        pieces: u32,
        steps: u32,
        escaped_rays: u64,
    ) -> RunState {
        RunState {
            format: FORMAT,
            version: env!("CARGO_PKG_VERSION").to_string(),
            fingerprint: fingerprint(id.mesh),
            lighting: id.lighting,
            settings: id.settings.into(),
            history: id.history.map(|h| SavedHistory {
                start: h.start,
                splits: h.splits.clone(),
            }),
            pieces,
            steps,
            escaped_rays,
            rays: estimate.rays(),
            patch: id.patch.to_vec(),
            area: id.mesh.patches().iter().map(|p| p.area).collect(),
            radiosity: arrays(estimate.radiosity()),
            variance: estimate.variance().map(arrays),
        }
    }

    /// The saved solution: radiosity (W/m²), its variance where known, and the rays of all
    /// pieces.
    pub fn estimate(&self) -> Result<Estimate, Error> {
        let vecs = |v: &[[f64; 3]]| v.iter().map(|&x| DVec3::from_array(x)).collect();
        Ok(Estimate::new(
            vecs(&self.radiosity),
            self.variance.as_deref().map(vecs),
            self.rays,
        )?)
    }

    /// The settings of the saved run (a continuation runs with them).
    pub fn settings(&self) -> Settings {
        // checked when read
        self.settings.settings().unwrap_or_default()
    }

    /// The recorded adaptive mesh, for the plan [`MeshPlan::Adaptive`].
    pub(crate) fn history(&self) -> Option<History> {
        self.history.as_ref().map(|h| History {
            start: h.start,
            splits: h.splits.clone(),
        })
    }

    /// The patch number of each patch, in mesh order (the input face for one patch per face).
    pub fn patch_numbers(&self) -> &[u32] {
        &self.patch
    }

    /// Each patch's area (scene units²), in mesh order.
    pub fn areas(&self) -> &[f64] {
        &self.area
    }

    /// Pieces merged into the state.
    pub fn pieces(&self) -> u32 {
        self.pieces
    }

    /// Steps over all pieces.
    pub fn steps(&self) -> u32 {
        self.steps
    }

    /// Rays that hit nothing, over all pieces.
    pub fn escaped_rays(&self) -> u64 {
        self.escaped_rays
    }

    /// Reads a state written by [`RunState::write`], checking its layout.
    pub fn read(reader: impl Read) -> Result<RunState, Error> {
        let state: RunState = ciborium::from_reader(reader).map_err(|e| match e {
            ciborium::de::Error::Io(e) => Error::StateIo(e),
            _ => Error::NotAState,
        })?;
        if state.format != FORMAT {
            return Err(Error::StateFormat {
                found: state.format,
                expected: FORMAT,
            });
        }
        let n = state.patch.len();
        let consistent = state.area.len() == n
            && state.radiosity.len() == n
            && state.variance.as_ref().is_none_or(|v| v.len() == n)
            && state.settings.settings().is_some();
        if !consistent {
            return Err(Error::NotAState);
        }
        Ok(state)
    }

    /// Writes the state (CBOR) to `writer`.
    pub fn write(&self, writer: impl Write) -> Result<(), Error> {
        ciborium::into_writer(self, writer).map_err(|e| match e {
            ciborium::ser::Error::Io(e) => Error::StateIo(e),
            ciborium::ser::Error::Value(v) => Error::StateIo(std::io::Error::other(v)),
        })
    }

    /// Checks that the run on `mesh` lit as `lighting` ([`lighting_fingerprint`]) continues
    /// this state: same mcrad version, mesh, lights and sky.
    pub(crate) fn check_continues(&self, mesh: &Mesh, lighting: u64) -> Result<(), Error> {
        let version = env!("CARGO_PKG_VERSION");
        if self.version != version {
            return Err(Error::StateVersion {
                saved: self.version.clone(),
                running: version.to_string(),
            });
        }
        if self.fingerprint != fingerprint(mesh) || self.patch.len() != mesh.patches().len() {
            return Err(Error::StateMesh {
                saved: self.patch.len(),
                now: mesh.patches().len(),
            });
        }
        if self.lighting != lighting {
            return Err(Error::StateLighting);
        }
        Ok(())
    }

    /// This state with `piece`, the solution of the next piece (an independent run), merged
    /// in by rays: the state after one more piece.
    pub(crate) fn continued(
        &self,
        piece: &Estimate,
        steps: u32,
        escaped_rays: u64,
    ) -> Result<RunState, Error> {
        let merged = merge(&self.estimate()?, piece, &ByRays)?;
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

fn arrays(v: &[DVec3]) -> Vec<[f64; 3]> {
    v.iter().map(|x| x.to_array()).collect()
}

/// A 64-bit FNV-1a hash of bytes.
struct Fnv(u64);

impl Fnv {
    fn new() -> Fnv {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
    fn eat(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }
}

/// A 64-bit FNV-1a hash of the lights without a surface and the sky a run is lit by: every
/// light's values (their shortest exact decimal forms), the sky's uniform radiance or its
/// map's size, rotation and pixels as bit patterns. Equal for equal lighting; a different
/// sun or sky changes it (up to a 2^-64 collision).
pub(crate) fn lighting_fingerprint(
    lights: &[mcrad_scene_io::Light],
    sky: Option<&mcrad_scene_io::Sky>,
) -> u64 {
    let mut h = Fnv::new();
    h.eat(format!("{lights:?}").as_bytes());
    match sky {
        None => h.eat(b"no sky"),
        Some(mcrad_scene_io::Sky::Uniform(l)) => h.eat(format!("uniform {l:?}").as_bytes()),
        Some(mcrad_scene_io::Sky::Map(map)) => {
            h.eat(b"map");
            h.eat(&map.width().to_le_bytes());
            h.eat(&map.height().to_le_bytes());
            h.eat(&map.rotation().to_le_bytes());
            for t in map.texels() {
                for c in t {
                    h.eat(&c.to_le_bytes());
                }
            }
        }
    }
    h.0
}

/// A 64-bit FNV-1a hash of what a solution depends on in the mesh: every patch's area,
/// reflectance, emission and input face, the mesh's local origin (when not zero) and every
/// triangle's corners (relative to it), as their bit patterns. Two meshes with the same
/// fingerprint solve the same problem (up to a 2^-64 collision).
fn fingerprint(mesh: &Mesh) -> u64 {
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
