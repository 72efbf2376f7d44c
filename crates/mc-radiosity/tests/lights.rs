//! Lights without a surface in every method, against exact answers.
//!
//! - A closed cube of side 4 and reflectance 0.5 with an isotropic point light of power `Phi`
//!   at its centre (CIE 171:2006's closed-room case): the area-mean irradiance is
//!   `Phi / (S (1 - rho))`, so the area-mean radiosity is `rho Phi / (S (1 - rho))`. Every
//!   method, over 4 seeds: the mean of the runs' area-means within 4 standard errors of their
//!   spread (plus 2e-3 of the answer for the bias a shooting threshold or a gathering
//!   remainder may leave).
//! - The sun on an open upward plane: `B = rho E sin(elevation)` exactly.
//! - Under a time budget the lights' pass takes what its time allows (4 points a patch when
//!   none is left, instead of 64), and the answer stays the closed cube's.

use glam::{DVec3, Vec3};
use mcrad_mc_radiosity::{Method, ScheduleConfig, run};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use mcrad_scene_io::{Face, Light, Material, PointLight, Scene, Sun};
use std::ops::ControlFlow;

mod common;

/// The inside of a cube of side `side` centred at the origin, reflectance `rho`, no emission,
/// lit by `lights`.
fn cube(side: f32, rho: f32, lights: Vec<Light>) -> Scene {
    let wall = Material {
        name: "wall".into(),
        reflectance: Vec3::splat(rho),
        emission: Vec3::ZERO,
    };
    common::cube(side, wall, lights)
}

fn solve(method: Method, mesh: &Mesh, bvh: &Bvh, config: &ScheduleConfig) -> Vec<DVec3> {
    run(
        method,
        mesh,
        bvh,
        config,
        &mut |_| ControlFlow::Continue(()),
    )
    .unwrap_or_else(|e| panic!("{method}: {e}"))
    .estimate
    .radiosity()
    .to_vec()
}

fn area_mean(mesh: &Mesh, b: &[DVec3]) -> DVec3 {
    let total: f64 = mesh.patches().iter().map(|p| p.area).sum();
    mesh.patches()
        .iter()
        .zip(b)
        .map(|(p, b)| *b * p.area)
        .sum::<DVec3>()
        / total
}

#[test]
fn a_point_light_in_a_closed_cube_gives_the_closed_room_answer_in_every_method() {
    let (side, rho, intensity) = (4.0f32, 0.5f64, DVec3::new(10.0, 20.0, 5.0));
    let light = Light::Point(PointLight {
        position: Vec3::new(0.1, -0.05, 0.02),
        intensity,
        range: None,
    });
    let scene = cube(side, rho as f32, vec![light.clone()]);
    // Patch walls not aligned with the light's symmetry: 1-unit patches, 96 of them.
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(1.0)).unwrap();
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
    let phi = light.power().unwrap();
    let s = 6.0 * f64::from(side * side);
    let exact = phi * rho / (s * (1.0 - rho));
    let seeds = 4;
    for method in Method::ALL {
        let means: Vec<DVec3> = (0..seeds)
            .map(|seed| {
                let config = ScheduleConfig {
                    rays: 200_000,
                    seed,
                    lights: scene.lights().to_vec(),
                    ..Default::default()
                };
                area_mean(&mesh, &solve(method, &mesh, &bvh, &config))
            })
            .collect();
        let n = f64::from(seeds as u32);
        let mean = means.iter().sum::<DVec3>() / n;
        let var = means
            .iter()
            .map(|m| (*m - mean) * (*m - mean))
            .sum::<DVec3>()
            / (n - 1.0);
        let se = (var / n).map(f64::sqrt);
        for c in 0..3 {
            let tolerance = 4.0 * se[c] + 2e-3 * exact[c];
            assert!(
                (mean[c] - exact[c]).abs() <= tolerance,
                "{method}: channel {c}: mean {} exact {} (se {})",
                mean[c],
                exact[c],
                se[c]
            );
        }
    }
}

#[test]
fn the_sun_on_an_open_plane_gives_rho_e_sin_elevation() {
    // A delta sun: exact; the sun's disk: each of 256 points per patch (this budget) sees a
    // direction up to 0.265 degrees off, `n · w` off by `cot(elevation) sin(theta) cos(phi)`
    // of its mean, a relative standard deviation below `cot(30°) 0.0046 / sqrt(2) / 16 =
    // 3.5e-4` for the patch's mean: 4 of them.
    for (diameter, tolerance) in [(0.0, 1e-6), (0.53f64.to_radians(), 1.4e-3)] {
        sun_on_a_plane(diameter, tolerance);
    }
}

fn sun_on_a_plane(diameter: f64, tolerance: f64) {
    let elevation = 30f64.to_radians();
    let (rho, e) = (0.4f32, 800.0);
    let sun = Light::Sun(Sun {
        direction: Vec3::new(elevation.cos() as f32, 0.0, elevation.sin() as f32) * 3.0,
        irradiance: DVec3::splat(e),
        diameter,
    });
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
    let material = Material {
        name: "ground".into(),
        reflectance: Vec3::splat(rho),
        emission: Vec3::ZERO,
    };
    let scene = Scene::new_lit(positions, faces, vec![material], vec![sun])
        .unwrap()
        .0;
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.5)).unwrap();
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
    let exact = f64::from(rho) * e * elevation.sin();
    for method in [Method::Shoot, Method::Gather, Method::Combined] {
        let config = ScheduleConfig {
            rays: 100_000,
            lights: scene.lights().to_vec(),
            ..Default::default()
        };
        let b = solve(method, &mesh, &bvh, &config);
        for (i, b) in b.iter().enumerate() {
            assert!(
                (b.x - exact).abs() < tolerance * exact,
                "{method}: patch {i}: {} vs {exact}",
                b.x
            );
        }
    }
}

