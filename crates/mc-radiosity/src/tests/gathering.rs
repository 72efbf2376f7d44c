//! Tests of the gathering family: gathering rounds, Jacobi gathering, vertex gathering, direct
//! light, the two-pass split and the ambient term.
//!
//! Statistical tests run `RUNS` independent seeds and compare the mean with the exact value using
//! the standard error measured across the runs: `|mean - exact| <= K * s / sqrt(RUNS)`. With
//! `RUNS = 16` the statistic is Student-t with 15 degrees of freedom, `P(|t| > 4) = 1.2e-3` and
//! `P(|t| > 4.5) = 4.2e-4` per compared value; each test states how many values it compares, so
//! its false-failure rate is at most that many times the per-value rate. Comparisons of two
//! estimators use Welch's statistic (about 30 degrees of freedom: `P(|t| > 4.5) = 1e-4`). The
//! seeds are fixed, so a pass or a failure is reproducible.
//!
//! In a closed furnace a constant input makes every gathering ray score the same value, so
//! gathering is exact there, not just unbiased: those tests compare exactly, allowing only for
//! the rare ray that slips through a shared edge (counted by the estimators; it scores 0).

use crate::{
    Context, DirectSampling, Emission, Error, GatherConfig, ShootConfig, SplitConfig, StopReason,
    ambient, direct, gather, gather_corners, gather_round, mean_reflectance, shoot, two_pass_split,
    with_ambient,
};
use glam::{DVec3, Vec3};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_random::StreamKey;
use mcrad_scene_io::{Face, Material, Scene};
use std::ops::ControlFlow;

use super::common;
use common::{box_faces, bvh, furnace, material, mean_se};

const RUNS: u64 = 16;
const K: f64 = 4.5;

fn material_rgb(name: &str, rho: Vec3, e: f32) -> Material {
    Material {
        name: name.into(),
        reflectance: rho,
        emission: Vec3::splat(e),
    }
}

/// A closed cube lit by its floor, with walls of different colours.
fn lit_box() -> Scene {
    let (mut p, mut f) = (Vec::new(), Vec::new());
    box_faces(1.0, &mut p, &mut f, [0, 1, 1, 2, 3, 1]);
    let materials = vec![
        material("lamp", 0.3, 1.0),
        material("white", 0.7, 0.0),
        material_rgb("red", Vec3::new(0.65, 0.1, 0.1), 0.0),
        material_rgb("green", Vec3::new(0.15, 0.6, 0.1), 0.0),
    ];
    Scene::new(p, f, materials).unwrap().0
}

/// An open box (no y = 1 wall) lit by its floor, with an inner panel whose back faces the light.
fn open_box() -> Scene {
    let (mut p, mut f) = (Vec::new(), Vec::new());
    box_faces(1.0, &mut p, &mut f, [1, 0, 0, 0, 0, 0]);
    f.remove(3);
    let b = p.len() as u32;
    p.extend([
        Vec3::new(0.3, 0.2, 0.5),
        Vec3::new(0.7, 0.2, 0.5),
        Vec3::new(0.7, 0.6, 0.5),
        Vec3::new(0.3, 0.6, 0.5),
    ]);
    f.push(Face {
        vertices: vec![b, b + 1, b + 2, b + 3],
        material: 0,
        source: 6,
    });
    for (i, face) in f.iter_mut().enumerate() {
        face.source = i as u32;
    }
    Scene::new(
        p,
        f,
        vec![material("white", 0.7, 0.0), material("lamp", 0.3, 2.0)],
    )
    .unwrap()
    .0
}

/// An emitter (E = 1, rho = 0) and a receiver (rho = 0.5), both unit squares: facing each other
/// one unit apart (`parallel`, F = 0.199825) or sharing an edge at a right angle (F = 0.200044).
fn two_squares(parallel: bool) -> Mesh {
    let lamp = Face {
        vertices: vec![0, 1, 2, 3],
        material: 0,
        source: 0,
    }; // z = 0, faces +z
    let (positions, receiver) = if parallel {
        let mut p: Vec<Vec3> = (0..4)
            .map(|k| Vec3::new((k == 1 || k == 2) as u8 as f32, (k >= 2) as u8 as f32, 0.0))
            .collect();
        p.extend(p.clone().iter().map(|v| *v + Vec3::Z));
        (p, vec![4, 7, 6, 5]) // z = 1, faces -z
    } else {
        let mut p: Vec<Vec3> = (0..4)
            .map(|k| Vec3::new((k == 1 || k == 2) as u8 as f32, (k >= 2) as u8 as f32, 0.0))
            .collect();
        p.extend([Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0)]);
        (p, vec![0, 4, 5, 1]) // y = 0, faces +y
    };
    let faces = vec![
        lamp,
        Face {
            vertices: receiver,
            material: 1,
            source: 1,
        },
    ];
    let scene = Scene::new(
        positions,
        faces,
        vec![material("lamp", 0.0, 1.0), material("grey", 0.5, 0.0)],
    )
    .unwrap()
    .0;
    Mesh::build(&scene, Subdivision::None).unwrap()
}

