//! Textured faces: every patch and adaptive element takes its reflectance from the texture over
//! its own area, times the material's factor.

use std::sync::Arc;

use glam::Vec3;
use mcrad_meshing::{AdaptiveBounds, AdaptiveMesh, Mesh, Subdivision};
use mcrad_scene_io::{Face, FaceMapping, Material, Scene, SceneTextures, Texture, Wrap};

/// A unit square (two triangles, faces 0 and 1) with reflectance factor 0.8, textured by a
/// 2 × 1 image, white on the left (`x < 0.5`), black on the right, clamped: `u = x`.
fn textured_square() -> Scene {
    let p = vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
    let tris = [[0u32, 1, 2], [0, 2, 3]];
    let faces = tris
        .iter()
        .enumerate()
        .map(|(i, t)| Face {
            vertices: t.to_vec(),
            material: 0,
            source: i as u32,
        })
        .collect();
    let material = Material {
        name: "floor".into(),
        reflectance: Vec3::splat(0.8),
        emission: Vec3::ONE,
    };
    let (scene, _) = Scene::new(p.clone(), faces, vec![material]).unwrap();
    let image = Texture::new(2, 1, vec![Vec3::ONE, Vec3::ZERO], [Wrap::Clamp; 2]).unwrap();
    let mapping = |t: [u32; 3]| {
        Some(FaceMapping {
            corners: t.map(|i| p[i as usize]),
            uv: t.map(|i| p[i as usize].truncate()),
            emissive_uv: t.map(|i| p[i as usize].truncate()),
            colors: [Vec3::ONE; 3],
            base: Some(0),
            emissive: None,
            alpha: None,
        })
    };
    scene.with_textures(SceneTextures {
        textures: vec![Arc::new(image)],
        faces: tris.iter().map(|&t| mapping(t)).collect(),
    })
}

/// Every patch away from the middle (where the bilinear lookup blends the two texels over
/// half a texel) has the texture's value times 0.8, and the area-weighted mean is 0.4 (the
/// clamped bilinear image integrates to exactly 1/2).
fn check(mesh: &Mesh) {
    let mut mean = 0.0;
    for p in mesh.patches() {
        let r = p.reflectance.x;
        if p.centroid.x < 0.2 {
            assert!((r - 0.8).abs() < 1e-4, "{p:?}");
        } else if p.centroid.x > 0.8 {
            assert!(r.abs() < 1e-4, "{p:?}");
        }
        assert_eq!(p.reflectance, Vec3::splat(r));
        mean += f64::from(r) * p.area;
    }
    assert!((mean - 0.4).abs() < 0.01, "{mean}");
}

#[test]
fn uniform_patches_take_the_texture_over_their_area() {
    let mesh = Mesh::build(&textured_square(), Subdivision::MaxEdge(0.1)).unwrap();
    assert!(mesh.patches().len() > 100);
    check(&mesh);
    // one patch per face: each triangle's own mean
    let coarse = Mesh::build(&textured_square(), Subdivision::None).unwrap();
    let r: Vec<f32> = coarse.patches().iter().map(|p| p.reflectance.x).collect();
    // triangle (0,0)-(1,0)-(1,1) lies mostly right of the middle, its twin mostly left
    assert!(
        r[0] < 0.4 && r[1] > 0.4 && ((r[0] + r[1]) / 2.0 - 0.4).abs() < 0.01,
        "{r:?}"
    );
}

#[test]
fn adaptive_children_take_the_texture_not_their_parents_value() {
    let scene = textured_square();
    let bounds = AdaptiveBounds {
        min_edge: 0.01,
        max_patches: 100_000,
    };
    let mut mesh = AdaptiveMesh::new(&scene, Subdivision::None, bounds).unwrap();
    for _ in 0..5 {
        let all: Vec<u32> = (0..mesh.len() as u32).collect();
        mesh.refine(&all);
    }
    assert!(mesh.len() > 1000);
    check(mesh.mesh());
}
