//! Clusters of small faces through the library's default solve: many tiny coplanar faces share
//! a few estimates of irradiance, each face keeps its own reflectance, and a cluster across a
//! shadow is split.

use glam::{DVec3, Vec3};
use mcrad_meshing::{
    ClusterBounds, Clusters, DEFAULT_CLUSTER_CONE_DEGREES, DEFAULT_COARSE_EDGE_FRACTION,
};
use mcrad_scene_io::{Face, Material, Scene};
use mcrad_solve::{Answer, Clustering, Problem, solve};
use std::f64::consts::PI;
use std::ops::ControlFlow;

fn go(_: &mcrad_solve::Progress) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

fn material(name: &str, reflectance: f32, emission: f32) -> Material {
    Material {
        name: name.to_string(),
        reflectance: Vec3::splat(reflectance),
        emission: Vec3::splat(emission),
    }
}

/// Emitted radiosity of the panel (W/m²), its half width (m) and height (m).
const PANEL: (f64, f64, f64) = (10.0, 5.0, 1.0);
/// Tiles: `N x N` squares of 2 cm (each two triangles) on `y = 0` around the origin.
const N: usize = 30;
const TILE: f32 = 0.02;

/// A black 10 m x 10 m panel 1 m above the floor, emitting [`PANEL`] downwards (material 0),
/// the floor's tiles of material `tile(i, j)` facing up, and, with `shadow`, a black plate 2 cm
/// above the tiles over `x < 0` facing up (its back absorbs what comes from below).
fn scene(tile: impl Fn(usize, usize) -> u32, shadow: bool) -> Scene {
    let mut positions = Vec::new();
    let mut faces = Vec::new();
    let mut face = |corners: &[Vec3], material: u32, positions: &mut Vec<Vec3>| {
        let first = positions.len() as u32;
        positions.extend_from_slice(corners);
        let source = faces.len() as u32;
        faces.push(Face {
            vertices: (first..first + corners.len() as u32).collect(),
            material,
            source,
        });
    };
    let (_, w, h) = PANEL;
    let (w, h) = (w as f32, h as f32);
    face(
        &[
            Vec3::new(-w, h, -w),
            Vec3::new(w, h, -w),
            Vec3::new(w, h, w),
            Vec3::new(-w, h, w),
        ],
        0,
        &mut positions,
    );
    if shadow {
        let y = 0.02;
        face(
            &[
                Vec3::new(-w, y, -w),
                Vec3::new(-w, y, w),
                Vec3::new(0.0, y, w),
                Vec3::new(0.0, y, -w),
            ],
            1,
            &mut positions,
        );
    }
    // tile corners shared by index, as an OBJ's are
    let first = positions.len() as u32;
    let x0 = -(N as f32) * TILE / 2.0;
    for j in 0..=N {
        for i in 0..=N {
            positions.push(Vec3::new(x0 + i as f32 * TILE, 0.0, x0 + j as f32 * TILE));
        }
    }
    let v = |i: usize, j: usize| first + (j * (N + 1) + i) as u32;
    for j in 0..N {
        for i in 0..N {
            let m = tile(i, j);
            // counter-clockwise seen from above (+y)
            for t in [
                [v(i, j), v(i, j + 1), v(i + 1, j + 1)],
                [v(i, j), v(i + 1, j + 1), v(i + 1, j)],
            ] {
                let source = faces.len() as u32;
                faces.push(Face {
                    vertices: t.to_vec(),
                    material: m,
                    source,
                });
            }
        }
    }
    let materials = vec![
        material("panel", 0.0, PANEL.0 as f32),
        material("black", 0.0, 0.0),
        material("dark", 0.3, 0.0),
        material("light", 0.6, 0.0),
    ];
    Scene::new(positions, faces, materials).unwrap().0
}

/// Irradiance (W/m²) at the point `(x, 0, z)` facing up from the panel: its exitance times the
/// form factor of a point to a parallel rectangle, summed over the rectangle's corners.
fn irradiance(x: f64, z: f64) -> f64 {
    let (e, w, h) = PANEL;
    let corner = |a: f64, b: f64| {
        let (a, b) = (a / h, b / h);
        let (ra, rb) = ((1.0 + a * a).sqrt(), (1.0 + b * b).sqrt());
        (a / ra * (b / ra).atan() + b / rb * (a / rb).atan()) / (2.0 * PI)
    };
    let f = corner(w - x, w - z) - corner(-w - x, w - z) - corner(w - x, -w - z)
        + corner(-w - x, -w - z);
    e * f
}

