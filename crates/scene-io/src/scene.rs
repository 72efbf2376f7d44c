//! The validated scene: positions, polygon faces and materials.

use crate::error::{SceneError, Warning};
use crate::polygon::{self, Shape};
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// A diffuse material.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    /// Name from the input file (MTL `newmtl`, glTF material name or `material<N>`).
    pub name: String,
    /// Diffuse reflectance `rho` per RGB channel; invariant: each channel in `[0, 1)`.
    pub reflectance: Vec3,
    /// Emitted radiosity `E` per RGB channel in W/m² (exitance, `E = pi * L`); invariant: finite, `>= 0`.
    pub emission: Vec3,
}

impl Material {
    /// Name of the built-in material given to faces that have none (OBJ faces before any or
    /// with an unknown `usemtl`, glTF primitives without `material`).
    pub const DEFAULT_NAME: &'static str = "default";
    /// Reflectance (each channel) of the built-in default material, and of MTL materials
    /// without `Kd`: a neutral 0.5 grey.
    pub const DEFAULT_REFLECTANCE: f32 = 0.5;

    /// The built-in default material: named [`Material::DEFAULT_NAME`], reflectance 0.5 grey,
    /// no emission. (glTF's own default is white; 0.5 keeps OBJ and glTF alike.)
    pub fn builtin_default() -> Material {
        Material {
            name: Self::DEFAULT_NAME.to_string(),
            reflectance: Vec3::splat(Self::DEFAULT_REFLECTANCE),
            emission: Vec3::ZERO,
        }
    }

    /// True if the material emits: some channel of [`Material::emission`] is `> 0`.
    pub fn is_emitter(&self) -> bool {
        self.emission.max_element() > 0.0
    }
}

/// One planar polygon face of the input, vertices counter-clockwise seen from its front side.
#[derive(Debug, Clone, PartialEq)]
pub struct Face {
    /// Indices into [`Scene::positions`], at least 3, counter-clockwise from the front.
    pub vertices: Vec<u32>,
    /// Index into [`Scene::materials`].
    pub material: u32,
    /// The face's number in the input: OBJ faces in file order over all objects, glTF triangles
    /// over primitives in scene traversal order (depth-first, children in order). Kept when
    /// degenerate faces before it are dropped; shared by the triangles of a split face.
    pub source: u32,
}

/// An axis-aligned bounding box in scene units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// The smallest coordinate per axis.
    pub min: Vec3,
    /// The largest coordinate per axis.
    pub max: Vec3,
}

impl Bounds {
    /// Length of the box's diagonal, in scene units (computed in f64).
    pub fn diagonal(&self) -> f64 {
        (self.max.as_dvec3() - self.min.as_dvec3()).length()
    }
}

/// A validated scene. Invariants (checked by [`Scene::new`]): at least one face; every position
/// finite; every face has >= 3 in-range vertex indices and a non-zero area; every material index
/// in range; every reflectance in `[0,1)`; every emission finite and `>= 0`; some face emits.
/// In addition every face is planar (within `1e-2` of its longest edge) and can be fanned from
/// its first vertex: each triangle `(v0, vi, vi+1)` faces the polygon's front side.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    positions: Vec<Vec3>,
    faces: Vec<Face>,
    materials: Vec<Material>,
    textures: Option<std::sync::Arc<crate::SceneTextures>>,
    lights: Vec<crate::Light>,
    sky: Option<crate::Sky>,
    /// Per material: two-sided (empty when every face is one-sided).
    two_sided: Vec<bool>,
    /// [`Scene::bounds`], computed once (the faces and positions never change).
    bounds: Bounds,
}

impl Scene {
    /// Validates and builds a scene. This is the one validation path of every loader.
    ///
    /// Errors (see [`SceneError`]; faces are named by their `source` number, materials by
    /// name): no faces, a non-finite position, a face with fewer than 3 vertices, a vertex or
    /// material index out of range, a reflectance channel outside `[0, 1)` or non-finite, an
    /// emission channel negative or non-finite, and no emitting face left after the repairs
    /// (naming emitting faces dropped as degenerate); and the limits: a coordinate beyond
    /// [`MAX_COORDINATE`](crate::MAX_COORDINATE), a face of more than
    /// [`MAX_FACE_VERTICES`](crate::MAX_FACE_VERTICES) vertices, more than
    /// [`MAX_FACES`](crate::MAX_FACES) faces.
    ///
    /// Repairs, each reported by one counted [`Warning`]:
    /// - **Duplicate faces are dropped** ([`Warning::DuplicateFacesDropped`]): a face, or a
    ///   triangle of a split face, with the same material and positions in the same cyclic
    ///   order as an earlier one (a face and its reverse, a two-sided surface, are kept).
    /// - **Degenerate faces are dropped** ([`Warning::DegenerateFacesDropped`]): a face whose
    ///   area (`|sum of fan cross products| / 2`, in f64) is `<= 1e-12 * d²` with `d` the
    ///   diagonal of the bounding box of the vertices the faces use, or exactly zero.
    /// - **Non-planar or non-convex faces are split into triangles** ([`Warning::FacesSplit`]),
    ///   each keeping the face's `source` and material. A face is kept whole if it is planar
    ///   (no vertex farther than `1e-2 *` its longest edge from the plane through its centroid
    ///   with its Newell normal) and some vertex fans it: every fan triangle from it has at least
    ///   `1e-7` of the face's area on the front side. Otherwise it is ear-clipped in its Newell
    ///   plane; (nearly) collinear vertices and back-facing parts of self-intersecting outlines
    ///   are left out, so the triangles' total area matches the face's up to those slivers.
    ///
    /// Silent, shape-preserving normalisations: consecutive vertices at the same position
    /// (same index or equal coordinates, including last = first) are merged into one, and a
    /// face's vertex list may be rotated so that the fan from its first vertex is valid (for
    /// example when vertex 0 is a T-junction on a straight edge). Faces keep their input order;
    /// `positions` and `materials` are kept as given (unused entries included).
    pub fn new(
        positions: Vec<Vec3>,
        faces: Vec<Face>,
        materials: Vec<Material>,
    ) -> Result<(Scene, Vec<Warning>), SceneError> {
        Scene::new_lit(positions, faces, materials, Vec::new())
    }

