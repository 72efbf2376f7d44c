//! glTF 2.0 / GLB reader (through `gltf`): triangles of the default scene's meshes, placed by
//! their node transforms; `baseColorFactor` as the reflectance and
//! `emissiveFactor * KHR_materials_emissive_strength` as the emitted radiance `L`, so `E = pi L`.

use crate::error::{Location, SceneError, Warning};
use crate::files::{self, LoadOptions};
use crate::{Camera, Face, Loaded, Material, Scene};
use glam::{Mat4, Vec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::{Mode, Semantic};
use rayon::prelude::*;
use std::path::Path;

/// What a reflectance channel of exactly 1.0 becomes (the solver needs `rho < 1`).
const CLAMPED_REFLECTANCE: f32 = 0.999;

/// Loads a `.gltf` (with its external or embedded buffers) or `.glb` file.
///
/// Walks the default scene (else the first scene, else every root node) depth-first, children
/// in order, placing each mesh by its node's world transform (`parent * local`); under a
/// mirroring transform (negative determinant) triangle winding is reversed so fronts stay
/// fronts. Primitives of mode `TRIANGLES`, `TRIANGLE_STRIP` and `TRIANGLE_FAN` give triangle
/// faces, numbered (`source`) over primitives in that traversal order (a mesh used by two nodes
/// counts twice); points, lines and primitives without `POSITION` are skipped
/// ([`Warning::PrimitivesSkipped`]). Vertices are not shared between primitives.
///
/// Materials are the document's, in order (unnamed ones are called `material<i>`):
/// reflectance = `baseColorFactor` rgb (alpha ignored; above 1 is an error), emission
/// `E = pi * emissiveFactor * emissiveStrength` in W/m². Textured faces (`baseColorTexture`,
/// `emissiveTexture` with a non-zero factor, `COLOR_0`) get a mapping in the scene's
/// [`SceneTextures`](crate::SceneTextures), which multiplies those factors over each patch;
/// textures that cannot be read are warned ([`Warning::TexturesUnreadable`]) and left out.
/// The solver needs `rho < 1`: a factor channel of exactly 1.0 is stored as 0.999 and a
/// textured face's reflectance `factor × COLOR_0 × texture` is clamped to 0.999 per patch;
/// a material is warned once ([`Warning::ReflectanceClamped`]) if that product can reach 1.0
/// on one of its faces (a white texel or vertex colour under a factor of 1), not for a factor
/// of 1.0 its textures keep below 1. Faces of `alphaMode` `MASK` or `BLEND` get a mapping with
/// a [`FaceAlpha`](crate::FaceAlpha): light passes them where their alpha says (see
/// [`FaceAlpha`](crate::FaceAlpha)). Primitives
/// without a material get
/// [`Material::builtin_default`] (0.5 grey, not glTF's white), appended last
/// ([`Warning::DefaultMaterial`]). Skins and morph targets are ignored; the first perspective camera in node order becomes
/// [`Loaded::camera`] (its node's world transform applied; orthographic cameras are ignored).
/// `KHR_lights_punctual` lights become [`Light`](crate::Light)s in node order, converted at
/// [`LoadOptions::light_efficacy`] (`gltf_light`), followed by [`LoadOptions::lights`].
///
/// Errors name the file and, for geometry, the node, mesh and primitive.
pub(crate) fn load_gltf(path: &Path, options: &LoadOptions) -> Result<Loaded, SceneError> {
    let bytes = files::read_file(path, options)?;
    load_gltf_bytes(bytes, path, options)
}

/// [`load_gltf`] of a document already in memory: `bytes` are the file's (JSON or GLB), `path`
/// names it in messages and is the folder its relative URIs (buffers, images) resolve against.
pub(crate) fn load_gltf_bytes(
    bytes: Vec<u8>,
    path: &Path,
    options: &LoadOptions,
) -> Result<Loaded, SceneError> {
    let in_file = |e: SceneError| e.in_file(path, Location::File);
    let invalid = |e: gltf::Error| in_file(SceneError::parse(format!("not valid glTF: {e}")));
    // Validation in `gltf-json` 1.4 panics on a POSITION accessor index out of range: parse,
    // check that, then validate.
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(&bytes).map_err(invalid)?;
    // The JSON text as written (unknown extensions and extras included), for writing back.
    let json_text = if bytes.starts_with(b"glTF") {
        gltf::binary::Glb::from_slice(&bytes)
            .map_err(invalid)?
            .json
            .into_owned()
    } else {
        bytes.clone()
    };
    let json = document.into_json();
    check_position_indices(&json).map_err(in_file)?;
    let document = gltf::Document::from_json(json).map_err(invalid)?;
    let buffers = load_buffers(&document, path, blob, options).map_err(in_file)?;

    let mut warnings = Vec::new();
    let (mut materials, factors) = convert_materials(&document);
    let mut geometry = Geometry {
        textures: crate::gltf_texture::TextureReader::new(&document, path, options, &buffers),
        buffers: &buffers,
        default_material: u32::try_from(materials.len()).map_err(|_| {
            in_file(SceneError::Unsupported {
                what: "more than 2^32 materials".into(),
            })
        })?,
        positions: Vec::new(),
        faces: Vec::new(),
        factors: &factors,
        reach: vec![Vec3::ZERO; factors.len()],
        defaulted: 0,
        skipped: 0,
        instances: Vec::new(),
    };
    let mut camera = None;
    let mut lights = Vec::new();
    walk_scene(&document, |node, world| {
        if camera.is_none() {
            camera = node.camera().and_then(|c| perspective(&c, world));
        }
        if let Some(light) = crate::gltf_light::node_light(node, world, options.light_efficacy)? {
            lights.push(light);
        }
        let Some(mesh) = node.mesh() else {
            return Ok(());
        };
        for primitive in mesh.primitives() {
            let location = Location::Primitive {
                node: node.index(),
                node_name: node.name().map(str::to_string),
                mesh: mesh.index(),
                mesh_name: mesh.name().map(str::to_string),
                primitive: primitive.index(),
            };
            geometry
                .add_primitive(&primitive, [node.index(), mesh.index()], world)
                .map_err(|e| e.in_file(path, location))?;
        }
        Ok(())
    })
    .map_err(|e| match e {
        e @ SceneError::InFile { .. } => e,
        e => in_file(e),
    })?;

    warnings.extend(clamp_warnings(&materials, &factors, &geometry.reach));
    if geometry.skipped > 0 {
        warnings.push(Warning::PrimitivesSkipped {
            count: geometry.skipped,
        });
    }
    if geometry.defaulted > 0 {
        materials.push(Material::builtin_default());
        warnings.push(Warning::DefaultMaterial {
            faces: geometry.defaulted,
        });
    }
    let Geometry {
        positions,
        faces,
        instances,
        textures,
        ..
    } = geometry;
    warnings.extend(textures.warnings());
    lights.extend(options.lights.iter().cloned());
    let (mut scene, more) =
        Scene::new_lit_sky(positions, faces, materials, lights, options.sky.clone())
            .map_err(in_file)?;
    // the built-in default material (appended last, if any) is one-sided, as glTF's own
    scene = scene.with_two_sided(document.materials().map(|m| m.double_sided()).collect());
    warnings.extend(more);
    if textures.out.faces.iter().any(Option::is_some) {
        scene = scene.with_textures(textures.out);
    }
    let gltf = GltfSource {
        json: json_text,
        document,
        buffers,
        instances,
    };
    Ok(Loaded {
        scene,
        warnings,
        camera,
        gltf: Some(Box::new(gltf)),
    })
}

/// A glTF perspective camera placed by its node's world transform: glTF cameras look along
/// their local `-z` with `+y` up. `None` for orthographic cameras and degenerate transforms.
fn perspective(camera: &gltf::Camera, world: Mat4) -> Option<Camera> {
    let gltf::camera::Projection::Perspective(p) = camera.projection() else {
        return None;
    };
    let eye = world.transform_point3(Vec3::ZERO);
    let forward = world.transform_vector3(-Vec3::Z).normalize_or_zero();
    let up = world.transform_vector3(Vec3::Y);
    let up = (up - forward * up.dot(forward)).normalize_or_zero();
    let fov_y_degrees = p.yfov().to_degrees();
    let valid = eye.is_finite()
        && forward != Vec3::ZERO
        && up != Vec3::ZERO
        && fov_y_degrees > 0.0
        && fov_y_degrees < 180.0;
    valid.then_some(Camera {
        eye,
        forward,
        up,
        fov_y_degrees,
    })
}

/// Checks that every primitive's `POSITION` names an existing accessor.
fn check_position_indices(json: &gltf::json::Root) -> Result<(), SceneError> {
    let positions = gltf::json::validation::Checked::Valid(Semantic::Positions);
    for (m, mesh) in json.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            if let Some(index) = primitive.attributes.get(&positions)
                && index.value() >= json.accessors.len()
            {
                return Err(SceneError::parse(format!(
                    "mesh {m} primitive {p}: POSITION is accessor {} but there are only {}",
                    index.value(),
                    json.accessors.len()
                )));
            }
        }
    }
    Ok(())
}

