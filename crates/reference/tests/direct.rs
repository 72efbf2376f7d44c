//! The reference solver's direct light from lights without a surface, against closed forms.

use glam::{DVec3, Vec3};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use mcrad_reference::direct_irradiance;
use mcrad_scene_io::{Face, Light, Material, PointLight, Scene, SpotLight, Sun};

fn material(name: &str) -> Material {
    Material {
        name: name.into(),
        reflectance: Vec3::splat(0.5),
        emission: Vec3::ZERO,
    }
}

/// The unit ground square `[0, 1]²` at `z = 0` facing up (patch 0) and, when `edge` is
/// given, an occluder at `z = 1` covering `x <= edge` (patch 1), lit by `light`.
fn ground(light: Light, edge: Option<f32>) -> (Mesh, Bvh) {
    let mut positions = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];
    let mut faces = vec![Face {
        vertices: vec![0, 1, 2, 3],
        material: 0,
        source: 0,
    }];
    if let Some(x) = edge {
        positions.extend([
            Vec3::new(-10.0, -10.0, 1.0),
            Vec3::new(-10.0, 10.0, 1.0),
            Vec3::new(x, 10.0, 1.0),
            Vec3::new(x, -10.0, 1.0),
        ]);
        faces.push(Face {
            vertices: vec![4, 5, 6, 7],
            material: 0,
            source: 1,
        });
    }
    let scene = Scene::new_lit(positions, faces, vec![material("m")], vec![light])
        .unwrap()
        .0;
    let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
    (mesh, bvh)
}

fn lights_of(mesh: &Mesh, light: &Light) -> Vec<Light> {
    vec![light.translated(-mesh.origin())]
}

/// `∫ h / r³ dA` over the rectangle `[x0, x1] × [y0, y1]` at height `-h` below a point: the
/// solid angle it subtends, by the rectangle formula summed over corners.
fn rectangle_solid_angle(x0: f64, x1: f64, y0: f64, y1: f64, h: f64) -> f64 {
    let f = |x: f64, y: f64| (x * y / (h * (x * x + y * y + h * h).sqrt())).atan();
    f(x1, y1) - f(x0, y1) - f(x1, y0) + f(x0, y0)
}

#[test]
fn a_point_light_over_an_open_square_gives_its_solid_angle_exactly() {
    let (c, h) = (DVec3::new(0.3, 0.4, 2.0), 2.0);
    let intensity = DVec3::new(10.0, 20.0, 30.0);
    let light = Light::Point(PointLight {
        position: c.as_vec3(),
        intensity,
        range: None,
    });
    let (mesh, bvh) = ground(light.clone(), None);
    let d = direct_irradiance(&mesh, &bvh, &lights_of(&mesh, &light));
    let omega = rectangle_solid_angle(-c.x, 1.0 - c.x, -c.y, 1.0 - c.y, h);
    let exact = intensity * omega;
    assert!(
        (d.irradiance[0] - exact).abs().max_element() < 1e-6 * exact.max_element(),
        "{} vs {exact}",
        d.irradiance[0]
    );
    assert_eq!((d.exact, d.quadrature), (1, 0));
}

#[test]
fn a_half_shadowed_square_gets_the_solid_angle_of_its_lit_part() {
    // Light at height 2, occluder edge at height 1 and x = 0.41: the shadow's edge on the
    // ground is x = 0.3 + 2 (0.41 - 0.3) = 0.52, so [0.52, 1] × [0, 1] is lit. FINE R2 points
    // per triangle: about 2e-4 of the answer on such edges (1e-3 is asked; a lattice of
    // centroids errs by 1% here).
    let (c, h) = (DVec3::new(0.3, 0.4, 2.0), 2.0);
    let intensity = DVec3::splat(10.0);
    let light = Light::Point(PointLight {
        position: c.as_vec3(),
        intensity,
        range: None,
    });
    let (mesh, bvh) = ground(light.clone(), Some(0.41));
    let d = direct_irradiance(&mesh, &bvh, &lights_of(&mesh, &light));
    let omega = rectangle_solid_angle(0.52 - c.x, 1.0 - c.x, -c.y, 1.0 - c.y, h);
    let exact = intensity.x * omega;
    let got = d.irradiance[0].x;
    let tolerance = 1e-3 * exact;
    assert!(
        (got - exact).abs() < tolerance,
        "{got} vs {exact} (tolerance {tolerance})"
    );
    assert_eq!(d.quadrature, 1, "the ground is partly shadowed");
}

#[test]
fn a_sun_gives_e_cos_and_a_spot_nothing_beyond_its_cone() {
    let elevation = 35f64.to_radians();
    let sun = Light::Sun(Sun {
        direction: Vec3::new(elevation.cos() as f32, 0.0, elevation.sin() as f32),
        irradiance: DVec3::splat(800.0),
        diameter: 0.53f64.to_radians(),
    });
    let (mesh, bvh) = ground(sun.clone(), None);
    let d = direct_irradiance(&mesh, &bvh, &lights_of(&mesh, &sun));
    let exact = 800.0 * elevation.sin();
    assert!((d.irradiance[0].x - exact).abs() < 1e-6 * exact);
    // A spot 1 above the square's far corner pointing away from it, outer cone 30°: nothing.
    let spot = Light::Spot(SpotLight {
        point: PointLight {
            position: Vec3::new(2.0, 2.0, 1.0),
            intensity: DVec3::splat(100.0),
            range: None,
        },
        direction: Vec3::new(1.0, 1.0, -0.2).normalize(),
        inner: 0.2,
        outer: 30f64.to_radians(),
    });
    let (mesh, bvh) = ground(spot.clone(), None);
    let d = direct_irradiance(&mesh, &bvh, &lights_of(&mesh, &spot));
    assert_eq!(d.irradiance[0], DVec3::ZERO);
}