    /// [`Scene::new`] with `lights` besides the emitting faces (in the scene's frame): a scene
    /// with a light needs no emitting face. Errors as [`Scene::new`]'s, plus
    /// [`SceneError::BadLight`] for a light out of range ([`Light::check`](crate::Light::check)).
    pub fn new_lit(
        positions: Vec<Vec3>,
        faces: Vec<Face>,
        materials: Vec<Material>,
        lights: Vec<crate::Light>,
    ) -> Result<(Scene, Vec<Warning>), SceneError> {
        Scene::new_lit_sky(positions, faces, materials, lights, None)
    }

    /// [`Scene::new_lit`] under a `sky` too: a scene with a sky needs no emitting face nor
    /// light. Errors as [`Scene::new_lit`]'s, plus [`SceneError::BadSkyRadiance`] for a
    /// uniform sky out of range ([`Sky::check`](crate::Sky::check)).
    pub fn new_lit_sky(
        positions: Vec<Vec3>,
        faces: Vec<Face>,
        materials: Vec<Material>,
        lights: Vec<crate::Light>,
        sky: Option<crate::Sky>,
    ) -> Result<(Scene, Vec<Warning>), SceneError> {
        if let Some(sky) = &sky {
            sky.check()
                .map_err(|reason| SceneError::BadSkyRadiance { reason })?;
        }
        for (index, light) in lights.iter().enumerate() {
            light.check().map_err(|reason| SceneError::BadLight {
                index,
                kind: light.kind(),
                reason,
            })?;
        }
        if faces.is_empty() {
            return Err(SceneError::NoFaces { dropped: 0 });
        }
        check_positions(&positions)?;
        check_materials(&materials)?;
        check_faces(&faces, positions.len(), materials.len())?;

        let bounds = used_bounds(&positions, &faces);
        let diagonal = bounds.map_or(0.0, |b| b.diagonal());
        let degenerate_area = 1e-12 * diagonal * diagonal;

        let Repaired {
            kept,
            dropped,
            split,
            duplicates,
            dark,
            dark_area,
        } = repair(faces, &positions, &materials, degenerate_area, REPAIR_BLOCK);

        if kept.is_empty() {
            return Err(SceneError::NoFaces {
                dropped: dropped.count,
            });
        }
        if lights.is_empty()
            && sky.is_none()
            && !kept
                .iter()
                .any(|f| materials[f.material as usize].is_emitter())
        {
            return Err(SceneError::NoEmitter {
                dropped_emitters: dark.first.map(|first| (dark.count, first)),
                smallest_dropped_area: dark_area,
                degenerate_area,
            });
        }

        let mut warnings = Vec::new();
        if let Some(first_source) = dropped.first {
            warnings.push(Warning::DegenerateFacesDropped {
                count: dropped.count,
                first_source,
                emitters: dark.count,
            });
        }
        if let Some(first_source) = duplicates.first {
            warnings.push(Warning::DuplicateFacesDropped {
                count: duplicates.count,
                first_source,
            });
        }
        if let Some(first_source) = split.first {
            warnings.push(Warning::FacesSplit {
                count: split.count,
                first_source,
            });
        }
        // A scene has at least one face, so the box is never empty.
        let bounds = used_bounds(&positions, &kept).unwrap_or(Bounds {
            min: Vec3::ZERO,
            max: Vec3::ZERO,
        });
        let scene = Scene {
            bounds,
            positions,
            faces: kept,
            materials,
            textures: None,
            lights,
            sky,
            two_sided: Vec::new(),
        };
        Ok((scene, warnings))
    }

