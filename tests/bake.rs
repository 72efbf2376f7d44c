//! End-to-end tests of `mcrad bake`: the user's glTF kept whole, lightmap coordinates added,
//! the lightmap's values those of the solution.

use std::path::Path;
use std::process::{Command, Output};

use serde_json::{Value, json};

fn mcrad(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("mcrad runs")
}

/// Two copies (nodes `a` and `b`) of one mesh: an inward-facing unit cube of 6 quads, every
/// face emitting `pi * 0.3` W/m² with reflectance 0.5, so `B = E / (1 - rho)` everywhere and
/// the incident irradiance `H = (B - E) / rho = E / (1 - rho) = 0.6 pi`. Geometry in an
/// external `box.bin`, a `TEXCOORD_0`, an external texture image, extras and an unknown
/// extension to keep.
fn write_box(dir: &Path) {
    let faces: [[[f32; 3]; 4]; 6] = [
        [[0., 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]],
        [[0., 0., 1.], [0., 1., 1.], [1., 1., 1.], [1., 0., 1.]],
        [[0., 0., 0.], [0., 0., 1.], [1., 0., 1.], [1., 0., 0.]],
        [[0., 1., 0.], [1., 1., 0.], [1., 1., 1.], [0., 1., 1.]],
        [[0., 0., 0.], [0., 1., 0.], [0., 1., 1.], [0., 0., 1.]],
        [[1., 0., 0.], [1., 0., 1.], [1., 1., 1.], [1., 1., 0.]],
    ];
    let (mut pos, mut uv, mut idx) = (Vec::new(), Vec::new(), Vec::new());
    for f in faces {
        let b = (pos.len() / 12) as u16;
        for p in f {
            pos.extend(p.iter().flat_map(|x| x.to_le_bytes()));
        }
        for t in [[0f32, 0.], [1., 0.], [1., 1.], [0., 1.]] {
            uv.extend(t.iter().flat_map(|x| x.to_le_bytes()));
        }
        for i in [b, b + 1, b + 2, b, b + 2, b + 3] {
            idx.extend(i.to_le_bytes());
        }
    }
    let mut bin = [pos.clone(), uv.clone(), idx.clone()].concat();
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    std::fs::write(dir.join("box.bin"), &bin).unwrap();
    // a 1x1 white PNG (the texture is only carried along)
    let png = [
        0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44,
        0x52, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01, 0x08, 0x02, 0x00, 0x00, 0x00, 0x90,
        0x77, 0x53, 0xde, 0x00, 0x00, 0x00, 0x0c, 0x49, 0x44, 0x41, 0x54, 0x08, 0xd7, 0x63, 0xf8,
        0xff, 0xff, 0x3f, 0x00, 0x05, 0xfe, 0x02, 0xfe, 0xdc, 0xcc, 0x59, 0xe7, 0x00, 0x00, 0x00,
        0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82,
    ];
    std::fs::write(dir.join("white.png"), png).unwrap();
    let (p, u) = (pos.len(), uv.len());
    let doc = json!({
        "asset": {"version": "2.0"},
        "extras": {"author": "test"},
        "extensionsUsed": ["EXT_something_unknown"],
        "buffers": [{"byteLength": bin.len(), "uri": "box.bin"}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": p},
            {"buffer": 0, "byteOffset": p, "byteLength": u},
            {"buffer": 0, "byteOffset": p + u, "byteLength": idx.len()}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 24, "type": "VEC3",
             "min": [0, 0, 0], "max": [1, 1, 1]},
            {"bufferView": 1, "componentType": 5126, "count": 24, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 36, "type": "SCALAR"}
        ],
        "images": [{"uri": "white.png"}],
        "textures": [{"source": 0}],
        "materials": [{
            "name": "glow", "extras": {"keep": "me"},
            "emissiveFactor": [0.3, 0.3, 0.3],
            "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0,
                                     "baseColorTexture": {"index": 0}}
        }],
        "meshes": [{"name": "box", "primitives": [
            {"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}
        ]}],
        "nodes": [{"name": "a", "mesh": 0}, {"name": "b", "mesh": 0, "translation": [3, 0, 0]}],
        "scenes": [{"nodes": [0, 1]}],
        "scene": 0
    });
    std::fs::write(dir.join("box.gltf"), doc.to_string()).unwrap();
}

