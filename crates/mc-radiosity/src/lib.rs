//! Monte Carlo radiosity estimators.
//!
//! Radiosity `B_i` (exitance, W/m²) solves `B_i = E_i + rho_i sum_j F_ij B_j`, where the form
//! factor `F_ij` is the probability that a cosine-distributed ray leaving a uniform point of patch
//! `i` first hits patch `j`. The estimators here never compute `F_ij`; they cast such rays through
//! a [`RayCaster`](mcrad_raycast::RayCaster) and return a
//! [`combine::Estimate`](mcrad_combine::Estimate).
//!
//! - [`shoot`]: stochastic shooting with Feda and Purgathofer's constant energy per ray (Balog,
//!   section 1.3): unshot power `dB_i A_i` leaves patch `i` on `n_i` rays of `dB_i A_i / n_i`
//!   each, `n_i` proportional to it.
//! - [`gather_round`], [`gather`](gather()), [`gather_corners`] ([`gather`](mod@gather)):
//!   gathering (section 1.4): patches (or vertices) average the radiosity that cosine rays hit;
//!   one Jacobi round, the iteration, and gathering at vertices (section 1.5).
//! - [`direct`](direct()) and [`two_pass_split`] ([`direct`](mod@direct)): direct light by
//!   sampling emitters (Shirley and Wang 1991) and the second pass
//!   `E + direct + gathered indirect` of two-pass radiosity (section 1.5).
//! - [`ambient`](ambient()) and [`with_ambient`] ([`ambient`](mod@ambient)): Cohen et al.'s
//!   ambient term for the power a shooting run left unshot (section 3.1).
//! - [`adaptive`]: adaptive meshing, refining an
//!   [`AdaptiveMesh`](mcrad_meshing::AdaptiveMesh) where the measured solution varies beyond
//!   its noise or the emitters' visibility changes within an element.
//! - [`schedule`]: the methods behind one interface — single-pass shooting, gathering and
//!   two-pass, the progressive Algorithms 1-4, bidirectional and the deterministic reference —
//!   handing each complete intermediate solution to an observer that may stop the run.
//! - [`method`]: the registry of those methods, one entry each ([`Method`]): names, metadata
//!   and the dispatch of [`schedule::run`]; clap's `ValueEnum` with feature `clap`, serde's
//!   `Serialize` (of [`Method`], [`StopReason`] and [`adaptive::RoundStats`]) with feature
//!   `serde`.
//!
//! Randomness is a pure function of `(seed, pass, item, sub-stream)` and every reduction runs
//! in a fixed order, so a seed gives the same answer whatever the thread count. With
//! [`Sampler::Qmc`], the default ([`Context::with_sampler`],
//! [`ScheduleConfig::sampler`](schedule::ScheduleConfig::sampler)), the rays of each patch are
//! the points of its own Owen-scrambled Sobol sequence ([`mcrad_random::Sobol`]), keyed that
//! way: stratified, still unbiased and deterministic; the variances the estimators report are
//! scaled to the stratified rays' error by the spread between the two scrambles every sequence
//! interleaves (module `replicates`). With [`Sampler::Random`] they are independent
//! pseudo-random rays ([`mcrad_random::Stream`]).
//! This crate does no I/O.

pub mod adaptive;
pub mod ambient;
mod context;
mod control;
pub mod direct;
mod error;
pub mod gather;
mod jobs;
pub mod method;
mod replicates;
mod sampling;
pub mod schedule;
mod shoot;
mod surface;

pub use ambient::{ambient, mean_reflectance, with_ambient};
pub use context::{Context, Sampler};
pub use control::ControlVariate;
pub use direct::{DirectLight, DirectSampling, SplitConfig, direct, two_pass_split};
pub use error::Error;
pub use gather::{
    CornerGathering, Emission, GatherConfig, GatherProgress, GatherRound, GatherStats, Gathering,
    gather, gather_corners, gather_round, gather_round_from,
};
pub use mcrad_random::StreamKey;
pub use method::{Kind, Method, StopReason, UnknownMethod};
pub use schedule::{DEFAULT_RAYS, DEFAULT_UNSHOT_THRESHOLD};
pub use shoot::{DEFAULT_MAX_OVERRUN, ShootConfig, ShootProgress, ShootStats, Shooting, shoot};
/// Uniform points and cosine-distributed rays on patches, for tests that check the estimators'
/// sampling against the reference (only with the `testing` feature).
#[cfg(feature = "testing")]
pub use surface::SurfaceSampler;
