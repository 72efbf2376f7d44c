//! The solved mesh as binary glTF 2.0 (`--gltf F.glb`): per-vertex radiosity as vertex colours.
//!
//! One mesh with one triangle primitive. Its vertices are the distinct (position, normal,
//! radiosity) triples over all patch corners, so corners that a smoothing step gave one value
//! (same point, same surface) share a vertex, while creases and material boundaries — where the
//! values or normals differ — stay sharp. Attributes:
//!
//! - `POSITION` (f32 vec3, scene units, with `min`/`max`), relative to the mesh's local origin
//!   ([`Mesh::origin`]); the one node carries that origin as its `translation` (omitted when
//!   zero), so the file sits where the scene is while its `f32` positions keep their precision,
//! - `NORMAL` (f32 vec3, the patch's unit normal),
//! - `COLOR_0` (f32 vec3, linear): the radiance `B / pi` times a colour scale, clamped to
//!   `[0, 1]` (see [`GltfOptions::exposure`]),
//! - `_RADIOSITY` ([`RADIOSITY_ATTRIBUTE`], f32 vec3): the radiosity `B` itself in W/m², exact
//!   to f32 rounding,
//!
//! and `u32` indices: each patch's fan triangles, counter-clockwise seen from the front; a patch
//! with T-vertices on its edges ([`Mesh::edge_points`], where an adaptive mesh's finer elements
//! meet a coarser one) is fanned from its centroid over its corners and those points instead,
//! valued linearly along the edge, so the surface has no cracks and no seams there. The mesh's
//! `extras` hold `{"mcrad": {"radiosity_attribute": "_RADIOSITY", "units": "W/m^2",
//! "color_scale": s}}` with `s` the scale applied to `B / pi` for `COLOR_0`. The material is
//! single-sided white, non-metallic and rough, and marked `KHR_materials_unlit` (listed in
//! `extensionsUsed`, not required), so viewers that know the extension show the baked colours
//! unshaded and the others still show them modulated by their lighting.

use crate::ExportError;
use glam::{DVec3, Vec3};
use gltf::json;
use json::accessor::{ComponentType, Type};
use json::buffer::Target;
use json::mesh::Semantic;
use json::validation::{Checked::Valid, USize64};
use mcrad_meshing::{CornerValues, Mesh};
use mcrad_scene_io::glb::{self, BinaryChunk, GlbError, push_accessor, push_view};
use serde_json::json;
use std::collections::HashMap;
use std::io::Write;

/// Name of the vertex attribute holding the radiosity `B` (W/m², f32 vec3). glTF 2.0 reserves
/// attribute names starting with `_` for applications.
pub const RADIOSITY_ATTRIBUTE: &str = "_RADIOSITY";

/// The percentile of per-vertex luminance that automatic exposure maps to 1.0.
pub const AUTO_EXPOSURE_PERCENTILE: f64 = 0.99;

/// Rec. 709 / sRGB luminance weights of linear R, G, B.
const LUMINANCE: DVec3 = DVec3::new(0.2126, 0.7152, 0.0722);

/// How [`write_glb`] maps radiosity to vertex colours.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GltfOptions {
    /// The colour scale `s` (sr·m²/W): `COLOR_0 = clamp(s · B / pi, 0, 1)` per channel, with `B`
    /// the vertex radiosity in W/m² (rounded to f32, as stored in `_RADIOSITY`) and `B / pi` its
    /// radiance. `Some(s)` needs `s` finite and `> 0`.
    ///
    /// `None` chooses `s` automatically: the luminance `Y = 0.2126 R + 0.7152 G + 0.0722 B` of
    /// `B / pi` is taken at every vertex of the file, and `s = 1 / Y_99` with `Y_99` the
    /// [`AUTO_EXPOSURE_PERCENTILE`] (99th) percentile by nearest rank (the `ceil(0.99 n)`-th
    /// smallest of the `n` vertex values), so about 1% of vertices — typically the lights —
    /// saturate. If `Y_99 <= 0` the largest luminance is used instead, and if that is `<= 0`
    /// too, `s = 1`. Either way the file records `s` as `extras.mcrad.color_scale`.
    pub exposure: Option<f32>,
}