/// The furnace box's exact incident irradiance `H = E / (1 - rho) = 0.6 pi` (W/m²).
const EXACT_H: f32 = 0.6 * std::f32::consts::PI;

/// Asserts that every used texel of the lightmap EXR `file` (in `dir`) holds [`EXACT_H`] within
/// 1e-3 relative (unused texels are 0) and that at least `at_least` are used.
fn assert_exact_lightmap(dir: &Path, file: &str, at_least: usize) {
    let exr = mcrad_render::read_exr(&dir.join(file)).unwrap();
    let used: Vec<_> = exr
        .pixels
        .iter()
        .filter(|h| h.max_element() > 0.0)
        .collect();
    assert!(used.len() >= at_least, "{} texels used", used.len());
    for h in used {
        assert!(
            (*h - glam::Vec3::splat(EXACT_H)).abs().max_element() < 1e-3 * EXACT_H,
            "{h}"
        );
    }
}

/// The JSON chunk and binary chunk of a GLB.
fn glb_parts(bytes: &[u8]) -> (Value, Vec<u8>) {
    assert_eq!(&bytes[0..4], b"glTF");
    let n = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    assert_eq!(&bytes[16..20], b"JSON");
    let json = serde_json::from_slice(&bytes[20..20 + n]).unwrap();
    let m = u32::from_le_bytes(bytes[20 + n..24 + n].try_into().unwrap()) as usize;
    assert_eq!(&bytes[24 + n..28 + n], b"BIN\0");
    (json, bytes[28 + n..28 + n + m].to_vec())
}

/// The `f32` elements of a float accessor.
fn floats(doc: &Value, bin: &[u8], accessor: &Value) -> Vec<f32> {
    let a = &doc["accessors"][accessor.as_u64().unwrap() as usize];
    assert_eq!(a["componentType"], 5126);
    let view = &doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
    let start = view["byteOffset"].as_u64().unwrap_or(0) + a["byteOffset"].as_u64().unwrap_or(0);
    let n = a["count"].as_u64().unwrap()
        * match a["type"].as_str().unwrap() {
            "VEC2" => 2,
            "VEC3" => 3,
            "VEC4" => 4,
            _ => 1,
        };
    (0..n)
        .map(|k| {
            let at = (start + 4 * k) as usize;
            f32::from_le_bytes(bin[at..at + 4].try_into().unwrap())
        })
        .collect()
}

