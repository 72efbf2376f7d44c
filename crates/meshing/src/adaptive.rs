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

use crate::build::{Mesh, MeshError, PatchTemplate, Subdivision};
use glam::{DVec3, Vec3};
use mcrad_scene_io::{Scene, SceneTextures};
use std::collections::HashMap;
use std::sync::Arc;

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
    fn corners(&self) -> &[Vec3] {
        &self.corners[..self.count as usize]
    }
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
    leaves: Vec<Leaf>,
    mesh: Mesh,
    bounds: AdaptiveBounds,
    /// The smallest element size (`sqrt(area)`) the start mesh's `f32` coordinates resolve
    /// ([`Mesh::resolved_size`]): no split makes a child smaller.
    resolved: f64,
    /// The start and every refinement so far (see [`AdaptiveMesh::history`]).
    history: History,
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
        bounds.check()?;
        let coarse = Mesh::build(scene, start)?;
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
        let mut leaves = Vec::with_capacity(coarse.patches().len());
        for patch in coarse.patches() {
            let c = coarse.corners(patch);
            let mut corners = [Vec3::ZERO; 4];
            for (k, &v) in c.iter().enumerate() {
                corners[k] = coarse.positions()[v as usize];
            }
            leaves.push(Leaf {
                corners,
                count: c.len() as u8,
                depth: 0,
                template: patch.material,
                face: patch.face,
                back: patch.back,
            });
        }
        let textures = scene.textures().cloned();
        // the leaves hold all of the start mesh: drop it before building the leaves' own
        let (origin, resolved, kept) =
            (coarse.origin(), coarse.resolved_size(), coarse.kept_whole());
        drop(coarse);
        let mut mesh = build_mesh(origin, &templates, &leaves, textures.clone());
        mesh.set_kept_whole(kept);
        let start = match start {
            Subdivision::None => None,
            Subdivision::MaxEdge(l) => Some(l),
        };
        Ok(AdaptiveMesh {
            textures,
            templates,
            leaves,
            mesh,
            bounds,
            resolved,
            history: History {
                start,
                splits: Vec::new(),
            },
        })
    }

    /// The adaptive mesh that `history` records, made anew from `scene` within `bounds`: the
    /// same leaves in the same order as the mesh that recorded it, when scene and bounds are
    /// the same. Errors: as [`AdaptiveMesh::new`], and [`MeshError::BadHistory`] when a
    /// recorded split does not apply (another scene or bounds).
    pub fn replay(
        scene: &Scene,
        history: &History,
        bounds: AdaptiveBounds,
    ) -> Result<AdaptiveMesh, MeshError> {
        let start = history
            .start
            .map_or(Subdivision::None, Subdivision::MaxEdge);
        let mut mesh = AdaptiveMesh::new(scene, start, bounds)?;
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
        split_plan(&self.leaves[i], self.bounds.min_edge).is_some()
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
            let Some(plan) = split_plan(&self.leaves[i], self.bounds.min_edge) else {
                held += sides;
                continue;
            };
            let Some(children) = split_leaf(&self.leaves[i], plan, self.resolved) else {
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
                    leaves.push(self.leaves[i]);
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
        self.leaves = leaves;
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

    /// Bytes held per leaf element: the hierarchy's leaves and templates (one a material) and
    /// the mesh's patches, corners, triangles and vertices (capacities, not counting allocator
    /// overhead).
    pub fn bytes_per_element(&self) -> f64 {
        let leaves = self.leaves.capacity() * size_of::<Leaf>();
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

/// The mesh of `leaves`: vertices shared where corners are equal as `f32`.
fn build_mesh(
    origin: Vec3,
    templates: &[PatchTemplate],
    leaves: &[Leaf],
    textures: Option<Arc<SceneTextures>>,
) -> Mesh {
    let mut mesh = Mesh::empty(origin, textures);
    // the arrays at their final size, so that no growth or shrinking copies them
    let corner_count: usize = leaves.iter().map(|l| usize::from(l.count)).sum();
    mesh.reserve_exact(leaves.len(), corner_count, corner_count - 2 * leaves.len());
    let mut vertex: HashMap<[u32; 3], u32> = HashMap::with_capacity(leaves.len());
    let mut corners = Vec::with_capacity(4);
    for leaf in leaves {
        if leaf.back {
            // pushed with its front (the template is two-sided)
            continue;
        }
        corners.clear();
        for &p in leaf.corners() {
            let key = p.to_array().map(|c| (c + 0.0).to_bits());
            let v = *vertex.entry(key).or_insert_with(|| mesh.push_position(p));
            corners.push(v);
        }
        let template = PatchTemplate {
            face: leaf.face,
            ..templates[leaf.template as usize]
        };
        mesh.push_patch(&corners, &template);
    }
    mesh.shrink_to_fit();
    mesh
}
