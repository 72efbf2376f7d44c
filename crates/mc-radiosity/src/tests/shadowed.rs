//! Groups of small faces split where a shadow crosses them ([`split_shadowed`]): down to single
//! faces with no smallest span, and never below half of it with one, whatever the faces'
//! tessellation.

use super::common::{self, material, quad};

use crate::{ShadowSplit, split_shadowed};
use glam::{DVec3, Vec3};
use mcrad_meshing::{Clusters, Mesh, Subdivision, UNGROUPED};
use mcrad_scene_io::{Light, Scene, Sun};

/// The shadow's edge on the floor (x, metres): inside a tile (60% of a 16th), off the tiles' medians.
const EDGE: f32 = 0.35;

/// A unit floor of `n x n` square tiles (z = 0, facing up, each its own face, corners shared),
/// under a sun straight above, and a black plate at z = 0.5 over `x < EDGE` (facing down) that
/// shades the tiles there.
fn shaded_tiles(n: u32) -> Scene {
    let (mut p, mut f) = (Vec::new(), Vec::new());
    for j in 0..=n {
        for i in 0..=n {
            p.push(Vec3::new(i as f32, j as f32, 0.0) / n as f32);
        }
    }
    let at = |i: u32, j: u32| j * (n + 1) + i;
    for j in 0..n {
        for i in 0..n {
            let source = f.len() as u32;
            f.push(quad(
                [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)],
                0,
                source,
            ));
        }
    }
    let base = p.len() as u32;
    for (x, y) in [(-0.5, -0.5), (-0.5, 1.5), (EDGE, 1.5), (EDGE, -0.5)] {
        p.push(Vec3::new(x, y, 0.5));
    }
    let source = f.len() as u32;
    f.push(quad([base, base + 1, base + 2, base + 3], 1, source));
    let sun = Light::Sun(Sun {
        direction: Vec3::Z,
        irradiance: DVec3::splat(500.0),
        diameter: 0.0,
    });
    let materials = vec![material("tile", 0.5, 0.0), material("black", 0.0, 0.0)];
    Scene::new_lit(p, f, materials, vec![sun]).unwrap().0
}

/// The groups after splitting all tiles of `mesh` as one group, with smallest span `min_span`,
/// each as its members; and the tiles left alone.
fn split(mesh: &Mesh, lights: &[Light], min_span: f64, seed: u64) -> (Vec<Vec<u32>>, usize) {
    let patches = mesh.patches();
    let mut group: Vec<u32> = patches
        .iter()
        .map(|p| if p.material == 0 { 0 } else { UNGROUPED })
        .collect();
    let tiles = group.iter().filter(|&&g| g == 0).count();
    // a lit tile's radiosity: the luminance the test compares with
    let radiosity = vec![DVec3::splat(250.0); patches.len()];
    let split = ShadowSplit {
        rays: 32,
        tolerance: 0.02,
        seed,
        min_span,
    };
    let caster = common::bvh(mesh);
    split_shadowed(mesh, &caster, lights, None, &radiosity, &mut group, split);
    let groups = Clusters::from_groups(&group, |_| true);
    let grouped = groups.patches();
    (
        groups.iter().map(<[u32]>::to_vec).collect(),
        tiles - grouped,
    )
}

#[test]
fn a_group_across_a_shadow_is_split_no_finer_than_its_smallest_span() {
    for (n, seed) in [(16, 1), (16, 2), (32, 3)] {
        let scene = shaded_tiles(n);
        let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
        // the tiles the edge crosses: partly in the shadow
        let x = |i: u32| mesh.patches()[i as usize].centroid.x + mesh.origin().x;
        let crossed = |g: &[u32]| g.iter().any(|&i| (x(i) - EDGE).abs() < 0.5 / n as f32);
        // no smallest span: the groups across the edge are split down to single tiles
        let (_, alone) = split(&mesh, scene.lights(), 0.0, seed);
        assert!(alone >= n as usize / 2, "n {n}: {alone} tiles alone");
        // a smallest span of 0.25: no group spans less than half of it, none is left alone,
        // and the groups the edge crosses span less than it, their count the same whatever
        // the tessellation (the unit edge's 1 / 0.125 groups of 0.125)
        let (groups, alone) = split(&mesh, scene.lights(), 0.25, seed);
        assert_eq!(alone, 0, "n {n}");
        let spans: Vec<f64> = groups.iter().map(|g| Clusters::span(&mesh, g)).collect();
        assert!(spans.iter().all(|&s| s >= 0.125 - 1e-6), "n {n}: {spans:?}");
        let across: Vec<f64> = groups
            .iter()
            .zip(&spans)
            .filter(|(g, _)| crossed(g))
            .map(|(_, &s)| s)
            .collect();
        assert_eq!(across.len(), 8, "n {n}: {across:?}");
        assert!(across.iter().all(|&s| s < 0.25), "n {n}: {across:?}");
    }
}
