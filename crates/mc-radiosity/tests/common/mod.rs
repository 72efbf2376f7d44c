//! Scenes shared by the integration tests.

use glam::Vec3;
use mcrad_scene_io::{Face, Light, Material, Scene};

/// The inside of a cube of side `side` centred at the origin (faces facing in), every face of
/// `material`, one patch per face when meshed with `Subdivision::None`, lit by `lights` (and by
/// the material's emission).
pub fn cube(side: f32, material: Material, lights: Vec<Light>) -> Scene {
    let h = side / 2.0;
    let p: Vec<Vec3> = (0..8)
        .map(|i| {
            Vec3::new(
                if i & 1 == 0 { -h } else { h },
                if i & 2 == 0 { -h } else { h },
                if i & 4 == 0 { -h } else { h },
            )
        })
        .collect();
    // Counter-clockwise seen from inside.
    let quads = [
        [0, 1, 3, 2], // z = -h, seen from +z
        [4, 6, 7, 5], // z = +h
        [0, 4, 5, 1], // y = -h
        [2, 3, 7, 6], // y = +h
        [0, 2, 6, 4], // x = -h
        [1, 5, 7, 3], // x = +h
    ];
    let faces = quads
        .iter()
        .enumerate()
        .map(|(i, q)| Face {
            vertices: q.to_vec(),
            material: 0,
            source: i as u32,
        })
        .collect();
    Scene::new_lit(p, faces, vec![material], lights).unwrap().0
}
