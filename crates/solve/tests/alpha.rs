//! Alpha-tested surfaces through the whole pipeline (mesh, caster, solve): a checkered card
//! lets half the light through, and a closed furnace with a masked card stays a furnace.

use std::ops::ControlFlow;
use std::sync::Arc;

use glam::{Vec2, Vec3};
use mcrad_mc_radiosity::Method;
use mcrad_scene_io::{
    AlphaMode, Face, FaceAlpha, FaceMapping, Material, Scene, SceneTextures, Texture, Wrap,
};
use mcrad_solve::{Answer, MeshPlan, Problem, solve};

/// A scene being assembled: quads (counter-clockwise from the front) of given materials.
#[derive(Default)]
struct Builder {
    positions: Vec<Vec3>,
    faces: Vec<Face>,
}

impl Builder {
    /// Adds a quad; returns its face source number.
    fn quad(&mut self, corners: [Vec3; 4], material: u32) -> u32 {
        let first = self.positions.len() as u32;
        self.positions.extend(corners);
        let source = self.faces.len() as u32;
        self.faces.push(Face {
            vertices: (first..first + 4).collect(),
            material,
            source,
        });
        source
    }
}

/// The square `[x0, x1] × [z0, z1]` at height `y`, facing up (`+y`) or down.
fn horizontal(y: f32, [x0, x1, z0, z1]: [f32; 4], up: bool) -> [Vec3; 4] {
    let q = [
        Vec3::new(x0, y, z0),
        Vec3::new(x0, y, z1),
        Vec3::new(x1, y, z1),
        Vec3::new(x1, y, z0),
    ];
    if up { q } else { [q[0], q[3], q[2], q[1]] }
}

/// An `n × n` checker of alpha 1 and 0 (white texels) over `[x0, x1] × [z0, z1]` of the quad
/// `corners` (from [`horizontal`]): its mapping with `mode`.
fn checker(n: u32, corners: [Vec3; 4], rect: [f32; 4], mode: AlphaMode) -> (Texture, FaceMapping) {
    let alpha = (0..n * n)
        .map(|i| f32::from(u8::from((i % n + i / n).is_multiple_of(2))))
        .collect();
    let texture = Texture::new(n, n, vec![Vec3::ONE; (n * n) as usize], [Wrap::Repeat; 2])
        .unwrap()
        .with_alpha(alpha)
        .unwrap();
    let [x0, x1, z0, z1] = rect;
    let uv = |p: Vec3| Vec2::new((p.x - x0) / (x1 - x0), (p.z - z0) / (z1 - z0));
    let tri = [corners[0], corners[1], corners[2]];
    let mapping = FaceMapping {
        corners: tri,
        uv: tri.map(uv),
        emissive_uv: tri.map(uv),
        colors: [Vec3::ONE; 3],
        base: Some(0),
        emissive: None,
        alpha: Some(FaceAlpha {
            mode,
            factor: 1.0,
            colors: [1.0; 3],
        }),
    };
    (texture, mapping)
}

fn material(name: &str, rho: f32, e: f32) -> Material {
    Material {
        name: name.into(),
        reflectance: Vec3::splat(rho),
        emission: Vec3::splat(e),
    }
}

fn go(_: &mcrad_solve::Progress) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

fn run(scene: &Scene, method: Method, seed: u64, rays: u64) -> Answer {
    let mut problem = Problem::new(scene);
    problem.settings.method = method;
    problem.settings.seed = seed;
    problem.settings.mesh = MeshPlan::Uniform {
        max_edge: Some(0.25),
    };
    problem.budget.rays = Some(rays);
    solve(&problem, &mut go).unwrap()
}

/// The area-weighted mean radiosity (channels averaged) of the patches of face `source`, and
/// its variance from the reported variances (patches taken as independent).
fn face_mean(answer: &Answer, source: u32) -> (f64, f64) {
    let patches = answer.mesh.patches();
    let variance = answer.estimate.variance().expect("a variance");
    let total: f64 = patches
        .iter()
        .filter(|p| p.face == source)
        .map(|p| p.area)
        .sum();
    let (mut mean, mut var) = (0.0, 0.0);
    for (i, p) in patches.iter().enumerate().filter(|(_, p)| p.face == source) {
        let w = p.area / total;
        mean += w * answer.estimate.radiosity()[i].element_sum() / 3.0;
        var += w * w * variance[i].element_sum() / 9.0;
    }
    (mean, var)
}

/// The form factor between two parallel, directly opposed `a × b` rectangles `c` apart.
fn parallel_form_factor(a: f64, b: f64, c: f64) -> f64 {
    let (x, y) = (a / c, b / c);
    let (x2, y2) = (x * x, y * y);
    2.0 / (std::f64::consts::PI * x * y)
        * (((1.0 + x2) * (1.0 + y2) / (1.0 + x2 + y2)).sqrt().ln()
            + x * (1.0 + y2).sqrt() * (x / (1.0 + y2).sqrt()).atan()
            + y * (1.0 + x2).sqrt() * (y / (1.0 + x2).sqrt()).atan()
            - x * x.atan()
            - y * y.atan())
}

