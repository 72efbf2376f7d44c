//! Scene-level tests of the renderer: auto-framing, determinism, flat against smooth shading.

use std::f64::consts::PI;
use std::path::Path;
use std::sync::Mutex;

use glam::{DVec3, Vec2, Vec3};
use mcrad_meshing::{CornerValues, Mesh, Subdivision};
use mcrad_raycast::{Bvh, RayCaster};

use super::*;

fn load(path: &Path, subdivision: Subdivision) -> (Mesh, Bvh) {
    let scene = mcrad_scene_io::load(path).unwrap().scene;
    let mesh = Mesh::build(&scene, subdivision).unwrap();
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
    (mesh, bvh)
}

fn scene(name: &str, subdivision: Subdivision) -> (Mesh, Bvh) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    load(&root.join(name), subdivision)
}

/// A 2 × 1 emitting quad in the plane z = 0 facing +z, emitted radiosity (3, 2, 1) W/m².
fn lamp(subdivision: Subdivision) -> (Mesh, Bvh) {
    lamp_at(0.0, subdivision)
}

/// [`lamp`] moved by `x` along the x axis.
fn lamp_at(x: f64, subdivision: Subdivision) -> (Mesh, Bvh) {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("l.mtl"),
        "newmtl lamp\nKd 0.5 0.5 0.5\nKe 3 2 1\n",
    )
    .unwrap();
    let (a, b) = (x, x + 2.0);
    let obj = format!(
        "mtllib l.mtl\nv {a} 0 0\nv {b} 0 0\nv {b} 1 0\nv {a} 1 0\nusemtl lamp\nf 1 2 3 4\n"
    );
    std::fs::write(dir.path().join("l.obj"), obj).unwrap();
    load(&dir.path().join("l.obj"), subdivision)
}

/// Per-corner values `f(position of the corner)`, in global corner order.
fn per_corner(mesh: &Mesh, f: impl Fn(Vec3) -> DVec3) -> CornerValues {
    CornerValues::per_corner(
        mesh.patches()
            .iter()
            .flat_map(|p| {
                mesh.corners(p)
                    .iter()
                    .map(|&v| f(mesh.positions()[v as usize]))
            })
            .collect(),
    )
}

fn settings(width: u32, height: u32, samples_per_pixel: u32) -> RenderSettings {
    RenderSettings {
        width,
        height,
        samples_per_pixel,
        sky: None,
        lights: Vec::new(),
        sky_rays: 0,
        gather_rays: 0,
    }
}

fn no_progress(_: usize) {}

/// A camera on the lamp's axis at `z` (in front of it for `z > 0`), looking at its centre
/// `(1, 0.5, 0)`, with a vertical field of view of `fov` degrees.
fn facing_lamp(z: f32, fov: f32) -> Camera {
    Camera::look_at(
        Vec3::new(1.0, 0.5, z),
        Vec3::new(1.0, 0.5, 0.0),
        Vec3::Y,
        fov,
    )
    .unwrap()
}

/// An 8 x 4 sky map bright above the horizon, (4, 5, 6) W/(m² sr), and dim below, 0.5.
fn half_bright_map() -> mcrad_scene_io::SkyMap {
    let (w, h) = (8u32, 4u32);
    let texels = (0..w * h)
        .map(|k| {
            if k / w < h / 2 {
                [4.0, 5.0, 6.0]
            } else {
                [0.5, 0.5, 0.5]
            }
        })
        .collect();
    mcrad_scene_io::SkyMap::new(w, h, texels, 0.0).unwrap()
}

