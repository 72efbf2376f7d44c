//! The mesh type and its construction from a scene.

use crate::subdivide::Cutter;
use glam::{DVec3, Vec3};
use mcrad_scene_io::{Scene, SceneTextures};
use rayon::prelude::*;
use std::sync::Arc;

/// How faces become patches.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Subdivision {
    /// One patch per input face, in face order (patch `i` is face `faces()[i]` when every face
    /// is one-sided; a two-sided face's back side follows its front).
    None,
    /// Cut every face uniformly until no patch edge is longer than this length (scene units,
    /// finite and `> 0`).
    MaxEdge(f32),
}

/// The default patch size as a fraction of the scene's size: no patch edge longer than the
/// bounding-box diagonal / 20 ([`Subdivision::default_for`]).
pub const DEFAULT_MAX_EDGE_FRACTION: f32 = 1.0 / 20.0;

impl Subdivision {
    /// The default subdivision of `scene`: [`Subdivision::MaxEdge`] of
    /// [`DEFAULT_MAX_EDGE_FRACTION`] times its bounding-box diagonal (scene units).
    pub fn default_for(scene: &Scene) -> Subdivision {
        Subdivision::MaxEdge(scene.bounds().diagonal() as f32 * DEFAULT_MAX_EDGE_FRACTION)
    }
}

/// Why a mesh could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshError {
    /// The maximum edge length is not a positive finite number.
    #[error("the maximum patch edge must be a positive length in scene units, got {0}")]
    BadMaxEdge(f32),
    /// The minimum edge of an adaptive mesh is not a positive finite number.
    #[error("the minimum element edge must be a positive length in scene units, got {0}")]
    BadMinEdge(f32),
    /// The patch budget of an adaptive mesh is zero.
    #[error("the patch budget of an adaptive mesh must be at least 1")]
    BadMaxPatches,
    /// Subdivision would create more patches than the limit (checked before any work).
    #[error(
        "subdividing to edges of at most {max_edge} scene units would make about {estimate:.1e} \
         patches, more than the limit of {limit:.1e}"
    )]
    TooManyPatches {
        /// The requested maximum edge length (scene units).
        max_edge: f32,
        /// Estimated patch count.
        estimate: u64,
        /// The limit.
        limit: u64,
    },
    /// The mesh has more patches than the caller's limit of [`Mesh::build_at_most`] (found
    /// while building, which stops there).
    #[error("the mesh has more than {limit} patches")]
    PatchLimit {
        /// The limit.
        limit: usize,
    },
    /// The leaves an adaptive mesh's start was cut into differ from their count (an internal
    /// error: both follow the same rules).
    #[error("the adaptive mesh's start was cut into another number of leaves than counted")]
    StartCount,
    /// [`Mesh::clustered`] got another number of group numbers than the mesh has patches.
    #[error("{got} group numbers for a mesh of {patches} patches")]
    GroupCount {
        /// The mesh's patches.
        patches: usize,
        /// The group numbers given.
        got: usize,
    },
    /// A recorded refinement ([`crate::History`]) does not apply to this scene and bounds.
    #[error(
        "refinement {round} of the recorded mesh split {recorded} elements, on this scene only \
         {split}: another scene, or other mesh bounds"
    )]
    BadHistory {
        /// The refinement (from 0).
        round: usize,
        /// Leaves it split when recorded.
        recorded: usize,
        /// Leaves it split now.
        split: usize,
    },
}

/// How many `f32` spacings a patch must span: a patch whose size (`sqrt(area)`) is below this
/// many spacings of `f32` coordinates at the mesh's largest coordinate (its local frame, see
/// [`Mesh::origin`]) is not resolved by its geometry ([`Mesh::resolved_size`]). Points drawn on it
/// and ray origins lifted off it are off by a few spacings, a relative error of about
/// `1 / F32_SPACINGS_PER_PATCH` of its size.
pub const F32_SPACINGS_PER_PATCH: f64 = 1024.0;

/// The most patches a mesh may have (indices stay below `2^31`, and memory in reach).
pub const MAX_PATCHES: u64 = 1 << 28;

