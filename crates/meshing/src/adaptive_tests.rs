//! Tests of adaptive refinement and of vertex radiosity at its T-vertices.

use crate::{
    AdaptiveBounds, AdaptiveMesh, CornerValues, DEFAULT_CREASE_ANGLE_DEGREES, Mesh, Subdivision,
};
use glam::{DVec3, Vec3};
use mcrad_scene_io::{Face, Material, Scene};
use std::collections::BTreeMap;

/// A scene of `faces` (vertex lists, one emitting grey material) over `positions`.
pub(crate) fn scene(positions: Vec<Vec3>, faces: Vec<Vec<u32>>) -> Scene {
    let materials = vec![Material {
        name: "lamp".into(),
        reflectance: Vec3::splat(0.5),
        emission: Vec3::ONE,
    }];
    let faces = faces
        .into_iter()
        .enumerate()
        .map(|(i, vertices)| Face {
            vertices,
            material: 0,
            source: i as u32,
        })
        .collect();
    Scene::new(positions, faces, materials)
        .expect("valid scene")
        .0
}

/// A 4 × 2 quad, a triangle next to it and a 2 × 0.1 strip, offset by `origin`.
fn shapes(origin: Vec3) -> Scene {
    let p = [
        (0.0, 0.0),
        (4.0, 0.0),
        (4.0, 2.0),
        (0.0, 2.0),
        (5.0, 1.0),
        (0.0, 3.0),
        (2.0, 3.0),
        (2.0, 3.1),
        (0.0, 3.1),
    ]
    .map(|(x, y)| origin + Vec3::new(x, y, 0.0))
    .to_vec();
    scene(p, vec![vec![0, 1, 2, 3], vec![1, 4, 2], vec![5, 6, 7, 8]])
}

fn face_areas(mesh: &Mesh) -> BTreeMap<u32, f64> {
    let mut areas = BTreeMap::new();
    for p in mesh.patches() {
        *areas.entry(p.face).or_insert(0.0) += p.area;
    }
    areas
}

fn bounds(min_edge: f32, max_patches: usize) -> AdaptiveBounds {
    AdaptiveBounds {
        min_edge,
        max_patches,
    }
}

#[test]
fn refining_everything_conserves_area_keeps_shapes_and_stops_at_the_minimum_edge() {
    let s = shapes(Vec3::ZERO);
    let mut m = AdaptiveMesh::new(&s, Subdivision::None, bounds(0.1, 1_000_000)).unwrap();
    let areas = face_areas(m.mesh());
    let mut rounds = 0;
    loop {
        let all: Vec<u32> = (0..m.len() as u32).collect();
        let r = m.refine(&all);
        m.mesh().validate().unwrap();
        assert_eq!(r.parent.len(), m.len());
        assert!(r.parent.windows(2).all(|w| w[0] <= w[1]));
        assert_eq!(r.unrefinable, 0);
        for (face, area) in face_areas(m.mesh()) {
            assert!(
                (area - areas[&face]).abs() <= 1e-6 * areas[&face],
                "face {face}"
            );
        }
        rounds += 1;
        if r.split == 0 {
            break;
        }
        assert!(rounds < 20, "refinement does not terminate");
    }
    // No element edge below the minimum, none above twice it, and the thin strip was cut
    // across its length only (its 0.1 side is never halved).
    for p in m.mesh().patches() {
        let c = m.mesh().corners(p);
        for k in 0..c.len() {
            let (a, b) = (
                m.mesh().positions()[c[k] as usize],
                m.mesh().positions()[c[(k + 1) % c.len()] as usize],
            );
            let e = a.distance(b);
            assert!(
                e >= 0.1 - 1e-6 || p.face == 1,
                "edge {e} of face {}",
                p.face
            );
        }
        if p.face == 2 {
            assert!(
                (p.area - 0.0125).abs() < 1e-7,
                "strip element of area {}",
                p.area
            );
        }
    }
    // The 4 × 2 quad ends in elements of 0.125 × 0.125 (children similar to the parent).
    let quads = m.mesh().patches().iter().filter(|p| p.face == 0).count();
    assert_eq!(quads, 32 * 16);
}

