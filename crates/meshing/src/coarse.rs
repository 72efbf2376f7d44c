//! Clusters as elements of transport: a coarser mesh in which each group of a finer mesh's
//! patches is one patch.
//!
//! A cluster element `c` of member faces `f` carries one incident irradiance `H_c` (W/m² per
//! channel) for all of them. Its area is `A_c = sum A_f`, its reflectance the area-weighted mean
//! `rho_c = sum rho_f A_f / A_c` (so its reflected power `rho_c H_c A_c` is exactly its
//! members' `sum rho_f H_c A_f`), its emission zero (members emit nothing). Rays leave and
//! arrive on its members' own triangles, each with its own normal
//! ([`Mesh::triangle_normal`]). Back on the finer mesh ([`Carry::refine`]), member `f`
//! gets `B_f = E_f + rho_f H_c` with `H_c = (B_c - E_c) / rho_c`, its variance scaled by
//! `(rho_f / rho_c)²`; a patch outside every cluster gets its element's values as they are.

use glam::{DVec3, Vec3};

use crate::build::{Mesh, MeshError, Patch};

/// A patch of the finer mesh in no group (see [`Mesh::clustered`]).
pub const UNGROUPED: u32 = u32::MAX;

/// The most members a cluster element holds; a larger group is cut into consecutive runs of
/// its members (in mesh order) of at most this many.
pub const MAX_CLUSTER_MEMBERS: usize = u16::MAX as usize;

/// A mesh for transport whose elements are the patches of a finer mesh, some grouped into one
/// element each (see the module documentation).
#[derive(Debug, Clone)]
pub struct ClusteredMesh {
    /// The coarser mesh: its patches are the elements, in the finer mesh's order (an element
    /// where its first member was).
    pub mesh: Mesh,
    /// For each patch of the finer mesh, the index of its element in `mesh`.
    pub element: Vec<u32>,
}

impl Mesh {
    /// This mesh with each group of patches made one element (see the module documentation):
    /// `group[i]` is patch `i`'s group number, or [`UNGROUPED`]; a group of one patch stays
    /// that patch. A member that may not join a cluster stays a patch of its own: a side of a
    /// two-sided face, an emitter, an alpha-tested face or a cluster already (a cluster's
    /// members are one-sided, opaque, emit nothing and are whole polygons).
    pub fn clustered(&self, group: &[u32]) -> Result<ClusteredMesh, MeshError> {
        let patches = self.patches();
        if group.len() != patches.len() {
            return Err(MeshError::GroupCount {
                patches: patches.len(),
                got: group.len(),
            });
        }
        // members that may not join a cluster stay patches of their own
        let alpha = crate::AlphaTest::tested_faces(self);
        let joins = |i: usize| {
            let p = &patches[i];
            group[i] != UNGROUPED
                && !p.is_cluster()
                && self.twin(i).is_none()
                && p.emission == Vec3::ZERO
                && !alpha.as_ref().is_some_and(|a| a[p.face as usize])
        };
        // each group's runs of at most MAX_CLUSTER_MEMBERS (members in mesh order)
        let groups = crate::Clusters::from_groups(group, joins);
        let runs: Vec<&[u32]> = groups
            .iter()
            .flat_map(|c| c.chunks(MAX_CLUSTER_MEMBERS))
            .filter(|r| r.len() >= 2)
            .collect();
        let mut run_of = vec![u32::MAX; patches.len()];
        for (k, r) in runs.iter().enumerate() {
            for &i in *r {
                run_of[i as usize] = k as u32;
            }
        }
        let (mut corners, mut triangles, mut triangle_patch) = (Vec::new(), Vec::new(), Vec::new());
        let mut elements: Vec<Patch> = Vec::new();
        let mut element = vec![0u32; patches.len()];
        for (i, p) in patches.iter().enumerate() {
            let run = run_of[i];
            if run != u32::MAX && runs[run as usize][0] != i as u32 {
                continue; // a later member of a run: made with its first
            }
            let id = elements.len() as u32;
            let first_corner = corners.len() as u32;
            let first_triangle = triangles.len() as u32;
            let alone = [i as u32];
            let part: &[u32] = if run == u32::MAX {
                &alone
            } else {
                runs[run as usize]
            };
            for &m in part {
                let q = &patches[m as usize];
                corners.extend_from_slice(self.corners(q));
                triangles.extend_from_slice(self.patch_triangles(q));
                element[m as usize] = id;
            }
            triangle_patch.extend(std::iter::repeat_n(
                id,
                triangles.len() - first_triangle as usize,
            ));
            let corner_count = corners.len() as u32 - first_corner;
            elements.push(if part.len() == 1 {
                Patch {
                    first_corner,
                    corner_count,
                    first_triangle,
                    ..p.clone()
                }
            } else {
                merged(patches, part, first_corner, corner_count, first_triangle)
            });
        }
        let mut coarse = self.with_patches(corners, triangles, triangle_patch, elements);
        coarse.shrink_to_fit();
        Ok(ClusteredMesh {
            mesh: coarse,
            element,
        })
    }

