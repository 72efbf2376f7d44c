//! Clusters: groups of small neighbouring input faces that share one estimate of incident
//! irradiance `H` (W/m²).
//!
//! A face's radiosity is `B_f = E_f + rho_f H_f`. Where many small faces lie side by side,
//! facing the same way, their `H_f` differ by less than each one's noise, and one estimate
//! `H` for the group, `B_f = E_f + rho_f H`, is both less noisy and still per face in its
//! reflectance (and texture). [`Clusters::build`] chooses the groups from the geometry alone;
//! whoever pools the estimates checks that the light does not vary across a group beyond its
//! noise, and splits it where it does (`mcrad-solve` does so).
//!
//! A cluster holds patches that are each a whole input face (the face's only patch on its
//! side: faces an adaptive or uniform cut split are left alone), emit nothing (a cluster never
//! mixes emission), are on the same side (fronts with fronts, backs with backs), are linked
//! through shared vertices, lie within a ball of diameter [`ClusterBounds::max_size`] and have
//! normals within [`ClusterBounds::cone_degrees`] of the first member's (so faces facing
//! different ways, such as a box's top and side, are never one cluster: their `H` differ).

use crate::build::Mesh;
use glam::Vec3;

/// The widest angle (degrees) between a cluster member's normal and its first member's:
/// two members differ by at most twice this (40°). Within it, a directional light's
/// irradiance `cos(theta)` changes across a cluster by at most `1 - cos(40°)` of its largest
/// value at normal incidence; larger changes at grazing light are left to the pooling's test
/// of the light's variation across a cluster.
pub const DEFAULT_CLUSTER_CONE_DEGREES: f32 = 20.0;

/// The limits of a cluster (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClusterBounds {
    /// Every member's corners lie within `max_size / 2` of the first member's centroid (scene
    /// units, `>= 0`; 0 forms no cluster).
    pub max_size: f32,
    /// The widest angle between a member's unit normal and the first member's (degrees, in
    /// `[0, 90)`).
    pub cone_degrees: f32,
}

/// Groups of patches of a [`Mesh`] that share one estimate of incident irradiance (see the
/// module documentation). Each cluster has at least two patches; a patch is in at most one
/// cluster. Built deterministically from the mesh alone.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Clusters {
    /// Cluster `k`'s members are `members[offsets[k]..offsets[k + 1]]`.
    offsets: Vec<u32>,
    /// Patch indices (mesh order), cluster by cluster, each cluster's in the order it grew.
    members: Vec<u32>,
}