/// One patch: a planar convex polygon.
#[derive(Debug, Clone, PartialEq)]
pub struct Patch {
    /// Area `A_i` in scene units², computed in f64, `> 0`. On an alpha-tested face (glTF
    /// `MASK` or `BLEND`) the area of its opaque part: the polygon's area times its opaque
    /// fraction ([`SceneTextures::coverage`], at least [`MIN_COVERAGE`]), so that `B_i` is the
    /// exitance of the opaque surface and `B_i A_i` its power.
    pub area: f64,
    /// Unit geometric normal on the front side (vertices counter-clockwise seen from it).
    pub normal: Vec3,
    /// Area centroid (scene units, in the mesh's local frame: see [`Mesh::origin`]).
    pub centroid: Vec3,
    /// Diffuse reflectance `rho_i` per RGB channel, each in `[0, 1)`.
    pub reflectance: Vec3,
    /// Emitted radiosity `E_i` per RGB channel, W/m², `>= 0`.
    pub emission: Vec3,
    /// The input face number this patch comes from ([`mcrad_scene_io::Face::source`]).
    pub face: u32,
    /// The material index in the scene.
    pub material: u32,
    /// The back side of a two-sided face ([`mcrad_scene_io::Scene::is_two_sided`]): the
    /// patch right before it in mesh order is its front, with the same polygon (corners in
    /// reverse order from the same first one), area, reflectance and emission, and the
    /// opposite normal. Each side has a radiosity of its own. `false` for every patch of a
    /// one-sided face and for fronts.
    pub back: bool,
    /// The polygons it is made of: 1 for a patch cut from one face; a cluster's member count
    /// (see [`Mesh::clustered`]), whose corners are its members' one after the other.
    pub(crate) polygons: u16,
    pub(crate) first_corner: u32,
    pub(crate) corner_count: u32,
    /// Its triangles are a fan over each polygon's corners: `corner_count - 2 polygons` of
    /// them from here.
    pub(crate) first_triangle: u32,
}

impl Patch {
    /// The number of its triangles: a fan over each of its polygons' corners.
    pub(crate) fn triangle_count(&self) -> usize {
        (self.corner_count as usize).saturating_sub(2 * self.polygons as usize)
    }

    /// Whether it is a cluster of several input faces (see [`Mesh::clustered`]): not planar,
    /// each of its triangles with a normal of its own ([`Mesh::triangle_normal`]).
    pub fn is_cluster(&self) -> bool {
        self.polygons > 1
    }
}

/// The radiosity mesh. Invariants (see [`Mesh::validate`]): every patch has >= 3 corners and >= 1
/// triangle, positive finite area, unit normal; triangle `t` belongs to patch
/// `triangle_patch()[t]`; each patch's triangles are contiguous and in patch order.
///
/// Positions, centroids and everything made from them are in the mesh's **local frame**: the
/// world point of a local point `p` is `p + origin()` (see [`Mesh::origin`]). A scene far from
/// the world origin thus keeps the `f32` resolution of a scene at the origin.
#[derive(Debug, Clone)]
pub struct Mesh {
    origin: Vec3,
    // The geometry is shared between clones (a mesh lit for a pass, a coarser mesh over the
    // same positions) until one of them changes it.
    positions: Arc<Vec<Vec3>>,
    corners: Arc<Vec<u32>>,
    triangles: Arc<Vec<[u32; 3]>>,
    triangle_patch: Arc<Vec<u32>>,
    patches: Vec<Patch>,
    /// Faces (or fan triangles of polygons) kept whole because cutting them would have made
    /// patches below [`Mesh::resolved_size`].
    kept_whole: usize,
    /// The scene's textured faces: a patch of one takes its reflectance and emission from the
    /// texture over its own area.
    textures: Option<Arc<SceneTextures>>,
}

impl Mesh {
    /// Builds the mesh of `scene` with the given subdivision.
    pub fn build(scene: &Scene, subdivision: Subdivision) -> Result<Mesh, MeshError> {
        Mesh::build_at_most(scene, subdivision, usize::MAX)
    }

