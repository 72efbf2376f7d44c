//! Issue 16: a scene far from the origin. Geometry is stored in `f32`, so a unit furnace moved
//! 1e7 from the origin had points 1 scene unit apart once subdivided: shooting panicked
//! (`NotFinite`) and at 1e6 the answer was 66% off. Meshes are now stored relative to their
//! local origin (`Mesh::origin`), so the furnace at 1e7 is the furnace at the origin, bit for
//! bit, for every method; one moved by a non-round offset agrees within noise (stated below).

use super::common;

use crate::Error;
use crate::{Method, ScheduleConfig, run};
use common::{box_faces, material};
use glam::{DVec3, Vec3};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use mcrad_scene_io::Scene;
use std::ops::ControlFlow;

fn furnace_at(offset: f32) -> Mesh {
    let (mut p, mut f) = (Vec::new(), Vec::new());
    box_faces(1.0, &mut p, &mut f, [0; 6]);
    for v in &mut p {
        *v += Vec3::splat(offset);
    }
    let scene = Scene::new(p, f, vec![material("furnace", 0.5, 1.0)])
        .unwrap()
        .0;
    Mesh::build(&scene, Subdivision::MaxEdge(0.25)).unwrap()
}

fn solve_all(method: Method, mesh: &Mesh, seed: u64) -> Result<Vec<DVec3>, Error> {
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
    let config = ScheduleConfig {
        rays: 20_000,
        seed,
        ..Default::default()
    };
    let s = run(method, mesh, &bvh, &config, &mut |_| {
        ControlFlow::Continue(())
    })?;
    Ok(s.estimate.radiosity().to_vec())
}

fn solve(method: Method, mesh: &Mesh, seed: u64) -> Result<f64, Error> {
    let b = solve_all(method, mesh, seed)?;
    Ok(b.iter().map(|b| b.x).sum::<f64>() / b.len() as f64)
}

#[test]
fn far_from_the_origin_every_method_gives_the_origins_answer_bit_for_bit() {
    // The unit furnace at 1e6 and 1e7 (coordinates exact in f32 there) has its local origin
    // on the box's corner, as at the origin: same local mesh, same rays, same answer.
    let near = furnace_at(0.0);
    assert_eq!(near.origin(), Vec3::ZERO);
    for offset in [1e6f32, 1e7] {
        let far = furnace_at(offset);
        assert_eq!(far.origin(), Vec3::splat(offset), "at {offset}");
        assert_eq!(far.positions(), near.positions(), "at {offset}");
        for method in Method::ALL {
            let a = solve_all(method, &near, 1).unwrap();
            let b = solve_all(method, &far, 1).unwrap_or_else(|e| panic!("{method:?}: {e}"));
            assert_eq!(a, b, "{method:?} at {offset}");
            // and it is the furnace's answer, B = E / (1 - rho) = 2, within 10%
            let mean = b.iter().map(|b| b.x).sum::<f64>() / b.len() as f64;
            assert!((mean - 2.0).abs() < 0.2, "{method:?} at {offset}: {mean}");
        }
    }
}

#[test]
fn a_non_round_offset_gives_the_origins_answer_within_noise() {
    // 1234567.75 from the origin (f32 spacing 0.125 there, coordinates exact) the local frame
    // is the box moved by a quarter unit, so rays differ in rounding from the origin's: the
    // mean radiosity of 8 seeds per method at the offset and at 0 agree within 5 standard
    // errors of their difference (about 14 dof: P(|t| > 5) < 2e-4 per method, 1e-3 for the
    // five; the false-failure rate).
    let (near, far) = (furnace_at(0.0), furnace_at(1_234_567.8));
    assert!(far.origin().x > 1e6);
    let local = far.positions().iter().map(|p| p.abs().max_element());
    assert!(local.fold(0.0, f32::max) <= 1.0);
    for method in [
        Method::Shoot,
        Method::Prr,
        Method::Gather,
        Method::Bidirectional,
        Method::Combined,
    ] {
        let a: Vec<f64> = (0..8).map(|s| solve(method, &near, s).unwrap()).collect();
        let b: Vec<f64> = (0..8).map(|s| solve(method, &far, s).unwrap()).collect();
        let mv = |x: &[f64]| {
            let m = x.iter().sum::<f64>() / 8.0;
            (
                m,
                x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / 7.0 / 8.0,
            )
        };
        let ((ma, va), (mb, vb)) = (mv(&a), mv(&b));
        // (gathering in a furnace of uniform E and rho is exact at every round: no spread,
        // so the two must agree to rounding)
        assert!(
            (ma - mb).abs() <= 5.0 * (va + vb).sqrt() + 1e-12 * ma.abs(),
            "{method:?}: {ma} vs {mb} (se {})",
            (va + vb).sqrt()
        );
    }
}

#[test]
fn a_patch_no_ray_reached_reports_no_information() {
    // Issue 16: a patch no ray reached came back as B = 0 with variance 0 (z infinite). A
    // 1 mm² patch (reflectance 0.5, no emission) 1 cm above the floor of the unit furnace
    // (rho 0.5, E = 1) faces up at walls of B = 2, so its exact B is about 1 W/m²; at 2e4 rays
    // about 0.003 hits are expected, so no ray reaches it (fixed seeds: deterministic).
    let (mut p, mut f) = (Vec::new(), Vec::new());
    box_faces(1.0, &mut p, &mut f, [0; 6]);
    let base = p.len() as u32;
    for (x, y) in [(0.5, 0.5), (0.501, 0.5), (0.501, 0.501), (0.5, 0.501)] {
        p.push(Vec3::new(x, y, 0.01));
    }
    f.push(common::quad([base, base + 1, base + 2, base + 3], 1, 6));
    let scene = Scene::new(
        p,
        f,
        vec![material("furnace", 0.5, 1.0), material("speck", 0.5, 0.0)],
    )
    .unwrap()
    .0;
    let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
    let speck = mesh.patches().len() - 1;
    for method in [Method::Shoot, Method::Prr, Method::Bidirectional] {
        for seed in 0..4 {
            let config = ScheduleConfig {
                rays: 20_000,
                seed,
                ..Default::default()
            };
            let s = run(method, &mesh, &bvh, &config, &mut |_| {
                ControlFlow::Continue(())
            })
            .unwrap();
            let b = s.estimate.radiosity()[speck].x;
            let v = s.estimate.variance().unwrap()[speck].x;
            let z = (b - 1.0) / v.sqrt();
            assert!(
                v > 0.0 && z.is_finite(),
                "{method:?} seed {seed}: B {b} var {v}"
            );
        }
    }
}
