//! The per-patch estimate that estimators produce and rules merge.

use glam::DVec3;

/// An estimate of the radiosity of every patch of a mesh.
///
/// Invariants (checked by [`Estimate::new`]): `radiosity` and `variance` (when present) have one
/// entry per patch, all finite; variances are `>= 0`. The default is the estimate of no
/// patches (what is left where an estimate was taken, `std::mem::take`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Estimate {
    radiosity: Vec<DVec3>,
    variance: Option<Vec<DVec3>>,
    rays: u64,
}

/// Why an [`Estimate`] could not be built or merged.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EstimateError {
    /// The variance vector does not have one entry per patch.
    #[error("variance has {variances} entries but there are {patches} patches")]
    VarianceLength {
        /// Number of patches (radiosity entries).
        patches: usize,
        /// Number of variance entries.
        variances: usize,
    },
    /// Two estimates of different meshes were merged.
    #[error("cannot merge estimates of {a} and {b} patches")]
    PatchCountMismatch {
        /// Patches of the first estimate.
        a: usize,
        /// Patches of the second estimate.
        b: usize,
    },
    /// A value is NaN or infinite, or a variance is negative.
    #[error(
        "patch {patch}: radiosity {radiosity} or variance {variance} is not finite and non-negative"
    )]
    NotFinite {
        /// Patch index.
        patch: usize,
        /// Offending radiosity (W/m²).
        radiosity: DVec3,
        /// Offending variance ((W/m²)²), zero when absent.
        variance: DVec3,
    },
    /// The rule needs variances and an estimate has none.
    #[error("the inverse-variance rule needs a variance for every patch")]
    MissingVariance,
    /// Runs merged by pooled inverse variance, and run `run` (counted from 0) reports no
    /// variance for any patch.
    #[error("run {run} has no variances, so it cannot be weighted against the other runs")]
    RunWithoutVariance {
        /// Index of the run among those merged.
        run: usize,
    },
    /// A merge of runs was given none.
    #[error("no runs to merge")]
    NoRuns,
}

impl Estimate {
    /// Builds an estimate from per-patch radiosity `B_i` (W/m², exitance per RGB channel), the
    /// estimated variance of each `B_i` ((W/m²)², per channel) when known, and the number of rays
    /// cast to produce it.
    pub fn new(
        radiosity: Vec<DVec3>,
        variance: Option<Vec<DVec3>>,
        rays: u64,
    ) -> Result<Estimate, EstimateError> {
        if let Some(v) = &variance
            && v.len() != radiosity.len()
        {
            return Err(EstimateError::VarianceLength {
                patches: radiosity.len(),
                variances: v.len(),
            });
        }
        for (i, b) in radiosity.iter().enumerate() {
            let v = variance.as_ref().map_or(DVec3::ZERO, |v| v[i]);
            if !b.is_finite() || !v.is_finite() || v.min_element() < 0.0 {
                return Err(EstimateError::NotFinite {
                    patch: i,
                    radiosity: *b,
                    variance: v,
                });
            }
        }
        Ok(Estimate {
            radiosity,
            variance,
            rays,
        })
    }

    /// Radiosity `B_i` per patch and RGB channel, W/m².
    pub fn radiosity(&self) -> &[DVec3] {
        &self.radiosity
    }

    /// Estimated variance of each `B_i` per channel, (W/m²)²; `None` where the estimator cannot
    /// say.
    pub fn variance(&self) -> Option<&[DVec3]> {
        self.variance.as_deref()
    }

    /// Rays cast to produce this estimate (the work behind it).
    pub fn rays(&self) -> u64 {
        self.rays
    }

    /// Number of patches.
    pub fn len(&self) -> usize {
        self.radiosity.len()
    }

    /// True when the estimate covers no patch.
    pub fn is_empty(&self) -> bool {
        self.radiosity.is_empty()
    }

    /// The estimate taken apart: radiosity (W/m²), variance ((W/m²)², when known) and rays,
    /// as [`Estimate::new`] takes them, so that a changed copy reuses the arrays instead of
    /// copying them.
    pub fn into_parts(self) -> (Vec<DVec3>, Option<Vec<DVec3>>, u64) {
        (self.radiosity, self.variance, self.rays)
    }
}
