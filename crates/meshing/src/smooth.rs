//! Vertex radiosity: per-patch values extrapolated to patch corners for smooth display.
//!
//! Balog's section 1.5: "Vertex radiosity is normally extrapolated from patches as area
//! weighted average." A corner takes the area-weighted mean of the patches around its vertex
//! that belong to the same surface as its own patch, so linear interpolation over the patch
//! shows smooth illumination while material boundaries and creases stay sharp.

#[cfg(doc)]
use crate::AdaptiveMesh;
use crate::adaptive::midpoint;
use crate::build::{Mesh, Patch};
use crate::corner_values::CornerValues;
use crate::reconstruct::{extrapolate, limited_gradients, tangents};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use rustc_hash::FxBuildHasher;
use std::collections::HashMap;

/// The default crease angle (degrees): neighbours whose normals differ from a corner's patch
/// normal by more than this are another surface and are not averaged in.
pub const DEFAULT_CREASE_ANGLE_DEGREES: f32 = 30.0;

/// Slack on the cosine comparison, so coplanar patches whose f32 normals differ by rounding
/// still count as one surface even at a crease angle of 0 (about 0.08° at 0°, far less above).
const COSINE_SLACK: f64 = 1e-6;

/// A vertex position as a hashable, ordered key: its coordinates' bits, with `-0` taken as `+0`
/// so that points equal as f32 are one vertex.
pub(crate) type PointKey = [u32; 3];

pub(crate) fn point_key(p: Vec3) -> PointKey {
    // `-0.0 + 0.0 == +0.0` in round-to-nearest; every other value is unchanged.
    p.to_array().map(|c| (c + 0.0).to_bits())
}

impl Mesh {
    /// Radiosity at every patch corner, extrapolated from per-patch values (W/m² per RGB channel,
    /// or any per-patch quantity) by the area-weighted average over the corner's surface.
    ///
    /// The value at corner `k` of patch `p` (global index [`Mesh::corner_offset`]`(p) + k`) is
    /// `sum_q A_q v_q / sum_q A_q` over the patches `q` that have a corner at the same point
    /// (positions equal as f32, so vertices an OBJ repeats per object or group still join;
    /// vertex indices are not compared) and lie on the same surface as `p`: the same
    /// [`Patch::material`](crate::Patch::material), and a normal within
    /// `crease_angle_degrees` of `p`'s normal. `p` itself always counts, once however many of
    /// its corners fall on the point. A patch that only touches the point along an edge
    /// (a T-junction) does not count ([`Mesh::seamless_corner_radiosity`] ties such points to
    /// the edge instead).
    ///
    /// `crease_angle_degrees` is clamped to `[0, 180]` (NaN counts as 0);
    /// [`DEFAULT_CREASE_ANGLE_DEGREES`] suits most scenes. At 180 every patch of the same
    /// material at the point is averaged in, including back-to-back ones.
    ///
    /// A corner whose surface is its own patch alone gets that patch's value exactly, and so does
    /// every corner of a constant solution. The result is deterministic: sums run in patch
    /// order.
    ///
    /// # Panics
    /// If `patch_values.len()` differs from [`Mesh::patches`]`().len()`.
    pub fn corner_radiosity(
        &self,
        patch_values: &[DVec3],
        crease_angle_degrees: f32,
    ) -> CornerValues {
        self.corner_values(patch_values, crease_angle_degrees, false)
    }

    /// Radiosity at every patch corner for display (renders, GLB, lightmaps): the linear
    /// reconstruction (the area-weighted mean over the corner's
    /// surface, as [`Mesh::corner_radiosity`], of each patch's limited linear extrapolation
    /// `v_q + g_q . (x - c_q)` to the point, never below zero where the values are not), without
    /// seams at T-vertices.
    ///
    /// A field linear over a face comes out exact at every corner, the face's border included
    /// (the area-weighted mean is off there by half an element's slope); a constant solution
    /// and a lone patch come out exactly; a step makes no value beyond the patches' range at a
    /// point the surface closes around.
    ///
    /// Where a corner's point is the midpoint of an edge of a patch `q` of the same surface
    /// (the T-vertices an [`AdaptiveMesh`]'s refinement makes next to a coarser element), the
    /// corners there take `q`'s value interpolated along that edge instead of the
    /// area-weighted mean, recursively for the halves of the edge, longest edges first. Linear
    /// interpolation over each patch is then continuous across every such edge: `q` interpolates
    /// between its two corner values along the edge, and the finer patches, piece by piece, do
    /// the same. Only midpoints are looked for: T-junctions at other fractions of an edge
    /// (uniform faces cut into different numbers of pieces) keep their area-weighted values.
    ///
    /// # Panics
    /// If `patch_values.len()` differs from [`Mesh::patches`]`().len()`.
    pub fn seamless_corner_radiosity(
        &self,
        patch_values: &[DVec3],
        crease_angle_degrees: f32,
    ) -> CornerValues {
        self.corner_values(patch_values, crease_angle_degrees, true)
    }

