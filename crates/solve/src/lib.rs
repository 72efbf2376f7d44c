//! mcrad's solve as a library: a [`Problem`] in, an [`Answer`] out.
//!
//! ```text
//! Problem { scene, settings, budget, threads, resume, cancel }
//!    │  mesh plan: adaptive (start, refine, pool) | uniform | one patch per face | replayed
//!    ▼
//! solve(problem, observer) ── after each step ────▶ observer(Progress) → Continue | Break
//!    │  the method (mc-radiosity's schedules), under the budget and the deadline
//!    ▼
//! Answer { mesh, bvh, estimate (W/m² and variance per patch), stats, state }
//! ```
//!
//! The crate owns everything between a scene and its answer that a user would otherwise have
//! to copy from the command line: the adaptive mesh's start and refinement, the run of the
//! method, the pooling of what the refinement learnt with the method's solution, the budget's
//! split between them, the deadline of a time budget, a target error, and continuing a saved
//! run. Its defaults ([`Settings::default`], [`Budget::default`]) are `mcrad solve`'s, and
//! `mcrad solve` is this crate plus flags, files, a progress bar and signals: the same inputs
//! give the same answer, bit for bit (the example `solve` writes the CLI's patch CSV).
//!
//! **The budget.** A ray budget `N` (default [`DEFAULT_RAYS`]) is split once, here: an
//! adaptive mesh's refinement gets `N / 4` (and a quarter of a time budget), the method what
//! the refinement left and at least `N / 2`. A time budget counts from [`Budget::since`]
//! (loading included, when the caller started the clock there); after each step the rays that
//! fit in the time left at the speed measured so far cap the rest of the run.
//!
//! **Memory** is bounded before the work: [`Problem::memory_estimate`] bounds the peak from the
//! face count, the mesh plan, the method and the ray budget ([`peak_bytes`]), and a problem whose estimate exceeds [`Budget::memory`] is
//! refused ([`Error::Memory`]) before anything is meshed.
//!
//! **A continued run** ([`Problem::resume`]) is an independent piece with its own random
//! streams ([`piece_seed`]), merged with the saved solution by rays: weights fixed by the work,
//! not by the values, so the merge stays unbiased. The state ([`RunState`]) records the
//! settings and the mesh (an adaptive mesh as its [`History`](mcrad_meshing::History)), so a
//! continuation needs nothing repeated, and a setting given again must agree
//! ([`Settings::agree`]).
//!
//! **The closure report** ([`Closure`], in [`RunStats::closure`], when [`Problem::closure`]
//! asks for it: its probe rays cost about a sixteenth of the method's): per channel the power
//! emitted, absorbed and escaped (W) and the standard error of their balance; a balance off by
//! more than [`CLOSURE_SIGMAS`] standard errors is a warning.
//!
//! Randomness is a pure function of the seed: the answer does not depend on the thread count.
//! The crate does no I/O and never prints: warnings are returned in [`Answer::warnings`].

mod closure;
mod clusters;
mod error;
mod memory;
mod per_patch;
mod pipeline;
mod problem;
mod state;
mod stats;

pub use closure::{CLOSURE_SIGMAS, Closure};
pub use error::Error;
pub use mcrad_mc_radiosity::DEFAULT_RAYS;
pub use memory::{
    BYTES_FIXED, BYTES_PER_ELEMENT, BYTES_PER_GATHERED, BYTES_PER_REACHED, MemoryEstimate,
    gather_rays_per_element, peak_bytes,
};
pub use per_patch::PerPatch;
pub use pipeline::{Answer, Observer, Progress, solve};
pub use problem::{
    AfterSolve, Budget, Clustering, Input, MAX_GROWN_PATCHES, MeshPlan, PATCH_RAYS, Problem,
    Settings,
};
pub use state::{RunState, piece_seed};
pub use stats::{ClusterStats, RefinementRound, RunStats, SetupPhases};
