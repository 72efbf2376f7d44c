//! The memory a solve will need at its peak, estimated before any work from the face count and
//! the mesh plan: [`Problem::memory_estimate`], held to [`Budget::memory`].

use crate::problem::Input;
use crate::{MeshPlan, Problem};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_scene_io::Scene;

/// Bytes per element (patch) at a solve's peak, all it holds per element together: the patch
/// and its triangles, the BVH, the sampler, the method's per-patch state (shooting's sums and
/// replicates, gathering's, the estimates of the steps and the refinement) and the
/// allocator's slack. Measured peak RSS on the generated atrium at 2e6 rays (docs/atrium.md,
/// "Memory and scale"): 638 bytes per element at 10^6 elements, 524 at 10^7, which this
/// bounds. The error samples grow with the rays (up to 384 bytes a patch in shooting, more in
/// the gathering): at 20 rays per element the 10^6-element atrium peaked at 1,744, over it.
pub const BYTES_PER_ELEMENT: u64 = 1_100;

/// Bytes of a process before its scene: code, thread stacks, the allocator's arenas.
pub const BYTES_FIXED: u64 = 64 << 20;

/// What [`Problem::memory_estimate`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemoryEstimate {
    /// The most elements (patches) the plan can make: the adaptive budget (one per input face
    /// plus half of `max_patches` when that is more, back sides included), an upper estimate of
    /// a uniform cut, or one per face and side; for the reference solver at most one past its
    /// patch limit (it refuses a larger mesh itself, as it builds it).
    pub elements: u64,
    /// The scene's own arrays (faces, vertex indices, positions, texture pixels), in bytes.
    pub scene_bytes: u64,
    /// The estimated peak of the whole solve in bytes: [`BYTES_FIXED`], the scene, and
    /// [`BYTES_PER_ELEMENT`] per element. An upper estimate, not a measurement.
    pub bytes: u64,
}

impl Problem<'_> {
    /// An upper estimate of the memory this solve needs at its peak (bytes), computed from the
    /// face count and the mesh plan before anything is meshed: [`crate::solve`] refuses a
    /// problem whose estimate exceeds [`Budget::memory`](crate::Budget::memory)
    /// ([`Error::Memory`](crate::Error::Memory)). Linear in the faces; no allocation beyond
    /// the scene's.
    pub fn memory_estimate(&self) -> MemoryEstimate {
        let (elements, scene_bytes) = match self.input {
            Input::Mesh(mesh) => (mesh.patches().len() as u64, 0),
            Input::Scene(scene) => (plan_elements(scene, self), scene_bytes(scene)),
            Input::SceneOnce(held) => match held.lock().ok().as_deref().and_then(Option::as_ref) {
                Some(scene) => (plan_elements(scene, self), scene_bytes(scene)),
                None => (0, 0),
            },
        };
        let bytes = BYTES_FIXED
            .saturating_add(scene_bytes)
            .saturating_add(elements.saturating_mul(BYTES_PER_ELEMENT));
        MemoryEstimate {
            elements,
            scene_bytes,
            bytes,
        }
    }
}

/// The most elements the plan of `problem` makes on `scene`.
fn plan_elements(scene: &Scene, problem: &Problem) -> u64 {
    let faces = scene.faces().len() as u64;
    let two_sided = scene
        .faces()
        .iter()
        .filter(|f| scene.is_two_sided(f.material))
        .count() as u64;
    let per_face = faces + two_sided;
    let elements = match problem.settings.mesh {
        MeshPlan::PerFace => per_face,
        MeshPlan::Uniform { max_edge } => {
            let subdivision = match max_edge {
                Some(l) => Subdivision::MaxEdge(l),
                None => Subdivision::default_for(scene),
            };
            let cut = Mesh::estimate_patches(scene, subdivision);
            // a back side doubles its front's pieces: at most twice the cut
            if two_sided > 0 {
                cut.saturating_mul(2)
            } else {
                cut
            }
        }
        MeshPlan::Adaptive { .. } if problem.settings.deterministic() => {
            Mesh::estimate_patches(scene, Subdivision::default_for(scene))
                .saturating_mul(if two_sided > 0 { 2 } else { 1 })
        }
        MeshPlan::Adaptive { max_patches, .. } => {
            let budget = (max_patches as u64).max(faces.saturating_add(max_patches as u64 / 2));
            budget.max(per_face)
        }
    };
    if problem.settings.deterministic() {
        // the reference solver refuses a larger mesh while it is built, with its own message
        let limit = mcrad_reference::ReferenceConfig::default().max_patches as u64;
        elements.min(limit.saturating_add(1))
    } else {
        elements
    }
}

/// The bytes of `scene`'s arrays: faces (with their vertex lists), positions, texture pixels.
fn scene_bytes(scene: &Scene) -> u64 {
    let faces: u64 = scene
        .faces()
        .iter()
        .map(|f| (size_of::<mcrad_scene_io::Face>() + 4 * f.vertices.len()) as u64)
        .sum();
    let positions = size_of_val(scene.positions()) as u64;
    let textures = scene.textures().map_or(0, |t| t.heap_bytes() as u64);
    faces + positions + textures
}

/// `bytes` for a message: `812.3 KiB`, `1.2 GiB`.
pub(crate) fn show_bytes(bytes: u64) -> String {
    const UNITS: [&str; 4] = ["KiB", "MiB", "GiB", "TiB"];
    if bytes < 1024 {
        return format!("{bytes} bytes");
    }
    let mut value = bytes as f64 / 1024.0;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    format!("{value:.1} {}", UNITS[unit])
}
