//! Results out of mcrad as files: the per-patch CSV (written and read, through serde and the
//! `csv` crate) and binary glTF with per-vertex radiosity (the formats
//! of the command line contract in `ARCHITECTURE.md`). Pictures are `mcrad-render`'s.
//!
//! Writers take any [`std::io::Write`] and never print; the caller owns files and messages.

mod gltf_out;
mod patches;

pub use gltf_out::{AUTO_EXPOSURE_PERCENTILE, GltfOptions, RADIOSITY_ATTRIBUTE, write_glb};
pub use patches::{
    PATCH_CSV_FACE_HEADER, PATCH_CSV_HEADER, PatchRow, ReadCsvError, patch_rows, per_face,
    read_patch_csv, write_patch_csv,
};

/// Why writing a result failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The output could not be written.
    #[error("could not write {what}: {reason}")]
    Io {
        /// What was being written.
        what: &'static str,
        /// The underlying error.
        reason: std::io::Error,
    },
    /// Serialising to JSON failed.
    #[error("could not encode {what} as JSON: {reason}")]
    Json {
        /// What was being written.
        what: &'static str,
        /// The underlying error.
        reason: serde_json::Error,
    },
    /// The glTF output could not be assembled: inconsistent or non-finite input, or a file too
    /// large for GLB.
    #[error("could not write glTF: {reason}")]
    Gltf {
        /// What is wrong, with the offending values.
        reason: String,
    },
}