#[test]
fn cornell_box_is_framed_from_its_open_side() {
    let (mesh, bvh) = scene("cornell-box.obj", Subdivision::None);
    let camera = Camera::frame_scene(&mesh, &bvh).unwrap();
    assert!((camera.forward() - Vec3::Z).length() < 1e-6, "{:?}", camera);
    assert!((camera.up() - Vec3::Y).length() < 1e-6, "{:?}", camera);
    assert!(
        camera.eye().z < -0.5,
        "eye outside the open side: {}",
        camera.eye()
    );
    assert_eq!(camera.fov_y_degrees(), FRAME_FOV_Y_DEGREES);
    // the whole box is in view: every corner of the open side projects into the image
    for &(x, y) in &[(0.0, 0.0), (0.556, 0.0), (0.0, 0.5488), (0.556, 0.5488)] {
        let p = camera.project(Vec3::new(x, y, 0.0), 100, 100);
        assert!(p.is_some(), "({x}, {y}) out of view");
    }
    // red wall (x = 0.55) on the left, as in the photographs
    let left = camera
        .project(Vec3::new(0.55, 0.27, 0.3), 100, 100)
        .unwrap();
    assert!(left.x < 50.0, "{left}");
}

#[test]
fn a_wall_is_framed_from_its_front() {
    let (mesh, bvh) = lamp(Subdivision::None);
    let camera = Camera::frame_scene(&mesh, &bvh).unwrap();
    assert!(
        (camera.forward() - Vec3::NEG_Z).length() < 1e-6,
        "{:?}",
        camera
    );
    assert!(camera.eye().z > 0.0);
}

#[test]
fn closed_room_is_framed_from_inside() {
    let (mesh, bvh) = scene("furnace.obj", Subdivision::None);
    let camera = Camera::frame_scene(&mesh, &bvh).unwrap();
    assert_eq!(camera.fov_y_degrees(), INSIDE_FOV_Y_DEGREES);
    assert!(
        (camera.eye() - Vec3::new(0.5, 0.5, 0.1)).length() < 1e-6,
        "{:?}",
        camera
    );
    assert!((camera.forward() - Vec3::Z).length() < 1e-6);
    // and from there it sees the walls' fronts
    let ray = camera.ray(Vec2::new(8.0, 8.0), 16, 16);
    assert!(bvh.closest_hit(&ray).unwrap().front);
}

#[test]
fn render_is_the_same_on_one_and_two_threads() {
    let (mesh, bvh) = scene("cornell-box.obj", Subdivision::MaxEdge(0.1));
    let camera = Camera::frame_scene(&mesh, &bvh).unwrap();
    // distinct values per patch, so that any mix-up shows
    let b: Vec<DVec3> = (0..mesh.patches().len())
        .map(|i| DVec3::new(i as f64, (i * 7 % 13) as f64, 1.0 / (1.0 + i as f64)))
        .collect();
    let corners = per_corner(&mesh, |p| p.as_dvec3() * 10.0);
    for (shading, spp, gather) in [
        (Shading::Flat(&b), 4, 0),
        (Shading::Smooth(&corners), 3, 0),
        (Shading::Flat(&b), 2, 3),
    ] {
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                render(
                    &mesh,
                    &bvh,
                    &camera,
                    shading,
                    &RenderSettings {
                        gather_rays: gather,
                        ..settings(61, 47, spp)
                    },
                    &no_progress,
                )
            })
            .unwrap()
        };
        let (one, two) = (run(1), run(2));
        assert!(
            one.pixels
                .iter()
                .zip(&two.pixels)
                .all(|(a, b)| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits))
        );
        assert!(one.pixels.iter().any(|p| *p != Vec3::ZERO));
    }
}

#[test]
fn constant_radiosity_renders_the_same_with_flat_and_smooth_shading() {
    let (mesh, bvh) = scene("cornell-box.obj", Subdivision::MaxEdge(0.1));
    let camera = Camera::frame_scene(&mesh, &bvh).unwrap();
    let c = DVec3::new(1.5, 2.5, 4.0);
    let flat = vec![c; mesh.patches().len()];
    let smooth = per_corner(&mesh, |_| c);
    let s = settings(40, 30, 4);
    let a = render(&mesh, &bvh, &camera, Shading::Flat(&flat), &s, &no_progress).unwrap();
    let b = render(
        &mesh,
        &bvh,
        &camera,
        Shading::Smooth(&smooth),
        &s,
        &no_progress,
    )
    .unwrap();
    let l = (c / PI).as_vec3();
    let mut lit = 0;
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        assert!(
            (*p - *q).abs().max_element() <= 1e-6 * l.max_element(),
            "{p} vs {q}"
        );
        if *p != Vec3::ZERO {
            lit += 1;
        }
    }
    // the centre sees the back wall fully
    assert!(
        (a.get(20, 15).unwrap() - l).abs().max_element() < 1e-6,
        "{}",
        a.get(20, 15).unwrap()
    );
    assert!(lit > 40 * 30 / 2, "{lit}");
}

