//! The user's glTF document rewritten around the lightmap: every buffer and external image in
//! one GLB binary chunk, baked primitives given their own vertices per chart and a
//! `TEXCOORD_1`, instanced meshes copied per node, the lightmap embedded and referenced from
//! the materials through `MOZ_lightmap`. Everything else in the JSON is kept as written.

use std::collections::HashMap;
use std::path::Path;

use glam::{DVec2, Vec3};
use mcrad_scene_io::glb::BinaryChunk;
use serde_json::{Map, Value, json};

use crate::BakeError;

/// `componentType` sizes in bytes (glTF 2.0, 3.6.2.2).
fn component_size(component_type: u64) -> Option<usize> {
    match component_type {
        5120 | 5121 => Some(1),
        5122 | 5123 => Some(2),
        5125 | 5126 => Some(4),
        _ => None,
    }
}

/// Components per element of an accessor `type` (matrices are not vertex attributes).
fn components(kind: &str) -> Option<usize> {
    match kind {
        "SCALAR" => Some(1),
        "VEC2" => Some(2),
        "VEC3" => Some(3),
        "VEC4" => Some(4),
        _ => None,
    }
}

/// One baked primitive: which mesh primitive of which node, and its new vertices.
pub(crate) struct BakedPrimitive {
    /// The node placing it.
    pub node: usize,
    /// The mesh the node used in the input.
    pub mesh: usize,
    /// The primitive's index in the mesh.
    pub primitive: usize,
    /// For each new vertex, the primitive vertex it copies.
    pub copies: Vec<u32>,
    /// For each new vertex, its lightmap coordinate (`TEXCOORD_1`, 0..1, v down); empty when
    /// baking vertex colours.
    pub uv: Vec<DVec2>,
    /// For each new vertex, its colour `H / intensity` when baking vertex colours; else empty.
    pub colors: Vec<Vec3>,
    /// Triangles over the new vertices, in the file's winding.
    pub triangles: Vec<[u32; 3]>,
}

/// The document being rewritten: its JSON and the one binary chunk it grows into.
pub(crate) struct Document {
    root: Value,
    bin: BinaryChunk,
}

fn field<'v>(v: &'v Value, key: &str) -> Option<&'v Value> {
    v.as_object()?.get(key)
}

fn uint(v: &Value, key: &str) -> Option<u64> {
    field(v, key)?.as_u64()
}

fn array_mut<'v>(root: &'v mut Value, key: &str) -> &'v mut Vec<Value> {
    let object = root.as_object_mut().expect("the root is an object");
    let entry = object
        .entry(key.to_string())
        .or_insert_with(|| Value::Array(Vec::new()));
    if !entry.is_array() {
        *entry = Value::Array(Vec::new());
    }
    entry.as_array_mut().expect("made an array")
}

impl Document {
    /// The document of `json` with its `buffers` moved into one binary chunk and its external
    /// images (named relative to `scene`, read under `options`) embedded.
    pub(crate) fn new(
        json: &[u8],
        buffers: &[gltf::buffer::Data],
        scene: &Path,
        options: &mcrad_scene_io::LoadOptions,
    ) -> Result<Document, BakeError> {
        let mut root: Value = serde_json::from_slice(json)
            .map_err(|e| BakeError::Document(format!("cannot re-read the JSON: {e}")))?;
        if !root.is_object() {
            return Err(BakeError::Document("the JSON is not an object".into()));
        }
        let mut doc = Document {
            root: Value::Null,
            bin: BinaryChunk::new(),
        };
        let mut offsets = Vec::new();
        let declared: Vec<usize> = field(&root, "buffers")
            .and_then(Value::as_array)
            .map(|b| {
                b.iter()
                    .map(|x| uint(x, "byteLength").unwrap_or(0) as usize)
                    .collect()
            })
            .unwrap_or_default();
        for (i, data) in buffers.iter().enumerate() {
            let n = declared
                .get(i)
                .copied()
                .unwrap_or(data.len())
                .min(data.len());
            offsets.push(doc.bin.push(&data[..n]).start as u64);
        }
        for view in array_mut(&mut root, "bufferViews") {
            let buffer = uint(view, "buffer").unwrap_or(0) as usize;
            let offset = uint(view, "byteOffset").unwrap_or(0) + offsets.get(buffer).unwrap_or(&0);
            let object = view
                .as_object_mut()
                .ok_or_else(|| BakeError::Document("a bufferView is not an object".into()))?;
            object.insert("buffer".into(), json!(0));
            object.insert("byteOffset".into(), json!(offset));
        }
        doc.root = root;
        doc.embed_images(scene, options)?;
        Ok(doc)
    }

