//! Adaptive meshes: elements that split where a solution asks for it.
//!
//! An [`AdaptiveMesh`] keeps the leaf elements of a refinement hierarchy over the faces of a
//! scene, each a triangle or a convex quad of the face it came from, and the [`Mesh`] of those
//! leaves (leaf `i` is patch `i`) that the solvers work on. [`AdaptiveMesh::refine`] splits the
//! leaves it is given at their edge midpoints:
//!
//! - a triangle into four similar triangles (corners and edge midpoints);
//! - a quad into four (edge midpoints and the centre), or into two across its long direction when
//!   one side is more than twice the other or the short side is below twice the minimum edge
//!   (so thin faces do not get thinner elements);
//!
//! and keeps every other leaf as it is. Children tile their parent exactly (a planar quad's
//! midpoint lines are straight), so each face's area is conserved to rounding, and children
//! have their parent's shape, so refinement never makes an element more degenerate than its
//! face. No quad edge is halved below the minimum edge (a triangle splits while its longest
//! edge is at least twice it). A leaf is not split when its children would not be valid elements (zero or non-finite area, or areas that do not add up to
//! the parent's to 1e-6: `f32` coordinates far from the origin, needles, 1e-6-area faces);
//! such leaves are counted ([`Refinement::unrefinable`]) and kept.
//!
//! Midpoints are computed as `(a + b) / 2` in `f64` from the `f32` corners and rounded to `f32`,
//! the same from either end, so a point where two leaves meet is one vertex. A leaf next to a
//! finer one has the finer one's corners in the middle of its edge (T-vertices); the vertex
//! radiosity of [`Mesh::corner_radiosity`] ties them to the coarse edge so shading is
//! continuous across it.

use crate::build::{
    Mesh, MeshError, PatchTemplate, Subdivision, checked_max_edge, local_origin, local_positions,
    max_coordinate, patches_of_face, resolved_size_at,
};
use crate::subdivide::{Cutter, Target};
use glam::{DVec3, Vec3};
use mcrad_scene_io::{Scene, SceneTextures};
use rayon::prelude::*;
use rustc_hash::FxBuildHasher;
use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};

/// One leaf element: a triangle (3 corners) or a convex quad (4), counter-clockwise from its
/// front, with the template of its input face.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Leaf {
    corners: [Vec3; 4],
    count: u8,
    /// Splits from the starting mesh's element.
    depth: u8,
    /// Index into [`AdaptiveMesh::templates`]: the face's material.
    template: u32,
    /// The input face ([`mcrad_scene_io::Face::source`]) the leaf lies in.
    face: u32,
    /// The back side of the leaf before it (a two-sided face): it splits with its front, into
    /// the same children, and its patch is the front's back side (its corners are unused).
    back: bool,
}

impl Leaf {
    /// A placeholder (no corners).
    const EMPTY: Leaf = Leaf {
        corners: [Vec3::ZERO; 4],
        count: 0,
        depth: 0,
        template: 0,
        face: 0,
        back: false,
    };

    fn corners(&self) -> &[Vec3] {
        &self.corners[..self.count as usize]
    }

    /// The leaf as the hierarchy keeps it, its corners left to its patch.
    fn record(&self) -> LeafRecord {
        LeafRecord {
            count: self.count,
            depth: self.depth,
            back: self.back,
            template: self.template,
            face: self.face,
        }
    }
}

/// A [`Leaf`] as an [`AdaptiveMesh`] keeps it between refinements: its corners are those of
/// its patch in the mesh (leaf `i` is patch `i`), read back where a split needs them
/// ([`AdaptiveMesh::leaf`]), so the hierarchy holds 12 bytes a leaf rather than 60.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LeafRecord {
    count: u8,
    depth: u8,
    back: bool,
    template: u32,
    face: u32,
}

/// The midpoint of `a` and `b`, computed in `f64` and rounded to `f32`; symmetric in `a`, `b`.
pub(crate) fn midpoint(a: Vec3, b: Vec3) -> Vec3 {
    ((a.as_dvec3() + b.as_dvec3()) * 0.5).as_vec3()
}

/// Area of a planar polygon (scene units², f64).
fn polygon_area(p: &[Vec3]) -> f64 {
    let p0 = p[0].as_dvec3();
    let mut area2 = DVec3::ZERO;
    for w in p[1..].windows(2) {
        area2 += (w[0].as_dvec3() - p0).cross(w[1].as_dvec3() - p0);
    }
    area2.length() / 2.0
}