#[test]
fn the_patch_budget_is_respected_in_the_order_given() {
    let s = shapes(Vec3::ZERO);
    let mut m = AdaptiveMesh::new(&s, Subdivision::None, bounds(0.01, 10)).unwrap();
    assert_eq!(m.len(), 3);
    // Splitting the triangle (+3) then the quad (+3) fits 9 <= 10; the strip (+1) would make 10.
    let r = m.refine(&[1, 0, 2, 1]);
    assert_eq!((r.split, r.held, m.len()), (3, 0, 10));
    let r = m.refine(&[0]);
    assert_eq!((r.split, r.held, m.len()), (0, 1, 10));
    assert!(m.len() <= m.bounds().max_patches);
}

#[test]
fn refine_within_adds_at_most_the_leaves_asked() {
    let s = shapes(Vec3::ZERO);
    let mut m = AdaptiveMesh::new(&s, Subdivision::None, bounds(0.01, 100)).unwrap();
    // At most 4 new leaves: the triangle (+3) fits, the quad (+3) is held, the strip (+1) fits.
    let r = m.refine_within(&[1, 0, 2], 4);
    assert_eq!((r.split, r.held, m.len()), (2, 1, 7));
}

#[test]
fn a_replayed_history_gives_the_same_mesh_and_another_scene_is_refused() {
    let s = shapes(Vec3::ZERO);
    let b = bounds(0.01, 100);
    let mut m = AdaptiveMesh::new(&s, Subdivision::MaxEdge(1.5), b).unwrap();
    m.refine_within(&[3, 0, 5, 1], 6);
    m.refine(&[7, 2, 2]);
    m.refine(&[]);
    assert_eq!(m.history().start, Some(1.5));
    assert_eq!(m.history().splits.len(), 3);
    assert!(
        m.history()
            .splits
            .iter()
            .all(|s| s.windows(2).all(|w| w[0] < w[1]))
    );
    let again = AdaptiveMesh::replay(&s, m.history(), b).unwrap();
    assert_eq!(again.len(), m.len());
    assert_eq!(again.mesh().positions(), m.mesh().positions());
    assert_eq!(again.mesh().triangles(), m.mesh().triangles());
    assert_eq!(again.history(), m.history());
    // within a smaller patch budget (one the refinement raised as it went): the recorded
    // splits decide, and the mesh keeps its count as its budget
    let small = AdaptiveMesh::replay(&s, m.history(), bounds(0.01, 5)).unwrap();
    assert!(m.len() > 5);
    assert_eq!(small.mesh().triangles(), m.mesh().triangles());
    assert_eq!(small.bounds().max_patches, m.len());
    // the same history within a larger minimum edge: splits that cannot be made
    let tight = AdaptiveMesh::replay(&s, m.history(), bounds(0.9, 100));
    assert!(
        matches!(tight, Err(crate::MeshError::BadHistory { .. })),
        "{tight:?}"
    );
}

#[test]
fn slivers_tiny_faces_and_faces_far_from_the_origin_terminate() {
    // A needle and a 1e-6-area triangle, where f32 cannot halve the elements for long, and the
    // shapes far from the origin, which the mesh's local frame (issue 16) lets be halved as at
    // the origin until the patch budget stops them.
    let needle = scene(
        vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(10.0, 0.0, 0.0),
            Vec3::new(5.0, 1e-4, 0.0),
            Vec3::new(20.0, 0.0, 0.0),
            Vec3::new(20.001, 0.0, 0.0),
            Vec3::new(20.0, 0.002, 0.0),
        ],
        vec![vec![0, 1, 2], vec![3, 4, 5]],
    );
    let far = shapes(Vec3::new(3.0e6, -2.0e6, 1.0e6));
    for (s, at_f32_limits) in [(&needle, true), (&far, false)] {
        let mut m = AdaptiveMesh::new(s, Subdivision::None, bounds(1e-9, 100_000)).unwrap();
        let areas = face_areas(m.mesh());
        let mut unrefinable = 0;
        for _ in 0..60 {
            let all: Vec<u32> = (0..m.len() as u32).collect();
            let r = m.refine(&all);
            unrefinable += r.unrefinable;
            m.mesh().validate().unwrap();
            if r.split == 0 {
                break;
            }
        }
        if at_f32_limits {
            assert!(unrefinable > 0, "some element reached the limits of f32");
        } else {
            assert!(m.len() > 50_000, "refined to {} leaves", m.len());
        }
        for (face, area) in face_areas(m.mesh()) {
            assert!(
                (area - areas[&face]).abs() <= 1e-5 * areas[&face],
                "face {face}"
            );
        }
    }
    assert!(AdaptiveMesh::new(&needle, Subdivision::None, bounds(0.0, 5)).is_err());
    assert!(AdaptiveMesh::new(&needle, Subdivision::None, bounds(0.1, 0)).is_err());
}