    /// The lights without a surface (point, spot, sun), in the scene's frame and radiometric
    /// units; the emitting faces are the other light sources.
    pub fn lights(&self) -> &[crate::Light] {
        &self.lights
    }

    /// The sky (radiance from the directions in which rays leave the scene), if any.
    pub fn sky(&self) -> Option<&crate::Sky> {
        self.sky.as_ref()
    }

    /// The scene with textured albedo and emission: the faces `textures` maps take their
    /// reflectance and emission from it ([`SceneTextures::average`](crate::SceneTextures::average)
    /// times the material's factors).
    pub fn with_textures(mut self, textures: crate::SceneTextures) -> Scene {
        self.textures = Some(std::sync::Arc::new(textures));
        self
    }

    /// The scene with two-sided materials: `two_sided[m]` makes the faces of material `m`
    /// two-sided (glTF `doubleSided`): each side of such a face reflects, and emits if the
    /// material emits, with a radiosity of its own, and rays meet either side. Materials past
    /// the end of `two_sided` stay one-sided (front side only).
    pub fn with_two_sided(mut self, mut two_sided: Vec<bool>) -> Scene {
        two_sided.truncate(self.materials.len());
        if !two_sided.contains(&true) {
            two_sided.clear();
        }
        self.two_sided = two_sided;
        self
    }

    /// Whether the faces of material `material` are two-sided (see [`Scene::with_two_sided`]).
    pub fn is_two_sided(&self, material: u32) -> bool {
        self.two_sided
            .get(material as usize)
            .copied()
            .unwrap_or(false)
    }

    /// Whether some material is two-sided.
    pub fn has_two_sided(&self) -> bool {
        !self.two_sided.is_empty()
    }

    /// The textures and face mappings, when the scene has textured faces.
    pub fn textures(&self) -> Option<&std::sync::Arc<crate::SceneTextures>> {
        self.textures.as_ref()
    }

    /// Vertex positions in scene units.
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }
    /// The faces, in input order (degenerate ones removed).
    pub fn faces(&self) -> &[Face] {
        &self.faces
    }
    /// The materials.
    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// Area of `face` in scene units², `|sum of fan cross products| / 2` computed in f64.
    ///
    /// # Panics
    /// If `face` refers to vertices this scene does not have (it is not one of its faces).
    pub fn face_area(&self, face: &Face) -> f64 {
        self.vector_area2(face).length() / 2.0
    }

    /// Unit normal of `face` on its front side (the Newell normal, computed in f64).
    ///
    /// # Panics
    /// If `face` refers to vertices this scene does not have (it is not one of its faces).
    pub fn face_normal(&self, face: &Face) -> Vec3 {
        self.vector_area2(face).normalize().as_vec3()
    }

    /// Bounding box of the vertices used by the faces, in scene units.
    pub fn bounds(&self) -> Bounds {
        self.bounds
    }

    fn vector_area2(&self, face: &Face) -> DVec3 {
        let pts: Vec<DVec3> = face
            .vertices
            .iter()
            .map(|&v| self.positions[v as usize].as_dvec3())
            .collect();
        polygon::vector_area2(&pts)
    }
}

/// Faces prepared in parallel per block of the repairs (see [`repair`]); the blocks are taken
/// in turn, each prepared while the one before is sorted in order.
const REPAIR_BLOCK: usize = 1 << 14;

/// What the repairs of [`Scene::new`] made of the faces.
#[derive(Default)]
struct Repaired {
    /// The faces kept, in input order (split faces by their triangles).
    kept: Vec<Face>,
    /// Faces dropped as degenerate.
    dropped: Tally,
    /// Faces split into triangles.
    split: Tally,
    /// Faces (or triangles of split faces) dropped as duplicates.
    duplicates: Tally,
    /// Emitting faces dropped as degenerate.
    dark: Tally,
    /// The largest area among `dark`, in units².
    dark_area: f64,
}

/// A face made ready for the repairs on its own (in parallel with the others): everything but
/// whether it repeats an earlier face, which takes the faces in order.
struct Prepared {
    /// The face, its vertices merged ([`merge_repeated`]) and, if it is kept whole, rotated.
    face: Face,
    /// Its key among the faces seen ([`Duplicates::key`] of the merged ring).
    key: u128,
    /// Its area (units²) if its material emits (for [`SceneError::NoEmitter`]'s message).
    emit_area: Option<f64>,
    /// What becomes of it if it repeats no earlier face.
    outcome: Outcome,
}

/// How a face that is no duplicate is stored.
enum Outcome {
    /// Dropped as degenerate.
    Degenerate,
    /// Kept whole, vertices as in [`Prepared::face`].
    Fan,
    /// Split: its triangles that are not slivers, each with its [`Duplicates::key`].
    Split(Vec<(Vec<u32>, u128)>),
}

