//! What every estimator of a run shares, built once: the mesh, the ray caster, the surface
//! sampler and the emitter sampler.

use crate::sampling::Discrete;
use crate::surface::SurfaceSampler;
use mcrad_meshing::Mesh;
use mcrad_raycast::RayCaster;

/// The scene an estimator works on: the `mesh` (patches with area, reflectance `rho` and
/// emission `E` in W/m²), the `caster` that finds first hits on it, and the samplers derived
/// from the mesh once per run: uniform points and cosine-distributed rays on each patch, and
/// emitters drawn in proportion to their power `sum_c E_c A` (W).
pub struct Context<'a, C: RayCaster> {
    mesh: &'a Mesh,
    caster: &'a C,
    sampler: SurfaceSampler,
    emitters: Option<Discrete>,
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