    /// The corner values of [`Mesh::corner_radiosity`], or with `seamless` those of
    /// [`Mesh::seamless_corner_radiosity`] (linear reconstruction, T-vertices tied).
    fn corner_values(
        &self,
        patch_values: &[DVec3],
        crease_angle_degrees: f32,
        seamless: bool,
    ) -> CornerValues {
        let patches = self.patches();
        assert_eq!(
            patch_values.len(),
            patches.len(),
            "corner_radiosity needs one value per patch"
        );
        let min_cosine = min_cosine(crease_angle_degrees);
        let points = Points::new(self);

        // For display, each patch's limited linear extrapolation (module `reconstruct`).
        let fitted = seamless.then(|| limited_gradients(self, patch_values, &points, min_cosine));
        let gradients = fitted.as_deref();
        // The smoothed value of each incidence: its patch's surface around the point. Filled
        // in place by blocks of whole points, in parallel (no copy of the output).
        let mut smoothed = vec![DVec3::ZERO; points.patches.len()];
        points
            .split(&mut smoothed)
            .into_par_iter()
            .for_each(|((first, end), out)| {
                let mut k = 0;
                for number in first..end {
                    let group = points.at(number);
                    let point = points.point(number).as_dvec3();
                    let at = |q: u32| match gradients {
                        Some(g) => extrapolate(
                            patch_values[q as usize],
                            &g[q as usize],
                            tangents(&patches[q as usize]),
                            point - patches[q as usize].centroid.as_dvec3(),
                        ),
                        None => patch_values[q as usize],
                    };
                    for &p in group {
                        let own = &patches[p as usize];
                        // `v_p + sum_q A_q (v_q - v_p) / sum_q A_q`: the area-weighted mean,
                        // written so that a lone patch or a constant solution comes out
                        // exactly.
                        let own_value = at(p);
                        let (mut weighted, mut area) = (DVec3::ZERO, 0.0);
                        let mut lowest = patch_values[p as usize];
                        for &q in group {
                            let other = &patches[q as usize];
                            if q == p || same_surface(own, other, min_cosine) {
                                weighted += other.area * (at(q) - own_value);
                                area += other.area;
                                lowest = lowest.min(patch_values[q as usize]);
                            }
                        }
                        // An extrapolation at a border never goes below zero (nor below the
                        // lowest value there, for signed quantities).
                        out[k] = (own_value + weighted / area).max(lowest.min(DVec3::ZERO));
                        k += 1;
                    }
                }
            });
        // (each array goes as soon as it has served: at 10^7 patches they are GiBs)
        drop(fitted);
        if seamless {
            self.tie_t_vertices(&points, &mut smoothed, min_cosine);
        }

        // Each corner's incidence, through which it reads its value.
        let incidence = self.corner_incidences(&points);
        drop(points);
        CornerValues::shared(smoothed, incidence)
    }

    /// The index in `points`' incidences of every corner (global corner order), by blocks of
    /// whole patches in parallel.
    fn corner_incidences(&self, points: &Points) -> Vec<u32> {
        let patches = self.patches();
        let mut incidence = vec![0u32; self.corner_count()];
        let ends: Vec<usize> = (PATCH_BLOCK..patches.len())
            .step_by(PATCH_BLOCK)
            .chain([patches.len()])
            .map(|p| self.corner_offset(p))
            .collect();
        split_by(&mut incidence, &ends)
            .into_par_iter()
            .enumerate()
            .for_each(|(block, (_, out))| {
                let first = block * PATCH_BLOCK;
                let last = (first + PATCH_BLOCK).min(patches.len());
                let mut k = 0;
                for (p, patch) in patches.iter().enumerate().take(last).skip(first) {
                    for &v in self.corners(patch) {
                        let i = points
                            .incidence_of_vertex(v, p as u32)
                            .expect("every corner was recorded as an incidence");
                        out[k] = i as u32;
                        k += 1;
                    }
                }
            });
        incidence
    }

