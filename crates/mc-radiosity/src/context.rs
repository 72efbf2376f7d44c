//! What every estimator of a run shares, built once: the mesh, the ray caster, the surface
//! sampler and the emitter sampler.

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
    sampler: SurfaceSampler,
    emitters: Option<Discrete>,
    cancel: Option<&'a AtomicBool>,
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
            emitters: Discrete::new(&power),
            cancel: None,
        }
    }

    /// This context with a cancellation flag: once `cancel` is true, the estimators skip the
    /// jobs not yet started and return [`Error::Cancelled`] (the flag only stops work; it
    /// never changes a result that is returned).
    pub fn with_cancel(mut self, cancel: Option<&'a AtomicBool>) -> Context<'a, C> {
        self.cancel = cancel;
        self
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
    pub(crate) fn sampler(&self) -> &SurfaceSampler {
        &self.sampler
    }

    /// Emitters by power; `None` when nothing emits.
    pub(crate) fn emitters(&self) -> Option<&Discrete> {
        self.emitters.as_ref()
    }
}

/// The largest spacing of `f32` coordinates accepted, as a fraction of the smallest patch's size
/// (`sqrt(area)`): `2^-10`. Points on patches are drawn and rays start in `f32` coordinates
/// of the mesh's local frame (`Mesh::origin`), and the ray caster lifts origins by a few `f32`
/// spacings of the coordinate's magnitude, so the relative error of an answer is of the order of a few spacings per patch
/// size: a unit furnace in patches of 1/12 gave the origin's answer at 1e3 from it (ratio 7e-4),
/// -0.04% at 1e4 (1.2e-2), -0.36% at 1e5, +10% at 1e6 and a panic at 1e7 (measured before
/// meshes were stored relative to their local origin; now the distance that matters is from the
/// scene's centre).
pub(crate) const MAX_SPACING_PER_SIZE: f64 = 1.0 / 1024.0;

/// Checks that `f32` coordinates of the mesh's local frame resolve its smallest patch
/// everywhere in the scene ([`Error::FarFromOrigin`] otherwise).
pub(crate) fn check_precision(mesh: &Mesh) -> Result<(), Error> {
    let coordinate = mesh
        .positions()
        .iter()
        .map(|p| f64::from(p.abs().max_element()))
        .fold(0.0, f64::max);
    let spacing = coordinate * f64::from(f32::EPSILON);
    let Some((patch, area)) = mesh
        .patches()
        .iter()
        .map(|p| p.area)
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(&b.1))
    else {
        return Ok(());
    };
    let size = area.max(0.0).sqrt();
    if spacing > MAX_SPACING_PER_SIZE * size {
        return Err(Error::FarFromOrigin {
            coordinate,
            spacing,
            patch,
            size,
        });
    }
    Ok(())
}
