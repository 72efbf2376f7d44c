//! OBJ + MTL reader (the OBJ parsed once, by `obj_text`; the MTL files by `tobj`): polygon
//! faces as they are (no triangulation), `Kd` as the reflectance, `Ke` as the emitted
//! radiosity `E` in W/m².

use crate::error::{Location, SceneError, Warning};
use crate::files::{self, LoadOptions};
use crate::obj_text::{self, ObjText, Statement};
use crate::{Face, Loaded, Material, Scene};
use glam::Vec3;
use rayon::prelude::*;
use std::collections::HashMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

/// Loads an OBJ file and the MTL files it names (relative to its directory).
///
/// Faces keep their vertex count (quads stay quads) and are numbered (`source`) in file order
/// over all objects and groups. The positions of all objects are merged into one list; a vertex
/// used by several objects or material groups appears once per group (as `tobj` splits).
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
    let mut obj = obj_text::scan_obj_parallel(&text)
        .map_err(|(line, e)| e.in_file(path, Location::Line(line)))?;
    // the parse owns what it read: the file's bytes go (as large as the file)
    drop(text);
    drop(bytes);

    // The faces grouped as `tobj` groups them (one group per object, group and material run),
    // with the MTL files read by `tobj` as their `mtllib` statements come.
    let mut libs = MtlLibs {
        obj: path,
        options,
        material_sources: Vec::new(),
    };
    let mut tobj_materials: Vec<tobj::Material> = Vec::new();
    let mut by_name: HashMap<String, usize> = HashMap::new();
    let mut groups: Vec<Group> = Vec::new();
    let mut group = Group::default();
    for statement in &obj.statements {
        match statement {
            Statement::Mtllib { name, line } => {
                let (mats, names) = libs.load(name, *line)?;
                // as `tobj` merges libraries: a later definition of a name wins
                let offset = tobj_materials.len();
                tobj_materials.extend(mats);
                by_name.extend(names.into_iter().map(|(n, i)| (n, i + offset)));
            }
            Statement::Group => group.split(&mut groups),
            Statement::Usemtl(name) => {
                // an unknown name leaves the faces without a material
                let id = by_name.get(name).copied();
                if group.material != id {
                    group.split(&mut groups);
                }
                group.material = id;
            }
            Statement::Face(corners) => group.faces.push(corners.clone()),
        }
    }
    group.split(&mut groups);

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

    let (positions, faces, defaulted) = collect_faces(&obj, &groups, materials.len())
        .map_err(|e| e.in_file(path, Location::File))?;
    // the faces are made: of the parse only the faces' lines are read again (in errors)
    drop(groups);
    let face_lines = std::mem::take(&mut obj.face_lines);
    drop(obj);
    if defaulted > 0 {
        materials.push(Material::builtin_default());
        warnings.push(Warning::DefaultMaterial { faces: defaulted });
    }

    let two_sided = vec![options.two_sided; materials.len()];
    let (scene, more) = Scene::new_lit_sky(
        positions,
        faces,
        materials,
        options.lights.clone(),
        options.sky.clone(),
    )
    .map_err(|e| {
        locate(
            e,
            path,
            &face_lines,
            &libs.material_sources,
            &tobj_materials,
        )
    })?;
    let scene = scene.with_two_sided(two_sided);
    warnings.extend(more);
    Ok(Loaded {
        scene,
        warnings,
        camera: None,
        gltf: None,
    })
}

/// Faces of one material within one object or group (a `tobj` model).
#[derive(Default)]
struct Group {
    /// Index into the MTL materials, if the `usemtl` in force named a known one.
    material: Option<usize>,
    /// Each face's range of [`ObjText::corners`].
    faces: Vec<Range<usize>>,
}

impl Group {
    /// Ends the group if it has faces (the next one keeps its material), as `tobj` does at
    /// `o`, `g`, a `usemtl` that changes the material and the end of the file.
    fn split(&mut self, groups: &mut Vec<Group>) {
        if !self.faces.is_empty() {
            groups.push(Group {
                material: self.material,
                faces: std::mem::take(&mut self.faces),
            });
        }
    }
}

/// Reads the MTL files an OBJ names, remembering where each material was defined.
struct MtlLibs<'a> {
    obj: &'a Path,
    options: &'a LoadOptions,
    /// File and `newmtl` line of each material, in load order.
    material_sources: Vec<(PathBuf, usize)>,
}