/// The longest edge of a polygon (scene units).
fn longest_edge(p: &[Vec3]) -> f64 {
    (0..p.len())
        .map(|i| p[i].as_dvec3().distance(p[(i + 1) % p.len()].as_dvec3()))
        .fold(0.0, f64::max)
}

/// Bounds of an adaptive mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdaptiveBounds {
    /// No element is split when its children's longest edge would be below this (scene units,
    /// finite, `> 0`).
    pub min_edge: f32,
    /// The most leaf elements the mesh may have (`>= 1`); a refinement that would exceed it
    /// splits only the first leaves of its list that fit.
    pub max_patches: usize,
}

/// The default starting mesh as a fraction of the scene's bounding-box diagonal: no element
/// edge longer than the diagonal / 40, half the uniform default's. With the display's linear
/// reconstruction ([`Mesh::seamless_corner_radiosity`]) evenly lit walls need no finer start:
/// at 1e8 rays (image error table room / Cornell box, seed 0, minimum edge / 320, renders at 16
/// samples per pixel) the diagonal / 40 measured 0.77% / 1.09% with 6,100 / 10,600 elements
/// after refinement, / 80 0.74% / 1.04% with 16,100 / 20,700 (docs/meshing.md).
pub const DEFAULT_COARSE_EDGE_FRACTION: f32 = 1.0 / 40.0;

/// The default minimum element edge as a fraction of the bounding-box diagonal: 1/640 (four
/// halvings of the starting mesh). Contact lines and shadow edges are what reach it; against
/// 1/320, default settings at `--time 10` (render `--spp 256`, seed 0, 2 cores) measured image
/// errors table room 0.68% -> 0.54% (6,060 -> 9,641 elements), Cornell box 0.88% -> 0.86%
/// (10,745 -> 26,072), boxes room 3.86% -> 3.00% (26,270 -> 40,000, the budget).
pub const DEFAULT_MIN_EDGE_FRACTION: f32 = 1.0 / 640.0;

/// The default maximum number of leaf elements of an adaptive mesh (the CLI starts within
/// half of it and leaves the rest to the refinement).
pub const DEFAULT_MAX_PATCHES: usize = 40_000;

impl AdaptiveBounds {
    /// These bounds for a scene of `faces` input faces: the patch budget raised to
    /// `faces + max_patches / 2` when that is more, so that a mesh may always hold at least
    /// half of `max_patches` elements beyond one per face, however many faces there are (a
    /// scene of many small faces, each kept whole, still has its large faces refined). A
    /// scene of at most half as many faces as the budget keeps the budget as it is.
    pub fn for_faces(self, faces: usize) -> AdaptiveBounds {
        AdaptiveBounds {
            max_patches: self
                .max_patches
                .max(faces.saturating_add(self.max_patches / 2)),
            ..self
        }
    }

    /// Errors: a minimum edge that is not a positive length, a budget of 0.
    fn check(&self) -> Result<(), MeshError> {
        if !(self.min_edge.is_finite() && self.min_edge > 0.0) {
            return Err(MeshError::BadMinEdge(self.min_edge));
        }
        if self.max_patches == 0 {
            return Err(MeshError::BadMaxPatches);
        }
        Ok(())
    }

    /// The defaults for `scene`: minimum edge [`DEFAULT_MIN_EDGE_FRACTION`] of the bounding-box
    /// diagonal, [`DEFAULT_MAX_PATCHES`] leaves.
    pub fn default_for(scene: &Scene) -> AdaptiveBounds {
        AdaptiveBounds {
            min_edge: scene.bounds().diagonal() as f32 * DEFAULT_MIN_EDGE_FRACTION,
            max_patches: DEFAULT_MAX_PATCHES,
        }
    }
}

/// What one [`AdaptiveMesh::refine`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct Refinement {
    /// For each leaf of the new mesh, the index of the leaf of the previous mesh it is or came
    /// from (non-decreasing).
    pub parent: Vec<u32>,
    /// Leaves split.
    pub split: usize,
    /// Leaves asked for that could not be split into valid elements (kept as they are).
    pub unrefinable: usize,
    /// Leaves asked for that were not split because of the minimum edge or the patch budget.
    pub held: usize,
}

/// A mesh of leaf elements that can be refined; see the module documentation.
///
/// Invariants: leaf `i` is patch `i` of [`AdaptiveMesh::mesh`]; every leaf has 3 or 4 corners,
/// positive area and lies within its input face; the leaves of a face tile it.
#[derive(Debug, Clone)]
pub struct AdaptiveMesh {
    /// The scene's textured faces (elements take their reflectance from them).
    textures: Option<Arc<SceneTextures>>,
    templates: Vec<PatchTemplate>,
    leaves: Vec<LeafRecord>,
    mesh: Mesh,
    bounds: AdaptiveBounds,
    /// The smallest element size (`sqrt(area)`) the start mesh's `f32` coordinates resolve
    /// ([`Mesh::resolved_size`]): no split makes a child smaller.
    resolved: f64,
    /// The start and every refinement so far (see [`AdaptiveMesh::history`]).
    history: History,
}