    /// [`Mesh::build`], refusing a mesh of more than `max_patches` patches
    /// ([`MeshError::PatchLimit`]) as soon as the faces built so far exceed it, so that a
    /// caller with a small limit (the reference solver's) refuses a huge mesh at once.
    pub fn build_at_most(
        scene: &Scene,
        subdivision: Subdivision,
        max_patches: usize,
    ) -> Result<Mesh, MeshError> {
        let max_edge = checked_max_edge(scene, subdivision)?;
        let origin = local_origin(scene);
        let mut mesh = Mesh {
            origin,
            positions: Arc::new(local_positions(scene, origin)),
            corners: Arc::default(),
            triangles: Arc::default(),
            triangle_patch: Arc::default(),
            patches: Vec::new(),
            kept_whole: 0,
            textures: scene.textures().cloned(),
        };
        let mut cutter = Cutter::keeping_whole_below(mesh.resolved_size());
        for face in scene.faces() {
            let material = &scene.materials()[face.material as usize];
            let template = PatchTemplate {
                reflectance: material.reflectance,
                emission: material.emission,
                face: face.source,
                material: face.material,
                two_sided: scene.is_two_sided(face.material),
            };
            match max_edge {
                None => mesh.push_patch(&face.vertices, &template),
                Some(l) => {
                    // every patch cut from it is a triangle or quad of edges <= l (area <= l²):
                    // refuse before cutting a face that alone would pass the limit
                    let at_least = scene.face_area(face) / (l as f64 * l as f64);
                    if mesh.patches.len() as f64 + at_least.floor() > max_patches as f64 {
                        return Err(MeshError::PatchLimit { limit: max_patches });
                    }
                    cutter.cut_face(&mut mesh, &face.vertices, l, &template);
                }
            }
            if mesh.patches.len() > max_patches {
                return Err(MeshError::PatchLimit { limit: max_patches });
            }
        }
        mesh.kept_whole = cutter.kept_whole();
        // the arrays grew by doubling: up to half of each is spare
        mesh.shrink_to_fit();
        Ok(mesh)
    }

    /// The number of patches [`Mesh::build`] makes of `scene` with `subdivision` (a two-sided
    /// face's back sides counted), without building it: the same cuts counted face by face,
    /// in parallel on rayon's pool. Errors as [`Mesh::build`]'s.
    pub fn count_patches(scene: &Scene, subdivision: Subdivision) -> Result<u64, MeshError> {
        let max_edge = checked_max_edge(scene, subdivision)?;
        let positions = match max_edge {
            Some(_) => local_positions(scene, local_origin(scene)),
            None => Vec::new(),
        };
        let cut = max_edge.map(|l| (l, resolved_size_at(max_coordinate(&positions))));
        Ok(scene
            .faces()
            .par_iter()
            .map_init(Vec::new, |pos, face| {
                patches_of_face(scene, face, &positions, cut, pos)
            })
            .sum())
    }

    /// A mesh without vertices or patches (to be filled by `push_position`/`push_patch`) whose
    /// local frame has its origin at world point `origin`, its patches textured by `textures`.
    pub(crate) fn empty(origin: Vec3, textures: Option<Arc<SceneTextures>>) -> Mesh {
        Mesh {
            origin,
            positions: Arc::default(),
            corners: Arc::default(),
            triangles: Arc::default(),
            triangle_patch: Arc::default(),
            patches: Vec::new(),
            kept_whole: 0,
            textures,
        }
    }

    /// The smallest patch size (`sqrt(area)`, scene units) that this mesh's `f32` coordinates
    /// resolve: [`F32_SPACINGS_PER_PATCH`] spacings of `f32` at its largest coordinate in the
    /// local frame (0 for a mesh without vertices). Uniform cuts keep a face whole rather than
    /// cut it below this, adaptive splits refuse to go below it.
    pub fn resolved_size(&self) -> f64 {
        resolved_size_at(max_coordinate(&self.positions))
    }

    /// The patches smaller than [`Mesh::resolved_size`] (whole slivers): their count and their
    /// summed area (scene units², f64). Their own radiosity is approximate (see
    /// [`F32_SPACINGS_PER_PATCH`]); the rest of the answer is not affected beyond their share
    /// of the light.
    pub fn unresolved_patches(&self) -> (usize, f64) {
        let limit = self.resolved_size();
        let limit2 = limit * limit;
        self.patches
            .iter()
            .filter(|p| p.area < limit2)
            .fold((0, 0.0), |(n, a), p| (n + 1, a + p.area))
    }

    /// Faces (or fan triangles of polygons) that a uniform cut kept whole because their pieces
    /// would have been smaller than [`Mesh::resolved_size`] (slivers at the scene's size): such a
    /// patch may have edges longer than the cut's maximum.
    pub fn kept_whole(&self) -> usize {
        self.kept_whole
    }

    /// Sets the count [`Mesh::kept_whole`] reports (an adaptive mesh carries its start's).
    pub(crate) fn set_kept_whole(&mut self, n: usize) {
        self.kept_whole = n;
    }

