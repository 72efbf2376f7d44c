//! Two-sided faces (glTF `doubleSided`) in every method, against exact answers.
//!
//! - An open two-sided plane between two delta suns, one above at 30° elevation and one below
//!   at 60°: nothing sends light back, so each side's radiosity is exactly `rho E_side`,
//!   `E_side = E sin(elevation)` of the sun on its side (1e-6 of it: rounding).
//! - A closed furnace (a cube's inside, every surface emitting `E` with reflectance `rho`)
//!   with a two-sided plane across it of the same `E` and `rho`: `B = E / (1 - rho)` on the
//!   walls and on both sides of the plane. Every method, over 4 seeds: the mean of the runs'
//!   area-means per group (walls, fronts, backs) within 4 standard errors of their spread
//!   plus 2e-3 of the answer (the bias a shooting threshold or a gathering remainder may
//!   leave). A plane seen from behind as a one-sided face would absorb and darken the backs
//!   far beyond that.

use glam::{DVec3, Vec3};
use mcrad_mc_radiosity::{Method, ScheduleConfig, run};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_scene_io::{Face, Light, Material, Scene, Sun};
use std::ops::ControlFlow;

fn solve(method: Method, mesh: &Mesh, config: &ScheduleConfig) -> Vec<DVec3> {
    let bvh = mesh.caster().unwrap();
    run(method, mesh, &bvh, config, &mut |_| {
        ControlFlow::Continue(())
    })
    .unwrap_or_else(|e| panic!("{method}: {e}"))
    .estimate
    .radiosity()
    .to_vec()
}

fn material(name: &str, rho: f32, e: f32) -> Material {
    Material {
        name: name.into(),
        reflectance: Vec3::splat(rho),
        emission: Vec3::splat(e),
    }
}

fn sun(elevation_degrees: f64, below: bool, e: f64) -> Light {
    let a = elevation_degrees.to_radians();
    let z = if below { -a.sin() } else { a.sin() };
    Light::Sun(Sun {
        direction: Vec3::new(a.cos() as f32, 0.0, z as f32),
        irradiance: DVec3::splat(e),
        diameter: 0.0,
    })
}

#[test]
fn an_open_two_sided_plane_between_two_suns_gives_each_side_rho_e() {
    let (rho, e) = (0.4f32, 800.0);
    let positions = vec![
        Vec3::new(-1.0, -1.0, 0.0),
        Vec3::new(1.0, -1.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(-1.0, 1.0, 0.0),
    ];
    let faces = vec![Face {
        vertices: vec![0, 1, 2, 3],
        material: 0,
        source: 0,
    }];
    let suns = vec![sun(30.0, false, e), sun(60.0, true, e)];
    let scene = Scene::new_lit(positions, faces, vec![material("sheet", rho, 0.0)], suns)
        .unwrap()
        .0
        .with_two_sided(vec![true]);
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.5)).unwrap();
    assert_eq!(mesh.patches().len(), 2 * 16);
    let front = f64::from(rho) * e * 30f64.to_radians().sin();
    let back = f64::from(rho) * e * 60f64.to_radians().sin();
    for method in Method::ALL {
        let config = ScheduleConfig {
            rays: 20_000,
            lights: scene.lights().to_vec(),
            ..Default::default()
        };
        let b = solve(method, &mesh, &config);
        for (i, (p, b)) in mesh.patches().iter().zip(&b).enumerate() {
            let exact = if p.back { back } else { front };
            assert!(
                (b.x - exact).abs() < 1e-6 * exact,
                "{method}: patch {i} (back {}): {} vs {exact}",
                p.back,
                b.x
            );
        }
    }
}

#[test]
fn a_two_sided_plane_in_a_closed_furnace_gives_e_over_one_minus_rho_on_both_sides() {
    let (rho, e) = (0.5f32, 1.0f32);
    let h = 1.0f32;
    let mut positions: Vec<Vec3> = (0..8)
        .map(|i| {
            Vec3::new(
                if i & 1 == 0 { -h } else { h },
                if i & 2 == 0 { -h } else { h },
                if i & 4 == 0 { -h } else { h },
            )
        })
        .collect();
    let quads = [
        [0, 1, 3, 2],
        [4, 6, 7, 5],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 2, 6, 4],
        [1, 5, 7, 3],
    ];
    let mut faces: Vec<Face> = quads
        .iter()
        .enumerate()
        .map(|(i, q)| Face {
            vertices: q.to_vec(),
            material: 0,
            source: i as u32,
        })
        .collect();
    // a tilted sheet across the middle, short of the walls
    positions.extend([
        Vec3::new(-0.8, -0.8, -0.3),
        Vec3::new(0.8, -0.8, -0.1),
        Vec3::new(0.8, 0.8, 0.3),
        Vec3::new(-0.8, 0.8, 0.1),
    ]);
    faces.push(Face {
        vertices: vec![8, 9, 10, 11],
        material: 1,
        source: 6,
    });
    let scene = Scene::new(
        positions,
        faces,
        vec![material("wall", rho, e), material("sheet", rho, e)],
    )
    .unwrap()
    .0
    .with_two_sided(vec![false, true]);
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(1.0)).unwrap();
    let exact = f64::from(e) / (1.0 - f64::from(rho));
    let group = |p: &mcrad_meshing::Patch| match (p.face, p.back) {
        (6, false) => 1,
        (6, true) => 2,
        _ => 0,
    };
    let seeds = 4u64;
    for method in Method::ALL {
        let means: Vec<[f64; 3]> = (0..seeds)
            .map(|seed| {
                let config = ScheduleConfig {
                    rays: 20_000,
                    seed,
                    ..Default::default()
                };
                let b = solve(method, &mesh, &config);
                let (mut sum, mut area) = ([0.0; 3], [0.0; 3]);
                for (p, b) in mesh.patches().iter().zip(&b) {
                    sum[group(p)] += b.x * p.area;
                    area[group(p)] += p.area;
                }
                [0, 1, 2].map(|g| sum[g] / area[g])
            })
            .collect();
        let n = seeds as f64;
        for g in 0..3 {
            let mean = means.iter().map(|m| m[g]).sum::<f64>() / n;
            let var = means.iter().map(|m| (m[g] - mean).powi(2)).sum::<f64>() / (n - 1.0);
            let se = (var / n).sqrt();
            assert!(
                (mean - exact).abs() <= 4.0 * se + 2e-3 * exact,
                "{method}: group {g}: mean {mean} exact {exact} (se {se})"
            );
        }
    }
}
