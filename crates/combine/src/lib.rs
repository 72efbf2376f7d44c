//! Weighting and merging of per-patch radiosity estimates.
//!
//! `combine` sees estimates — a radiosity value and (where known) a variance per patch and RGB
//! channel, plus the work (rays) behind them — and never rays or geometry. Estimators in
//! `mc-radiosity` return an [`Estimate`]; schedules (the paper's Algorithms 1-4) ask this crate how
//! to merge two of them. There is one merge ([`merge`]) and the rule is a parameter, a
//! [`Weighting`]: a pure function of the estimates it merges, swapped and tested alone.
//!
//! Two independent unbiased estimates `X_a`, `X_b` of the same radiosity merge into
//! `w_a X_a + w_b X_b` with `w_a + w_b = 1`, which stays unbiased. The variance of the merge,
//! `w_a² V_a + w_b² V_b`, is smallest for inverse-variance weights `w ∝ 1/V`
//! ([`InverseVariance`], or [`InverseExpectedVariance`] with modelled variances); when
//! variances are unknown, weights proportional to the work behind each estimate ([`ByRays`])
//! are what Feda and Purgathofer's progressive ray refinement and progressive gathering use
//! (Balog, sections 2.1-2.2). A new rule is one `impl Weighting`.
//!
//! Inverse-variance weights are only as good as the variances: [`expected`] has the models the
//! combined method (Algorithm 4) weights by, and why an estimate's own sample variance biases
//! the merge. Self-emission `E_i` is exact and the same in every estimate; since the weights
//! sum to one, `w_a (E + a) + w_b (E + b) = E + w_a a + w_b b`: merging combines the reflected
//! parts and carries the emission through (tested with [`merge`]).
//!
//! Independent runs of one scene (different seeds, machines) merge all at once with
//! [`merge_runs`] under a [`RunWeighting`]: one weight per run and channel, the inverse of the
//! run's variance pooled over its patches, which keeps the merge unbiased where a patch's own
//! variance would not (the maths is on [`RunWeighting`]).

mod estimate;
pub mod expected;
mod measure;
mod runs;
mod weighting;

pub use estimate::{Estimate, EstimateError};
pub use measure::{relative_error, rms_rel, weighted_quantile};
pub use runs::{MergedRuns, Run, RunWeighting, merge_runs};
pub use weighting::{
    ByRays, InverseExpectedVariance, InverseVariance, Operand, Weighting, merge, merge_weighted,
    weights,
};
