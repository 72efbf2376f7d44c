//! The memory a solve will need at its peak, estimated before any work from the face count,
//! the mesh plan, the method and the ray budget: [`Problem::memory_estimate`], held to
//! [`Budget::memory`].

use crate::problem::Input;
use crate::{MeshPlan, Problem};
use mcrad_mc_radiosity::Method;
use mcrad_meshing::{DEFAULT_MAX_PATCHES, Mesh, Subdivision};
use mcrad_scene_io::Scene;

/// Bytes per element (patch) a solve holds whatever its rays: the patch and its triangles,
/// the BVH and its build, the adaptive hierarchy, the sampler, the method's dense per-patch
/// arrays (shooting's unshot and reflected power and rays cast, the steps' copy, the
/// refinement's pooled estimate, the answer) and the allocator's slack. Measured peak RSS on
/// the generated atrium of 10^6 elements at 2e6 rays, where a tenth of the patches get a
/// deposit (docs/meshing.md, "Memory per element"): 575-620 bytes per element (median 589,
/// against 651 before), of which about 60 are the rows of the patches reached
/// ([`BYTES_PER_REACHED`]) and 66 the fixed part.
pub const BYTES_PER_ELEMENT: u64 = 400;

/// Bytes per element a shooting ray's first deposit adds: its error samples (four rows of
/// 24 `f32`, 384 bytes), the slots of its last rays (64) and its replicate sums and sums of
/// squares (128), in blocks that never move, made only for patches a deposit lands on, so at
/// most `min(elements, rays)` of them.
pub const BYTES_PER_REACHED: u64 = 600;

/// Bytes per element a gathering pass adds (the gathers' merged estimate and their image of
/// the shooting's error samples, held through the next pass's shooting beside the earlier
/// passes' shooting estimate and samples): measured with [`BYTES_PER_ELEMENT`] and
/// [`BYTES_PER_REACHED`] at 2e7 rays on the 10^6-element atrium, about 1,150 bytes per
/// element in all. A method gathers on a mesh of `P` patches only with at least
/// [`gather_rays_per_element`] `P` rays, so at most `min(elements, rays / k)` elements.
pub const BYTES_PER_GATHERED: u64 = 250;

/// Bytes of a process before its scene: code, thread stacks, the allocator's arenas.
pub const BYTES_FIXED: u64 = 64 << 20;

/// The fewest rays per patch with which `method` gathers at every patch (`k`): 8 for
/// `combined` (its passes pay for 2 emitter samples and 2 gathering rays a patch and a
/// shooting share, else it shoots alone), 2 for the others (a gathering round casts at least
/// two rays a patch).
pub fn gather_rays_per_element(method: Method) -> u64 {
    match method {
        Method::Combined => 8,
        _ => 2,
    }
}

/// The memory model's peak in bytes for a solve of `elements` elements (patches) and at most
/// `rays` rays (`u64::MAX`: no limit, a time budget) by `method`, beside `scene_bytes` of
/// scene: [`BYTES_FIXED`] + scene + `elements` [`BYTES_PER_ELEMENT`] +
/// `min(elements, rays)` [`BYTES_PER_REACHED`] + `min(elements, rays / k)`
/// [`BYTES_PER_GATHERED`] (`k`: [`gather_rays_per_element`]). Nondecreasing in each argument.
pub fn peak_bytes(elements: u64, rays: u64, method: Method, scene_bytes: u64) -> u64 {
    let reached = elements.min(rays);
    let gathered = elements.min(rays / gather_rays_per_element(method));
    BYTES_FIXED
        .saturating_add(scene_bytes)
        .saturating_add(elements.saturating_mul(BYTES_PER_ELEMENT))
        .saturating_add(reached.saturating_mul(BYTES_PER_REACHED))
        .saturating_add(gathered.saturating_mul(BYTES_PER_GATHERED))
}

/// What [`Problem::memory_estimate`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemoryEstimate {
    /// The most elements (patches) the plan can make: the adaptive budget (one per input face
    /// plus half of `max_patches` when that is more, back sides included; the default budget
    /// as far as the rays grow it, [`crate::PATCH_RAYS`]), an upper estimate of
    /// a uniform cut, or one per face and side; for the reference solver at most one past its
    /// patch limit (it refuses a larger mesh itself, as it builds it).
    pub elements: u64,
    /// The scene's own arrays (faces, vertex indices, positions, texture pixels), in bytes.
    pub scene_bytes: u64,
    /// The rays the estimate assumes: the budget's ([`Budget::total_rays`](crate::Budget::total_rays);
    /// `u64::MAX` under a time budget alone, when every element is taken to be reached and
    /// gathered).
    pub rays: u64,
    /// The estimated peak of the whole solve in bytes, [`peak_bytes`] of the above. An upper
    /// estimate, not a measurement.
    pub bytes: u64,
}

