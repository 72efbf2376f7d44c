//! Writing binary glTF (GLB): the one writer of the container in mcrad, used by
//! `mcrad-export` (`--gltf`, the solved mesh with vertex radiosity) and `mcrad-bake` (the
//! user's document with its lightmap, and scenes converted to glTF).
//!
//! A GLB file is a 12-byte header, a JSON chunk (padded with spaces to 4 bytes) and one binary
//! chunk (padded with zeros). The binary chunk is built with [`BinaryChunk`], whose pieces all
//! start 4-byte aligned (so any accessor's components are aligned); [`push_view`] and
//! [`push_accessor`] describe a piece with `gltf-json`'s types; [`write_glb`] and
//! [`glb_bytes`] write the container.

use gltf::json;
use json::accessor::{ComponentType, GenericComponentType, Type};
use json::validation::{Checked::Valid, USize64};
use std::io::Write;
use std::ops::Range;

/// Why a GLB file could not be written.
#[derive(Debug, thiserror::Error)]
pub enum GlbError {
    /// The file would be larger than GLB's 32-bit lengths allow.
    #[error(
        "the file would be {bytes} bytes; GLB is limited to {} bytes",
        u32::MAX
    )]
    TooLarge {
        /// The size the file would have, bytes.
        bytes: u64,
    },
    /// Writing to the output failed.
    #[error("could not write the GLB file: {0}")]
    Io(#[source] std::io::Error),
}

/// The binary chunk of a GLB file being built: pieces appended one after the other, each
/// starting at a multiple of 4 bytes.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct BinaryChunk {
    bytes: Vec<u8>,
}

impl BinaryChunk {
    /// An empty chunk.
    pub fn new() -> BinaryChunk {
        BinaryChunk::default()
    }

    /// Appends `data` after zero padding to a multiple of 4 bytes; its byte range in the chunk.
    pub fn push(&mut self, data: &[u8]) -> Range<usize> {
        self.align();
        let start = self.bytes.len();
        self.bytes.extend_from_slice(data);
        start..self.bytes.len()
    }

    /// Appends `values` as little-endian `f32` (4-byte aligned); their byte range.
    pub fn push_f32(&mut self, values: impl IntoIterator<Item = f32>) -> Range<usize> {
        self.align();
        let start = self.bytes.len();
        for v in values {
            self.bytes.extend_from_slice(&v.to_le_bytes());
        }
        start..self.bytes.len()
    }

    /// Appends `values` as little-endian `u32` (4-byte aligned); their byte range.
    pub fn push_u32(&mut self, values: impl IntoIterator<Item = u32>) -> Range<usize> {
        self.align();
        let start = self.bytes.len();
        for v in values {
            self.bytes.extend_from_slice(&v.to_le_bytes());
        }
        start..self.bytes.len()
    }

    /// Pads the chunk with zeros to a multiple of 4 bytes.
    pub fn align(&mut self) {
        let padded = self.bytes.len().next_multiple_of(4);
        self.bytes.resize(padded, 0);
    }

    /// Its length in bytes (padding included).
    pub fn len(&self) -> usize {
        self.bytes.len()
    }

    /// Whether nothing has been appended.
    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }

    /// The bytes so far.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The bytes, padded to a multiple of 4 as the GLB chunk holds them.
    pub fn into_bytes(mut self) -> Vec<u8> {
        self.align();
        self.bytes
    }
}

/// Adds to `root` a buffer view of bytes `range` of `buffer` (its `byteOffset` written even
/// when 0), with `target` when given; its index.
pub fn push_view(
    root: &mut json::Root,
    buffer: json::Index<json::Buffer>,
    range: Range<usize>,
    target: Option<json::buffer::Target>,
) -> json::Index<json::buffer::View> {
    root.push(json::buffer::View {
        buffer,
        byte_length: USize64::from(range.len()),
        byte_offset: Some(USize64::from(range.start)),
        byte_stride: None,
        name: None,
        target: target.map(Valid),
        extensions: None,
        extras: None,
    })
}