impl Clusters {
    /// The clusters of `mesh` within `bounds`: seeds taken in mesh order, each grown through
    /// shared vertices to every eligible patch not yet in a cluster that keeps the bounds
    /// (breadth first); a seed that gathers no other patch forms none. Linear in the mesh's
    /// corners.
    pub fn build(mesh: &Mesh, bounds: ClusterBounds) -> Clusters {
        let patches = mesh.patches();
        let n = patches.len();
        let mut clusters = Clusters {
            offsets: vec![0],
            members: Vec::new(),
        };
        if !(bounds.max_size.is_finite() && bounds.max_size > 0.0) || n < 2 {
            return clusters;
        }
        // Patches per face and side: only a face's single patch may join a cluster.
        let faces = mesh.face_count();
        let mut per_face = vec![0u8; faces * 2];
        for p in patches {
            let k = p.face as usize * 2 + usize::from(p.back);
            per_face[k] = per_face[k].saturating_add(1);
        }
        let eligible: Vec<bool> = patches
            .iter()
            .map(|p| {
                per_face[p.face as usize * 2 + usize::from(p.back)] == 1 && p.emission == Vec3::ZERO
            })
            .collect();
        // The eligible patches at each vertex (compressed rows).
        let positions = mesh.positions();
        let mut start = vec![0u32; positions.len() + 1];
        for (p, _) in patches.iter().zip(&eligible).filter(|(_, e)| **e) {
            for &v in mesh.corners(p) {
                start[v as usize + 1] += 1;
            }
        }
        for v in 0..positions.len() {
            start[v + 1] += start[v];
        }
        let mut fill = start.clone();
        let mut at_vertex = vec![0u32; start[positions.len()] as usize];
        for (i, p) in patches.iter().enumerate().filter(|(i, _)| eligible[*i]) {
            for &v in mesh.corners(p) {
                at_vertex[fill[v as usize] as usize] = i as u32;
                fill[v as usize] += 1;
            }
        }
        drop(fill);
        let cone = bounds.cone_degrees.clamp(0.0, 89.9).to_radians().cos();
        let radius2 = f64::from(bounds.max_size / 2.0).powi(2);
        let mut taken = vec![false; n];
        let mut queue = std::collections::VecDeque::new();
        for seed in 0..n {
            if !eligible[seed] || taken[seed] {
                continue;
            }
            let s = &patches[seed];
            let within = |j: usize| {
                let p = &patches[j];
                p.back == s.back
                    && p.normal.dot(s.normal) >= cone
                    && mesh.corners(p).iter().all(|&v| {
                        positions[v as usize]
                            .as_dvec3()
                            .distance_squared(s.centroid.as_dvec3())
                            <= radius2
                    })
            };
            if !within(seed) {
                continue;
            }
            let first = clusters.members.len();
            taken[seed] = true;
            clusters.members.push(seed as u32);
            queue.push_back(seed);
            while let Some(i) = queue.pop_front() {
                for &v in mesh.corners(&patches[i]) {
                    let row = start[v as usize] as usize..start[v as usize + 1] as usize;
                    for &j in &at_vertex[row] {
                        let j = j as usize;
                        if !taken[j] && within(j) {
                            taken[j] = true;
                            clusters.members.push(j as u32);
                            queue.push_back(j);
                        }
                    }
                }
            }
            if clusters.members.len() - first < 2 {
                // alone: free for a later seed's cluster
                taken[seed] = false;
                clusters.members.truncate(first);
            } else {
                clusters.offsets.push(clusters.members.len() as u32);
            }
        }
        clusters.members.shrink_to_fit();
        clusters.offsets.shrink_to_fit();
        clusters
    }

