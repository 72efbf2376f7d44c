//! `cargo xtask bake-check [--seeds K] [--rays N] [--method M]`: are the baked texels as accurate as the bake
//! says? A textured Cornell-style room (a closed 1 m box, red and green side walls, the floor
//! textured by an orange/blue checker, a 0.3 m light in the ceiling; convex, so the reference
//! solver is exact) is solved by the reference solver and by
//! `combined` with K seeds on the same patches, and each solution is baked at the same texel
//! size. Per input face, the mean irradiance of its texels is compared with the reference bake's
//! (both interpolated alike, so only the solution differs), against the variance the bake
//! reports for that mean ([`mcrad_bake::FaceTexels::variance`]): the spread between seeds over
//! the reported variance (pooled over faces and channels) and the mean `z²` should both be near
//! 1 (the target: spread/reported within [0.67, 1.5]).

use anyhow::{Context as _, Result, bail};
use glam::{DVec3, Vec3};
use mcrad_bake::{BakeInput, BakeOptions, FaceTexels};
use mcrad_mc_radiosity::{Method, ScheduleConfig};
use mcrad_meshing::{Mesh, Subdivision};
use serde_json::{Value, json};
use std::ops::ControlFlow;
use std::path::Path;

/// The textured room as GLB bytes.
pub fn textured_cornell() -> Result<Vec<u8>> {
    let mut bin: Vec<u8> = Vec::new();
    let (mut views, mut accessors, mut primitives) = (Vec::new(), Vec::new(), Vec::new());
    let mut push = |bytes: &[u8], views: &mut Vec<Value>| {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        views.push(json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()}));
        bin.extend_from_slice(bytes);
        views.len() - 1
    };
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    // (corner, u, v, facing, material): the rectangle p, p + u, p + u + v, p + v
    let mut rects = vec![
        (Vec3::ZERO, x, z, y, 0), // floor, textured
        (Vec3::ZERO, y, z, x, 2), // left, red
        (x, y, z, -x, 3),         // right, green
        (z, x, y, -z, 1),         // back
        (Vec3::ZERO, x, y, z, 1), // front (closed box)
    ];
    // the ceiling as a 3 x 3 grid whose middle is the light, so the room is convex (the
    // reference solver then needs no visibility, and is exact)
    let cs = [0.0, 0.35, 0.65, 1.0];
    for i in 0..3 {
        for k in 0..3 {
            let corner = Vec3::new(cs[i], 1.0, cs[k]);
            let (du, dv) = ((cs[i + 1] - cs[i]) * x, (cs[k + 1] - cs[k]) * z);
            rects.push((corner, du, dv, -y, if i == 1 && k == 1 { 4 } else { 1 }));
        }
    }
    for (p, u, v, normal, material) in rects {
        let mut ring = [p, p + u, p + u + v, p + v];
        if u.cross(v).dot(normal) < 0.0 {
            ring.reverse();
        }
        let pos: Vec<u8> = ring
            .iter()
            .flat_map(|q| q.to_array())
            .flat_map(f32::to_le_bytes)
            .collect();
        let uv: Vec<u8> = ring
            .iter()
            .flat_map(|q| [q.x, q.z])
            .flat_map(f32::to_le_bytes)
            .collect();
        let idx: Vec<u8> = [0u16, 1, 2, 0, 2, 3]
            .iter()
            .flat_map(|i| i.to_le_bytes())
            .collect();
        let (lo, hi) = (
            ring.iter().fold(Vec3::INFINITY, |a, b| a.min(*b)),
            ring.iter().fold(Vec3::NEG_INFINITY, |a, b| a.max(*b)),
        );
        let pv = push(&pos, &mut views);
        accessors.push(
            json!({"bufferView": pv, "componentType": 5126, "count": 4, "type": "VEC3",
                              "min": lo.to_array(), "max": hi.to_array()}),
        );
        let uvv = push(&uv, &mut views);
        accessors
            .push(json!({"bufferView": uvv, "componentType": 5126, "count": 4, "type": "VEC2"}));
        let iv = push(&idx, &mut views);
        accessors
            .push(json!({"bufferView": iv, "componentType": 5123, "count": 6, "type": "SCALAR"}));
        let a = accessors.len();
        primitives.push(
            json!({"attributes": {"POSITION": a - 3, "TEXCOORD_0": a - 2},
                               "indices": a - 1, "material": material}),
        );
    }
    let png = crate::bake_bench::checker_png([240, 150, 60], [60, 90, 220])?;
    let png_view = push(&png, &mut views);
    let solid =
        |r: f32, g: f32, b: f32| json!({"baseColorFactor": [r, g, b, 1.0], "metallicFactor": 0.0});
    let doc = json!({
        "asset": {"version": "2.0", "generator": "cargo xtask bake-check"},
        "extensionsUsed": ["KHR_materials_emissive_strength"],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": accessors,
        "images": [{"bufferView": png_view, "mimeType": "image/png"}],
        "textures": [{"source": 0}],
        "materials": [
            {"name": "floor", "pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.9, 0.9, 1.0],
             "metallicFactor": 0.0, "baseColorTexture": {"index": 0}}},
            {"name": "white", "pbrMetallicRoughness": solid(0.75, 0.75, 0.75)},
            {"name": "red", "pbrMetallicRoughness": solid(0.63, 0.065, 0.05)},
            {"name": "green", "pbrMetallicRoughness": solid(0.14, 0.45, 0.09)},
            {"name": "light", "emissiveFactor": [1, 0.85, 0.6],
             "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 10}},
             "pbrMetallicRoughness": solid(0.5, 0.5, 0.5)}
        ],
        "meshes": [{"name": "room", "primitives": primitives}],
        "nodes": [{"name": "room", "mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0
    });
    Ok(mcrad_scene_io::glb::glb_bytes(
        &serde_json::to_vec(&doc)?,
        &bin,
    )?)
}