/// A unit light (`E = 1`, black) at height 1 facing down, a unit floor (`rho = 0.5`) at 0
/// facing up, and between them at 0.5 a black card facing the light with `card` as its
/// alpha test (`None`: opaque). No light reaches the floor but straight from the light through
/// the card (the card's back and the light absorb what the floor sends up), so the floor's mean
/// radiosity is `rho H`, `H` the direct irradiance.
fn card_over_floor(card: Option<AlphaMode>) -> Scene {
    let unit = [0.0, 1.0, 0.0, 1.0];
    let mut b = Builder::default();
    b.quad(horizontal(1.0, unit, false), 0);
    b.quad(horizontal(0.0, unit, true), 1);
    let corners = horizontal(0.5, unit, true);
    let card_face = b.quad(corners, 2);
    let materials = vec![
        material("light", 0.0, 1.0),
        material("floor", 0.5, 0.0),
        material("card", 0.0, 0.0),
    ];
    let (scene, _) = Scene::new(b.positions, b.faces, materials).unwrap();
    match card {
        None => scene,
        Some(mode) => {
            let (texture, mapping) = checker(8, corners, unit, mode);
            let mut faces = vec![None; 3];
            faces[card_face as usize] = Some(mapping);
            scene.with_textures(SceneTextures {
                textures: vec![Arc::new(texture)],
                faces,
            })
        }
    }
}

/// The mean over `seeds` independent runs of the mean radiosity of face `source`, and its
/// standard error from the spread between the runs.
fn over_seeds(scene: &Scene, method: Method, seeds: u64, rays: u64, source: u32) -> (f64, f64) {
    let values: Vec<f64> = (0..seeds)
        .map(|seed| face_mean(&run(scene, method, seed, rays), source).0)
        .collect();
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

#[test]
fn a_half_checkered_card_halves_the_direct_irradiance_under_it() {
    // Every ray from the light to the floor crosses the card at the midpoint of its ends.
    // The 8 × 8 checker (cells 1/8) maps to its complement under the mirror x -> 1 - x, which
    // leaves light and floor unchanged: both let the same light through, and together all of
    // it, so each lets exactly half: H = E F / 2, F the unit squares' form factor at 1.
    let f = parallel_form_factor(1.0, 1.0, 1.0);
    let open = 0.5 * f;
    // k = 5 standard errors of the mean over 8 seeds (the error from the spread between them:
    // Student's t with 7 degrees of freedom exceeds 5 about once in 600)
    const K: f64 = 5.0;
    for (card, expected) in [
        (AlphaMode::Mask { cutoff: 0.5 }, open / 2.0),
        (AlphaMode::Blend, open / 2.0),
        // alpha 0 and 1 are both below a cut-off of 2: all light passes
        (AlphaMode::Mask { cutoff: 2.0 }, open),
    ] {
        let scene = card_over_floor(Some(card));
        for method in [Method::Combined, Method::Shoot] {
            let (mean, se) = over_seeds(&scene, method, 8, 200_000, 1);
            assert!(
                (mean - expected).abs() <= K * se,
                "{card:?} {method:?}: floor B {mean} ± {se}, expected {expected}"
            );
        }
    }
    // the opaque card leaves the floor dark; the masked card's patches (2 × 2 cells each) count
    // their opaque half
    let (dark, _) = face_mean(
        &run(&card_over_floor(None), Method::Combined, 0, 100_000),
        1,
    );
    assert_eq!(dark, 0.0);
    let masked = card_over_floor(Some(AlphaMode::Mask { cutoff: 0.5 }));
    let answer = run(&masked, Method::Combined, 0, 10_000);
    for p in answer.mesh.patches().iter().filter(|p| p.face == 2) {
        assert!((p.area - 0.5 * 0.0625).abs() < 1e-3 * 0.0625, "{}", p.area);
    }
}

#[test]
fn a_closed_furnace_with_a_masked_card_stays_a_furnace() {
    // The unit cube, every face E = 1 W/m² and rho = 0.5 (B = E / (1 - rho) = 2 everywhere),
    // holding a card made of two masked squares back to back (a gap of 1e-4, each facing out,
    // the same 6 × 6 checker): light passes the cut-out cells and meets the front of an opaque
    // one, so the card's opaque part is one more furnace wall. Its patches (2 × 2 cells) count
    // their opaque half: with the whole area they would shoot back twice their power per area
    // and hold B = 1.5.
    let mut b = Builder::default();
    let unit = [0.0, 1.0, 0.0, 1.0];
    b.quad(horizontal(0.0, unit, true), 0);
    b.quad(horizontal(1.0, unit, false), 0);
    let (o, x, y, z) = (Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z);
    for [a, u, v] in [[o, y, z], [x, z, y], [o, x, y], [z, y, x]] {
        // the four walls, facing in: corners a, a + u, a + u + v, a + v
        b.quad([a, a + u, a + u + v, a + v], 0);
    }
    let rect = [0.2, 0.8, 0.2, 0.8];
    let upper = horizontal(0.5 + 5e-5, rect, true);
    let lower = horizontal(0.5 - 5e-5, rect, false);
    let up = b.quad(upper, 0);
    let down = b.quad(lower, 0);
    let (scene, _) = Scene::new(b.positions, b.faces, vec![material("furnace", 0.5, 1.0)]).unwrap();
    let mode = AlphaMode::Mask { cutoff: 0.5 };
    let (texture, top) = checker(6, upper, rect, mode);
    let (_, bottom) = checker(6, lower, rect, mode);
    let mut faces = vec![None; 8];
    faces[up as usize] = Some(top);
    faces[down as usize] = Some(bottom);
    let scene = scene.with_textures(SceneTextures {
        textures: vec![Arc::new(texture)],
        faces,
    });
    // k = 5 standard errors from the spread over 6 seeds, and 2e-3 for the light that slips
    // through a cut-out cell of one square into the back of an opaque cell of the other
    const K: f64 = 5.0;
    for method in [Method::Shoot, Method::Combined] {
        for source in [0, up, down] {
            let (mean, se) = over_seeds(&scene, method, 6, 200_000, source);
            assert!(
                (mean - 2.0).abs() <= K * se + 2e-3,
                "{method:?} face {source}: B {mean} ± {se}, expected 2"
            );
        }
    }
}
