//! Scene input for mcrad: OBJ+MTL (through `tobj`) and glTF/GLB (through `gltf`) read into one
//! validated [`Scene`] of planar polygon faces with diffuse materials.
//!
//! Units and conventions (see `ARCHITECTURE.md`):
//! - positions are in scene units (metres unless the file says otherwise); areas in units².
//! - [`Material::reflectance`] is the diffuse reflectance `rho` per RGB channel, each in `[0, 1)`.
//! - [`Material::emission`] is the emitted radiosity `E` (exitance, W/m²) per RGB channel, `>= 0`.
//!   OBJ/MTL: `Kd` is `rho`, `Ke` is `E`. glTF: `baseColorFactor` is `rho`,
//!   `emissiveFactor * KHR_materials_emissive_strength` is the emitted *radiance* `L`, so
//!   `E = pi * L`.
//! - a face is front-facing on the side from which its vertices run counter-clockwise.
//!
//! Every loader ends in [`Scene::new`], the one validation path: it rejects bad content (no
//! faces, non-finite positions, reflectance outside `[0, 1)`, negative emission, no emitter,
//! ...), drops degenerate faces and splits non-planar or non-convex ones into triangles, so
//! every face of a [`Scene`] is planar, has non-zero area and can be fanned from its first
//! vertex. Faces keep their input number ([`Face::source`]) through drops and splits.
//!
//! Hostile input is bounded ([`LoadOptions`], and the limits [`MAX_FACE_VERTICES`],
//! [`MAX_FACES`], [`MAX_COORDINATE`]): only regular files are read, each of at most
//! [`LoadOptions::max_file_bytes`], and files a scene names (`mtllib`, glTF buffer URIs) must lie
//! inside the scene file's folder unless [`LoadOptions::allow_outside_paths`] is set.
//!
//! Loading never prints and never panics on bad input: repairs (dropped or split faces,
//! defaulted materials, skipped primitives) are returned as counted [`Warning`]s next to the
//! scene, and bad input is a typed [`SceneError`] whose message names the file, the line (OBJ,
//! MTL) or node/mesh/primitive (glTF), and the offending value. Faces without a material get
//! [`Material::builtin_default`] (0.5 grey, no emission).
//!
//! ```
//! use mcrad_scene_io::load;
//!
//! let dir = tempfile::tempdir()?;
//! std::fs::write(dir.path().join("lamp.mtl"), "newmtl lamp\nKd 0.5 0.5 0.5\nKe 10 10 10\n")?;
//! std::fs::write(
//!     dir.path().join("lamp.obj"),
//!     "mtllib lamp.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl lamp\nf 1 2 3 4\n",
//! )?;
//! let loaded = load(&dir.path().join("lamp.obj"))?;
//! assert!(loaded.warnings.is_empty());
//! let scene = &loaded.scene;
//! let quad = &scene.faces()[0];
//! assert_eq!(quad.vertices.len(), 4); // OBJ polygons are not triangulated
//! assert_eq!(scene.face_area(quad), 1.0); // units²
//! assert_eq!(scene.materials()[quad.material as usize].emission.x, 10.0); // Ke = E, W/m²
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod alpha;
mod error;
mod files;
pub mod glb;
mod gltf_light;
mod gltf_load;
mod gltf_texture;
mod light;
mod obj;
mod obj_text;
mod polygon;
mod scene;
mod sky;
mod texture;

pub use alpha::{AlphaMode, FaceAlpha};
pub use error::{Location, SceneError, Warning};
pub use files::{DEFAULT_MAX_FILE_BYTES, LoadOptions, Outside};
pub use gltf_light::SUN_DIAMETER_EXTRA;
pub use gltf_load::{GltfSource, PrimitiveInstance, percent_decode};
pub use gltf_texture::MAX_TEXTURE_EDGE;
pub use light::{
    DEFAULT_LIGHT_EFFICACY, DEFAULT_SUN_DIAMETER, Light, LightSample, PointLight, SpotLight, Sun,
};
pub use scene::{Bounds, Face, Material, Scene};
pub use sky::{MAX_SKY_EDGE, Sky, SkyMap, SkySample};
pub use texture::{FaceMapping, SceneTextures, Texture, Wrap, srgb_to_linear};

use glam::Vec3;
use std::path::Path;

