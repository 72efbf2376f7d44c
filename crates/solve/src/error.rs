//! Why a solve failed.

use mcrad_combine::EstimateError;
use mcrad_mc_radiosity::AdaptiveError;
use mcrad_meshing::MeshError;
use mcrad_raycast::BuildError;

/// Why [`crate::solve`] (or reading a [`crate::RunState`]) failed, by who is responsible.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The scene could not be meshed as planned.
    #[error("{source}")]
    Mesh {
        /// What meshing refused.
        source: MeshError,
        /// The uniform cut being built: its longest edge (scene units; for an adaptive mesh,
        /// its start's), or `None` for one patch per face.
        max_edge: Option<f32>,
    },
    /// An [`Input::SceneOnce`](crate::Input::SceneOnce) held no scene (a solve took it before,
    /// or a thread panicked holding its lock).
    #[error("the scene was taken by an earlier solve: hand each solve its own")]
    SceneTaken,
    /// The ray caster could not be built over the mesh.
    #[error("could not build the ray caster: {0}")]
    Caster(#[from] BuildError),
    /// The method refused the mesh or its settings.
    #[error(transparent)]
    Method(#[from] mcrad_mc_radiosity::Error),
    /// The adaptive refinement failed.
    #[error(transparent)]
    Refine(#[from] AdaptiveError),
    /// Estimates did not merge (they cover different patches).
    #[error("the estimates do not merge: {0}")]
    Estimate(#[from] EstimateError),
    /// The worker threads could not be started.
    #[error("could not start {threads} worker threads: {source}")]
    Threads {
        /// Threads asked for.
        threads: usize,
        /// Why not.
        source: rayon::ThreadPoolBuildError,
    },
    /// The solve's estimated peak memory ([`crate::Problem::memory_estimate`]) exceeds the
    /// budget's [`crate::Budget::memory`]: refused before any work.
    #[error(
        "the solve would need about {} of memory at its peak ({elements} elements of about \
         {per_element} bytes at its ray budget, and the scene's {}), more than the {} it may \
         use: give it more memory, fewer rays, or a coarser mesh or fewer patches",
        crate::memory::show_bytes(*estimate),
        crate::memory::show_bytes(*scene_bytes),
        crate::memory::show_bytes(*limit)
    )]
    Memory {
        /// The estimated peak (bytes).
        estimate: u64,
        /// The most elements the plan makes.
        elements: u64,
        /// The estimate's bytes per element at the ray budget
        /// ([`MemoryEstimate::per_element`](crate::MemoryEstimate::per_element)).
        per_element: u64,
        /// The scene's own bytes.
        scene_bytes: u64,
        /// The memory allowed (bytes).
        limit: u64,
    },
    /// The run was cancelled before its first complete step: there is no answer.
    #[error("cancelled before the first step completed: there is no answer")]
    CancelledEarly,
    /// A continued run's settings differ from the saved run's.
    #[error(
        "the saved run has {what} {saved}, this run asks for {given}: continue it with the saved run's {what}"
    )]
    Disagree {
        /// The setting.
        what: &'static str,
        /// Its saved value.
        saved: String,
        /// The value asked for now.
        given: String,
    },
    /// A deterministic method has no run to continue.
    #[error("the method {0} is deterministic: there is no run to continue")]
    DeterministicResume(mcrad_mc_radiosity::Method),
    /// A continued run's mesh is not the saved one.
    #[error(
        "the saved run was solved on another scene or mesh ({saved} patches; this run: {now}): \
         continue it with the saved run's scene"
    )]
    StateMesh {
        /// Patches of the saved run.
        saved: usize,
        /// Patches of this run.
        now: usize,
    },
    /// A continued run is lit by other lights without a surface (point, spot, sun) or another
    /// sky than the saved run.
    #[error(
        "the saved run was lit by other lights (point, spot, sun) or another sky than this run: \
         continue it with the saved run's lights and sky"
    )]
    StateLighting,
    /// A continued run's scene cannot make the saved run's adaptive mesh.
    #[error(
        "the saved run was solved on another scene or mesh: its adaptive mesh cannot be made \
         from this scene ({0}); continue it with the saved run's scene"
    )]
    StateReplay(MeshError),
    /// The state was written by another version of mcrad.
    #[error(
        "the state was saved by mcrad {saved}, this is mcrad {running}: a run can only be \
         continued by the version that started it"
    )]
    StateVersion {
        /// The version that saved it.
        saved: String,
        /// This version.
        running: String,
    },
    /// The state has a layout this mcrad does not read.
    #[error("the state has format {found}, this mcrad reads format {expected}")]
    StateFormat {
        /// Its format.
        found: u32,
        /// The format read here.
        expected: u32,
    },
    /// The bytes are not a saved state (or it is damaged).
    #[error("not a state saved by mcrad (or it is damaged)")]
    NotAState,
    /// Reading or writing the state failed.
    #[error("{0}")]
    StateIo(std::io::Error),
}