/// The repairs of [`Scene::new`] (merged vertices, duplicates, degenerate, non-planar and
/// non-convex faces) over faces whose indices were checked. The per-face work runs in parallel
/// in blocks of `block` faces; duplicates are then found in input order, so the result is the
/// same for any block size and thread count.
fn repair(
    faces: Vec<Face>,
    positions: &[Vec3],
    materials: &[Material],
    degenerate_area: f64,
    block: usize,
) -> Repaired {
    let mut out = Repaired {
        kept: Vec::with_capacity(faces.len()),
        ..Repaired::default()
    };
    let mut seen = Duplicates::with_capacity(faces.len());
    let mut faces = faces.into_iter();
    let block = block.max(1);
    let next = |faces: &mut std::vec::IntoIter<Face>| -> Vec<Prepared> {
        let chunk: Vec<Face> = faces.by_ref().take(block).collect();
        chunk
            .into_par_iter()
            .map(|face| prepare(face, positions, materials, degenerate_area))
            .collect()
    };
    let mut current = next(&mut faces);
    while !current.is_empty() {
        let (following, ()) = rayon::join(
            || next(&mut faces),
            || {
                for prepared in current {
                    out.take(prepared, &mut seen);
                }
            },
        );
        current = following;
    }
    out
}

/// The per-face part of [`repair`].
fn prepare(
    mut face: Face,
    positions: &[Vec3],
    materials: &[Material],
    degenerate_area: f64,
) -> Prepared {
    let ring = merge_repeated(std::mem::take(&mut face.vertices), positions);
    let key = Duplicates::key(&ring, face.material, positions);
    // the corners of faces of up to `SMALL` vertices in a buffer on the stack (no allocation
    // per face)
    let mut small = [DVec3::ZERO; SMALL];
    let mut large: Vec<DVec3> = Vec::new();
    let pts: &mut [DVec3] = if ring.len() <= SMALL {
        &mut small[..ring.len()]
    } else {
        large.resize(ring.len(), DVec3::ZERO);
        &mut large
    };
    for (p, &v) in pts.iter_mut().zip(&ring) {
        *p = positions[v as usize].as_dvec3();
    }
    let pts: &[DVec3] = pts;
    let emit_area = materials[face.material as usize]
        .is_emitter()
        .then(|| polygon::vector_area2(pts).length() / 2.0);
    let outcome = match polygon::classify(pts, degenerate_area) {
        Shape::Degenerate => Outcome::Degenerate,
        Shape::Fan { apex } => {
            let mut vertices = ring;
            vertices.rotate_left(apex);
            face.vertices = vertices;
            Outcome::Fan
        }
        Shape::Split(tris) => Outcome::Split(
            tris.into_iter()
                .filter_map(|t| {
                    let tri = [pts[t[0]], pts[t[1]], pts[t[2]]];
                    if polygon::vector_area2(&tri).length() / 2.0 <= degenerate_area {
                        return None;
                    }
                    let vertices = vec![ring[t[0]], ring[t[1]], ring[t[2]]];
                    let key = Duplicates::key(&vertices, face.material, positions);
                    Some((vertices, key))
                })
                .collect(),
        ),
    };
    Prepared {
        face,
        key,
        emit_area,
        outcome,
    }
}

impl Repaired {
    /// Takes the next face in input order: drops it if it repeats an earlier one, else stores
    /// it as prepared.
    fn take(&mut self, prepared: Prepared, seen: &mut Duplicates) {
        let Prepared {
            face,
            key,
            emit_area,
            outcome,
        } = prepared;
        if !seen.insert(key) {
            self.duplicates.add(face.source);
            return;
        }
        match outcome {
            Outcome::Degenerate => self.drop_degenerate(face.source, emit_area),
            Outcome::Fan => self.kept.push(face),
            Outcome::Split(tris) => {
                let before = self.kept.len();
                let mut repeated = false;
                for (vertices, key) in tris {
                    // (a self-overlapping outline such as `f 1 2 3 1 2 3` splits into copies
                    // of one triangle)
                    if !seen.insert(key) {
                        self.duplicates.add(face.source);
                        repeated = true;
                        continue;
                    }
                    self.kept.push(Face {
                        vertices,
                        material: face.material,
                        source: face.source,
                    });
                }
                if self.kept.len() > before {
                    self.split.add(face.source);
                } else if !repeated {
                    self.drop_degenerate(face.source, emit_area);
                }
            }
        }
    }

    /// Drops face `source` as degenerate (`emit_area`: its area if it emits).
    fn drop_degenerate(&mut self, source: u32, emit_area: Option<f64>) {
        self.dropped.add(source);
        if let Some(area) = emit_area {
            self.dark.add(source);
            self.dark_area = self.dark_area.max(area);
        }
    }
}

/// Counts faces and remembers the first one's source.
#[derive(Debug, Default, PartialEq)]
struct Tally {
    count: usize,
    first: Option<u32>,
}

impl Tally {
    fn add(&mut self, source: u32) {
        self.count += 1;
        self.first.get_or_insert(source);
    }
}