/// One output vertex, compared bit for bit (with `-0` taken as `+0`).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
struct VertexKey {
    position: [u32; 3],
    normal: [u32; 3],
    radiosity: [u32; 3],
}

fn bits(v: Vec3) -> [u32; 3] {
    // `-0.0 + 0.0 == +0.0`; every other value is unchanged.
    v.to_array().map(|c| (c + 0.0).to_bits())
}

/// The deduplicated vertices and the triangles over them.
struct Geometry {
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    /// `B` in W/m², rounded to f32.
    radiosity: Vec<Vec3>,
    indices: Vec<u32>,
}

/// Writes `mesh` with per-corner radiosity `corner_radiosity` (W/m² per RGB channel, indexed by
/// global corner: [`Mesh::corner_offset`]`(p) + k` for corner `k` of patch `p`, e.g. from
/// [`Mesh::corner_radiosity`]) to `out` as one binary glTF 2.0 file. The layout and the colour
/// mapping are described in the module documentation and [`GltfOptions`].
///
/// Errors: [`ExportError::Gltf`] if `corner_radiosity` does not have [`Mesh::corner_count`]
/// values, a value is not finite in f32, the mesh has no patches, the exposure is not a positive
/// finite number, or the file would exceed GLB's 4 GiB limit; [`ExportError::Io`] if writing
/// fails.
pub fn write_glb<W: Write>(
    out: W,
    mesh: &Mesh,
    corner_radiosity: &CornerValues,
    options: &GltfOptions,
) -> Result<(), ExportError> {
    let geometry = deduplicate(mesh, corner_radiosity)?;
    let scale = match options.exposure {
        Some(s) if s.is_finite() && s > 0.0 => f64::from(s),
        Some(s) => {
            return Err(gltf_error(format!(
                "exposure must be a positive finite colour scale, got {s}"
            )));
        }
        None => auto_color_scale(&geometry.radiosity),
    };
    let colors: Vec<Vec3> = geometry
        .radiosity
        .iter()
        .map(|&b| color(b, scale))
        .collect();

    // The binary chunk: one view per attribute, then the indices.
    let mut bin = BinaryChunk::new();
    let attribute_ranges: Vec<_> = [
        &geometry.positions,
        &geometry.normals,
        &colors,
        &geometry.radiosity,
    ]
    .map(|data| bin.push_f32(data.iter().flat_map(|v| v.to_array())))
    .into();
    let index_range = bin.push_u32(geometry.indices.iter().copied());

    let mut root = json::Root {
        asset: json::Asset {
            generator: Some(format!("mcrad {}", env!("CARGO_PKG_VERSION"))),
            ..Default::default()
        },
        extensions_used: vec!["KHR_materials_unlit".to_owned()],
        ..Default::default()
    };
    let buffer = root.push(json::Buffer {
        byte_length: USize64::from(bin.len()),
        name: None,
        uri: None,
        extensions: None,
        extras: None,
    });
    let vertex_count = geometry.positions.len();
    let (min, max) = geometry.positions.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    let (min, max) = (min.to_array(), max.to_array());
    let semantics = [
        Semantic::Positions,
        Semantic::Normals,
        Semantic::Colors(0),
        Semantic::Extras(RADIOSITY_ATTRIBUTE[1..].to_owned()),
    ];
    let views: Vec<_> = attribute_ranges
        .into_iter()
        .map(|range| push_view(&mut root, buffer, range, Some(Target::ArrayBuffer)))
        .collect();
    let index_view = push_view(
        &mut root,
        buffer,
        index_range,
        Some(Target::ElementArrayBuffer),
    );
    let mut attributes = std::collections::BTreeMap::new();
    for (k, (semantic, view)) in semantics.into_iter().zip(views).enumerate() {
        let bounds = (k == 0).then_some((&min[..], &max[..]));
        let index = push_accessor(
            &mut root,
            view,
            vertex_count,
            ComponentType::F32,
            Type::Vec3,
            bounds,
        );
        attributes.insert(Valid(semantic), index);
    }
    let indices = push_accessor(
        &mut root,
        index_view,
        geometry.indices.len(),
        ComponentType::U32,
        Type::Scalar,
        None,
    );

    let material = root.push(json::Material {
        name: Some("mcrad radiosity (unlit vertex colours)".to_owned()),
        double_sided: false,
        pbr_metallic_roughness: json::material::PbrMetallicRoughness {
            metallic_factor: json::material::StrengthFactor(0.0),
            roughness_factor: json::material::StrengthFactor(1.0),
            ..Default::default()
        },
        ..Default::default()
    });
    let extras = json!({
        "mcrad": {
            "radiosity_attribute": RADIOSITY_ATTRIBUTE,
            "units": "W/m^2",
            "color_scale": scale,
        }
    });
    let mesh_index = root.push(json::Mesh {
        extensions: None,
        extras: Some(serde_json::value::to_raw_value(&extras).map_err(json_error)?),
        name: Some("radiosity".to_owned()),
        primitives: vec![json::mesh::Primitive {
            attributes,
            extensions: None,
            extras: None,
            indices: Some(indices),
            material: Some(material),
            mode: Valid(json::mesh::Mode::Triangles),
            targets: None,
        }],
        weights: None,
    });
    // positions are in the mesh's local frame: the node puts them back where the scene is
    let origin = mesh.origin();
    let node = root.push(json::Node {
        mesh: Some(mesh_index),
        translation: (origin != Vec3::ZERO).then(|| origin.to_array()),
        ..Default::default()
    });
    let scene = root.push(json::Scene {
        extensions: None,
        extras: None,
        name: None,
        nodes: vec![node],
    });
    root.scene = Some(scene);

    // gltf-json only knows `KHR_materials_unlit` behind a feature this workspace leaves off, so
    // the (empty) extension object is added to the serialised material.
    let mut value = root.to_value().map_err(json_error)?;
    value["materials"][0]["extensions"] = json!({ "KHR_materials_unlit": {} });
    let json_bytes = serde_json::to_vec(&value).map_err(json_error)?;

    glb::write_glb(out, &json_bytes, bin.as_bytes()).map_err(|e| match e {
        GlbError::Io(source) => ExportError::Io {
            what: "glTF binary",
            reason: source,
        },
        e @ GlbError::TooLarge { .. } => gltf_error(format!(
            "{e} ({vertex_count} vertices, {} triangles)",
            geometry.indices.len() / 3
        )),
    })
}