#[test]
fn a_uniformly_lit_wall_shows_e_over_pi() {
    let (mesh, bvh) = lamp(Subdivision::MaxEdge(0.3));
    let camera = facing_lamp(3.0, 15.0);
    let e: Vec<DVec3> = mesh
        .patches()
        .iter()
        .map(|p| p.emission.as_dvec3())
        .collect();
    let corners = per_corner(&mesh, |_| DVec3::new(3.0, 2.0, 1.0));
    let expected = Vec3::new(3.0, 2.0, 1.0) / std::f32::consts::PI;
    for shading in [Shading::Flat(&e), Shading::Smooth(&corners)] {
        let image = render(
            &mesh,
            &bvh,
            &camera,
            shading,
            &settings(16, 16, 9),
            &no_progress,
        )
        .unwrap();
        for p in &image.pixels {
            assert!((*p - expected).abs().max_element() < 1e-6, "{p}");
        }
    }
}

#[test]
fn a_scene_far_from_the_origin_renders_as_at_the_origin() {
    // Issue 16: the lamp 1e7 along x (exact in f32) seen by the same camera moved with it, the
    // camera translated into the mesh's local frame: the image is the origin's, bit for bit.
    let view = |x: f64| {
        let (mesh, bvh) = lamp_at(x, Subdivision::MaxEdge(0.3));
        // (coordinates exact in f32 at 1e7, where f32 values are 1 apart)
        let eye = Vec3::new((x + 1.0) as f32, 0.25, 3.0);
        let look = Vec3::new((x + 1.0) as f32, 0.5, 0.0);
        let camera = Camera::look_at(eye, look, Vec3::Y, 25.0)
            .unwrap()
            .translated(mesh.origin().as_dvec3());
        let corners = per_corner(&mesh, |p| DVec3::new(1.0 + p.x as f64, 2.0, 3.0));
        let image = render(
            &mesh,
            &bvh,
            &camera,
            Shading::Smooth(&corners),
            &settings(24, 16, 4),
            &no_progress,
        )
        .unwrap();
        (mesh.origin(), image.pixels)
    };
    let (near_origin, near) = view(0.0);
    let (far_origin, far) = view(1e7);
    assert_eq!(near_origin, Vec3::ZERO);
    assert_eq!(far_origin, Vec3::new(1e7, 0.0, 0.0));
    assert!(near.iter().any(|p| p.max_element() > 0.0));
    assert_eq!(near, far);
}

#[test]
fn smooth_shading_interpolates_a_linear_field_exactly() {
    let (mesh, bvh) = lamp(Subdivision::MaxEdge(0.3));
    let camera = Camera::look_at(
        Vec3::new(0.7, 0.2, 2.0),
        Vec3::new(1.0, 0.5, 0.0),
        Vec3::Y,
        30.0,
    )
    .unwrap();
    let f = |p: Vec3| DVec3::new(1.0 + p.x as f64, 2.0 - p.y as f64, 0.5 + (p.x + p.y) as f64);
    let corners = per_corner(&mesh, f);
    let (w, h) = (24, 20);
    let image = render(
        &mesh,
        &bvh,
        &camera,
        Shading::Smooth(&corners),
        &settings(w, h, 1),
        &no_progress,
    )
    .unwrap();
    let mut checked = 0;
    for y in 0..h {
        for x in 0..w {
            let ray = camera.ray(Vec2::new(x as f32 + 0.5, y as f32 + 0.5), w, h);
            let t = -ray.origin.z / ray.dir.z;
            let p = ray.origin + t * ray.dir;
            let got = image.get(x, y).unwrap();
            if (0.01..1.99).contains(&p.x) && (0.01..0.99).contains(&p.y) {
                let expected = (f(p) / PI).as_vec3();
                assert!(
                    (got - expected).abs().max_element() < 1e-4,
                    "({x}, {y}): {got} vs {expected}"
                );
                checked += 1;
            } else if !(-0.01..2.01).contains(&p.x) || !(-0.01..1.01).contains(&p.y) {
                assert_eq!(got, Vec3::ZERO, "({x}, {y}) misses");
            }
        }
    }
    assert!(checked > 100, "{checked}");
}