    /// Ties the values at T-vertices to the edges they lie on (see
    /// [`Mesh::seamless_corner_radiosity`]): where the midpoint `m` of an edge `(a, b)` of patch
    /// `q` is a corner of other patches of `q`'s surface, those corners get
    /// `(v_q(a) + v_q(b)) / 2`, and the halves `(a, m)` and `(m, b)` are tied in turn. Edges are
    /// tied longest first, repeated until nothing changes (a T-vertex depends only on longer
    /// edges, so this ends).
    fn tie_t_vertices(&self, points: &Points, smoothed: &mut [DVec3], min_cosine: f64) {
        let positions = self.positions();
        // the edges whose midpoint is a point of the mesh, patch by patch (in order)
        let mut edges: Vec<(f64, u32, Vec3, Vec3)> = self
            .patches()
            .par_iter()
            .enumerate()
            .flat_map_iter(|(q, patch)| {
                let c = self.corners(patch);
                (0..c.len()).filter_map(move |k| {
                    let (a, b) = (
                        positions[c[k] as usize],
                        positions[c[(k + 1) % c.len()] as usize],
                    );
                    points
                        .range(point_key(midpoint(a, b)))
                        .map(|_| (a.as_dvec3().distance(b.as_dvec3()), q as u32, a, b))
                })
            })
            .collect();
        if edges.is_empty() {
            return;
        }
        edges.sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));
        let tie = Tie {
            points,
            patches: self.patches(),
            min_cosine,
        };
        for _ in 0..64 {
            let mut changed = false;
            for &(_, q, a, b) in &edges {
                let value = |p: Vec3| {
                    let i = points
                        .incidence(point_key(p), q)
                        .expect("a patch's corner is one of its incidences");
                    smoothed[i]
                };
                let (va, vb) = (value(a), value(b));
                changed |= tie.edge(smoothed, q, a, b, va, vb, 0);
            }
            if !changed {
                break;
            }
        }
    }

    /// Every `(point, patch)` incidence, sorted by point and then patch, without repeats.
    fn incidences(&self) -> Vec<(PointKey, u32)> {
        let mut incidences: Vec<(PointKey, u32)> = Vec::with_capacity(self.corner_count());
        for (p, patch) in self.patches().iter().enumerate() {
            for &v in self.corners(patch) {
                incidences.push((point_key(self.positions()[v as usize]), p as u32));
            }
        }
        // equal entries are equal: the order is the same on any thread count
        incidences.par_sort_unstable();
        incidences.dedup();
        incidences
    }

    /// The surfaces [`Mesh::corner_radiosity`] averages over, grouped so that corners averaging
    /// over the same patches at the same point share one group.
    ///
    /// Corner `k` of patch `p` (global index [`Mesh::corner_offset`]`(p) + k`) belongs to group
    /// [`CornerGroups::group_of`]`(corner)`, whose [`CornerGroups::patches`] are exactly the
    /// patches `q` that `corner_radiosity` averages for that corner with the same
    /// `crease_angle_degrees` (its own patch, and those with a corner at the same point, the same
    /// material and a normal within the crease angle of `p`'s). So
    /// `corner_radiosity(v)[corner]` is the area-weighted mean of `v` over the corner's group, and
    /// a per-vertex quantity computed once per group (a vertex gather) belongs to every corner of
    /// the group. The relation "within the crease angle of" is not transitive, so two corners at
    /// one point may belong to different, overlapping groups.
    ///
    /// Groups are numbered by point (ordered by the bits of its coordinates) and then by the
    /// lowest patch index that uses them; the result is deterministic.
    pub fn corner_groups(&self, crease_angle_degrees: f32) -> CornerGroups {
        let patches = self.patches();
        let min_cosine = min_cosine(crease_angle_degrees);
        let points = Points::new(self);
        let mut groups = CornerGroups {
            points: Vec::new(),
            first_patch: vec![0],
            patches: Vec::new(),
            corner_group: Vec::new(),
        };
        // The group of each incidence.
        let mut incidence_group = Vec::with_capacity(points.patches.len());
        let mut members = Vec::new();
        for at in 0..points.len() {
            let at_point = points.at(at);
            let first_group_here = groups.len();
            for &p in at_point {
                let own = &patches[p as usize];
                members.clear();
                members.extend(
                    at_point
                        .iter()
                        .copied()
                        .filter(|&q| q == p || same_surface(own, &patches[q as usize], min_cosine)),
                );
                let existing =
                    (first_group_here..groups.len()).find(|&g| groups.patches(g) == members);
                let g = existing.unwrap_or_else(|| {
                    groups.points.push(points.point(at));
                    groups.patches.extend_from_slice(&members);
                    groups.first_patch.push(groups.patches.len() as u32);
                    groups.len() - 1
                });
                incidence_group.push(g as u32);
            }
        }
        groups.corner_group = self
            .corner_incidences(&points)
            .into_iter()
            .map(|i| incidence_group[i as usize])
            .collect();
        groups
    }
}