    /// Appends `bytes` as a new buffer view (with `stride` and `target` when given); its index.
    fn push_view(&mut self, bytes: &[u8], stride: Option<usize>, target: Option<u64>) -> usize {
        let range = self.bin.push(bytes);
        let mut view = json!({"buffer": 0, "byteOffset": range.start, "byteLength": range.len()});
        if let Some(s) = stride {
            view["byteStride"] = json!(s);
        }
        if let Some(t) = target {
            view["target"] = json!(t);
        }
        let views = array_mut(&mut self.root, "bufferViews");
        views.push(view);
        views.len() - 1
    }

    /// Images named by a URI other than `data:` are read and embedded (a GLB stands alone).
    fn embed_images(
        &mut self,
        scene: &Path,
        options: &mcrad_scene_io::LoadOptions,
    ) -> Result<(), BakeError> {
        let count = array_mut(&mut self.root, "images").len();
        for i in 0..count {
            let uri = match field(&self.root["images"][i], "uri").and_then(Value::as_str) {
                Some(u) if !u.starts_with("data:") => u.to_string(),
                _ => continue,
            };
            let name = mcrad_scene_io::percent_decode(&uri).ok_or_else(|| {
                BakeError::Document(format!("image {i} has a URI that is not UTF-8"))
            })?;
            let bytes = mcrad_scene_io::read_named_file(scene, &name, true, options)
                .map_err(|e| BakeError::Image { index: i, cause: e })?;
            let mime = if bytes.starts_with(b"\x89PNG") {
                "image/png"
            } else if bytes.starts_with(&[0xff, 0xd8]) {
                "image/jpeg"
            } else if bytes.len() > 12 && &bytes[8..12] == b"WEBP" {
                "image/webp"
            } else if bytes.starts_with(b"\xabKTX 20") {
                "image/ktx2"
            } else {
                "application/octet-stream"
            };
            let view = self.push_view(&bytes, None, None);
            let image = self.root["images"][i]
                .as_object_mut()
                .ok_or_else(|| BakeError::Document(format!("image {i} is not an object")))?;
            image.remove("uri");
            image.insert("bufferView".into(), json!(view));
            image.insert("mimeType".into(), json!(mime));
        }
        Ok(())
    }

    /// A copy of accessor `index` holding element `copies[k]` of it as element `k`, in a
    /// new buffer view; with `min`/`max` when `bounds` (POSITION needs them).
    fn gather(&mut self, index: u64, copies: &[u32], bounds: bool) -> Result<usize, BakeError> {
        let bad = |why: &str| BakeError::Document(format!("accessor {index}: {why}"));
        let accessor = self.root["accessors"]
            .get(index as usize)
            .cloned()
            .ok_or_else(|| bad("missing"))?;
        if field(&accessor, "sparse").is_some() {
            return Err(BakeError::Unsupported(format!(
                "accessor {index} is sparse (bake reads dense vertex attributes only)"
            )));
        }
        let view_index = uint(&accessor, "bufferView").ok_or_else(|| bad("no bufferView"))?;
        let component_type = uint(&accessor, "componentType").ok_or_else(|| bad("no type"))?;
        let kind = field(&accessor, "type")
            .and_then(Value::as_str)
            .unwrap_or("");
        let csize = component_size(component_type).ok_or_else(|| bad("bad componentType"))?;
        let ncomp = components(kind).ok_or_else(|| bad("not a vertex attribute type"))?;
        let count = uint(&accessor, "count").ok_or_else(|| bad("no count"))? as usize;
        let view = self.root["bufferViews"]
            .get(view_index as usize)
            .cloned()
            .ok_or_else(|| bad("its bufferView is missing"))?;
        let elem = csize * ncomp;
        let stride = uint(&view, "byteStride").map_or(elem, |s| s as usize);
        let start = (uint(&view, "byteOffset").unwrap_or(0)
            + uint(&accessor, "byteOffset").unwrap_or(0)) as usize;
        let out_stride = elem.next_multiple_of(4);
        let mut bytes = Vec::with_capacity(copies.len() * out_stride);
        for &c in copies {
            let c = c as usize;
            if c >= count {
                return Err(bad("a vertex index is past its count"));
            }
            let at = start + c * stride;
            let src = self
                .bin
                .as_bytes()
                .get(at..at + elem)
                .ok_or_else(|| bad("reads past its buffer"))?;
            bytes.extend_from_slice(src);
            bytes.resize(bytes.len() + out_stride - elem, 0);
        }
        let view = self.push_view(
            &bytes,
            (out_stride != elem).then_some(out_stride),
            Some(34962),
        );
        let mut out = json!({
            "bufferView": view,
            "componentType": component_type,
            "count": copies.len(),
            "type": kind,
        });
        if let Some(n) = field(&accessor, "normalized") {
            out["normalized"] = n.clone();
        }
        if bounds && component_type == 5126 {
            let mut lo = vec![f32::INFINITY; ncomp];
            let mut hi = vec![f32::NEG_INFINITY; ncomp];
            for e in bytes.chunks(out_stride) {
                for k in 0..ncomp {
                    let x = f32::from_le_bytes(e[4 * k..4 * k + 4].try_into().expect("4 bytes"));
                    lo[k] = lo[k].min(x);
                    hi[k] = hi[k].max(x);
                }
            }
            out["min"] = json!(lo);
            out["max"] = json!(hi);
        }
        let accessors = array_mut(&mut self.root, "accessors");
        accessors.push(out);
        Ok(accessors.len() - 1)
    }

