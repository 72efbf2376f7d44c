//! The reference solver's direct light through a window in a vertical wall, against exact
//! answers: a convex room lit by a uniform sky ([`sky_irradiance`]) or a sun
//! ([`direct_irradiance`]) through it.
//!
//! The sky:
//! - Per patch: every point of the room sees the whole window or none of it (the room is a
//!   convex box), so `H_i = pi L F_i` exactly, `F_i` the patch's mean form factor to the window
//!   (Lambert's contour integral, [`point_polygon_form_factor`], averaged over the patch by a
//!   midpoint rule of 64 points per triangle: within 1.2e-3 of `F_i` against 1024 points).
//!   Measured: within `7.8e-4 pi L` of it (tolerance `1.5e-3 pi L`). Before the fix of the
//!   quadrature's probe, 8 patches far from the window were taken for closed: 0 where up to
//!   `0.015 pi L` was due.
//! - In all: the power the patches receive, `sum_i A_i H_i`, is what enters through the
//!   window, `pi L A_w` (the sky is the same along every direction that leaves the scene, so
//!   the window is lit by a radiance `L` over its whole outer hemisphere). Measured: `-4.7e-4`
//!   of it (tolerance `1e-3`; `-1.5e-2` before the fix).
//!
//! The sun: every ray of it that enters the window falls on the floor, so the floor receives
//! `E A_w cos` in all, `cos` between the sun's direction and the window's normal. Measured:
//! `+8.3e-5` of it (tolerance `2e-4`); `-1.9e-3` when a point's direction in the sun's cone was
//! drawn from the point's own sequence (the penumbra's integral biased).

use glam::{DVec3, Vec3};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_reference::{direct_irradiance, point_polygon_form_factor, sky_irradiance};
use mcrad_scene_io::{Face, Light, Material, Scene, Sky, Sun};
use std::f64::consts::PI;

/// The room: `[0, 4] x [0, 2.5] x [0, 3]` (y up), faces inward, its `x = 4` wall cut around
/// the window `z` in [`WINDOW_Z`], `y` in [`WINDOW_Y`].
const WINDOW_Z: [f32; 2] = [0.9, 2.1];
const WINDOW_Y: [f32; 2] = [0.8, 1.8];

/// The room of the module documentation lit by `lights` and `sky`, patches of at most
/// `max_edge`.
fn window_room(lights: Vec<Light>, sky: Option<Sky>, max_edge: f32) -> Mesh {
    let (w, h, d) = (4.0f32, 2.5f32, 3.0f32);
    let (mut positions, mut faces) = (Vec::new(), Vec::new());
    // the rectangle `p, p + u, p + u + v, p + v`, turned to face along `normal`
    let mut rect = |p: Vec3, u: Vec3, v: Vec3, normal: Vec3| {
        let base = positions.len() as u32;
        positions.extend([p, p + u, p + u + v, p + v]);
        let mut vertices: Vec<u32> = (base..base + 4).collect();
        if u.cross(v).dot(normal) < 0.0 {
            vertices.reverse();
        }
        let source = faces.len() as u32;
        faces.push(Face {
            vertices,
            material: 0,
            source,
        });
    };
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    rect(Vec3::ZERO, w * x, d * z, y);
    rect(h * y, w * x, d * z, -y);
    rect(Vec3::ZERO, d * z, h * y, x);
    rect(Vec3::ZERO, w * x, h * y, z);
    rect(d * z, w * x, h * y, -z);
    let ([z0, z1], [y0, y1]) = (WINDOW_Z, WINDOW_Y);
    let o = w * x;
    rect(o, d * z, y0 * y, -x);
    rect(o + y1 * y, d * z, (h - y1) * y, -x);
    rect(o + y0 * y, z0 * z, (y1 - y0) * y, -x);
    rect(o + y0 * y + z1 * z, (d - z1) * z, (y1 - y0) * y, -x);
    let grey = Material {
        name: "grey".into(),
        reflectance: Vec3::splat(0.5),
        emission: Vec3::ZERO,
    };
    let scene = Scene::new_lit_sky(positions, faces, vec![grey], lights, sky)
        .unwrap()
        .0;
    Mesh::build(&scene, Subdivision::MaxEdge(max_edge)).unwrap()
}

/// The window as a polygon in the mesh's frame.
fn window(mesh: &Mesh) -> Vec<DVec3> {
    let ([z0, z1], [y0, y1]) = (WINDOW_Z, WINDOW_Y);
    [(z0, y0), (z1, y0), (z1, y1), (z0, y1)]
        .iter()
        .map(|&(z, y)| (Vec3::new(4.0, y, z) - mesh.origin()).as_dvec3())
        .collect()
}