/// Linear interpolation of per-corner values along an edge of `patch` at fraction `t` from
/// corner `k` to corner `k + 1` (what renders do along an element's edge).
fn along(mesh: &Mesh, values: &CornerValues, patch: usize, k: usize, t: f64) -> (DVec3, DVec3) {
    let p = &mesh.patches()[patch];
    let c = mesh.corners(p);
    let o = mesh.corner_offset(patch);
    let k1 = (k + 1) % c.len();
    let a = mesh.positions()[c[k] as usize].as_dvec3();
    let b = mesh.positions()[c[k1] as usize].as_dvec3();
    (a.lerp(b, t), values[o + k] * (1.0 - t) + values[o + k1] * t)
}

#[test]
fn vertex_radiosity_is_continuous_across_t_vertices() {
    // Two unit squares side by side (one face each); the right one is refined twice in its
    // left column, so the shared edge x = 1 has T-vertices at y = 1/4, 1/2, 3/4 on one side.
    let s = scene(
        vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
        ],
        vec![vec![0, 1, 2, 3], vec![1, 4, 5, 2]],
    );
    let mut m = AdaptiveMesh::new(&s, Subdivision::None, bounds(0.01, 1000)).unwrap();
    m.refine(&[1]);
    // Children of the right square: 0 is the left one, then [1 bottom-left, 2 bottom-right,
    // 3 top-right, 4 top-left]; refine the two on the left edge again.
    m.refine(&[1, 4]);
    let mesh = m.mesh();
    assert_eq!(mesh.patches().len(), 1 + 2 * 4 + 2);
    let values: Vec<DVec3> = (0..mesh.patches().len())
        .map(|p| DVec3::new(1.0 + p as f64, (p * p % 7) as f64, 10.0 / (1.0 + p as f64)))
        .collect();
    let corners = mesh.seamless_corner_radiosity(&values, DEFAULT_CREASE_ANGLE_DEGREES);
    // The left square's edge x = 1 is its corners 1 -> 2; the finer elements' edges on x = 1.
    let mut checked = 0;
    for q in 1..mesh.patches().len() {
        let c = mesh.corners(&mesh.patches()[q]);
        for k in 0..c.len() {
            let a = mesh.positions()[c[k] as usize];
            let b = mesh.positions()[c[(k + 1) % c.len()] as usize];
            if a.x != 1.0 || b.x != 1.0 {
                continue;
            }
            for t in [0.0, 0.3, 0.5, 0.9, 1.0] {
                let (point, fine) = along(mesh, &corners, q, k, t);
                let s = point.y;
                let (_, coarse) = along(mesh, &corners, 0, 1, s);
                assert!(
                    (fine - coarse).abs().max_element() < 1e-12,
                    "at {point}: fine {fine}, coarse {coarse}"
                );
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 4 * 5);
    // Without the tie the finer side would show its own area-weighted values: the check can
    // fail (the middle T-vertex's area-weighted value differs from the coarse interpolation).
    let mid = mesh
        .patches()
        .iter()
        .enumerate()
        .skip(1)
        .find_map(|(q, p)| {
            let c = mesh.corners(p);
            (0..c.len()).find_map(|k| {
                let v = mesh.positions()[c[k] as usize];
                (v == Vec3::new(1.0, 0.5, 0.0)).then(|| mesh.corner_offset(q) + k)
            })
        })
        .unwrap();
    let (_, coarse) = along(mesh, &corners, 0, 1, 0.5);
    assert_eq!(corners[mid], coarse);
}

/// Every back side right after its front: the same corners reversed (from the same first one),
/// area, face and material, the opposite normal; no back side otherwise.
fn assert_paired(mesh: &Mesh) {
    let patches = mesh.patches();
    assert!(!patches[0].back);
    for (i, p) in patches.iter().enumerate() {
        let Some(j) = mesh.twin(i) else {
            continue;
        };
        assert_eq!(mesh.twin(j), Some(i));
        if !p.back {
            continue;
        }
        let f = &patches[j];
        assert_eq!(j, i - 1);
        assert!(!f.back);
        let (fc, bc) = (mesh.corners(f), mesh.corners(p));
        let reversed: Vec<u32> = std::iter::once(fc[0])
            .chain(fc[1..].iter().rev().copied())
            .collect();
        assert_eq!(bc, &reversed[..], "patch {i}");
        assert_eq!((p.area, p.face, p.material), (f.area, f.face, f.material));
        assert_eq!(p.normal, -f.normal);
    }
}

#[test]
fn two_sided_faces_have_back_sides_that_split_with_their_fronts_and_are_traced() {
    let s = shapes(Vec3::ZERO).with_two_sided(vec![true]);
    let uniform = Mesh::build(&s, Subdivision::MaxEdge(1.5)).unwrap();
    let one = Mesh::build(&shapes(Vec3::ZERO), Subdivision::MaxEdge(1.5)).unwrap();
    assert_eq!(uniform.patches().len(), 2 * one.patches().len());
    assert!(uniform.is_two_sided() && !one.is_two_sided());
    assert_eq!(uniform.back_face_offset(), 3);
    assert_paired(&uniform);
    // corner groups never join a front with its back
    let groups = uniform.corner_groups(DEFAULT_CREASE_ANGLE_DEGREES);
    for g in 0..groups.len() {
        let sides: Vec<bool> = groups
            .patches(g)
            .iter()
            .map(|&p| uniform.patches()[p as usize].back)
            .collect();
        assert!(sides.iter().all(|&b| b == sides[0]), "group {g}");
    }
    // asking for a back side splits the pair; children alternate front, back
    let b = bounds(0.01, 1000);
    let mut m = AdaptiveMesh::new(&s, Subdivision::MaxEdge(1.5), b).unwrap();
    let before = m.len();
    let r = m.refine(&[1, 2, 5]);
    assert_eq!(r.split, 6);
    assert_eq!(m.len(), m.mesh().patches().len());
    assert!(m.len() > before);
    assert_paired(m.mesh());
    for (j, &p) in r.parent.iter().enumerate() {
        assert_eq!(m.mesh().patches()[j].back, p % 2 == 1, "leaf {j}");
    }
    m.refine(&[7, 0]);
    assert_paired(m.mesh());
    let again = AdaptiveMesh::replay(&s, m.history(), b).unwrap();
    assert_eq!(again.mesh().triangles(), m.mesh().triangles());
    assert_eq!(again.history(), m.history());
    // the caster: one triangle set, the back side's id from below
    let mesh = m.mesh();
    let bvh = mesh.caster().unwrap();
    let triangles = mesh
        .patches()
        .iter()
        .filter(|p| !p.back)
        .map(|p| mesh.patch_triangles(p).len())
        .sum::<usize>();
    assert_eq!(bvh.triangle_count(), triangles);
    use mcrad_raycast::{Ray, RayCaster};
    for (i, p) in mesh.patches().iter().enumerate() {
        let dir = if p.back { Vec3::Z } else { -Vec3::Z };
        let hit = bvh.closest_hit(&Ray::new(p.centroid - dir, dir)).unwrap();
        assert_eq!((hit.id, hit.front), (i as u32, true), "patch {i}");
    }
}

/// The hierarchy keeps one template a material, not one a face: on a scene of many faces of
/// one material, split once, it holds a leaf (60 bytes) and the mesh per element, each patch
/// still naming its own face.
#[test]
fn the_hierarchy_holds_a_leaf_per_element_and_a_template_per_material() {
    let n = 2000u32;
    let mut positions = Vec::new();
    let mut faces = Vec::new();
    for i in 0..n {
        let x = i as f32;
        let at = positions.len() as u32;
        positions.extend([
            Vec3::new(x, 0.0, 0.0),
            Vec3::new(x + 1.0, 0.0, 0.0),
            Vec3::new(x, 1.0, 0.0),
        ]);
        faces.push(vec![at, at + 1, at + 2]);
    }
    let s = scene(positions, faces);
    let mut m = AdaptiveMesh::new(&s, Subdivision::None, bounds(0.1, 1_000_000)).unwrap();
    m.refine(&[0, 7, 1999]);
    assert_eq!(m.len(), n as usize + 9);
    assert_eq!(size_of::<super::adaptive::LeafRecord>(), 12);
    let mesh_bytes = m.mesh().heap_bytes() as f64 / m.len() as f64;
    let hierarchy = m.bytes_per_element() - mesh_bytes;
    assert!(hierarchy <= 13.0, "{hierarchy} bytes per element");
    // every patch names its face: the first four are face 0's children, then face 1
    let faces: Vec<u32> = m.mesh().patches().iter().map(|p| p.face).collect();
    assert_eq!(&faces[..6], &[0, 0, 0, 0, 1, 2]);
    assert_eq!(&faces[faces.len() - 4..], &[1999; 4]);
    assert_eq!(faces[10..14], [7; 4]);
}

/// A wavy terrain of `n × n` cells, two triangles each (`2 n²` faces), each side 1 long, its
/// material two-sided when asked: enough faces for several blocks of the start's and the
/// vertex sharing's parallel passes.
fn terrain(n: u32, two_sided: bool) -> Scene {
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f32, j as f32);
            positions.push(Vec3::new(x, y, (0.3 * x).sin() + (0.2 * y).cos()));
        }
    }
    let at = |i: u32, j: u32| j * (n + 1) + i;
    let mut faces = Vec::new();
    for j in 0..n {
        for i in 0..n {
            faces.push(vec![at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            faces.push(vec![at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    let s = scene(positions, faces);
    if two_sided {
        s.with_two_sided(vec![true])
    } else {
        s
    }
}

#[test]
fn start_counts_are_the_meshes_patch_counts() {
    let scenes = [
        shapes(Vec3::ZERO),
        shapes(Vec3::splat(1e4)),
        terrain(12, false),
        terrain(12, true),
    ];
    for scene in &scenes {
        for start in [
            Subdivision::None,
            Subdivision::MaxEdge(0.3),
            Subdivision::MaxEdge(0.7),
            Subdivision::MaxEdge(5.0),
        ] {
            let built = Mesh::build(scene, start).unwrap().patches().len();
            assert_eq!(Mesh::count_patches(scene, start).unwrap(), built as u64);
            let b = bounds(0.01, 1 << 20);
            assert_eq!(AdaptiveMesh::start_len(scene, start, b).unwrap(), built);
            assert_eq!(AdaptiveMesh::new(scene, start, b).unwrap().len(), built);
        }
        // the errors of a build
        assert!(Mesh::count_patches(scene, Subdivision::MaxEdge(0.0)).is_err());
        assert!(AdaptiveMesh::start_len(scene, Subdivision::None, bounds(0.01, 0)).is_err());
    }
}

#[test]
fn the_start_is_the_uniform_mesh_with_its_corners_shared() {
    for scene in [terrain(12, false), terrain(12, true), shapes(Vec3::ZERO)] {
        for start in [Subdivision::None, Subdivision::MaxEdge(0.4)] {
            let uniform = Mesh::build(&scene, start).unwrap();
            let adaptive = AdaptiveMesh::new(&scene, start, bounds(0.01, 1 << 20)).unwrap();
            let mesh = adaptive.mesh();
            assert_eq!(mesh.patches().len(), uniform.patches().len());
            for (a, u) in mesh.patches().iter().zip(uniform.patches()) {
                let corners = |m: &Mesh, p| -> Vec<Vec3> {
                    m.corners(p)
                        .iter()
                        .map(|&v| m.positions()[v as usize])
                        .collect()
                };
                assert_eq!(corners(mesh, a), corners(&uniform, u));
                assert_eq!(
                    (a.area, a.normal, a.centroid, a.face, a.back),
                    (u.area, u.normal, u.centroid, u.face, u.back)
                );
            }
            // one vertex per position
            let mut keys: Vec<[u32; 3]> = mesh
                .positions()
                .iter()
                .map(|p| p.to_array().map(f32::to_bits))
                .collect();
            let n = keys.len();
            keys.sort_unstable();
            keys.dedup();
            assert_eq!(keys.len(), n, "a position has two vertices");
            mesh.validate().unwrap();
        }
    }
}

#[test]
fn the_start_and_its_refinement_are_the_same_on_any_thread_count() {
    // 2 × 110² faces: several blocks of faces and of leaves
    let scene = terrain(110, true);
    let build = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut m = AdaptiveMesh::new(&scene, Subdivision::MaxEdge(0.9), bounds(0.01, 1 << 20))
                .unwrap();
            let every_third: Vec<u32> = (0..m.len() as u32).step_by(3).collect();
            m.refine(&every_third);
            m
        })
    };
    let (one, three) = (build(1), build(3));
    assert!(one.len() > 1 << 15, "{} leaves", one.len());
    let (a, b) = (one.mesh(), three.mesh());
    assert_eq!(a.positions(), b.positions());
    assert_eq!(a.triangles(), b.triangles());
    assert_eq!(a.triangle_patch(), b.triangle_patch());
    assert_eq!(a.patches(), b.patches());
}