    /// Clusters of the given patch lists (patch indices, mesh order), in order; a list of
    /// fewer than two patches forms none. The caller keeps a patch in one list at most.
    pub fn from_lists<'l>(lists: impl IntoIterator<Item = &'l [u32]>) -> Clusters {
        let mut clusters = Clusters {
            offsets: vec![0],
            members: Vec::new(),
        };
        for list in lists.into_iter().filter(|l| l.len() >= 2) {
            clusters.members.extend_from_slice(list);
            clusters.offsets.push(clusters.members.len() as u32);
        }
        clusters
    }

    /// The groups of `group` (per patch its group number, or [`crate::UNGROUPED`]) as
    /// clusters, in the order of their numbers, each's members in patch order; only the
    /// patches `keep` accepts count, and a group left with fewer than two forms none. Linear in
    /// the patches and the largest group number.
    pub fn from_groups(group: &[u32], keep: impl Fn(usize) -> bool) -> Clusters {
        let kept = || (0..group.len()).filter(|&i| group[i] != crate::UNGROUPED && keep(i));
        let groups = kept().map(|i| group[i] as usize + 1).max().unwrap_or(0);
        // a counting sort by group number
        let mut start = vec![0u32; groups + 1];
        for i in kept() {
            start[group[i] as usize + 1] += 1;
        }
        for g in 0..groups {
            start[g + 1] += start[g];
        }
        let mut fill = start.clone();
        let mut members = vec![0u32; start[groups] as usize];
        for i in kept() {
            let g = group[i] as usize;
            members[fill[g] as usize] = i as u32;
            fill[g] += 1;
        }
        Clusters::from_lists(
            (0..groups).map(|g| &members[start[g] as usize..start[g + 1] as usize]),
        )
    }

    /// These clusters without the patches for which `drop` is true (a cluster left with fewer
    /// than two patches goes).
    pub fn without(&self, drop: impl Fn(u32) -> bool) -> Clusters {
        let lists: Vec<Vec<u32>> = self
            .iter()
            .map(|c| c.iter().copied().filter(|&i| !drop(i)).collect())
            .collect();
        Clusters::from_lists(lists.iter().map(Vec::as_slice))
    }

    /// Sorts `members` (patch indices of `mesh`) along their centroids' longest extent, ties
    /// by patch index: the order in which a cluster is cut in two at its median.
    pub fn sort_along_extent(mesh: &Mesh, members: &mut [u32]) {
        let patches = mesh.patches();
        let (lo, hi) = members.iter().fold(
            (glam::DVec3::splat(f64::MAX), glam::DVec3::splat(f64::MIN)),
            |(lo, hi), &i| {
                let c = patches[i as usize].centroid.as_dvec3();
                (lo.min(c), hi.max(c))
            },
        );
        let axis = (hi - lo).max_position();
        members.sort_by(|&x, &y| {
            let (cx, cy) = (
                patches[x as usize].centroid[axis],
                patches[y as usize].centroid[axis],
            );
            cx.total_cmp(&cy).then(x.cmp(&y))
        });
    }

    /// The longest side of the axis-aligned box round the corners of `members` (patch
    /// indices of `mesh`; scene units, 0 for none): a group's size, which its splits compare
    /// with an element's smallest.
    pub fn span(mesh: &Mesh, members: &[u32]) -> f64 {
        let (patches, positions) = (mesh.patches(), mesh.positions());
        let (lo, hi) = members
            .iter()
            .flat_map(|&i| mesh.corners(&patches[i as usize]))
            .fold(
                (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
                |(lo, hi), &v| {
                    let x = positions[v as usize];
                    (lo.min(x), hi.max(x))
                },
            );
        if members.is_empty() {
            0.0
        } else {
            f64::from((hi - lo).max_element())
        }
    }

    /// The number of clusters.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Whether there is no cluster.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The patches in clusters, summed over the clusters.
    pub fn patches(&self) -> usize {
        self.members.len()
    }

    /// The patch indices (mesh order) of cluster `k`, at least two.
    ///
    /// # Panics
    /// If `k >= len()`.
    pub fn get(&self, k: usize) -> &[u32] {
        &self.members[self.offsets[k] as usize..self.offsets[k + 1] as usize]
    }

    /// The clusters in order, each as its patch indices.
    pub fn iter(&self) -> impl Iterator<Item = &[u32]> {
        (0..self.len()).map(|k| self.get(k))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{AdaptiveBounds, AdaptiveMesh, DEFAULT_COARSE_EDGE_FRACTION, Subdivision};
    use mcrad_scene_io::{Face, Material, Scene};

    /// A 10 m emitting floor (one face) and the faces of `tiles`, each a polygon of material 0.
    fn scene(tiles: &[Vec<Vec3>]) -> Scene {
        let mut positions = vec![
            Vec3::new(-5.0, -1.0, -5.0),
            Vec3::new(-5.0, -1.0, 5.0),
            Vec3::new(5.0, -1.0, 5.0),
            Vec3::new(5.0, -1.0, -5.0),
        ];
        let mut faces = vec![Face {
            vertices: vec![0, 1, 2, 3],
            material: 1,
            source: 0,
        }];
        for t in tiles {
            // corners shared by value, as an OBJ's indexed vertices are
            let vertices = t
                .iter()
                .map(|c| match positions.iter().position(|p| p == c) {
                    Some(i) => i as u32,
                    None => {
                        positions.push(*c);
                        (positions.len() - 1) as u32
                    }
                })
                .collect();
            let source = faces.len() as u32;
            faces.push(Face {
                vertices,
                material: 0,
                source,
            });
        }
        let materials = vec![
            Material {
                name: "grey".into(),
                reflectance: Vec3::splat(0.5),
                emission: Vec3::ZERO,
            },
            Material {
                name: "glow".into(),
                reflectance: Vec3::ZERO,
                emission: Vec3::ONE,
            },
        ];
        Scene::new(positions, faces, materials).unwrap().0
    }

    /// The default adaptive start of `scene` and its clusters within the start's cut.
    fn clusters_of(scene: &Scene) -> (Mesh, Clusters) {
        let cut = scene.bounds().diagonal() as f32 * DEFAULT_COARSE_EDGE_FRACTION;
        let mesh = AdaptiveMesh::new(
            scene,
            Subdivision::MaxEdge(cut),
            AdaptiveBounds::default_for(scene),
        )
        .unwrap()
        .into_mesh();
        let clusters = Clusters::build(
            &mesh,
            ClusterBounds {
                max_size: cut,
                cone_degrees: DEFAULT_CLUSTER_CONE_DEGREES,
            },
        );
        (mesh, clusters)
    }

    /// An `n x n` grid of 1 cm quads on the plane through `o` spanned by `u`, `v` (front
    /// `u x v`).
    fn grid(o: Vec3, u: Vec3, v: Vec3, n: usize) -> Vec<Vec<Vec3>> {
        let h = 0.01;
        let p = |i: usize, j: usize| o + u * (i as f32 * h) + v * (j as f32 * h);
        (0..n)
            .flat_map(|j| (0..n).map(move |i| (i, j)))
            .map(|(i, j)| vec![p(i, j), p(i + 1, j), p(i + 1, j + 1), p(i, j + 1)])
            .collect()
    }

    #[test]
    fn coplanar_small_faces_cluster_within_the_size_and_large_faces_do_not() {
        let tiles = grid(Vec3::ZERO, Vec3::X, Vec3::Z * -1.0, 40);
        let scene = scene(&tiles);
        let (mesh, clusters) = clusters_of(&scene);
        // the floor is cut (several patches): never in a cluster
        assert!(
            clusters
                .iter()
                .flatten()
                .all(|&i| mesh.patches()[i as usize].face != 0)
        );
        // every tile in a cluster, clusters of several tiles, few of them
        assert_eq!(clusters.patches(), 1600);
        assert!(
            clusters.len() >= 4 && clusters.len() <= 100,
            "{} clusters",
            clusters.len()
        );
        let half = scene.bounds().diagonal() * f64::from(DEFAULT_COARSE_EDGE_FRACTION) / 2.0;
        for c in clusters.iter() {
            let seed = mesh.patches()[c[0] as usize].centroid;
            for &i in c {
                let d = mesh.patches()[i as usize].centroid.distance(seed);
                assert!(f64::from(d) <= half, "member {i} {d} from its seed");
            }
        }
        // the same clusters again (deterministic)
        assert_eq!(clusters_of(&scene).1, clusters);
    }

    #[test]
    fn a_small_box_top_and_sides_are_never_one_cluster() {
        // a 10 cm box of 1 cm tiles standing on the floor: its top and its four sides share
        // edges, and face different ways
        let (o, s) = (Vec3::new(0.0, -1.0, 0.0), 0.1);
        let mut tiles = grid(o + Vec3::new(0.0, s, s), Vec3::X, -Vec3::Z, 10); // top (+y)
        tiles.extend(grid(o + Vec3::new(0.0, 0.0, s), Vec3::X, Vec3::Y, 10)); // +z
        tiles.extend(grid(o, Vec3::Y, Vec3::X, 10)); // -z
        tiles.extend(grid(o + Vec3::new(s, 0.0, 0.0), Vec3::Y, Vec3::Z, 10)); // +x
        tiles.extend(grid(o, Vec3::Z, Vec3::Y, 10)); // -x
        let (mesh, clusters) = clusters_of(&scene(&tiles));
        assert!(clusters.len() >= 5, "{} clusters", clusters.len());
        assert_eq!(clusters.patches(), 500);
        for c in clusters.iter() {
            let n = mesh.patches()[c[0] as usize].normal;
            for &i in c {
                let m = mesh.patches()[i as usize].normal;
                assert!(m.dot(n) > 0.99, "normals {n} and {m} in one cluster");
            }
        }
    }

    #[test]
    fn no_cluster_without_size() {
        let scene = scene(&grid(Vec3::ZERO, Vec3::X, -Vec3::Z, 4));
        let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
        let bounds = ClusterBounds {
            max_size: 0.0,
            cone_degrees: 20.0,
        };
        assert!(Clusters::build(&mesh, bounds).is_empty());
    }
}