/// The first position (in order) that is not finite or beyond the largest coordinate, checked
/// in parallel.
fn check_positions(positions: &[Vec3]) -> Result<(), SceneError> {
    let bad = positions
        .par_iter()
        .enumerate()
        .find_map_first(|(vertex, &position)| {
            if !position.is_finite() {
                return Some(SceneError::NonFinitePosition { vertex, position });
            }
            if position.abs().max_element() > crate::MAX_COORDINATE {
                return Some(SceneError::CoordinateTooLarge { vertex, position });
            }
            None
        });
    bad.map_or(Ok(()), Err)
}

fn check_materials(materials: &[Material]) -> Result<(), SceneError> {
    for m in materials {
        let r = m.reflectance;
        // `!(x >= 0)` is also true for NaN.
        if !(r.is_finite() && r.min_element() >= 0.0 && r.max_element() < 1.0) {
            return Err(SceneError::BadReflectance {
                material: m.name.clone(),
                reflectance: r,
            });
        }
        let e = m.emission;
        if !(e.is_finite() && e.min_element() >= 0.0) {
            return Err(SceneError::BadEmission {
                material: m.name.clone(),
                emission: e,
            });
        }
    }
    Ok(())
}

/// The first face (in order) that breaks a limit or has an index out of range, checked in
/// parallel.
fn check_faces(faces: &[Face], positions: usize, materials: usize) -> Result<(), SceneError> {
    if faces.len() > crate::MAX_FACES {
        return Err(SceneError::TooManyFaces);
    }
    let bad = faces.par_iter().find_map_first(|f| {
        if f.vertices.len() > crate::MAX_FACE_VERTICES {
            return Some(SceneError::TooManyFaceVertices {
                count: f.vertices.len(),
            });
        }
        if f.vertices.len() < 3 {
            return Some(SceneError::TooFewVertices {
                face: f.source,
                count: f.vertices.len(),
            });
        }
        if let Some(&vertex) = f.vertices.iter().find(|&&v| v as usize >= positions) {
            return Some(SceneError::VertexOutOfRange {
                face: f.source,
                vertex,
                count: positions,
            });
        }
        if f.material as usize >= materials {
            return Some(SceneError::MaterialOutOfRange {
                face: f.source,
                material: f.material,
                count: materials,
            });
        }
        None
    });
    bad.map_or(Ok(()), Err)
}

/// Bounding box of the positions the faces use; `None` if they use none. Indices must be valid.
/// (Computed in parallel: minima and maxima do not depend on the order.)
fn used_bounds(positions: &[Vec3], faces: &[Face]) -> Option<Bounds> {
    fn join(a: Option<Bounds>, b: Option<Bounds>) -> Option<Bounds> {
        match (a, b) {
            (Some(a), Some(b)) => Some(Bounds {
                min: a.min.min(b.min),
                max: a.max.max(b.max),
            }),
            (a, None) => a,
            (None, b) => b,
        }
    }
    faces
        .par_iter()
        .with_min_len(1024)
        .fold(
            || None,
            |b, f| {
                f.vertices.iter().fold(b, |b, &v| {
                    let p = positions[v as usize];
                    join(b, Some(Bounds { min: p, max: p }))
                })
            },
        )
        .reduce(|| None, join)
}

/// The faces seen so far, to find duplicates: a face (or a triangle of a split face) with the
/// same material and the same positions in the same cyclic order (so the same front side) as
/// an earlier one. Faces are
/// remembered by a 128-bit hash (16 bytes each; two different faces share one with
/// probability about `n² / 2^129`).
struct Duplicates {
    seen: std::collections::HashSet<u128, std::hash::BuildHasherDefault<Folded>>,
}

/// The set's hasher: its keys are already hashes (uniform 128-bit), so their two halves xored
/// are a hash; hashing them again (SipHash) took a quarter of the time of loading ten million
/// triangles.
#[derive(Default)]
struct Folded(u64);

impl std::hash::Hasher for Folded {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        // not used by u128 keys; a plain FNV-1a for completeness
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }

    fn write_u128(&mut self, key: u128) {
        self.0 ^= (key >> 64) as u64 ^ key as u64;
    }
}

impl Duplicates {
    /// Room for the faces of a scene of `faces` faces (the set does not rehash as it grows).
    fn with_capacity(faces: usize) -> Duplicates {
        Duplicates {
            seen: std::collections::HashSet::with_capacity_and_hasher(faces, Default::default()),
        }
    }

    /// Remembers a face by its [`Duplicates::key`]; false if a face of that key was seen.
    fn insert(&mut self, key: u128) -> bool {
        self.seen.insert(key)
    }