fn run(scene: &Scene, seed: u64, threads: usize) -> Answer {
    run_with(scene, seed, threads, Clustering::Transport)
}

fn run_with(scene: &Scene, seed: u64, threads: usize, clustering: Clustering) -> Answer {
    let mut problem = Problem::new(scene);
    problem.clustering = clustering;
    problem.settings.seed = seed;
    problem.budget.rays = Some(2_000_000);
    problem.threads = Some(threads);
    solve(&problem, &mut go).unwrap()
}

/// The tiles' patches of `answer` (material 2 or 3).
fn tiles(answer: &Answer) -> Vec<usize> {
    let p = answer.mesh.patches();
    (0..p.len()).filter(|&i| p[i].material >= 2).collect()
}

/// The checkerboard of [`tiny_coplanar_faces_share_few_estimates_each_with_its_own_reflectance`]
/// as one element of transport per group: the tiles' faces share few estimates, each face its
/// reflectance times its group's irradiance, which is within its standard errors of the exact
/// one (the transport's members' errors are one error: pooling them as independent would
/// report a standard error ten times too small).
#[test]
fn tiny_coplanar_faces_are_few_elements_of_transport_each_with_its_own_reflectance() {
    let scene = scene(|i, j| 2 + ((i + j) % 2) as u32, false);
    let mut zs = Vec::new();
    for seed in 0..4 {
        let answer = run(&scene, seed, 2);
        let stats = answer.stats.clusters.expect("clusters formed");
        let tiles = tiles(&answer);
        let transport = stats.transport_elements.expect("clusters as transport");
        // every tile in a group, few groups, few elements
        assert_eq!(stats.pooled_faces, tiles.len(), "{stats:?}");
        assert!(stats.groups * 20 <= tiles.len(), "{stats:?}");
        assert!(transport + tiles.len() <= answer.mesh.patches().len() + stats.groups);
        let (b, var) = (
            answer.estimate.radiosity(),
            answer.estimate.variance().unwrap(),
        );
        let p = answer.mesh.patches();
        // the groups: tiles of one irradiance B / rho (to rounding)
        let mut by_h: Vec<(f64, usize)> = tiles
            .iter()
            .map(|&i| (b[i].y / f64::from(p[i].reflectance.y), i))
            .collect();
        by_h.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut groups: Vec<Vec<usize>> = Vec::new();
        for (h, i) in by_h {
            match groups.last_mut() {
                Some(g)
                    if (b[g[0]].y / f64::from(p[g[0]].reflectance.y) - h).abs() <= 1e-12 * h =>
                {
                    g.push(i)
                }
                _ => groups.push(vec![i]),
            }
        }
        assert_eq!(groups.len(), stats.groups, "{stats:?}");
        for g in &groups {
            let (mut weight, mut exact) = (0.0, 0.0);
            for &i in g {
                let rho = f64::from(p[i].reflectance.y);
                let o = p[i].centroid.as_dvec3() + answer.mesh.origin().as_dvec3();
                weight += rho * p[i].area;
                exact += rho * p[i].area * irradiance(o.x, o.z);
                // the variance its reflectance squared times the shared one's
                let (rho0, r) = (f64::from(p[g[0]].reflectance.y), rho);
                let (vr, vh) = (var[i].y / (r * r), var[g[0]].y / (rho0 * rho0));
                assert!((vr - vh).abs() <= 1e-9 * vh);
            }
            exact /= weight;
            let rho0 = f64::from(p[g[0]].reflectance.y);
            let h = b[g[0]].y / rho0;
            zs.push((h - exact) / (var[g[0]].y.sqrt() / rho0));
        }
    }
    // the shared irradiances within their standard errors of the exact ones: each within 4.5,
    // and their mean square near 1 (about 70 groups: within 0.45 and 2)
    let mean_z2 = zs.iter().map(|z| z * z).sum::<f64>() / zs.len() as f64;
    assert!(zs.iter().all(|z| z.abs() < 4.5), "{zs:?}");
    assert!(
        (0.45..2.0).contains(&mean_z2),
        "mean z² {mean_z2} over {}",
        zs.len()
    );
}

