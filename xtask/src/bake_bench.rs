//! `cargo xtask bench bake`: how long `mcrad bake` takes on a 100k-triangle textured glTF scene
//! of many nodes and instances ("city": 8,400 placements of one textured box mesh on a
//! textured 60 m floor under a 20 m ceiling light, written to `target/bake-bench/city.glb`).
//! Runs `mcrad bake --time 30` and `--rays 1e6` and prints the wall-clock times (the issue's
//! target: under a minute on 2 cores).

use anyhow::{Result, bail};
use serde_json::json;
use std::path::Path;
use std::process::Command;
use std::time::Instant;

/// Placements of the box mesh.
const BOXES: usize = 8400;

/// SplitMix64 (a fixed layout).
fn next(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

/// A 64 × 64 PNG of 8 × 8-texel squares of the sRGB colours `a` and `b` (a test texture).
pub fn checker_png(a: [u8; 3], b: [u8; 3]) -> Result<Vec<u8>> {
    let image = image::RgbImage::from_fn(64, 64, |x, y| {
        image::Rgb(if (x / 8 + y / 8) % 2 == 1 { a } else { b })
    });
    let mut png = Vec::new();
    image::DynamicImage::ImageRgb8(image)
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
    Ok(png)
}

/// The city scene as GLB bytes: 12 × 8,400 + 4 triangles.
pub fn city() -> Result<Vec<u8>> {
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut push = |bytes: &[u8], target: Option<u32>| {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        bin.extend_from_slice(bytes);
        views.push(v);
        views.len() - 1
    };
    let f32s = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
    // an outward unit box: 6 faces of 4 vertices with texture coordinates
    let faces: [[[f32; 3]; 4]; 6] = [
        [[0., 0., 1.], [1., 0., 1.], [1., 1., 1.], [0., 1., 1.]],
        [[1., 0., 0.], [0., 0., 0.], [0., 1., 0.], [1., 1., 0.]],
        [[1., 0., 1.], [1., 0., 0.], [1., 1., 0.], [1., 1., 1.]],
        [[0., 0., 0.], [0., 0., 1.], [0., 1., 1.], [0., 1., 0.]],
        [[0., 1., 1.], [1., 1., 1.], [1., 1., 0.], [0., 1., 0.]],
        [[0., 0., 0.], [1., 0., 0.], [1., 0., 1.], [0., 0., 1.]],
    ];
    let (mut pos, mut uv, mut idx) = (Vec::new(), Vec::new(), Vec::new());
    for (k, f) in faces.iter().enumerate() {
        pos.extend(f.iter().flatten());
        uv.extend([0., 0., 1., 0., 1., 1., 0., 1.]);
        let b = 4 * k as u16;
        idx.extend([b, b + 1, b + 2, b, b + 2, b + 3]);
    }
    let idx_bytes: Vec<u8> = idx.iter().flat_map(|i: &u16| i.to_le_bytes()).collect();
    let quad_idx: Vec<u8> = [0u16, 1, 2, 0, 2, 3]
        .iter()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let floor = [0., 0., 0., 0., 0., 60., 60., 0., 60., 60., 0., 0.];
    let light = [20., 8., 20., 40., 8., 20., 40., 8., 40., 20., 8., 40.];
    let accessors = json!([
        {"bufferView": push(&f32s(&pos), Some(34962)), "componentType": 5126, "count": 24,
         "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1]},
        {"bufferView": push(&f32s(&uv), Some(34962)), "componentType": 5126, "count": 24, "type": "VEC2"},
        {"bufferView": push(&idx_bytes, Some(34963)), "componentType": 5123, "count": 36, "type": "SCALAR"},
        {"bufferView": push(&f32s(&floor), None), "componentType": 5126, "count": 4, "type": "VEC3",
         "min": [0, 0, 0], "max": [60, 0, 60]},
        {"bufferView": push(&f32s(&[0., 0., 0., 8., 8., 8., 8., 0.]), None), "componentType": 5126,
         "count": 4, "type": "VEC2"},
        {"bufferView": push(&quad_idx, None), "componentType": 5123, "count": 6, "type": "SCALAR"},
        {"bufferView": push(&f32s(&light), None), "componentType": 5126, "count": 4, "type": "VEC3",
         "min": [20, 8, 20], "max": [40, 8, 40]}
    ]);
    let png = checker_png([255, 200, 150], [60, 60, 200])?;
    let png_view = push(&png, None);
    let mut state = 7u64;
    let mut nodes = vec![
        json!({"name": "floor", "mesh": 1}),
        json!({"name": "light", "mesh": 2}),
    ];
    for i in 0..BOXES {
        let (x, z) = (1.0 + 57.0 * next(&mut state), 1.0 + 57.0 * next(&mut state));
        let s = 0.2 + 0.4 * next(&mut state);
        let h = s * (0.5 + 2.5 * next(&mut state));
        nodes.push(json!({"name": format!("box{i}"), "mesh": 0,
                          "translation": [x, 0, z], "scale": [s, h, s]}));
    }
    let roots: Vec<usize> = (0..nodes.len()).collect();
    let pbr = |factor: f32| {
        json!({"baseColorFactor": [factor, factor, factor, 1.0],
                                   "metallicFactor": 0.0, "baseColorTexture": {"index": 0}})
    };
    let doc = json!({
        "asset": {"version": "2.0", "generator": "cargo xtask bench bake"},
        "extensionsUsed": ["KHR_materials_emissive_strength"],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": accessors,
        "images": [{"bufferView": png_view, "mimeType": "image/png"}],
        "textures": [{"source": 0}],
        "materials": [
            {"name": "boxes", "pbrMetallicRoughness": pbr(0.8)},
            {"name": "floor", "pbrMetallicRoughness": pbr(0.7)},
            {"name": "light", "emissiveFactor": [1, 1, 1],
             "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 30}},
             "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1]}}
        ],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]},
            {"primitives": [{"attributes": {"POSITION": 3, "TEXCOORD_0": 4}, "indices": 5, "material": 1}]},
            {"primitives": [{"attributes": {"POSITION": 6}, "indices": 5, "material": 2}]}
        ],
        "nodes": nodes,
        "scenes": [{"nodes": roots}],
        "scene": 0
    });
    Ok(mcrad_scene_io::glb::glb_bytes(
        &serde_json::to_vec(&doc)?,
        &bin,
    )?)
}

/// Writes the city and times two bakes of it.
pub fn run(root: &Path, mcrad: &Path) -> Result<()> {
    let dir = root.join("target/bake-bench");
    std::fs::create_dir_all(&dir)?;
    let scene = dir.join("city.glb");
    std::fs::write(&scene, city()?)?;
    for budget in [["--rays", "1e6"], ["--time", "30"]] {
        let start = Instant::now();
        let status = Command::new(mcrad)
            .arg("bake")
            .arg(&scene)
            .arg("--out")
            .arg(dir.join("city-baked.glb"))
            .args(budget)
            .status()?;
        if !status.success() {
            bail!("mcrad bake failed");
        }
        println!(
            "bake city.glb ({} triangles) {} {}: {:.1} s wall-clock",
            12 * BOXES + 4,
            budget[0],
            budget[1],
            start.elapsed().as_secs_f64()
        );
    }
    Ok(())
}
