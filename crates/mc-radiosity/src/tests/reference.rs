//! The deterministic reference solver against exact answers: analytic form factors, closed
//! boxes whose rows sum to 1, the closed furnace `B = E / (1 - ρ)`, and an occluded pair
//! against a Monte Carlo estimate with a known standard error.

use super::common;

use crate::SurfaceSampler;
use common::{box_faces, bvh, furnace, material, parallel_squares, quad};
use glam::{DVec3, Vec3};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_random::Stream;
use mcrad_raycast::RayCaster;
use mcrad_reference::{
    FormFactors, ReferenceConfig, ReferenceError, form_factors, point_polygon_form_factor,
    reference,
};
use mcrad_scene_io::Scene;

/// Parallel unit squares one unit apart, facing each other (Hottel's crossed-strings value).
const PARALLEL: f64 = 0.199_824_895_698_387_5;
/// Unit squares sharing an edge at a right angle.
const PERPENDICULAR: f64 = 0.200_043_776_075_403_2;

/// Form factors with the given quadrature and visibility tolerances.
fn factors_with(mesh: &Mesh, tolerance: f64, visibility_tolerance: f64) -> FormFactors {
    let config = ReferenceConfig {
        tolerance,
        visibility_tolerance,
        ..ReferenceConfig::default()
    };
    form_factors(mesh, &bvh(mesh), &config, &|_| {}).unwrap()
}

fn factors(mesh: &Mesh, tolerance: f64) -> FormFactors {
    factors_with(
        mesh,
        tolerance,
        ReferenceConfig::default().visibility_tolerance,
    )
}

/// Two unit squares sharing the edge `y = z = 0`: `z = 0` facing +z, `y = 0` facing +y.
fn perpendicular_squares() -> Scene {
    let positions = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(1.0, 0.0, 1.0),
    ];
    let faces = vec![quad([0, 1, 2, 3], 0, 0), quad([0, 4, 5, 1], 1, 1)];
    Scene::new(
        positions,
        faces,
        vec![material("lamp", 0.0, 1.0), material("grey", 0.5, 0.0)],
    )
    .unwrap()
    .0
}

#[test]
fn point_to_square_matches_the_closed_form() {
    // A point under the centre of a parallel unit square at distance 1: four corner
    // rectangles 0.5 x 0.5, each (X/√(1+X²) atan(Y/√(1+X²)) + Y/√(1+Y²) atan(X/√(1+Y²)))/2π.
    let x = 0.5f64;
    let s = (1.0 + x * x).sqrt();
    let exact = 4.0 * 2.0 * (x / s * (x / s).atan()) / std::f64::consts::TAU;
    let square = [
        DVec3::new(-0.5, -0.5, 1.0),
        DVec3::new(0.5, -0.5, 1.0),
        DVec3::new(0.5, 0.5, 1.0),
        DVec3::new(-0.5, 0.5, 1.0),
    ];
    let f = point_polygon_form_factor(DVec3::ZERO, DVec3::Z, &square);
    assert!((f - exact).abs() < 1e-14, "{f} vs {exact}");
    // Tilting the receiver's normal by 90 degrees about x keeps the half above its horizon.
    let tilted = point_polygon_form_factor(DVec3::ZERO, DVec3::Y, &square);
    assert!(tilted > 0.0 && tilted < f, "{tilted}");
}

#[test]
fn parallel_unit_squares_have_the_analytic_form_factor() {
    let mesh = Mesh::build(&parallel_squares(), Subdivision::None).unwrap();
    let f = factors(&mesh, 1e-4);
    for (i, j) in [(0, 1), (1, 0)] {
        let got = f.get(i, j);
        assert!((got - PARALLEL).abs() < 1e-4 * PARALLEL, "F_{i}{j} = {got}");
    }
    assert!(f.stats().max_quadrature_error <= 1e-4, "{:?}", f.stats());
    // Nothing between them: no shadow ray, no visibility error.
    assert_eq!((f.stats().occluded_pairs, f.stats().rays), (0, 0));
    assert_eq!(f.stats().max_visibility_error, 0.0);
    // Tighter tolerance, tighter answer: the error estimate is honest.
    let f = factors(&mesh, 1e-9);
    assert!((f.get(0, 1) - PARALLEL).abs() < 1e-9, "{}", f.get(0, 1));
}

