//! Scenes at real scale through the library's default solve: many small input faces next to a
//! few huge ones (the default adaptive mesh still refines the huge ones), and a sliver too thin
//! for `f32` coordinates at the scene's size (kept whole with one warning, never a refusal).

use glam::Vec3;
use mcrad_meshing::{AdaptiveBounds, DEFAULT_COARSE_EDGE_FRACTION, Mesh, Subdivision};
use mcrad_scene_io::{Face, Material, Scene};
use mcrad_solve::{MeshPlan, Problem, solve};
use std::ops::ControlFlow;

fn go(_: &mcrad_solve::Progress) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

/// A scene being assembled from polygons (counter-clockwise from the front).
#[derive(Default)]
struct Builder {
    positions: Vec<Vec3>,
    faces: Vec<Face>,
}

impl Builder {
    /// Adds a polygon of `material`; returns its face number.
    fn face(&mut self, corners: &[Vec3], material: u32) -> u32 {
        let first = self.positions.len() as u32;
        self.positions.extend_from_slice(corners);
        let source = self.faces.len() as u32;
        self.faces.push(Face {
            vertices: (first..first + corners.len() as u32).collect(),
            material,
            source,
        });
        source
    }

    fn scene(self, materials: Vec<Material>) -> Scene {
        Scene::new(self.positions, self.faces, materials).unwrap().0
    }
}

fn material(name: &str, reflectance: f32, emission: f32) -> Material {
    Material {
        name: name.to_string(),
        reflectance: Vec3::splat(reflectance),
        emission: Vec3::splat(emission),
    }
}

/// The square `[x0, x1] × [z0, z1]` at height `y`, facing up or down.
fn horizontal(y: f32, [x0, x1, z0, z1]: [f32; 4], up: bool) -> Vec<Vec3> {
    let q = vec![
        Vec3::new(x0, y, z0),
        Vec3::new(x0, y, z1),
        Vec3::new(x1, y, z1),
        Vec3::new(x1, y, z0),
    ];
    if up { q } else { vec![q[0], q[3], q[2], q[1]] }
}

#[test]
fn many_small_faces_do_not_switch_off_the_refinement_of_the_huge_ones() {
    // An atrium in miniature: a 40 m x 40 m floor of one face, lit by a 10 m x 10 m panel 20 m
    // above it (10 W/m²), and a 4 m x 2 m wall standing on it made of 201 x 101 tiles of
    // 2 cm (40,602 triangles: more faces than the default budget of 40,000 elements). The
    // wall's shadow crosses the floor. Before, more input faces than half the budget made the
    // start one element per face and left the refinement nothing to add: the floor stayed one
    // element. Now the start keeps the tiles whole and cuts the floor to the diagonal / 40,
    // and the refinement may add half the budget beyond its start.
    let mut b = Builder::default();
    let floor = b.face(&horizontal(0.0, [-20.0, 20.0, -20.0, 20.0], true), 0);
    b.face(&horizontal(20.0, [-5.0, 5.0, -5.0, 5.0], false), 1);
    let (nx, ny) = (201, 101);
    let (w, h) = (4.0 / nx as f32, 2.0 / ny as f32);
    for j in 0..ny {
        for i in 0..nx {
            let (x, y) = (-2.0 + i as f32 * w, j as f32 * h);
            let p = |u: f32, v: f32| Vec3::new(x + u * w, y + v * h, 2.0);
            // facing +z
            b.face(&[p(0.0, 0.0), p(1.0, 0.0), p(1.0, 1.0)], 0);
            b.face(&[p(0.0, 0.0), p(1.0, 1.0), p(0.0, 1.0)], 0);
        }
    }
    let scene = b.scene(vec![
        material("grey", 0.5, 0.0),
        material("panel", 0.0, 10.0),
    ]);
    assert!(scene.faces().len() > AdaptiveBounds::default_for(&scene).max_patches);
    let diagonal = scene.bounds().diagonal() as f32;
    let start = Mesh::build(
        &scene,
        Subdivision::MaxEdge(diagonal * DEFAULT_COARSE_EDGE_FRACTION),
    )
    .unwrap();
    let on_floor = |mesh: &Mesh| mesh.patches().iter().filter(|p| p.face == floor).count();
    let mut problem = Problem::new(&scene);
    // The default settings (adaptive mesh, its budget and minimum edge, combined) with rays
    // enough for a round of marks over every element (48 rays each) after the pilot.
    problem.budget.rays = Some(16_000_000);
    let answer = solve(&problem, &mut go).unwrap();
    let rounds = answer.stats.refinement.as_ref().expect("an adaptive mesh");
    let split: usize = rounds.iter().map(|r| r.split).sum();
    assert!(split > 0, "no element split: {rounds:?}");
    let (before, after) = (on_floor(&start), on_floor(&answer.mesh));
    assert!(
        before > 1 && after > before,
        "floor elements: start {before}, refined {after}"
    );
    // every tile is still its own element
    assert!(answer.mesh.patches().len() >= scene.faces().len() + after - 1);
}