/// Reads every buffer: embedded (`data:` URI), GLB binary chunk, or a file (a relative path
/// in the glTF's folder, or with `options.allow_outside_paths` any path or `file:` URI), read
/// under the policy of [`LoadOptions`].
fn load_buffers(
    document: &gltf::Document,
    path: &Path,
    mut blob: Option<Vec<u8>>,
    options: &LoadOptions,
) -> Result<Vec<gltf::buffer::Data>, SceneError> {
    let base = path.parent().unwrap_or(Path::new(""));
    let mut buffers = Vec::new();
    for buffer in document.buffers() {
        let i = buffer.index();
        let data = match buffer.source() {
            gltf::buffer::Source::Uri(uri) if !uri.starts_with("data:") => {
                // as `gltf` reads URIs: `file:` or a relative path (percent-decoded), no other
                // scheme
                let name = if uri.starts_with("file:") {
                    uri.to_string()
                } else if uri.contains(':') {
                    return Err(SceneError::Unsupported {
                        what: format!("buffer {i} URI {}", crate::quote(uri)),
                    });
                } else {
                    // (`gltf` panics on a percent-encoding that is not UTF-8: checked here)
                    percent_decode(uri).ok_or_else(|| {
                        SceneError::parse(format!(
                            "buffer {i} has a URI that is not UTF-8: {}",
                            crate::quote(uri)
                        ))
                    })?
                };
                let file = files::resolve_named(path, &name, true, options)?;
                let mut bytes = files::read_file(&file, options)?;
                while !bytes.len().is_multiple_of(4) {
                    bytes.push(0);
                }
                gltf::buffer::Data(bytes)
            }
            source => gltf::buffer::Data::from_source_and_blob(source, Some(base), &mut blob)
                .map_err(|e| SceneError::parse(format!("cannot read buffer {i}: {e}")))?,
        };
        if data.len() < buffer.length() {
            return Err(SceneError::parse(format!(
                "buffer {i} has {} bytes but its byteLength is {}",
                data.len(),
                buffer.length()
            )));
        }
        buffers.push(data);
    }
    Ok(buffers)
}