#[test]
fn perpendicular_unit_squares_have_the_analytic_form_factor() {
    let mesh = Mesh::build(&perpendicular_squares(), Subdivision::None).unwrap();
    let f = factors(&mesh, 1e-4);
    for (i, j) in [(0, 1), (1, 0)] {
        let got = f.get(i, j);
        assert!(
            (got - PERPENDICULAR).abs() < 1e-4 * PERPENDICULAR,
            "F_{i}{j} = {got}"
        );
    }
    let f = factors(&mesh, 1e-9);
    assert!(
        (f.get(0, 1) - PERPENDICULAR).abs() < 1e-9,
        "{}",
        f.get(0, 1)
    );
}

#[test]
fn closed_cube_rows_sum_to_one_and_obey_reciprocity() {
    for subdivision in [Subdivision::None, Subdivision::MaxEdge(0.3)] {
        let mesh = Mesh::build(&furnace(0.5), subdivision).unwrap();
        let f = factors(&mesh, 1e-4);
        let patches = mesh.patches();
        for i in 0..patches.len() {
            let s = f.row_sum(i);
            assert!(
                (s - 1.0).abs() < 1e-4,
                "{subdivision:?}: row {i} sums to {s}"
            );
            let (cols, vals) = f.row(i);
            for (&j, &fij) in cols.iter().zip(vals) {
                let j = j as usize;
                assert_ne!(
                    patches[i].face, patches[j].face,
                    "coplanar patches exchange"
                );
                let (gij, gji) = (patches[i].area * fij, patches[j].area * f.get(j, i));
                assert!(
                    (gij - gji).abs() <= 1e-4 * gij.max(gji),
                    "{subdivision:?}: A_{i} F_{i}{j} = {gij}, A_{j} F_{j}{i} = {gji}"
                );
            }
        }
        assert!(f.stats().max_quadrature_error <= 1e-4, "{:?}", f.stats());
        assert_eq!(f.stats().rows_over_tolerance, 0);
    }
}

#[test]
fn closed_furnace_gives_e_over_one_minus_rho() {
    for rho in [0.5f32, 0.9] {
        for subdivision in [Subdivision::None, Subdivision::MaxEdge(0.5)] {
            let mesh = Mesh::build(&furnace(rho), subdivision).unwrap();
            let config = ReferenceConfig {
                tolerance: 1e-8,
                ..ReferenceConfig::default()
            };
            let r = reference(&mesh, &bvh(&mesh), &config, &|_| {}).unwrap();
            let exact = 1.0 / (1.0 - rho as f64);
            for (i, b) in r.estimate.radiosity().iter().enumerate() {
                assert!(
                    (*b - DVec3::splat(exact)).abs().max_element() < 1e-6 * exact,
                    "rho {rho}, {subdivision:?}: patch {i}: {b} vs {exact}"
                );
            }
            assert!(r.stats.residual <= 1e-9);
            assert!(r.estimate.variance().is_none());
        }
    }
}

#[test]
fn default_tolerance_furnace_is_within_its_error_budget() {
    // With the default row tolerance 1e-4, B = E / (1 - ρ S) is off by at most
    // ρ / (1 - ρ)² × 1e-4 relative to the row sums; here it must be far better than that.
    let mesh = Mesh::build(&furnace(0.9), Subdivision::MaxEdge(0.25)).unwrap();
    let r = reference(&mesh, &bvh(&mesh), &ReferenceConfig::default(), &|_| {}).unwrap();
    for b in r.estimate.radiosity() {
        assert!((b.x - 10.0).abs() < 9e-3, "{b}");
    }
}

/// The parallel squares with a blocker square `[0.3, 0.8] x [0.2, 0.7]` at `z = 0.5`,
/// facing down, so that it hides part of each square from the other.
fn blocked_squares() -> Scene {
    let mut scene_positions = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(1.0, 0.0, 1.0),
        Vec3::new(1.0, 1.0, 1.0),
        Vec3::new(0.0, 1.0, 1.0),
    ];
    scene_positions.extend([
        Vec3::new(0.3, 0.2, 0.5),
        Vec3::new(0.8, 0.2, 0.5),
        Vec3::new(0.8, 0.7, 0.5),
        Vec3::new(0.3, 0.7, 0.5),
    ]);
    let faces = vec![
        quad([0, 1, 2, 3], 0, 0),
        quad([4, 7, 6, 5], 0, 1),
        quad([8, 11, 10, 9], 0, 2),
    ];
    Scene::new(scene_positions, faces, vec![material("grey", 0.5, 1.0)])
        .unwrap()
        .0
}

