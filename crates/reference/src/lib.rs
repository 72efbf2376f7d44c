//! The deterministic reference solver: explicit form factors and a linear solve.
//!
//! Monte Carlo estimators are judged against a reference solution of
//! `B_i = E_i + ρ_i Σ_j F_ij B_j` (radiosity `B` and emission `E` in W/m², per RGB channel).
//! This crate computes one for scenes of up to about ten thousand patches (work and memory
//! grow as the square of the patch count): the form factors `F_ij` ([`form_factors`]), then
//! Gauss-Seidel to a residual `|E + ρ F B - B|` below `1e-9` of each patch's own `B` ([`solve`]). The result
//! is a [`combine::Estimate`](mcrad_combine::Estimate) without variance. Everything is a pure
//! function of the mesh and the configuration: the shadow rays' jitter comes from
//! [`Stream`](mcrad_random::Stream)s keyed by the pair, and the answer does not depend on the
//! thread count.
//!
//! # Form factors
//!
//! With `P_i' = P_i ∩ {front of P_j}` and `P_j' = P_j ∩ {front of P_i}` (a patch emits and
//! receives on its front only; both clipped once per pair, an empty one or coplanar patches
//! giving 0), the exchange `G_ij = A_i F_ij = A_j F_ji` (scene units²) of each unordered pair is
//! computed once, so reciprocity holds to rounding:
//!
//! ```text
//! G_ij = φ_ij U_ij,   U_ij = ∫_{P_i'} F_{x→P_j'} dA_x,
//! ```
//!
//! `U_ij` the unoccluded exchange and `φ_ij` the visible fraction, weighted by the kernel.
//!
//! * **Quadrature.** `F_{x→P}` is the exact point-to-polygon form factor
//!   ([`point_polygon_form_factor`], Lambert's contour integral). The outer integral runs over
//!   the fan triangles of the smaller of `P_i'`, `P_j'` (the integral is symmetric), with
//!   Radon's degree-5 rule, then Dunavant's degree-8 rule, then the degree-8 rule on the four
//!   midpoint children, adaptively, each triangle carrying the difference from an embedded
//!   lower-degree rule as its error estimate (conservative: it is the error of the lower
//!   rule). Each pair is refined to [`ReferenceConfig::tolerance`] relative to `U_ij`, so every
//!   row's quadrature error is below that fraction of its sum. The integrand is smooth except
//!   at vertices the two polygons share, where the refinement concentrates.
//! * **Shaft culling.** If no face of the scene meets the interior of the convex hull of
//!   `P_i'` and `P_j'` (the faces rebuilt from their patches, tested exactly by clipping them to
//!   the hull; contact does not count), `φ_ij = 1` exactly and no ray is cast.
//! * **Visibility** of the other pairs is estimated with shadow rays through
//!   [`RayCaster::occluded`]: two jittered rays per block of an adaptive partition of
//!   `P_i' × P_j'`, blocks weighted by their unoccluded exchange, refined in sweeps whose
//!   splitting depends only on earlier sweeps, so that each sweep's estimate is unbiased; its
//!   standard deviation is estimated from the rays' disagreement within blocks. When every ray
//!   of a pair passes, the occluders may only graze its shaft, and an analytic bound on what
//!   they can block (`Σ_Q min(∫_{P_i'} F_{x→Q}, ∫_{P_j'} F_{y→Q})` over the occluders `Q`
//!   clipped to the shaft) is used when it is tighter.
//! * **Budgets.** Visibility errors are random and independent between pairs, so a row adds
//!   them in quadrature; row `r` may have a standard deviation of
//!   [`ReferenceConfig::visibility_tolerance`] `× S_r`, shared out among its occluded pairs in
//!   proportion to `sqrt(F_rj)` (which minimises the rays for shadow-ray errors that fall as
//!   the square root of their number), and each pair is refined until it meets the smaller of
//!   its two rows' shares, or a work limit. `S_r = Σ_j F_rj` is taken as at least `0.1 ×` the
//!   area-weighted mean row sum: a patch hidden under a block receives almost nothing, and
//!   holding it to a fraction of that would cost more rays than the rest of the scene.
//!
//! Shadow rays converge slowly (on the Cornell box, halving the visibility tolerance doubles the
//! rays; `1e-4` takes about twenty times as long as `2e-3`), hence the two tolerances: both
//! `1e-4` by default (the accuracy a reference needs), the visibility one loosened where a
//! quicker, rougher answer will do (`--visibility-tolerance 2e-3`: 23 s instead of about 8
//! minutes for the Cornell box at 1940 patches on 2 cores).
//! [`FormFactorStats`] reports the largest estimated error of each kind.
//!
//! What the estimates cannot see: a pair declared visible by the shaft test is exact; one
//! whose rays all agree carries the error `1/(n + 2)` for `n` rays (the posterior mean of a
//! lit or blocked fraction under a uniform prior), which is honest for one shadow but not for
//! a structure finer than the blocks (a grille).
//!
//! # Example
//!
//! ```
//! use glam::Vec3;
//! use mcrad_reference::{ReferenceConfig, reference};
//! use mcrad_meshing::{Mesh, Subdivision};
//! use mcrad_raycast::Bvh;
//! use mcrad_scene_io::{Face, Material, Scene};
//!
//! // A closed unit cube, every face emitting 1 W/m² with reflectance 0.5: B = E / (1 - ρ) = 2.
//! let positions: Vec<Vec3> = (0..8)
//!     .map(|k| Vec3::new((k & 1) as f32, (k >> 1 & 1) as f32, (k >> 2) as f32))
//!     .collect();
//! let quads = [[1, 3, 2, 0], [6, 7, 5, 4], [4, 5, 1, 0], [3, 7, 6, 2], [2, 6, 4, 0], [5, 7, 3, 1]];
//! let faces = quads
//!     .iter()
//!     .enumerate()
//!     .map(|(k, q)| Face { vertices: q.to_vec(), material: 0, source: k as u32 })
//!     .collect();
//! let material = Material { name: "m".into(), reflectance: Vec3::splat(0.5), emission: Vec3::ONE };
//! let scene = Scene::new(positions, faces, vec![material]).unwrap().0;
//! let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
//! let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
//! let r = reference(&mesh, &bvh, &ReferenceConfig::default(), &|_| {}).unwrap();
//! for b in r.estimate.radiosity() {
//!     assert!((b.x - 2.0).abs() < 1e-3);
//! }
//! ```