/// Decodes the `%XX` escapes of a URI as the `gltf` crate does; `None` if the result is not
/// UTF-8.
pub fn percent_decode(uri: &str) -> Option<String> {
    let hex = |b: Option<&u8>| b.and_then(|b| (*b as char).to_digit(16));
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%'
            && let (Some(h), Some(l)) = (hex(bytes.get(i + 1)), hex(bytes.get(i + 2)))
        {
            out.push((h * 16 + l) as u8);
            i += 3;
            continue;
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8(out).ok()
}

/// The document's materials, and for each its `baseColorFactor` rgb as written in the file
/// (before channels of exactly 1.0 become [`CLAMPED_REFLECTANCE`]).
fn convert_materials(document: &gltf::Document) -> (Vec<Material>, Vec<Vec3>) {
    let (materials, factors) = document
        .materials()
        .enumerate()
        .map(|(i, m)| {
            let name = m
                .name()
                .map(str::to_string)
                .unwrap_or_else(|| format!("material{i}"));
            let pbr = m.pbr_metallic_roughness();
            let [r, g, b, _alpha] = pbr.base_color_factor();
            let factor = Vec3::new(r, g, b);
            // (warned after the geometry, only where a face's texture lets it reach 1)
            let rgb = Vec3::select(
                factor.cmpeq(Vec3::ONE),
                Vec3::splat(CLAMPED_REFLECTANCE),
                factor,
            );
            let radiance = Vec3::from(m.emissive_factor()) * m.emissive_strength().unwrap_or(1.0);
            let material = Material {
                name,
                reflectance: rgb,
                emission: std::f32::consts::PI * radiance,
            };
            (material, factor)
        })
        .unzip();
    (materials, factors)
}

/// One [`Warning::ReflectanceClamped`] per material where `baseColorFactor` times the largest
/// value its faces' `COLOR_0 × baseColorTexture` takes (`reach`, per channel; 0 for a material
/// no face uses) reaches 1.0 in some channel.
fn clamp_warnings(materials: &[Material], factors: &[Vec3], reach: &[Vec3]) -> Vec<Warning> {
    materials
        .iter()
        .zip(factors.iter().zip(reach))
        .filter_map(|(m, (&factor, &reach))| {
            let count = (factor * reach).cmpge(Vec3::ONE).bitmask().count_ones() as usize;
            (count > 0).then(|| Warning::ReflectanceClamped {
                material: m.name.clone(),
                count,
            })
        })
        .collect()
}

/// Calls `visit` on every node of the default scene (else the first scene, else all root
/// nodes), depth-first with children in order, with the node's world transform.
fn walk_scene<'a>(
    document: &'a gltf::Document,
    mut visit: impl FnMut(&gltf::Node<'a>, Mat4) -> Result<(), SceneError>,
) -> Result<(), SceneError> {
    let roots: Vec<gltf::Node> = match document
        .default_scene()
        .or_else(|| document.scenes().next())
    {
        Some(scene) => scene.nodes().collect(),
        None => {
            let mut is_child = vec![false; document.nodes().len()];
            for child in document.nodes().flat_map(|n| n.children()) {
                is_child[child.index()] = true;
            }
            document.nodes().filter(|n| !is_child[n.index()]).collect()
        }
    };
    // An explicit stack (deep hierarchies cannot overflow the call stack) and a visited mark
    // (a node reached twice would mean a cycle or shared child, which glTF forbids).
    let mut visited = vec![false; document.nodes().len()];
    let mut stack: Vec<(gltf::Node, Mat4)> = roots
        .into_iter()
        .rev()
        .map(|n| (n, Mat4::IDENTITY))
        .collect();
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut visited[node.index()], true) {
            return Err(SceneError::parse(format!(
                "node {} is reached twice: the node hierarchy is not a set of trees",
                node.index()
            )));
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        visit(&node, world)?;
        let children: Vec<gltf::Node> = node.children().collect();
        stack.extend(children.into_iter().rev().map(|c| (c, world)));
    }
    Ok(())
}