/// Checks the mean over runs of `samples[run][k]` against `exact[k]` within K standard errors.
fn assert_within_k_se(samples: &[Vec<f64>], exact: &[f64], what: &str) {
    for (k, &x) in exact.iter().enumerate() {
        let column: Vec<f64> = samples.iter().map(|s| s[k]).collect();
        let (mean, se) = mean_se(&column);
        assert!(se > 0.0, "{what}: value {k} has no spread");
        assert!(
            (mean - x).abs() <= K * se,
            "{what}: value {k}: mean {mean:.6} vs exact {x:.6}, {:.2} standard errors ({se:.2e})",
            (mean - x).abs() / se
        );
    }
}

/// All channels of all patches, flattened.
fn flat(values: &[DVec3]) -> Vec<f64> {
    values.iter().flat_map(|v| v.to_array()).collect()
}

#[test]
fn one_round_from_the_exact_furnace_solution_reproduces_it() {
    // Exact, not statistical: every ray scores B (see the file's documentation).
    for rho in [0.5f32, 0.9] {
        let mesh = Mesh::build(&furnace(rho), Subdivision::MaxEdge(0.5)).unwrap();
        assert_eq!(mesh.patches().len(), 24);
        let bvh = bvh(&mesh);
        let ctx = Context::new(&mesh, &bvh);
        let b = 1.0 / (1.0 - rho as f64);
        let input = vec![DVec3::splat(b); 24];
        let n = 4000;
        for (emission, want) in [(Emission::Include, b), (Emission::Exclude, b - 1.0)] {
            let r = gather_round(&ctx, &input, emission, n, StreamKey::new(7)).unwrap();
            assert_eq!(r.back_face_hits, 0);
            assert_eq!(r.estimate.rays(), 24 * n as u64);
            assert!(r.escaped_rays as f64 <= 1e-5 * r.estimate.rays() as f64);
            let slack = r.escaped_rays as f64 * rho as f64 * b / n as f64 + 1e-12 * b;
            for (i, (v, var)) in r
                .estimate
                .radiosity()
                .iter()
                .zip(r.estimate.variance().unwrap())
                .enumerate()
            {
                assert!(
                    (*v - DVec3::splat(want)).abs().max_element() <= slack,
                    "rho {rho}, patch {i}: {v} vs {want}"
                );
                if r.escaped_rays == 0 {
                    assert_eq!(*var, DVec3::ZERO);
                }
            }
        }
    }
}

#[test]
fn jacobi_gathering_converges_to_the_furnace_answer() {
    // Round m of Jacobi in the furnace gives exactly B_m = (1 - rho^(m+1)) / (1 - rho); the run
    // stops at the first round whose change relative to the reflected light, rho^m / (B_m - E)
    // with E = 1, times the remainder factor max(1, rho / (1 - rho)), is below the threshold.
    for rho in [0.5f32, 0.9] {
        let mesh = Mesh::build(&furnace(rho), Subdivision::MaxEdge(0.5)).unwrap();
        let rho = rho as f64;
        let bvh = bvh(&mesh);
        let config = GatherConfig {
            rays: 10_000_000,
            rays_per_patch: 500,
            threshold: 1e-4,
            seed: 3,
        };
        let mut changes = Vec::new();
        let r = gather(&Context::new(&mesh, &bvh), &config, &mut |p| {
            changes.push(p.change);
            ControlFlow::Continue(())
        })
        .unwrap();
        assert_eq!(r.stats.stop, StopReason::Converged);
        let m = r.rounds as i32;
        let want_rounds = (1..)
            .find(|&m| {
                rho.powi(m) / ((rho - rho.powi(m + 1)) / (1.0 - rho)) * (rho / (1.0 - rho)).max(1.0)
                    <= 1e-4
            })
            .unwrap();
        assert_eq!(m, want_rounds, "rho {rho}");
        assert_eq!(changes.len(), m as usize);
        assert!(changes.windows(2).all(|w| w[1] < w[0]));
        assert_eq!(r.estimate.rays(), m as u64 * 24 * 500);
        let exact = 1.0 / (1.0 - rho);
        let b_m = (1.0 - rho.powi(m + 1)) / (1.0 - rho);
        // What the threshold promises: the missing bounces (rho/(1-rho) of the last change)
        // are at most the threshold relative to the reflected light.
        assert!(
            exact - b_m <= 1e-4 * (exact - 1.0),
            "rho {rho}: {b_m} vs {exact}"
        );
        // An escape lowers one round's value by rho B / n, and later rounds carry it on.
        let slack = r.stats.escaped_rays as f64 * exact / 500.0 / (1.0 - rho) + 1e-12;
        for v in r.estimate.radiosity() {
            assert!(
                (*v - DVec3::splat(b_m)).abs().max_element() <= slack,
                "rho {rho}: {v} vs {b_m}"
            );
        }
    }
}