/// Monte Carlo `F_ij`: the fraction of `n` cosine-distributed rays from uniform points of
/// patch `i` whose first hit is the front of patch `j`, and its standard error.
fn monte_carlo(mesh: &Mesh, caster: &impl RayCaster, i: usize, j: usize, n: u64) -> (f64, f64) {
    let sampler = SurfaceSampler::new(mesh);
    let mut rng = Stream::new(7, 0, i as u64, j as u64);
    let hits = (0..n)
        .filter(|_| {
            let ray = sampler.ray(i, &mut rng);
            matches!(caster.closest_hit(&ray), Some(h) if h.front && h.id == j as u32)
        })
        .count();
    let p = hits as f64 / n as f64;
    (p, (p * (1.0 - p) / n as f64).sqrt())
}

#[test]
fn occluded_pairs_agree_with_monte_carlo() {
    // Squares cut in 4 x 4, so that many pairs are partly hidden. Each compared value is
    // within 4.5 combined standard errors (Monte Carlo's and the reference's own estimate) plus
    // the quadrature tolerance: a false failure has probability below 7e-6 per value (normal
    // tail), 1e-4 over the 17 values.
    let mesh = Mesh::build(&blocked_squares(), Subdivision::MaxEdge(0.26)).unwrap();
    let caster = bvh(&mesh);
    let f = factors_with(&mesh, 1e-4, 1e-3);
    let stats = f.stats().clone();
    assert!(stats.occluded_pairs > 0 && stats.rays > 0, "{stats:?}");
    let patches = mesh.patches();
    let on = |face| -> Vec<usize> {
        (0..patches.len())
            .filter(|&k| patches[k].face == face)
            .collect()
    };
    let (bottom, top) = (on(0), on(1));
    assert_eq!((bottom.len(), top.len()), (16, 16));
    // Patch to the whole top face: the sum of a row over the top face's patches.
    let sampler = SurfaceSampler::new(&mesh);
    for &i in &bottom {
        let reference: f64 = top.iter().map(|&j| f.get(i, j)).sum();
        let mut rng = Stream::new(11, 0, i as u64, 0);
        let n = 400_000u64;
        let hits = (0..n)
            .filter(|_| {
                let ray = sampler.ray(i, &mut rng);
                matches!(
                    caster.closest_hit(&ray),
                    Some(h) if h.front && patches[h.id as usize].face == 1
                )
            })
            .count();
        let p = hits as f64 / n as f64;
        let se = (p * (1.0 - p) / n as f64).sqrt();
        let own = stats.max_visibility_error * f.row_sum(i);
        assert!(
            (reference - p).abs() <= 4.5 * (se * se + own * own).sqrt() + 1e-4,
            "patch {i}: reference {reference:.5} vs Monte Carlo {p:.5} ± {se:.1e} (own {own:.1e})"
        );
    }
    // One partly hidden pair of small patches, with many rays.
    let (i, j) = (bottom[5], top[6]);
    let (p, se) = monte_carlo(&mesh, &caster, i, j, 4_000_000);
    let got = f.get(i, j);
    let own = stats.max_visibility_error * f.row_sum(i);
    assert!(
        (got - p).abs() <= 4.5 * (se * se + own * own).sqrt() + 1e-4 * f.row_sum(i),
        "F_{i}{j}: reference {got:.6} vs Monte Carlo {p:.6} ± {se:.1e} (own {own:.1e})"
    );
}

/// The parallel squares with a large plate at `z = 0.5` over `x < 0.5`, facing down.
fn half_blocked_squares() -> Scene {
    let mut positions = parallel_squares().positions().to_vec();
    positions.extend([
        Vec3::new(-10.0, -10.0, 0.5),
        Vec3::new(-10.0, 11.0, 0.5),
        Vec3::new(0.5, 11.0, 0.5),
        Vec3::new(0.5, -10.0, 0.5),
    ]);
    let faces = vec![
        quad([0, 1, 2, 3], 0, 0),
        quad([4, 7, 6, 5], 0, 1),
        quad([8, 9, 10, 11], 0, 2),
    ];
    Scene::new(positions, faces, vec![material("grey", 0.5, 1.0)])
        .unwrap()
        .0
}