/// An [`AdaptiveMesh`]'s starting leaves without their mesh ([`AdaptiveMesh::leaves`]): what
/// it needs of its scene, which may go before [`AdaptiveStart::build`] makes the mesh.
#[derive(Debug, Clone)]
pub struct AdaptiveStart {
    /// The hierarchy, its mesh and leaves empty.
    mesh: AdaptiveMesh,
    /// The leaves, with their corners.
    leaves: Vec<Leaf>,
    /// Faces kept whole rather than cut ([`Mesh::kept_whole`]).
    kept: usize,
}

impl AdaptiveStart {
    /// The starting mesh of these leaves (that of [`AdaptiveMesh::new`]).
    pub fn build(self) -> AdaptiveMesh {
        let AdaptiveStart {
            mut mesh,
            leaves,
            kept,
        } = self;
        let origin = mesh.mesh.origin();
        mesh.mesh = build_mesh(origin, &mesh.templates, &leaves, mesh.textures.clone());
        mesh.mesh.set_kept_whole(kept);
        mesh.leaves = leaves.iter().map(Leaf::record).collect();
        mesh
    }
}

/// How an adaptive mesh was made from its scene: its start and, refinement by refinement, the
/// leaves split (indices into the leaves before that refinement, ascending). Replaying it
/// ([`AdaptiveMesh::replay`]) on the same scene and bounds gives the same mesh, bit for bit.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct History {
    /// The starting mesh's uniform cut: `None` for one element per face, else the longest
    /// edge (scene units) of [`Subdivision::MaxEdge`].
    pub start: Option<f32>,
    /// Per refinement, the leaves split, ascending.
    pub splits: Vec<Vec<u32>>,
}

impl AdaptiveMesh {
    /// The starting mesh of `scene`: its faces cut uniformly by `start` (e.g.
    /// [`Subdivision::None`], or [`Subdivision::MaxEdge`] of [`DEFAULT_COARSE_EDGE_FRACTION`]
    /// times the diagonal), every patch a leaf.
    pub fn new(
        scene: &Scene,
        start: Subdivision,
        bounds: AdaptiveBounds,
    ) -> Result<AdaptiveMesh, MeshError> {
        Ok(AdaptiveMesh::leaves(scene, start, bounds)?.build())
    }

    /// The leaves of [`AdaptiveMesh::new`], their mesh not yet built: all it needs of `scene`,
    /// so that a caller can let the scene go before the mesh is made ([`AdaptiveStart::build`]).
    pub fn leaves(
        scene: &Scene,
        start: Subdivision,
        bounds: AdaptiveBounds,
    ) -> Result<AdaptiveStart, MeshError> {
        bounds.check()?;
        let (leaves, origin, resolved, kept) = start_leaves(scene, start)?;
        // one template a material (its factors: a textured face's patches multiply them anew);
        // each leaf names its face itself
        let templates: Vec<PatchTemplate> = scene
            .materials()
            .iter()
            .enumerate()
            .map(|(m, material)| PatchTemplate {
                reflectance: material.reflectance,
                emission: material.emission,
                face: 0,
                material: m as u32,
                two_sided: scene.is_two_sided(m as u32),
            })
            .collect();
        Ok(AdaptiveStart {
            leaves,
            mesh: AdaptiveMesh {
                textures: scene.textures().cloned(),
                templates,
                leaves: Vec::new(),
                mesh: Mesh::empty(origin, None),
                bounds,
                resolved,
                history: History {
                    start: match start {
                        Subdivision::None => None,
                        Subdivision::MaxEdge(l) => Some(l),
                    },
                    splits: Vec::new(),
                },
            },
            kept,
        })
    }

    /// The number of leaves [`AdaptiveMesh::new`] starts with for the same arguments (the
    /// patches of [`Mesh::build`] with `start`, counted without building them), or its error.
    pub fn start_len(
        scene: &Scene,
        start: Subdivision,
        bounds: AdaptiveBounds,
    ) -> Result<usize, MeshError> {
        bounds.check()?;
        let count = Mesh::count_patches(scene, start)?;
        Ok(usize::try_from(count).unwrap_or(usize::MAX))
    }

