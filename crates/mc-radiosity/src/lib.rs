//! Monte Carlo radiosity: the solution methods of Balog's paper behind one interface.
//!
//! Radiosity `B_i` (exitance, W/m²) solves `B_i = E_i + rho_i sum_j F_ij B_j`, where the form
//! factor `F_ij` is the probability that a cosine-distributed ray leaving a uniform point of patch
//! `i` first hits patch `j`. The estimators here never compute `F_ij`; they cast such rays through
//! a [`RayCaster`](mcrad_raycast::RayCaster) and return a
//! [`combine::Estimate`](mcrad_combine::Estimate).
//!
//! - [`run`] (and [`run_cancellable`]) runs a [`Method`] of the registry: single-pass shooting
//!   (Feda and Purgathofer's constant energy per ray, section 1.3), Jacobi gathering (section
//!   1.4) and two-pass (section 1.5, optionally with Shirley and Wang's direct/indirect
//!   split), the progressive Algorithms 1-4, bidirectional and the deterministic reference,
//!   handing each complete intermediate solution ([`Step`]) to an [`Observer`] that may stop
//!   the run or cap its rays; the answer is a [`Solution`]. [`ScheduleConfig`] holds the
//!   settings (budget, seed, unshot threshold, Cohen et al.'s ambient term of section 3.1,
//!   [`Sampler`], [`ControlVariate`]).
//! - [`run_combined_with`] runs Algorithm 4 (`combined`) with a
//!   [`Weighting`](mcrad_combine::Weighting) of the caller's choice.
//! - [`gather_at_vertices`]: radiosity gathered at the mesh's vertices from a solution (the
//!   paper's per-vertex gathering, section 1.5), for a smooth display without extrapolation.
//! - [`gather_from`]: one Jacobi gathering round from a given solution (the paper's Figure 2
//!   gathers from shooting solutions of growing quality).
//! - [`refine`] and [`pool`]: adaptive meshing, refining an
//!   [`AdaptiveMesh`](mcrad_meshing::AdaptiveMesh) where the measured solution varies beyond
//!   its noise or the emitters' visibility changes within an element;
//!   [`pool_correlation`]: the per-face correlation factors of a pooled answer.
//! - [`Solution::face_correlation`]: per input face, the factor by which the correlation
//!   between its patches' errors scales their variances summed as independent, for the
//!   variance of the face's mean (`--per-face`, a bake's per-face figures).
//!
//! Randomness is a pure function of `(seed, pass, item, sub-stream)` and every reduction runs
//! in a fixed order, so a seed gives the same answer whatever the thread count. With
//! [`Sampler::Qmc`], the default ([`ScheduleConfig::sampler`]), the rays of each patch are
//! the points of its own Owen-scrambled Sobol sequence ([`mcrad_random::Sobol`]), keyed that
//! way: stratified, still unbiased and deterministic; the variances the estimators report are
//! scaled to the stratified rays' error by the spread between the two scrambles every sequence
//! interleaves (module `replicates`). With [`Sampler::Random`] they are independent
//! pseudo-random rays ([`mcrad_random::Stream`]).
//! This crate does no I/O.

mod adaptive;
mod ambient;
mod context;
mod control;
mod correlation;
mod direct;
mod error;
mod fates;
mod gather;
mod jobs;
mod lights;
mod method;
mod replicates;
mod sampling;
mod schedule;
mod shadowed;
mod shoot;
mod sky;
mod surface;
#[cfg(test)]
mod tests;

// The public interface: the methods and how to run them, and adaptive meshing.
pub use adaptive::{
    AdaptiveConfig, AdaptiveError, Refined, RoundStats, pool, pool_correlation, refine,
};
pub use context::Sampler;
pub use control::ControlVariate;
pub use error::Error;
pub use fates::{RayFates, ray_fates};
pub use gather::CornerGathering;
pub use method::{Kind, Method, StopReason, UnknownName};
pub use schedule::{
    DEFAULT_RAYS, DEFAULT_UNSHOT_THRESHOLD, Observer, ScheduleConfig, Solution, Step,
    gather_at_vertices, gather_from, run, run_cancellable, run_combined_with,
};
pub use shadowed::{ShadowSplit, split_shadowed};

// The estimators the schedules compose, for the crate's tests (`src/tests`).
#[cfg(test)]
use ambient::{ambient, mean_reflectance, with_ambient};
#[cfg(test)]
use context::Context;
#[cfg(test)]
use direct::{DirectSampling, SplitConfig, direct, two_pass_split};
#[cfg(test)]
use gather::{Emission, GatherConfig, gather, gather_corners, gather_round};
#[cfg(test)]
use shoot::{ShootConfig, Shooting, shoot};
#[cfg(test)]
use surface::SurfaceSampler;
