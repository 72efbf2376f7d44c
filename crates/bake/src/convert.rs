//! A scene written as a glTF document (for baking an OBJ scene, and for the bundled glTF scenes).

use std::collections::BTreeMap;
use std::path::Path;

use glam::Vec3;
use gltf::json;
use json::accessor::{ComponentType, Type};
use json::buffer::Target;
use json::validation::{Checked::Valid, USize64};
use mcrad_scene_io::glb::{self, BinaryChunk, push_accessor, push_view};
use mcrad_scene_io::{Camera, LoadOptions, Loaded, Scene};

use crate::BakeError;

/// The glTF document for `scene` and `camera` as `gltf-json`'s root, and its binary buffer.
fn document(scene: &Scene, camera: Option<&Camera>) -> (json::Root, Vec<u8>) {
    let mut root = json::Root {
        asset: json::Asset {
            generator: Some("cargo xtask gen-scenes".to_owned()),
            ..Default::default()
        },
        extensions_used: vec!["KHR_materials_emissive_strength".to_owned()],
        ..Default::default()
    };
    let buffer = root.push(json::Buffer {
        byte_length: USize64(0),
        name: None,
        uri: None,
        extensions: None,
        extras: None,
    });
    let mut bin = BinaryChunk::new();
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
        for &v in &used {
            let p = positions[v as usize];
            lo = lo.min(p);
            hi = hi.max(p);
        }
        let range = bin.push_f32(used.iter().flat_map(|&v| positions[v as usize].to_array()));
        let view = push_view(&mut root, buffer, range, Some(Target::ArrayBuffer));
        let position = push_accessor(
            &mut root,
            view,
            used.len(),
            ComponentType::F32,
            Type::Vec3,
            Some((&lo.to_array(), &hi.to_array())),
        );
        let range = bin.push_u32(indices.iter().copied());
        let view = push_view(&mut root, buffer, range, Some(Target::ElementArrayBuffer));
        let indices = push_accessor(
            &mut root,
            view,
            indices.len(),
            ComponentType::U32,
            Type::Scalar,
            None,
        );
        primitives.push(json::mesh::Primitive {
            attributes: BTreeMap::from([(Valid(json::mesh::Semantic::Positions), position)]),
            extensions: None,
            extras: None,
            indices: Some(indices),
            material: Some(json::Index::new(m as u32)),
            mode: Valid(json::mesh::Mode::Triangles),
            targets: None,
        });
    }
    for (index, m) in scene.materials().iter().enumerate() {
        // glTF's emissive factor is radiance and at most 1: the rest in emissive strength
        let l = m.emission / std::f32::consts::PI;
        let strength = l.max_element().max(1.0);
        // the material extensions have more fields when gltf's features turn them on
        #[allow(clippy::needless_update)]
        let extensions = json::extensions::material::Material {
            emissive_strength: Some(json::extensions::material::EmissiveStrength {
                emissive_strength: json::extensions::material::EmissiveStrengthFactor(strength),
            }),
            ..Default::default()
        };
        root.push(json::Material {
            name: Some(m.name.clone()),
            pbr_metallic_roughness: json::material::PbrMetallicRoughness {
                base_color_factor: json::material::PbrBaseColorFactor(
                    m.reflectance.extend(1.0).to_array(),
                ),
                metallic_factor: json::material::StrengthFactor(0.0),
                roughness_factor: json::material::StrengthFactor(1.0),
                ..Default::default()
            },
            emissive_factor: json::material::EmissiveFactor((l / strength).to_array()),
            extensions: Some(extensions),
            // an OBJ made two-sided (`LoadOptions::two_sided`) stays two-sided
            double_sided: scene.is_two_sided(index as u32),
            ..Default::default()
        });
    }
    let mesh = root.push(json::Mesh {
        extensions: None,
        extras: None,
        name: Some("scene".to_owned()),
        primitives,
        weights: None,
    });
    let mut nodes = vec![root.push(json::Node {
        name: Some("scene".to_owned()),
        mesh: Some(mesh),
        ..Default::default()
    })];
    if let Some(c) = camera {
        let (f, u, e) = (c.forward, c.up, c.eye);
        let r = f.cross(u);
        let matrix = [
            r.x, r.y, r.z, 0.0, u.x, u.y, u.z, 0.0, -f.x, -f.y, -f.z, 0.0, e.x, e.y, e.z, 1.0,
        ];
        let camera = root.push(json::Camera {
            name: None,
            type_: Valid(json::camera::Type::Perspective),
            orthographic: None,
            perspective: Some(json::camera::Perspective {
                aspect_ratio: Some(1.0),
                yfov: c.fov_y_degrees.to_radians(),
                zfar: Some(1000.0),
                znear: 0.01,
                extensions: None,
                extras: None,
            }),
            extensions: None,
            extras: None,
        });
        nodes.push(root.push(json::Node {
            name: Some("camera".to_owned()),
            camera: Some(camera),
            matrix: Some(matrix),
            ..Default::default()
        }));
    }
    let scene = root.push(json::Scene {
        extensions: None,
        extras: None,
        name: None,
        nodes,
    });
    root.scene = Some(scene);
    let bin = bin.into_bytes();
    root.buffers[0].byte_length = USize64::from(bin.len());
    (root, bin)
}