/// What tying an edge's T-vertices reads: see [`Mesh::tie_t_vertices`].
struct Tie<'a> {
    points: &'a Points,
    patches: &'a [Patch],
    min_cosine: f64,
}

impl Tie<'_> {
    /// Sets the values at the midpoint of `q`'s edge piece `(a, b)` (values `va`, `vb` at its
    /// ends) for the patches of `q`'s surface with a corner there, and recurses into the halves;
    /// whether any value changed.
    #[allow(clippy::too_many_arguments)]
    fn edge(
        &self,
        smoothed: &mut [DVec3],
        q: u32,
        a: Vec3,
        b: Vec3,
        va: DVec3,
        vb: DVec3,
        depth: u32,
    ) -> bool {
        if depth > 48 {
            return false;
        }
        let m = midpoint(a, b);
        if m == a || m == b {
            return false;
        }
        let Some((start, end)) = self.points.range(point_key(m)) else {
            return false;
        };
        let own = &self.patches[q as usize];
        let vm = (va + vb) * 0.5;
        let (mut found, mut changed) = (false, false);
        for (&p, value) in self.points.patches[start..end]
            .iter()
            .zip(&mut smoothed[start..end])
        {
            if p != q && same_surface(own, &self.patches[p as usize], self.min_cosine) {
                found = true;
                if *value != vm {
                    *value = vm;
                    changed = true;
                }
            }
        }
        if !found {
            return false;
        }
        let left = self.edge(smoothed, q, a, m, va, vm, depth + 1);
        let right = self.edge(smoothed, q, m, b, vm, vb, depth + 1);
        changed | left | right
    }
}

/// A mesh's `(point, patch)` incidences, sorted by point and then patch without repeats, by
/// point: each point's key and run of patches, a point's key or a mesh vertex to its run (about
/// 4 bytes an incidence, 36 a point and 4 a vertex), so that a corner's incidence is found
/// without a search over all of them.
pub(crate) struct Points {
    /// Point `k`'s key.
    keys: Vec<PointKey>,
    /// The patch of each incidence: point `k`'s are `patches[starts[k]..starts[k + 1]]`,
    /// ascending.
    pub(crate) patches: Vec<u32>,
    starts: Vec<u32>,
    /// A point's key to its number.
    number: HashMap<PointKey, u32, FxBuildHasher>,
    /// Each vertex's point number ([`u32::MAX`] for a position no patch has as a corner).
    of_vertex: Vec<u32>,
}

impl Points {
    /// The points of `mesh`'s patches' corners.
    pub(crate) fn new(mesh: &Mesh) -> Points {
        let incidences = mesh.incidences();
        let mut number = HashMap::with_hasher(FxBuildHasher);
        let (mut keys, mut starts) = (Vec::new(), vec![0u32]);
        for run in incidences.chunk_by(|a, b| a.0 == b.0) {
            number.insert(run[0].0, keys.len() as u32);
            keys.push(run[0].0);
            starts.push(starts[starts.len() - 1] + run.len() as u32);
        }
        // the keys are the points' own: each incidence keeps its patch (16 bytes -> 4)
        let patches = incidences.par_iter().map(|&(_, p)| p).collect();
        drop(incidences);
        let of_vertex = mesh
            .positions()
            .par_iter()
            .map(|&x| number.get(&point_key(x)).copied().unwrap_or(u32::MAX))
            .collect();
        Points {
            keys,
            patches,
            starts,
            number,
            of_vertex,
        }
    }

    /// The number of points.
    pub(crate) fn len(&self) -> usize {
        self.keys.len()
    }

    /// Point `k`'s position.
    pub(crate) fn point(&self, k: usize) -> Vec3 {
        Vec3::from_array(self.keys[k].map(f32::from_bits))
    }

    /// The patches at point `k`, ascending.
    pub(crate) fn at(&self, k: usize) -> &[u32] {
        &self.patches[self.starts[k] as usize..self.starts[k + 1] as usize]
    }