#[test]
fn jacobi_gathering_agrees_with_shooting_in_a_lit_box() {
    // Welch's test on 24 patches x 3 channels = 72 values at K = 4.5: under 1% false failures.
    // 30 rounds leave (0.7)^30 = 2e-5 of the light uncounted, far below the standard errors.
    let mesh = Mesh::build(&lit_box(), Subdivision::MaxEdge(0.5)).unwrap();
    let bvh = bvh(&mesh);
    let n = 128;
    let (mut gathered, mut shot) = (Vec::new(), Vec::new());
    for seed in 0..RUNS {
        let config = GatherConfig {
            rays: 30 * 24 * n as u64,
            rays_per_patch: n,
            threshold: 0.0,
            seed,
        };
        let g = gather(&Context::new(&mesh, &bvh), &config, &mut |_| {
            ControlFlow::Continue(())
        })
        .unwrap();
        assert_eq!((g.rounds, g.stats.stop), (30, StopReason::BudgetSpent));
        gathered.push(flat(g.estimate.radiosity()));
        let s = ShootConfig {
            rays: 300_000,
            unshot_threshold: 1e-5,
            seed: 1000 + seed,
            ..Default::default()
        };
        let s = shoot(&Context::new(&mesh, &bvh), &s, &mut |_| {
            ControlFlow::Continue(())
        })
        .unwrap();
        shot.push(flat(s.estimate.radiosity()));
    }
    for k in 0..gathered[0].len() {
        let (a, sa) = mean_se(&gathered.iter().map(|s| s[k]).collect::<Vec<_>>());
        let (b, sb) = mean_se(&shot.iter().map(|s| s[k]).collect::<Vec<_>>());
        let se = (sa * sa + sb * sb).sqrt();
        assert!(
            (a - b).abs() <= K * se,
            "value {k}: gathered {a:.5} vs shot {b:.5} ({:.2} standard errors)",
            (a - b).abs() / se
        );
    }
}

#[test]
fn vertex_gathering_matches_patch_gathering_in_a_uniformly_lit_furnace() {
    // Exact (see the file's documentation). At the default crease angle a floor vertex gathers
    // about the floor's normal; at 90° the vertices on the box's edges and corners gather about
    // a diagonal normal, and their rays must see the walls they walk into (front faces, never a
    // back face or the outside).
    let rho = 0.5;
    let mesh = Mesh::build(&furnace(rho as f32), Subdivision::MaxEdge(0.25)).unwrap();
    let bvh = bvh(&mesh);
    let ctx = Context::new(&mesh, &bvh);
    let b = 1.0 / (1.0 - rho);
    let n = 2000;
    for crease in [30.0, 90.0] {
        let groups = mesh.corner_groups(crease);
        let input = vec![DVec3::splat(b); mesh.patches().len()];
        let v = gather_corners(
            &ctx,
            &groups,
            &input,
            Emission::Include,
            n,
            StreamKey::new(5),
        )
        .unwrap();
        assert_eq!(v.back_face_hits, 0, "crease {crease}");
        assert!(
            v.escaped_rays as f64 <= 1e-5 * v.rays as f64,
            "crease {crease}"
        );
        assert_eq!(v.radiosity.len(), mesh.corner_count());
        assert_eq!(v.rays, groups.len() as u64 * n as u64);
        let slack = v.escaped_rays as f64 * rho * b / n as f64 + 1e-12;
        for (c, x) in v.radiosity.iter().enumerate() {
            assert!(
                (*x - DVec3::splat(b)).abs().max_element() <= slack,
                "crease {crease}, corner {c}: {x}"
            );
        }
    }
    // The floor gathers from walls worth B, while the floor itself is worth 1000: a ray from a
    // floor vertex that hit the floor it starts on (or a coplanar neighbour) would show. Floor
    // vertices and floor patches must both see exactly B.
    let floor: Vec<bool> = mesh.patches().iter().map(|p| p.normal.z > 0.5).collect();
    let input: Vec<DVec3> = floor
        .iter()
        .map(|&f| DVec3::splat(if f { 1000.0 } else { b }))
        .collect();
    let groups = mesh.corner_groups(30.0);
    let v = gather_corners(
        &ctx,
        &groups,
        &input,
        Emission::Include,
        n,
        StreamKey::new(6),
    )
    .unwrap();
    let p = gather_round(&ctx, &input, Emission::Include, n, StreamKey::new(6)).unwrap();
    assert_eq!(v.back_face_hits + p.back_face_hits, 0);
    assert!((v.escaped_rays + p.escaped_rays) as f64 <= 1e-5 * (v.rays + p.estimate.rays()) as f64);
    let want = 1.0 + rho * b;
    let slack = (v.escaped_rays + p.escaped_rays) as f64 * rho * b / n as f64 + 1e-12;
    let mut floor_corners = 0;
    for (i, _) in mesh.patches().iter().enumerate().filter(|(i, _)| floor[*i]) {
        assert!(
            (p.estimate.radiosity()[i] - DVec3::splat(want))
                .abs()
                .max_element()
                <= slack
        );
        for c in mesh.corner_offset(i)..mesh.corner_offset(i + 1) {
            floor_corners += 1;
            assert!(
                (v.radiosity[c] - p.estimate.radiosity()[i])
                    .abs()
                    .max_element()
                    <= 2.0 * slack,
                "floor corner {c}: {} vs patch {i}: {}",
                v.radiosity[c],
                p.estimate.radiosity()[i]
            );
        }
    }
    assert_eq!(floor_corners, 16 * 4);
}