/// Patch `i`'s mean form factor to `window`: the midpoint rule on each triangle cut into 64
/// similar triangles.
fn form_factor(mesh: &Mesh, i: usize, window: &[DVec3]) -> f64 {
    let patch = &mesh.patches()[i];
    let n = patch.normal.as_dvec3();
    let p = mesh.positions();
    let k = 8;
    let (mut sum, mut area) = (0.0, 0.0);
    for t in mesh.patch_triangles(patch) {
        let [a, b, c] = t.map(|v| p[v as usize].as_dvec3());
        let small = 0.5 * (b - a).cross(c - a).length() / f64::from(k * k);
        let at = |s: f64, t: f64| a + (b - a) * (s / f64::from(k)) + (c - a) * (t / f64::from(k));
        for s in 0..k {
            for t in 0..k - s {
                let (s, t) = (f64::from(s), f64::from(t));
                // the upright small triangle, and the inverted one beside it
                let up = (at(s, t) + at(s + 1.0, t) + at(s, t + 1.0)) / 3.0;
                sum += point_polygon_form_factor(up, n, window) * small;
                area += small;
                if s + t + 2.0 <= f64::from(k) {
                    let down = (at(s + 1.0, t) + at(s, t + 1.0) + at(s + 1.0, t + 1.0)) / 3.0;
                    sum += point_polygon_form_factor(down, n, window) * small;
                    area += small;
                }
            }
        }
    }
    sum / area
}

#[test]
fn the_sky_through_a_wall_window_reaches_every_patch_that_sees_it() {
    let l = DVec3::new(20.0, 25.0, 35.0);
    let mesh = window_room(Vec::new(), Some(Sky::Uniform(l)), 0.5);
    let bvh = mesh.caster().unwrap();
    let d = sky_irradiance(&mesh, &bvh, &Sky::Uniform(l));
    let window = window(&mesh);
    let (mut power, mut worst) = (DVec3::ZERO, (0.0f64, 0usize));
    for (i, patch) in mesh.patches().iter().enumerate() {
        let exact = PI * form_factor(&mesh, i, &window) * l.y;
        let h = d.irradiance[i].y;
        power += d.irradiance[i] * patch.area;
        // relative to the window's irradiance scale pi L, so that patches lit at a grazing
        // angle count by what they receive
        let error = (h - exact).abs() / (PI * l.y);
        if error > worst.0 {
            worst = (error, i);
        }
        assert!(
            error <= 1.5e-3,
            "patch {i} at {}: H {h} exact {exact}",
            patch.centroid + mesh.origin()
        );
    }
    let a_window = f64::from((WINDOW_Z[1] - WINDOW_Z[0]) * (WINDOW_Y[1] - WINDOW_Y[0]));
    let exact = l * (PI * a_window);
    for c in 0..3 {
        assert!(
            (power[c] / exact[c] - 1.0).abs() <= 1e-3,
            "channel {c}: power {} exact {} (worst patch {worst:?})",
            power[c],
            exact[c]
        );
    }
}

#[test]
fn the_sun_through_a_wall_window_puts_e_a_cos_on_the_floor() {
    let (e, towards) = (300.0, Vec3::new(0.7, 0.6, 0.3).normalize());
    let sun = Light::Sun(Sun {
        direction: towards,
        irradiance: DVec3::splat(e),
        diameter: mcrad_scene_io::DEFAULT_SUN_DIAMETER,
    });
    let mesh = window_room(vec![sun.clone()], None, 0.5);
    let bvh = mesh.caster().unwrap();
    let d = direct_irradiance(&mesh, &bvh, &[sun]);
    let mut power = 0.0;
    for (h, patch) in d.irradiance.iter().zip(mesh.patches()) {
        power += h.x * patch.area;
        if patch.face != 0 {
            // the floor's corner of light touches the z = 0 wall: its penumbra may reach it
            assert!(h.x <= 1e-3 * e, "{h} at {}", patch.centroid + mesh.origin());
        }
    }
    let a_window = f64::from((WINDOW_Z[1] - WINDOW_Z[0]) * (WINDOW_Y[1] - WINDOW_Y[0]));
    let exact = e * a_window * f64::from(towards.x);
    assert!(
        (power / exact - 1.0).abs() <= 2e-4,
        "power {power} exact {exact} ({:+.2e})",
        power / exact - 1.0
    );
}