    /// The adaptive mesh that `history` records, made anew from `scene` within `bounds`: the
    /// same leaves in the same order as the mesh that recorded it, when scene and minimum edge
    /// are the same. The recorded splits, not `bounds.max_patches`, decide the count (a
    /// refinement may have raised its budget with the rays); the mesh keeps the larger of the
    /// two as its budget. Errors: as [`AdaptiveMesh::new`], and [`MeshError::BadHistory`] when
    /// a recorded split does not apply (another scene or minimum edge).
    pub fn replay(
        scene: &Scene,
        history: &History,
        bounds: AdaptiveBounds,
    ) -> Result<AdaptiveMesh, MeshError> {
        bounds.check()?;
        let start = history
            .start
            .map_or(Subdivision::None, Subdivision::MaxEdge);
        let unbounded = AdaptiveBounds {
            max_patches: usize::MAX,
            ..bounds
        };
        let mut mesh = AdaptiveMesh::new(scene, start, unbounded)?;
        for (round, split) in history.splits.iter().enumerate() {
            let done = mesh.refine(split);
            if done.split != split.len() {
                return Err(MeshError::BadHistory {
                    round,
                    recorded: split.len(),
                    split: done.split,
                });
            }
        }
        mesh.bounds.max_patches = bounds.max_patches.max(mesh.len());
        Ok(mesh)
    }

    /// How this mesh was made: its start and the leaves each refinement split.
    pub fn history(&self) -> &History {
        &self.history
    }

    /// The mesh of the current leaves (leaf `i` is patch `i`).
    pub fn mesh(&self) -> &Mesh {
        &self.mesh
    }

    /// The mesh of the current leaves, giving up the hierarchy.
    pub fn into_mesh(self) -> Mesh {
        self.mesh
    }

    /// The bounds the refinement keeps.
    pub fn bounds(&self) -> AdaptiveBounds {
        self.bounds
    }

    /// Number of leaves.
    pub fn len(&self) -> usize {
        self.leaves.len()
    }

    /// True when there are no leaves.
    pub fn is_empty(&self) -> bool {
        self.leaves.is_empty()
    }

    /// How many times leaf `i` was split from its starting element.
    pub fn depth(&self, i: usize) -> u32 {
        u32::from(self.leaves[i].depth)
    }

    /// Sets the bounds the refinements from now on keep. Errors as [`AdaptiveMesh::new`]'s for bad bounds.
    pub fn set_bounds(&mut self, bounds: AdaptiveBounds) -> Result<(), MeshError> {
        bounds.check()?;
        self.bounds = bounds;
        Ok(())
    }

    /// Whether leaf `i` is large enough to split: some edge it would halve stays at least the
    /// minimum edge (see [`AdaptiveMesh::refine`]).
    pub fn can_split(&self, i: usize) -> bool {
        split_plan(&self.leaf(i), self.bounds.min_edge).is_some()
    }

    /// Splits the leaves listed in `order` (indices into the current leaves; earlier ones first
    /// when the patch budget cannot hold them all; repeats are ignored) and rebuilds the mesh.
    /// Leaves below twice the minimum edge, or beyond the budget, are held; leaves whose
    /// children would be invalid are kept and counted as unrefinable. The new leaves keep the
    /// order of the old ones, children in place of their parent.
    pub fn refine(&mut self, order: &[u32]) -> Refinement {
        self.refine_within(order, usize::MAX)
    }