/// The scene's geometry as it is being collected.
struct Geometry<'b> {
    /// Textures and the mappings of textured faces.
    textures: crate::gltf_texture::TextureReader<'b>,
    buffers: &'b [gltf::buffer::Data],
    /// Each document material's `baseColorFactor` rgb as in the file.
    factors: &'b [Vec3],
    /// Per document material, the largest `COLOR_0 × baseColorTexture` of its faces, per
    /// channel (1 for faces without either).
    reach: Vec<Vec3>,
    /// Material index given to primitives without a material.
    default_material: u32,
    positions: Vec<Vec3>,
    faces: Vec<Face>,
    /// Faces given the default material.
    defaulted: usize,
    /// Primitives skipped (no surface).
    skipped: usize,
    /// The primitives that gave faces, in order.
    instances: Vec<PrimitiveInstance>,
}

impl Geometry<'_> {
    /// Adds the triangles of one primitive placed by `world`.
    fn add_primitive(
        &mut self,
        primitive: &gltf::Primitive,
        [node, mesh]: [usize; 2],
        world: Mat4,
    ) -> Result<(), SceneError> {
        let mode = primitive.mode();
        let surface = matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        );
        let Some(accessor) = primitive.get(&Semantic::Positions).filter(|_| surface) else {
            self.skipped += 1;
            return Ok(());
        };
        check_accessor(
            &accessor,
            self.buffers,
            "POSITION",
            Dimensions::Vec3,
            &[DataType::F32],
        )?;
        let buffers = self.buffers;
        let reader = primitive.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let unreadable = |what: &str| SceneError::parse(format!("cannot read the {what}"));
        let local: Vec<Vec3> = reader
            .read_positions()
            .ok_or_else(|| unreadable("positions"))?
            .map(Vec3::from)
            .collect();
        let count = local.len();
        let indices: Vec<u32> = match primitive.indices() {
            Some(accessor) => {
                let types = [DataType::U8, DataType::U16, DataType::U32];
                check_accessor(
                    &accessor,
                    self.buffers,
                    "indices",
                    Dimensions::Scalar,
                    &types,
                )?;
                let read = reader.read_indices().ok_or_else(|| unreadable("indices"))?;
                read.into_u32().collect()
            }
            None => (0..u32::try_from(count).unwrap_or(u32::MAX)).collect(),
        };
        if let Some(&index) = indices.iter().find(|&&i| i as usize >= count) {
            return Err(SceneError::IndexOutOfRange { index, count });
        }
        let mut triangles = triangles(mode, &indices)?;
        // (checked before the faces are made: instancing multiplies a small file's triangles)
        if self.faces.len() + triangles.len() > crate::MAX_FACES {
            return Err(SceneError::TooManyFaces);
        }
        self.instances.push(PrimitiveInstance {
            node,
            mesh,
            primitive: primitive.index(),
            first_face: self.faces.len() as u32,
            vertex_offset: self.positions.len() as u32,
            triangles: triangles.clone(),
        });
        if world.determinant() < 0.0 {
            for t in &mut triangles {
                t.swap(1, 2);
            }
        }

        let offset = u32::try_from(self.positions.len())
            .ok()
            .filter(|o| o.checked_add(count as u32).is_some())
            .ok_or_else(|| SceneError::Unsupported {
                what: "more than 2^32 vertices".into(),
            })?;
        // (in parallel; the first bad vertex in order is reported)
        let bad = local.par_iter().enumerate().find_map_first(|(vertex, p)| {
            // The value in the file first; then the transform may still overflow.
            [*p, world.transform_point3(*p)]
                .into_iter()
                .find(|position| !position.is_finite())
                .map(|position| SceneError::NonFinitePosition { vertex, position })
        });
        if let Some(e) = bad {
            return Err(e);
        }
        self.positions
            .par_extend(local.par_iter().map(|p| world.transform_point3(*p)));
        let placed = &self.positions[offset as usize..];
        // a factor channel of 1.0 is stored as 0.999: the texture's mapping makes up for it
        let index = primitive.material().index();
        let file_factor = index.and_then(|i| self.factors.get(i)).copied();
        let scale = file_factor.map_or(Vec3::ONE, |f| {
            Vec3::select(
                f.cmpeq(Vec3::ONE),
                Vec3::splat(1.0 / CLAMPED_REFLECTANCE),
                Vec3::ONE,
            )
        });
        let reach =
            self.textures
                .add_primitive(primitive, self.faces.len(), &triangles, placed, scale);
        if let Some(r) = index.and_then(|i| self.reach.get_mut(i)) {
            *r = r.max(reach);
        }
        let material = match index {
            Some(i) => i as u32,
            None => {
                self.defaulted += triangles.len();
                self.default_material
            }
        };
        let first = self.faces.len();
        if first + triangles.len() > u32::MAX as usize + 1 {
            return Err(SceneError::Unsupported {
                what: "more than 2^32 faces".into(),
            });
        }
        // (in parallel, in order)
        self.faces
            .par_extend(triangles.par_iter().enumerate().map(|(k, t)| Face {
                vertices: t.iter().map(|&i| i + offset).collect(),
                material,
                source: (first + k) as u32,
            }));
        Ok(())
    }
}