#[test]
fn a_half_plane_at_mid_height_hides_exactly_half() {
    // The segment from (x1, y1, 0) to (x2, y2, 1) is blocked when x1 + x2 < 1. Reflecting
    // both squares in x = 1/2 swaps blocked and unblocked segments and keeps the kernel, so
    // exactly half of the exchange is hidden: F_01 = PARALLEL / 2. Compared within 4.5 of the
    // estimated standard deviations (one value: a false failure rate below 7e-6).
    for subdivision in [Subdivision::None, Subdivision::MaxEdge(0.5)] {
        let mesh = Mesh::build(&half_blocked_squares(), subdivision).unwrap();
        let f = factors_with(&mesh, 1e-6, 1e-3);
        let patches = mesh.patches();
        let on = |face| (0..patches.len()).filter(move |&k| patches[k].face == face);
        let area: f64 = on(0).map(|i| patches[i].area).sum();
        let exchange: f64 = on(0)
            .flat_map(|i| on(1).map(move |j| (i, j)))
            .map(|(i, j)| patches[i].area * f.get(i, j))
            .sum();
        let got = exchange / area;
        let sigma = f.stats().max_visibility_error * PARALLEL / 2.0;
        assert!(sigma > 0.0 && sigma < 2e-3 * PARALLEL, "{:?}", f.stats());
        assert!(
            (got - PARALLEL / 2.0).abs() <= 4.5 * sigma + 1e-6,
            "{subdivision:?}: {got:.7} vs {:.7} (σ {sigma:.1e})",
            PARALLEL / 2.0
        );
    }
}

#[test]
fn hidden_and_back_facing_pairs_exchange_nothing() {
    // The blocker faces the bottom square; its back faces the top one, which it hides in part
    // from the bottom square.
    let mesh = Mesh::build(&blocked_squares(), Subdivision::None).unwrap();
    let f = factors(&mesh, 1e-4);
    assert!(f.get(0, 2) > 0.0 && f.get(2, 0) > 0.0);
    assert_eq!(f.get(2, 1), 0.0, "the top square is behind the blocker");
    assert_eq!(f.get(1, 2), 0.0, "the blocker's back faces the top square");
    assert!(f.get(0, 1) > 0.0 && f.get(0, 1) < PARALLEL - 0.01);
    // Two squares facing away from each other: nothing.
    let mut scene = parallel_squares();
    let mut faces = scene.faces().to_vec();
    faces[1].vertices.reverse();
    scene = Scene::new(
        scene.positions().to_vec(),
        faces,
        scene.materials().to_vec(),
    )
    .unwrap()
    .0;
    let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
    let f = factors(&mesh, 1e-4);
    assert_eq!((f.row_sum(0), f.row_sum(1)), (0.0, 0.0));
}

#[test]
fn same_answer_with_one_or_two_threads() {
    let mesh = Mesh::build(&blocked_squares(), Subdivision::MaxEdge(0.3)).unwrap();
    let caster = bvh(&mesh);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let config = ReferenceConfig {
                    visibility_tolerance: 1e-2,
                    ..ReferenceConfig::default()
                };
                form_factors(&mesh, &caster, &config, &|_| {}).unwrap()
            })
    };
    assert_eq!(run(1), run(2));
}

#[test]
fn progress_counts_every_row() {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let mesh = Mesh::build(&furnace(0.5), Subdivision::MaxEdge(0.5)).unwrap();
    let (calls, last) = (AtomicUsize::new(0), AtomicUsize::new(0));
    reference(&mesh, &bvh(&mesh), &ReferenceConfig::default(), &|done| {
        calls.fetch_add(1, Ordering::Relaxed);
        last.fetch_max(done, Ordering::Relaxed);
    })
    .unwrap();
    // Two passes over the rows, each counting half.
    assert_eq!(calls.into_inner(), 48);
    assert_eq!(last.into_inner(), 24);
}

#[test]
fn too_many_patches_is_refused_with_the_count_and_the_limit() {
    let mesh = Mesh::build(&furnace(0.5), Subdivision::MaxEdge(0.5)).unwrap();
    let config = ReferenceConfig {
        max_patches: 20,
        ..ReferenceConfig::default()
    };
    let err = reference(&mesh, &bvh(&mesh), &config, &|_| panic!("no work")).unwrap_err();
    assert_eq!(
        err,
        ReferenceError::TooManyPatches {
            patches: 24,
            limit: 20
        }
    );
    let message = err.to_string();
    assert!(
        message.contains("24 patches") && message.contains("limit of 20"),
        "{message}"
    );
}

