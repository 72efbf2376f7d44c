//! glTF textures read for the solver: base-colour and emissive textures decoded (under the file
//! policy), and each textured triangle's mapping.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use glam::{Vec2, Vec3};
use gltf::texture::WrappingMode;

use crate::error::Warning;
use crate::files::LoadOptions;
use crate::texture::{FaceMapping, SceneTextures, Texture, Wrap, srgb_to_linear};

/// The largest texture edge decoded, texels (larger images are refused with a warning).
pub const MAX_TEXTURE_EDGE: u32 = 16384;

/// Textures decoded so far and the mappings of the faces read so far.
pub(crate) struct TextureReader<'a> {
    document: &'a gltf::Document,
    path: &'a Path,
    options: &'a LoadOptions,
    buffers: &'a [gltf::buffer::Data],
    /// Texture index in the document → index in `out.textures` (`None`: unreadable).
    decoded: HashMap<usize, Option<u32>>,
    /// Unreadable textures: (document index, reason), each once.
    pub unreadable: Vec<(usize, String)>,
    pub out: SceneTextures,
    /// The largest texel of each of `out.textures`, per channel.
    maxima: Vec<Vec3>,
}

/// What a material asks of the textures: (texture, texCoord set) for base colour and emission.
#[derive(Debug, Clone, Copy, Default)]
struct Wanted {
    base: Option<(usize, u32)>,
    emissive: Option<(usize, u32)>,
}

fn wanted(material: &gltf::Material) -> Wanted {
    let base = material
        .pbr_metallic_roughness()
        .base_color_texture()
        .map(|t| (t.texture().index(), t.tex_coord()));
    let emissive = material
        .emissive_texture()
        .filter(|_| material.emissive_factor().iter().any(|&f| f > 0.0))
        .map(|t| (t.texture().index(), t.tex_coord()));
    Wanted { base, emissive }
}