/// The form factor from a point to a parallel rectangle `a × b` at height `c`, with the normal
/// through one of the rectangle's corners.
fn point_to_corner_rectangle(a: f64, b: f64, c: f64) -> f64 {
    let (x, y) = (a / c, b / c);
    let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
    (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / (2.0 * std::f64::consts::PI)
}

#[test]
fn vertex_gathering_matches_the_analytic_point_form_factor() {
    // A floor (rho 0.5) under a parallel unit-square lamp at height 1, both cut 4 x 4. A floor
    // vertex at (u, v) gathers rho F(u, v) from the lamp (input 1); F splits into the four
    // rectangles of the lamp around the point above it. 25 floor vertices compared: 1%.
    let positions = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(0.0, 1.0, 1.0),
        Vec3::new(1.0, 1.0, 1.0),
        Vec3::new(1.0, 0.0, 1.0),
    ];
    let faces = vec![
        Face {
            vertices: vec![0, 1, 2, 3],
            material: 0,
            source: 0,
        },
        Face {
            vertices: vec![4, 5, 6, 7],
            material: 1,
            source: 1,
        },
    ];
    let scene = Scene::new(
        positions,
        faces,
        vec![material("floor", 0.5, 0.0), material("lamp", 0.0, 1.0)],
    )
    .unwrap()
    .0;
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.25)).unwrap();
    let bvh = bvh(&mesh);
    let ctx = Context::new(&mesh, &bvh);
    let groups = mesh.corner_groups(30.0);
    let input: Vec<DVec3> = mesh
        .patches()
        .iter()
        .map(|p| p.emission.as_dvec3())
        .collect();
    let floor_groups: Vec<usize> = (0..groups.len())
        .filter(|&g| groups.point(g).z == 0.0)
        .collect();
    assert_eq!(floor_groups.len(), 25);
    // One corner of each floor group.
    let corner_of: Vec<usize> = floor_groups
        .iter()
        .map(|&g| {
            (0..mesh.corner_count())
                .find(|&c| groups.group_of(c) == g)
                .unwrap()
        })
        .collect();
    let exact: Vec<f64> = floor_groups
        .iter()
        .map(|&g| {
            let p = groups.point(g).as_dvec3();
            let (u, v) = (p.x, p.y);
            0.5 * [(u, v), (1.0 - u, v), (u, 1.0 - v), (1.0 - u, 1.0 - v)]
                .iter()
                .map(|&(a, b)| point_to_corner_rectangle(a, b, 1.0))
                .sum::<f64>()
        })
        .collect();
    let samples: Vec<Vec<f64>> = (0..RUNS)
        .map(|seed| {
            let v = gather_corners(
                &ctx,
                &groups,
                &input,
                Emission::Exclude,
                20_000,
                StreamKey::new(seed),
            )
            .unwrap();
            corner_of.iter().map(|&c| v.radiosity[c].x).collect()
        })
        .collect();
    assert_within_k_se(&samples, &exact, "floor vertices under a lamp");
}