/// Adds to `root` a dense accessor of `count` elements of `type_` with `component` components
/// over all of `view`, with `min` and `max` when `bounds` is given (POSITION needs them); its
/// index.
pub fn push_accessor(
    root: &mut json::Root,
    view: json::Index<json::buffer::View>,
    count: usize,
    component: ComponentType,
    type_: Type,
    bounds: Option<(&[f32], &[f32])>,
) -> json::Index<json::Accessor> {
    let values = |v: &[f32]| json::Value::from(v.to_vec());
    root.push(json::Accessor {
        buffer_view: Some(view),
        byte_offset: None,
        count: USize64::from(count),
        component_type: Valid(GenericComponentType(component)),
        extensions: None,
        extras: None,
        type_: Valid(type_),
        min: bounds.map(|(lo, _)| values(lo)),
        max: bounds.map(|(_, hi)| values(hi)),
        name: None,
        normalized: false,
        sparse: None,
    })
}

/// The size of a GLB file of `json` and `bin` bytes (each chunk padded to 4 bytes).
fn glb_length(json: usize, bin: usize) -> u64 {
    let padded = |n: usize| n.div_ceil(4) as u64 * 4;
    12 + 8 + padded(json) + 8 + padded(bin)
}

/// Writes one GLB file to `out`: the document `json` (UTF-8 JSON text) and the binary chunk
/// `bin` (the document's buffer 0, without a `uri`), each padded to 4 bytes (JSON with spaces,
/// binary with zeros).
///
/// Errors: [`GlbError::TooLarge`] if the file would exceed 4 GiB (nothing is written then),
/// [`GlbError::Io`] if writing fails.
pub fn write_glb<W: Write>(out: W, json: &[u8], bin: &[u8]) -> Result<(), GlbError> {
    let bytes = glb_length(json.len(), bin.len());
    let length = u32::try_from(bytes).map_err(|_| GlbError::TooLarge { bytes })?;
    let glb = gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length,
        },
        json: json.into(),
        bin: Some(bin.into()),
    };
    glb.to_writer(out).map_err(|e| match e {
        gltf::Error::Io(e) => GlbError::Io(e),
        other => GlbError::Io(std::io::Error::other(other.to_string())),
    })
}

/// [`write_glb`] into memory: the GLB file's bytes.
pub fn glb_bytes(json: &[u8], bin: &[u8]) -> Result<Vec<u8>, GlbError> {
    let mut out = Vec::new();
    write_glb(&mut out, json, bin)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pieces_are_aligned_and_the_container_reads_back() {
        let mut bin = BinaryChunk::new();
        assert!(bin.is_empty());
        assert_eq!(bin.push(b"abc"), 0..3);
        assert_eq!(bin.push_f32([1.5, -2.0]), 4..12);
        assert_eq!(bin.push_u32([7]), 12..16);
        assert_eq!(bin.push(b"x"), 16..17);
        assert_eq!(bin.as_bytes()[3], 0);
        assert_eq!(bin.len(), 17);
        let bin = bin.into_bytes();
        assert_eq!(bin.len(), 20);
        assert_eq!(&bin[4..8], &1.5f32.to_le_bytes());

        let json = br#"{"asset":{"version":"2.0"}}"#;
        let bytes = glb_bytes(json, &bin).unwrap();
        assert_eq!(bytes.len() as u64, glb_length(json.len(), bin.len()));
        assert_eq!(&bytes[8..12], &(bytes.len() as u32).to_le_bytes());
        let glb = gltf::binary::Glb::from_slice(&bytes).unwrap();
        assert_eq!(glb.json.trim_ascii_end(), json);
        assert_eq!(glb.bin.as_deref(), Some(&bin[..]));
    }

    #[test]
    fn views_and_accessors_describe_their_pieces() {
        let mut bin = BinaryChunk::new();
        let mut root = json::Root::default();
        let buffer = root.push(json::Buffer {
            byte_length: USize64(0),
            name: None,
            uri: None,
            extensions: None,
            extras: None,
        });
        bin.push(b"z");
        let range = bin.push_f32([0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
        let view = push_view(
            &mut root,
            buffer,
            range,
            Some(json::buffer::Target::ArrayBuffer),
        );
        let accessor = push_accessor(
            &mut root,
            view,
            2,
            ComponentType::F32,
            Type::Vec3,
            Some((&[0.0, 1.0, 2.0], &[3.0, 4.0, 5.0])),
        );
        let value = root.to_value().unwrap();
        assert_eq!(value["bufferViews"][0]["byteOffset"], 4);
        assert_eq!(value["bufferViews"][0]["byteLength"], 24);
        assert_eq!(value["bufferViews"][0]["target"], 34962);
        assert_eq!(value["accessors"][accessor.value()]["count"], 2);
        assert_eq!(
            value["accessors"][0]["max"],
            json::Value::from(vec![3.0, 4.0, 5.0])
        );
    }
}