#[test]
fn bake_keeps_the_document_and_its_lightmap_holds_the_exact_furnace_irradiance() {
    let dir = tempfile::tempdir().unwrap();
    write_box(dir.path());
    // gather is exact in a closed furnace (every patch sees the same radiosity)
    let o = mcrad(
        dir.path(),
        &[
            "bake",
            "box.gltf",
            "--out",
            "out.glb",
            "--method",
            "gather",
            "--rays",
            "1e5",
            "--texel",
            "0.02",
            "--threads",
            "2",
            "-q",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    // (the white texture is read: no warning)
    assert!(!err.contains("warning"), "{err}");
    let bytes = std::fs::read(dir.path().join("out.glb")).unwrap();
    let (doc, bin) = glb_parts(&bytes);

    // kept: names, extras, unknown extensions, the material and its texture (now embedded)
    assert_eq!(doc["extras"]["author"], "test");
    assert_eq!(doc["nodes"][0]["name"], "a");
    assert_eq!(doc["nodes"][1]["name"], "b");
    assert_eq!(doc["nodes"][1]["translation"], json!([3, 0, 0]));
    assert_eq!(doc["materials"][0]["extras"]["keep"], "me");
    assert_eq!(
        doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["index"],
        0
    );
    let used = doc["extensionsUsed"].as_array().unwrap();
    assert!(
        used.contains(&json!("EXT_something_unknown")) && used.contains(&json!("MOZ_lightmap"))
    );
    assert_eq!(doc["buffers"].as_array().unwrap().len(), 1);
    assert!(
        doc["buffers"][0].get("uri").is_none(),
        "one embedded buffer"
    );
    assert!(
        doc["images"][0].get("uri").is_none(),
        "the texture is embedded"
    );
    assert_eq!(doc["images"][0]["mimeType"], "image/png");

    // one mesh per placement, each with lightmap coordinates inside the atlas
    let (ma, mb) = (&doc["nodes"][0]["mesh"], &doc["nodes"][1]["mesh"]);
    assert_ne!(ma, mb, "the instanced mesh is copied for its second node");
    let lightmap = &doc["materials"][0]["extensions"]["MOZ_lightmap"];
    assert_eq!(lightmap["texCoord"], 1);
    let intensity = lightmap["intensity"].as_f64().unwrap();
    let exr = mcrad_render::read_exr(&dir.path().join("out.lightmap.exr")).unwrap();
    assert_eq!(exr.width, exr.height);
    let exact = EXACT_H;
    for m in [ma, mb] {
        let primitive = &doc["meshes"][m.as_u64().unwrap() as usize]["primitives"][0];
        let uv = floats(&doc, &bin, &primitive["attributes"]["TEXCOORD_1"]);
        let positions = floats(&doc, &bin, &primitive["attributes"]["POSITION"]);
        let texcoord0 = floats(&doc, &bin, &primitive["attributes"]["TEXCOORD_0"]);
        assert_eq!(uv.len() / 2, positions.len() / 3);
        assert_eq!(uv.len(), texcoord0.len());
        for t in uv.chunks(2) {
            assert!(t.iter().all(|x| (0.0..=1.0).contains(x)), "{t:?}");
            // the texel under every vertex (a chart corner) holds the exact irradiance
            let x = ((t[0] * exr.width as f32) as u32).min(exr.width - 1);
            let y = ((t[1] * exr.height as f32) as u32).min(exr.height - 1);
            let h = exr.get(x, y).unwrap();
            assert!(
                (h - glam::Vec3::splat(exact)).abs().max_element() < 1e-3 * exact,
                "{h}"
            );
        }
    }
    // every texel is the exact value or unused (0): no chart reads another's light; 12 faces
    // of 1 m² at 0.02 m per texel: at least 12 * 2500 texels
    assert_exact_lightmap(dir.path(), "out.lightmap.exr", 12 * 2500);
    assert!(
        (intensity as f32 - exact).abs() < 1e-3 * exact,
        "{intensity}"
    );

    // the baked file is a valid scene again, with the same surfaces
    let reloaded = mcrad_scene_io::load(&dir.path().join("out.glb")).unwrap();
    assert_eq!(reloaded.scene.faces().len(), 24);
}

#[test]
fn bake_refuses_what_it_cannot_write() {
    let dir = tempfile::tempdir().unwrap();
    write_box(dir.path());
    let cases: [(&[&str], &str); 3] = [
        (
            &["bake", "box.gltf", "--out", "out.gltf"],
            "must end in .glb",
        ),
        (
            &["bake", "box.gltf", "--out", "o.glb", "--texel", "0"],
            "not a positive finite",
        ),
        (
            &[
                "bake", "box.gltf", "--out", "o.glb", "--texel", "1e-5", "--rays", "1e4",
            ],
            "choose a larger texel size",
        ),
    ];
    for (args, part) in cases {
        let o = mcrad(dir.path(), args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(part), "{args:?}: {err}");
    }
}

#[test]
fn an_obj_scene_is_baked_into_a_new_gltf_document() {
    let dir = tempfile::tempdir().unwrap();
    let cornell = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box.obj");
    let o = mcrad(
        dir.path(),
        &[
            "bake",
            cornell.to_str().unwrap(),
            "--out",
            "o.glb",
            "--rays",
            "1e5",
            "-q",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (doc, _) = glb_parts(&std::fs::read(dir.path().join("o.glb")).unwrap());
    // one primitive per material, each with lightmap coordinates, materials named as in the MTL
    let obj = mcrad_scene_io::load(&cornell).unwrap().scene;
    let primitives = doc["meshes"][0]["primitives"].as_array().unwrap();
    assert_eq!(primitives.len(), obj.materials().len());
    assert!(
        primitives
            .iter()
            .all(|p| p["attributes"].get("TEXCOORD_1").is_some())
    );
    let names: Vec<&str> = doc["materials"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|m| m["name"].as_str())
        .collect();
    assert!(
        names.contains(&"light") && names.contains(&"red"),
        "{names:?}"
    );
    // the baked file reads back as the same surfaces (the OBJ's quads as triangle pairs)
    let back = mcrad_scene_io::load(&dir.path().join("o.glb"))
        .unwrap()
        .scene;
    let area = |s: &mcrad_scene_io::Scene| s.faces().iter().map(|f| s.face_area(f)).sum::<f64>();
    let (a, b) = (area(&back), area(&obj));
    // (slightly non-planar quads: two triangles hold a hair more area than the polygon)
    assert!((a - b).abs() < 1e-4 * b, "{a} vs {b}");
}

#[test]
fn target_error_stops_the_solve_and_stats_report_the_texel_error_with_its_parts() {
    let dir = tempfile::tempdir().unwrap();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box.gltf");
    let run = |target: &str, stats: &str| {
        let o = mcrad(
            dir.path(),
            &[
                "bake",
                scene.to_str().unwrap(),
                "--out",
                "c.glb",
                "--rays",
                "4e6",
                "--threads",
                "2",
                "--stats",
                stats,
                "-q",
                "--target-error",
                target,
                // The stop itself is under test: on the uniform mesh, whose fewer patches reach
                // a loose target within the budget (the adaptive default's five times as many
                // elements need more rays for the same noise per element).
                "--mesh",
                "uniform",
            ],
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let json: Value =
            serde_json::from_slice(&std::fs::read(dir.path().join(stats)).unwrap()).unwrap();
        json
    };
    // a loose target stops early, within it; a tight one runs to the budget, above it
    let loose = run("0.2", "loose.json");
    let tight = run("0.001", "tight.json");
    let rays = |j: &Value| j["rays"].as_u64().unwrap();
    assert!(rays(&loose) < 4_000_000 / 2, "{}", rays(&loose));
    assert!(rays(&tight) >= 3_900_000, "{}", rays(&tight));
    for (j, target, below) in [(&loose, 0.2, true), (&tight, 0.001, false)] {
        let e = &j["bake"]["texel_relative_error"];
        let p95 = e["p95"].as_f64().unwrap();
        let median = e["median"].as_f64().unwrap();
        assert!(
            e["texels"].as_u64().unwrap() > 10_000 && median <= p95,
            "{e}"
        );
        // texels take their patches' errors and weigh them by area, as the stop does
        assert_eq!(p95 <= target * 1.05, below, "{e}");
        // the total is the root sum of squares of the noise and the mesh per texel, each
        // reported finite and no larger than the total
        for part in ["noise", "mesh"] {
            for q in ["median", "p95"] {
                let x = e[part][q].as_f64().unwrap();
                assert!(
                    x.is_finite() && x >= 0.0 && x <= e[q].as_f64().unwrap() + 1e-12,
                    "{e}"
                );
            }
        }
        let (n, m) = (
            e["noise"]["p95"].as_f64().unwrap(),
            e["mesh"]["p95"].as_f64().unwrap(),
        );
        assert!(p95 >= n.max(m) - 1e-12, "{e}");
    }
}

#[test]
fn a_bake_is_the_same_for_a_seed_on_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    write_box(dir.path());
    let bake = |threads: &str, out: &str| {
        let o = mcrad(
            dir.path(),
            &[
                "bake",
                "box.gltf",
                "--out",
                out,
                "--rays",
                "2e5",
                "--seed",
                "3",
                "--threads",
                threads,
                "-q",
            ],
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(dir.path().join(out)).unwrap()
    };
    let one = bake("1", "one.glb");
    assert!(one == bake("2", "two.glb"), "1 and 2 threads differ");
    assert!(one == bake("2", "again.glb"), "a second run differs");
}

#[test]
fn vertex_colours_hold_the_exact_furnace_irradiance() {
    let dir = tempfile::tempdir().unwrap();
    write_box(dir.path());
    let o = mcrad(
        dir.path(),
        &[
            "bake",
            "box.gltf",
            "--out",
            "v.glb",
            "--method",
            "gather",
            "--rays",
            "1e5",
            "--vertex-colors",
            "-q",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (doc, bin) = glb_parts(&std::fs::read(dir.path().join("v.glb")).unwrap());
    assert!(!dir.path().join("v.lightmap.exr").exists(), "no lightmap");
    assert!(
        doc["materials"][0]["extensions"]
            .get("MOZ_lightmap")
            .is_none()
    );
    let intensity = doc["asset"]["extras"]["mcradVertexIntensity"]
        .as_f64()
        .unwrap() as f32;
    let exact = EXACT_H;
    for node in 0..2 {
        let m = doc["nodes"][node]["mesh"].as_u64().unwrap() as usize;
        let attributes = &doc["meshes"][m]["primitives"][0]["attributes"];
        assert!(attributes.get("TEXCOORD_1").is_none());
        let colors = floats(&doc, &bin, &attributes["COLOR_0"]);
        let positions = floats(&doc, &bin, &attributes["POSITION"]);
        assert_eq!(
            colors.len() / 4,
            positions.len() / 3,
            "one colour per vertex"
        );
        for c in colors.chunks(4) {
            for &x in &c[..3] {
                assert!(
                    (x * intensity - exact).abs() < 1e-3 * exact,
                    "{c:?} x {intensity}"
                );
            }
            assert_eq!(c[3], 1.0);
        }
    }
}

#[test]
fn many_instances_of_a_textured_mesh_each_get_their_own_light() {
    let dir = tempfile::tempdir().unwrap();
    write_box(dir.path());
    // 60 placements of the one textured box mesh, in a parent-child hierarchy
    let path = dir.path().join("box.gltf");
    let mut doc: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    let nodes: Vec<Value> = (0..60)
        .map(|i| {
            let mut n = json!({"name": format!("box{i}"), "mesh": 0,
                               "translation": [2.0 * (i % 8) as f64, 0, 2.0 * (i / 8) as f64]});
            if i % 2 == 0 {
                n["children"] = json!([i + 1]);
            } else {
                n["translation"] = json!([2.0, 0, 0]);
            }
            n
        })
        .collect();
    let roots: Vec<usize> = (0..60).step_by(2).collect();
    doc["nodes"] = json!(nodes);
    doc["scenes"] = json!([{"nodes": roots}]);
    std::fs::write(&path, doc.to_string()).unwrap();
    let o = mcrad(
        dir.path(),
        &[
            "bake", "box.gltf", "--out", "out.glb", "--method", "gather", "--rays", "2e5",
            "--texel", "0.05", "-q",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (out, _) = glb_parts(&std::fs::read(dir.path().join("out.glb")).unwrap());
    let meshes: std::collections::BTreeSet<u64> = (0..60)
        .map(|i| out["nodes"][i]["mesh"].as_u64().unwrap())
        .collect();
    assert_eq!(meshes.len(), 60, "one mesh per placement");
    assert_eq!(
        out["nodes"][0]["children"],
        json!([1]),
        "the hierarchy is kept"
    );
    for m in &meshes {
        let p = &out["meshes"][*m as usize]["primitives"][0];
        assert!(
            p["attributes"].get("TEXCOORD_1").is_some()
                && p["attributes"].get("TEXCOORD_0").is_some()
        );
    }
    // every box is a closed furnace: every used texel holds the exact irradiance; 6 faces of
    // 1 m² per box at 0.05 per texel: at least 400 texels each
    assert_exact_lightmap(dir.path(), "out.lightmap.exr", 60 * 6 * 400);
}

#[test]
fn a_scene_far_from_the_origin_bakes_as_at_the_origin() {
    let dir = tempfile::tempdir().unwrap();
    write_box(dir.path());
    let path = dir.path().join("box.gltf");
    let mut doc: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    doc["nodes"][0]["translation"] = json!([1e6, 0, 0]);
    doc["nodes"][1]["translation"] = json!([1e6 + 3.0, 0, 0]);
    std::fs::write(&path, doc.to_string()).unwrap();
    let o = mcrad(
        dir.path(),
        &[
            "bake", "box.gltf", "--out", "far.glb", "--method", "gather", "--rays", "1e5",
            "--texel", "0.02", "-q",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_exact_lightmap(dir.path(), "far.lightmap.exr", 2 * 6 * 2500);
}

/// A two-sided plane (`--two-sided`, reflectance 0.5) under a delta sun at 30 degrees
/// elevation, 1000 W/m²: glTF has one texel for both sides, and the lightmap holds the
/// **front** side's incident irradiance, as documented. Sun above: every texel the front's
/// `E sin(30°) = 500 W/m²`. Sun below: every texel 0 (the front is dark), while the patch
/// CSV's back rows (face `f + 2`: the quad is two triangles in glTF) have
/// `B = rho E sin(30°) = 250`.
#[test]
fn a_two_sided_face_bakes_its_front_side() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("plane.obj"),
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
    )
    .unwrap();
    let x = 30f64.to_radians().cos();
    for (z, front) in [(0.5, 500.0f32), (-0.5, 0.0)] {
        let sun = format!("--sun={x},0,{z},1000,0");
        let o = mcrad(
            dir.path(),
            &[
                "bake",
                "plane.obj",
                "--out",
                "o.glb",
                "--two-sided",
                "--no-subdivide",
                "--texel",
                "0.05",
                "--rays",
                "2e4",
                "--patches",
                "p.csv",
                "-q",
                &sun,
            ],
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let exr = mcrad_render::read_exr(&dir.path().join("o.lightmap.exr")).unwrap();
        let used = exr.pixels.iter().filter(|h| h.max_element() > 0.0).count();
        if front > 0.0 {
            assert!(used >= 400, "{used} texels used");
        } else {
            assert_eq!(used, 0);
        }
        for h in &exr.pixels {
            if h.max_element() > 0.0 {
                assert!((h.y - front).abs() < 1e-3 * front, "{h}");
            }
        }
        // the bake's scene is the glTF of the OBJ, the quad two triangles: faces 0 and 1 the
        // fronts, 2 and 3 (face + 2 faces) their backs
        let rows = mcrad_export::read_patch_csv(&dir.path().join("p.csv")).unwrap();
        assert_eq!(rows.len(), 4);
        for row in rows {
            let is_back = row.face.expect("a face number") >= 2;
            let lit = (front > 0.0) != is_back;
            let expect = if lit { 250.0 } else { 0.0 };
            assert!((row.radiosity.x - expect).abs() < 1e-3, "{row:?}");
        }
    }
}
