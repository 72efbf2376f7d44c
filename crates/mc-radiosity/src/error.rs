//! The one error type of the estimators and schedules.

use glam::DVec3;
use mcrad_combine::EstimateError;

/// Why an estimator or a schedule refuses its input. Every variant is a property of the input
/// (mesh, configuration, input radiosity), never a failure of the machine.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Error {
    /// Nothing in the mesh emits: there is nothing to shoot.
    #[error("no patch emits light: there is nothing to shoot")]
    NoEmission,
    /// The ray budget is zero.
    #[error("the ray budget must be at least 1")]
    NoRays,
    /// The unshot threshold of shooting is not a fraction in `[0, 1]`.
    #[error("the unshot threshold must be in [0, 1], got {0}")]
    BadUnshotThreshold(f64),
    /// The share of the budget a shooting's finishing tail may overrun is negative or NaN.
    #[error("the finishing tail's overrun must be >= 0, got {0}")]
    BadMaxOverrun(f64),
    /// The convergence threshold of Jacobi gathering is negative or not finite.
    #[error("the gathering threshold must be finite and >= 0, got {0}")]
    BadGatherThreshold(f64),
    /// The scene is so large relative to its patches that `f32` coordinates cannot place
    /// points on them: patches smaller than 1024 `f32` spacings (`Mesh::resolved_size`) hold
    /// more than 1% of the area, so the answer would be silently wrong. Coordinates are those of
    /// the mesh's local frame (`Mesh::origin`, near the scene's centre), so where the scene lies
    /// in the world does not matter, only its extent over its patches (beyond about `2^13`). A
    /// few slivers below the limit are accepted.
    #[error(
        "coordinates reach {coordinate:e} scene units from the scene's centre, where f32 points \
         are {spacing:e} apart, more than 1/1024 of {unresolved} patches holding {:.1}% of the \
         area (the smallest, patch {patch}, is {size:e} across): the scene is too large for \
         its patches (geometry is stored in f32)",
        100.0 * share
    )]
    FarFromOrigin {
        /// The largest coordinate magnitude in the mesh's local frame (scene units).
        coordinate: f64,
        /// The spacing of `f32` values there (scene units).
        spacing: f64,
        /// The smallest patch (mesh order).
        patch: usize,
        /// Its size, the square root of its area (scene units).
        size: f64,
        /// Patches smaller than 1024 spacings.
        unresolved: usize,
        /// Their share of the mesh's area (more than 0.01).
        share: f64,
    },
    /// The mesh has more patches than ray ids or hit records can name.
    #[error("{patches} patches are more than the estimator can address ({limit})")]
    TooManyPatches {
        /// Patches in the mesh.
        patches: usize,
        /// The most the estimator can address.
        limit: u64,
    },
    /// A per-patch input (radiosity, unshot power) does not have one entry per patch.
    #[error("the input has {got} values but the mesh has {patches} patches")]
    InputLength {
        /// Patches in the mesh.
        patches: usize,
        /// Entries given.
        got: usize,
    },
    /// An input radiosity is NaN or infinite.
    #[error("input radiosity of patch {patch} is not finite: {value}")]
    NotFinite {
        /// Patch index.
        patch: usize,
        /// The offending value (W/m²).
        value: DVec3,
    },
    /// Fewer than two rays (or samples) per item: the sample variance needs two.
    #[error("at least 2 rays per patch or vertex are needed for a variance, got {0}")]
    TooFewRays(u32),
    /// The ray budget of Jacobi gathering cannot pay for a single round.
    #[error("a budget of {budget} rays cannot pay for one round of {round} rays")]
    BudgetBelowRound {
        /// The budget.
        budget: u64,
        /// Rays of one round (`patches × rays_per_patch`).
        round: u64,
    },
    /// The ray budget of a schedule is too small for one pass of its method.
    #[error("the ray budget of {0} rays is too small for one pass of this method")]
    BudgetTooSmall(u64),
    /// The corner groups were made for another mesh.
    #[error("the corner groups cover {got} corners but the mesh has {corners}")]
    GroupsMismatch {
        /// Corners of the mesh.
        corners: usize,
        /// Corners the groups cover.
        got: usize,
    },
    /// An unshot power is NaN, infinite or negative.
    #[error("unshot power of patch {patch} is not finite and non-negative: {value}")]
    BadUnshot {
        /// Patch index.
        patch: usize,
        /// The offending value (W).
        value: DVec3,
    },
    /// The escape share of the ambient term is not in `[0, 1]` in every channel.
    #[error("the escaped share of shot power must be in [0, 1], got {0}")]
    BadEscape(DVec3),
    /// A result could not be made or merged into an [`mcrad_combine::Estimate`] (a non-finite
    /// sum: overflow).
    #[error(transparent)]
    Estimate(#[from] EstimateError),
    /// The caller cancelled the run ([`run_cancellable`](crate::run_cancellable)):
    /// the step in progress was abandoned; the observer has seen every complete step.
    #[error("the run was cancelled")]
    Cancelled,
    /// The reference solver (method `reference`) refused its input or failed.
    #[error(transparent)]
    Reference(#[from] mcrad_reference::ReferenceError),
}