/// The arguments of `cargo xtask bake-check`.
#[derive(Debug, Clone, clap::Args)]
pub struct BakeCheckArgs {
    /// Seeds 0..K of the Monte Carlo method
    #[arg(long, value_name = "K", default_value_t = 8)]
    pub seeds: u64,
    /// Rays of every run (e.g. 2e6)
    #[arg(long, value_name = "N", default_value_t = 2_000_000, value_parser = crate::parse_count)]
    pub rays: u64,
    /// The method baked and judged
    #[arg(long, value_name = "M", default_value_t = Method::Combined)]
    pub method: Method,
}

/// `cargo xtask bake-check [--seeds K] [--rays N] [--method M]` (default `combined`).
pub fn run(root: &Path, args: &BakeCheckArgs) -> Result<()> {
    let (seeds, rays, method) = (args.seeds, args.rays, args.method);
    let dir = root.join("target/bake-check");
    std::fs::create_dir_all(&dir)?;
    let path = dir.join("cornell-textured.glb");
    std::fs::write(&path, textured_cornell()?)?;
    let options = mcrad_scene_io::LoadOptions::default();
    let loaded = mcrad_scene_io::load_with(&path, &options)?;
    let gltf = loaded.gltf.as_deref().context("a glTF scene")?;
    let mesh = Mesh::build(&loaded.scene, Subdivision::MaxEdge(0.1))?;
    let bvh = mesh.caster()?;
    let bake = |radiosity: &[DVec3],
                variance: Option<&[DVec3]>,
                face_correlation: Option<&[DVec3]>|
     -> Result<Vec<FaceTexels>> {
        let input = BakeInput {
            path: &path,
            load_options: &options,
            scene: &loaded.scene,
            gltf,
            mesh: &mesh,
            caster: &bvh,
            radiosity,
            variance,
            face_correlation,
            progress: None,
            direct: None,
        };
        let baked = mcrad_bake::bake(
            &input,
            &BakeOptions {
                texel: Some(0.01),
                ..Default::default()
            },
        )?;
        Ok(baked.face_texels)
    };
    let reference = mcrad_mc_radiosity::run(
        Method::Reference,
        &mesh,
        &bvh,
        &ScheduleConfig::default(),
        &mut |_| ControlFlow::Continue(()),
    )?;
    let exact = bake(reference.estimate.radiosity(), None, None)?;
    // Each seed's bake with the patches' correlation (as `mcrad bake` reports) and without.
    let mut runs: Vec<Vec<FaceTexels>> = Vec::new();
    let mut independent: Vec<Vec<FaceTexels>> = Vec::new();
    for seed in 0..seeds {
        let config = ScheduleConfig {
            rays,
            seed,
            ..Default::default()
        };
        let s = crate::solve_fixed(method, &mesh, &config, &mut |_| ControlFlow::Continue(()))?;
        let (b, v) = (s.estimate.radiosity(), s.estimate.variance());
        runs.push(bake(b, v, s.face_correlation.as_deref())?);
        independent.push(bake(b, v, None)?);
    }
    let (spread_c, z2_c) = scores(&exact, &runs, true)?;
    let (spread, z2) = scores(&exact, &independent, false)?;
    let which = if differ(&runs, &independent) {
        "with the patches' correlation"
    } else {
        "(the method gives no correlation: the same)"
    };
    println!(
        "\nAll faces and channels, {seeds} seeds of {method} at {rays} rays, spread/reported \
         (pooled) and mean z² (targets: [0.67, 1.5] and [0.7, 1.5]):\n\
         - patches taken as independent: {spread:.3}, {z2:.3}\n\
         - {which}: {spread_c:.3}, {z2_c:.3}"
    );
    Ok(())
}