impl<'a> TextureReader<'a> {
    pub(crate) fn new(
        document: &'a gltf::Document,
        path: &'a Path,
        options: &'a LoadOptions,
        buffers: &'a [gltf::buffer::Data],
    ) -> TextureReader<'a> {
        TextureReader {
            document,
            path,
            options,
            buffers,
            decoded: HashMap::new(),
            unreadable: Vec::new(),
            out: SceneTextures::default(),
            maxima: Vec::new(),
        }
    }

    /// Records the mappings of a primitive's triangles (`triangles[k]` is face
    /// `first_source + k`, corners placed at `world`), if its material has textures or it has
    /// vertex colours; `scale` multiplies the mapped vertex colours (it undoes the clamp of a
    /// factor channel of 1.0). Returns the largest `COLOR_0 × baseColorTexture` the faces take,
    /// per channel (1 without a mapping: the material's factor applies as it is).
    pub(crate) fn add_primitive(
        &mut self,
        primitive: &gltf::Primitive,
        first_source: usize,
        triangles: &[[u32; 3]],
        world: &[Vec3],
        scale: Vec3,
    ) -> Vec3 {
        let w = wanted(&primitive.material());
        let buffers = self.buffers;
        let reader = primitive.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let colors: Option<Vec<Vec3>> = reader
            .read_colors(0)
            .map(|c| c.into_rgb_f32().map(Vec3::from).collect());
        if w.base.is_none() && w.emissive.is_none() && colors.is_none() {
            return Vec3::ONE;
        }
        let set = w.base.or(w.emissive).map_or(0, |(_, s)| s);
        let uv: Option<Vec<Vec2>> = reader
            .read_tex_coords(set)
            .map(|t| t.into_f32().map(Vec2::from).collect());
        let texture = |this: &mut Self, t: Option<(usize, u32)>| {
            let (index, _) = t?;
            uv.as_ref()?;
            this.texture(index)
        };
        let base = texture(self, w.base);
        let emissive = texture(self, w.emissive);
        let n = world.len();
        let colors_ok = colors.as_ref().is_none_or(|v| v.len() == n);
        let uv_ok = uv.as_ref().is_none_or(|v| v.len() == n);
        if !colors_ok || !uv_ok || (base.is_none() && emissive.is_none() && colors.is_none()) {
            return Vec3::ONE;
        }
        let texel_max = base.map_or(Vec3::ONE, |t| self.maxima[t as usize]);
        let mut reach = Vec3::ZERO;
        if self.out.faces.len() < first_source + triangles.len() {
            self.out.faces.resize(first_source + triangles.len(), None);
        }
        for (k, t) in triangles.iter().enumerate() {
            let at = |i: usize| t[i] as usize;
            let uv_of = |i: usize| {
                uv.as_ref()
                    .map_or(Vec2::ZERO, |u| u[at(i)])
                    .clamp(Vec2::splat(-1e6), Vec2::splat(1e6))
            };
            let color_of = |i: usize| colors.as_ref().map_or(Vec3::ONE, |c| c[at(i)]) * scale;
            let uv = [uv_of(0), uv_of(1), uv_of(2)];
            // NaN texture coordinates: the face keeps its factors
            let uv_ok = uv.iter().all(|u| u.is_finite());
            let texel_max = if uv_ok { texel_max } else { Vec3::ONE };
            for i in 0..3 {
                reach = reach.max(color_of(i) / scale * texel_max);
            }
            self.out.faces[first_source + k] = Some(FaceMapping {
                corners: [world[at(0)], world[at(1)], world[at(2)]],
                uv,
                colors: [color_of(0), color_of(1), color_of(2)],
                base: base.filter(|_| uv_ok),
                emissive: emissive.filter(|_| uv_ok),
            });
        }
        reach
    }

    /// The index in `out.textures` of document texture `index`, decoding it the first time;
    /// `None` (and a note in `unreadable`) when it cannot be read.
    fn texture(&mut self, index: usize) -> Option<u32> {
        if let Some(&known) = self.decoded.get(&index) {
            return known;
        }
        let result = match self.document.textures().nth(index) {
            Some(t) => self.decode(&t),
            None => Err("not found".to_string()),
        };
        let slot = match result {
            Ok(texture) => {
                self.maxima.push(texture.max());
                self.out.textures.push(Arc::new(texture));
                Some((self.out.textures.len() - 1) as u32)
            }
            Err(reason) => {
                self.unreadable.push((index, reason));
                None
            }
        };
        self.decoded.insert(index, slot);
        slot
    }

    /// Decodes a texture's image to linear RGB (sRGB-decoded) with its sampler's wrapping.
    fn decode(&self, texture: &gltf::Texture) -> Result<Texture, String> {
        let bytes: Vec<u8> = match texture.source().source() {
            gltf::image::Source::View { view, .. } => {
                let data = self
                    .buffers
                    .get(view.buffer().index())
                    .ok_or("its buffer is missing")?;
                data.get(view.offset()..view.offset() + view.length())
                    .ok_or("its bufferView is outside its buffer")?
                    .to_vec()
            }
            gltf::image::Source::Uri { uri, .. } if uri.starts_with("data:") => {
                use base64::Engine as _;
                let payload = uri
                    .split_once(";base64,")
                    .map(|(_, p)| p)
                    .ok_or("its data: URI is not base64")?;
                base64::engine::general_purpose::STANDARD
                    .decode(payload.trim_end())
                    .map_err(|e| format!("its data: URI is not valid base64 ({e})"))?
            }
            gltf::image::Source::Uri { uri, .. } => {
                let name = crate::gltf_load::percent_decode(uri).ok_or("its URI is not UTF-8")?;
                crate::read_named_file(self.path, &name, true, self.options)
                    .map_err(|e| e.to_string())?
            }
        };
        let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| e.to_string())?;
        let mut limits = image::Limits::default();
        limits.max_image_width = Some(MAX_TEXTURE_EDGE);
        limits.max_image_height = Some(MAX_TEXTURE_EDGE);
        limits.max_alloc = Some(2 << 30);
        reader.limits(limits);
        let image = reader.decode().map_err(|e| e.to_string())?.to_rgb8();
        let (w, h) = image.dimensions();
        let texels = image
            .pixels()
            .map(|p| Vec3::from(p.0.map(|c| srgb_to_linear(f32::from(c) / 255.0))))
            .collect();
        let mode = |m: WrappingMode| match m {
            WrappingMode::Repeat => Wrap::Repeat,
            WrappingMode::ClampToEdge => Wrap::Clamp,
            WrappingMode::MirroredRepeat => Wrap::Mirror,
        };
        let sampler = texture.sampler();
        Texture::new(
            w,
            h,
            texels,
            [mode(sampler.wrap_s()), mode(sampler.wrap_t())],
        )
        .ok_or_else(|| "the image is empty".to_string())
    }

    /// The warnings for textures that could not be read.
    pub(crate) fn warnings(&self) -> Vec<Warning> {
        let mut w = Vec::new();
        if let Some((texture, reason)) = self.unreadable.first() {
            w.push(Warning::TexturesUnreadable {
                count: self.unreadable.len(),
                first: *texture,
                reason: reason.clone(),
            });
        }
        w
    }
}
