//! Tests of patch geometry and subdivision.

use crate::{Mesh, MeshError, Subdivision};
use glam::{DVec3, Vec3};
use mcrad_scene_io::{Face, Material, Scene};

fn materials() -> Vec<Material> {
    vec![
        Material {
            name: "white".into(),
            reflectance: Vec3::splat(0.5),
            emission: Vec3::ZERO,
        },
        Material {
            name: "lamp".into(),
            reflectance: Vec3::ZERO,
            emission: Vec3::ONE,
        },
    ]
}

fn face(vertices: &[u32], material: u32, source: u32) -> Face {
    Face {
        vertices: vertices.to_vec(),
        material,
        source,
    }
}

/// A triangle, a trapezoid quad, a convex pentagon and a concave (dart) quad sharing vertices.
fn mixed_scene() -> Scene {
    let positions = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(3.0, 0.0, 0.0),
        Vec3::new(2.0, 1.7, 0.0),
        Vec3::new(0.5, 1.3, 0.0),
        // a pentagon in the plane y = -1
        Vec3::new(0.0, -1.0, 0.0),
        Vec3::new(0.0, -1.0, 2.0),
        Vec3::new(1.0, -1.0, 2.7),
        Vec3::new(2.0, -1.0, 2.0),
        Vec3::new(2.0, -1.0, 0.0),
        // a light triangle
        Vec3::new(0.0, 5.0, 0.0),
        Vec3::new(0.0, 5.0, 1.0),
        Vec3::new(1.0, 5.0, 0.0),
        // dart: reflex corner at index 14
        Vec3::new(5.0, 0.0, 0.0),
        Vec3::new(7.0, 0.0, 0.0),
        Vec3::new(6.0, 0.5, 0.0),
        Vec3::new(6.0, 2.0, 0.0),
    ];
    let faces = vec![
        face(&[0, 1, 2, 3], 0, 0),
        face(&[0, 3, 2], 0, 1),
        face(&[4, 5, 6, 7, 8], 0, 2),
        face(&[9, 10, 11], 1, 3),
        face(&[14, 15, 12, 13], 0, 4),
    ];
    Scene::new(positions, faces, materials())
        .expect("valid scene")
        .0
}

fn polygon_area(p: &[Vec3]) -> f64 {
    let p0 = p[0].as_dvec3();
    let s: DVec3 = p[1..]
        .windows(2)
        .map(|w| (w[0].as_dvec3() - p0).cross(w[1].as_dvec3() - p0))
        .sum();
    s.length() / 2.0
}

#[test]
fn one_patch_per_face_keeps_order_area_and_face_numbers() {
    let scene = mixed_scene();
    let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
    mesh.validate().unwrap();
    assert_eq!(mesh.patches().len(), scene.faces().len());
    for (patch, face) in mesh.patches().iter().zip(scene.faces()) {
        assert_eq!(patch.face, face.source);
        let pts: Vec<Vec3> = face
            .vertices
            .iter()
            .map(|&i| scene.positions()[i as usize])
            .collect();
        assert!((patch.area - polygon_area(&pts)).abs() < 1e-9 * patch.area.max(1.0));
        assert_eq!(mesh.corners(patch), &face.vertices[..]);
    }
    // The quad lies in z = 0, counter-clockwise seen from +z.
    assert!((mesh.patches()[0].normal - Vec3::Z).length() < 1e-6);
    // The pentagon in the plane y = -1 runs counter-clockwise seen from +y.
    assert!((mesh.patches()[2].normal - Vec3::Y).length() < 1e-6);
}

#[test]
fn subdivision_preserves_each_face_area_and_bounds_edges() {
    let scene = mixed_scene();
    for max_edge in [2.0f32, 0.5, 0.137, 0.03] {
        let mesh = Mesh::build(&scene, Subdivision::MaxEdge(max_edge)).unwrap();
        mesh.validate().unwrap();
        let mut per_face = vec![0.0f64; scene.faces().len()];
        for p in mesh.patches() {
            per_face[p.face as usize] += p.area;
            let c = mesh.corners(p);
            for k in 0..c.len() {
                let (a, b) = (
                    mesh.positions()[c[k] as usize],
                    mesh.positions()[c[(k + 1) % c.len()] as usize],
                );
                assert!(
                    a.distance(b) <= max_edge * (1.0 + 1e-5),
                    "edge {} > {max_edge}",
                    a.distance(b)
                );
            }
            assert!(
                p.normal.dot(
                    mesh.patches()
                        .iter()
                        .find(|q| q.face == p.face)
                        .unwrap()
                        .normal
                ) > 0.999
            );
        }
        for (f, face) in scene.faces().iter().enumerate() {
            let pts: Vec<Vec3> = face
                .vertices
                .iter()
                .map(|&i| scene.positions()[i as usize])
                .collect();
            let exact = polygon_area(&pts);
            assert!(
                (per_face[f] - exact).abs() <= 1e-6 * exact,
                "face {f} at max edge {max_edge}: {} vs {exact}",
                per_face[f]
            );
        }
        let total: f64 = scene
            .faces()
            .iter()
            .map(|f| {
                polygon_area(
                    &f.vertices
                        .iter()
                        .map(|&i| scene.positions()[i as usize])
                        .collect::<Vec<_>>(),
                )
            })
            .sum();
        assert!((mesh.total_area() - total).abs() <= 1e-6 * total);
    }
}