/// The glTF document a scene was read from, kept for writing results back into it (baking):
/// the document as parsed, its buffers' bytes (read under the same file policy as the scene),
/// and which faces of the [`Scene`](crate::Scene) each triangle primitive gave.
#[derive(Debug, Clone)]
pub struct GltfSource {
    /// The document's JSON text as in the file (the JSON chunk of a GLB), with everything the
    /// parsed [`document`](Self::document) may not model (unknown extensions, extras).
    pub json: Vec<u8>,
    /// The parsed and validated document.
    pub document: gltf::Document,
    /// The bytes of each buffer, in document order.
    pub buffers: Vec<gltf::buffer::Data>,
    /// One entry per placed triangle primitive (a mesh used by two nodes appears twice), in
    /// the order their faces were numbered.
    pub instances: Vec<PrimitiveInstance>,
}

/// One triangle primitive placed by one node: faces `first_face..first_face + triangles.len()`
/// of the scene (by [`Face::source`](crate::Face::source)), face `first_face + k` made of
/// `triangles[k]`.
#[derive(Debug, Clone)]
pub struct PrimitiveInstance {
    /// The node placing it (document index).
    pub node: usize,
    /// Its mesh (document index).
    pub mesh: usize,
    /// Its index among the mesh's primitives.
    pub primitive: usize,
    /// The source number of its first face.
    pub first_face: u32,
    /// The scene vertex index of the primitive's vertex 0: vertex `v` of the primitive is scene
    /// vertex `vertex_offset + v`, placed by the node's world transform.
    pub vertex_offset: u32,
    /// Its triangles as vertex indices of the primitive, in the file's winding (before any
    /// flip for a mirroring transform).
    pub triangles: Vec<[u32; 3]>,
}