#[test]
fn a_sliver_too_thin_for_f32_at_the_scene_size_is_kept_whole_with_one_warning() {
    // A 35 m x 10 m x 10 m closed hall (reflectance 0.5, ceiling emitting 1 W/m²) with a
    // triangular sliver 20 m long and 0.5 mm wide lying 1 cm above the floor. Cut to edges of
    // 0.5 m it would make 1,600 triangles 0.0125 mm wide, about 1.8 mm across
    // (`sqrt(area)`), below the 2.1 mm that f32 resolves 17.5 m from the hall's centre
    // (1024 spacings): the run was refused ("the scene is too large for its smallest patch").
    let mut b = Builder::default();
    let (x, y, z) = (17.5, 5.0, 5.0);
    let c = |i: usize| {
        Vec3::new(
            if i & 1 == 0 { -x } else { x },
            if i & 2 == 0 { -y } else { y },
            if i & 4 == 0 { -z } else { z },
        )
    };
    // the six walls of the box [-x, x] x [-y, y] x [-z, z], facing in
    for (quad, m) in [
        ([4, 5, 1, 0], 0), // floor y = -y, facing +y
        ([3, 7, 6, 2], 1), // ceiling, facing -y
        ([2, 6, 4, 0], 0), // x = -x, facing +x
        ([5, 7, 3, 1], 0), // x = +x
        ([1, 3, 2, 0], 0), // z = -z, facing +z
        ([6, 7, 5, 4], 0), // z = +z
    ] {
        b.face(&quad.map(c), m);
    }
    let h = -y + 0.01;
    let sliver = b.face(
        &[
            Vec3::new(-10.0, h, 0.0),
            Vec3::new(10.0, h, 0.0005),
            Vec3::new(10.0, h, 0.0),
        ],
        0,
    );
    let scene = b.scene(vec![
        material("wall", 0.5, 0.0),
        material("light", 0.5, 1.0),
    ]);
    let mut problem = Problem::new(&scene);
    problem.settings.mesh = MeshPlan::Uniform {
        max_edge: Some(0.5),
    };
    problem.budget.rays = Some(200_000);
    let answer = solve(&problem, &mut go).unwrap();
    let slivers: Vec<_> = answer
        .mesh
        .patches()
        .iter()
        .filter(|p| p.face == sliver)
        .collect();
    assert_eq!(slivers.len(), 1, "the sliver is one patch");
    assert!(
        (slivers[0].area - 0.005).abs() < 1e-6,
        "{}",
        slivers[0].area
    );
    assert_eq!(answer.mesh.kept_whole(), 1);
    let said: Vec<_> = answer
        .warnings
        .iter()
        .filter(|w| w.contains("kept whole"))
        .collect();
    assert_eq!(said.len(), 1, "{:?}", answer.warnings);
    assert!(said[0].starts_with("1 faces"), "{}", said[0]);
    // the rest of the hall is cut as asked: no patch edge of a wall beyond 0.5 m, so a 10 m x
    // 35 m wall has at least 1,400 patches
    let walls = answer.mesh.patches().iter().filter(|p| p.face == 0).count();
    assert!(walls >= 1400, "{walls}");
}