    /// [`AdaptiveMesh::refine`] adding at most `new` leaves (a split into `k` children adds
    /// `k - 1`) besides the patch budget: leaves beyond either are held.
    pub fn refine_within(&mut self, order: &[u32], new: usize) -> Refinement {
        let budget = self
            .bounds
            .max_patches
            .min(self.leaves.len().saturating_add(new));
        let mut split = vec![None::<Vec<Leaf>>; self.leaves.len()];
        let (mut count, mut unrefinable, mut held) = (self.leaves.len(), 0, 0);
        for &i in order {
            let mut i = i as usize;
            if i >= self.leaves.len() {
                continue;
            }
            // a back side splits with its front: the pair counts as two leaves throughout
            if self.leaves[i].back {
                i -= 1;
            }
            let sides = if self.is_paired(i) { 2 } else { 1 };
            if split[i].is_some() {
                continue;
            }
            let leaf = self.leaf(i);
            let Some(plan) = split_plan(&leaf, self.bounds.min_edge) else {
                held += sides;
                continue;
            };
            let Some(children) = split_leaf(&leaf, plan, self.resolved) else {
                unrefinable += sides;
                continue;
            };
            if count + sides * (children.len() - 1) > budget {
                held += sides;
                continue;
            }
            count += sides * (children.len() - 1);
            if sides == 2 {
                split[i + 1] = Some(children.iter().map(|c| Leaf { back: true, ..*c }).collect());
            }
            split[i] = Some(children);
        }
        let mut leaves = Vec::with_capacity(count);
        let mut parent = Vec::with_capacity(count);
        let mut done = 0;
        let mut split_leaves = Vec::new();
        let mut i = 0;
        while i < self.leaves.len() {
            match &split[i] {
                Some(children) if self.is_paired(i) => {
                    // fronts and backs alternate: each back right after its front
                    let backs = split[i + 1].as_ref().expect("a pair splits whole");
                    done += 2;
                    split_leaves.extend([i as u32, i as u32 + 1]);
                    for (f, b) in children.iter().zip(backs) {
                        parent.extend([i as u32, i as u32 + 1]);
                        leaves.extend([*f, *b]);
                    }
                    i += 2;
                    continue;
                }
                Some(children) => {
                    done += 1;
                    split_leaves.push(i as u32);
                    parent.extend(std::iter::repeat_n(i as u32, children.len()));
                    leaves.extend(children.iter().copied());
                }
                None => {
                    parent.push(i as u32);
                    leaves.push(self.leaf(i));
                }
            }
            i += 1;
        }
        let kept = self.mesh.kept_whole();
        self.mesh = build_mesh(
            self.mesh.origin(),
            &self.templates,
            &leaves,
            self.textures.clone(),
        );
        self.mesh.set_kept_whole(kept);
        self.leaves = leaves.iter().map(Leaf::record).collect();
        drop(leaves);
        self.history.splits.push(split_leaves);
        Refinement {
            parent,
            split: done,
            unrefinable,
            held,
        }
    }

    /// Whether leaf `i` is the front of a two-sided pair (the next leaf is its back).
    fn is_paired(&self, i: usize) -> bool {
        !self.leaves[i].back && self.leaves.get(i + 1).is_some_and(|l| l.back)
    }

    /// Leaf `i` with its corners, read from its patch (leaf `i` is patch `i`, a single polygon
    /// whose corners are the leaf's in order; a back side's are its front's reversed from the
    /// same first one).
    fn leaf(&self, i: usize) -> Leaf {
        let r = self.leaves[i];
        let mut corners = [Vec3::ZERO; 4];
        let positions = self.mesh.positions();
        let patch = &self.mesh.patches()[i];
        for (c, &v) in corners.iter_mut().zip(self.mesh.corners(patch)) {
            *c = positions[v as usize];
        }
        Leaf {
            corners,
            count: r.count,
            depth: r.depth,
            template: r.template,
            face: r.face,
            back: r.back,
        }
    }

    /// Bytes held per leaf element: the hierarchy's leaves and templates (one a material) and
    /// the mesh's patches, corners, triangles and vertices (capacities, not counting allocator
    /// overhead).
    pub fn bytes_per_element(&self) -> f64 {
        let leaves = self.leaves.capacity() * size_of::<LeafRecord>();
        let templates = self.templates.capacity() * size_of::<PatchTemplate>();
        (leaves + templates + self.mesh.heap_bytes()) as f64 / self.leaves.len().max(1) as f64
    }
}

/// How a leaf splits: a triangle into four, a quad across `u` (its `c0 -> c1` direction), `v`
/// (`c0 -> c3`) or both.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Plan {
    Triangle,
    Quad { u: bool, v: bool },
}

/// How `leaf` splits without an edge below `min_edge`: a triangle when its longest edge is at
/// least twice `min_edge` (its children are similar to it); a quad across each direction whose
/// side halves to at least `min_edge` and is not less than half the other side (so thin quads
/// are cut across their length only). `None`: it does not split.
fn split_plan(leaf: &Leaf, min_edge: f32) -> Option<Plan> {
    let c = leaf.corners();
    let min = f64::from(min_edge);
    if c.len() == 3 {
        return (longest_edge(c) >= 2.0 * min).then_some(Plan::Triangle);
    }
    let d = |a: Vec3, b: Vec3| a.as_dvec3().distance(b.as_dvec3());
    let u = d(c[0], c[1]).max(d(c[3], c[2]));
    let v = d(c[0], c[3]).max(d(c[1], c[2]));
    let (su, sv) = (
        u >= 2.0 * min && 2.0 * u >= v,
        v >= 2.0 * min && 2.0 * v >= u,
    );
    (su || sv).then_some(Plan::Quad { u: su, v: sv })
}

