//! What every estimator of a run shares, built once: the mesh, the ray caster, the surface
//! sampler and the emitter sampler.

use crate::control::{ControlVariate, Coverage};
use crate::error::Error;
use crate::sampling::Discrete;
use crate::surface::SurfaceSampler;
use mcrad_meshing::Mesh;
use mcrad_raycast::RayCaster;
use std::sync::atomic::{AtomicBool, Ordering};

/// The scene an estimator works on: the `mesh` (patches with area, reflectance `rho` and
/// emission `E` in W/m²), the `caster` that finds first hits on it, and the samplers derived
/// from the mesh once per run: uniform points and cosine-distributed rays on each patch, and
/// emitters drawn in proportion to their power `sum_c E_c A` (W); and optionally a flag that
/// cancels the run (the estimators check it between jobs of rays).
pub struct Context<'a, C: RayCaster> {
    mesh: &'a Mesh,
    caster: &'a C,
    sampler: SurfaceSampler<'a>,
    choice: Sampler,
    emitters: Option<Discrete>,
    cancel: Option<&'a AtomicBool>,
    coverage: Option<Coverage>,
}

impl<'a, C: RayCaster> Context<'a, C> {
    /// The context of `mesh` with rays cast through `caster` (built over the same mesh: ray ids
    /// are patch indices).
    pub fn new(mesh: &'a Mesh, caster: &'a C) -> Context<'a, C> {
        let power: Vec<f64> = mesh
            .patches()
            .iter()
            .map(|p| p.emission.as_dvec3().element_sum() * p.area)
            .collect();
        Context {
            mesh,
            caster,
            sampler: SurfaceSampler::new(mesh),
            choice: Sampler::Random,
            emitters: Discrete::new(&power),
            cancel: None,
            coverage: None,
        }
    }

    /// This context with a cancellation flag: once `cancel` is true, the estimators skip the
    /// jobs not yet started and return [`Error::Cancelled`] (the flag only stops work; it
    /// never changes a result that is returned).
    pub fn with_cancel(mut self, cancel: Option<&'a AtomicBool>) -> Context<'a, C> {
        self.cancel = cancel;
        self
    }

    /// This context with its estimators drawing their rays by `sampler` ([`Sampler::Random`]
    /// unless set).
    pub fn with_sampler(mut self, sampler: Sampler) -> Context<'a, C> {
        self.choice = sampler;
        self
    }

    /// How the estimators draw their rays.
    pub fn sampling(&self) -> Sampler {
        self.choice
    }

    /// This context with patch gathering using `control` ([`ControlVariate::Off`] unless set).
    /// With [`ControlVariate::Constant`] the context learns each patch's hemisphere over the
    /// rounds of patch gathering run on it, in the order they run (see `crate::control`): a
    /// context serves one run.
    pub fn with_control_variate(mut self, control: ControlVariate) -> Context<'a, C> {
        self.coverage = match control {
            ControlVariate::Off => None,
            ControlVariate::Constant => Some(Coverage::default()),
        };
        self
    }

    /// What the rounds of patch gathering have learned for the control variate; `None` when
    /// it is off.
    pub(crate) fn coverage(&self) -> Option<&Coverage> {
        self.coverage.as_ref()
    }

    /// True once the run is cancelled: a job that sees it casts nothing.
    pub(crate) fn cancelled(&self) -> bool {
        self.cancel.is_some_and(|c| c.load(Ordering::Relaxed))
    }

    /// [`Error::Cancelled`] once the run is cancelled: an estimator calls it after its
    /// parallel jobs, whose results are incomplete then.
    pub(crate) fn check_cancelled(&self) -> Result<(), Error> {
        if self.cancelled() {
            Err(Error::Cancelled)
        } else {
            Ok(())
        }
    }

    /// The mesh.
    pub fn mesh(&self) -> &'a Mesh {
        self.mesh
    }

    /// The ray caster.
    pub fn caster(&self) -> &'a C {
        self.caster
    }

    /// Uniform points and cosine rays on the patches.
    pub(crate) fn sampler(&self) -> &SurfaceSampler<'a> {
        &self.sampler
    }

    /// Emitters by power; `None` when nothing emits.
    pub(crate) fn emitters(&self) -> Option<&Discrete> {
        self.emitters.as_ref()
    }
}