    /// A new accessor of `values` (`f32` components, `kind` = "VEC2"...) or of `u32` indices.
    fn push_f32(&mut self, values: &[f32], kind: &str, n: usize, target: u64) -> usize {
        let bytes: Vec<u8> = values.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.push_view(&bytes, None, Some(target));
        let accessors = array_mut(&mut self.root, "accessors");
        accessors
            .push(json!({"bufferView": view, "componentType": 5126, "count": n, "type": kind}));
        accessors.len() - 1
    }

    fn push_indices(&mut self, triangles: &[[u32; 3]]) -> usize {
        let bytes: Vec<u8> = triangles
            .iter()
            .flatten()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let view = self.push_view(&bytes, None, Some(34963));
        let accessors = array_mut(&mut self.root, "accessors");
        accessors.push(json!({
            "bufferView": view, "componentType": 5125, "count": triangles.len() * 3, "type": "SCALAR"
        }));
        accessors.len() - 1
    }

    /// Which mesh each node's baked primitives go to: the first node keeps the mesh, later
    /// nodes placing the same mesh get a copy of it (made from the input's JSON).
    fn placements(
        &mut self,
        primitives: &[BakedPrimitive],
    ) -> Result<HashMap<usize, usize>, BakeError> {
        let originals: Vec<Value> = array_mut(&mut self.root, "meshes").clone();
        let mut owned: HashMap<usize, usize> = HashMap::new();
        let mut target: HashMap<usize, usize> = HashMap::new();
        for p in primitives {
            if target.contains_key(&p.node) {
                continue;
            }
            let mesh = if owned.insert(p.mesh, p.node).is_none() {
                p.mesh
            } else {
                let copy = originals
                    .get(p.mesh)
                    .cloned()
                    .ok_or_else(|| BakeError::Document(format!("mesh {} missing", p.mesh)))?;
                let meshes = array_mut(&mut self.root, "meshes");
                meshes.push(copy);
                let m = meshes.len() - 1;
                self.root["nodes"][p.node]["mesh"] = json!(m);
                m
            };
            target.insert(p.node, mesh);
        }
        Ok(target)
    }

    /// Rewrites primitive `p` in `mesh` over its new vertices: every attribute and morph
    /// target copied per new vertex (but those named in `replace`, which `extra` supplies),
    /// triangle-list indices, and a material (the solver's grey default where it had none).
    /// Returns the material index.
    fn rewrite(
        &mut self,
        p: &BakedPrimitive,
        mesh: usize,
        extra: &[(&str, usize)],
        default_material: &mut Option<usize>,
    ) -> Result<usize, BakeError> {
        let old = self.root["meshes"][mesh]["primitives"][p.primitive].clone();
        let attributes = field(&old, "attributes")
            .and_then(Value::as_object)
            .cloned()
            .unwrap_or_default();
        let mut new_attributes = Map::new();
        for (name, accessor) in &attributes {
            if extra.iter().any(|(n, _)| n == name) {
                continue;
            }
            let a = accessor
                .as_u64()
                .ok_or_else(|| BakeError::Document(format!("attribute {name} is not an index")))?;
            let copy = self.gather(a, &p.copies, name == "POSITION")?;
            new_attributes.insert(name.clone(), json!(copy));
        }
        for (name, accessor) in extra {
            new_attributes.insert(name.to_string(), json!(accessor));
        }
        let mut primitive = old.as_object().cloned().unwrap_or_default();
        primitive.insert("attributes".into(), Value::Object(new_attributes));
        if let Some(targets) = field(&old, "targets").and_then(Value::as_array) {
            let mut new_targets = Vec::new();
            for t in targets {
                let mut nt = Map::new();
                for (name, a) in t.as_object().into_iter().flatten() {
                    let a = a.as_u64().ok_or_else(|| {
                        BakeError::Document(format!("target {name} is not an index"))
                    })?;
                    nt.insert(name.clone(), json!(self.gather(a, &p.copies, true)?));
                }
                new_targets.push(Value::Object(nt));
            }
            primitive.insert("targets".into(), Value::Array(new_targets));
        }
        primitive.insert("indices".into(), json!(self.push_indices(&p.triangles)));
        primitive.insert("mode".into(), json!(4));
        let material = match uint(&old, "material") {
            Some(m) => m as usize,
            None => *default_material.get_or_insert_with(|| {
                // the solver's default (0.5 grey, not glTF's white metal)
                let materials = array_mut(&mut self.root, "materials");
                materials.push(json!({
                    "name": "mcrad default",
                    "pbrMetallicRoughness": {
                        "baseColorFactor": [0.5, 0.5, 0.5, 1.0], "metallicFactor": 0.0
                    }
                }));
                materials.len() - 1
            }),
        };
        primitive.insert("material".into(), json!(material));
        self.root["meshes"][mesh]["primitives"][p.primitive] = Value::Object(primitive);
        if !self.root["materials"][material].is_object() {
            return Err(BakeError::Document(format!("material {material} missing")));
        }
        Ok(material)
    }