impl MtlLibs<'_> {
    /// The materials of the library `name` named on OBJ line `line`, and their indices by
    /// name, as `tobj` reads them.
    fn load(
        &mut self,
        name: &str,
        line: usize,
    ) -> Result<(Vec<tobj::Material>, HashMap<String, usize>), SceneError> {
        let mtl = files::resolve_named(self.obj, name, false, self.options)
            .map_err(|e| e.in_file(self.obj, Location::Line(line)))?;
        let bytes = match files::read_file(&mtl, self.options) {
            Ok(b) => b,
            Err(SceneError::Io { reason, .. }) => {
                return Err(SceneError::MissingMtl {
                    obj: self.obj.to_path_buf(),
                    line,
                    mtl,
                    reason,
                });
            }
            Err(e) => return Err(e.in_file(self.obj, Location::Line(line))),
        };
        let text = String::from_utf8_lossy(&bytes);
        let mtl_text =
            obj_text::scan_mtl(&text).map_err(|(l, e)| e.in_file(&mtl, Location::Line(l)))?;
        match tobj::load_mtl_buf(&mut mtl_text.text.as_bytes()) {
            Ok((mats, map)) => {
                for i in 0..mats.len() {
                    let l = mtl_text.newmtl_lines.get(i).copied().unwrap_or(0);
                    self.material_sources.push((mtl.clone(), l));
                }
                Ok((mats, map.into_iter().collect()))
            }
            Err(tobj_error) => {
                // tobj's errors carry no line: find the first line that fails on its own.
                let bad = mtl_text
                    .text
                    .lines()
                    .position(|l| tobj::load_mtl_buf(&mut l.as_bytes()).is_err());
                Err(match bad {
                    Some(i) => SceneError::parse(format!(
                        "cannot parse {}: {tobj_error}",
                        crate::quote(mtl_text.text.lines().nth(i).unwrap_or("").trim())
                    ))
                    .in_file(&mtl, Location::Line(i + 1)),
                    None => SceneError::parse(format!("tobj cannot read it: {tobj_error}"))
                        .in_file(&mtl, Location::File),
                })
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

/// The groups' positions and faces, in file order: each group lists the positions its faces
/// use once, in order of first use (as `tobj` does, so a vertex used by several groups appears
/// once per group). Faces without a (known) material get index `materials` (the default
/// material, appended by the caller); their count is returned.
fn collect_faces(
    obj: &ObjText,
    groups: &[Group],
    materials: usize,
) -> Result<(Vec<Vec3>, Vec<Face>, usize), SceneError> {
    let too_many = |what: &str| SceneError::Unsupported {
        what: format!("more than {} {what}", u32::MAX),
    };
    let default = u32::try_from(materials).map_err(|_| too_many("materials"))?;
    let mut positions = Vec::new();
    let mut defaulted = 0;
    // Each OBJ vertex's index in this group's positions (`UNSEEN` before its first use): a
    // dense table reset through the entries the group touched, instead of a hash map (a
    // quarter of the time of loading ten million triangles went to hashing).
    const UNSEEN: u32 = u32::MAX;
    let mut index: Vec<u32> = vec![UNSEEN; obj.positions.len()];
    let mut touched: Vec<usize> = Vec::new();
    // First, in order, each corner's index into `positions` (`mapped[c]` for `obj.corners[c]`)
    let mut mapped: Vec<u32> = vec![0; obj.corners.len()];
    let mut group_materials = Vec::with_capacity(groups.len());
    for group in groups {
        for v in touched.drain(..) {
            index[v] = UNSEEN;
        }
        let material = match group.material {
            Some(id) if id < materials => id as u32,
            _ => default,
        };
        group_materials.push(material);
        if material == default {
            defaulted += group.faces.len();
        }
        for corners in &group.faces {
            for c in corners.clone() {
                let v = obj.corners[c];
                mapped[c] = match index[v] {
                    UNSEEN => {
                        let next =
                            u32::try_from(positions.len()).map_err(|_| too_many("vertices"))?;
                        if next == UNSEEN {
                            return Err(too_many("vertices"));
                        }
                        positions.push(obj.positions[v]);
                        index[v] = next;
                        touched.push(v);
                        next
                    }
                    i => i,
                };
            }
        }
    }
    // then the faces, in parallel (each its own list of vertices), in order
    let total: usize = groups.iter().map(|g| g.faces.len()).sum();
    if total > u32::MAX as usize + 1 {
        return Err(too_many("faces"));
    }
    let mut faces = Vec::with_capacity(total);
    for (group, &material) in groups.iter().zip(&group_materials) {
        let first = faces.len();
        faces.par_extend(group.faces.par_iter().enumerate().map(|(k, corners)| Face {
            vertices: mapped[corners.clone()].to_vec(),
            material,
            source: (first + k) as u32,
        }));
    }
    Ok((positions, faces, defaulted))
}

/// Wraps a [`Scene::new`] error with the file and line it comes from: the MTL file and
/// `newmtl` line for a material, the OBJ line for a face, else the OBJ file.
fn locate(
    e: SceneError,
    obj_path: &Path,
    face_lines: &[usize],
    material_sources: &[(PathBuf, usize)],
    tobj_materials: &[tobj::Material],
) -> SceneError {
    let face_line = |face: u32| face_lines.get(face as usize).copied();
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Positions and faces (vertices, material) as `tobj` groups `obj` (already in the form it
    /// reads: every `v` first, absolute indices), with `mtl` the MTL files by name.
    fn as_tobj_reads(obj: &str, mtl: &[(&str, &str)]) -> (Vec<Vec3>, Vec<(Vec<u32>, u32)>) {
        #[allow(clippy::needless_update)]
        let options = tobj::LoadOptions {
            triangulate: false,
            single_index: false,
            ignore_points: true,
            ignore_lines: true,
            ..Default::default()
        };
        let (models, materials) = tobj::load_obj_buf(&mut obj.as_bytes(), &options, |p| {
            let text = mtl.iter().find(|(n, _)| Path::new(n) == p).unwrap().1;
            tobj::load_mtl_buf(&mut text.as_bytes())
        })
        .unwrap();
        let default = materials.unwrap().len() as u32;
        let (mut positions, mut faces) = (Vec::new(), Vec::new());
        for model in models {
            let offset = positions.len() as u32;
            positions.extend(
                model
                    .mesh
                    .positions
                    .chunks(3)
                    .map(|p| vec3([p[0], p[1], p[2]])),
            );
            let material = model.mesh.material_id.map_or(default, |m| m as u32);
            // tobj leaves `face_arities` empty when every face is a triangle
            let mut arities = model.mesh.face_arities.clone();
            if arities.is_empty() {
                arities = vec![3; model.mesh.indices.len() / 3];
            }
            let mut start = 0;
            for arity in arities {
                let end = start + arity as usize;
                let vertices = model.mesh.indices[start..end].iter().map(|&i| i + offset);
                faces.push((vertices.collect(), material));
                start = end;
            }
        }
        (positions, faces)
    }

    #[test]
    fn faces_are_grouped_and_materials_resolved_as_tobj_does() {
        // usemtl before its library, unknown names, repeated and redefined materials, groups,
        // vertices shared between groups
        let obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\n\
                   f 1 2 3 4\nusemtl lamp\nf 1 2 3\nmtllib a.mtl\no first\nusemtl white\n\
                   f 2 5 6 3\nusemtl lamp\nf 1 2 3 4\nusemtl nothing\nf 2 5 6\ng second\n\
                   f 1 5 6\nusemtl white\nusemtl white\nf 2 5 6\nmtllib b.mtl\nusemtl white\n\
                   f 3 4 1\nusemtl lamp\nf 2 5 6 3\n";
        let mtl = [
            (
                "a.mtl",
                "newmtl white\nKd 0.5 0.5 0.5\nnewmtl lamp\nKd 0.5 0.5 0.5\nKe 1 1 1\n",
            ),
            ("b.mtl", "newmtl white\nKd 0.25 0.25 0.25\n"),
        ];
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("s.obj"), obj).unwrap();
        for (name, text) in mtl {
            std::fs::write(dir.path().join(name), text).unwrap();
        }
        let loaded = load_obj(&dir.path().join("s.obj"), &LoadOptions::default()).unwrap();
        let (positions, faces) = as_tobj_reads(obj, &mtl);
        assert_eq!(loaded.scene.positions(), positions);
        let got: Vec<(Vec<u32>, u32)> = loaded
            .scene
            .faces()
            .iter()
            .map(|f| (f.vertices.clone(), f.material))
            .collect();
        assert_eq!(got, faces);
        // the second library's `white` is what the last faces use
        assert_eq!(faces[7].1, 2);
        assert_eq!(loaded.scene.materials()[2].reflectance, Vec3::splat(0.25));
    }
}