    /// The key of a face (`ring` of vertices after [`merge_repeated`], `material`): the same
    /// for the same material and positions in the same cyclic order.
    fn key(ring: &[u32], material: u32, positions: &[Vec3]) -> u128 {
        use std::hash::{Hash, Hasher};
        // on the stack for faces of up to `SMALL` vertices
        let mut small = [[0u32; 3]; SMALL];
        let mut large = Vec::new();
        let key: &mut [[u32; 3]] = if ring.len() <= SMALL {
            &mut small[..ring.len()]
        } else {
            large.resize(ring.len(), [0u32; 3]);
            &mut large
        };
        for (k, &v) in key.iter_mut().zip(ring) {
            *k = positions[v as usize].to_array().map(f32::to_bits);
        }
        // rotate the smallest position first: the same cycle gives the same key
        if let Some(start) = (0..key.len()).min_by_key(|&i| key[i]) {
            key.rotate_left(start);
        }
        let key: &[[u32; 3]] = key;
        let half = |salt: u64| {
            let mut hasher = std::collections::hash_map::DefaultHasher::new();
            (salt, material, key).hash(&mut hasher);
            hasher.finish() as u128
        };
        half(1) << 64 | half(2)
    }
}

/// Faces of at most this many vertices are checked without a heap allocation.
const SMALL: usize = 8;