#[test]
fn one_round_from_a_unit_emitter_gives_the_analytic_form_factors() {
    // Input: the lamp's radiosity 1, the receiver's 0; the receiver gathers rho F. One value per
    // scene: 0.04% false failures each.
    for (parallel, f) in [(true, 0.199825), (false, 0.200044)] {
        let mesh = two_squares(parallel);
        let bvh = bvh(&mesh);
        let ctx = Context::new(&mesh, &bvh);
        let input = [DVec3::ONE, DVec3::ZERO];
        let samples: Vec<Vec<f64>> = (0..RUNS)
            .map(|seed| {
                let r = gather_round(
                    &ctx,
                    &input,
                    Emission::Exclude,
                    100_000,
                    StreamKey::new(seed),
                )
                .unwrap();
                assert_eq!(r.estimate.radiosity()[0], DVec3::ZERO);
                vec![r.estimate.radiosity()[1].x]
            })
            .collect();
        assert_within_k_se(&samples, &[0.5 * f], "gathered form factor");
    }
}

#[test]
fn direct_light_gives_the_analytic_form_factors() {
    // rho F E for the receiver, 0 for the lamp (rho 0). Three statistical comparisons: 0.13%.
    let cases = [
        (true, 0.199825, DirectSampling::Emitters),
        (true, 0.199825, DirectSampling::EmittersAndCosine),
        (false, 0.200044, DirectSampling::EmittersAndCosine),
    ];
    for (parallel, f, sampling) in cases {
        let mesh = two_squares(parallel);
        let bvh = bvh(&mesh);
        let ctx = Context::new(&mesh, &bvh);
        let samples: Vec<Vec<f64>> = (0..RUNS)
            .map(|seed| {
                let d = direct(&ctx, 50_000, sampling, StreamKey::new(seed)).unwrap();
                assert_eq!(d.estimate.radiosity()[0], DVec3::ZERO);
                assert_eq!(d.occluded, 0);
                vec![d.estimate.radiosity()[1].x]
            })
            .collect();
        assert_within_k_se(&samples, &[0.5 * f], &format!("direct {sampling:?}"));
    }
    // Emitter sampling next to a perpendicular emitter has infinite variance (see `direct`):
    // Student-t does not apply and the error falls like n^(-1/3). With these fixed seeds the
    // mean of 16 runs of 1e6 samples is 0.12% off; allow 1%.
    let mesh = two_squares(false);
    let bvh = bvh(&mesh);
    let ctx = Context::new(&mesh, &bvh);
    let mean = (0..RUNS)
        .map(|seed| {
            direct(
                &ctx,
                1_000_000,
                DirectSampling::Emitters,
                StreamKey::new(seed),
            )
            .unwrap()
            .estimate
            .radiosity()[1]
                .x
        })
        .sum::<f64>()
        / RUNS as f64;
    assert!((mean / (0.5 * 0.200044) - 1.0).abs() < 0.01, "{mean}");
}

/// The average over patches of (spread of the estimates over runs) / (mean estimated variance),
/// over patches where either is positive.
fn variance_ratio(values: &[Vec<f64>], variances: &[Vec<f64>]) -> (f64, usize) {
    let (mut sum, mut count) = (0.0, 0);
    for k in 0..values[0].len() {
        let column: Vec<f64> = values.iter().map(|s| s[k]).collect();
        let (_, se) = mean_se(&column);
        let spread = se * se * RUNS as f64;
        let estimated = variances.iter().map(|s| s[k]).sum::<f64>() / RUNS as f64;
        if spread > 0.0 || estimated > 0.0 {
            sum += spread / estimated;
            count += 1;
        }
    }
    (sum / count as f64, count)
}

#[test]
fn estimated_variances_agree_with_the_spread_over_seeds() {
    // Per patch, the spread of 16 runs has a relative standard deviation of sqrt(2/15) = 0.37;
    // averaged over ~100 patch-channels the ratio's standard deviation is about 0.04, so the
    // band 0.7..1.4 is more than 7 standard deviations wide on either side.
    let mesh = Mesh::build(&open_box(), Subdivision::MaxEdge(0.25)).unwrap();
    let bvh = bvh(&mesh);
    let ctx = Context::new(&mesh, &bvh);
    let input: Vec<DVec3> = mesh
        .patches()
        .iter()
        .enumerate()
        .map(|(i, p)| p.emission.as_dvec3() + DVec3::new(0.1, 0.2, 0.3) * (i % 5) as f64)
        .collect();
    let groups = mesh.corner_groups(30.0);
    type Run = (Vec<f64>, Vec<f64>);
    let estimators: [(&str, &dyn Fn(u64) -> Run); 3] = [
        ("gather_round", &|seed| {
            let r =
                gather_round(&ctx, &input, Emission::Include, 32, StreamKey::new(seed)).unwrap();
            (
                flat(r.estimate.radiosity()),
                flat(r.estimate.variance().unwrap()),
            )
        }),
        ("gather_corners", &|seed| {
            let r = gather_corners(
                &ctx,
                &groups,
                &input,
                Emission::Include,
                32,
                StreamKey::new(seed),
            )
            .unwrap();
            (flat(&r.radiosity), flat(&r.variance))
        }),
        ("direct", &|seed| {
            let r = direct(
                &ctx,
                32,
                DirectSampling::EmittersAndCosine,
                StreamKey::new(seed),
            )
            .unwrap();
            (
                flat(r.estimate.radiosity()),
                flat(r.estimate.variance().unwrap()),
            )
        }),
    ];
    for (name, run) in estimators {
        let (values, variances): (Vec<_>, Vec<_>) = (0..RUNS).map(run).unzip();
        let (ratio, count) = variance_ratio(&values, &variances);
        assert!(count >= 50, "{name}: only {count} noisy values");
        assert!(
            (0.7..=1.4).contains(&ratio),
            "{name}: spread / estimated variance = {ratio:.3} over {count} values"
        );
    }
}

