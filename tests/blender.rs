//! A glTF as Blender's exporter writes it (Standard lighting: W to lm at 683), lit by a sun and
//! a point lamp, with alpha-masked, double-sided leaves: it solves, renders and bakes, and the
//! light it computes is the closed-form one.
//!
//! The scene (metres, +y up): a 10 m ground square (reflectance 0.5, a UV map as Blender writes
//! one) and 1 m above its centre a leaf card (reflectance 0.4, alphaMode MASK, doubleSided) whose
//! 2 x 2 checker texture is opaque on half its area. The sun shines straight down with
//! E = 100 W/m² (68,300 lux); a lamp of I = 10 W/sr (6,830 cd, "1000 W / (4 pi) x 683 / 1000 x
//! 125.7" in Blender's terms) hangs 0.5 m above a corner region, below the card's height, so
//! the card never shadows it.
//!
//! Exact: the ground's mean direct irradiance is `E (1 - 0.5 / 100) + I Omega / A`, `Omega`
//! the solid angle the square subtends at the lamp (the card's opaque half, 0.5 m², shades
//! 0.5% of the sun's light on the ground); the light the card's underside reflects back adds
//! under 1e-3 of it. The card's top receives the sun alone: `B = 0.402 E`.

use std::path::Path;
use std::process::{Command, Output};

use serde_json::json;

fn mcrad(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("mcrad runs")
}

const SUN: f64 = 100.0;
const LAMP: [f64; 3] = [3.0, 0.5, 2.0];
const INTENSITY: f64 = 10.0;

/// Writes `leaves.gltf` (geometry in `leaves.bin`, the leaves' texture in `leaves.png`).
fn write_scene(dir: &Path) {
    // Ground (faces 0, 1) facing up; the card (faces 2, 3) facing up at y = 1.
    let quads: [[[f32; 3]; 4]; 2] = [
        [[-5., 0., -5.], [-5., 0., 5.], [5., 0., 5.], [5., 0., -5.]],
        [
            [-0.5, 1., -0.5],
            [-0.5, 1., 0.5],
            [0.5, 1., 0.5],
            [0.5, 1., -0.5],
        ],
    ];
    let mut bin = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    for q in quads {
        let start = bin.len();
        for p in q {
            bin.extend(p.iter().flat_map(|x| x.to_le_bytes()));
        }
        for t in [[0f32, 0.], [0., 1.], [1., 1.], [1., 0.]] {
            bin.extend(t.iter().flat_map(|x| x.to_le_bytes()));
        }
        for i in [0u16, 1, 2, 0, 2, 3] {
            bin.extend(i.to_le_bytes());
        }
        let lo: Vec<f32> = (0..3)
            .map(|k| q.iter().map(|p| p[k]).fold(f32::MAX, f32::min))
            .collect();
        let hi: Vec<f32> = (0..3)
            .map(|k| q.iter().map(|p| p[k]).fold(f32::MIN, f32::max))
            .collect();
        let v = views.len();
        views.push(json!({"buffer": 0, "byteOffset": start, "byteLength": 48}));
        views.push(json!({"buffer": 0, "byteOffset": start + 48, "byteLength": 32}));
        views.push(json!({"buffer": 0, "byteOffset": start + 80, "byteLength": 12}));
        accessors.push(json!({"bufferView": v, "componentType": 5126, "count": 4,
                              "type": "VEC3", "min": lo, "max": hi}));
        accessors.push(
            json!({"bufferView": v + 1, "componentType": 5126, "count": 4,
                              "type": "VEC2"}),
        );
        accessors.push(
            json!({"bufferView": v + 2, "componentType": 5123, "count": 6,
                              "type": "SCALAR"}),
        );
    }
    std::fs::write(dir.join("leaves.bin"), &bin).unwrap();
    // A 2 x 2 checker: opaque green on the diagonal, transparent elsewhere.
    let mut png = image::RgbaImage::new(2, 2);
    for (x, y, p) in png.enumerate_pixels_mut() {
        *p = if (x + y) % 2 == 0 {
            image::Rgba([170, 170, 170, 255])
        } else {
            image::Rgba([170, 170, 170, 0])
        };
    }
    png.save(dir.join("leaves.png")).unwrap();
    // Blender writes a light's node rotated so that its -z looks along the light.
    let down = [
        -std::f64::consts::FRAC_1_SQRT_2,
        0.0,
        0.0,
        std::f64::consts::FRAC_1_SQRT_2,
    ];
    let doc = json!({
        "asset": {"version": "2.0", "generator": "Khronos glTF Blender I/O v4.2.83"},
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"name": "Sun", "type": "directional", "color": [1, 1, 1], "intensity": SUN * 683.0},
            {"name": "Lamp", "type": "point", "color": [1, 1, 1],
             "intensity": INTENSITY * 683.0}
        ]}},
        "scene": 0,
        "scenes": [{"name": "Scene", "nodes": [0, 1, 2, 3]}],
        "nodes": [
            {"name": "Ground", "mesh": 0},
            {"name": "Leaves", "mesh": 1},
            {"name": "Sun", "rotation": down, "translation": [0, 10, 0],
             "extensions": {"KHR_lights_punctual": {"light": 0}}},
            {"name": "Lamp", "translation": LAMP,
             "extensions": {"KHR_lights_punctual": {"light": 1}}}
        ],
        "materials": [
            {"name": "Ground", "doubleSided": false,
             "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1],
                                      "metallicFactor": 0, "roughnessFactor": 0.5}},
            {"name": "Leaves", "doubleSided": true, "alphaMode": "MASK", "alphaCutoff": 0.5,
             "pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                      "metallicFactor": 0, "roughnessFactor": 0.5}}
        ],
        "textures": [{"sampler": 0, "source": 0}],
        "samplers": [{"magFilter": 9728, "minFilter": 9728}],
        "images": [{"mimeType": "image/png", "name": "leaves", "uri": "leaves.png"}],
        "meshes": [
            {"name": "Ground", "primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1},
                                               "indices": 2, "material": 0}]},
            {"name": "Leaves", "primitives": [{"attributes": {"POSITION": 3, "TEXCOORD_0": 4},
                                               "indices": 5, "material": 1}]}
        ],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len(), "uri": "leaves.bin"}]
    });
    std::fs::write(dir.join("leaves.gltf"), doc.to_string()).unwrap();
}