    /// A mesh over this one's positions (and origin, textures and count of faces kept whole)
    /// with the given corners, triangles and patches.
    pub(crate) fn with_patches(
        &self,
        corners: Vec<u32>,
        triangles: Vec<[u32; 3]>,
        triangle_patch: Vec<u32>,
        patches: Vec<Patch>,
    ) -> Mesh {
        Mesh {
            origin: self.origin,
            positions: Arc::clone(&self.positions),
            corners: Arc::new(corners),
            triangles: Arc::new(triangles),
            triangle_patch: Arc::new(triangle_patch),
            patches,
            kept_whole: self.kept_whole,
            textures: self.textures.clone(),
        }
    }

    /// Releases the spare capacity of the arrays it does not share.
    pub(crate) fn shrink_to_fit(&mut self) {
        fn shrink<T>(a: &mut Arc<Vec<T>>) {
            if let Some(v) = Arc::get_mut(a) {
                v.shrink_to_fit();
            }
        }
        shrink(&mut self.positions);
        shrink(&mut self.corners);
        shrink(&mut self.triangles);
        shrink(&mut self.triangle_patch);
        self.patches.shrink_to_fit();
    }

    /// Bytes of the mesh's arrays (their capacities, shared ones included; allocator overhead
    /// not counted).
    pub fn heap_bytes(&self) -> usize {
        self.positions.capacity() * size_of::<Vec3>()
            + self.corners.capacity() * size_of::<u32>()
            + self.triangles.capacity() * size_of::<[u32; 3]>()
            + self.triangle_patch.capacity() * size_of::<u32>()
            + self.patches.capacity() * size_of::<Patch>()
    }

    /// Appends a vertex and returns its index.
    pub(crate) fn push_position(&mut self, p: Vec3) -> u32 {
        let positions = Arc::make_mut(&mut self.positions);
        positions.push(p);
        (positions.len() - 1) as u32
    }

    /// Position of vertex `i`.
    pub(crate) fn position(&self, i: u32) -> Vec3 {
        self.positions[i as usize]
    }

    /// Appends a convex planar polygon patch with the given corner indices (counter-clockwise),
    /// and right after it its back side when the template is two-sided.
    pub(crate) fn push_patch(&mut self, corners: &[u32], t: &PatchTemplate) {
        self.push_front(corners, t);
        if t.two_sided {
            self.push_back_side();
        }
    }

    /// Sets the mesh's patches to `count` polygons over its positions, made in parallel on
    /// rayon's pool, as [`Mesh::push_patch`] would push them one by one: `corners` holds
    /// each patch's corner vertices in patch order (a back side's as
    /// [`Mesh::push_patch`] makes them from its front's) and `side(i)` gives patch `i`'s
    /// corner count, whether it is the back side of patch `i - 1`, and its template.
    pub(crate) fn set_polygons(
        &mut self,
        corners: Vec<u32>,
        count: usize,
        side: impl Fn(usize) -> (usize, bool, PatchTemplate) + Sync,
    ) {
        // patch i's corners start at first[i]; its triangles (a fan of count - 2) at
        // first[i] - 2 i
        let mut first = Vec::with_capacity(count + 1);
        let mut at = 0u32;
        for i in 0..count {
            first.push(at);
            at += side(i).0 as u32;
        }
        first.push(at);
        let front = |i: usize, t: &PatchTemplate| {
            let (s, e) = (first[i] as usize, first[i + 1] as usize);
            self.front_patch(&corners[s..e], t, first[i], first[i] - 2 * i as u32)
        };
        let patches: Vec<Patch> = (0..count)
            .into_par_iter()
            .with_min_len(1 << 12)
            .map(|i| {
                let (_, back, t) = side(i);
                if back && i > 0 {
                    let f = front(i - 1, &t);
                    Patch {
                        normal: -f.normal,
                        back: true,
                        first_corner: first[i],
                        first_triangle: first[i] - 2 * i as u32,
                        ..f
                    }
                } else {
                    front(i, &t)
                }
            })
            .collect();
        let triangle_count = at as usize - 2 * count;
        let mut triangles = Vec::with_capacity(triangle_count);
        let mut triangle_patch = Vec::with_capacity(triangle_count);
        for (i, p) in patches.iter().enumerate() {
            if p.back {
                // the front's triangles, each turned over
                let f = &patches[i - 1];
                let s = f.first_triangle as usize;
                for k in s..s + f.triangle_count() {
                    let t: [u32; 3] = triangles[k];
                    triangles.push([t[0], t[2], t[1]]);
                }
            } else {
                let c = &corners[first[i] as usize..first[i + 1] as usize];
                for w in c[1..].windows(2) {
                    triangles.push([c[0], w[0], w[1]]);
                }
            }
            triangle_patch.extend(std::iter::repeat_n(i as u32, p.triangle_count()));
        }
        self.corners = Arc::new(corners);
        self.triangles = Arc::new(triangles);
        self.triangle_patch = Arc::new(triangle_patch);
        self.patches = patches;
    }

