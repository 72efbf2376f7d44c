//! What can go wrong while loading a scene ([`SceneError`]) and what was repaired ([`Warning`]).

use glam::Vec3;
use std::fmt;
use std::path::PathBuf;

/// Formats a vector as `(x, y, z)` with Rust's shortest round-trip float format (in exponent
/// notation below 1e-4 and from 1e7), so `NaN`, `inf` and the exact offending values show.
pub(crate) fn fmt_vec3(v: Vec3) -> String {
    format!("({}, {}, {})", fmt_f32(v.x), fmt_f32(v.y), fmt_f32(v.z))
}

/// A number as short as it reads: exponent notation far from 1 (`1e38`, `5e-9`), else plain.
fn fmt_f32(x: f32) -> String {
    if x != 0.0 && x.is_finite() && !(1e-4..1e7).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// Where in a file an error was found; shown after the file name.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Location {
    /// The file as a whole (or a place the message itself names).
    File,
    /// A 1-based line of a text file (OBJ or MTL).
    Line(usize),
    /// A glTF mesh primitive, reached through a node of the scene graph.
    Primitive {
        /// Index of the node in the document's `nodes` array.
        node: usize,
        /// The node's name, if it has one.
        node_name: Option<String>,
        /// Index of the mesh in the document's `meshes` array.
        mesh: usize,
        /// The mesh's name, if it has one.
        mesh_name: Option<String>,
        /// Index of the primitive within its mesh.
        primitive: usize,
    },
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fn named(
            f: &mut fmt::Formatter<'_>,
            what: &str,
            i: usize,
            name: &Option<String>,
        ) -> fmt::Result {
            match name {
                Some(n) => write!(f, "{what} {i} {}", crate::quote(n)),
                None => write!(f, "{what} {i}"),
            }
        }
        match self {
            Location::File => Ok(()),
            Location::Line(line) => write!(f, " line {line}"),
            Location::Primitive {
                node,
                node_name,
                mesh,
                mesh_name,
                primitive,
            } => {
                f.write_str(" (")?;
                named(f, "node", *node, node_name)?;
                f.write_str(", ")?;
                named(f, "mesh", *mesh, mesh_name)?;
                write!(f, ", primitive {primitive})")
            }
        }
    }
}

