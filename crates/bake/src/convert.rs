//! A scene written as a glTF document (for baking an OBJ scene, and for the bundled glTF scenes).

use glam::Vec3;
use mcrad_scene_io::{Camera, Scene};
use serde_json::json;

/// A glTF document for `scene` (an OBJ scene to bake, a bundled scene in glTF): its JSON and
/// its binary buffer, named `bin_uri` in the document (`None`: the GLB's own binary chunk).
/// Faces are fanned into triangles, one primitive per material (in material order, faces in
/// file order within it); materials become `baseColorFactor = rho`, `metallicFactor = 0`,
/// `roughnessFactor = 1` and emission `E / pi` as `emissiveFactor` (scaled into `[0, 1]` with
/// `KHR_materials_emissive_strength`), so reading it back gives the same reflectance and
/// emission. `camera` (if any) becomes the first camera, aspect 1.
pub fn gltf_from_scene(
    scene: &Scene,
    camera: Option<&Camera>,
    bin_uri: Option<&str>,
) -> (String, Vec<u8>) {
    let mut bin = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut primitives = Vec::new();
    let positions = scene.positions();
    for (m, _) in scene.materials().iter().enumerate() {
        let mut used: Vec<u32> = Vec::new();
        let mut map = std::collections::HashMap::new();
        let mut indices: Vec<u32> = Vec::new();
        for f in scene.faces().iter().filter(|f| f.material as usize == m) {
            for k in 1..f.vertices.len() - 1 {
                for v in [f.vertices[0], f.vertices[k], f.vertices[k + 1]] {
                    let i = *map.entry(v).or_insert_with(|| {
                        used.push(v);
                        used.len() as u32 - 1
                    });
                    indices.push(i);
                }
            }
        }
        if indices.is_empty() {
            continue;
        }
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        let start = bin.len();
        for &v in &used {
            let p = positions[v as usize];
            lo = lo.min(p);
            hi = hi.max(p);
            bin.extend(p.to_array().iter().flat_map(|x| x.to_le_bytes()));
        }
        views.push(json!({"buffer": 0, "byteOffset": start, "byteLength": bin.len() - start, "target": 34962}));
        accessors.push(json!({"bufferView": views.len() - 1, "componentType": 5126,
            "count": used.len(), "type": "VEC3", "min": lo.to_array(), "max": hi.to_array()}));
        let start = bin.len();
        bin.extend(indices.iter().flat_map(|x| x.to_le_bytes()));
        views.push(json!({"buffer": 0, "byteOffset": start, "byteLength": bin.len() - start, "target": 34963}));
        accessors.push(json!({"bufferView": views.len() - 1, "componentType": 5125,
            "count": indices.len(), "type": "SCALAR"}));
        primitives.push(json!({"attributes": {"POSITION": accessors.len() - 2},
            "indices": accessors.len() - 1, "material": m}));
    }
    let materials: Vec<_> = scene
        .materials()
        .iter()
        .map(|m| {
            // glTF's emissive factor is radiance and at most 1: the rest in emissive strength
            let l = m.emission / std::f32::consts::PI;
            let strength = l.max_element().max(1.0);
            json!({
                "name": m.name,
                "pbrMetallicRoughness": {
                    "baseColorFactor": [m.reflectance.x, m.reflectance.y, m.reflectance.z, 1.0],
                    "metallicFactor": 0.0, "roughnessFactor": 1.0
                },
                "emissiveFactor": (l / strength).to_array(),
                "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": strength}}
            })
        })
        .collect();
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": "cargo xtask gen-scenes"},
        "extensionsUsed": ["KHR_materials_emissive_strength"],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": accessors,
        "materials": materials,
        "meshes": [{"name": "scene", "primitives": primitives}],
        "nodes": [{"name": "scene", "mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0
    });
    if let Some(uri) = bin_uri {
        doc["buffers"][0]["uri"] = json!(uri);
    }
    if let Some(c) = camera {
        let (f, u, e) = (c.forward, c.up, c.eye);
        let r = f.cross(u);
        let matrix = [
            r.x, r.y, r.z, 0.0, u.x, u.y, u.z, 0.0, -f.x, -f.y, -f.z, 0.0, e.x, e.y, e.z, 1.0,
        ];
        doc["cameras"] = json!([{"type": "perspective", "perspective": {
            "yfov": c.fov_y_degrees.to_radians(), "aspectRatio": 1.0,
            "znear": 0.01, "zfar": 1000.0}}]);
        doc["nodes"]
            .as_array_mut()
            .expect("an array")
            .push(json!({"name": "camera", "camera": 0, "matrix": matrix}));
        doc["scenes"][0]["nodes"] = json!([0, 1]);
    }
    (serde_json::to_string_pretty(&doc).expect("JSON"), bin)
}

/// [`gltf_from_scene`] as one GLB file's bytes.
pub fn glb_from_scene(scene: &Scene, camera: Option<&Camera>) -> Vec<u8> {
    let (json, bin) = gltf_from_scene(scene, camera, None);
    crate::document::glb(json.into_bytes(), bin)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mcrad_scene_io::{Face, Material};

    #[test]
    fn a_scene_round_trips_through_glb() {
        let p = vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
        let faces = vec![Face {
            vertices: vec![0, 1, 2, 3],
            material: 0,
            source: 0,
        }];
        let m = Material {
            name: "lamp".into(),
            reflectance: Vec3::new(0.5, 0.25, 0.0),
            emission: Vec3::new(10.0, 5.0, 0.0),
        };
        let (scene, _) = Scene::new(p, faces, vec![m.clone()]).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.glb");
        std::fs::write(&path, glb_from_scene(&scene, None)).unwrap();
        let back = mcrad_scene_io::load(&path).unwrap();
        assert_eq!(
            back.scene.faces().len(),
            2,
            "the quad fanned into two triangles"
        );
        assert_eq!(back.scene.materials()[0].reflectance, m.reflectance);
        let e = back.scene.materials()[0].emission;
        assert!((e - m.emission).abs().max_element() < 1e-5, "{e}");
        assert!(back.gltf.is_some());
    }
}