mod direct;
mod form_factor;
mod matrix;
mod quadrature;
mod shaft;
mod solve;
mod visibility;

pub use direct::{
    Direct, FINE, PROBE, SKY_DIRECTIONS, SKY_POINTS, direct_irradiance, sky_irradiance,
};
pub use form_factor::point_polygon_form_factor;
pub use matrix::{FormFactorStats, FormFactors, form_factors};
pub use solve::{DIM_FLOOR, Solution, solve};

use mcrad_combine::Estimate;
use mcrad_meshing::Mesh;
use mcrad_raycast::RayCaster;

/// The default visibility tolerance ([`ReferenceConfig::visibility_tolerance`]): each row's
/// shadow-ray estimate to one standard deviation of `1e-4` of the row sum, the accuracy a
/// reference needs. `2e-3` is about twenty times quicker where a rougher answer will do.
pub const DEFAULT_VISIBILITY_TOLERANCE: f64 = 1e-4;

/// Settings of the reference solver.
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceConfig {
    /// The most patches accepted; larger meshes are refused before any work
    /// ([`ReferenceError::TooManyPatches`]). Work grows as the square of the patch count:
    /// about 10k patches is the practical ceiling.
    pub max_patches: usize,
    /// Target quadrature error of each form-factor row relative to its sum `Σ_j F_ij`, in
    /// `(0, 1)`: the error of the integrals of the exact kernel over the patches, estimated
    /// conservatively.
    pub tolerance: f64,
    /// Target visibility error of each row (one standard deviation of the shadow-ray estimate)
    /// relative to its sum, in `(0, 1)`. Shadow rays converge slowly (on the Cornell box,
    /// halving this doubles the rays), hence a separate, looser target.
    pub visibility_tolerance: f64,
    /// Target residual of the solve relative to each patch's own radiosity,
    /// `max_{i,c} |E + ρ F B - B|_ic / max(B_ic, DIM_FLOOR max B)` ([`DIM_FLOOR`]),
    /// `> 0`.
    pub residual: f64,
    /// Gauss-Seidel sweeps allowed before [`ReferenceError::NotConverged`].
    pub max_iterations: usize,
}