    /// Appends the back side of the last patch (see [`Patch::back`]).
    fn push_back_side(&mut self) {
        let front = self.patches.len() - 1;
        let f = self.patches[front].clone();
        let id = self.patches.len() as u32;
        let first_corner = self.corners.len() as u32;
        let first_triangle = self.triangles.len() as u32;
        let own = self.corners(&f).to_vec();
        let turned: Vec<[u32; 3]> = self.patch_triangles(&f).to_vec();
        let corners = Arc::make_mut(&mut self.corners);
        corners.push(own[0]);
        corners.extend(own[1..].iter().rev());
        let (triangles, triangle_patch) = (
            Arc::make_mut(&mut self.triangles),
            Arc::make_mut(&mut self.triangle_patch),
        );
        for t in turned {
            triangles.push([t[0], t[2], t[1]]);
            triangle_patch.push(id);
        }
        self.patches.push(Patch {
            normal: -f.normal,
            back: true,
            first_corner,
            first_triangle,
            ..f
        });
    }

    /// The other side of patch `i` when it belongs to a two-sided face (see [`Patch::back`]):
    /// `i + 1` for a front, `i - 1` for a back; `None` for a one-sided patch.
    ///
    /// # Panics
    /// If `i` is out of range.
    pub fn twin(&self, i: usize) -> Option<usize> {
        if self.patches[i].back {
            Some(i - 1)
        } else {
            self.patches.get(i + 1).filter(|p| p.back).map(|_| i + 1)
        }
    }

    /// What a back side adds to its face number in outputs (per-face rows, the `face` column):
    /// `N`, one more than the largest face number of the mesh (the input's face count unless
    /// its last faces were dropped), so the back of face `f` is `f + N`. 0 for a mesh without
    /// back sides. Computed over the patches (linear time).
    pub fn back_face_offset(&self) -> u32 {
        if !self.is_two_sided() {
            return 0;
        }
        self.patches
            .iter()
            .map(|p| p.face)
            .max()
            .map_or(0, |f| f.saturating_add(1))
    }

    /// Whether some patch is the back side of a two-sided face.
    pub fn is_two_sided(&self) -> bool {
        self.patches.iter().any(|p| p.back)
    }

    /// Appends one side of a patch.
    fn push_front(&mut self, corners: &[u32], t: &PatchTemplate) {
        let id = self.patches.len() as u32;
        let first_corner = self.corners.len() as u32;
        let first_triangle = self.triangles.len() as u32;
        Arc::make_mut(&mut self.corners).extend_from_slice(corners);
        let (triangles, triangle_patch) = (
            Arc::make_mut(&mut self.triangles),
            Arc::make_mut(&mut self.triangle_patch),
        );
        for w in corners[1..].windows(2) {
            triangles.push([corners[0], w[0], w[1]]);
            triangle_patch.push(id);
        }
        let patch = self.front_patch(corners, t, first_corner, first_triangle);
        self.patches.push(patch);
    }