/// A loaded scene together with the repairs made while loading it.
#[derive(Debug, Clone)]
pub struct Loaded {
    /// The validated scene.
    pub scene: Scene,
    /// Repairs made on the way (each one counted), for the caller to report.
    pub warnings: Vec<Warning>,
    /// The file's viewpoint, when it has one (glTF: the first perspective camera in node
    /// order; OBJ has none).
    pub camera: Option<Camera>,
    /// For a glTF or GLB file, the document and which faces each primitive gave (for writing
    /// results back into it); `None` for OBJ.
    pub gltf: Option<Box<GltfSource>>,
}

/// A pinhole viewpoint from the scene file, in scene units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub eye: Vec3,
    /// Unit viewing direction.
    pub forward: Vec3,
    /// Unit up direction, orthogonal to `forward`.
    pub up: Vec3,
    /// Vertical field of view in degrees, in `(0, 180)`.
    pub fov_y_degrees: f32,
}

/// The most vertices a face may have ([`SceneError::TooManyFaceVertices`] beyond): splitting a
/// non-convex polygon takes time quadratic in its vertices.
pub const MAX_FACE_VERTICES: usize = 1024;

/// The most faces a scene may have ([`SceneError::TooManyFaces`] beyond), counting every
/// instance of a glTF mesh: 2^24, about 0.8 GB of faces before subdivision.
pub const MAX_FACES: usize = 1 << 24;

/// The largest coordinate magnitude accepted, in scene units
/// ([`SceneError::CoordinateTooLarge`] beyond): areas and bounding-box diagonals of faces
/// within it stay finite in `f32` (`(2e18)² * 14 < f32::MAX`).
pub const MAX_COORDINATE: f32 = 1e18;

/// The most characters of input a message quotes (see [`quote`]).
pub const QUOTE_MAX_CHARS: usize = 60;

/// Input text as messages quote it: in single quotes, control characters (a stray CR, NUL,
/// escape sequences) escaped as Rust does (`\r`, `\u{1b}`), and cut after
/// [`QUOTE_MAX_CHARS`] characters with the total length said, so a message stays one short line
/// whatever the file holds.
///
/// ```
/// assert_eq!(mcrad_scene_io::quote("v 1 2\r"), "'v 1 2\\r'");
/// let long = "f 1 2 3 ".repeat(1000);
/// assert!(mcrad_scene_io::quote(&long).ends_with("... (8000 bytes)"));
/// ```
pub fn quote(text: &str) -> String {
    let mut out = String::from("'");
    for (shown, c) in text.chars().enumerate() {
        if shown == QUOTE_MAX_CHARS {
            out.push_str(&format!("'... ({} bytes)", text.len()));
            return out;
        }
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out.push('\'');
    out
}

/// The bytes of a file named `name` by the scene file `scene` (a glTF image URI, an MTL
/// texture), under the same policy as the scene's own files: a relative name is relative to the
/// scene's folder and must stay inside it unless [`LoadOptions::allow_outside_paths`]; only
/// regular files of at most [`LoadOptions::max_file_bytes`]. `uri` says whether `name` is a
/// URI (then `file:` applies and percent-escapes are the caller's to decode).
pub fn read_named_file(
    scene: &Path,
    name: &str,
    uri: bool,
    options: &LoadOptions,
) -> Result<Vec<u8>, SceneError> {
    let file = files::resolve_named(scene, name, uri, options)?;
    files::read_file(&file, options)
}

/// Loads a scene from `path`, choosing the reader by extension: `.obj` (with the `.mtl` files it
/// names), `.gltf` or `.glb`, under the default [`LoadOptions`].
pub fn load(path: &Path) -> Result<Loaded, SceneError> {
    load_with(path, &LoadOptions::default())
}

/// A glTF or GLB document already in memory (`bytes`, e.g. made by a writer), read exactly as
/// [`load_with`] reads the file `path` holding those bytes: `path` names the document in
/// messages and is where relative URIs (buffers, images) resolve from, under `options`. A GLB
/// whose buffer is its binary chunk and whose images are embedded reads no file.
pub fn load_gltf_bytes(
    bytes: Vec<u8>,
    path: &Path,
    options: &LoadOptions,
) -> Result<Loaded, SceneError> {
    gltf_load::load_gltf_bytes(bytes, path, options)
}

/// [`load`] under `options`: which files the scene may name, how large a file may be.
pub fn load_with(path: &Path, options: &LoadOptions) -> Result<Loaded, SceneError> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .as_deref()
    {
        Some("obj") => obj::load_obj(path, options),
        Some("gltf") | Some("glb") => gltf_load::load_gltf(path, options),
        _ => Err(SceneError::UnsupportedFormat {
            path: path.to_path_buf(),
        }),
    }
}
