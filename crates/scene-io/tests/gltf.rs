//! glTF / GLB loading through `mcrad_scene_io::load`, on documents assembled by the tests:
//! node transforms, the emission mapping `E = pi * emissiveFactor * strength`, repairs, and bad
//! input whose messages must name the file and the node, mesh and primitive.

use glam::Vec3;
use mcrad_scene_io::{Loaded, SceneError, Warning, load};
use std::f32::consts::PI;
use std::fs;
use std::path::PathBuf;
use tempfile::TempDir;

/// Buffer, views and accessors of a glTF document being assembled.
#[derive(Default)]
struct Doc {
    bin: Vec<u8>,
    views: Vec<String>,
    accessors: Vec<String>,
}

impl Doc {
    fn view(&mut self, bytes: &[u8]) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        self.views.push(format!(
            r#"{{"buffer":0,"byteOffset":{},"byteLength":{}}}"#,
            self.bin.len(),
            bytes.len()
        ));
        self.bin.extend_from_slice(bytes);
        self.views.len() - 1
    }

    /// A VEC3 float accessor; returns its index.
    fn positions(&mut self, p: &[[f32; 3]]) -> usize {
        let bytes: Vec<u8> = p.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes);
        let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
        for q in p {
            for c in 0..3 {
                lo[c] = lo[c].min(q[c]);
                hi[c] = hi[c].max(q[c]);
            }
        }
        self.accessors.push(format!(
            r#"{{"bufferView":{view},"componentType":5126,"count":{},"type":"VEC3","min":{lo:?},"max":{hi:?}}}"#,
            p.len()
        ));
        self.accessors.len() - 1
    }

    /// A SCALAR u16 accessor; returns its index.
    fn indices(&mut self, i: &[u16]) -> usize {
        let bytes: Vec<u8> = i.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes);
        self.accessors.push(format!(
            r#"{{"bufferView":{view},"componentType":5123,"count":{},"type":"SCALAR"}}"#,
            i.len()
        ));
        self.accessors.len() - 1
    }

    /// The JSON with `rest` (scenes, nodes, meshes, materials) and the buffer given by `buffer`
    /// (its `uri` field, or empty for the GLB binary chunk).
    fn json(&self, rest: &str, buffer_uri: &str) -> String {
        let uri = if buffer_uri.is_empty() {
            String::new()
        } else {
            format!(r#","uri":"{buffer_uri}""#)
        };
        format!(
            r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"byteLength":{}{uri}}}],"bufferViews":[{}],"accessors":[{}],{rest}}}"#,
            self.bin.len(),
            self.views.join(","),
            self.accessors.join(",")
        )
    }

    /// A `.gltf` with the buffer embedded as base64.
    fn gltf(&self, rest: &str) -> String {
        let uri = format!("data:application/octet-stream;base64,{}", base64(&self.bin));
        self.json(rest, &uri)
    }

    /// A `.glb`: header, JSON chunk, BIN chunk.
    fn glb(&self, rest: &str) -> Vec<u8> {
        let mut json = self.json(rest, "").into_bytes();
        while !json.len().is_multiple_of(4) {
            json.push(b' ');
        }
        let mut bin = self.bin.clone();
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let total = 12 + 8 + json.len() + 8 + bin.len();
        let mut out = Vec::with_capacity(total);
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(json.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&json);
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
        out
    }
}

fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// A unit quad in the plane y = 0 facing +y, as 4 positions and 2 triangles.
const QUAD: [[f32; 3]; 4] = [[0., 0., 0.], [0., 0., 1.], [1., 0., 1.], [1., 0., 0.]];
const QUAD_TRIANGLES: [u16; 6] = [0, 1, 2, 0, 2, 3];

/// Materials: 0 "floor" (white: channels of exactly 1.0), 1 "lamp" (emissive with strength 4).
const MATERIALS: &str = r#""materials":[
    {"name":"floor","pbrMetallicRoughness":{"baseColorFactor":[1.0,0.5,1.0,0.3]}},
    {"name":"lamp","pbrMetallicRoughness":{"baseColorFactor":[0.2,0.2,0.2,1]},
     "emissiveFactor":[1.0,0.5,0.25],
     "extensions":{"KHR_materials_emissive_strength":{"emissiveStrength":4.0}}}],
  "extensionsUsed":["KHR_materials_emissive_strength"]"#;

/// Two meshes: 0 the floor (material 0), 1 the lamp (material 1). Node 0 "room" (the floor)
/// scales by 2 and translates by (1, 2, 3); its child node 1 "lamp" translates by (0, 0.5, 0)
/// and rotates by pi about x, so the lamp faces down.
fn two_quads() -> Doc {
    let mut d = Doc::default();
    d.positions(&QUAD);
    d.indices(&QUAD_TRIANGLES);
    d
}

const SCENE: &str = r#""scene":0,"scenes":[{"nodes":[0]}],
  "nodes":[
    {"name":"room","mesh":0,"translation":[1,2,3],"scale":[2,2,2],"children":[1]},
    {"name":"lamp","mesh":1,"translation":[0,0.5,0],"rotation":[1,0,0,0]}],
  "meshes":[
    {"name":"floor","primitives":[{"attributes":{"POSITION":0},"indices":1,"material":0}]},
    {"name":"lamp","primitives":[{"attributes":{"POSITION":0},"indices":1,"material":1}]}]"#;