    /// The patch of corners `corners` (vertex indices, counter-clockwise) and template `t`
    /// whose corners and triangles start at `first_corner` and `first_triangle`: its area,
    /// normal and centroid from the mesh's positions, its reflectance and emission from the
    /// template (times the texture's mean over it).
    pub(crate) fn front_patch(
        &self,
        corners: &[u32],
        t: &PatchTemplate,
        first_corner: u32,
        first_triangle: u32,
    ) -> Patch {
        let p0 = self.positions[corners[0] as usize].as_dvec3();
        let mut area2 = DVec3::ZERO; // twice the vector area
        let mut moment = DVec3::ZERO; // sum of (twice triangle area) * triangle centroid
        let mut doubled_areas = 0.0;
        for w in corners[1..].windows(2) {
            let (p1, p2) = (
                self.positions[w[0] as usize].as_dvec3(),
                self.positions[w[1] as usize].as_dvec3(),
            );
            let c = (p1 - p0).cross(p2 - p0);
            area2 += c;
            doubled_areas += c.length();
            moment += c.length() * (p0 + p1 + p2) / 3.0;
        }
        let normal = area2.normalize_or_zero();
        // a textured face: the material's factors times the texture's mean over this patch
        let (mut reflectance, mut emission) = (t.reflectance, t.emission);
        if let Some(textures) = &self.textures
            && let Some((albedo, glow)) = textures.average(t.face, &self.world_corners(corners))
        {
            reflectance = (reflectance * albedo).clamp(Vec3::ZERO, Vec3::splat(MAX_REFLECTANCE));
            emission = (emission * glow).max(Vec3::ZERO);
        }
        // an alpha-tested face: only the opaque part receives and reflects light
        let mut area = area2.length() / 2.0;
        if let Some(textures) = &self.textures
            && let Some(coverage) = textures.coverage(t.face, &self.world_corners(corners))
        {
            area *= f64::from(coverage.max(MIN_COVERAGE));
        }
        Patch {
            area,
            normal: normal.as_vec3(),
            centroid: if doubled_areas > 0.0 {
                (moment / doubled_areas).as_vec3()
            } else {
                p0.as_vec3()
            },
            reflectance,
            emission,
            face: t.face,
            material: t.material,
            back: false,
            polygons: 1,
            first_corner,
            corner_count: corners.len() as u32,
            first_triangle,
        }
    }

    /// The world positions of vertices `corners` (texture mappings are in world
    /// coordinates; the mesh in its local frame).
    fn world_corners(&self, corners: &[u32]) -> Vec<Vec3> {
        corners
            .iter()
            .map(|&c| (self.positions[c as usize].as_dvec3() + self.origin.as_dvec3()).as_vec3())
            .collect()
    }

    /// The scene's textures and alpha-tested faces this mesh was cut from, if any.
    pub fn textures(&self) -> Option<&Arc<SceneTextures>> {
        self.textures.as_ref()
    }

    /// The patches, in mesh order.
    pub fn patches(&self) -> &[Patch] {
        &self.patches
    }

    /// Its patches, the rest of it dropped.
    pub fn into_patches(self) -> Vec<Patch> {
        self.patches
    }

    /// The length of a table indexed by input face ([`Patch::face`]): one more than the
    /// largest face number of a patch (0 without patches). Faces that no patch comes from
    /// get a row too.
    pub fn face_count(&self) -> usize {
        self.patches
            .iter()
            .map(|p| p.face as usize + 1)
            .max()
            .unwrap_or(0)
    }

    /// Sets the emitted radiosity `E` (W/m² per channel) of patch `patch` (mesh order), for a
    /// solver that turns light from elsewhere (lights without a surface) into the light a
    /// patch sends out. Panics if `patch` is out of range.
    pub fn set_emission(&mut self, patch: usize, emission: Vec3) {
        self.patches[patch].emission = emission;
    }

    /// The world position (scene units) of the local frame's origin: every position of the
    /// mesh is relative to it. It is the centre of the scene's bounding box rounded to a
    /// multiple of `2^k`, the smallest power of two not below the box's diagonal, so it is
    /// exactly zero for a scene around the world origin (positions are then the input's, bit for
    /// bit) and, far from it, subtracting it from an input coordinate is exact.
    pub fn origin(&self) -> Vec3 {
        self.origin
    }