    /// Rewrites the baked primitives with their lightmap coordinates (`TEXCOORD_1`, from
    /// `p.uv`), embeds the lightmap `png` and points every baked material at it with
    /// `intensity` (W/m² per unit of the decoded texel).
    pub(crate) fn bake(
        &mut self,
        primitives: &[BakedPrimitive],
        png: &[u8],
        intensity: f32,
    ) -> Result<(), BakeError> {
        let target = self.placements(primitives)?;
        let texture = self.add_lightmap(png);
        let mut default_material = None;
        for p in primitives {
            let uv: Vec<f32> = p.uv.iter().flat_map(|u| [u.x as f32, u.y as f32]).collect();
            let uv = self.push_f32(&uv, "VEC2", p.uv.len(), 34962);
            let material = self.rewrite(
                p,
                target[&p.node],
                &[("TEXCOORD_1", uv)],
                &mut default_material,
            )?;
            let m = self.root["materials"][material]
                .as_object_mut()
                .expect("checked by rewrite");
            let extensions = m.entry("extensions").or_insert_with(|| json!({}));
            extensions["MOZ_lightmap"] =
                json!({"index": texture, "texCoord": 1, "intensity": intensity});
        }
        let used = array_mut(&mut self.root, "extensionsUsed");
        if !used.iter().any(|e| e == "MOZ_lightmap") {
            used.push(json!("MOZ_lightmap"));
        }
        Ok(())
    }

    /// Rewrites the baked primitives with vertex colours instead: `COLOR_0` (float RGBA) is
    /// `colors[k] = H / intensity` per new vertex, times the primitive's own `COLOR_0` where it
    /// had one (its alpha kept); `intensity` (W/m²) goes to `asset.extras.mcradVertexIntensity`.
    pub(crate) fn bake_colors(
        &mut self,
        primitives: &[BakedPrimitive],
        intensity: f32,
    ) -> Result<(), BakeError> {
        let target = self.placements(primitives)?;
        let mut default_material = None;
        for p in primitives {
            let mesh = target[&p.node];
            let old =
                &self.root["meshes"][mesh]["primitives"][p.primitive]["attributes"]["COLOR_0"];
            let own = match old.as_u64() {
                Some(a) => Some(self.colors(a, &p.copies)?),
                None => None,
            };
            let rgba: Vec<f32> = p
                .colors
                .iter()
                .enumerate()
                .flat_map(|(k, c)| {
                    let o = own.as_ref().map_or([1.0; 4], |o| o[k]);
                    [c.x * o[0], c.y * o[1], c.z * o[2], o[3]]
                })
                .collect();
            let colors = self.push_f32(&rgba, "VEC4", p.colors.len(), 34962);
            self.rewrite(p, mesh, &[("COLOR_0", colors)], &mut default_material)?;
        }
        let asset = self.root["asset"]
            .as_object_mut()
            .ok_or_else(|| BakeError::Document("asset is not an object".into()))?;
        let extras = asset.entry("extras").or_insert_with(|| json!({}));
        if let Some(extras) = extras.as_object_mut() {
            extras.insert("mcradVertexIntensity".into(), json!(intensity));
        }
        Ok(())
    }