/// A glTF document for `scene` (an OBJ scene to bake, a bundled scene in glTF): its JSON and
/// its binary buffer, named `bin_uri` in the document (`None`: the GLB's own binary chunk).
/// Faces are fanned into triangles, one primitive per material (in material order, faces in
/// file order within it); materials become `baseColorFactor = rho`, `metallicFactor = 0`,
/// `roughnessFactor = 1` and emission `E / pi` as `emissiveFactor` (scaled into `[0, 1]` with
/// `KHR_materials_emissive_strength`), so reading it back gives the same reflectance and
/// emission; a two-sided material is `doubleSided`. `camera` (if any) becomes the first
/// camera, aspect 1.
pub fn gltf_from_scene(
    scene: &Scene,
    camera: Option<&Camera>,
    bin_uri: Option<&str>,
) -> (String, Vec<u8>) {
    let (mut root, bin) = document(scene, camera);
    root.buffers[0].uri = bin_uri.map(str::to_owned);
    // gltf-json's types serialise to JSON without failing (string keys, no maps of floats)
    let text = json::serialize::to_string_pretty(&root).expect("gltf-json serialises");
    (text, bin)
}

/// [`gltf_from_scene`] as one GLB file's bytes. Errors: [`BakeError::Glb`] if the file would
/// exceed GLB's 4 GiB.
pub fn glb_from_scene(scene: &Scene, camera: Option<&Camera>) -> Result<Vec<u8>, BakeError> {
    let (root, bin) = document(scene, camera);
    let json = json::serialize::to_vec(&root).expect("gltf-json serialises");
    Ok(glb::glb_bytes(&json, &bin)?)
}

/// The glTF document [`glb_from_scene`] makes of `scene` and `camera`, read back in memory
/// exactly as `mcrad_scene_io::load_with` reads that GLB file (no file is written): the
/// [`Loaded`] scene of its triangles (fanned from the faces, grouped per material), with the
/// document itself in [`Loaded::gltf`] for baking into, and the document's camera (`camera`
/// again, aspect 1; `camera` itself if the document gives none). `path` names the document in
/// messages; `options` are the load options the scene was read under.
///
/// This is how `mcrad bake` bakes an OBJ scene: into a glTF document made from it, solved as
/// that document reads back. Errors: [`BakeError::Glb`] if the document exceeds GLB's 4 GiB,
/// [`BakeError::Convert`] if the document does not read back as a scene.
pub fn gltf_scene(
    scene: &Scene,
    camera: Option<&Camera>,
    path: &Path,
    options: &LoadOptions,
) -> Result<Loaded, BakeError> {
    let glb = glb_from_scene(scene, camera)?;
    let mut loaded =
        mcrad_scene_io::load_gltf_bytes(glb, path, options).map_err(BakeError::Convert)?;
    loaded.camera = loaded.camera.or(camera.copied());
    Ok(loaded)
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
        std::fs::write(&path, glb_from_scene(&scene, None).unwrap()).unwrap();
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

    #[test]
    fn the_scene_in_memory_is_the_glb_file_read_back() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("s.mtl"),
            "newmtl white\nKd 0.7 0.6 0.5\nnewmtl lamp\nKd 0.5 0.5 0.5\nKe 20 10 5\n",
        )
        .unwrap();
        std::fs::write(
            dir.path().join("s.obj"),
            "mtllib s.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\n\
             usemtl white\nf 1 2 3 4\nusemtl lamp\nf 1 5 6 2\nusemtl white\nf 2 6 3\n",
        )
        .unwrap();
        let obj = mcrad_scene_io::load(&dir.path().join("s.obj")).unwrap();
        let camera = Camera {
            eye: Vec3::new(0.5, 3.0, 0.5),
            forward: Vec3::NEG_Y,
            up: Vec3::Z,
            fov_y_degrees: 40.0,
        };
        let options = LoadOptions::default();
        let path = dir.path().join("s.obj");
        let memory = gltf_scene(&obj.scene, Some(&camera), &path, &options).unwrap();
        let glb = dir.path().join("s.glb");
        std::fs::write(&glb, glb_from_scene(&obj.scene, Some(&camera)).unwrap()).unwrap();
        let file = mcrad_scene_io::load_with(&glb, &options).unwrap();

        // the same scene, face for face, and the same document
        let (a, b) = (&memory.scene, &file.scene);
        assert_eq!(a.positions(), b.positions());
        assert_eq!(a.faces(), b.faces());
        assert_eq!(a.materials(), b.materials());
        assert_eq!(a.faces().len(), 5, "quads fanned, grouped by material");
        assert_eq!(memory.camera, file.camera);
        let (ga, gb) = (memory.gltf.unwrap(), file.gltf.unwrap());
        assert_eq!(ga.json, gb.json);
        assert_eq!(ga.buffers.len(), 1);
        assert_eq!(*ga.buffers[0], *gb.buffers[0]);
        // the camera reads back as it was (aspect 1)
        let back = memory.camera.expect("a camera");
        assert!((back.eye - camera.eye).length() < 1e-6);
        assert!((back.forward - camera.forward).length() < 1e-6);
        assert!((back.up - camera.up).length() < 1e-6);
        assert!((back.fov_y_degrees - 40.0).abs() < 1e-4);
        // without a camera in the document none is made up
        let none = gltf_scene(&obj.scene, None, &path, &options).unwrap();
        assert_eq!(none.camera, None);
    }
}