    /// `data` (one item per incidence) cut into blocks of whole points of about
    /// [`POINT_BLOCK`] incidences, each with its first point and the point after its last.
    pub(crate) fn split<'d, T>(&self, data: &'d mut [T]) -> Vec<((usize, usize), &'d mut [T])> {
        debug_assert_eq!(data.len(), self.patches.len());
        let mut blocks = Vec::new();
        let mut first = 0;
        while first < self.len() {
            let want = self.starts[first] as usize + POINT_BLOCK;
            let end = self
                .starts
                .partition_point(|&s| (s as usize) < want)
                .clamp(first + 1, self.len());
            blocks.push((first, end));
            first = end;
        }
        let ends: Vec<usize> = blocks
            .iter()
            .map(|&(_, end)| self.starts[end] as usize)
            .collect();
        blocks
            .into_iter()
            .zip(split_by(data, &ends))
            .map(|(block, (_, piece))| (block, piece))
            .collect()
    }

    /// Point `k`'s range of incidences.
    fn run(&self, k: u32) -> Option<(usize, usize)> {
        let k = k as usize;
        Some((
            *self.starts.get(k)? as usize,
            *self.starts.get(k + 1)? as usize,
        ))
    }

    /// The range of the incidences at the point `key`, if it is one of their points.
    pub(crate) fn range(&self, key: PointKey) -> Option<(usize, usize)> {
        self.run(*self.number.get(&key)?)
    }

    /// The range of the incidences at mesh vertex `v`'s point, if it is a corner.
    pub(crate) fn range_of_vertex(&self, v: u32) -> Option<(usize, usize)> {
        self.run(*self.of_vertex.get(v as usize)?)
    }

    /// The index of the incidence `(key, patch)`, if there is one.
    pub(crate) fn incidence(&self, key: PointKey, patch: u32) -> Option<usize> {
        self.within(self.range(key)?, patch)
    }

    /// The index of the incidence of mesh vertex `v`'s point and `patch`, if there is one.
    pub(crate) fn incidence_of_vertex(&self, v: u32, patch: u32) -> Option<usize> {
        self.within(self.range_of_vertex(v)?, patch)
    }

    /// The index of `patch`'s incidence in the run `(start, end)`.
    fn within(&self, (start, end): (usize, usize), patch: u32) -> Option<usize> {
        self.patches[start..end]
            .binary_search(&patch)
            .ok()
            .map(|i| start + i)
    }
}

/// The cosine a neighbour's normal must reach to lie within `crease_angle_degrees` (clamped to
/// `[0, 180]`, NaN as 0), less the rounding slack.
fn min_cosine(crease_angle_degrees: f32) -> f64 {
    let angle = if crease_angle_degrees.is_nan() {
        0.0
    } else {
        crease_angle_degrees.clamp(0.0, 180.0)
    };
    (angle as f64).to_radians().cos() - COSINE_SLACK
}

/// Whether `other` belongs to `own`'s surface at a shared point: the same material and a normal
/// within the crease angle (`own` itself always does; callers test that by index).
pub(crate) fn same_surface(own: &Patch, other: &Patch, min_cosine: f64) -> bool {
    other.material == own.material
        && other.normal.as_dvec3().dot(own.normal.as_dvec3()) >= min_cosine
}

/// Groups of patch corners that share a surface at a point: see [`Mesh::corner_groups`].
///
/// Invariants: every group has a point and at least one patch (sorted, without repeats, all of
/// one material); every corner of the mesh names a group.
#[derive(Debug, Clone, PartialEq)]
pub struct CornerGroups {
    /// Per group: the shared corner position (scene units).
    points: Vec<Vec3>,
    /// Per group `g`: its patches are `patches[first_patch[g]..first_patch[g + 1]]`.
    first_patch: Vec<u32>,
    patches: Vec<u32>,
    /// Per global corner: its group.
    corner_group: Vec<u32>,
}

impl CornerGroups {
    /// Number of groups.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when there is no group (a mesh without patches).
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The position shared by the corners of group `g` (scene units).
    pub fn point(&self, g: usize) -> Vec3 {
        self.points[g]
    }

    /// The patch indices of group `g`, ascending: the patches whose values are averaged there.
    pub fn patches(&self, g: usize) -> &[u32] {
        &self.patches[self.first_patch[g] as usize..self.first_patch[g + 1] as usize]
    }

    /// The group of global corner `corner` (see [`Mesh::corner_offset`]).
    pub fn group_of(&self, corner: usize) -> usize {
        self.corner_group[corner] as usize
    }

    /// The group of every global corner, in corner order ([`Mesh::corner_count`] entries).
    pub fn corner_groups(&self) -> &[u32] {
        &self.corner_group
    }
}

/// Patches per block of the parallel corner lookup.
const PATCH_BLOCK: usize = 16_384;

/// Incidences per block of the parallel smoothing, about (blocks end at a point's end).
const POINT_BLOCK: usize = 65_536;

/// `data` cut at the increasing `ends` (the last `data.len()`), each piece with its start.
fn split_by<'a, T>(mut data: &'a mut [T], ends: &[usize]) -> Vec<(usize, &'a mut [T])> {
    let mut pieces = Vec::with_capacity(ends.len());
    let mut start = 0;
    for &end in ends {
        let (piece, rest) = data.split_at_mut(end - start);
        pieces.push((start, piece));
        data = rest;
        start = end;
    }
    pieces
}