#[test]
fn back_faces_are_black() {
    let (mesh, bvh) = lamp(Subdivision::None);
    let camera = facing_lamp(-3.0, 15.0);
    let b = vec![DVec3::ONE; mesh.patches().len()];
    let image = render(
        &mesh,
        &bvh,
        &camera,
        Shading::Flat(&b),
        &settings(8, 8, 1),
        &no_progress,
    )
    .unwrap();
    assert!(image.pixels.iter().all(|p| *p == Vec3::ZERO));
    // whereas the ray at the centre does hit the quad
    assert!(
        bvh.closest_hit(&camera.ray(Vec2::splat(4.0), 8, 8))
            .is_some()
    );
}

/// A two-sided quad seen from behind shows its back side's radiosity (flat and smooth: front
/// and back never share a vertex value), from the front its front's.
#[test]
fn a_camera_behind_a_two_sided_face_sees_its_back_side() {
    let scene = mcrad_scene_io::Scene::new(
        vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ],
        vec![mcrad_scene_io::Face {
            vertices: vec![0, 1, 2, 3],
            material: 0,
            source: 0,
        }],
        vec![mcrad_scene_io::Material {
            name: "sheet".into(),
            reflectance: Vec3::splat(0.5),
            emission: Vec3::ONE,
        }],
    )
    .unwrap()
    .0
    .with_two_sided(vec![true]);
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.3)).unwrap();
    let bvh = mesh.caster().unwrap();
    let (front, back) = (DVec3::new(3.0, 2.0, 1.0), DVec3::new(0.5, 1.0, 4.0));
    let b: Vec<DVec3> = mesh
        .patches()
        .iter()
        .map(|p| if p.back { back } else { front })
        .collect();
    let corners = mesh.corner_radiosity(&b, mcrad_meshing::DEFAULT_CREASE_ANGLE_DEGREES);
    for (z, expected) in [(3.0, front), (-3.0, back)] {
        let camera = facing_lamp(z, 15.0);
        let expected = (expected / PI).as_vec3();
        for shading in [Shading::Flat(&b), Shading::Smooth(&corners)] {
            let image = render(
                &mesh,
                &bvh,
                &camera,
                shading,
                &settings(16, 16, 9),
                &no_progress,
            )
            .unwrap();
            for p in &image.pixels {
                assert!((*p - expected).abs().max_element() < 1e-5, "z {z}: {p}");
            }
        }
    }
}

#[test]
fn progress_counts_every_row_up_to_the_height() {
    let (mesh, bvh) = lamp(Subdivision::None);
    let camera = Camera::frame_scene(&mesh, &bvh).unwrap();
    let b = vec![DVec3::ONE; mesh.patches().len()];
    let seen = Mutex::new(Vec::new());
    let progress = |rows: usize| seen.lock().unwrap().push(rows);
    render(
        &mesh,
        &bvh,
        &camera,
        Shading::Flat(&b),
        &settings(5, 13, 1),
        &progress,
    )
    .unwrap();
    let mut seen = seen.into_inner().unwrap();
    seen.sort_unstable();
    assert_eq!(seen, (1..=13).collect::<Vec<_>>());
}