#[test]
fn two_pass_split_from_the_exact_furnace_solution_is_unbiased() {
    // Indirect light is exact here (constant input); the direct part is random. 24 patches:
    // 1% false failures.
    let rho = 0.5;
    let mesh = Mesh::build(&furnace(rho as f32), Subdivision::MaxEdge(0.5)).unwrap();
    let bvh = bvh(&mesh);
    let ctx = Context::new(&mesh, &bvh);
    let b = 1.0 / (1.0 - rho);
    let shooting = vec![DVec3::splat(b); 24];
    let config = SplitConfig {
        rays_per_patch: 64,
        samples_per_patch: 2000,
        sampling: DirectSampling::EmittersAndCosine,
    };
    let samples: Vec<Vec<f64>> = (0..RUNS)
        .map(|seed| {
            let e = two_pass_split(&ctx, &exact(&shooting), &config, StreamKey::new(seed)).unwrap();
            e.radiosity().iter().map(|v| v.x).collect()
        })
        .collect();
    assert_within_k_se(&samples, &[b; 24], "two-pass split");
}

#[test]
fn same_seed_same_answer_with_one_or_two_threads() {
    let mesh = Mesh::build(&open_box(), Subdivision::MaxEdge(0.2)).unwrap();
    let bvh = bvh(&mesh);
    let ctx = Context::new(&mesh, &bvh);
    let groups = mesh.corner_groups(30.0);
    let input: Vec<DVec3> = (0..mesh.patches().len())
        .map(|i| DVec3::new(1.0, 0.5, 0.25) * (1 + i % 3) as f64)
        .collect();
    // More rays than one job, so that chunks are merged.
    let n = 5000;
    let run = |seed: u64| {
        let round = gather_round(
            &ctx,
            &input,
            Emission::Include,
            n,
            StreamKey::new(seed).pass(2),
        )
        .unwrap();
        let config = GatherConfig {
            rays: 3 * mesh.patches().len() as u64 * 64,
            rays_per_patch: 64,
            threshold: 0.0,
            seed,
        };
        let jacobi = gather(&Context::new(&mesh, &bvh), &config, &mut |_| {
            ControlFlow::Continue(())
        })
        .unwrap()
        .estimate;
        let corners = gather_corners(
            &ctx,
            &groups,
            &input,
            Emission::Exclude,
            n,
            StreamKey::new(seed).pass(2),
        )
        .unwrap();
        let direct = direct(
            &ctx,
            n,
            DirectSampling::EmittersAndCosine,
            StreamKey::new(seed).pass(2),
        )
        .unwrap();
        let split = SplitConfig {
            rays_per_patch: 64,
            samples_per_patch: 64,
            sampling: DirectSampling::Emitters,
        };
        let split =
            two_pass_split(&ctx, &exact(&input), &split, StreamKey::new(seed).pass(2)).unwrap();
        (round, jacobi, corners, direct, split)
    };
    let solve = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| run(42))
    };
    let (one, two) = (solve(1), solve(2));
    assert_eq!(one, two);
    let other = run(43);
    assert_ne!(one.0, other.0);
    assert_ne!(one.1, other.1);
    assert_ne!(one.2, other.2);
    assert_ne!(one.3, other.3);
    assert_ne!(one.4, other.4);
}