/// The children of `leaf` split by `plan`, or `None` if they would not be valid elements
/// (among them: smaller than `min_size`, `sqrt(area)` in scene units).
fn split_leaf(leaf: &Leaf, plan: Plan, min_size: f64) -> Option<Vec<Leaf>> {
    let c = leaf.corners();
    let child = |corners: &[Vec3]| {
        let mut out = [Vec3::ZERO; 4];
        out[..corners.len()].copy_from_slice(corners);
        Leaf {
            corners: out,
            count: corners.len() as u8,
            depth: leaf.depth.saturating_add(1),
            template: leaf.template,
            face: leaf.face,
            back: false,
        }
    };
    let children: Vec<Leaf> = match plan {
        Plan::Triangle => {
            let (m01, m12, m20) = (
                midpoint(c[0], c[1]),
                midpoint(c[1], c[2]),
                midpoint(c[2], c[0]),
            );
            vec![
                child(&[c[0], m01, m20]),
                child(&[m01, c[1], m12]),
                child(&[m20, m12, c[2]]),
                child(&[m01, m12, m20]),
            ]
        }
        Plan::Quad { u, v } => {
            let (m01, m12, m23, m30) = (
                midpoint(c[0], c[1]),
                midpoint(c[1], c[2]),
                midpoint(c[2], c[3]),
                midpoint(c[3], c[0]),
            );
            match (u, v) {
                (true, false) => {
                    vec![
                        child(&[c[0], m01, m23, c[3]]),
                        child(&[m01, c[1], c[2], m23]),
                    ]
                }
                (false, true) => {
                    vec![
                        child(&[c[0], c[1], m12, m30]),
                        child(&[m30, m12, c[2], c[3]]),
                    ]
                }
                _ => {
                    let centre =
                        ((c[0].as_dvec3() + c[1].as_dvec3() + c[2].as_dvec3() + c[3].as_dvec3())
                            * 0.25)
                            .as_vec3();
                    vec![
                        child(&[c[0], m01, centre, m30]),
                        child(&[m01, c[1], m12, centre]),
                        child(&[centre, m12, c[2], m23]),
                        child(&[m30, centre, m23, c[3]]),
                    ]
                }
            }
        }
    };
    let parent_area = polygon_area(c);
    let mut sum = 0.0;
    for ch in &children {
        let a = polygon_area(ch.corners());
        if !(a.is_finite() && a > 0.0)
            || a < 1e-3 * parent_area / children.len() as f64
            || a < min_size * min_size
        {
            return None;
        }
        sum += a;
    }
    ((sum - parent_area).abs() <= 1e-3 * parent_area).then_some(children)
}

/// The leaves of the start mesh of `scene` cut by `start` (the patches [`Mesh::build`] makes,
/// in its order, without the patches' areas, normals and textures), the local frame's origin,
/// the start's resolved size ([`Mesh::resolved_size`]) and its faces kept whole. Faces are cut
/// in parallel in blocks of [`START_BLOCK`] (a point a block makes on a face edge is computed
/// from the edge's ends, as another block would: the same leaves on any thread count). Errors
/// as [`Mesh::build`]'s.
fn start_leaves(
    scene: &Scene,
    start: Subdivision,
) -> Result<(Vec<Leaf>, Vec3, f64, usize), MeshError> {
    let max_edge = checked_max_edge(scene, start)?;
    let origin = local_origin(scene);
    let positions = local_positions(scene, origin);
    let coordinate = max_coordinate(&positions);
    let min_size = resolved_size_at(coordinate);
    let template = |face: &mcrad_scene_io::Face| {
        let material = &scene.materials()[face.material as usize];
        PatchTemplate {
            reflectance: material.reflectance,
            emission: material.emission,
            face: face.source,
            material: face.material,
            two_sided: scene.is_two_sided(face.material),
        }
    };
    // Each block's leaves, counted first, are cut into its own part of one array (no block
    // holds an array of its own: freed on worker threads, those would stay resident).
    let blocks: Vec<&[mcrad_scene_io::Face]> = scene.faces().chunks(START_BLOCK).collect();
    let counts: Vec<usize> = blocks
        .par_iter()
        .map(|faces| {
            let mut pos = Vec::new();
            let cut = max_edge.map(|l| (l, min_size));
            faces
                .iter()
                .map(|face| patches_of_face(scene, face, &positions, cut, &mut pos) as usize)
                .sum()
        })
        .collect();
    let mut leaves = vec![Leaf::EMPTY; counts.iter().sum()];
    let mut parts = Vec::with_capacity(blocks.len());
    let mut rest = &mut leaves[..];
    for &n in &counts {
        let (part, after) = rest.split_at_mut(n);
        parts.push(part);
        rest = after;
    }
    let cut: Vec<(f64, usize, bool)> = blocks
        .into_par_iter()
        .zip(parts)
        .map(|(faces, part)| {
            let expected = part.len();
            let mut sink = LeafSink {
                base: &positions,
                extra: Vec::new(),
                out: part,
                filled: 0,
            };
            let mut cutter = Cutter::keeping_whole_below(min_size);
            for face in faces {
                match max_edge {
                    None => sink.push_patch(&face.vertices, &template(face)),
                    Some(l) => cutter.cut_face(&mut sink, &face.vertices, l, &template(face)),
                }
            }
            let extra = max_coordinate(&sink.extra);
            (extra, cutter.kept_whole(), sink.filled == expected)
        })
        .collect();
    if cut.iter().any(|c| !c.2) {
        // the counts and the cuts disagree (they share their rules: never expected)
        return Err(MeshError::StartCount);
    }
    let coordinate = cut.iter().map(|c| c.0).fold(coordinate, f64::max);
    let kept = cut.iter().map(|c| c.1).sum();
    Ok((leaves, origin, resolved_size_at(coordinate), kept))
}