/// One vertex per distinct (position, normal, f32 radiosity) over the corners, in first-use
/// order, and the patches' fan triangles over them.
fn deduplicate(mesh: &Mesh, corner_radiosity: &CornerValues) -> Result<Geometry, ExportError> {
    if corner_radiosity.len() != mesh.corner_count() {
        return Err(gltf_error(format!(
            "{} radiosity values for {} patch corners",
            corner_radiosity.len(),
            mesh.corner_count()
        )));
    }
    if mesh.patches().is_empty() {
        return Err(gltf_error("the mesh has no patches".to_owned()));
    }
    let mut geometry = Geometry {
        positions: Vec::new(),
        normals: Vec::new(),
        radiosity: Vec::new(),
        indices: Vec::new(),
    };
    let mut seen: HashMap<VertexKey, u32> = HashMap::new();
    let mut patch_vertices = Vec::new();
    let edge_points = mesh.edge_points();
    let mut vertex = |geometry: &mut Geometry, position: Vec3, normal: Vec3, b32: Vec3| {
        let key = VertexKey {
            position: bits(position),
            normal: bits(normal),
            radiosity: bits(b32),
        };
        let next = geometry.positions.len();
        let index = *seen.entry(key).or_insert_with(|| next as u32);
        if index as usize == next {
            if next == u32::MAX as usize {
                return Err(gltf_error(format!(
                    "more than {} distinct vertices do not fit u32 indices",
                    u32::MAX - 1
                )));
            }
            geometry.positions.push(position);
            geometry.normals.push(normal);
            geometry.radiosity.push(b32);
        }
        Ok(index)
    };
    for (p, patch) in mesh.patches().iter().enumerate() {
        let offset = mesh.corner_offset(p);
        let corners = mesh.corners(patch);
        patch_vertices.clear();
        let mut with_t_vertices = false;
        for (k, &v) in corners.iter().enumerate() {
            let b = corner_radiosity[offset + k];
            let b32 = b.as_vec3();
            if !b32.is_finite() {
                return Err(gltf_error(format!(
                    "radiosity {b} W/m² at corner {k} of patch {p} (global corner {}) is not finite in f32",
                    offset + k
                )));
            }
            let position = mesh.positions()[v as usize];
            patch_vertices.push(vertex(&mut geometry, position, patch.normal, b32)?);
            // T-vertices on the edge to the next corner, valued along it (no cracks, no seams).
            let next = corner_radiosity[offset + (k + 1) % corners.len()];
            for &(t, point) in edge_points.on_edge(offset + k) {
                with_t_vertices = true;
                let value = (b * (1.0 - t) + next * t).as_vec3();
                patch_vertices.push(vertex(&mut geometry, point, patch.normal, value)?);
            }
        }
        if with_t_vertices {
            // A fan from the patch's centroid over its corners and T-vertices.
            let mean = (offset..offset + corners.len())
                .map(|c| corner_radiosity[c])
                .sum::<DVec3>()
                / corners.len() as f64;
            let centre = vertex(&mut geometry, patch.centroid, patch.normal, mean.as_vec3())?;
            for i in 0..patch_vertices.len() {
                let j = (i + 1) % patch_vertices.len();
                geometry
                    .indices
                    .extend_from_slice(&[centre, patch_vertices[i], patch_vertices[j]]);
            }
        } else {
            // The fan over the corners, as `Mesh` triangulates a patch: counter-clockwise.
            for w in patch_vertices[1..].windows(2) {
                geometry
                    .indices
                    .extend_from_slice(&[patch_vertices[0], w[0], w[1]]);
            }
        }
    }
    Ok(geometry)
}