/// `∫ h / r³ dA` over `[x0, x1] × [z0, z1]` at depth `h` below a point: its solid angle.
fn rectangle_solid_angle(x0: f64, x1: f64, z0: f64, z1: f64, h: f64) -> f64 {
    let f = |x: f64, z: f64| (x * z / (h * (x * x + z * z + h * h).sqrt())).atan();
    f(x1, z1) - f(x0, z1) - f(x1, z0) + f(x0, z0)
}

fn srgb_to_linear(c: f64) -> f64 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// The area-weighted mean radiosity (red channel) and its standard error of the per-face rows
/// `faces` of a `--per-face` CSV.
fn faces_mean(csv: &str, faces: &[u32]) -> (f64, f64) {
    let (mut area, mut sum, mut var) = (0.0, 0.0, 0.0);
    for line in csv.lines().skip(1) {
        let f: Vec<f64> = line.split(',').map(|x| x.parse().unwrap_or(0.0)).collect();
        if faces.contains(&(f[0] as u32)) {
            area += f[1];
            sum += f[1] * f[2];
            var += f[1] * f[1] * f[5];
        }
    }
    (sum / area, var.sqrt() / area)
}

#[test]
fn a_blender_scene_with_sun_lamp_and_masked_leaves_solves_renders_bakes_and_measures_right() {
    let dir = tempfile::tempdir().unwrap();
    write_scene(dir.path());
    let o = mcrad(
        dir.path(),
        &[
            "solve",
            "leaves.gltf",
            "--rays",
            "1e6",
            "--seed",
            "3",
            "--patches",
            "faces.csv",
            "--per-face",
            "--image",
            "view.png",
            "--threads",
            "2",
            "-q",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(!err.contains("clamped"), "{err}");
    assert!(dir.path().join("view.png").is_file());
    let csv = std::fs::read_to_string(dir.path().join("faces.csv")).unwrap();

    let omega = rectangle_solid_angle(
        -5.0 - LAMP[0],
        5.0 - LAMP[0],
        -5.0 - LAMP[2],
        5.0 - LAMP[2],
        LAMP[1],
    );
    let ground = 0.5 * (SUN * (1.0 - 0.5 / 100.0) + INTENSITY * omega / 100.0);
    let (b, se) = faces_mean(&csv, &[0, 1]);
    // 4 standard errors, and 1e-3 for the light the card reflects down (the leaves counted
    // opaque would be 0.5% low; not shaded at all, 0.5% high).
    assert!(
        (b - ground).abs() <= 4.0 * se + 1e-3 * ground,
        "ground {b} ± {se} against {ground}"
    );
    let (b, se) = faces_mean(&csv, &[2, 3]);
    // The texture is sRGB: 170 / 255 is a reflectance of 0.402.
    let top = srgb_to_linear(170.0 / 255.0) * SUN;
    assert!(
        (b - top).abs() <= 4.0 * se + 1e-3 * top,
        "leaves' top {b} ± {se} against {top}"
    );

    let o = mcrad(
        dir.path(),
        &[
            "bake",
            "leaves.gltf",
            "--out",
            "baked.glb",
            "--rays",
            "4e5",
            "--threads",
            "2",
            "-q",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let lightmap = mcrad_render::read_exr(&dir.path().join("baked.lightmap.exr")).unwrap();
    // Every texel's irradiance is within what the scene can give: the ground's at most the
    // sun's plus the lamp's straight below it, and the brightest texels are the sunlit ones.
    let most = SUN + INTENSITY / (LAMP[1] * LAMP[1]);
    let max = lightmap
        .pixels
        .iter()
        .map(|p| f64::from(p.max_element()))
        .fold(0.0, f64::max);
    assert!(max > 0.9 * SUN && max < 1.05 * most, "lightmap max {max}");
}