fn write(name: &str, contents: &[u8]) -> (TempDir, PathBuf) {
    let dir = TempDir::new().unwrap();
    let path = dir.path().join(name);
    fs::write(&path, contents).unwrap();
    (dir, path)
}

fn load_ok(name: &str, contents: &[u8]) -> Loaded {
    let (_dir, path) = write(name, contents);
    load(&path).unwrap_or_else(|e| panic!("{name} should load: {e}"))
}

fn load_err(name: &str, contents: &[u8]) -> (String, SceneError) {
    let (_dir, path) = write(name, contents);
    match load(&path) {
        Ok(_) => panic!("{name} should not load"),
        Err(e) => (e.to_string(), e),
    }
}

fn assert_contains(message: &str, parts: &[&str]) {
    for p in parts {
        assert!(
            message.contains(p),
            "message {message:?} should contain {p:?}"
        );
    }
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).abs().max_element() < 1e-5
}

fn check_two_quads(loaded: &Loaded) {
    let Loaded {
        scene, warnings, ..
    } = loaded;
    assert_eq!(
        warnings,
        &vec![Warning::ReflectanceClamped {
            material: "floor".into(),
            count: 2
        }]
    );
    let faces = scene.faces();
    assert_eq!(faces.len(), 4);
    let sources: Vec<u32> = faces.iter().map(|f| f.source).collect();
    assert_eq!(sources, vec![0, 1, 2, 3]);
    assert!(faces.iter().all(|f| f.vertices.len() == 3));

    // Floor: world = T(1,2,3) S(2).
    let at = |face: usize, corner: usize| scene.positions()[faces[face].vertices[corner] as usize];
    assert!(close(at(0, 0), Vec3::new(1., 2., 3.)));
    assert!(close(at(0, 2), Vec3::new(3., 2., 5.)));
    assert!(close(scene.face_normal(&faces[0]), Vec3::Y));
    assert!((scene.face_area(&faces[0]) - 2.0).abs() < 1e-5);
    // Lamp: world = T(1,2,3) S(2) T(0,0.5,0) R_x(pi): (1,0,1) -> (1,0,-1) -> (1,0.5,-1) -> (3,3,1).
    assert!(close(at(2, 2), Vec3::new(3., 3., 1.)));
    assert!(close(scene.face_normal(&faces[2]), -Vec3::Y));

    let floor = &scene.materials()[faces[0].material as usize];
    assert_eq!(
        floor.reflectance,
        Vec3::new(0.999, 0.5, 0.999),
        "alpha ignored"
    );
    assert_eq!(floor.emission, Vec3::ZERO);
    let lamp = &scene.materials()[faces[2].material as usize];
    assert_eq!(lamp.name, "lamp");
    assert_eq!(lamp.reflectance, Vec3::splat(0.2));
    let expected = PI * 4.0 * Vec3::new(1.0, 0.5, 0.25);
    assert!(
        close(lamp.emission, expected),
        "E = pi L: {}",
        lamp.emission
    );
}

#[test]
fn gltf_with_embedded_buffer_and_node_transforms() {
    let doc = two_quads();
    let json = doc.gltf(&format!("{SCENE},{MATERIALS}"));
    check_two_quads(&load_ok("scene.gltf", json.as_bytes()));
}

/// `doubleSided` makes a material's faces two-sided; the built-in default material (faces
/// without one) stays one-sided, as glTF's; `LoadOptions::two_sided` is for OBJ and changes
/// nothing here.
#[test]
fn double_sided_materials_are_two_sided() {
    let mut doc = two_quads();
    let other = doc.indices(&QUAD_TRIANGLES);
    let rest = format!(
        r#""nodes":[{{"mesh":0}}],
      "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"material":0}},
                               {{"attributes":{{"POSITION":0}},"indices":1,"material":1}},
                               {{"attributes":{{"POSITION":0}},"indices":{other}}}]}}],
      "materials":[{{"name":"leaf","doubleSided":true}},
                   {{"name":"lamp","emissiveFactor":[1,1,1]}}]"#
    );
    let json = doc.gltf(&rest);
    let (_dir, path) = write("leaf.gltf", json.as_bytes());
    for two_sided in [false, true] {
        let options = mcrad_scene_io::LoadOptions {
            two_sided,
            ..Default::default()
        };
        let scene = mcrad_scene_io::load_with(&path, &options).unwrap().scene;
        let names: Vec<&str> = scene.materials().iter().map(|m| m.name.as_str()).collect();
        assert_eq!(names, ["leaf", "lamp", "default"]);
        assert!(scene.has_two_sided());
        assert_eq!(
            (0..3).map(|m| scene.is_two_sided(m)).collect::<Vec<_>>(),
            [true, false, false]
        );
    }
    // without doubleSided: one-sided throughout
    let json = json.replace(r#","doubleSided":true"#, "");
    let scene = load_ok("one.gltf", json.as_bytes()).scene;
    assert!(!scene.has_two_sided() && !scene.is_two_sided(0));
}