/// Why a scene could not be loaded. Grouped by who is responsible: the file system, the file's
/// syntax, and the scene's content (checked by [`Scene::new`](crate::Scene::new), for every
/// loader alike).
///
/// Errors found in a file come wrapped in [`SceneError::InFile`], which names the file and the
/// line or glTF primitive; [`SceneError::innermost`] gives the wrapped error. Every message
/// (`Display`) is complete on its own: it includes the message of the error it wraps, so
/// `source()` is `None` for every variant (a reporter that walks the chain, such as anyhow's
/// `{:#}`, says each cause once). Input quoted in a message is escaped and cut short (see
/// [`quote`](crate::quote)).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SceneError {
    /// A file could not be read. Example: `cannot read scenes/box.obj: No such file or directory
    /// (os error 2)`.
    #[error("cannot read {}: {reason}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's reason.
        reason: std::io::Error,
    },
    /// A file to read is not a regular file (a device such as `/dev/zero`, a pipe or a
    /// directory): only regular files are read. Example: `/dev/zero is not a regular file (a
    /// device, pipe or directory): only regular files are read`.
    #[error("{} is not a regular file (a device, pipe or directory): only regular files are read",
        path.display())]
    NotAFile {
        /// The file.
        path: PathBuf,
    },
    /// A file is larger than [`LoadOptions::max_file_bytes`](crate::LoadOptions). Example:
    /// `big.obj is 2147483648 bytes, more than the limit of 1073741824 bytes per file`.
    #[error("{} is {bytes} bytes, more than the limit of {limit} bytes per file", path.display())]
    FileTooLarge {
        /// The file.
        path: PathBuf,
        /// Its size (or the bytes read when it claimed less), at least `limit + 1`.
        bytes: u64,
        /// The limit.
        limit: u64,
    },
    /// A scene names a file outside its folder and
    /// [`LoadOptions::allow_outside_paths`](crate::LoadOptions) is off (wrapped in
    /// [`SceneError::InFile`], naming the scene file). Example (wrapped): `'../../etc/passwd' is
    /// outside the scene's folder: its '..' climbs out of it (files outside it are read only
    /// when allowed: mcrad --allow-outside-paths)`.
    #[error(
        "{} is outside the scene's folder: {why} (files outside it are read only when \
        allowed: mcrad --allow-outside-paths)",
        crate::quote(name)
    )]
    OutsideScene {
        /// The name as the scene file gives it (`mtllib` argument, buffer URI).
        name: String,
        /// Why it is outside.
        why: crate::Outside,
    },
    /// The file extension is none of `.obj`, `.gltf`, `.glb`. Example: `scene.ply: unsupported
    /// scene format (expected .obj, .gltf or .glb)`.
    #[error("{}: unsupported scene format (expected .obj, .gltf or .glb)", path.display())]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
    },
    /// An OBJ file names (by `mtllib`) a material library that cannot be read. Example:
    /// `box.obj line 2: cannot read material library dir/box.mtl named by mtllib: No such file
    /// or directory (os error 2)`.
    #[error("{} line {line}: cannot read material library {} named by mtllib: {reason}",
        obj.display(), mtl.display())]
    MissingMtl {
        /// The OBJ file.
        obj: PathBuf,
        /// The 1-based line of the `mtllib` statement.
        line: usize,
        /// The MTL path as the OBJ resolves it (relative to the OBJ's directory).
        mtl: PathBuf,
        /// The operating system's reason.
        reason: std::io::Error,
    },
    /// An error found in a file, with the file and the place in it. Example: `box.obj line 57:
    /// face uses vertex 99 but only 36 vertices are defined in total`.
    #[error("{}{location}: {error}", path.display())]
    InFile {
        /// The file (OBJ, MTL, glTF or GLB).
        path: PathBuf,
        /// Where in the file.
        location: Location,
        /// What is wrong there.
        error: Box<SceneError>,
    },
    /// The file is malformed: the message says how. Example (wrapped): `box.obj line 4: vertex
    /// needs 3 numbers, found 'v 1 2'`.
    #[error("{message}")]
    Parse {
        /// What is malformed, quoting the input.
        message: String,
    },
    /// The file uses a feature this reader does not support. Example (wrapped):
    /// `unsupported: sparse accessor 3 for POSITION`.
    #[error("unsupported: {what}")]
    Unsupported {
        /// The feature.
        what: String,
    },
    /// An OBJ face refers to a vertex that does not exist. Examples (wrapped): `face uses vertex
    /// 99 but only 36 vertices are defined in total`, `face uses vertex -40 (relative) but only 36
    /// vertices are defined so far`, `face uses vertex 0, but OBJ vertex numbers start at 1`.
    #[error("{}", obj_index_message(*index, *available))]
    ObjFaceVertex {
        /// The index as written: 1-based, or negative for relative to the last vertex so far.
        index: i64,
        /// Vertices available to it: in total for positive indices, so far for negative ones.
        available: usize,
    },
    /// A glTF primitive's index refers past its vertices. Example (wrapped): `vertex index 40 is
    /// out of range: the primitive has 36 vertices`.
    #[error("vertex index {index} is out of range: the primitive has {count} vertices")]
    IndexOutOfRange {
        /// The offending index (0-based).
        index: u32,
        /// The number of vertices of the primitive.
        count: usize,
    },
    /// The scene has no faces, or none left after dropping degenerate ones. Examples: `the scene
    /// has no faces`, `the scene has no faces left: all 4 were degenerate (zero area) and
    /// dropped`.
    #[error("{}", no_faces_message(*dropped))]
    NoFaces {
        /// Degenerate faces dropped (0 when the input had no faces at all).
        dropped: usize,
    },
    /// A face has more vertices than [`MAX_FACE_VERTICES`](crate::MAX_FACE_VERTICES): splitting
    /// such polygons would take too long. Example (wrapped): `a face has 60000 vertices, more
    /// than the 1024 supported: triangulate it`.
    #[error(
        "a face has {count} vertices, more than the {} supported: triangulate it",
        crate::MAX_FACE_VERTICES
    )]
    TooManyFaceVertices {
        /// The face's vertex count.
        count: usize,
    },
    /// The scene has more faces than [`MAX_FACES`](crate::MAX_FACES) (counting every instance
    /// of a glTF mesh). Example: `the scene has more than 16777216 faces (glTF: counting every
    /// instance of a mesh)`.
    #[error(
        "the scene has more than {} faces (glTF: counting every instance of a mesh)",
        crate::MAX_FACES
    )]
    TooManyFaces,
    /// A coordinate's magnitude exceeds [`MAX_COORDINATE`](crate::MAX_COORDINATE): face areas
    /// would overflow `f32`. Example: `vertex 3 has a coordinate beyond ±1e18 scene units (1e38,
    /// 0, 0): scale the scene down`.
    #[error("vertex {vertex} has a coordinate beyond ±{:e} scene units {}: scale the scene down",
        crate::MAX_COORDINATE, fmt_vec3(*position))]
    CoordinateTooLarge {
        /// The vertex, numbered as in [`SceneError::NonFinitePosition`].
        vertex: usize,
        /// The position as read.
        position: Vec3,
    },
    /// A position has a NaN or infinite coordinate. Example: `vertex 12 has a non-finite
    /// coordinate (NaN, 0, 1)`.
    #[error("vertex {vertex} has a non-finite coordinate {}", fmt_vec3(*position))]
    NonFinitePosition {
        /// The vertex: 0-based index into the positions for [`Scene::new`](crate::Scene::new)
        /// and within the primitive for glTF; the 1-based OBJ vertex number in OBJ files.
        vertex: usize,
        /// The position as read.
        position: Vec3,
    },
    /// A face has fewer than 3 vertices. Example: `face 7 has 2 vertices; a face needs at least
    /// 3`.
    #[error("face {face} has {count} vertices; a face needs at least 3")]
    TooFewVertices {
        /// The face's [`source`](crate::Face::source) number.
        face: u32,
        /// Its number of vertices.
        count: usize,
    },
    /// A face refers to a vertex past the end of the positions. Example: `face 7 uses vertex 40
    /// but there are only 36`.
    #[error("face {face} uses vertex {vertex} but there are only {count}")]
    VertexOutOfRange {
        /// The face's [`source`](crate::Face::source) number.
        face: u32,
        /// The offending 0-based vertex index.
        vertex: u32,
        /// The number of positions.
        count: usize,
    },
    /// A face refers to a material past the end of the materials. Example: `face 7 uses material
    /// 5 but there are only 2`.
    #[error("face {face} uses material {material} but there are only {count}")]
    MaterialOutOfRange {
        /// The face's [`source`](crate::Face::source) number.
        face: u32,
        /// The offending 0-based material index.
        material: u32,
        /// The number of materials.
        count: usize,
    },
    /// A reflectance channel is outside `[0, 1)` or not finite. Example: `material 'red' has
    /// reflectance (1.2, 0.1, 0.1): each channel must be in [0, 1)`.
    #[error("material {} has reflectance {}: each channel must be in [0, 1)",
        crate::quote(material), fmt_vec3(*reflectance))]
    BadReflectance {
        /// The material's name.
        material: String,
        /// The reflectance as read (after any clamping of exact 1.0 in glTF).
        reflectance: Vec3,
    },
    /// An emission channel is negative or not finite. Example: `material 'lamp' has negative
    /// emission (-1, 0, 0): each channel must be finite and >= 0 W/m²`.
    #[error("material {} has {} emission {}: each channel must be finite and >= 0 W/m²",
        crate::quote(material), if emission.is_finite() { "negative" } else { "non-finite" },
        fmt_vec3(*emission))]
    BadEmission {
        /// The material's name.
        material: String,
        /// The emitted radiosity `E` in W/m² as computed from the file.
        emission: Vec3,
    },
    /// No face emits. Examples: `the scene has no emitting face (no material with emission > 0
    /// is used by any face)`; when the only emitters were degenerate: `the scene has no
    /// emitting face left: its 1 emitting face was dropped as degenerate (area 5.0e-13, at most
    /// 3.0e-12 counts as zero: 1e-12 of the bounding-box diagonal squared); the first is face
    /// 1`.
    #[error("{}", no_emitter_message(dropped_emitters, *smallest_dropped_area, *degenerate_area))]
    NoEmitter {
        /// Emitting faces dropped as degenerate: `(count, source of the first)`, `None` when
        /// no face uses an emitting material at all.
        dropped_emitters: Option<(usize, u32)>,
        /// The largest area of those dropped emitting faces, scene units².
        smallest_dropped_area: f64,
        /// The area at or below which a face counts as degenerate, scene units².
        degenerate_area: f64,
    },
    /// A light (point, spot, sun) with a value out of range. Example: `light 2 (spot): cone
    /// angles inner 0.5 and outer 0.4 are not 0 <= inner < outer <= pi/2`.
    #[error("light {index} ({kind}): {reason}")]
    BadLight {
        /// Index of the light in the scene's list (glTF: in the order the nodes are visited).
        index: usize,
        /// The kind of light: `point`, `spot` or `sun`.
        kind: &'static str,
        /// What is wrong, with the value.
        reason: String,
    },
    /// A sky map that cannot be used. Example: `sky map 'sky.exr': 100 x 40 pixels: an
    /// equirectangular map is twice as wide as high, at most 32768 x 16384`.
    #[error("sky map {}: {reason}", crate::quote(&path.display().to_string()))]
    BadSky {
        /// The map's file.
        path: std::path::PathBuf,
        /// What is wrong, with the value.
        reason: String,
    },
    /// A uniform sky with a radiance out of range. Example: `sky: radiance [1, -1, 0]
    /// W/(m² sr) is negative or not finite`.
    #[error("sky: {reason}")]
    BadSkyRadiance {
        /// What is wrong, with the value.
        reason: String,
    },
}