#[test]
fn neighbouring_faces_share_their_edge_points() {
    // Two unit squares sharing the edge x = 1, each cut 4 x 4: 5 x 9 = 45 distinct vertices.
    let positions = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::new(2.0, 0.0, 0.0),
        Vec3::new(2.0, 1.0, 0.0),
    ];
    let faces = vec![face(&[0, 1, 2, 3], 0, 0), face(&[1, 4, 5, 2], 1, 1)];
    let scene = Scene::new(positions, faces, materials()).unwrap().0;
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.25)).unwrap();
    assert_eq!(mesh.patches().len(), 32);
    let used: std::collections::BTreeSet<u32> = mesh
        .patches()
        .iter()
        .flat_map(|p| mesh.corners(p).to_vec())
        .collect();
    assert_eq!(used.len(), 45);
    // Patches cut from the emitting face keep its emission and face number.
    assert!(
        mesh.patches()
            .iter()
            .filter(|p| p.face == 1)
            .all(|p| p.emission == Vec3::ONE)
    );
}

#[test]
fn bad_max_edge_and_absurd_counts_are_errors() {
    let scene = mixed_scene();
    for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        assert!(Mesh::build(&scene, Subdivision::MaxEdge(bad)).is_err());
    }
    let err = Mesh::build(&scene, Subdivision::MaxEdge(1e-6)).unwrap_err();
    assert!(matches!(err, MeshError::TooManyPatches { .. }), "{err}");
    // the library names no command-line flag: the CLI adds advice about the flags given
    assert!(!err.to_string().contains("--"), "{err}");
    assert!(err.to_string().contains("4.9e13 patches"), "{err}");
}

#[test]
fn a_patch_limit_refuses_before_cutting_a_face_that_alone_exceeds_it() {
    let scene = mixed_scene();
    let all = Mesh::build(&scene, Subdivision::MaxEdge(0.05)).unwrap();
    let n = all.patches().len();
    assert!(n > 100, "{n}");
    let exact = Mesh::build_at_most(&scene, Subdivision::MaxEdge(0.05), n).unwrap();
    assert_eq!(exact.patches().len(), n);
    assert_eq!(
        Mesh::build_at_most(&scene, Subdivision::MaxEdge(0.05), n - 1).unwrap_err(),
        MeshError::PatchLimit { limit: n - 1 }
    );
    // 1e-3 edges would make millions of patches of one face (refused before it is cut)
    assert_eq!(
        Mesh::build_at_most(&scene, Subdivision::MaxEdge(1e-3), 10_000).unwrap_err(),
        MeshError::PatchLimit { limit: 10_000 }
    );
    assert_eq!(
        Mesh::build_at_most(&scene, Subdivision::None, 1).unwrap_err(),
        MeshError::PatchLimit { limit: 1 }
    );
}

#[test]
fn a_patch_takes_80_bytes() {
    // Every element of a solve holds one (issue 35, memory per element): area, four vectors,
    // face and material, its side, its corners and its first triangle (their count follows
    // from its corners').
    assert_eq!(size_of::<crate::Patch>(), 80);
}

#[test]
fn a_clone_shares_its_geometry_until_one_of_them_changes_it() {
    let mesh = Mesh::build(&mixed_scene(), Subdivision::MaxEdge(0.5)).unwrap();
    let mut lit = mesh.clone();
    // a pass lights its own copy: the patches are its own, the geometry is not copied
    lit.set_emission(0, Vec3::ONE);
    assert!(std::ptr::eq(lit.positions(), mesh.positions()));
    assert!(std::ptr::eq(lit.triangles(), mesh.triangles()));
    assert_ne!(lit.patches()[0].emission, mesh.patches()[0].emission);
    // a clone that grows gets its own positions; the original keeps its own
    let n = mesh.positions().len();
    let v = lit.push_position(Vec3::splat(7.0));
    assert_eq!(v as usize, n);
    assert_eq!(lit.positions().len(), n + 1);
    assert_eq!(mesh.positions().len(), n);
    assert!(std::ptr::eq(lit.triangles(), mesh.triangles()));
}