    /// Vertex positions (scene units, local frame: add [`Mesh::origin`] for world positions);
    /// the input's vertices first, then those subdivision made.
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }

    /// Corner vertex indices of `patch`, counter-clockwise seen from its front.
    pub fn corners(&self, patch: &Patch) -> &[u32] {
        let s = patch.first_corner as usize;
        &self.corners[s..s + patch.corner_count as usize]
    }

    /// The global corner index of corner 0 of patch number `patch_index` (its index in
    /// [`Mesh::patches`]). Corners are numbered patch by patch in mesh order, each patch's in
    /// [`Mesh::corners`] order, so corner `k` of patch `p` is `corner_offset(p) + k`: the sum of
    /// the corner counts of patches `0..p`, plus `k`. Per-corner arrays (e.g.
    /// [`Mesh::corner_radiosity`]) are indexed this way. `corner_offset(patches().len())` is
    /// [`Mesh::corner_count`].
    ///
    /// # Panics
    /// If `patch_index > patches().len()`.
    pub fn corner_offset(&self, patch_index: usize) -> usize {
        match self.patches.get(patch_index) {
            Some(p) => p.first_corner as usize,
            None if patch_index == self.patches.len() => self.corners.len(),
            None => panic!(
                "patch index {patch_index} out of range ({} patches)",
                self.patches.len()
            ),
        }
    }

    /// The number of patch corners over all patches: the length of per-corner arrays.
    pub fn corner_count(&self) -> usize {
        self.corners.len()
    }

    /// All triangles (vertex indices), grouped by patch in patch order; counter-clockwise from
    /// the front.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// The triangles of `patch` (a fan over its corners; a cluster's, its members' fans).
    pub fn patch_triangles(&self, patch: &Patch) -> &[[u32; 3]] {
        let s = patch.first_triangle as usize;
        &self.triangles[s..s + patch.triangle_count()]
    }

    /// The index in [`Mesh::triangles`] of the first triangle of `patch` (its triangles are
    /// [`Mesh::patch_triangles`], contiguous from there).
    pub fn first_triangle(&self, patch: &Patch) -> usize {
        patch.first_triangle as usize
    }

    /// For each triangle of [`Mesh::triangles`], the index of its patch.
    pub fn triangle_patch(&self) -> &[u32] {
        &self.triangle_patch
    }

    /// The triangles as vertex positions, in [`Mesh::triangles`] order (for building a BVH).
    pub fn triangle_positions(&self) -> Vec<[Vec3; 3]> {
        self.triangles
            .iter()
            .map(|t| t.map(|i| self.positions[i as usize]))
            .collect()
    }

    /// A distance that leaves the mesh's bounding box from any point in it: twice the box's
    /// diagonal (scene units, in the mesh's frame; at least 1, e.g. for a mesh of one point).
    /// Where a shadow ray towards a light at infinity (a sun) may end.
    pub fn escape_distance(&self) -> f64 {
        let (lo, hi) = self.positions().iter().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        );
        (2.0 * f64::from((hi - lo).length())).max(1.0)
    }

    /// Total area of all patches (scene units²), summed in f64.
    pub fn total_area(&self) -> f64 {
        self.patches.iter().map(|p| p.area).sum()
    }

    /// Checks the invariants; returns a description of the first violation.
    pub fn validate(&self) -> Result<(), String> {
        for (i, p) in self.patches.iter().enumerate() {
            if p.polygons == 0 || p.corner_count < 3 * u32::from(p.polygons) {
                return Err(format!(
                    "patch {i} has {} corners in {} polygons",
                    p.corner_count, p.polygons
                ));
            }
            if !(p.area.is_finite() && p.area > 0.0) {
                return Err(format!("patch {i} has area {}", p.area));
            }
            if (p.normal.length() - 1.0).abs() > 1e-4 {
                return Err(format!("patch {i} has normal {}", p.normal));
            }
            let s = p.first_triangle as usize;
            if s + p.triangle_count() > self.triangles.len()
                || self.triangle_patch.get(s) != Some(&(i as u32))
            {
                return Err(format!("patch {i} triangles are not its own"));
            }
        }
        if self.triangle_patch.len() != self.triangles.len() {
            return Err("triangle_patch length differs from triangles".into());
        }
        Ok(())
    }
}

/// The smallest opaque fraction a patch of an alpha-tested face keeps (a patch cut out
/// entirely is never hit, and keeps a positive area).
pub const MIN_COVERAGE: f32 = 1e-3;

/// The largest reflectance a texture may give a patch (a texel of 1 under a factor of 1).
const MAX_REFLECTANCE: f32 = 0.999;

/// What every patch cut from one face shares (for a textured face, the material's factors,
/// which the texture multiplies patch by patch).
#[derive(Debug, Clone, Copy)]
pub(crate) struct PatchTemplate {
    pub reflectance: Vec3,
    pub emission: Vec3,
    pub face: u32,
    pub material: u32,
    /// Push each patch's back side right after it.
    pub two_sided: bool,
}

/// The largest coordinate magnitude of `positions` (0 for none), in parallel.
pub(crate) fn max_coordinate(positions: &[Vec3]) -> f64 {
    positions
        .par_iter()
        .with_min_len(1 << 14)
        .map(|p| f64::from(p.abs().max_element()))
        .reduce(|| 0.0, f64::max)
}

/// [`Mesh::resolved_size`] of a mesh whose largest coordinate magnitude is `coordinate`.
pub(crate) fn resolved_size_at(coordinate: f64) -> f64 {
    coordinate * f64::from(f32::EPSILON) * F32_SPACINGS_PER_PATCH
}