fn obj_index_message(index: i64, available: usize) -> String {
    match index {
        0 => "face uses vertex 0, but OBJ vertex numbers start at 1".to_string(),
        i if i < 0 => format!(
            "face uses vertex {i} (relative) but only {available} vertices are defined so far"
        ),
        i => format!("face uses vertex {i} but only {available} vertices are defined in total"),
    }
}

fn no_emitter_message(dropped: &Option<(usize, u32)>, area: f64, degenerate: f64) -> String {
    match dropped {
        None => "the scene has no emitting face (no material with emission > 0 is used by any \
                 face) and no light: light it with an emissive material or a light (glTF \
                 KHR_lights_punctual point, spot or directional)"
            .to_string(),
        Some((count, first)) => format!(
            "the scene has no emitting face left: its {count} emitting face{s} {was} dropped as \
             degenerate (area {area:.1e}, at most {degenerate:.1e} counts as zero: 1e-12 of the \
             bounding-box diagonal squared); the first is face {first}",
            s = if *count == 1 { "" } else { "s" },
            was = if *count == 1 { "was" } else { "were" },
        ),
    }
}

fn no_faces_message(dropped: usize) -> String {
    if dropped == 0 {
        "the scene has no faces".to_string()
    } else {
        format!(
            "the scene has no faces left: all {dropped} were degenerate (zero area) and dropped"
        )
    }
}