/// Faces a block of [`start_leaves`] cuts.
const START_BLOCK: usize = 1 << 14;

/// Where [`start_leaves`] cuts a block of faces: the scene's positions (local frame), the
/// points it adds, the leaves it makes.
struct LeafSink<'a> {
    base: &'a [Vec3],
    extra: Vec<Vec3>,
    /// The block's part of the leaves, filled up to `filled`.
    out: &'a mut [Leaf],
    filled: usize,
}

impl LeafSink<'_> {
    /// Puts `leaf` in the block's next place (one past its end is counted, not written).
    fn push(&mut self, leaf: Leaf) {
        if let Some(place) = self.out.get_mut(self.filled) {
            *place = leaf;
        }
        self.filled += 1;
    }

    fn leaf(&self, corners: &[u32], t: &PatchTemplate, back: bool) -> Leaf {
        let mut c = [Vec3::ZERO; 4];
        let count = corners.len() as u8;
        for (k, &v) in corners.iter().enumerate() {
            c[k] = self.position(v);
        }
        Leaf {
            corners: c,
            count,
            depth: 0,
            template: t.material,
            face: t.face,
            back,
        }
    }
}

impl Target for LeafSink<'_> {
    fn position(&self, i: u32) -> Vec3 {
        let i = i as usize;
        match self.base.get(i) {
            Some(&p) => p,
            None => self.extra[i - self.base.len()],
        }
    }

    fn push_position(&mut self, p: Vec3) -> u32 {
        self.extra.push(p);
        (self.base.len() + self.extra.len() - 1) as u32
    }

    fn push_patch(&mut self, corners: &[u32], t: &PatchTemplate) {
        let front = self.leaf(corners, t, false);
        self.push(front);
        if t.two_sided {
            // the back side's corners: the front's first, then the rest in reverse
            let mut own: Vec<u32> = corners.to_vec();
            own[1..].reverse();
            let back = self.leaf(&own, t, true);
            self.push(back);
        }
    }
}

/// Buckets of [`build_mesh`]'s vertex sharing (a fixed number: the same mesh on any thread
/// count).
const VERTEX_BUCKETS: usize = 64;

/// Leaves per block of [`build_mesh`]'s vertex sharing.
const LEAF_BLOCK: usize = 1 << 14;

/// The key of a corner: its coordinates' bits, `-0` as `+0`.
fn vertex_key(p: Vec3) -> [u32; 3] {
    p.to_array().map(|c| (c + 0.0).to_bits())
}

/// The bucket of a key: a multiplicative hash's top bits.
fn vertex_bucket(k: &[u32; 3]) -> usize {
    let h = (u64::from(k[0]) | (u64::from(k[1]) << 32)).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ u64::from(k[2]).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    (h.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 58) as usize % VERTEX_BUCKETS
}