#[test]
fn bad_settings_and_shading_are_typed_errors() {
    let (mesh, bvh) = lamp(Subdivision::None);
    let camera = Camera::frame_scene(&mesh, &bvh).unwrap();
    let one = [DVec3::ONE];
    let go = |shading, s: RenderSettings| {
        render(&mesh, &bvh, &camera, shading, &s, &no_progress).unwrap_err()
    };
    assert_eq!(
        go(Shading::Flat(&one), settings(0, 4, 1)),
        RenderError::BadSize {
            width: 0,
            height: 4
        }
    );
    assert!(matches!(
        go(Shading::Flat(&one), settings(MAX_SIDE + 1, 4, 1)),
        RenderError::BadSize { .. }
    ));
    assert_eq!(
        go(Shading::Flat(&one), settings(4, 4, 0)),
        RenderError::NoSamples
    );
    let one_corner = CornerValues::per_corner(one.to_vec());
    assert_eq!(
        go(Shading::Smooth(&one_corner), settings(4, 4, 1)),
        RenderError::ShadingLength {
            per: "corner",
            expected: 4,
            got: 1
        }
    );
    assert_eq!(
        go(Shading::Flat(&[]), settings(4, 4, 1)),
        RenderError::ShadingLength {
            per: "patch",
            expected: 1,
            got: 0
        }
    );
    let nan = [DVec3::new(1.0, f64::NAN, 0.0)];
    let err = go(Shading::Flat(&nan), settings(4, 4, 1));
    assert!(
        matches!(err, RenderError::NonFiniteRadiosity { index: 0, .. }),
        "{err}"
    );
}

#[test]
fn rays_that_leave_the_scene_see_the_sky() {
    let (mesh, bvh) = lamp(Subdivision::None);
    let e: Vec<DVec3> = mesh
        .patches()
        .iter()
        .map(|p| p.emission.as_dvec3())
        .collect();
    // Looking at the lamp's middle with a wide view: the lamp in the centre, sky around it.
    let camera = facing_lamp(1.0, 150.0);
    // a map bright above the horizon, dim below
    let map = half_bright_map();
    let mut with_sky = settings(9, 9, 1);
    with_sky.sky = Some(mcrad_scene_io::Sky::Map(std::sync::Arc::new(map)));
    let image = render(
        &mesh,
        &bvh,
        &camera,
        Shading::Flat(&e),
        &with_sky,
        &no_progress,
    )
    .unwrap();
    let lamp = Vec3::new(3.0, 2.0, 1.0) / std::f32::consts::PI;
    assert!((image.get(4, 4).unwrap() - lamp).abs().max_element() < 1e-6);
    // the top corner row looks up (+Y), the bottom one down
    assert_eq!(image.get(0, 0).unwrap(), Vec3::new(4.0, 5.0, 6.0));
    assert_eq!(image.get(8, 8).unwrap(), Vec3::splat(0.5));
    // without a sky a miss is black
    let black = render(
        &mesh,
        &bvh,
        &camera,
        Shading::Flat(&e),
        &settings(9, 9, 1),
        &no_progress,
    )
    .unwrap();
    assert_eq!(black.get(0, 0).unwrap(), Vec3::ZERO);
}