#[test]
fn tiny_coplanar_faces_share_few_estimates_each_with_its_own_reflectance() {
    // 1,800 triangles of 2 cm in a checkerboard of reflectances 0.3 and 0.6 under the panel:
    // their irradiance is the panel's direct light alone (nothing else reflects), known in
    // closed form, and varies by 0.3% across them. Pooled after a transport per face.
    let scene = scene(|i, j| 2 + ((i + j) % 2) as u32, false);
    let cut = scene.bounds().diagonal() as f32 * DEFAULT_COARSE_EDGE_FRACTION;
    for seed in 0..3 {
        let answer = run_with(&scene, seed, 2, Clustering::Pool);
        let stats = answer.stats.clusters.expect("clusters formed");
        let tiles = tiles(&answer);
        assert_eq!(tiles.len(), 2 * N * N);
        // few elements for the tiles: every tile pooled, in groups of many
        assert_eq!(stats.pooled_faces, tiles.len(), "{stats:?}");
        assert!(stats.groups * 20 <= tiles.len(), "{stats:?}");
        assert_eq!(
            (stats.splits, stats.groups),
            (0, stats.clusters),
            "{stats:?}"
        );
        // the groups are the geometry's clusters
        let clusters = Clusters::build(
            &answer.mesh,
            ClusterBounds {
                max_size: cut,
                cone_degrees: DEFAULT_CLUSTER_CONE_DEGREES,
            },
        );
        assert_eq!(clusters.len(), stats.groups);
        let (b, var) = (
            answer.estimate.radiosity(),
            answer.estimate.variance().unwrap(),
        );
        let p = answer.mesh.patches();
        for c in clusters.iter() {
            let (mut weight, mut exact) = (0.0, 0.0);
            let mut reflectances = [false; 2];
            for &i in c {
                let q = &p[i as usize];
                let rho = f64::from(q.reflectance.x);
                reflectances[usize::from(rho > 0.5)] = true;
                weight += rho * q.area;
                let o = q.centroid.as_dvec3() + answer.mesh.origin().as_dvec3();
                exact += rho * q.area * irradiance(o.x, o.z);
            }
            exact /= weight;
            assert!(reflectances[0] && reflectances[1], "one reflectance only");
            let i0 = c[0] as usize;
            let rho0 = p[i0].reflectance.as_dvec3();
            let h = b[i0] / rho0;
            for &i in c {
                let i = i as usize;
                let rho = p[i].reflectance.as_dvec3();
                // each face's radiosity is its reflectance times the shared irradiance: the
                // ratio of two faces' radiosities is that of their reflectances, exactly
                let r = b[i] / rho;
                assert!(
                    (r - h).abs().max_element() <= 1e-12 * h.max_element(),
                    "{r} {h}"
                );
                // and its variance its reflectance squared times the shared one's
                let vr = var[i] / (rho * rho);
                let vh = var[i0] / (rho0 * rho0);
                assert!((vr - vh).abs().max_element() <= 1e-9 * vh.max_element());
            }
            // the shared irradiance within 4.5 of its standard errors of the exact one
            // (3 seeds x about 30 clusters x 3 channels)
            let se = (var[i0] / (rho0 * rho0)).powf(0.5);
            let z = (h - DVec3::splat(exact)).abs() / se;
            assert!(
                z.max_element() < 4.5,
                "seed {seed}: H {h} exact {exact} se {se}"
            );
        }
    }
}

#[test]
fn clusters_are_the_same_on_any_thread_count() {
    let scene = scene(|i, j| 2 + ((i + j) % 2) as u32, true);
    let (a, b) = (run(&scene, 7, 1), run(&scene, 7, 2));
    assert!(
        a.stats
            .clusters
            .is_some_and(|c| c.transport_elements.is_some())
    );
    assert_eq!(a.estimate, b.estimate);
    assert_eq!(a.stats.clusters, b.stats.clusters);
}