/// The patches [`Mesh::build`] cuts `face` of `scene` into (a two-sided face's back sides
/// counted): one, or with `cut` = (maximum edge, resolved size) the uniform cut's count from
/// the face's corners in `positions` (the local frame); `pos` is room for those corners.
pub(crate) fn patches_of_face(
    scene: &Scene,
    face: &mcrad_scene_io::Face,
    positions: &[Vec3],
    cut: Option<(f32, f64)>,
    pos: &mut Vec<DVec3>,
) -> u64 {
    let sides = 1 + u64::from(scene.is_two_sided(face.material));
    let Some((max_edge, min_size)) = cut else {
        return sides;
    };
    pos.clear();
    pos.extend(
        face.vertices
            .iter()
            .map(|&v| positions[v as usize].as_dvec3()),
    );
    sides * crate::subdivide::count_face(pos, max_edge, min_size)
}

/// `scene`'s positions in the local frame of origin `origin` (see [`Mesh::origin`]).
pub(crate) fn local_positions(scene: &Scene, origin: Vec3) -> Vec<Vec3> {
    scene
        .positions()
        .par_iter()
        .with_min_len(1 << 14)
        .map(|p| (p.as_dvec3() - origin.as_dvec3()).as_vec3())
        .collect()
}

/// The maximum edge of `subdivision` (`None` for one patch per face), checked as
/// [`Mesh::build`] checks it: a positive finite length, and a cut of `scene` of at most
/// [`MAX_PATCHES`] patches by [`estimate_patches`].
pub(crate) fn checked_max_edge(
    scene: &Scene,
    subdivision: Subdivision,
) -> Result<Option<f32>, MeshError> {
    let max_edge = match subdivision {
        Subdivision::None => None,
        Subdivision::MaxEdge(l) if l.is_finite() && l > 0.0 => Some(l),
        Subdivision::MaxEdge(l) => return Err(MeshError::BadMaxEdge(l)),
    };
    if let Some(l) = max_edge {
        let estimate = estimate_patches(scene, l);
        if estimate > MAX_PATCHES {
            return Err(MeshError::TooManyPatches {
                max_edge: l,
                estimate,
                limit: MAX_PATCHES,
            });
        }
    }
    Ok(max_edge)
}

/// The origin of the local frame of `scene`'s mesh (see [`Mesh::origin`]): the bounding box's
/// centre rounded to a multiple of the smallest power of two `>=` its diagonal.
pub(crate) fn local_origin(scene: &Scene) -> Vec3 {
    let b = scene.bounds();
    let centre = (b.min.as_dvec3() + b.max.as_dvec3()) / 2.0;
    let diagonal = b.diagonal();
    if !(diagonal.is_finite() && diagonal > 0.0) {
        return Vec3::ZERO;
    }
    let step = 2f64.powi(diagonal.log2().ceil() as i32);
    let origin = ((centre / step).round() * step).as_vec3();
    if origin.is_finite() {
        origin
    } else {
        Vec3::ZERO
    }
}

impl Mesh {
    /// An upper estimate of the patches [`Mesh::build`] makes of `scene` with `subdivision`
    /// (front sides; a two-sided face's back side doubles its pieces), without building it: a
    /// face whose longest edge is `n` times the maximum edge gives at most `n²` pieces per fan
    /// triangle. Linear in the faces.
    pub fn estimate_patches(scene: &Scene, subdivision: Subdivision) -> u64 {
        match subdivision {
            Subdivision::None => scene.faces().len() as u64,
            Subdivision::MaxEdge(l) if l.is_finite() && l > 0.0 => estimate_patches(scene, l),
            Subdivision::MaxEdge(_) => scene.faces().len() as u64,
        }
    }
}

/// An upper estimate of the patch count a subdivision makes (to refuse absurd requests early).
fn estimate_patches(scene: &Scene, max_edge: f32) -> u64 {
    let l = max_edge as f64;
    let p = scene.positions();
    scene
        .faces()
        .par_iter()
        .with_min_len(1 << 12)
        .map(|f| {
            let longest = f
                .vertices
                .iter()
                .zip(f.vertices.iter().cycle().skip(1))
                .map(|(&a, &b)| p[a as usize].distance(p[b as usize]) as f64)
                .fold(0.0, f64::max);
            let n = (longest / l).ceil().max(1.0);
            ((f.vertices.len() - 2) as f64 * n * n).min(u64::MAX as f64 / 2.0) as u64
        })
        .reduce(|| 0, u64::saturating_add)
}