#[test]
fn the_ambient_term_restores_the_furnace_mean() {
    // After the first wave in a furnace of reflectance rho, the unshot power is rho times the
    // emitted power (half of it at rho = 0.5). The ambient term must put back exactly what the
    // rest of the run would add: the area-weighted mean becomes E/(1 - rho) to rounding, apart
    // from the power of rays that slipped through an edge. Per patch the expectation is exact
    // too: 24 patches x 2 reflectances compared, 2% false failures.
    for (rho, waves) in [(0.5f32, 1), (0.9, 3)] {
        let mesh = Mesh::build(&furnace(rho), Subdivision::MaxEdge(0.5)).unwrap();
        let rho = rho as f64;
        let bvh = bvh(&mesh);
        let exact = 1.0 / (1.0 - rho);
        assert!(
            (mean_reflectance(&mesh) - DVec3::splat(rho))
                .abs()
                .max_element()
                < 1e-7
        );
        let samples: Vec<Vec<f64>> = (0..RUNS)
            .map(|seed| {
                let config = ShootConfig {
                    rays: 100_000,
                    unshot_threshold: 0.0,
                    seed,
                    ..Default::default()
                };
                let s = shoot(&Context::new(&mesh, &bvh), &config, &mut |p| {
                    if p.waves == waves {
                        ControlFlow::Break(())
                    } else {
                        ControlFlow::Continue(())
                    }
                })
                .unwrap();
                let unshot_fraction = s.stats.unshot.x / s.stats.emitted.x;
                let expected = rho.powi(waves as i32);
                assert!(
                    (unshot_fraction - expected).abs() < 1e-3,
                    "{unshot_fraction}"
                );
                let a = ambient(&mesh, &s.unshot, s.stats.escape_fraction()).unwrap();
                let b = with_ambient(&mesh, &s.estimate, a).unwrap();
                assert_eq!(b.variance(), s.estimate.variance());
                let area = mesh.total_area();
                let mean: f64 = b
                    .radiosity()
                    .iter()
                    .zip(mesh.patches())
                    .map(|(v, p)| v.x * p.area)
                    .sum::<f64>()
                    / area;
                let leaked = s.stats.escaped.x / area / (1.0 - rho);
                assert!(
                    (mean - exact).abs() <= leaked + 1e-9,
                    "rho {rho}: mean {mean} vs {exact}"
                );
                // Without the term the solution is far too dark.
                let before: f64 = s
                    .estimate
                    .radiosity()
                    .iter()
                    .zip(mesh.patches())
                    .map(|(v, p)| v.x * p.area)
                    .sum::<f64>()
                    / area;
                assert!(before < exact * (1.0 - 0.5 * rho * expected));
                b.radiosity().iter().map(|v| v.x).collect()
            })
            .collect();
        assert_within_k_se(&samples, &[exact; 24], "ambient");
    }
}