#[test]
fn a_cluster_across_a_shadow_is_split() {
    // The tiles of reflectance 0.6 with a black plate 2 cm above those at x < 0: a sharp
    // shadow across the clusters that straddle x = 0. Pooled whole, such a cluster would give
    // its shadowed tiles about half the light of the lit ones. Both ways: one element of
    // transport per group (split by the shadow rays before), and pooled after.
    let scene = scene(|_, _| 3, true);
    for (seed, clustering) in [
        (0, Clustering::Transport),
        (1, Clustering::Transport),
        (2, Clustering::Transport),
        (0, Clustering::Pool),
        (1, Clustering::Pool),
    ] {
        let answer = run_with(&scene, seed, 2, clustering);
        let stats = answer.stats.clusters.expect("clusters formed");
        let (b, p) = (answer.estimate.radiosity(), answer.mesh.patches());
        let x = |i: usize| f64::from(p[i].centroid.x + answer.mesh.origin().x);
        let tiles = tiles(&answer);
        let lit: Vec<f64> = tiles
            .iter()
            .filter(|&&i| x(i) > 0.1)
            .map(|&i| b[i].y)
            .collect();
        let lit = lit.iter().sum::<f64>() / lit.len() as f64;
        assert!(lit > 0.5 * 0.6 * PANEL.0, "lit tiles {lit}");
        for &i in tiles.iter().filter(|&&i| x(i) < -0.1) {
            assert!(
                b[i].y < 0.05 * lit,
                "seed {seed}: tile {i} at x {:.3} in the shadow has {} of the lit {lit}",
                x(i),
                b[i].y
            );
        }
        assert!(stats.splits > 0, "{stats:?}");
        assert!(stats.groups > 0, "{stats:?}");
    }
}

#[test]
fn every_method_solves_on_clusters_as_elements_of_transport() {
    // The checkerboard under the panel by every Monte Carlo method: each runs on the coarser
    // mesh (few elements for the tiles) and gives the tiles' mean irradiance, known in closed
    // form, within 5 of its standard errors (from the answer's variances: the members of a
    // group share one error) and 0.3% (the light's variation across a group), or within 3%
    // where a method reports no variance.
    let scene = scene(|i, j| 2 + ((i + j) % 2) as u32, false);
    for method in mcrad_mc_radiosity::Method::ALL {
        let mut problem = Problem::new(&scene);
        problem.settings.method = method;
        if problem.settings.deterministic() {
            continue;
        }
        problem.budget.rays = Some(400_000);
        problem.threads = Some(2);
        let answer = solve(&problem, &mut go).unwrap();
        let stats = answer.stats.clusters.expect("clusters formed");
        let transport = stats.transport_elements.expect("clusters as transport");
        assert!(
            transport * 2 < answer.mesh.patches().len(),
            "{method:?}: {stats:?}"
        );
        let (b, p) = (answer.estimate.radiosity(), answer.mesh.patches());
        let var = answer.estimate.variance();
        let (mut area, mut h, mut exact) = (0.0, 0.0, 0.0);
        // per group (one irradiance B / rho): its area and the variance of its irradiance
        let mut groups: Vec<(f64, f64, f64)> = Vec::new();
        for i in tiles(&answer) {
            let o = p[i].centroid.as_dvec3() + answer.mesh.origin().as_dvec3();
            assert!(
                b[i].is_finite() && b[i].min_element() >= 0.0,
                "{method:?}: {}",
                b[i]
            );
            let rho = f64::from(p[i].reflectance.y);
            let hi = b[i].y / rho;
            area += p[i].area;
            h += p[i].area * hi;
            exact += p[i].area * irradiance(o.x, o.z);
            let vi = var.map_or(0.0, |v| v[i].y / (rho * rho));
            match groups.iter_mut().find(|g| (g.0 - hi).abs() <= 1e-12 * hi) {
                Some(g) => g.1 += p[i].area,
                None => groups.push((hi, p[i].area, vi)),
            }
        }
        let (h, exact) = (h / area, exact / area);
        let se = groups
            .iter()
            .map(|(_, a, v)| (a / area).powi(2) * v)
            .sum::<f64>()
            .sqrt();
        let allowed = if var.is_some() {
            5.0 * se + 0.003 * exact
        } else {
            0.03 * exact
        };
        assert!(
            (h - exact).abs() < allowed,
            "{method:?}: mean irradiance {h}, exact {exact}, standard error {se}"
        );
    }
}