#[test]
fn glb_with_binary_chunk() {
    let doc = two_quads();
    check_two_quads(&load_ok(
        "scene.GLB",
        &doc.glb(&format!("{SCENE},{MATERIALS}")),
    ));
}

#[test]
fn gltf_with_external_buffer_and_a_missing_one() {
    let doc = two_quads();
    let json = doc.json(&format!("{SCENE},{MATERIALS}"), "scene%20data.bin");
    let (dir, path) = write("scene.gltf", json.as_bytes());
    let e = load(&path).unwrap_err();
    assert_contains(
        &e.to_string(),
        &["scene.gltf", "scene data.bin", "cannot read"],
    );
    fs::write(dir.path().join("scene data.bin"), &doc.bin).unwrap();
    check_two_quads(&load(&path).unwrap());
}

#[test]
fn mirroring_transform_keeps_front_faces_front() {
    let doc = two_quads();
    let rest = r#""scenes":[{"nodes":[0,1]}],
      "nodes":[{"mesh":0,"scale":[-1,1,1]},{"mesh":1,"translation":[0,1,0],"scale":[1,-1,1]}],
      "meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1,"material":0}]},
                {"primitives":[{"attributes":{"POSITION":0},"indices":1,"material":1}]}]"#;
    let Loaded { scene, .. } = load_ok(
        "m.gltf",
        doc.gltf(&format!("{rest},{MATERIALS}")).as_bytes(),
    );
    let f = scene.faces();
    // x mirrored: the quad still faces +y. y mirrored: the quad turns over and faces -y.
    assert!(close(scene.face_normal(&f[0]), Vec3::Y));
    assert!(close(scene.face_normal(&f[2]), -Vec3::Y));
}

#[test]
fn default_material_skipped_primitives_textures_and_root_nodes_without_scene() {
    let mut doc = two_quads();
    let points = doc.positions(&[[5., 5., 5.]]);
    // No "scenes": every root node is walked. Node 1 is a child of node 0.
    let rest = format!(
        r#""nodes":[{{"mesh":0,"children":[1]}},{{"mesh":1}}],
      "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}},
                               {{"attributes":{{"POSITION":{points}}},"mode":0}}]}},
                {{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"material":0}}]}}],
      "textures":[{{"source":0}}],"images":[{{"uri":"never_read.png"}}],
      "materials":[{{"name":"lit","emissiveFactor":[1,1,1],
                    "pbrMetallicRoughness":{{"baseColorFactor":[0.5,0.5,0.5,1],"baseColorTexture":{{"index":0}}}}}}]"#
    );
    let Loaded {
        scene, warnings, ..
    } = load_ok("d.gltf", doc.gltf(&rest).as_bytes());
    assert_eq!(
        warnings,
        vec![
            Warning::PrimitivesSkipped { count: 1 },
            Warning::DefaultMaterial { faces: 2 },
        ]
    );
    let names: Vec<&str> = scene
        .faces()
        .iter()
        .map(|f| scene.materials()[f.material as usize].name.as_str())
        .collect();
    assert_eq!(names, ["default", "default", "lit", "lit"]);
    assert_eq!(scene.materials()[1].reflectance, Vec3::splat(0.5));
}

#[test]
fn index_out_of_range_names_node_mesh_and_primitive() {
    let mut doc = Doc::default();
    doc.positions(&QUAD);
    doc.indices(&[0, 1, 2, 0, 2, 9]);
    let (m, e) = load_err(
        "bad.gltf",
        doc.gltf(&format!("{SCENE},{MATERIALS}")).as_bytes(),
    );
    assert!(matches!(
        e.innermost(),
        SceneError::IndexOutOfRange { index: 9, count: 4 }
    ));
    assert_contains(
        &m,
        &["bad.gltf (node 0 'room', mesh 0 'floor', primitive 0): vertex index 9 is out of range"],
    );
}

#[test]
fn non_finite_position_names_the_primitive() {
    let mut doc = Doc::default();
    let mut quad = QUAD;
    quad[2][1] = f32::NAN;
    // min/max must be numbers in JSON: write the accessor by hand.
    doc.positions(&QUAD);
    let bytes: Vec<u8> = quad
        .iter()
        .flatten()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    doc.bin[..48].copy_from_slice(&bytes);
    doc.indices(&QUAD_TRIANGLES);
    let (m, _) = load_err("nan.glb", &doc.glb(&format!("{SCENE},{MATERIALS}")));
    assert_contains(
        &m,
        &[
            "nan.glb (node 0 'room'",
            "vertex 2 has a non-finite coordinate (1, NaN, 1)",
        ],
    );
}

#[test]
fn reflectance_above_one_and_negative_emission() {
    let doc = two_quads();
    let materials = MATERIALS.replace("[1.0,0.5,1.0,0.3]", "[1.5,0.5,1.0,1]");
    let (m, _) = load_err(
        "r.gltf",
        doc.gltf(&format!("{SCENE},{materials}")).as_bytes(),
    );
    assert_contains(
        &m,
        &["r.gltf: material 'floor' has reflectance (1.5, 0.5, 0.999)"],
    );
    let materials = MATERIALS.replace("\"emissiveStrength\":4.0", "\"emissiveStrength\":-1.0");
    let (m, _) = load_err(
        "e.gltf",
        doc.gltf(&format!("{SCENE},{materials}")).as_bytes(),
    );
    assert_contains(&m, &["e.gltf: material 'lamp' has negative emission"]);
}