/// The closed cube of side 4 and reflectance 0.5 with a point light near its centre, meshed in
/// 1-unit patches, and its exact area-mean radiosity `rho Phi / (S (1 - rho))`.
fn point_lit_cube() -> (Scene, Mesh, Bvh, DVec3) {
    let (side, rho) = (4.0f32, 0.5f64);
    let light = Light::Point(PointLight {
        position: Vec3::new(0.1, -0.05, 0.02),
        intensity: DVec3::new(10.0, 20.0, 5.0),
        range: None,
    });
    let scene = cube(side, rho as f32, vec![light.clone()]);
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(1.0)).unwrap();
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
    let exact = light.power().unwrap() * rho / (6.0 * f64::from(side * side) * (1.0 - rho));
    (scene, mesh, bvh, exact)
}

#[test]
fn the_reference_solver_lights_the_closed_cube_deterministically() {
    // The reference's direct light is a closed form here (every wall patch wholly lit), its
    // closed cube conserving power exactly: the closed-room answer within 1e-6 (2.9e-8 seen), where a
    // Monte Carlo direct light of this budget would be off by its noise, and the same answer
    // for every seed.
    let (scene, mesh, bvh, exact) = point_lit_cube();
    let means: Vec<DVec3> = (0..2)
        .map(|seed| {
            let config = ScheduleConfig {
                rays: 10_000,
                seed,
                lights: scene.lights().to_vec(),
                ..Default::default()
            };
            area_mean(&mesh, &solve(Method::Reference, &mesh, &bvh, &config))
        })
        .collect();
    assert_eq!(means[0], means[1], "the reference depends on the seed");
    let error = ((means[0] - exact) / exact).abs().max_element();
    assert!(error < 1e-6, "{} vs {exact}: {error:.2e}", means[0]);
}

/// Under a time budget (`rays: u64::MAX`) a pass given no time for the lights casts 4 points a
/// patch (64 without [`ScheduleConfig::lights_seconds`]: on a 100k-element mesh with a sun and
/// a sky that was 37M shadow rays, most of a 10 s run); the first step of `combined` over 4
/// seeds still gives the closed cube's answer within 4 standard errors (+2e-3).
#[test]
fn a_time_budget_sizes_the_lights_pass_to_its_time() {
    let (scene, mesh, bvh, exact) = point_lit_cube();
    let first_step = |seed: u64, lights_seconds: Option<f64>| {
        let config = ScheduleConfig {
            rays: u64::MAX,
            seed,
            lights: scene.lights().to_vec(),
            lights_seconds,
            ..Default::default()
        };
        let mut seen = None;
        let _ = run(Method::Combined, &mesh, &bvh, &config, &mut |step| {
            seen = Some((step.rays, area_mean(&mesh, step.radiosity)));
            ControlFlow::Break(())
        });
        seen.expect("a first step")
    };
    let patches = mesh.patches().len() as u64;
    let (timed_rays, _) = first_step(0, Some(0.0));
    let (untimed_rays, _) = first_step(0, None);
    // the pass's own rays differ by 60 points a patch; the first pass's whole rays per patch
    // follow the lit emission, so its count moves by a few rays
    let saved = untimed_rays.abs_diff(timed_rays);
    assert!(
        saved.abs_diff((64 - 4) * patches) <= 64,
        "{saved} rays fewer, expected {}",
        (64 - 4) * patches
    );
    // With a ray budget too (`--rays N --time S`), the time still sizes the pass: a budget
    // that gives 256 points a patch alone (16² at 4 x 256 rays a patch) gives 4 under a time
    // of 0.
    let big = 4 * 256 * patches;
    let with_rays = |lights_seconds: Option<f64>| {
        let config = ScheduleConfig {
            rays: big,
            seed: 0,
            lights: scene.lights().to_vec(),
            lights_seconds,
            ..Default::default()
        };
        let mut seen = None;
        let _ = run(Method::Combined, &mesh, &bvh, &config, &mut |step| {
            seen = Some(step.rays);
            ControlFlow::Break(())
        });
        seen.expect("a first step")
    };
    // (the first pass's share of a finite budget moves by a few rays a patch with the pass's)
    let saved = with_rays(None).abs_diff(with_rays(Some(0.0)));
    assert!(
        saved.abs_diff((256 - 4) * patches) <= 8 * patches,
        "{saved} rays fewer, expected {}",
        (256 - 4) * patches
    );
    let means: Vec<DVec3> = (0..4).map(|seed| first_step(seed, Some(0.0)).1).collect();
    let mean = means.iter().sum::<DVec3>() / 4.0;
    let var = means
        .iter()
        .map(|m| (*m - mean) * (*m - mean))
        .sum::<DVec3>()
        / 3.0;
    for c in 0..3 {
        let tolerance = 4.0 * (var[c] / 4.0).sqrt() + 2e-3 * exact[c];
        assert!(
            (mean[c] - exact[c]).abs() <= tolerance,
            "channel {c}: mean {} exact {}",
            mean[c],
            exact[c]
        );
    }
}