/// The tiles' area-weighted mean irradiance `B / rho` in `answer`, the exact one at their
/// centroids, and the standard error of the former from the answer's variances (the members
/// of a group share one irradiance, so one error).
fn mean_irradiance(answer: &Answer) -> (f64, f64, f64) {
    let (b, p) = (answer.estimate.radiosity(), answer.mesh.patches());
    let var = answer.estimate.variance().expect("a variance");
    let (mut area, mut h, mut exact) = (0.0, 0.0, 0.0);
    // per group (one irradiance B / rho): its irradiance, area and variance of its irradiance
    let mut groups: Vec<(f64, f64, f64)> = Vec::new();
    for i in tiles(answer) {
        let o = p[i].centroid.as_dvec3() + answer.mesh.origin().as_dvec3();
        let rho = f64::from(p[i].reflectance.y);
        let hi = b[i].y / rho;
        area += p[i].area;
        h += p[i].area * hi;
        exact += p[i].area * irradiance(o.x, o.z);
        match groups.iter_mut().find(|g| (g.0 - hi).abs() <= 1e-12 * hi) {
            Some(g) => g.1 += p[i].area,
            None => groups.push((hi, p[i].area, var[i].y / (rho * rho))),
        }
    }
    let se = groups
        .iter()
        .map(|(_, a, v)| (a / area).powi(2) * v)
        .sum::<f64>()
        .sqrt();
    (h / area, exact / area, se)
}

#[test]
fn shooting_pooled_after_the_transport_keeps_the_light_of_tiles_it_did_not_reach() {
    // The checkerboard under the panel, solved per patch and pooled after, by the shooting
    // methods: at 4e5 rays about half the tiles get no hit from the run and nearly all none
    // from the refinement's pilot. The run's estimate is pooled with the pilot's per face;
    // a pilot's 0 for an unreached tile is no information (it was taken as exact, with
    // variance 0, and the tiles kept a third of their light). The mean irradiance over the
    // tiles within 4.5 standard errors of the exact one (6 comparisons: a chance of 4e-5 that
    // a right answer fails, the reported variances of unreached tiles, one hit's, being if
    // anything too large), plus 0.3% (the light's variation across a group, whose shared
    // value weights its faces by reflectance). The standard error is that of about 1,300 hits
    // on the tiles (a Poisson count: 3%, more with the unreached tiles' one-hit variances):
    // below 5%, so that the test tells a third of the light from all of it.
    let scene = scene(|i, j| 2 + ((i + j) % 2) as u32, false);
    for method in ["shoot", "prr"] {
        for seed in 0..3 {
            let mut problem = Problem::new(&scene);
            problem.clustering = Clustering::Pool;
            problem.settings.method = method.parse().unwrap();
            problem.settings.seed = seed;
            problem.budget.rays = Some(400_000);
            problem.threads = Some(2);
            let answer = solve(&problem, &mut go).unwrap();
            let (h, exact, se) = mean_irradiance(&answer);
            assert!(
                se < 0.05 * exact,
                "{method} seed {seed}: standard error {se} of {exact}"
            );
            assert!(
                (h - exact).abs() < 4.5 * se + 0.003 * exact,
                "{method} seed {seed}: mean irradiance {h}, exact {exact}, standard error {se}"
            );
        }
    }
}

#[test]
fn an_observer_sees_each_step_per_patch_and_a_stop_keeps_the_answer_it_saw() {
    // The method runs on the coarser mesh of clusters; the observer reads a step per patch
    // of the mesh solved (carried from the elements when read), and a run stopped there
    // answers what the observer was shown.
    let scene = scene(|i, j| 2 + ((i + j) % 2) as u32, false);
    let mut problem = Problem::new(&scene);
    problem.settings.method = mcrad_mc_radiosity::Method::Prr;
    problem.budget.rays = Some(400_000);
    problem.threads = Some(2);
    let (mut steps, mut seen) = (0, None);
    let answer = solve(&problem, &mut |p| {
        steps += 1;
        assert_eq!(p.radiosity().unwrap().len(), p.mesh().patches().len());
        if steps < 3 {
            return ControlFlow::Continue(());
        }
        seen = Some(p.answer().unwrap());
        ControlFlow::Break(())
    })
    .unwrap();
    let transport = answer.stats.clusters.and_then(|c| c.transport_elements);
    assert!(transport.is_some_and(|t| t * 2 < answer.mesh.patches().len()));
    let seen = seen.expect("a third step");
    assert_eq!(answer.estimate.radiosity(), seen.radiosity());
    assert_eq!(answer.estimate.variance(), seen.variance());
}