impl MemoryEstimate {
    /// The estimate's bytes per element beyond the fixed part and the scene (0 without
    /// elements).
    pub fn per_element(&self) -> u64 {
        self.bytes
            .saturating_sub(BYTES_FIXED + self.scene_bytes)
            .checked_div(self.elements)
            .unwrap_or(0)
    }
}

impl Problem<'_> {
    /// An upper estimate of the memory this solve needs at its peak (bytes), computed from the
    /// face count, the mesh plan, the method and the ray budget ([`peak_bytes`]; a time
    /// budget without rays is taken as unlimited rays) before anything is meshed: [`crate::solve`] refuses a
    /// problem whose estimate exceeds [`Budget::memory`](crate::Budget::memory)
    /// ([`Error::Memory`](crate::Error::Memory)). Linear in the faces; no allocation beyond
    /// the scene's.
    pub fn memory_estimate(&self) -> MemoryEstimate {
        self.estimate_within(self.grown_patches())
    }

    /// The most patches the default adaptive budget ([`MeshPlan::Adaptive`] without
    /// `max_patches`) may grow to in this problem: one per [`crate::PATCH_RAYS`] rays of the
    /// budget (all of [`crate::MAX_GROWN_PATCHES`] under a time budget alone), and no more than
    /// [`Budget::memory`](crate::Budget::memory) leaves room for by [`Problem::memory_estimate`]
    /// (never below [`DEFAULT_MAX_PATCHES`]: a limit the default budget exceeds refuses the
    /// problem as before).
    pub fn grown_patches(&self) -> usize {
        let rays = self.budget.total_rays() / crate::PATCH_RAYS;
        let want = usize::try_from(rays)
            .unwrap_or(usize::MAX)
            .clamp(DEFAULT_MAX_PATCHES, crate::MAX_GROWN_PATCHES);
        // only the default adaptive plan grows: others are estimated without the growth
        let grows = matches!(
            self.settings.mesh,
            MeshPlan::Adaptive {
                max_patches: None,
                ..
            }
        ) && !self.settings.deterministic();
        let Some(limit) = self.budget.memory.filter(|_| grows) else {
            return want;
        };
        let fits = |n: usize| self.estimate_within(n).bytes <= limit;
        if fits(want) {
            return want;
        }
        // the estimate grows with the budget: the largest that fits, by bisection
        let (mut low, mut high) = (DEFAULT_MAX_PATCHES, want);
        while high - low > 1 {
            let mid = low + (high - low) / 2;
            if fits(mid) {
                low = mid;
            } else {
                high = mid;
            }
        }
        low
    }

    /// [`Problem::memory_estimate`] with the default adaptive budget grown to `grown` patches.
    pub(crate) fn estimate_within(&self, grown: usize) -> MemoryEstimate {
        let (elements, scene_bytes) = match self.input {
            Input::Mesh(mesh) => (mesh.patches().len() as u64, 0),
            Input::Scene(scene) => (plan_elements(scene, self, grown), scene_bytes(scene)),
            Input::SceneOnce(held) => match held.lock().ok().as_deref().and_then(Option::as_ref) {
                Some(scene) => (plan_elements(scene, self, grown), scene_bytes(scene)),
                None => (0, 0),
            },
        };
        let rays = self.budget.total_rays();
        MemoryEstimate {
            elements,
            scene_bytes,
            rays,
            bytes: peak_bytes(elements, rays, self.settings.method, scene_bytes),
        }
    }
}

/// The most elements the plan of `problem` makes on `scene`, the default adaptive budget grown
/// to `grown` patches.
fn plan_elements(scene: &Scene, problem: &Problem, grown: usize) -> u64 {
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
            // the default budget grows with the rays (all the way under a time budget)
            let max_patches = max_patches.unwrap_or(grown) as u64;
            let budget = max_patches.max(faces.saturating_add(max_patches / 2));
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
