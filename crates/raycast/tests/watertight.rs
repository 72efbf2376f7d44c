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

/// A geodesic sphere: an icosahedron subdivided `levels` times (`20 * 4^levels` triangles,
/// shared vertices computed once, so neighbouring triangles share their edges exactly), facing
/// outwards, one id per triangle.
fn icosphere(center: Vec3, radius: f32, levels: u32) -> Scene {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut verts: Vec<Vec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| vec3(x, y, z).normalize())
    .collect();
    let mut faces: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut midpoints = std::collections::HashMap::new();
        let mut mid = |a: usize, b: usize, verts: &mut Vec<Vec3>| {
            *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
                verts.push(((verts[a] + verts[b]) * 0.5).normalize());
                verts.len() - 1
            })
        };
        faces = faces
            .iter()
            .flat_map(|&[a, b, c]| {
                let (ab, bc, ca) = (
                    mid(a, b, &mut verts),
                    mid(b, c, &mut verts),
                    mid(c, a, &mut verts),
                );
                [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
            })
            .collect();
    }
    let verts: Vec<Vec3> = verts.iter().map(|&v| center + v * radius).collect();
    let mut s = Scene::default();
    for f in faces {
        let id = s.new_id();
        s.tris.push(f.map(|i| verts[i]));
        s.ids.push(id);
    }
    s
}

#[test]
fn no_ray_slips_out_of_a_closed_sphere() {
    // 1M rays from inside a closed, finely tessellated sphere (5120 triangles, every edge
    // shared by two of them): from random interior points in random directions, and from
    // random points of the surface into the sphere.
    const SPHERE_RAYS: usize = 1_000_000;
    let s = icosphere(vec3(0.3, -0.2, 0.1), 2.0, 4);
    let bvh = Bvh::build(&s.tris, &s.ids).unwrap();
    let center = vec3(0.3, -0.2, 0.1);
    let unit = |rng: &mut Rng| {
        let z = rng.range(-1.0, 1.0);
        let phi = rng.range(0.0, std::f32::consts::TAU);
        let r = (1.0 - z * z).sqrt();
        vec3(r * phi.cos(), r * phi.sin(), z)
    };
    let escapes = |seed: u64, make: &(dyn Fn(&mut Rng) -> Ray + Sync)| {
        (0..(SPHERE_RAYS / 2 / CHUNK) as u64)
            .into_par_iter()
            .map(|chunk| {
                let mut rng = Rng::new(seed + chunk);
                (0..CHUNK)
                    .filter(|_| bvh.closest_hit(&make(&mut rng)).is_none())
                    .count()
            })
            .sum::<usize>()
    };
    let free = escapes(5000, &|rng| {
        let o = center + unit(rng) * 1.9 * rng.f32().cbrt();
        Ray::new(o, unit(rng))
    });
    let surface = escapes(6000, &|rng| {
        let i = rng.below(s.tris.len());
        let p = point_on(&s, i, Spot::Uniform, rng);
        // the inside is the back side: leave along minus the outward normal
        let n = -s.normal(i);
        Ray::from_surface(p, n, cosine_dir(n, rng), s.ids[i])
    });
    assert_eq!(
        (free, surface),
        (0, 0),
        "rays escaped (free, from the surface)"
    );
}