/// How the estimators draw the points and directions of their rays (the command line's
/// `--sampler`). Either way every ray is distributed as its estimator needs (a uniform point
/// of the patch, a cosine-distributed direction), so every estimate is unbiased; what changes
/// is how the rays of one patch relate to each other. The default is [`Sampler::Qmc`]: about
/// 3x fewer rays to the same error for `combined` (docs/results.md), with honest variances.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Sampler {
    /// Independent pseudo-random rays ([`mcrad_random::Stream`]).
    Random,
    /// Randomised quasi-Monte Carlo: the rays of a patch are the points of its own
    /// Owen-scrambled Sobol sequence ([`mcrad_random::Sobol`]), indexed by the patch's ray
    /// counter (in shooting, continued across waves), so they are stratified in point and
    /// direction; each patch and pass has an independent scramble. The sequence interleaves two
    /// independent scrambles, whose difference scales the estimators' variances to the
    /// stratified rays' true error (the module `replicates` of this crate has the maths).
    #[default]
    Qmc,
}

impl Sampler {
    /// Every sampler, in the order the command line lists them.
    pub const ALL: [Sampler; 2] = [Sampler::Random, Sampler::Qmc];

    /// The name on the command line and in run statistics: `random` or `qmc`.
    pub const fn name(self) -> &'static str {
        match self {
            Sampler::Random => "random",
            Sampler::Qmc => "qmc",
        }
    }
}

impl std::str::FromStr for Sampler {
    type Err = crate::UnknownName;

    /// The sampler of a [name](Sampler::name) (exactly).
    fn from_str(s: &str) -> Result<Sampler, crate::UnknownName> {
        crate::method::parse_name(s, &Sampler::ALL, Sampler::name, "sampler")
    }
}

impl std::fmt::Display for Sampler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The share of the mesh's area that may lie in patches smaller than its `f32` coordinates
/// resolve (`Mesh::resolved_size`: [`mcrad_meshing::F32_SPACINGS_PER_PATCH`] spacings) before
/// a run is refused. Points on patches are drawn and rays start in `f32` coordinates of the
/// mesh's local frame (`Mesh::origin`), and the ray caster lifts origins by a few `f32`
/// spacings of the coordinate's magnitude, so the relative error of a patch's answer is of the
/// order of a few spacings per patch size: a unit furnace in patches of 1/12 gave the origin's
/// answer at 1e3 from it (ratio 7e-4), -0.04% at 1e4 (1.2e-2), -0.36% at 1e5, +10% at 1e6 and
/// a panic at 1e7 (measured before meshes were stored relative to their local origin). A few
/// slivers (real models have them) are approximate on their own tiny area and are accepted
/// (the pipeline warns); a mesh whose unresolved patches hold more than this share would be
/// wrong where it matters.
pub(crate) const MAX_UNRESOLVED_AREA_SHARE: f64 = 0.01;

/// Checks that `f32` coordinates of the mesh's local frame resolve its patches, all but
/// slivers of at most [`MAX_UNRESOLVED_AREA_SHARE`] of the area ([`Error::FarFromOrigin`]
/// otherwise, naming the smallest patch).
pub(crate) fn check_precision(mesh: &Mesh) -> Result<(), Error> {
    let (count, area) = mesh.unresolved_patches();
    if count == 0 || area <= MAX_UNRESOLVED_AREA_SHARE * mesh.total_area() {
        return Ok(());
    }
    let coordinate = mesh
        .positions()
        .iter()
        .map(|p| f64::from(p.abs().max_element()))
        .fold(0.0, f64::max);
    let spacing = coordinate * f64::from(f32::EPSILON);
    let Some((patch, smallest)) = mesh
        .patches()
        .iter()
        .map(|p| p.area)
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(&b.1))
    else {
        return Ok(());
    };
    Err(Error::FarFromOrigin {
        coordinate,
        spacing,
        patch,
        size: smallest.max(0.0).sqrt(),
        unresolved: count,
        share: area / mesh.total_area(),
    })
}
