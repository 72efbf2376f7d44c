//! OBJ + MTL reader (through `tobj`): polygon faces as they are (no triangulation), `Kd` as the
//! reflectance, `Ke` as the emitted radiosity `E` in W/m².

use crate::error::{Location, SceneError, Warning};
use crate::files::{self, LoadOptions};
use crate::obj_text::{self, ObjText};
use crate::{Face, Loaded, Material, Scene};
use glam::Vec3;
use std::cell::RefCell;
use std::path::{Path, PathBuf};

/// Loads an OBJ file and the MTL files it names (relative to its directory).
///
/// Faces keep their vertex count (quads stay quads) and are numbered (`source`) in file order
/// over all objects and groups. The positions of all objects are merged into one list; a vertex
/// used by several objects or material groups appears once per group (`tobj` splits there).
/// Materials are those of the MTL files, in load order; a material without `Kd` gets
/// reflectance 0.5 grey ([`Warning::MaterialDefaulted`]), one without `Ke` emits nothing. Faces
/// without a material (before any `usemtl`, or naming an unknown material, see
/// [`Warning::UnknownMaterial`]) get [`Material::builtin_default`], appended last
/// ([`Warning::DefaultMaterial`]). Texture coordinates, normals, points and lines are ignored.
/// Non-UTF-8 bytes are replaced (they only matter in names and comments).
///
/// Errors name the file (OBJ or MTL) and the line: unreadable OBJ ([`SceneError::Io`]), unreadable
/// MTL ([`SceneError::MissingMtl`]), malformed statements, face indices out of range (negative,
/// relative indices allowed), non-finite coordinates, and everything [`Scene::new`] rejects.
pub(crate) fn load_obj(path: &Path, options: &LoadOptions) -> Result<Loaded, SceneError> {
    let bytes = files::read_file(path, options)?;
    let text = String::from_utf8_lossy(&bytes);
    let obj =
        obj_text::scan_obj(&text).map_err(|(line, e)| e.in_file(path, Location::Line(line)))?;

    let libs = MtlLibs {
        obj: path,
        options,
        lines: &obj.mtllib_lines,
        state: RefCell::new(MtlState::default()),
    };
    // `..Default::default()` is needed when tobj's optional features add fields.
    #[allow(clippy::needless_update)]
    let options = tobj::LoadOptions {
        triangulate: false,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let result = tobj::load_obj_buf(&mut obj.text.as_bytes(), &options, |p| libs.load(p));
    let state = libs.state.into_inner();
    if let Some(e) = state.error {
        return Err(e);
    }
    let tobj_failed = |e: tobj::LoadError| {
        SceneError::parse(format!("tobj cannot read it: {e}")).in_file(path, Location::File)
    };
    let (models, tobj_materials) = result.map_err(tobj_failed)?;
    let tobj_materials = tobj_materials.map_err(tobj_failed)?;

    let mut warnings = Vec::new();
    let mut materials: Vec<Material> = tobj_materials
        .iter()
        .map(|m| convert_material(m, &mut warnings))
        .collect();
    for (name, line) in &obj.usemtl {
        if !materials.iter().any(|m| m.name == *name) {
            warnings.push(Warning::UnknownMaterial {
                name: name.clone(),
                line: *line,
            });
        }
    }

    let (positions, faces, defaulted) =
        collect_faces(&models, materials.len()).map_err(|e| e.in_file(path, Location::File))?;
    if defaulted > 0 {
        materials.push(Material::builtin_default());
        warnings.push(Warning::DefaultMaterial { faces: defaulted });
    }

    let (scene, more) = Scene::new(positions, faces, materials)
        .map_err(|e| locate(e, path, &obj, &state.material_sources, &tobj_materials))?;
    warnings.extend(more);
    Ok(Loaded {
        scene,
        warnings,
        camera: None,
        gltf: None,
    })
}

/// Reads the MTL files `tobj` asks for, remembering the first error with its line and where
/// each material was defined.
struct MtlLibs<'a> {
    obj: &'a Path,
    options: &'a LoadOptions,
    /// Line of each `mtllib`, in the order `tobj` asks for them.
    lines: &'a [usize],
    state: RefCell<MtlState>,
}

#[derive(Default)]
struct MtlState {
    calls: usize,
    error: Option<SceneError>,
    /// File and `newmtl` line of each material, in `tobj`'s material order.
    material_sources: Vec<(PathBuf, usize)>,
}