/// The mesh of `leaves`: vertices shared where corners are equal as `f32`, numbered in the
/// order their first corner comes (leaf by leaf, corner by corner); leaf `i` (not a back side)
/// is a patch followed by its back side when its template is two-sided. Made in parallel on
/// rayon's pool: the corners are shared bucket by bucket (a bucket's first corner of each
/// position found in corner order), the patches' areas, normals and textures computed at once.
fn build_mesh(
    origin: Vec3,
    templates: &[PatchTemplate],
    leaves: &[Leaf],
    textures: Option<Arc<SceneTextures>>,
) -> Mesh {
    // corner k of leaf i is slot 4 i + k, sorted into buckets (each bucket's slots in
    // order, in one array: no block holds arrays of its own)
    let bucket_counts: Vec<[usize; VERTEX_BUCKETS]> = leaves
        .par_chunks(LEAF_BLOCK)
        .map(|block| {
            let mut counts = [0usize; VERTEX_BUCKETS];
            for leaf in block.iter().filter(|l| !l.back) {
                for &p in leaf.corners() {
                    counts[vertex_bucket(&vertex_key(p))] += 1;
                }
            }
            counts
        })
        .collect();
    let total: usize = bucket_counts.iter().flatten().sum();
    let mut slots = vec![0u32; total];
    let mut bucket_ranges = Vec::with_capacity(VERTEX_BUCKETS);
    let mut block_parts: Vec<Vec<&mut [u32]>> = bucket_counts
        .iter()
        .map(|_| Vec::with_capacity(VERTEX_BUCKETS))
        .collect();
    let (mut rest, mut at) = (&mut slots[..], 0);
    for bucket in 0..VERTEX_BUCKETS {
        let start = at;
        for (b, counts) in bucket_counts.iter().enumerate() {
            let (part, after) = rest.split_at_mut(counts[bucket]);
            block_parts[b].push(part);
            rest = after;
            at += counts[bucket];
        }
        bucket_ranges.push(start..at);
    }
    leaves
        .par_chunks(LEAF_BLOCK)
        .zip(block_parts)
        .enumerate()
        .for_each(|(b, (block, mut parts))| {
            let mut filled = [0usize; VERTEX_BUCKETS];
            for (j, leaf) in block.iter().enumerate() {
                if leaf.back {
                    continue;
                }
                let slot = 4 * (b * LEAF_BLOCK + j);
                for (k, &p) in leaf.corners().iter().enumerate() {
                    let bucket = vertex_bucket(&vertex_key(p));
                    parts[bucket][filled[bucket]] = (slot + k) as u32;
                    filled[bucket] += 1;
                }
            }
        });
    // first[slot]: the slot of the first corner at its position
    let mut first: Vec<AtomicU32> = (0..4 * leaves.len())
        .into_par_iter()
        .map(|_| AtomicU32::new(u32::MAX))
        .collect();
    bucket_ranges.into_par_iter().for_each(|range| {
        // corner keys are no one's input to attack: a fast hash
        let mut seen: HashMap<[u32; 3], u32, FxBuildHasher> =
            HashMap::with_capacity_and_hasher(range.len(), FxBuildHasher);
        for &slot in &slots[range] {
            let p = leaves[slot as usize / 4].corners[slot as usize % 4];
            let f = *seen.entry(vertex_key(p)).or_insert(slot);
            first[slot as usize].store(f, Ordering::Relaxed);
        }
    });
    drop(slots);
    // in corner order: a first corner is a new vertex, the others take their first's (its
    // slot in `first` now holds its vertex)
    let mut mesh = Mesh::empty(origin, textures);
    let corner_count: usize = leaves.iter().map(|l| usize::from(l.count)).sum();
    let mut corners = Vec::with_capacity(corner_count);
    let mut patch_leaf: Vec<u32> = Vec::with_capacity(leaves.len());
    for (i, leaf) in leaves.iter().enumerate() {
        if leaf.back {
            // pushed with its front (the template is two-sided)
            continue;
        }
        let start = corners.len();
        for (k, &p) in leaf.corners().iter().enumerate() {
            let slot = 4 * i + k;
            let f = *first[slot].get_mut() as usize;
            let v = if f == slot {
                mesh.push_position(p)
            } else {
                *first[f].get_mut()
            };
            *first[slot].get_mut() = v;
            corners.push(v);
        }
        patch_leaf.push(i as u32);
        if templates[leaf.template as usize].two_sided {
            corners.push(corners[start]);
            for k in (start + 1..corners.len() - 1).rev() {
                corners.push(corners[k]);
            }
            patch_leaf.push(i as u32 | BACK);
        }
    }
    drop(first);
    let count = patch_leaf.len();
    mesh.set_polygons(corners, count, |p| {
        let i = (patch_leaf[p] & !BACK) as usize;
        let leaf = &leaves[i];
        let template = PatchTemplate {
            face: leaf.face,
            ..templates[leaf.template as usize]
        };
        (usize::from(leaf.count), patch_leaf[p] & BACK != 0, template)
    });
    mesh.shrink_to_fit();
    mesh
}

/// The flag of a back side in [`build_mesh`]'s patch list.
const BACK: u32 = 1 << 31;