impl Default for ReferenceConfig {
    /// 10 000 patches; row errors `1e-4` (quadrature, and visibility as one standard
    /// deviation: [`DEFAULT_VISIBILITY_TOLERANCE`]) of the row sum; residual `1e-9`; 10 000
    /// sweeps.
    fn default() -> Self {
        ReferenceConfig {
            max_patches: 10_000,
            tolerance: 1e-4,
            visibility_tolerance: DEFAULT_VISIBILITY_TOLERANCE,
            residual: 1e-9,
            max_iterations: 10_000,
        }
    }
}

/// Why the reference solver refused or failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReferenceError {
    /// The mesh is too large for explicit form factors.
    #[error(
        "the mesh has {patches} patches, more than the reference solver's limit of {limit}: \
         its form factors take work and memory that grow as the square of the patch count; \
         use a coarser mesh"
    )]
    TooManyPatches {
        /// Patches in the mesh.
        patches: usize,
        /// The limit ([`ReferenceConfig::max_patches`]).
        limit: usize,
    },
    /// A form-factor tolerance is not in `(0, 1)`.
    #[error("the form-factor {name} must be in (0, 1), got {value}")]
    BadTolerance {
        /// Which tolerance ([`ReferenceConfig`] field name).
        name: &'static str,
        /// The value given.
        value: f64,
    },
    /// The residual target is not a positive number.
    #[error("the residual target must be a positive number, got {0}")]
    BadResidual(f64),
    /// The form-factor matrix belongs to another mesh.
    #[error("the form-factor matrix has {rows} rows but the mesh has {patches} patches")]
    MatrixSize {
        /// Patches in the mesh.
        patches: usize,
        /// Rows of the matrix.
        rows: usize,
    },
    /// Gauss-Seidel did not reach the residual target.
    #[error(
        "Gauss-Seidel reached a residual of {residual:.3e} after {iterations} sweeps, not the \
         target {target:.1e} (reflectances close to 1 converge slowly; allow more sweeps)"
    )]
    NotConverged {
        /// Sweeps done.
        iterations: usize,
        /// Residual reached (relative to the largest radiosity).
        residual: f64,
        /// The target.
        target: f64,
    },
}

/// Work, accuracy and convergence of a reference solution.
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceStats {
    /// Patches solved.
    pub patches: usize,
    /// Form-factor work and estimated accuracy.
    pub form_factors: FormFactorStats,
    /// Gauss-Seidel sweeps.
    pub iterations: usize,
    /// Final residual relative to each patch's own radiosity ([`Solution::residual`]).
    pub residual: f64,
}

/// A reference solution.
#[derive(Debug, Clone)]
pub struct Reference {
    /// Radiosity `B_i` (W/m² per channel); no variance (the error is deterministic: see
    /// [`ReferenceStats`]); `rays` counts the shadow rays cast.
    pub estimate: Estimate,
    /// Work and accuracy.
    pub stats: ReferenceStats,
}

/// Solves radiosity on `mesh` deterministically: form factors with visibility from `caster`
/// (ids must be patch indices), then Gauss-Seidel. `progress` is called with the number of
/// form-factor rows done (from worker threads, not necessarily in order; up to
/// `mesh.patches().len()`, see [`form_factors`]).
///
/// Refuses meshes with more than [`ReferenceConfig::max_patches`] patches before doing any
/// work.
pub fn reference<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    config: &ReferenceConfig,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Reference, ReferenceError> {
    let patches = mesh.patches().len();
    if !(config.residual > 0.0 && config.residual.is_finite()) {
        return Err(ReferenceError::BadResidual(config.residual));
    }
    let factors = form_factors(mesh, caster, config, progress)?;
    let solution = solve(mesh, &factors, config.residual, config.max_iterations)?;
    let stats = ReferenceStats {
        patches,
        form_factors: factors.stats().clone(),
        iterations: solution.iterations,
        residual: solution.residual,
    };
    let estimate = Estimate::new(solution.radiosity, None, stats.form_factors.rays)
        .expect("a converged solution is finite");
    Ok(Reference { estimate, stats })
}