#[cfg(test)]
mod tests {
    use super::DEFAULT_CREASE_ANGLE_DEGREES;
    use crate::{Mesh, Subdivision};
    use glam::{DVec3, Vec3};
    use mcrad_scene_io::{Face, Material, Scene};

    /// Two materials, both emitting (a scene needs an emitter; smoothing ignores emission).
    fn materials() -> Vec<Material> {
        ["white", "red"]
            .iter()
            .map(|name| Material {
                name: (*name).into(),
                reflectance: Vec3::splat(0.5),
                emission: Vec3::ONE,
            })
            .collect()
    }

    fn face(vertices: &[u32], material: u32, source: u32) -> Face {
        Face {
            vertices: vertices.to_vec(),
            material,
            source,
        }
    }

    fn mesh(positions: Vec<Vec3>, faces: Vec<Face>, subdivision: Subdivision) -> Mesh {
        let scene = Scene::new(positions, faces, materials())
            .expect("valid scene")
            .0;
        let mesh = Mesh::build(&scene, subdivision).expect("mesh");
        mesh.validate().expect("valid mesh");
        mesh
    }

    /// Global corner indices and positions of `patch`'s corners.
    fn corners(mesh: &Mesh, patch: usize) -> impl Iterator<Item = (usize, Vec3)> + '_ {
        let offset = mesh.corner_offset(patch);
        mesh.corners(&mesh.patches()[patch])
            .iter()
            .enumerate()
            .map(move |(k, &v)| (offset + k, mesh.positions()[v as usize]))
    }

    /// Two unit quads sharing the edge x = 1 (vertices 1 and 2); the second is turned up about
    /// that edge by `bend_degrees` (0: coplanar, 90: a wall). Each quad uses its own copies of
    /// the shared vertices, as an OBJ with two objects would.
    fn hinge(bend_degrees: f32, materials: [u32; 2]) -> Mesh {
        let (s, c) = bend_degrees.to_radians().sin_cos();
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            // copies of 1 and 2, then the far edge of the bent quad
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0 + c, 0.0, s),
            Vec3::new(1.0 + c, 1.0, s),
            Vec3::new(1.0, 1.0, 0.0),
        ];
        let faces = vec![
            face(&[0, 1, 2, 3], materials[0], 0),
            face(&[4, 5, 6, 7], materials[1], 1),
        ];
        mesh(positions, faces, Subdivision::None)
    }

    fn on_hinge(p: Vec3) -> bool {
        p.x == 1.0 && p.z == 0.0
    }

    #[test]
    fn corner_offsets_are_prefix_sums_of_corner_counts() {
        let m = hinge(0.0, [0, 0]);
        assert_eq!(m.corner_offset(0), 0);
        assert_eq!(m.corner_offset(1), 4);
        assert_eq!(m.corner_offset(2), 8);
        assert_eq!(m.corner_count(), 8);
    }

    #[test]
    fn a_constant_solution_stays_constant_at_every_corner() {
        // Two walls, a floor, a bent quad and a pentagon of two materials, subdivided.
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 2.0, 0.0),
            Vec3::new(0.0, 2.0, 0.0),
            Vec3::new(0.0, 0.0, 1.5),
            Vec3::new(2.0, 0.0, 1.5),
            Vec3::new(2.5, 2.0, 0.3),
            Vec3::new(-1.0, 1.0, 0.0),
            Vec3::new(-0.7, 0.2, 0.0),
        ];
        let faces = vec![
            face(&[0, 1, 2, 3], 0, 0),
            face(&[1, 0, 4, 5], 0, 1),
            face(&[1, 6, 2], 1, 2),
            face(&[0, 3, 7, 8], 1, 3),
        ];
        let m = mesh(positions, faces, Subdivision::MaxEdge(0.3));
        let value = DVec3::new(0.7, 3.1, 12.9);
        let out = m.corner_radiosity(&vec![value; m.patches().len()], 45.0);
        assert_eq!(out.len(), m.corner_count());
        for (i, v) in out.iter().enumerate() {
            assert_eq!(v, value, "corner {i}");
        }
    }

    #[test]
    fn a_linear_field_is_reproduced_at_interior_vertices_of_uniform_grids() {
        // Around an interior vertex of a uniform quad grid (4 quads) or triangle grid (6
        // triangles) the neighbours are equal in area and point-symmetric about the vertex, so
        // the area-weighted mean of a linear function at their centroids is its vertex value.
        let f = |p: DVec3| DVec3::new(1.0 + 2.0 * p.x - 3.0 * p.y, 0.5 * p.x + p.y, 4.0 - p.y);
        let square = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(4.0, 0.0, 0.0),
            Vec3::new(4.0, 4.0, 0.0),
            Vec3::new(0.0, 4.0, 0.0),
        ];
        let e = 1e-3;
        let in_square = |p: Vec3| p.x > e && p.y > e && p.x < 4.0 - e && p.y < 4.0 - e;
        let in_triangle = |p: Vec3| p.y > e && p.x < 4.0 - e && p.x - p.y > e;
        // Grid spacings 1 and 1/2, so every position is exact in f32 and the symmetry is exact.
        type Interior<'a> = &'a dyn Fn(Vec3) -> bool;
        let cases: [(Face, f32, Interior, usize); 2] = [
            (face(&[0, 1, 2, 3], 0, 0), 1.0, &in_square, 3 * 3),
            (face(&[0, 1, 2], 0, 0), 0.75, &in_triangle, 7 * 6 / 2),
        ];
        for (face, max_edge, interior, interior_vertices) in cases {
            let m = mesh(square.clone(), vec![face], Subdivision::MaxEdge(max_edge));
            // The centroid of these triangles and parallelograms is the mean of their corners.
            let values: Vec<DVec3> = (0..m.patches().len())
                .map(|p| {
                    let c: Vec<DVec3> = corners(&m, p).map(|(_, x)| x.as_dvec3()).collect();
                    f(c.iter().sum::<DVec3>() / c.len() as f64)
                })
                .collect();
            let out = m.corner_radiosity(&values, DEFAULT_CREASE_ANGLE_DEGREES);
            let mut seen = std::collections::BTreeSet::new();
            for p in 0..m.patches().len() {
                for (i, pos) in corners(&m, p).filter(|&(_, pos)| interior(pos)) {
                    seen.insert(pos.to_array().map(f32::to_bits));
                    let want = f(pos.as_dvec3());
                    assert!(
                        (out[i] - want).abs().max_element() < 1e-12,
                        "corner {i} at {pos}: {} vs {want}",
                        out[i]
                    );
                }
            }
            assert_eq!(seen.len(), interior_vertices);
        }
    }

    #[test]
    fn a_material_boundary_is_not_averaged_across() {
        let values = [DVec3::splat(1.0), DVec3::splat(3.0)];
        // Same material: the shared edge's corners get the mean of the two equal-area quads.
        let joined = hinge(0.0, [0, 0]);
        let out = joined.corner_radiosity(&values, DEFAULT_CREASE_ANGLE_DEGREES);
        for (p, value) in values.iter().enumerate() {
            for (i, pos) in corners(&joined, p) {
                let want = if on_hinge(pos) { 2.0 } else { value.x };
                assert_eq!(out[i], DVec3::splat(want), "patch {p} corner at {pos}");
            }
        }
        // Different materials: every corner keeps its own patch's value.
        let split = hinge(0.0, [0, 1]);
        let out = split.corner_radiosity(&values, 180.0);
        for (p, &value) in values.iter().enumerate() {
            for (i, pos) in corners(&split, p) {
                assert_eq!(out[i], value, "patch {p} corner at {pos}");
            }
        }
    }

    #[test]
    fn a_crease_is_not_averaged_across_but_a_gentle_bend_is() {
        let values = [DVec3::new(1.0, 2.0, 4.0), DVec3::new(3.0, 2.0, 0.0)];
        let wall = hinge(90.0, [0, 0]);
        let out = wall.corner_radiosity(&values, DEFAULT_CREASE_ANGLE_DEGREES);
        for (p, &value) in values.iter().enumerate() {
            for (i, _) in corners(&wall, p) {
                assert_eq!(out[i], value);
            }
        }
        // A 10° bend is one surface at the default crease angle, but not at a 5° one.
        let bent = hinge(10.0, [0, 0]);
        let (a0, a1) = (bent.patches()[0].area, bent.patches()[1].area);
        let mean = (a0 * values[0] + a1 * values[1]) / (a0 + a1);
        let out = bent.corner_radiosity(&values, DEFAULT_CREASE_ANGLE_DEGREES);
        let sharp = bent.corner_radiosity(&values, 5.0);
        let mut shared = 0;
        for (p, &value) in values.iter().enumerate() {
            for (i, pos) in corners(&bent, p) {
                if on_hinge(pos) {
                    shared += 1;
                    assert!((out[i] - mean).abs().max_element() < 1e-12, "{}", out[i]);
                } else {
                    assert_eq!(out[i], value);
                }
                assert_eq!(sharp[i], value);
            }
        }
        assert_eq!(shared, 4);
    }

    #[test]
    fn corner_groups_hold_exactly_what_corner_radiosity_averages() {
        // Walls, a floor, a gentle bend and a second material, subdivided; and a fan of three
        // quads bent by 20° each (the outer two 40° apart).
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 2.0, 0.0),
            Vec3::new(0.0, 2.0, 0.0),
            Vec3::new(0.0, 0.0, 1.5),
            Vec3::new(2.0, 0.0, 1.5),
            Vec3::new(2.5, 2.0, 0.3),
            Vec3::new(-1.0, 1.0, 0.0),
            Vec3::new(-0.7, 0.2, 0.0),
        ];
        let faces = vec![
            face(&[0, 1, 2, 3], 0, 0),
            face(&[1, 0, 4, 5], 0, 1),
            face(&[1, 6, 2], 0, 2),
            face(&[0, 3, 7, 8], 1, 3),
        ];
        let walls = mesh(positions, faces, Subdivision::MaxEdge(0.4));
        let fan = {
            let (s, c) = 20f32.to_radians().sin_cos();
            let (s2, c2) = 40f32.to_radians().sin_cos();
            let positions = vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(1.0 + c, 0.0, s),
                Vec3::new(1.0 + c, 1.0, s),
                Vec3::new(1.0 + c + c2, 0.0, s + s2),
                Vec3::new(1.0 + c + c2, 1.0, s + s2),
            ];
            let faces = vec![
                face(&[0, 1, 2, 3], 0, 0),
                face(&[1, 4, 5, 2], 0, 1),
                face(&[4, 6, 7, 5], 0, 2),
            ];
            mesh(positions, faces, Subdivision::None)
        };
        for m in [&walls, &fan] {
            let values: Vec<DVec3> = (0..m.patches().len())
                .map(|p| DVec3::new(1.0 + p as f64, (p * p % 7) as f64, 0.5 * (p % 3) as f64))
                .collect();
            for crease in [0.0, DEFAULT_CREASE_ANGLE_DEGREES, 90.0, 180.0] {
                let smooth = m.corner_radiosity(&values, crease);
                let groups = m.corner_groups(crease);
                assert_eq!(groups.corner_groups().len(), m.corner_count());
                for p in 0..m.patches().len() {
                    for (i, pos) in corners(m, p) {
                        let g = groups.group_of(i);
                        let members = groups.patches(g);
                        assert_eq!(groups.point(g), pos);
                        assert!(members.contains(&(p as u32)));
                        assert!(members.windows(2).all(|w| w[0] < w[1]));
                        let (mut sum, mut area) = (DVec3::ZERO, 0.0);
                        for &q in members {
                            sum += m.patches()[q as usize].area * values[q as usize];
                            area += m.patches()[q as usize].area;
                        }
                        assert!(
                            (sum / area - smooth[i]).abs().max_element() < 1e-12,
                            "crease {crease}, corner {i}"
                        );
                    }
                }
                // Groups are distinct (point, patches) pairs.
                for g in 0..groups.len() {
                    for h in 0..g {
                        assert!(
                            groups.point(g) != groups.point(h)
                                || groups.patches(g) != groups.patches(h)
                        );
                    }
                }
            }
        }
        // In the fan at 30°, the middle quad shares its first hinge with the first quad and its
        // second with the third, which are two surfaces apart.
        let groups = fan.corner_groups(DEFAULT_CREASE_ANGLE_DEGREES);
        let first_hinge = (0..4)
            .map(|k| fan.corner_offset(1) + k)
            .map(|i| groups.patches(groups.group_of(i)).to_vec())
            .collect::<Vec<_>>();
        assert_eq!(first_hinge[0], vec![0, 1]);
        assert_eq!(first_hinge[1], vec![1, 2]);
    }

    #[test]
    fn back_to_back_patches_are_separate_surfaces_below_180_degrees() {
        // The same square twice, facing +z and -z.
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let faces = vec![face(&[0, 1, 2, 3], 0, 0), face(&[3, 2, 1, 0], 0, 1)];
        let m = mesh(positions, faces, Subdivision::None);
        let values = [DVec3::ONE, DVec3::splat(5.0)];
        let out = m.corner_radiosity(&values, 179.0);
        assert!((0..4).all(|c| out[c] == values[0]));
        assert!((4..8).all(|c| out[c] == values[1]));
        let out = m.corner_radiosity(&values, 180.0);
        assert!(out.iter().all(|v| v == DVec3::splat(3.0)));
    }
}