impl MtlLibs<'_> {
    fn load(&self, name: &Path) -> tobj::MTLLoadResult {
        let mut state = self.state.borrow_mut();
        let line = self.lines.get(state.calls).copied().unwrap_or(0);
        state.calls += 1;
        let fail = |state: &mut MtlState, e: SceneError, tobj_error| {
            state.error.get_or_insert(e);
            Err(tobj_error)
        };
        let named = name.to_string_lossy();
        let mtl = match files::resolve_named(self.obj, &named, false, self.options) {
            Ok(mtl) => mtl,
            Err(e) => {
                let e = e.in_file(self.obj, Location::Line(line));
                return fail(&mut state, e, tobj::LoadError::OpenFileFailed);
            }
        };
        let bytes = match files::read_file(&mtl, self.options) {
            Ok(b) => b,
            Err(SceneError::Io { reason, .. }) => {
                let e = SceneError::MissingMtl {
                    obj: self.obj.to_path_buf(),
                    line,
                    mtl,
                    reason,
                };
                return fail(&mut state, e, tobj::LoadError::OpenFileFailed);
            }
            Err(e) => {
                let e = e.in_file(self.obj, Location::Line(line));
                return fail(&mut state, e, tobj::LoadError::OpenFileFailed);
            }
        };
        let text = String::from_utf8_lossy(&bytes);
        let mtl_text = match obj_text::scan_mtl(&text) {
            Ok(t) => t,
            Err((l, e)) => {
                let e = e.in_file(&mtl, Location::Line(l));
                return fail(&mut state, e, tobj::LoadError::MaterialParseError);
            }
        };
        match tobj::load_mtl_buf(&mut mtl_text.text.as_bytes()) {
            Ok((mats, map)) => {
                for i in 0..mats.len() {
                    let l = mtl_text.newmtl_lines.get(i).copied().unwrap_or(0);
                    state.material_sources.push((mtl.clone(), l));
                }
                Ok((mats, map))
            }
            Err(tobj_error) => {
                // tobj's errors carry no line: find the first line that fails on its own.
                let bad = mtl_text
                    .text
                    .lines()
                    .position(|l| tobj::load_mtl_buf(&mut l.as_bytes()).is_err());
                let e = match bad {
                    Some(i) => SceneError::parse(format!(
                        "cannot parse {}: {tobj_error}",
                        crate::quote(mtl_text.text.lines().nth(i).unwrap_or("").trim())
                    ))
                    .in_file(&mtl, Location::Line(i + 1)),
                    None => SceneError::parse(format!("tobj cannot read it: {tobj_error}"))
                        .in_file(&mtl, Location::File),
                };
                fail(&mut state, e, tobj_error)
            }
        }
    }
}

/// `tobj`'s numbers are f32 or f64 depending on its `use_f64` feature.
fn to_f32(x: impl Into<f64>) -> f32 {
    x.into() as f32
}

fn vec3(c: [impl Into<f64> + Copy; 3]) -> Vec3 {
    Vec3::new(to_f32(c[0]), to_f32(c[1]), to_f32(c[2]))
}

fn convert_material(m: &tobj::Material, warnings: &mut Vec<Warning>) -> Material {
    let reflectance = match m.diffuse {
        Some(kd) => vec3(kd),
        None => {
            warnings.push(Warning::MaterialDefaulted {
                name: m.name.clone(),
                what: format!(
                    "no Kd; reflectance set to {} grey",
                    Material::DEFAULT_REFLECTANCE
                ),
            });
            Vec3::splat(Material::DEFAULT_REFLECTANCE)
        }
    };
    Material {
        name: m.name.clone(),
        reflectance,
        emission: m.emissive.map(vec3).unwrap_or(Vec3::ZERO),
    }
}

/// Merges the models' positions and faces. Faces without a (known) material get index
/// `materials` (the default material, appended by the caller); their count is returned.
fn collect_faces(
    models: &[tobj::Model],
    materials: usize,
) -> Result<(Vec<Vec3>, Vec<Face>, usize), SceneError> {
    let too_many = |what: &str| SceneError::Unsupported {
        what: format!("more than {} {what}", u32::MAX),
    };
    let default = u32::try_from(materials).map_err(|_| too_many("materials"))?;
    let mut positions = Vec::new();
    let mut faces = Vec::new();
    let mut defaulted = 0;
    for model in models {
        let mesh = &model.mesh;
        let offset = u32::try_from(positions.len()).map_err(|_| too_many("vertices"))?;
        positions.extend(
            mesh.positions
                .chunks_exact(3)
                .map(|p| vec3([p[0], p[1], p[2]])),
        );
        let material = match mesh.material_id {
            Some(id) if id < materials => id as u32,
            _ => default,
        };
        // tobj leaves `face_arities` empty when every face is a triangle.
        let arities = if mesh.face_arities.is_empty() {
            vec![3; mesh.indices.len() / 3]
        } else {
            mesh.face_arities.clone()
        };
        let mut start = 0usize;
        for arity in arities {
            let end = start + arity as usize;
            let Some(indices) = mesh.indices.get(start..end) else {
                break;
            };
            let source = u32::try_from(faces.len()).map_err(|_| too_many("faces"))?;
            faces.push(Face {
                vertices: indices.iter().map(|&i| i + offset).collect(),
                material,
                source,
            });
            if material == default {
                defaulted += 1;
            }
            start = end;
        }
    }
    Ok((positions, faces, defaulted))
}

/// Wraps a [`Scene::new`] error with the file and line it comes from: the MTL file and
/// `newmtl` line for a material, the OBJ line for a face, else the OBJ file.
fn locate(
    e: SceneError,
    obj_path: &Path,
    obj: &ObjText,
    material_sources: &[(PathBuf, usize)],
    tobj_materials: &[tobj::Material],
) -> SceneError {
    let face_line = |face: u32| obj.face_lines.get(face as usize).copied();
    match &e {
        SceneError::BadReflectance { material, .. } | SceneError::BadEmission { material, .. } => {
            let at = tobj_materials
                .iter()
                .position(|m| m.name == *material)
                .and_then(|i| material_sources.get(i));
            match at {
                Some((mtl, line)) => e.in_file(mtl, Location::Line(*line)),
                None => e.in_file(obj_path, Location::File),
            }
        }
        SceneError::TooFewVertices { face, .. }
        | SceneError::VertexOutOfRange { face, .. }
        | SceneError::MaterialOutOfRange { face, .. } => match face_line(*face) {
            Some(line) => e.in_file(obj_path, Location::Line(line)),
            None => e.in_file(obj_path, Location::File),
        },
        _ => e.in_file(obj_path, Location::File),
    }
}