    /// The unit normal at the points of triangle `t` (an index into [`Mesh::triangles`]) of
    /// `patch`: the patch's normal, or for a cluster ([`Patch::is_cluster`]) the triangle's own
    /// (counter-clockwise from the front).
    #[inline]
    pub fn triangle_normal(&self, patch: &Patch, t: usize) -> Vec3 {
        if !patch.is_cluster() {
            return patch.normal;
        }
        let [a, b, c] = self.triangles()[t].map(|v| self.positions()[v as usize].as_dvec3());
        let n = (b - a).cross(c - a).normalize_or_zero();
        if n == DVec3::ZERO {
            patch.normal
        } else {
            n.as_vec3()
        }
    }
}

/// The element of `members` (patch indices of `patches`, at least two) whose corners and
/// triangles the caller put at `first_corner` and `first_triangle`.
fn merged(
    patches: &[Patch],
    members: &[u32],
    first_corner: u32,
    corner_count: u32,
    first_triangle: u32,
) -> Patch {
    let (mut area, mut normal, mut centroid) = (0.0, DVec3::ZERO, DVec3::ZERO);
    let (mut reflected, mut emitted) = (DVec3::ZERO, DVec3::ZERO);
    for &m in members {
        let q = &patches[m as usize];
        area += q.area;
        normal += q.normal.as_dvec3() * q.area;
        centroid += q.centroid.as_dvec3() * q.area;
        reflected += q.reflectance.as_dvec3() * q.area;
        emitted += q.emission.as_dvec3() * q.area;
    }
    let first = &patches[members[0] as usize];
    let normal = normal.normalize_or_zero();
    Patch {
        area,
        normal: if normal == DVec3::ZERO {
            first.normal
        } else {
            normal.as_vec3()
        },
        centroid: (centroid / area).as_vec3(),
        reflectance: (reflected / area).as_vec3(),
        emission: (emitted / area).as_vec3(),
        face: first.face,
        material: first.material,
        back: false,
        polygons: members.len() as u16,
        first_corner,
        corner_count,
        first_triangle,
    }
}

impl ClusteredMesh {
    /// What carries per-element values back to the finer mesh.
    pub fn carry(&self) -> Carry<'_> {
        Carry {
            elements: self.mesh.patches(),
            element: &self.element,
        }
    }

    /// The cluster elements' members (patches of the finer mesh, in its order), cluster by
    /// cluster in element order.
    pub fn clusters(&self) -> crate::Clusters {
        let elements = self.mesh.patches();
        crate::Clusters::from_groups(&self.element, |i| {
            elements[self.element[i] as usize].is_cluster()
        })
    }

    /// What carries values back to the finer mesh, without the elements' geometry (their
    /// corners and triangles are as many as the finer mesh's).
    pub fn into_carrier(self) -> Carrier {
        Carrier {
            elements: self.mesh.into_patches(),
            element: self.element,
        }
    }
}

/// The elements of a [`ClusteredMesh`] without their geometry, and each finer patch's element:
/// what carries per-element values back to the finer mesh ([`Carrier::carry`]).
#[derive(Debug, Clone, Default)]
pub struct Carrier {
    /// The coarser mesh's patches, in its order.
    pub elements: Vec<Patch>,
    /// For each patch of the finer mesh, the index of its element in `elements`.
    pub element: Vec<u32>,
}

impl Carrier {
    /// What carries per-element values back to the finer mesh.
    pub fn carry(&self) -> Carry<'_> {
        Carry {
            elements: &self.elements,
            element: &self.element,
        }
    }
}

/// Per-element values of a [`ClusteredMesh`] carried back to the patches of its finer mesh:
/// the elements (the coarser mesh's patches) and each finer patch's element.
#[derive(Debug, Clone, Copy)]
pub struct Carry<'a> {
    /// The coarser mesh's patches, in its order.
    pub elements: &'a [Patch],
    /// For each patch of the finer mesh, the index of its element in `elements`.
    pub element: &'a [u32],
}