impl SceneError {
    /// The error inside any [`SceneError::InFile`] wrappers: what is wrong, without where.
    pub fn innermost(&self) -> &SceneError {
        match self {
            SceneError::InFile { error, .. } => error.innermost(),
            other => other,
        }
    }

    /// Wraps `self` with the file and place it was found in.
    pub(crate) fn in_file(self, path: impl Into<PathBuf>, location: Location) -> SceneError {
        SceneError::InFile {
            path: path.into(),
            location,
            error: Box::new(self),
        }
    }

    /// A [`SceneError::Parse`] with `message`.
    pub(crate) fn parse(message: impl Into<String>) -> SceneError {
        SceneError::Parse {
            message: message.into(),
        }
    }
}

/// A repair made while loading, counted: the scene is usable, but differs from the file.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Warning {
    /// Faces of zero or near-zero area (`<= 1e-12 * diagonal²` of the scene's bounding box, or
    /// fewer than 3 distinct consecutive vertices) were removed. Example: `dropped 3 degenerate
    /// faces (zero or near-zero area); the first is face 7`.
    DegenerateFacesDropped {
        /// How many faces were dropped.
        count: usize,
        /// [`source`](crate::Face::source) of the first one dropped.
        first_source: u32,
        /// How many of them had an emitting material (their light is lost).
        emitters: usize,
    },
    /// Faces, or triangles of split faces, that repeat an earlier one (the same material and
    /// positions in the same cyclic order, so the same front side) were removed: they would
    /// only hide each other. Example: `dropped 11999 duplicate faces or face parts (the same
    /// vertices, side and material as an earlier one); the first is face 1`.
    DuplicateFacesDropped {
        /// How many faces or parts were dropped.
        count: usize,
        /// [`source`](crate::Face::source) of the first one dropped.
        first_source: u32,
    },
    /// Non-planar or non-convex polygons were split into triangles that keep the polygon's
    /// `source`. Example: `split 2 non-planar or non-convex faces into triangles; the first is
    /// face 4`.
    FacesSplit {
        /// How many input faces were split.
        count: usize,
        /// [`source`](crate::Face::source) of the first one split.
        first_source: u32,
    },
    /// A material lacked a property and got a default. Example: `material 'wall': no Kd;
    /// reflectance set to 0.5 grey`.
    MaterialDefaulted {
        /// The material's name.
        name: String,
        /// What was missing and what it was set to.
        what: String,
    },
    /// Faces with no material got the built-in material
    /// [`Material::DEFAULT_NAME`](crate::Material::DEFAULT_NAME) (reflectance 0.5 grey, no
    /// emission). Example: `12 faces have no material and use the built-in 'default' (reflectance
    /// 0.5, no emission)`.
    DefaultMaterial {
        /// How many faces (as read, before any split or drop).
        faces: usize,
    },
    /// An OBJ `usemtl` names a material that no MTL file defines; its faces use the built-in
    /// default material (and count in [`Warning::DefaultMaterial`]). Example: `usemtl 'gold' on
    /// line 12 names no material of the MTL files`.
    UnknownMaterial {
        /// The name given to `usemtl`.
        name: String,
        /// The 1-based line of the first such `usemtl`.
        line: usize,
    },
    /// glTF primitives without a surface (points, lines, or no `POSITION`) were skipped. Example:
    /// `skipped 2 glTF primitives without a surface (points, lines or no POSITION)`.
    PrimitivesSkipped {
        /// How many primitives (per node instance).
        count: usize,
    },
    /// A glTF material's reflectance (`baseColorFactor`, times `COLOR_0 × baseColorTexture` on
    /// textured faces) reaches 1.0 in some channels on some of its faces; there it is clamped to
    /// 0.999, the largest value the solver accepts with margin. Raised once per material, and
    /// not for a factor of 1.0 whose textures stay below 1. Example: `material 'white':
    /// reflectance (baseColorFactor × texture) reaches 1.0 in 3 channels, clamped to 0.999`.
    ReflectanceClamped {
        /// The material's name.
        material: String,
        /// How many channels reach 1.0 (1 to 3).
        count: usize,
    },
    /// Textures that could not be read (missing file, unknown format such as KTX2 or WebP,
    /// larger than [`MAX_TEXTURE_EDGE`](crate::MAX_TEXTURE_EDGE)): the faces using them keep
    /// their material's factors alone. Example: `2 textures could not be read (texture 0: ...);
    /// their faces use the material's factors alone`.
    TexturesUnreadable {
        /// How many textures.
        count: usize,
        /// The document index of the first.
        first: usize,
        /// Why the first could not be read.
        reason: String,
    },
}