/// The mean and standard error of the mean of the luminance-free channel sum over an image's
/// pixels (each pixel an independent estimate).
fn mean_and_error(image: &Image) -> (f64, f64) {
    let values: Vec<f64> = image
        .pixels
        .iter()
        .map(|p| f64::from(p.x + p.y + p.z) / 3.0)
        .collect();
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

#[test]
fn a_final_gather_in_a_closed_furnace_reads_the_shading_one_bounce_away() {
    // Every wall emits E = 1 and reflects rho = 0.5. Shaded with a constant reflected part c,
    // a pixel shows E / π (its own), rho c / π (gathered) and rho E / π (the walls' emission,
    // drawn by area: H_e = E in a closed room): (E + rho c + rho E) / π. With c = B - E = 1
    // (B = E / (1 - rho) = 2) that is B / π, the exact answer; with c = 4 it is 3.5 / π (the
    // shading is read, not shown: shown it would be 4 / π).
    let (mesh, bvh) = scene("furnace.obj", Subdivision::MaxEdge(0.3));
    let camera = Camera::frame_scene(&mesh, &bvh).unwrap();
    for (c, expected) in [(1.0, 2.0 / PI), (4.0, 3.5 / PI)] {
        let b = vec![DVec3::splat(c); mesh.patches().len()];
        let gathered = RenderSettings {
            gather_rays: 2,
            ..settings(24, 24, 4)
        };
        let image = render(
            &mesh,
            &bvh,
            &camera,
            Shading::Flat(&b),
            &gathered,
            &no_progress,
        )
        .unwrap();
        let (mean, error) = mean_and_error(&image);
        assert!(error > 0.0 && error < 0.05 * expected, "{error}");
        assert!(
            (mean - expected).abs() < 4.0 * error,
            "c {c}: mean {mean}, expected {expected} +- {error}"
        );
    }
}

#[test]
fn a_final_gather_under_a_uniform_sky_sees_the_sky_from_an_open_plane() {
    // The lamp alone under a uniform sky L: every gather ray leaves the scene, so a pixel shows
    // E / π + rho L exactly, whatever the shading holds (it is never shown, and nothing is
    // there to read it from); the lamp's own emission lights no point of its plane.
    let (mesh, bvh) = lamp(Subdivision::MaxEdge(0.5));
    let camera = facing_lamp(2.0, 20.0);
    let junk = vec![DVec3::new(100.0, 50.0, 7.0); mesh.patches().len()];
    let l = DVec3::new(1.0, 2.0, 3.0);
    let gathered = RenderSettings {
        sky: Some(mcrad_scene_io::Sky::Uniform(l)),
        gather_rays: 3,
        ..settings(8, 8, 2)
    };
    let image = render(
        &mesh,
        &bvh,
        &camera,
        Shading::Flat(&junk),
        &gathered,
        &no_progress,
    )
    .unwrap();
    let expected = (DVec3::new(3.0, 2.0, 1.0) / PI + 0.5 * l).as_vec3();
    for p in &image.pixels {
        assert!(
            (*p - expected).abs().max_element() < 1e-5,
            "{p} against {expected}"
        );
    }
}

#[test]
fn points_on_an_emitter_are_uniform_by_area() {
    // A convex pentagon, one patch: the points' share in each fan triangle is its share of
    // the area (within 4 binomial standard errors), and their mean is the area centroid.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("p.mtl"),
        "newmtl m\nKd 0.5 0.5 0.5\nKe 1 1 1\n",
    )
    .unwrap();
    let obj = "mtllib p.mtl\nv 0 0 0\nv 2 0 0\nv 2.5 1.5 0\nv 1 2.5 0\nv -0.5 1.5 0\nusemtl m\nf 1 2 3 4 5\n";
    std::fs::write(dir.path().join("p.obj"), obj).unwrap();
    let (mesh, _) = load(&dir.path().join("p.obj"), Subdivision::None);
    assert_eq!(mesh.patches().len(), 1);
    let patch = &mesh.patches()[0];
    let corners: Vec<DVec3> = mesh
        .corners(patch)
        .iter()
        .map(|&v| mesh.positions()[v as usize].as_dvec3())
        .collect();
    assert_eq!(corners.len(), 5);
    let a = corners[0];
    let triangles: Vec<(DVec3, DVec3, f64)> = (1..4)
        .map(|j| {
            let (b, c) = (corners[j], corners[j + 1]);
            (b, c, (b - a).cross(c - a).length() / 2.0)
        })
        .collect();
    let area: f64 = triangles.iter().map(|t| t.2).sum();
    let centroid = triangles
        .iter()
        .map(|&(b, c, s)| (a + b + c) / 3.0 * s)
        .sum::<DVec3>()
        / area;
    // which fan triangle holds p (by the signs of its edges' cross products)
    let inside = |p: DVec3, (b, c, _): (DVec3, DVec3, f64)| {
        let z = |u: DVec3, v: DVec3| (v - u).cross(p - u).z;
        z(a, b) >= -1e-9 && z(b, c) >= -1e-9 && z(c, a) >= -1e-9
    };
    let n = 40_000;
    let mut rng = mcrad_random::Stream::new(9, 0, 0, 0);
    let mut counts = [0usize; 3];
    let mut mean = DVec3::ZERO;
    for _ in 0..n {
        let p = gather::point_on(&mesh, patch, [rng.uniform_f64(), rng.uniform_f64()]);
        let k = (0..3)
            .find(|&k| inside(p, triangles[k]))
            .expect("inside the pentagon");
        counts[k] += 1;
        mean += p / n as f64;
    }
    for k in 0..3 {
        let share = triangles[k].2 / area;
        let se = (share * (1.0 - share) / n as f64).sqrt();
        let got = counts[k] as f64 / n as f64;
        assert!(
            (got - share).abs() < 4.0 * se,
            "triangle {k}: {got} against {share}"
        );
    }
    // the spread of a coordinate over the pentagon is below 1, so 4 / sqrt(n) bounds 4 SE
    assert!(
        (mean - centroid).length() < 4.0 / (n as f64).sqrt(),
        "{mean} against {centroid}"
    );
}