/// The face's vertex ring with consecutive vertices at equal positions merged (cyclically), in
/// place: the first of each run of equal positions is kept.
fn merge_repeated(mut ring: Vec<u32>, positions: &[Vec3]) -> Vec<u32> {
    let at = |v: u32| positions[v as usize];
    ring.dedup_by(|v, kept| at(*v) == at(*kept));
    while ring.len() > 1 && at(ring[0]) == at(ring[ring.len() - 1]) {
        ring.pop();
    }
    ring
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mat(name: &str, rho: f32, e: f32) -> Material {
        Material {
            name: name.to_string(),
            reflectance: Vec3::splat(rho),
            emission: Vec3::splat(e),
        }
    }

    fn face(vertices: &[u32], material: u32, source: u32) -> Face {
        Face {
            vertices: vertices.to_vec(),
            material,
            source,
        }
    }

    /// The repairs in blocks of any size, on any thread count, give the same faces, counts and
    /// first sources as one face at a time: random faces on a small grid (so duplicates,
    /// reversed copies, degenerate, non-planar and non-convex faces are common), some
    /// emitting.
    #[test]
    fn repairs_do_not_depend_on_blocks_or_threads() {
        use rand_core::Rng as _;
        let mut stream = rand_pcg::Pcg32::new(7, 0x0a02_bdbf_7bb3_c0a7);
        let mut pick = |n: u64| (stream.next_u64() % n) as u32;
        let positions: Vec<Vec3> = (0..27)
            .map(|i| Vec3::new((i % 3) as f32, (i / 3 % 3) as f32, (i / 9) as f32))
            .collect();
        let materials = vec![mat("white", 0.5, 0.0), mat("lamp", 0.5, 1.0)];
        let faces: Vec<Face> = (0..3000)
            .map(|source| {
                let n = 3 + pick(4) as usize;
                // mostly on the z = 0 plane (indices 0..9), where copies are likely
                let range = if pick(3) == 0 { 27 } else { 9 };
                let vertices: Vec<u32> = (0..n).map(|_| pick(range)).collect();
                face(&vertices, pick(2), source)
            })
            .collect();
        let run = |block: usize, threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| repair(faces.clone(), &positions, &materials, 1e-9, block))
        };
        let one = run(1, 1);
        assert!(one.duplicates.count > 100 && one.split.count > 100 && one.dropped.count > 100);
        assert!(one.dark.count > 0 && one.kept.len() > 500);
        for (block, threads) in [(7, 2), (REPAIR_BLOCK, 2), (1000, 3), (1 << 20, 1)] {
            let other = run(block, threads);
            assert_eq!(other.kept, one.kept, "blocks of {block}, {threads} threads");
            assert_eq!(
                [&other.dropped, &other.split, &other.duplicates, &other.dark],
                [&one.dropped, &one.split, &one.duplicates, &one.dark]
            );
            assert_eq!(other.dark_area, one.dark_area);
        }
    }

    /// Faces of more corners than the stack buffers hold (`SMALL`) take the heap path: a
    /// 12-gon, the same 12-gon rotated with a repeated corner (a duplicate once it is merged),
    /// and a quad with a corner repeated under another index (equal positions merge).
    #[test]
    fn large_faces_are_merged_and_found_duplicate_like_small_ones() {
        let n = 3 * SMALL / 2;
        let mut p: Vec<Vec3> = (0..n)
            .map(|k| {
                let a = std::f32::consts::TAU * k as f32 / n as f32;
                Vec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        p.push(p[0]);
        let first: Vec<u32> = (0..n as u32).collect();
        let mut rotated: Vec<u32> = (0..n as u32).map(|k| (k + 5) % n as u32).collect();
        rotated.insert(3, rotated[2]);
        let faces = vec![
            face(&first, 0, 0),
            face(&rotated, 0, 1),
            face(&[0, n as u32, 1, 2, 3], 0, 2),
        ];
        let (scene, warnings) = Scene::new(p, faces, vec![mat("lamp", 0.5, 1.0)]).unwrap();
        let sizes: Vec<(u32, usize)> = scene
            .faces()
            .iter()
            .map(|f| (f.source, f.vertices.len()))
            .collect();
        assert_eq!(sizes, vec![(0, n), (2, 4)], "{warnings:?}");
        assert_eq!(scene.faces()[1].vertices, vec![0, 1, 2, 3]);
        assert_eq!(
            warnings,
            vec![Warning::DuplicateFacesDropped {
                count: 1,
                first_source: 1
            }]
        );
    }

    /// A unit square (emitting) and a square at z = 1 (material 1), 8 positions.
    fn two_squares() -> (Vec<Vec3>, Vec<Face>, Vec<Material>) {
        let mut p = Vec::new();
        for z in [0.0, 1.0] {
            p.extend([
                Vec3::new(0., 0., z),
                Vec3::new(1., 0., z),
                Vec3::new(1., 1., z),
                Vec3::new(0., 1., z),
            ]);
        }
        let faces = vec![face(&[0, 1, 2, 3], 0, 0), face(&[7, 6, 5, 4], 1, 1)];
        (p, faces, vec![mat("lamp", 0.5, 1.0), mat("grey", 0.5, 0.0)])
    }

    #[test]
    fn valid_scene_is_kept_as_given() {
        let (p, f, m) = two_squares();
        let (scene, warnings) = Scene::new(p.clone(), f.clone(), m.clone()).unwrap();
        assert!(warnings.is_empty());
        assert_eq!(scene.faces(), &f[..]);
        assert_eq!(scene.positions(), &p[..]);
        assert_eq!(scene.face_area(&scene.faces()[0]), 1.0);
        assert_eq!(scene.face_normal(&scene.faces()[0]), Vec3::Z);
        assert_eq!(scene.face_normal(&scene.faces()[1]), -Vec3::Z);
        assert_eq!(scene.bounds().max, Vec3::ONE);
        assert!((scene.bounds().diagonal() - 3f64.sqrt()).abs() < 1e-12);
    }

    fn err(p: Vec<Vec3>, f: Vec<Face>, m: Vec<Material>) -> String {
        Scene::new(p, f, m).unwrap_err().to_string()
    }

    #[test]
    fn each_invariant_violation_is_a_specific_error() {
        let (p, f, m) = two_squares();
        assert_eq!(err(p.clone(), vec![], m.clone()), "the scene has no faces");

        let mut q = p.clone();
        q[5] = Vec3::new(f32::NAN, 0., 1.);
        assert_eq!(
            err(q, f.clone(), m.clone()),
            "vertex 5 has a non-finite coordinate (NaN, 0, 1)"
        );

        let mut g = f.clone();
        g[1].vertices = vec![4, 5];
        assert_eq!(
            err(p.clone(), g, m.clone()),
            "face 1 has 2 vertices; a face needs at least 3"
        );

        let mut g = f.clone();
        g[1].vertices[2] = 40;
        assert_eq!(
            err(p.clone(), g, m.clone()),
            "face 1 uses vertex 40 but there are only 8"
        );

        let mut g = f.clone();
        g[0].material = 5;
        assert_eq!(
            err(p.clone(), g, m.clone()),
            "face 0 uses material 5 but there are only 2"
        );

        let mut n = m.clone();
        n[1] = Material {
            name: "red".into(),
            reflectance: Vec3::new(1.2, 0.1, 0.1),
            emission: Vec3::ZERO,
        };
        assert_eq!(
            err(p.clone(), f.clone(), n),
            "material 'red' has reflectance (1.2, 0.1, 0.1): each channel must be in [0, 1)"
        );
        let mut n = m.clone();
        n[1].reflectance.y = 1.0;
        assert!(err(p.clone(), f.clone(), n).contains("(0.5, 1, 0.5)"));

        let mut n = m.clone();
        n[0].emission = Vec3::new(-1., 0., 0.);
        assert_eq!(
            err(p.clone(), f.clone(), n),
            "material 'lamp' has negative emission (-1, 0, 0): each channel must be finite and \
             >= 0 W/m²"
        );
        let mut n = m.clone();
        n[0].emission.z = f32::INFINITY;
        assert!(err(p.clone(), f.clone(), n).contains("non-finite emission (1, 1, inf)"));

        let mut n = m.clone();
        n[0].emission = Vec3::ZERO;
        assert_eq!(
            err(p.clone(), f.clone(), n),
            "the scene has no emitting face (no material with emission > 0 is used by any face) \
             and no light: light it with an emissive material or a light (glTF \
             KHR_lights_punctual point, spot or directional)"
        );
        // A light is enough.
        let mut n = m.clone();
        n[0].emission = Vec3::ZERO;
        let sun = crate::Light::Sun(crate::Sun {
            direction: Vec3::Z,
            irradiance: glam::DVec3::ONE,
            diameter: 0.0,
        });
        let (scene, _) = Scene::new_lit(p.clone(), f.clone(), n.clone(), vec![sun]).unwrap();
        assert_eq!(scene.lights().len(), 1);
        let bad = crate::Light::Sun(crate::Sun {
            direction: Vec3::Z,
            irradiance: glam::DVec3::NEG_ONE,
            diameter: 0.0,
        });
        let e = Scene::new_lit(p.clone(), f.clone(), n, vec![bad]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "light 0 (sun): irradiance [-1, -1, -1] is negative or not finite"
        );
    }

    #[test]
    fn degenerate_faces_are_dropped_counted_and_sources_kept() {
        let (mut p, mut f, m) = two_squares();
        p.push(Vec3::new(2., 0., 0.)); // 8: collinear with 0 and 1
        p.push(Vec3::new(0.5, 0.5, 0.5 + 1e-7)); // 9: a sliver
        f.insert(0, face(&[0, 1, 8], 1, 10)); // zero area
        f.insert(2, face(&[4, 4, 5], 1, 11)); // repeated vertex
        f.push(face(&[0, 1, 1, 1, 0], 1, 12)); // collapses to 2 vertices
        f.push(face(&[9, 9, 9], 1, 13));
        let (scene, warnings) = Scene::new(p, f, m).unwrap();
        let sources: Vec<u32> = scene.faces().iter().map(|f| f.source).collect();
        assert_eq!(sources, vec![0, 1]);
        assert_eq!(
            warnings,
            vec![Warning::DegenerateFacesDropped {
                count: 4,
                first_source: 10,
                emitters: 0
            }]
        );
    }

    #[test]
    fn dropping_can_leave_no_emitter_or_no_faces() {
        let (mut p, mut f, m) = two_squares();
        p[2] = Vec3::new(2., 0., 0.);
        p[3] = Vec3::new(3., 0., 0.);
        assert_eq!(
            Scene::new(p.clone(), f.clone(), m.clone())
                .unwrap_err()
                .to_string(),
            "the scene has no emitting face left: its 1 emitting face was dropped as degenerate \
             (area 0.0e0, at most 1.1e-11 counts as zero: 1e-12 of the bounding-box diagonal \
             squared); the first is face 0"
        );
        f.truncate(1);
        assert_eq!(
            Scene::new(p, f, m).unwrap_err().to_string(),
            "the scene has no faces left: all 1 were degenerate (zero area) and dropped"
        );
    }

    #[test]
    fn tiny_faces_are_degenerate_relative_to_the_scene() {
        let (mut p, mut f, m) = two_squares();
        let base = p.len() as u32;
        p.extend([
            Vec3::new(0.5, 0.5, 0.5),
            Vec3::new(0.5 + 1e-7, 0.5, 0.5),
            Vec3::new(0.5, 0.5 + 1e-7, 0.5),
        ]);
        f.push(face(&[base, base + 1, base + 2], 1, 2));
        let (scene, w) = Scene::new(p, f, m).unwrap();
        assert_eq!(scene.faces().len(), 2);
        assert_eq!(w.len(), 1);
    }

    #[test]
    fn non_planar_and_concave_faces_are_split_with_their_source() {
        let (mut p, mut f, m) = two_squares();
        p[2].z = 0.25; // the emitting square is no longer planar
        let base = p.len() as u32;
        // A concave outline that no vertex can fan (area 5).
        p.extend(
            [[0., 0.], [3., 0.], [3., 3.], [2., 1.], [1., 1.], [0., 3.]]
                .map(|[x, y]| Vec3::new(x, y, 2.)),
        );
        f.push(face(&(base..base + 6).collect::<Vec<_>>(), 1, 7));
        let (scene, warnings) = Scene::new(p, f, m).unwrap();
        assert_eq!(
            warnings,
            vec![Warning::FacesSplit {
                count: 2,
                first_source: 0
            }]
        );
        let sources: Vec<u32> = scene.faces().iter().map(|f| f.source).collect();
        assert_eq!(sources, vec![0, 0, 1, 7, 7, 7, 7]);
        assert!(
            scene
                .faces()
                .iter()
                .all(|f| f.source != 0 || f.material == 0)
        );
        let area7: f64 = scene
            .faces()
            .iter()
            .filter(|f| f.source == 7)
            .map(|f| scene.face_area(f))
            .sum();
        assert!((area7 - 5.0).abs() < 1e-9);
        for f in scene.faces().iter().filter(|f| f.source == 7) {
            assert!(scene.face_normal(f).z > 0.99);
        }
    }

    #[test]
    fn t_junction_face_is_rotated_not_split() {
        let (mut p, mut f, m) = two_squares();
        p.push(Vec3::new(0.5, 0., 0.)); // 8: on the edge 0-1
        f[0].vertices = vec![0, 8, 1, 2, 3]; // fanning from 0 makes (0, 8, 1): zero area
        let (scene, warnings) = Scene::new(p, f, m).unwrap();
        assert!(warnings.is_empty());
        let v = &scene.faces()[0].vertices;
        assert_eq!(v.len(), 5);
        assert_ne!(v[0], 0);
        assert!((scene.face_area(&scene.faces()[0]) - 1.0).abs() < 1e-12);
    }
}