impl fmt::Display for Warning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::DegenerateFacesDropped {
                count,
                first_source,
                emitters,
            } => {
                write!(
                    f,
                    "dropped {count} degenerate faces (zero or near-zero area); the first is face \
                     {first_source}"
                )?;
                if *emitters > 0 {
                    write!(f, "; {emitters} of them emitted light, which is lost")?;
                }
                Ok(())
            }
            Warning::DuplicateFacesDropped {
                count,
                first_source,
            } => write!(
                f,
                "dropped {count} duplicate faces or face parts (the same vertices, side and \
                 material as an earlier one); the first is face {first_source}"
            ),
            Warning::FacesSplit {
                count,
                first_source,
            } => write!(
                f,
                "split {count} non-planar or non-convex faces into triangles; the first is face \
                 {first_source}"
            ),
            Warning::MaterialDefaulted { name, what } => {
                write!(f, "material {}: {what}", crate::quote(name))
            }
            Warning::DefaultMaterial { faces } => write!(
                f,
                "{faces} faces have no material and use the built-in '{}' (reflectance 0.5, no \
                 emission)",
                crate::Material::DEFAULT_NAME
            ),
            Warning::UnknownMaterial { name, line } => write!(
                f,
                "usemtl {} on line {line} names no material of the MTL files",
                crate::quote(name)
            ),
            Warning::PrimitivesSkipped { count } => write!(
                f,
                "skipped {count} glTF primitives without a surface (points, lines or no POSITION)"
            ),
            Warning::ReflectanceClamped { material, count } => write!(
                f,
                "material {}: reflectance (baseColorFactor × texture) reaches 1.0 in {count} \
                 channel{}, clamped to 0.999",
                crate::quote(material),
                if *count == 1 { "" } else { "s" }
            ),
            Warning::TexturesUnreadable {
                count,
                first,
                reason,
            } => write!(
                f,
                "{count} texture{} could not be read (texture {first}: {}); their faces use \
                 the material's factors alone",
                if *count == 1 { "" } else { "s" },
                crate::quote(reason)
            ),
        }
    }
}
