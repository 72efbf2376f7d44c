//! Watertightness is counted, not promised: obvhs's Möller-Trumbore test lets about one ray in
//! three million slip through a shared edge. Rays from inside closed, finely tessellated boxes
//! must (almost) never escape.

mod common;

use common::*;
use glam::{Mat3, Vec3, vec3};
use mcrad_raycast::{BruteForce, Bvh, Ray, RayCaster};
use rayon::prelude::*;

const RAYS: usize = 200_000;
/// Rays per seeded stream (one stream per chunk, so the rays do not depend on threads).
const CHUNK: usize = 5_000;
/// Allowed escapes: 1e-5 of the rays.
const MAX_MISSES: usize = RAYS / 100_000;

fn closed_boxes() -> Vec<(&'static str, Scene)> {
    let mut axis = Scene::default();
    axis.cuboid(
        vec3(2.0, 1.5, 2.5),
        vec3(2.0, 1.5, 2.5),
        Mat3::IDENTITY,
        false,
        32,
        true,
    );
    let mut rotated = Scene::default();
    let rot = Mat3::from_euler(glam::EulerRot::YXZ, 0.5, 0.3, 0.2);
    rotated.cuboid(
        vec3(-3.0, 7.0, 1.0),
        vec3(1.0, 2.0, 3.0),
        rot,
        false,
        32,
        true,
    );
    vec![("axis-aligned", axis), ("rotated", rotated)]
}

/// The rays among `RAYS` seeded ones that hit nothing.
fn escaping(bvh: &Bvh, seed: u64, make: impl Fn(&mut Rng) -> Ray + Send + Sync) -> Vec<Ray> {
    (0..(RAYS / CHUNK) as u64)
        .into_par_iter()
        .flat_map_iter(|chunk| {
            let mut rng = Rng::new(seed + chunk);
            (0..CHUNK).map(|_| make(&mut rng)).collect::<Vec<_>>()
        })
        .filter(|r| bvh.closest_hit(r).is_none())
        .collect()
}

#[test]
fn surface_rays_inside_closed_boxes_almost_never_escape() {
    for (name, s) in closed_boxes() {
        let bvh = Bvh::build(&s.tris, &s.ids).unwrap();
        let misses = escaping(&bvh, 1000, |rng| surface_ray(&s, Spot::Uniform, false, rng));
        assert!(
            misses.len() <= MAX_MISSES,
            "{name}: {} of {RAYS} rays escaped",
            misses.len()
        );
    }
}

#[test]
fn free_rays_inside_closed_boxes_almost_never_escape() {
    for (name, s) in closed_boxes() {
        let bvh = Bvh::build(&s.tris, &s.ids).unwrap();
        let (lo, hi) = bvh.bounds();
        let center = (lo + hi) * 0.5;
        let misses = escaping(&bvh, 2000, |rng| {
            // points near the centre: inside the box whatever its rotation
            let o = center + (Vec3::new(rng.f32(), rng.f32(), rng.f32()) - 0.5) * 0.5;
            let z = rng.range(-1.0, 1.0);
            let phi = rng.range(0.0, std::f32::consts::TAU);
            let r = (1.0 - z * z).sqrt();
            Ray::new(o, vec3(r * phi.cos(), r * phi.sin(), z))
        });
        assert!(
            misses.len() <= MAX_MISSES,
            "{name}: {} of {RAYS} rays escaped",
            misses.len()
        );
    }
}

#[test]
fn rays_from_edges_and_corners_escape_only_where_the_input_lets_them() {
    // An origin exactly on a rotated box's edge is rounded to f32 and may land outside the box:
    // some such rays escape even for the exact oracle. Every escape must be one of those, or a
    // query the oracle itself decides differently within half a surface offset.
    for (name, s) in closed_boxes() {
        let bvh = Bvh::build(&s.tris, &s.ids).unwrap();
        let oracle = BruteForce::build(&s.tris, &s.ids).unwrap();
        for (seed, spot) in [(3000, Spot::Edge), (4000, Spot::Corner)] {
            let misses = escaping(&bvh, seed, |rng| surface_ray(&s, spot, false, rng));
            let mut tally = Tally::default();
            for r in &misses {
                tally.add(judge(&oracle, r, None));
            }
            let what = format!("{name}, {spot:?}: {} escaped: {tally:?}", misses.len());
            assert!(
                tally.wrong.is_empty() && misses.len() <= RAYS / 1000,
                "{what}"
            );
        }
    }
}