/// The automatic colour scale of [`GltfOptions::exposure`] for vertex radiosities `B` (W/m²).
fn auto_color_scale(radiosity: &[Vec3]) -> f64 {
    let mut luminance: Vec<f64> = radiosity
        .iter()
        .map(|b| b.as_dvec3().dot(LUMINANCE) / std::f64::consts::PI)
        .collect();
    if luminance.is_empty() {
        return 1.0;
    }
    let n = luminance.len();
    let rank = ((AUTO_EXPOSURE_PERCENTILE * n as f64).ceil() as usize).clamp(1, n);
    let (_, &mut percentile, _) = luminance.select_nth_unstable_by(rank - 1, f64::total_cmp);
    let max = luminance.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let reference = if percentile > 0.0 { percentile } else { max };
    if reference > 0.0 && reference.is_finite() {
        1.0 / reference
    } else {
        1.0
    }
}

/// `COLOR_0` of a vertex with radiosity `b` (W/m², f32) at colour scale `scale` (sr·m²/W).
fn color(b: Vec3, scale: f64) -> Vec3 {
    (b.as_dvec3() / std::f64::consts::PI * scale)
        .clamp(DVec3::ZERO, DVec3::ONE)
        .as_vec3()
}

fn gltf_error(reason: String) -> ExportError {
    ExportError::Gltf { reason }
}

