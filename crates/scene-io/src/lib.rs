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
//! Loading never prints: repairs (dropped degenerate faces, defaulted materials) are returned as
//! [`Warning`]s next to the scene, and bad input is a typed [`SceneError`].

mod error;
mod gltf_load;
mod obj;
mod scene;

pub use error::{SceneError, Warning};
pub use scene::{Face, Material, Scene};

use std::path::Path;

/// A loaded scene together with the repairs made while loading it.
#[derive(Debug, Clone)]
pub struct Loaded {
    /// The validated scene.
    pub scene: Scene,
    /// Repairs made on the way (each one counted), for the caller to report.
    pub warnings: Vec<Warning>,
}

/// Loads a scene from `path`, choosing the reader by extension: `.obj` (with the `.mtl` files it
/// names), `.gltf` or `.glb`.
pub fn load(path: &Path) -> Result<Loaded, SceneError> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .as_deref()
    {
        Some("obj") => obj::load_obj(path),
        Some("gltf") | Some("glb") => gltf_load::load_gltf(path),
        _ => Err(SceneError::UnsupportedFormat {
            path: path.to_path_buf(),
        }),
    }
}