/// The triangles of a `TRIANGLES`, `TRIANGLE_STRIP` or `TRIANGLE_FAN` index list, as in the
/// glTF specification (3.7.2.1), counter-clockwise from the front.
fn triangles(mode: Mode, indices: &[u32]) -> Result<Vec<[u32; 3]>, SceneError> {
    let n = indices.len();
    let v = |i: usize| indices[i];
    Ok(match mode {
        Mode::Triangles => {
            if !n.is_multiple_of(3) {
                return Err(SceneError::parse(format!(
                    "a TRIANGLES primitive has {n} vertex indices, not a multiple of 3"
                )));
            }
            indices
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]])
                .collect()
        }
        Mode::TriangleStrip => (0..n.saturating_sub(2))
            .map(|i| [v(i), v(i + 1 + i % 2), v(i + 2 - i % 2)])
            .collect(),
        Mode::TriangleFan => (0..n.saturating_sub(2))
            .map(|i| [v(i + 1), v(i + 2), v(0)])
            .collect(),
        _ => Vec::new(),
    })
}

/// Checks what the `gltf` reader would trust: a dense accessor of the expected type whose
/// elements lie inside its buffer view, which lies inside its buffer.
fn check_accessor(
    accessor: &gltf::Accessor,
    buffers: &[gltf::buffer::Data],
    what: &str,
    dimensions: Dimensions,
    types: &[DataType],
) -> Result<(), SceneError> {
    let i = accessor.index();
    let bad = |problem: String| SceneError::parse(format!("accessor {i} ({what}) {problem}"));
    if accessor.sparse().is_some() {
        return Err(SceneError::Unsupported {
            what: format!("sparse accessor {i} ({what})"),
        });
    }
    if accessor.dimensions() != dimensions || !types.contains(&accessor.data_type()) {
        return Err(SceneError::Unsupported {
            what: format!(
                "accessor {i} ({what}) of type {:?} {:?} (expected {dimensions:?} of {types:?})",
                accessor.dimensions(),
                accessor.data_type()
            ),
        });
    }
    let Some(view) = accessor.view() else {
        return Err(bad("has no bufferView".into()));
    };
    let size = accessor.size();
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Err(bad(format!(
            "has {size}-byte elements but buffer view {} has byteStride {stride}",
            view.index()
        )));
    }
    let count = accessor.count();
    if count == 0 {
        return Err(bad("has count 0".into()));
    }
    let end = (count - 1)
        .checked_mul(stride)
        .and_then(|x| x.checked_add(size))
        .and_then(|x| x.checked_add(accessor.offset()));
    if end.is_none_or(|end| end > view.length()) {
        return Err(bad(format!(
            "reads past the end of buffer view {} ({} bytes)",
            view.index(),
            view.length()
        )));
    }
    let buffer = view.buffer().index();
    let available = buffers.get(buffer).map_or(0, |d| d.len());
    if view
        .offset()
        .checked_add(view.length())
        .is_none_or(|end| end > available)
    {
        return Err(SceneError::parse(format!(
            "buffer view {} reaches past the end of buffer {buffer} ({available} bytes)",
            view.index()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_and_fans_follow_the_specification() {
        let idx = [0, 1, 2, 3, 4];
        assert_eq!(
            triangles(Mode::TriangleStrip, &idx).unwrap(),
            vec![[0, 1, 2], [1, 3, 2], [2, 3, 4]]
        );
        assert_eq!(
            triangles(Mode::TriangleFan, &idx).unwrap(),
            vec![[1, 2, 0], [2, 3, 0], [3, 4, 0]]
        );
        assert!(triangles(Mode::Triangles, &idx[..4]).is_err());
        assert!(
            triangles(Mode::TriangleStrip, &idx[..2])
                .unwrap()
                .is_empty()
        );
    }

    #[test]
    fn percent_decoding_rejects_non_utf8() {
        assert_eq!(percent_decode("a%20b.bin").as_deref(), Some("a b.bin"));
        assert_eq!(percent_decode("%zz%4").as_deref(), Some("%zz%4"));
        assert_eq!(percent_decode("%FF.bin"), None);
    }
}