fn json_error(source: serde_json::Error) -> ExportError {
    ExportError::Json {
        what: "glTF document",
        reason: source,
    }
}

#[cfg(test)]
mod tests {
    use super::{GltfOptions, RADIOSITY_ATTRIBUTE, write_glb};
    use crate::ExportError;
    use glam::{DVec3, Vec3};
    use gltf::Semantic;
    use mcrad_meshing::{CornerValues, DEFAULT_CREASE_ANGLE_DEGREES, Mesh, Subdivision};
    use mcrad_scene_io::{Face, Material, Scene};
    use std::collections::HashSet;
    use std::f64::consts::PI;

    /// An open box corner: a floor (two materials side by side) and a wall of the first
    /// material at 90°, subdivided into 0.5-unit patches.
    fn corner_mesh() -> Mesh {
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 1.0),
            Vec3::new(2.0, 1.0, 1.0),
        ];
        let face = |vertices: &[u32], material, source| Face {
            vertices: vertices.to_vec(),
            material,
            source,
        };
        let faces = vec![
            face(&[0, 1, 2, 3], 0, 0),
            face(&[1, 4, 5, 2], 1, 1),
            face(&[3, 5, 7, 6], 0, 2),
        ];
        let materials = vec![
            Material {
                name: "white".into(),
                reflectance: Vec3::splat(0.5),
                emission: Vec3::ZERO,
            },
            Material {
                name: "lamp".into(),
                reflectance: Vec3::splat(0.2),
                emission: Vec3::splat(10.0),
            },
        ];
        let scene = Scene::new(positions, faces, materials).unwrap().0;
        Mesh::build(&scene, Subdivision::MaxEdge(0.5)).unwrap()
    }

    #[test]
    fn a_far_scene_is_written_local_with_its_origin_as_the_node_translation() {
        // The corner moved 1e7 along x (exact in f32): positions in the file are the ones at
        // the origin, and the node puts them back at 1e7.
        let near = corner_mesh();
        let positions: Vec<Vec3> = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ]
        .map(|p| Vec3::from(p) + Vec3::new(1e7, 0.0, 0.0))
        .to_vec();
        let face = Face {
            vertices: vec![0, 1, 2, 3],
            material: 0,
            source: 0,
        };
        let material = Material {
            name: "lamp".into(),
            reflectance: Vec3::splat(0.5),
            emission: Vec3::ONE,
        };
        let scene = Scene::new(positions, vec![face], vec![material]).unwrap().0;
        let far = Mesh::build(&scene, Subdivision::MaxEdge(0.5)).unwrap();
        assert_eq!(far.origin(), Vec3::new(1e7, 0.0, 0.0));
        let got = read_back(&write(
            &far,
            &vec![DVec3::ONE; far.corner_count()],
            &GltfOptions::default(),
        ));
        let node = got.document.nodes().next().unwrap();
        let (translation, _, _) = node.transform().decomposed();
        assert_eq!(translation, [1e7, 0.0, 0.0]);
        assert!(got.positions.iter().all(|p| p[0].abs() <= 1.0));
        // a mesh around the origin has no translation
        let got = read_back(&write(
            &near,
            &corner_values(&near),
            &GltfOptions::default(),
        ));
        let node = got.document.nodes().next().unwrap();
        assert_eq!(node.transform().decomposed().0, [0.0; 3]);
    }

    /// Patch values varying over the scene, smoothed to corners.
    fn corner_values(mesh: &Mesh) -> Vec<DVec3> {
        let values: Vec<DVec3> = mesh
            .patches()
            .iter()
            .map(|p| {
                let c = p.centroid.as_dvec3();
                DVec3::new(1.0 + c.x, 2.0 + c.y * c.y, 3.0 * c.z) + p.emission.as_dvec3()
            })
            .collect();
        mesh.corner_radiosity(&values, DEFAULT_CREASE_ANGLE_DEGREES)
            .iter()
            .collect()
    }

    struct ReadBack {
        positions: Vec<[f32; 3]>,
        normals: Vec<[f32; 3]>,
        colors: Vec<[f32; 3]>,
        radiosity: Vec<[f32; 3]>,
        indices: Vec<u32>,
        extras: serde_json::Value,
        document: gltf::Document,
    }

    fn read_back(bytes: &[u8]) -> ReadBack {
        let (document, buffers, _) = gltf::import_slice(bytes).expect("a valid glTF");
        let gltf_mesh = document.meshes().next().expect("one mesh");
        assert_eq!(document.meshes().count(), 1);
        assert_eq!(gltf_mesh.primitives().count(), 1);
        let primitive = gltf_mesh.primitives().next().unwrap();
        let reader = primitive.reader(|b| Some(&buffers[b.index()]));
        let accessor = primitive
            .get(&Semantic::Extras(RADIOSITY_ATTRIBUTE[1..].to_owned()))
            .expect("the radiosity attribute");
        let radiosity =
            gltf::accessor::Iter::<[f32; 3]>::new(accessor, |b| Some(&buffers[b.index()][..]))
                .expect("readable")
                .collect();
        let extras = serde_json::from_str(gltf_mesh.extras().as_ref().expect("extras").get())
            .expect("extras are JSON");
        ReadBack {
            positions: reader.read_positions().unwrap().collect(),
            normals: reader.read_normals().unwrap().collect(),
            colors: reader.read_colors(0).unwrap().into_rgb_f32().collect(),
            radiosity,
            indices: reader.read_indices().unwrap().into_u32().collect(),
            extras,
            document: document.clone(),
        }
    }

    fn write(mesh: &Mesh, values: &[DVec3], options: &GltfOptions) -> Vec<u8> {
        let mut bytes = Vec::new();
        let values = CornerValues::per_corner(values.to_vec());
        write_glb(&mut bytes, mesh, &values, options).expect("written");
        bytes
    }

    #[test]
    fn the_glb_round_trips_vertices_colours_radiosity_and_triangles() {
        let mesh = corner_mesh();
        let values = corner_values(&mesh);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("solved.glb");
        write_glb(
            std::fs::File::create(&path).unwrap(),
            &mesh,
            &CornerValues::per_corner(values.clone()),
            &GltfOptions::default(),
        )
        .unwrap();
        let got = read_back(&std::fs::read(&path).unwrap());

        // One vertex per distinct (position, normal, value) over the corners.
        let mut distinct = HashSet::new();
        for (p, patch) in mesh.patches().iter().enumerate() {
            for (k, &v) in mesh.corners(patch).iter().enumerate() {
                let b = values[mesh.corner_offset(p) + k].as_vec3();
                distinct.insert(
                    [mesh.positions()[v as usize], patch.normal, b]
                        .map(|x| x.to_array().map(f32::to_bits)),
                );
            }
        }
        assert_eq!(got.positions.len(), distinct.len());
        // Smoothing merged corners, but the crease and the material boundary kept some apart.
        let points: HashSet<_> = mesh
            .positions()
            .iter()
            .map(|p| p.to_array().map(f32::to_bits))
            .collect();
        assert!(distinct.len() < mesh.corner_count());
        assert!(distinct.len() > points.len());

        // Every corner's vertex, read back, carries its exact f32 radiosity.
        let stored: HashSet<_> = (0..got.positions.len())
            .map(|i| {
                [got.positions[i], got.normals[i], got.radiosity[i]].map(|x| x.map(f32::to_bits))
            })
            .collect();
        assert_eq!(stored, distinct);

        // COLOR_0 = clamp(scale · B/pi, 0, 1) with the recorded scale.
        let mcrad = &got.extras["mcrad"];
        assert_eq!(mcrad["radiosity_attribute"], RADIOSITY_ATTRIBUTE);
        assert_eq!(mcrad["units"], "W/m^2");
        let scale = mcrad["color_scale"].as_f64().expect("a scale");
        for (b, c) in got.radiosity.iter().zip(&got.colors) {
            let want = (Vec3::from(*b).as_dvec3() / PI * scale)
                .clamp(DVec3::ZERO, DVec3::ONE)
                .as_vec3();
            assert_eq!(Vec3::from(*c), want);
        }
        // Automatic exposure: the 99th-percentile luminance maps to 1, so about 1% saturates.
        let lum = |c: &[f32; 3]| 0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64;
        let mut lums: Vec<f64> = got.radiosity.iter().map(|b| lum(b) / PI * scale).collect();
        lums.sort_by(f64::total_cmp);
        let n = lums.len();
        assert!((lums[(0.99 * n as f64).ceil() as usize - 1] - 1.0).abs() < 1e-12);

        // Triangles: valid indices, counter-clockwise around NORMAL, covering the patch area.
        assert_eq!(got.indices.len() % 3, 0);
        let mut area = 0.0;
        for t in got.indices.chunks(3) {
            assert!(t.iter().all(|&i| (i as usize) < got.positions.len()));
            let [a, b, c] = [0, 1, 2].map(|k| Vec3::from(got.positions[t[k] as usize]).as_dvec3());
            let cross = (b - a).cross(c - a);
            for &i in t {
                assert!(cross.dot(Vec3::from(got.normals[i as usize]).as_dvec3()) > 0.0);
            }
            area += cross.length() / 2.0;
        }
        assert!((area - mesh.total_area()).abs() < 1e-9 * mesh.total_area());

        // POSITION carries its bounds; the material is white, single-sided and unlit.
        let primitive = got
            .document
            .meshes()
            .next()
            .unwrap()
            .primitives()
            .next()
            .unwrap();
        let bounds = primitive.bounding_box();
        assert_eq!((bounds.min, bounds.max), ([0.0; 3], [2.0, 1.0, 1.0]));
        let material = primitive.material();
        assert!(!material.double_sided());
        assert_eq!(
            material.pbr_metallic_roughness().base_color_factor(),
            [1.0; 4]
        );
        assert!(
            got.document
                .extensions_used()
                .any(|e| e == "KHR_materials_unlit")
        );
    }

    #[test]
    fn a_fixed_exposure_is_used_as_the_colour_scale() {
        let mesh = corner_mesh();
        let values = corner_values(&mesh);
        let got = read_back(&write(
            &mesh,
            &values,
            &GltfOptions {
                exposure: Some(0.25),
            },
        ));
        assert_eq!(got.extras["mcrad"]["color_scale"].as_f64(), Some(0.25));
        for (b, c) in got.radiosity.iter().zip(&got.colors) {
            let want = (Vec3::from(*b).as_dvec3() / PI * 0.25)
                .clamp(DVec3::ZERO, DVec3::ONE)
                .as_vec3();
            assert_eq!(Vec3::from(*c), want);
        }
        // The brightest (emitting) vertices saturate at this scale.
        assert!(got.colors.iter().any(|c| c.contains(&1.0)));
    }

    #[test]
    fn a_black_solution_gets_scale_one() {
        let mesh = corner_mesh();
        let got = read_back(&write(
            &mesh,
            &vec![DVec3::ZERO; mesh.corner_count()],
            &GltfOptions::default(),
        ));
        assert_eq!(got.extras["mcrad"]["color_scale"].as_f64(), Some(1.0));
        assert!(got.colors.iter().all(|c| *c == [0.0; 3]));
    }

    #[test]
    fn bad_inputs_are_errors_naming_the_value() {
        let mesh = corner_mesh();
        let values = corner_values(&mesh);
        let message = |values: &[DVec3], exposure| {
            let values = CornerValues::per_corner(values.to_vec());
            let options = GltfOptions { exposure };
            let err = write_glb(Vec::new(), &mesh, &values, &options).unwrap_err();
            assert!(matches!(err, ExportError::Gltf { .. }), "{err:?}");
            err.to_string()
        };
        assert!(
            message(&values[1..], None).contains(&format!("{} radiosity values", values.len() - 1))
        );
        let mut nan = values.clone();
        nan[7] = DVec3::new(0.0, f64::NAN, 0.0);
        assert!(message(&nan, None).contains("global corner 7"));
        let mut huge = values.clone();
        huge[3].x = 1e300;
        assert!(message(&huge, None).contains("not finite"));
        for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert!(message(&values, Some(bad)).contains("exposure"));
        }
    }

    #[test]
    fn an_adaptive_mesh_is_written_without_cracks_or_seams() {
        use mcrad_meshing::{AdaptiveBounds, AdaptiveMesh};
        use std::collections::HashMap;
        // Two unit squares side by side; the right one refined twice along the shared edge.
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
        ];
        let faces = (0..2)
            .map(|i| Face {
                vertices: [vec![0, 1, 2, 3], vec![1, 4, 5, 2]][i].clone(),
                material: 0,
                source: i as u32,
            })
            .collect();
        let materials = vec![Material {
            name: "lamp".into(),
            reflectance: Vec3::splat(0.5),
            emission: Vec3::ONE,
        }];
        let scene = Scene::new(positions, faces, materials).unwrap().0;
        let bounds = AdaptiveBounds {
            min_edge: 0.01,
            max_patches: 100,
        };
        let mut adaptive = AdaptiveMesh::new(&scene, Subdivision::None, bounds).unwrap();
        adaptive.refine(&[1]);
        adaptive.refine(&[1, 4]);
        let mesh = adaptive.mesh();
        let values: Vec<DVec3> = (0..mesh.patches().len())
            .map(|p| DVec3::new(1.0 + p as f64, 2.0, 3.0 + (p % 3) as f64))
            .collect();
        let corners = mesh.seamless_corner_radiosity(&values, DEFAULT_CREASE_ANGLE_DEGREES);
        let corners: Vec<DVec3> = corners.iter().collect();
        let back = read_back(&write(mesh, &corners, &GltfOptions::default()));
        // Every triangle edge inside the two squares is used by exactly two triangles, in
        // opposite directions, with the same values at its ends: no T-junction, no crack.
        let mut edges: HashMap<([u32; 3], [u32; 3]), i32> = HashMap::new();
        let key = |i: u32| back.positions[i as usize].map(f32::to_bits);
        let mut ends: HashMap<[u32; 3], [f32; 3]> = HashMap::new();
        for t in back.indices.chunks(3) {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                for v in [a, b] {
                    let r = back.radiosity[v as usize];
                    let old = *ends.entry(key(v)).or_insert(r);
                    assert_eq!(old, r, "two values at {:?}", back.positions[v as usize]);
                }
                let (ka, kb) = (key(a), key(b));
                if ka < kb {
                    *edges.entry((ka, kb)).or_default() += 1;
                } else {
                    *edges.entry((kb, ka)).or_default() -= 1;
                }
            }
        }
        let outside = |p: [u32; 3]| {
            let p = p.map(f32::from_bits);
            p[0] == 0.0 || p[0] == 2.0 || p[1] == 0.0 || p[1] == 1.0
        };
        for ((a, b), count) in edges {
            let on_boundary = outside(a) && outside(b) && {
                let (pa, pb) = (a.map(f32::from_bits), b.map(f32::from_bits));
                pa[0] == pb[0] && (pa[0] == 0.0 || pa[0] == 2.0)
                    || pa[1] == pb[1] && (pa[1] == 0.0 || pa[1] == 1.0)
            };
            if !on_boundary {
                assert_eq!(
                    count,
                    0,
                    "an open edge {:?} - {:?}",
                    a.map(f32::from_bits),
                    b.map(f32::from_bits)
                );
            }
        }
    }
}