#[test]
fn slow_convergence_is_an_error_not_a_wrong_answer() {
    let mesh = Mesh::build(&furnace(0.99), Subdivision::None).unwrap();
    let config = ReferenceConfig {
        max_iterations: 50,
        ..ReferenceConfig::default()
    };
    let err = reference(&mesh, &bvh(&mesh), &config, &|_| {}).unwrap_err();
    assert!(
        matches!(err, ReferenceError::NotConverged { iterations: 50, residual, .. } if residual > 1e-9),
        "{err}"
    );
    for value in [0.0, 1.0, f64::NAN] {
        for config in [
            ReferenceConfig {
                tolerance: value,
                ..ReferenceConfig::default()
            },
            ReferenceConfig {
                visibility_tolerance: value,
                ..ReferenceConfig::default()
            },
        ] {
            let err = reference(&mesh, &bvh(&mesh), &config, &|_| {}).unwrap_err();
            assert!(err.to_string().contains("tolerance"), "{err}");
        }
    }
}

/// `(I - diag(ρ) F) B = E` solved directly (Gaussian elimination; the matrix is diagonally
/// dominant, so without pivoting), one channel.
fn dense_solve(mesh: &Mesh, factors: &FormFactors, channel: usize) -> Vec<f64> {
    let n = mesh.patches().len();
    let mut a = vec![vec![0.0f64; n + 1]; n];
    for (i, (p, row)) in mesh.patches().iter().zip(&mut a).enumerate() {
        let rho = f64::from(p.reflectance[channel]);
        for (j, x) in row[..n].iter_mut().enumerate() {
            *x = -rho * factors.get(i, j);
        }
        row[i] += 1.0;
        row[n] = f64::from(p.emission[channel]);
    }
    for k in 0..n {
        let (above, below) = a.split_at_mut(k + 1);
        let pivot = &above[k];
        for row in below {
            let f = row[k] / pivot[k];
            if f != 0.0 {
                for (x, y) in row[k..].iter_mut().zip(&pivot[k..]) {
                    *x -= f * y;
                }
            }
        }
    }
    let mut b = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|j| a[i][j] * b[j]).sum();
        b[i] = (a[i][n] - s) / a[i][i];
    }
    b
}

#[test]
fn a_small_bright_light_leaves_no_dim_patch_short() {
    // A 1 x 1 x 6 tunnel of reflectance 0.5 lit by one 0.25 x 0.25 patch of one end: the far
    // end is about 1e-3 as bright as the light. Gauss-Seidel approaches the solution from
    // below, so a residual judged against the light's radiosity left the far end short by
    // about 1e-9 / 1e-3 of its own (a bias of the reference); judged against each patch's own
    // radiosity, every patch is within 1e-8 of the direct solve of the same system.
    let (mut positions, mut faces) = (Vec::new(), Vec::new());
    box_faces(1.0, &mut positions, &mut faces, [1, 0, 0, 0, 0, 0]);
    for p in &mut positions {
        p.z *= 6.0;
    }
    let materials = vec![material("grey", 0.5, 0.0), material("lamp", 0.5, 1.0)];
    let scene = Scene::new(positions, faces, materials).unwrap().0;
    let mut mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.25)).unwrap();
    // the end wall z = 0 (face 0) emits on its first patch only
    let end: Vec<usize> = (0..mesh.patches().len())
        .filter(|&i| mesh.patches()[i].face == 0)
        .collect();
    for &i in &end[1..] {
        mesh.set_emission(i, Vec3::ZERO);
    }
    let f = factors(&mesh, 1e-6);
    let solution = mcrad_reference::solve(&mesh, &f, 1e-9, 10_000).unwrap();
    let exact = dense_solve(&mesh, &f, 0);
    let dimmest = exact.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(dimmest < 2e-3 && dimmest > 0.0, "{dimmest}");
    let worst = solution
        .radiosity
        .iter()
        .zip(&exact)
        .map(|(b, x)| (b.x - x).abs() / x)
        .fold(0.0, f64::max);
    assert!(worst < 1e-8, "largest relative error {worst:e}");
    assert!(solution.residual <= 1e-9, "{}", solution.residual);
}