    /// A `COLOR_0` accessor's values for vertices `copies`, as linear RGBA (alpha 1 for RGB).
    fn colors(&self, index: u64, copies: &[u32]) -> Result<Vec<[f32; 4]>, BakeError> {
        let bad = |why: &str| BakeError::Document(format!("COLOR_0 accessor {index}: {why}"));
        let a = self.root["accessors"]
            .get(index as usize)
            .ok_or_else(|| bad("missing"))?;
        if field(a, "sparse").is_some() {
            return Err(BakeError::Unsupported(format!(
                "accessor {index} is sparse"
            )));
        }
        let ct = uint(a, "componentType").ok_or_else(|| bad("no type"))?;
        let n = match field(a, "type").and_then(Value::as_str) {
            Some("VEC3") => 3,
            Some("VEC4") => 4,
            _ => return Err(bad("not VEC3 or VEC4")),
        };
        let csize = component_size(ct).ok_or_else(|| bad("bad componentType"))?;
        let view = &self.root["bufferViews"]
            [uint(a, "bufferView").ok_or_else(|| bad("no view"))? as usize];
        let stride = uint(view, "byteStride").map_or(n * csize, |s| s as usize);
        let start =
            (uint(view, "byteOffset").unwrap_or(0) + uint(a, "byteOffset").unwrap_or(0)) as usize;
        let count = uint(a, "count").unwrap_or(0) as usize;
        copies
            .iter()
            .map(|&c| {
                let c = c as usize;
                if c >= count {
                    return Err(bad("a vertex index is past its count"));
                }
                let mut out = [1.0f32; 4];
                for (k, o) in out.iter_mut().enumerate().take(n) {
                    let at = start + c * stride + k * csize;
                    let b = self
                        .bin
                        .as_bytes()
                        .get(at..at + csize)
                        .ok_or_else(|| bad("past its buffer"))?;
                    *o = match ct {
                        5121 => f32::from(b[0]) / 255.0,
                        5123 => f32::from(u16::from_le_bytes([b[0], b[1]])) / 65535.0,
                        5126 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                        _ => return Err(bad("not float, unsigned byte or unsigned short")),
                    };
                }
                Ok(out)
            })
            .collect()
    }

    /// Embeds the lightmap PNG with a linear, clamped sampler; the texture's index.
    fn add_lightmap(&mut self, png: &[u8]) -> usize {
        let view = self.push_view(png, None, None);
        let images = array_mut(&mut self.root, "images");
        images.push(json!({"bufferView": view, "mimeType": "image/png", "name": "mcrad lightmap"}));
        let image = images.len() - 1;
        let samplers = array_mut(&mut self.root, "samplers");
        samplers
            .push(json!({"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071}));
        let sampler = samplers.len() - 1;
        let textures = array_mut(&mut self.root, "textures");
        textures.push(json!({"sampler": sampler, "source": image, "name": "mcrad lightmap"}));
        textures.len() - 1
    }

    /// The GLB file: this JSON and the binary chunk.
    pub(crate) fn into_glb(self) -> Result<Vec<u8>, BakeError> {
        let mut root = self.root;
        let bin = self.bin.into_bytes();
        let object = root.as_object_mut().expect("the root is an object");
        object.insert("buffers".into(), json!([{"byteLength": bin.len()}]));
        let json = serde_json::to_vec(&root)
            .map_err(|e| BakeError::Document(format!("cannot write the JSON: {e}")))?;
        Ok(mcrad_scene_io::glb::glb_bytes(&json, &bin)?)
    }
}

/// The lightmap as an 8-bit sRGB PNG of `irradiance / intensity` (`size × size`, row-major,
/// top row first), and the `intensity` (W/m²) that maps a decoded texel of 1 back: the largest
/// channel value, so nothing clips.
pub(crate) fn lightmap_png(irradiance: &[Vec3], size: u32) -> Result<(Vec<u8>, f32), BakeError> {
    let intensity = irradiance
        .iter()
        .map(|v| v.max_element())
        .fold(0.0f32, f32::max)
        .max(f32::MIN_POSITIVE);
    let mut pixels = Vec::with_capacity(irradiance.len() * 3);
    for v in irradiance {
        for c in v.to_array() {
            let x = mcrad_render::srgb_encode((c / intensity).clamp(0.0, 1.0));
            pixels.push((x * 255.0).round() as u8);
        }
    }
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(&pixels, size, size, image::ExtendedColorType::Rgb8)
        .map_err(|e| BakeError::Document(format!("cannot encode the lightmap PNG: {e}")))?;
    Ok((png, intensity))
}

use image::ImageEncoder as _;