/// Whether some face's reported variance differs between the two sets of bakes.
fn differ(a: &[Vec<FaceTexels>], b: &[Vec<FaceTexels>]) -> bool {
    a.iter()
        .zip(b)
        .any(|(a, b)| a.iter().zip(b).any(|(a, b)| a.variance != b.variance))
}

/// Pooled spread / reported and mean `z²` over faces and channels of `runs` (one bake per
/// seed) against the reference bake `exact`, printing the table of faces when `table`.
fn scores(exact: &[FaceTexels], runs: &[Vec<FaceTexels>], table: bool) -> Result<(f64, f64)> {
    let k = runs.len() as f64;
    let (mut spread, mut reported, mut z2, mut n) = (0.0, 0.0, 0.0, 0.0);
    if table {
        println!("| face | texels | reference H (W/m², rgb) | spread/reported | mean z² |");
        println!("|---:|---:|---|---:|---:|");
    }
    for (f, e) in exact.iter().enumerate() {
        let faces: Vec<&FaceTexels> = runs.iter().map(|r| &r[f]).collect();
        if faces.iter().any(|t| t.source != e.source) {
            bail!("the bakes cover different faces");
        }
        let mean = faces.iter().map(|t| t.mean).sum::<DVec3>() / k;
        let s2 = faces
            .iter()
            .map(|t| (t.mean - mean).powf(2.0))
            .sum::<DVec3>()
            / (k - 1.0);
        let v = faces.iter().filter_map(|t| t.variance).sum::<DVec3>() / k;
        let zz = faces
            .iter()
            .map(|t| {
                let d = t.mean - e.mean;
                let var = t.variance.unwrap_or(DVec3::ZERO);
                DVec3::new(d.x * d.x / var.x, d.y * d.y / var.y, d.z * d.z / var.z)
            })
            .sum::<DVec3>()
            / k;
        let ok = |c: usize| v[c] > 0.0 && e.mean[c] > 0.0;
        for c in (0..3).filter(|&c| ok(c)) {
            spread += s2[c];
            reported += v[c];
            z2 += zz[c];
            n += 1.0;
        }
        if !table {
            continue;
        }
        println!(
            "| {} | {} | {:.3} {:.3} {:.3} | {:.2} | {:.2} |",
            e.source,
            e.texels,
            e.mean.x,
            e.mean.y,
            e.mean.z,
            s2.element_sum() / v.element_sum(),
            zz.element_sum() / 3.0
        );
    }
    Ok((spread / reported, z2 / n))
}