#[test]
fn no_emitter_and_empty_scene() {
    let doc = two_quads();
    let materials = MATERIALS.replace("[1.0,0.5,0.25]", "[0,0,0]");
    let (m, _) = load_err(
        "n.gltf",
        doc.gltf(&format!("{SCENE},{materials}")).as_bytes(),
    );
    assert_contains(
        &m,
        &["n.gltf: the scene has no emitting face", "and no light"],
    );
    let (m, _) = load_err(
        "empty.gltf",
        doc.gltf(r#""scenes":[{"nodes":[]}]"#).as_bytes(),
    );
    assert_contains(&m, &["empty.gltf: the scene has no faces"]);
}

/// The floor of [`two_quads`] unlit, with `KHR_lights_punctual` lights on nodes: a point light
/// of 683 cd (colour (1, 0.5, 0.25)) under the scaled "room" node at local (0, 1, 0), a spot
/// turned to look down -y, and a directional light looking down -y with an angular diameter
/// of 2 degrees in its extras.
const LIT: &str = r#""scene":0,"scenes":[{"nodes":[0,2,3]}],
  "nodes":[
    {"name":"room","mesh":0,"translation":[1,2,3],"scale":[2,2,2],"children":[1]},
    {"name":"bulb","translation":[0,1,0],"extensions":{"KHR_lights_punctual":{"light":0}}},
    {"name":"spot","translation":[0,4,0],"rotation":[-0.70710678,0,0,0.70710678],
     "extensions":{"KHR_lights_punctual":{"light":1}}},
    {"name":"sun","rotation":[-0.70710678,0,0,0.70710678],
     "extensions":{"KHR_lights_punctual":{"light":2}}}],
  "meshes":[
    {"name":"floor","primitives":[{"attributes":{"POSITION":0},"indices":1,"material":0}]}],
  "materials":[{"name":"floor","pbrMetallicRoughness":{"baseColorFactor":[0.5,0.5,0.5,1]}}],
  "extensions":{"KHR_lights_punctual":{"lights":[
    {"type":"point","intensity":683,"color":[1,0.5,0.25],"range":10},
    {"type":"spot","intensity":1366,"spot":{"innerConeAngle":0.1,"outerConeAngle":0.3}},
    {"type":"directional","intensity":68300,"extras":{"angular_diameter":2.0}}]}},
  "extensionsUsed":["KHR_lights_punctual"]"#;

#[test]
fn punctual_lights_are_placed_by_their_nodes_in_radiometric_units() {
    use mcrad_scene_io::{LoadOptions, load_with};
    let doc = two_quads();
    let loaded = load_ok("lit.gltf", doc.gltf(LIT).as_bytes());
    let lights = loaded.scene.lights();
    assert_eq!(lights.len(), 3);
    let close = |a: Vec3, b: Vec3| (a - b).length() < 1e-5;
    let mcrad_scene_io::Light::Point(p) = &lights[0] else {
        panic!("{:?}", lights[0])
    };
    // Under the room's scale 2 and translation (1, 2, 3): local (0, 1, 0) is (1, 4, 3); the
    // range is not scaled.
    assert!(
        close(p.position, Vec3::new(1.0, 4.0, 3.0)),
        "{}",
        p.position
    );
    assert!((p.intensity - glam::DVec3::new(1.0, 0.5, 0.25)).length() < 1e-12);
    assert_eq!(p.range, Some(10.0));
    let mcrad_scene_io::Light::Spot(s) = &lights[1] else {
        panic!("{:?}", lights[1])
    };
    assert!(close(s.direction, Vec3::NEG_Y), "{}", s.direction);
    assert!((s.point.intensity.x - 2.0).abs() < 1e-12);
    assert!((s.inner - 0.1).abs() < 1e-7 && (s.outer - 0.3).abs() < 1e-7);
    let mcrad_scene_io::Light::Sun(sun) = &lights[2] else {
        panic!("{:?}", lights[2])
    };
    assert!(close(sun.direction, Vec3::Y), "{}", sun.direction);
    assert!((sun.irradiance.x - 100.0).abs() < 1e-9);
    assert!((sun.diameter - 2f64.to_radians()).abs() < 1e-12);

    // Efficacy 1 reads the intensities as radiometric; a caller's sun comes last.
    let (_dir, path) = write("lit.gltf", doc.gltf(LIT).as_bytes());
    let extra = mcrad_scene_io::Light::Sun(mcrad_scene_io::Sun {
        direction: Vec3::Z,
        irradiance: glam::DVec3::ONE,
        diameter: 0.0,
    });
    let options = LoadOptions {
        light_efficacy: 1.0,
        lights: vec![extra.clone()],
        ..LoadOptions::default()
    };
    let loaded = load_with(&path, &options).unwrap();
    let lights = loaded.scene.lights();
    assert_eq!(lights.len(), 4);
    let mcrad_scene_io::Light::Point(p) = &lights[0] else {
        panic!()
    };
    assert!((p.intensity.x - 683.0).abs() < 1e-9);
    assert_eq!(lights[3], extra);

    // A bad cone is refused with the light named.
    let bad = LIT.replace("\"innerConeAngle\":0.1", "\"innerConeAngle\":0.5");
    let (m, _) = load_err("bad.gltf", doc.gltf(&bad).as_bytes());
    assert_contains(&m, &["bad.gltf", "light 1 (spot): cone angles inner 0.5"]);
}

#[test]
fn malformed_files() {
    let (m, _) = load_err("x.gltf", b"{ not json");
    assert_contains(&m, &["x.gltf", "not valid glTF"]);
    let (m, _) = load_err("x.glb", b"glTF\x02\0\0\0\x0c\0\0\0");
    assert_contains(&m, &["x.glb", "not valid glTF"]);
    // An accessor reading past its buffer view.
    let mut doc = two_quads();
    doc.views[0] = doc.views[0].replace("\"byteLength\":48", "\"byteLength\":40");
    let (m, _) = load_err(
        "short.gltf",
        doc.gltf(&format!("{SCENE},{MATERIALS}")).as_bytes(),
    );
    assert_contains(
        &m,
        &[
            "short.gltf (node 0 'room', mesh 0 'floor', primitive 0)",
            "reads past the end of buffer view 0",
        ],
    );
    let e = load(&PathBuf::from("/nonexistent/dir/scene.glb")).unwrap_err();
    assert_contains(&e.to_string(), &["cannot read", "scene.glb"]);
}

/// Must not panic: truncations of a valid GLB and of its JSON, and single-byte corruptions.
#[test]
fn corrupted_files_error_without_panicking() {
    let doc = two_quads();
    let glb = doc.glb(&format!("{SCENE},{MATERIALS}"));
    let json = doc.gltf(&format!("{SCENE},{MATERIALS}")).into_bytes();
    let dir = TempDir::new().unwrap();
    let run = |name: &str, bytes: &[u8]| {
        let path = dir.path().join(name);
        fs::write(&path, bytes).unwrap();
        let _ = load(&path);
    };
    // Every cut in the header and chunk headers, every 4th elsewhere (file writes are slow).
    for n in (0..glb.len()).filter(|&n| n < 40 || n % 4 == 1) {
        run("t.glb", &glb[..n]);
    }
    for n in (0..json.len()).step_by(29) {
        run("t.gltf", &json[..n]);
    }
    // A deterministic walk over positions and byte values (one seeded PCG stream).
    use rand_core::Rng as _;
    let mut stream = rand_pcg::Pcg32::new(1, 0x0a02_bdbf_7bb3_c0a7);
    for _ in 0..500 {
        let mut bytes = glb.clone();
        let at = (stream.next_u64() % bytes.len() as u64) as usize;
        bytes[at] = (stream.next_u32() >> 24) as u8;
        run("c.glb", &bytes);
    }
}

#[test]
fn first_perspective_camera_is_placed_by_its_node() {
    // Node 2 holds an orthographic camera (ignored), node 3 a perspective one 1 unit up the
    // room's +z, turned by pi/2 about +y so it looks along -x (glTF cameras look along -z).
    let doc = two_quads();
    let (s, c) = (
        std::f32::consts::FRAC_1_SQRT_2,
        std::f32::consts::FRAC_1_SQRT_2,
    );
    let scene = format!(
        r#""scene":0,"scenes":[{{"nodes":[0,2,3]}}],
  "nodes":[
    {{"name":"room","mesh":0,"translation":[1,2,3],"scale":[2,2,2],"children":[1]}},
    {{"name":"lamp","mesh":1,"translation":[0,0.5,0],"rotation":[1,0,0,0]}},
    {{"name":"ortho","camera":0}},
    {{"name":"eye","camera":1,"translation":[0,0,1],"rotation":[0,{s},0,{c}]}}],
  "cameras":[
    {{"type":"orthographic","orthographic":{{"xmag":1,"ymag":1,"znear":0.1,"zfar":10}}}},
    {{"type":"perspective","perspective":{{"yfov":0.5,"znear":0.1}}}}],
  "meshes":[
    {{"name":"floor","primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"material":0}}]}},
    {{"name":"lamp","primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"material":1}}]}}]"#
    );
    let loaded = load_ok(
        "camera.gltf",
        doc.gltf(&format!("{scene},{MATERIALS}")).as_bytes(),
    );
    let camera = loaded.camera.expect("the perspective camera");
    assert!(close(camera.eye, Vec3::new(0.0, 0.0, 1.0)), "{camera:?}");
    assert!(
        close(camera.forward, Vec3::new(-1.0, 0.0, 0.0)),
        "{camera:?}"
    );
    assert!(close(camera.up, Vec3::Y), "{camera:?}");
    assert!((camera.fov_y_degrees - 0.5f32.to_degrees()).abs() < 1e-4);
    // OBJ files carry no camera; a glTF without one neither.
    assert!(
        load_ok(
            "plain.gltf",
            doc.gltf(&format!("{SCENE},{MATERIALS}")).as_bytes()
        )
        .camera
        .is_none()
    );
}

/// A 2 x 1 PNG: left texel white, right black.
fn half_white_png() -> Vec<u8> {
    let mut png = Vec::new();
    image::ImageEncoder::write_image(
        image::codecs::png::PngEncoder::new(&mut png),
        &[255, 255, 255, 0, 0, 0],
        2,
        1,
        image::ExtendedColorType::Rgb8,
    )
    .unwrap();
    png
}

#[test]
fn textured_faces_map_their_texture_and_unreadable_textures_are_warned() {
    // u = x, v = z over the quad
    let png = format!("data:image/png;base64,{}", base64(&half_white_png()));
    let material = r#"{"emissiveFactor":[1,1,1],"alphaMode":"MASK",
        "pbrMetallicRoughness":{"baseColorFactor":[0.8,0.8,0.8,1],"baseColorTexture":{"index":0}}}"#;
    let quad =
        |image: &str| textured_quad(material, image, r#"{"wrapS":33071,"wrapT":33071}"#, None);
    let Loaded {
        scene, warnings, ..
    } = quad(&png);
    assert!(warnings.is_empty(), "{warnings:?}");
    let textures = scene.textures().expect("textured");
    // the material's factor stays 0.8; the texture over a polygon of the quad: white (1) on
    // the left quarter, black (0) on the right quarter (sRGB 0 and 255 decode to 0 and 1)
    assert_eq!(scene.materials()[0].reflectance, Vec3::splat(0.8));
    for source in 0..2 {
        let (left, emission) = textures.average(source, &strip(0.0, 0.25)).unwrap();
        let (right, _) = textures.average(source, &strip(0.75, 1.0)).unwrap();
        assert!((left - Vec3::ONE).abs().max_element() < 1e-5, "{left}");
        assert!(right.abs().max_element() < 1e-5, "{right}");
        assert_eq!(emission, Vec3::ONE, "no emissive texture");
    }
    // a missing image: warned, the faces keep the factor alone
    let Loaded {
        scene, warnings, ..
    } = quad("missing.png");
    let unreadable = warnings
        .iter()
        .find(|w| {
            matches!(
                w,
                Warning::TexturesUnreadable {
                    count: 1,
                    first: 0,
                    ..
                }
            )
        })
        .unwrap_or_else(|| panic!("{warnings:?}"));
    assert!(
        unreadable.to_string().contains("missing.png"),
        "{unreadable}"
    );
    // (the faces keep a mapping for their alpha mode only)
    let textures = scene.textures().expect("alpha-tested");
    assert!(
        textures.faces.iter().flatten().all(|m| m.base.is_none()),
        "no texture left to map"
    );
    // a KTX2 texture (the image crate reads none) and a texture over the size limit: warned
    let ktx2 = format!(
        "data:image/ktx2;base64,{}",
        base64(b"\xabKTX 20\xbb\r\n\x1a\n rest of a KTX2 file")
    );
    let mut huge = Vec::new();
    image::ImageEncoder::write_image(
        image::codecs::png::PngEncoder::new(&mut huge),
        &vec![0u8; 16385],
        16385,
        1,
        image::ExtendedColorType::L8,
    )
    .unwrap();
    let huge = format!("data:image/png;base64,{}", base64(&huge));
    for image in [ktx2, huge] {
        let Loaded { warnings, .. } = quad(&image);
        assert!(
            warnings
                .iter()
                .any(|w| matches!(w, Warning::TexturesUnreadable { count: 1, .. })),
            "{warnings:?}"
        );
    }
}

/// A PNG of `width × height` texels from `rgba` (8 bits per channel, top row first).
fn png_rgba(width: u32, height: u32, rgba: &[u8]) -> String {
    let mut png = Vec::new();
    image::ImageEncoder::write_image(
        image::codecs::png::PngEncoder::new(&mut png),
        rgba,
        width,
        height,
        image::ExtendedColorType::Rgba8,
    )
    .unwrap();
    format!("data:image/png;base64,{}", base64(&png))
}

/// The unit quad (u = x, v = z) with material `material` (JSON) whose textures are image 0 at
/// `image` (a URI), sampler `sampler` (JSON) and, if `colors`, vertex colours `COLOR_0`
/// (its four corners as given).
fn textured_quad(material: &str, image: &str, sampler: &str, colors: Option<[f32; 12]>) -> Loaded {
    let mut doc = two_quads();
    let uv: Vec<u8> = [[0f32, 0.], [0., 1.], [1., 1.], [1., 0.]]
        .iter()
        .flatten()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    let view = doc.view(&uv);
    doc.accessors.push(format!(
        r#"{{"bufferView":{view},"componentType":5126,"count":4,"type":"VEC2"}}"#
    ));
    let color = colors.map_or(String::new(), |c| {
        let bytes: Vec<u8> = c.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = doc.view(&bytes);
        doc.accessors.push(format!(
            r#"{{"bufferView":{view},"componentType":5126,"count":4,"type":"VEC3"}}"#
        ));
        format!(r#","COLOR_0":{}"#, doc.accessors.len() - 1)
    });
    let rest = format!(
        r#""nodes":[{{"mesh":0}}],"scenes":[{{"nodes":[0]}}],"scene":0,
          "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"TEXCOORD_0":2{color}}},"indices":1,"material":0}}]}}],
          "samplers":[{sampler}],
          "textures":[{{"source":0,"sampler":0}}],"images":[{{"uri":"{image}"}}],
          "materials":[{material}],"extensionsUsed":["KHR_texture_transform"]"#
    );
    load_ok("t.gltf", doc.gltf(&rest).as_bytes())
}

/// The quad's strip `x0 <= x <= x1` (all of z), as a polygon of the quad's plane.
fn strip(x0: f32, x1: f32) -> [Vec3; 4] {
    [
        Vec3::new(x0, 0., 0.),
        Vec3::new(x0, 0., 1.),
        Vec3::new(x1, 0., 1.),
        Vec3::new(x1, 0., 0.),
    ]
}

#[test]
fn the_clamp_is_warned_once_per_material_and_only_where_the_texture_reaches_one() {
    let white = |factor: &str| {
        format!(
            r#"{{"name":"m","emissiveFactor":[1,1,1],"pbrMetallicRoughness":{{"baseColorFactor":{factor},"baseColorTexture":{{"index":0}}}}}}"#
        )
    };
    let clamp = r#"{"wrapS":33071,"wrapT":33071}"#;
    // a texture whose brightest texel is sRGB 200 (linear 0.578): a factor of 1.0 is glTF's
    // default and the product never reaches 1: no warning, and the patch reflectance is the
    // texel itself (the factor's 1.0 is not replaced by 0.999)
    let grey = png_rgba(2, 1, &[200, 200, 200, 255, 100, 100, 100, 255]);
    let Loaded {
        scene, warnings, ..
    } = textured_quad(&white("[1,1,1,1]"), &grey, clamp, None);
    assert!(warnings.is_empty(), "{warnings:?}");
    let rho = scene.materials()[0].reflectance;
    let (albedo, _) = scene
        .textures()
        .unwrap()
        .average(0, &strip(0.0, 0.25))
        .unwrap();
    let texel = mcrad_scene_io::srgb_to_linear(200.0 / 255.0);
    assert!(((rho * albedo) - Vec3::splat(texel)).abs().max_element() < 1e-6);
    // a white texel (255) under a factor of 1.0 in two channels: one warning, 2 channels
    let white_texel = png_rgba(2, 1, &[255, 255, 255, 255, 0, 0, 0, 255]);
    let Loaded { warnings, .. } = textured_quad(&white("[1,0.5,1,1]"), &white_texel, clamp, None);
    assert_eq!(
        warnings,
        vec![Warning::ReflectanceClamped {
            material: "m".into(),
            count: 2
        }]
    );
    assert!(
        warnings[0]
            .to_string()
            .contains("reaches 1.0 in 2 channels")
    );
    // vertex colours count too: red 0.5 on every corner keeps the red channel below 1
    let Loaded { warnings, .. } = textured_quad(
        &white("[1,1,1,1]"),
        &white_texel,
        clamp,
        Some([0.5, 1., 1., 0.5, 1., 1., 0.5, 1., 1., 0.5, 1., 1.]),
    );
    assert_eq!(
        warnings,
        vec![Warning::ReflectanceClamped {
            material: "m".into(),
            count: 2
        }]
    );
}

#[test]
fn jpeg_textures_decode() {
    let mut jpeg = Vec::new();
    image::ImageEncoder::write_image(
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95),
        &[128u8; 8 * 8 * 3],
        8,
        8,
        image::ExtendedColorType::Rgb8,
    )
    .unwrap();
    let uri = format!("data:image/jpeg;base64,{}", base64(&jpeg));
    let material =
        r#"{"emissiveFactor":[1,1,1],"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#;
    let Loaded {
        scene, warnings, ..
    } = textured_quad(material, &uri, "{}", None);
    assert!(warnings.is_empty(), "{warnings:?}");
    let (albedo, _) = scene
        .textures()
        .unwrap()
        .average(0, &strip(0.0, 1.0))
        .unwrap();
    let grey = mcrad_scene_io::srgb_to_linear(128.0 / 255.0);
    assert!(
        (albedo - Vec3::splat(grey)).abs().max_element() < 0.02,
        "{albedo}"
    );
}

#[test]
fn texture_transforms_move_the_lookup() {
    // 2 x 2 texels: top row red, green; bottom row blue, white (sRGB 0 and 255: linear 0, 1)
    let image = png_rgba(
        2,
        2,
        &[
            255, 0, 0, 255, 0, 255, 0, 255, //
            0, 0, 255, 255, 255, 255, 255, 255,
        ],
    );
    let material = |transform: &str| {
        format!(
            r#"{{"emissiveFactor":[1,1,1],"pbrMetallicRoughness":{{"baseColorFactor":[0.5,0.5,0.5,1],
              "baseColorTexture":{{"index":0,"texCoord":1,"extensions":{{"KHR_texture_transform":{transform}}}}}}}}}"#
        )
    };
    let centre = [
        Vec3::new(0.49, 0., 0.49),
        Vec3::new(0.49, 0., 0.51),
        Vec3::new(0.51, 0., 0.51),
        Vec3::new(0.51, 0., 0.49),
    ];
    let albedo = |transform: &str| {
        let Loaded { scene, .. } = textured_quad(&material(transform), &image, "{}", None);
        scene.textures().map(|t| t.average(0, &centre).unwrap().0)
    };
    // The quad's centre has uv (0.5, 0.5). The specification's example (offset (0, 1), a
    // quarter turn, scale 1/2): uv' = offset + R (scale ⊙ uv) with R = [[cos, sin], [-sin,
    // cos]] gives (0.5 v, 1 - 0.5 u) = (0.25, 0.75), the centre of the bottom-left texel (blue).
    // (Without the rotation: (0.25, 1.25), which repeats to red; the rotation the other way:
    // (-0.25, 1.25), green; no transform: the mean of all four.) texCoord 0 replaces the
    // textureInfo's 1, which the primitive does not have.
    let spec = r#"{"texCoord":0,"offset":[0,1],"rotation":1.5707963,"scale":[0.5,0.5]}"#;
    let blue = albedo(spec).expect("texCoord 0 is read");
    assert!((blue - Vec3::Z).abs().max_element() < 0.03, "{blue}");
    // offset alone: (0.5, 0.5) + (0.25, -0.25) = (0.75, 0.25), the top-right texel (green)
    let green = albedo(r#"{"texCoord":0,"offset":[0.25,-0.25]}"#).unwrap();
    assert!((green - Vec3::Y).abs().max_element() < 0.03, "{green}");
    // without the override the textureInfo's set 1 is missing: no mapping
    assert!(albedo(r#"{"offset":[0.25,-0.25]}"#).is_none());
}

#[test]
fn alpha_masks_and_blends_decide_where_light_passes() {
    // a 4 x 4 checker of alpha 255 and 0 (top-left opaque), white
    let texels: Vec<u8> = (0..16)
        .flat_map(|i| {
            let a = if (i % 4 + i / 4) % 2 == 0 { 255 } else { 0 };
            [255, 255, 255, a]
        })
        .collect();
    let image = png_rgba(4, 4, &texels);
    let material = |mode: &str, factor_alpha: f32| {
        format!(
            r#"{{"emissiveFactor":[1,1,1],{mode},"pbrMetallicRoughness":{{
              "baseColorFactor":[0.5,0.5,0.5,{factor_alpha}],"baseColorTexture":{{"index":0}}}}}}"#
        )
    };
    let whole = strip(0.0, 1.0);
    // MASK (cut-off 0.5): the checker's opaque half; light passes the cells of alpha 0 (the
    // texel at u = x, v = z: cell (1, 0) is cut out, (0, 0) and (1, 1) are not)
    let Loaded {
        scene, warnings, ..
    } = textured_quad(&material(r#""alphaMode":"MASK""#, 1.0), &image, "{}", None);
    assert!(warnings.is_empty(), "{warnings:?}");
    let t = scene.textures().unwrap();
    assert!(t.has_alpha());
    for source in 0..2 {
        let c = t.coverage(source, &whole).unwrap();
        assert!((c - 0.5).abs() < 0.01, "{c}");
    }
    let cell = |i: f32, j: f32| Vec3::new((i + 0.5) / 4.0, 0.0, (j + 0.5) / 4.0);
    let source_of = |p: Vec3| if p.x <= p.z { 0 } else { 1 };
    for (i, j, cut) in [
        (0., 0., false),
        (1., 0., true),
        (1., 1., false),
        (2., 3., true),
    ] {
        let p = cell(i, j);
        assert_eq!(t.passes(source_of(p), p, 0.5), cut, "cell {i} {j}");
    }
    // a cut-off above the opaque texels' alpha factor: everything passes
    let Loaded { scene, .. } = textured_quad(
        &material(r#""alphaMode":"MASK","alphaCutoff":0.6"#, 0.5),
        &image,
        "{}",
        None,
    );
    let t = scene.textures().unwrap();
    assert_eq!(t.coverage(0, &whole), Some(0.0));
    // BLEND: the mean alpha (half the cells, times the factor 0.5); an opaque cell passes a
    // ray with probability 1 - 0.5, decided by the caller's number
    let Loaded { scene, .. } =
        textured_quad(&material(r#""alphaMode":"BLEND""#, 0.5), &image, "{}", None);
    let t = scene.textures().unwrap();
    let c = t.coverage(1, &whole).unwrap();
    assert!((c - 0.25).abs() < 0.01, "{c}");
    let p = cell(1.0, 1.0);
    assert!(!t.passes(source_of(p), p, 0.3));
    assert!(t.passes(source_of(p), p, 0.7));
    // OPAQUE: no alpha test, whatever the texture's alpha
    let Loaded { scene, .. } = textured_quad(
        &material(r#""alphaMode":"OPAQUE""#, 1.0),
        &image,
        "{}",
        None,
    );
    let t = scene.textures().unwrap();
    assert!(!t.has_alpha());
    assert_eq!(t.coverage(0, &whole), None);
    assert!(!t.passes(0, cell(1.0, 0.0), 0.5));
}