#[test]
fn a_gathered_pixels_standard_error_matches_the_spread_between_pixels() {
    // In the furnace every pixel estimates the same B / π = 2 / π (the gathered part is exact,
    // the emitters' drawn light is not): the standard error each pixel reports from its own
    // samples must match the spread of the pixels' values about their mean, and a render of
    // a constant shading without lights or gather must report 0.
    let (mesh, bvh) = scene("furnace.obj", Subdivision::MaxEdge(0.3));
    let camera = Camera::frame_scene(&mesh, &bvh).unwrap();
    let b = vec![DVec3::ONE; mesh.patches().len()];
    let gathered = RenderSettings {
        gather_rays: 2,
        ..settings(32, 32, 8)
    };
    let (image, error) = render_with_error(
        &mesh,
        &bvh,
        &camera,
        Shading::Flat(&b),
        &gathered,
        &no_progress,
    )
    .unwrap();
    let n = image.pixels.len() as f64;
    let values: Vec<f64> = image.pixels.iter().map(|p| f64::from(p.y)).collect();
    let mean = values.iter().sum::<f64>() / n;
    let spread = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let reported = error
        .pixels
        .iter()
        .map(|e| f64::from(e.y).powi(2))
        .sum::<f64>()
        / n;
    let ratio = reported / spread;
    assert!(
        (0.7..1.4).contains(&ratio),
        "reported {reported} against {spread}: {ratio}"
    );
    let (_, none) = render_with_error(
        &mesh,
        &bvh,
        &camera,
        Shading::Flat(&b),
        &settings(8, 8, 4),
        &no_progress,
    )
    .unwrap();
    assert!(none.pixels.iter().all(|e| *e == Vec3::ZERO));
}

#[test]
fn a_final_gather_under_a_sky_map_sees_its_mean() {
    // The lamp under a map bright above the horizon (4, 5, 6) and dim below (0.5): its
    // hemisphere about +z takes half of each, H = π ((4, 5, 6) + 0.5) / 2, and a pixel shows
    // E / π + rho H / π. The gather draws the map by cosine and by luminance (balance
    // heuristic): the image's mean is within 4 of its standard errors of that, per channel.
    let (mesh, bvh) = lamp(Subdivision::MaxEdge(0.5));
    let camera = facing_lamp(2.0, 20.0);
    let map = half_bright_map();
    let zeros = vec![DVec3::ZERO; mesh.patches().len()];
    let gathered = RenderSettings {
        sky: Some(mcrad_scene_io::Sky::Map(std::sync::Arc::new(map))),
        gather_rays: 2,
        ..settings(16, 16, 4)
    };
    let (image, error) = render_with_error(
        &mesh,
        &bvh,
        &camera,
        Shading::Flat(&zeros),
        &gathered,
        &no_progress,
    )
    .unwrap();
    let expected = DVec3::new(3.0, 2.0, 1.0) / PI + 0.5 * DVec3::new(4.5, 5.5, 6.5) / 2.0;
    let n = image.pixels.len() as f64;
    let mean = image.pixels.iter().map(|p| p.as_dvec3()).sum::<DVec3>() / n;
    let se = (error
        .pixels
        .iter()
        .map(|e| e.as_dvec3() * e.as_dvec3())
        .sum::<DVec3>())
    .powf(0.5)
        / n;
    for c in 0..3 {
        assert!(se[c] > 0.0 && se[c] < 0.02 * expected[c], "{se}");
        assert!(
            (mean[c] - expected[c]).abs() < 4.0 * se[c],
            "channel {c}: {mean} against {expected} +- {se}"
        );
    }
}