impl Carry<'_> {
    /// Per-element values `coarse` (W/m² per channel: radiosity `B`, or a part of it that
    /// reflects, such as its direct light) carried back to the finer mesh `fine` (the mesh the
    /// elements were made from): an element's reflected part `B_c - E_c` becomes each member's
    /// incident irradiance `H_c = (B_c - E_c) / rho_c`, and the member gets `E_f + rho_f H_c`
    /// (`E_f` only where `with_emission`), per channel, or `E_f` where `rho_c = 0`. A patch
    /// outside every cluster gets its element's value as it is.
    pub fn refine(&self, fine: &Mesh, coarse: &[DVec3], with_emission: bool) -> Vec<DVec3> {
        self.map(fine, coarse, |f, c, v| {
            let (rho_f, rho_c) = (f.reflectance.as_dvec3(), c.reflectance.as_dvec3());
            let (e_f, e_c) = if with_emission {
                (f.emission.as_dvec3(), c.emission.as_dvec3())
            } else {
                (DVec3::ZERO, DVec3::ZERO)
            };
            DVec3::select(
                rho_c.cmpgt(DVec3::ZERO),
                e_f + rho_f * (v - e_c) / rho_c,
                e_f,
            )
        })
    }

    /// Per-element variances (of values [`Carry::refine`] carries back) carried back to the
    /// finer mesh `fine`: each member's is its element's times `(rho_f / rho_c)²` per channel
    /// (0 where `rho_c = 0`); a patch outside every cluster keeps its element's.
    pub fn refine_variance(&self, fine: &Mesh, coarse: &[DVec3]) -> Vec<DVec3> {
        self.map(fine, coarse, |f, c, v| {
            let (rho_f, rho_c) = (f.reflectance.as_dvec3(), c.reflectance.as_dvec3());
            let k = DVec3::select(rho_c.cmpgt(DVec3::ZERO), rho_f / rho_c, DVec3::ZERO);
            v * k * k
        })
    }

    /// Per-element irradiances `coarse` (W/m² per channel, shared by an element's members, such
    /// as its direct light `H_d`) per patch of the finer mesh: each patch gets its element's.
    pub fn shared(&self, coarse: &[DVec3]) -> Vec<DVec3> {
        self.element.iter().map(|&e| coarse[e as usize]).collect()
    }

    /// `coarse` per patch of `fine` through `member(fine patch, its element, element's value)`
    /// for members of clusters, as it is for the rest.
    fn map(
        &self,
        fine: &Mesh,
        coarse: &[DVec3],
        member: impl Fn(&Patch, &Patch, DVec3) -> DVec3,
    ) -> Vec<DVec3> {
        fine.patches()
            .iter()
            .zip(self.element)
            .map(|(f, &e)| {
                let (c, v) = (&self.elements[e as usize], coarse[e as usize]);
                if c.is_cluster() { member(f, c, v) } else { v }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ClusterBounds, Clusters, Subdivision};
    use mcrad_scene_io::{Face, Material, Scene};

    /// An emitting square above a bent strip of 1 cm tiles (the second half tilted 15° about
    /// the x axis), tiles alternating reflectance 0.3 and 0.6 (materials 0 and 1).
    fn strip() -> (Mesh, Clusters) {
        let mut positions = vec![
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(0.0, 1.0, 1.0),
        ];
        let mut faces = vec![Face {
            vertices: vec![0, 1, 2, 3],
            material: 2,
            source: 0,
        }];
        let (n, h) = (20usize, 0.01f32);
        let tilt = 15f32.to_radians();
        let at = |i: usize, j: usize| {
            let (x, z) = (i as f32 * h, j as f32 * h);
            let half = (n / 2) as f32 * h;
            if z <= half {
                Vec3::new(x, 0.0, z)
            } else {
                let d = z - half;
                Vec3::new(x, d * tilt.sin(), half + d * tilt.cos())
            }
        };
        for j in 0..=n {
            for i in 0..=n {
                positions.push(at(i, j));
            }
        }
        let v = |i: usize, j: usize| (4 + j * (n + 1) + i) as u32;
        for j in 0..n {
            for i in 0..n {
                let source = faces.len() as u32;
                faces.push(Face {
                    // front +y: counter-clockwise seen from above
                    vertices: vec![v(i, j), v(i, j + 1), v(i + 1, j + 1), v(i + 1, j)],
                    material: ((i + j) % 2) as u32,
                    source,
                });
            }
        }
        let grey = |name: &str, r: f32| Material {
            name: name.into(),
            reflectance: Vec3::splat(r),
            emission: Vec3::ZERO,
        };
        let materials = vec![
            grey("dark", 0.3),
            grey("light", 0.6),
            Material {
                name: "glow".into(),
                reflectance: Vec3::ZERO,
                emission: Vec3::ONE,
            },
        ];
        let scene = Scene::new(positions, faces, materials).unwrap().0;
        let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
        let clusters = Clusters::build(
            &mesh,
            ClusterBounds {
                max_size: 0.1,
                cone_degrees: 10.0,
            },
        );
        (mesh, clusters)
    }

    fn groups(mesh: &Mesh, clusters: &Clusters) -> Vec<u32> {
        let mut group = vec![UNGROUPED; mesh.patches().len()];
        for (k, c) in clusters.iter().enumerate() {
            for &i in c {
                group[i as usize] = k as u32;
            }
        }
        group
    }

    #[test]
    fn a_cluster_element_keeps_its_members_area_power_and_triangles() {
        let (mesh, clusters) = strip();
        assert!(clusters.len() >= 8, "{} clusters", clusters.len());
        let c = mesh.clustered(&groups(&mesh, &clusters)).unwrap();
        c.mesh.validate().unwrap();
        let (fine, coarse) = (mesh.patches(), c.mesh.patches());
        assert_eq!(
            coarse.len(),
            fine.len() - clusters.patches() + clusters.len()
        );
        // every element: its members' area and reflected power; triangles are its members'
        for (e, p) in coarse.iter().enumerate() {
            let members: Vec<usize> = (0..fine.len())
                .filter(|&i| c.element[i] as usize == e)
                .collect();
            assert_eq!(p.is_cluster(), members.len() > 1);
            let area: f64 = members.iter().map(|&i| fine[i].area).sum();
            assert!((p.area - area).abs() <= 1e-12 * area);
            let power: f64 = members
                .iter()
                .map(|&i| f64::from(fine[i].reflectance.x) * fine[i].area)
                .sum();
            assert!((f64::from(p.reflectance.x) * p.area - power).abs() <= 1e-6 * power);
            let mut own: Vec<[u32; 3]> = c.mesh.patch_triangles(p).to_vec();
            let mut theirs: Vec<[u32; 3]> = members
                .iter()
                .flat_map(|&i| mesh.patch_triangles(&fine[i]).to_vec())
                .collect();
            own.sort_unstable();
            theirs.sort_unstable();
            assert_eq!(own, theirs);
            // each triangle's normal is its member's (tilted or not)
            let first = c.mesh.first_triangle(p);
            for (k, t) in c.mesh.patch_triangles(p).iter().enumerate() {
                let m = members
                    .iter()
                    .find(|&&i| mesh.patch_triangles(&fine[i]).contains(t))
                    .unwrap();
                let n = c.mesh.triangle_normal(p, first + k);
                assert!(
                    n.dot(fine[*m].normal) > 1.0 - 1e-6,
                    "{n} {}",
                    fine[*m].normal
                );
            }
        }
        // the emitter and every unclustered patch are copies
        assert_eq!(coarse[0], fine[0]);
    }

    #[test]
    fn values_come_back_per_member_by_its_own_reflectance() {
        let (mesh, clusters) = strip();
        let c = mesh.clustered(&groups(&mesh, &clusters)).unwrap();
        // an element of incident irradiance H = 2 + e (W/m²): B = E + rho H
        let b: Vec<DVec3> = c
            .mesh
            .patches()
            .iter()
            .enumerate()
            .map(|(e, p)| p.emission.as_dvec3() + p.reflectance.as_dvec3() * (2.0 + e as f64))
            .collect();
        let var: Vec<DVec3> = (0..b.len()).map(|e| DVec3::splat(e as f64)).collect();
        let (back, back_var) = (
            c.carry().refine(&mesh, &b, true),
            c.carry().refine_variance(&mesh, &var),
        );
        for (i, p) in mesh.patches().iter().enumerate() {
            let e = c.element[i] as usize;
            let want = p.emission.as_dvec3() + p.reflectance.as_dvec3() * (2.0 + e as f64);
            assert!((back[i] - want).abs().max_element() < 1e-5, "{i}");
            let q = &c.mesh.patches()[e];
            if q.is_cluster() {
                let k = f64::from(p.reflectance.x) / f64::from(q.reflectance.x);
                let want = var[e].x * k * k;
                assert!((back_var[i].x - want).abs() <= 1e-12 * want, "{i}");
            } else {
                // unclustered: the very values
                assert_eq!((back[i], back_var[i]), (b[e], var[e]));
            }
        }
    }

    #[test]
    fn an_emitter_stays_alone_and_a_wrong_length_is_refused() {
        let (mesh, clusters) = strip();
        let mut group = groups(&mesh, &clusters);
        assert!(matches!(
            mesh.clustered(&group[1..]),
            Err(MeshError::GroupCount { .. })
        ));
        group[0] = group[1];
        let c = mesh.clustered(&group).unwrap();
        assert_eq!(c.mesh.patches()[0], mesh.patches()[0]);
        assert_eq!(c.element[0], 0);
        assert_eq!(
            c.mesh.patches().len(),
            mesh.clustered(&groups(&mesh, &clusters))
                .unwrap()
                .mesh
                .patches()
                .len()
        );
    }

    #[test]
    fn a_patch_stays_80_bytes() {
        assert_eq!(size_of::<Patch>(), 80);
    }
}