#[test]
fn gather_stops_on_budget_and_observer() {
    let mesh = Mesh::build(&furnace(0.9), Subdivision::None).unwrap();
    let bvh = bvh(&mesh);
    let config = GatherConfig {
        rays: 6 * 100 * 3 + 599,
        rays_per_patch: 100,
        threshold: 0.0,
        seed: 1,
    };
    let r = gather(&Context::new(&mesh, &bvh), &config, &mut |_| {
        ControlFlow::Continue(())
    })
    .unwrap();
    assert_eq!((r.rounds, r.stats.stop), (3, StopReason::BudgetSpent));
    assert_eq!(r.stats.rays, 1800);
    let r = gather(
        &Context::new(&mesh, &bvh),
        &GatherConfig {
            rays: 1_000_000,
            ..config
        },
        &mut |p| {
            if p.rounds == 2 {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        },
    )
    .unwrap();
    assert_eq!((r.rounds, r.stats.stop), (2, StopReason::Stopped));
}

#[test]
fn bad_inputs_are_errors() {
    let mesh = Mesh::build(&furnace(0.5), Subdivision::None).unwrap();
    let bvh = bvh(&mesh);
    let ctx = Context::new(&mesh, &bvh);
    let good = vec![DVec3::ONE; 6];
    let round = |input: &[DVec3], n| {
        gather_round(&ctx, input, Emission::Include, n, StreamKey::new(0)).map(|_| ())
    };
    assert_eq!(
        round(&good[..5], 10),
        Err(Error::InputLength { patches: 6, got: 5 })
    );
    let mut nan = good.clone();
    nan[3].y = f64::NAN;
    assert!(matches!(
        round(&nan, 10),
        Err(Error::NotFinite { patch: 3, .. })
    ));
    assert_eq!(round(&good, 1), Err(Error::TooFewRays(1)));
    let other = Mesh::build(&furnace(0.5), Subdivision::MaxEdge(0.5)).unwrap();
    let e = gather_corners(
        &ctx,
        &other.corner_groups(30.0),
        &good,
        Emission::Include,
        10,
        StreamKey::new(0),
    )
    .unwrap_err();
    assert!(e.to_string().contains("corner groups"), "{e}");
    let go = |c: GatherConfig| {
        gather(&Context::new(&mesh, &bvh), &c, &mut |_| {
            ControlFlow::Continue(())
        })
        .map(|_| ())
        .unwrap_err()
        .to_string()
    };
    assert!(
        go(GatherConfig {
            rays: 10,
            ..Default::default()
        })
        .contains("one round")
    );
    assert!(
        go(GatherConfig {
            threshold: -1.0,
            ..Default::default()
        })
        .contains(">= 0")
    );
    assert!(
        direct(&ctx, 0, DirectSampling::Emitters, StreamKey::new(0))
            .unwrap_err()
            .to_string()
            .contains("at least 2")
    );
    assert!(ambient(&mesh, &good[..2], DVec3::ZERO).is_err());
    assert!(ambient(&mesh, &[DVec3::NEG_ONE; 6], DVec3::ZERO).is_err());
    assert!(ambient(&mesh, &good, DVec3::splat(1.5)).is_err());
    assert!(ambient(&mesh, &good, DVec3::splat(f64::NAN)).is_err());
}

/// `values` as an estimate without noise (zero variance, no rays).
fn exact(values: &[DVec3]) -> mcrad_combine::Estimate {
    mcrad_combine::Estimate::new(values.to_vec(), Some(vec![DVec3::ZERO; values.len()]), 0).unwrap()
}

/// A closed unit box of reflectance `rho` whose floor alone emits 1 W/m²: the total power
/// `sum_i B_i A_i` is exactly `1 / (1 - rho)` W (every watt is reflected until absorbed).
fn lit_floor_furnace(rho: f32) -> Scene {
    let (mut p, mut f) = (Vec::new(), Vec::new());
    box_faces(1.0, &mut p, &mut f, [1, 0, 0, 0, 0, 0]);
    Scene::new(
        p,
        f,
        vec![material("wall", rho, 0.0), material("lamp", rho, 1.0)],
    )
    .unwrap()
    .0
}

fn gather_method(mesh: &Mesh, rays: u64, seed: u64) -> crate::Solution {
    use crate::{Method, ScheduleConfig, run};
    let config = ScheduleConfig {
        rays,
        seed,
        ..Default::default()
    };
    run(Method::Gather, mesh, &bvh(mesh), &config, &mut |_| {
        ControlFlow::Continue(())
    })
    .unwrap()
}

#[test]
fn jacobi_gathering_sums_the_whole_series_at_high_reflectance() {
    // Issue 16: the `gather` method cut the Jacobi series after ten rounds (rays per patch =
    // budget / 10), -89.5% at rho 0.99. Its rounds now follow the reflectance. Statistic: the
    // total power of 8 seeds against the exact `1 / (1 - rho)` within 5 standard errors
    // (Student-t, 7 dof: P(|t| > 5) = 1.6e-3 per value, 2 values: false-failure rate 0.3%).
    let area = 1.0;
    for rho in [0.9f32, 0.99] {
        let mesh = Mesh::build(&lit_floor_furnace(rho), Subdivision::None).unwrap();
        let powers: Vec<f64> = (0..8)
            .map(|seed| {
                let s = gather_method(&mesh, 400_000, seed);
                s.estimate.radiosity().iter().map(|b| b.x * area).sum()
            })
            .collect();
        let (mean, se) = mean_se(&powers);
        let exact = 1.0 / (1.0 - rho as f64);
        assert!(se > 0.0, "rho {rho}: no spread");
        assert!(
            (mean - exact).abs() <= 5.0 * se,
            "rho {rho}: power {mean:.4} vs exact {exact:.4} ({:.1} standard errors, se {se:.2e})",
            (mean - exact).abs() / se
        );
    }
}

#[test]
fn jacobi_gathering_does_not_stop_on_rounds_that_saw_no_light() {
    // Issue 16: in a room lit by a tiny light, a first round in which no ray reached the light
    // changed nothing and counted as converged: `B = E` after one round. A 1 cm² lamp under the
    // ceiling of a closed unit box of 600 patches, 8 seeds (deterministic: no false failures).
    let (mut p, mut f) = (Vec::new(), Vec::new());
    box_faces(1.0, &mut p, &mut f, [0; 6]);
    let base = p.len() as u32;
    for (x, y) in [
        (0.495, 0.495),
        (0.495, 0.505),
        (0.505, 0.505),
        (0.505, 0.495),
    ] {
        p.push(Vec3::new(x, y, 0.99));
    }
    // Counter-clockwise seen from below: it shines down.
    f.push(Face {
        vertices: vec![base, base + 1, base + 2, base + 3],
        material: 1,
        source: 6,
    });
    let scene = Scene::new(
        p,
        f,
        vec![material("wall", 0.5, 0.0), material("lamp", 0.0, 1.0)],
    )
    .unwrap()
    .0;
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.1)).unwrap();
    for seed in 0..8 {
        let s = gather_method(&mesh, 60_000, seed);
        assert!(
            s.steps > 1,
            "seed {seed}: stopped after {} round(s), {:?}",
            s.steps,
            s.stop
        );
    }
}
