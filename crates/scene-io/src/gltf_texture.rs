//! glTF textures read for the solver: base-colour and emissive textures decoded (under the file
//! policy), and each textured triangle's mapping.

use std::collections::{HashMap, HashSet};
use std::path::Path;
use std::sync::Arc;

use glam::{Affine2, Mat2, Vec2, Vec3};
use gltf::texture::WrappingMode;

use crate::error::Warning;
use crate::files::LoadOptions;
use crate::texture::{FaceMapping, SceneTextures, Texture, Wrap, srgb_to_linear};
use crate::{AlphaMode, FaceAlpha};

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
    /// Document textures whose alpha is kept: the base-colour textures of alpha-tested
    /// materials.
    alpha_textures: HashSet<usize>,
}

/// How a material's alpha lets light through: `None` for `OPAQUE`.
fn alpha_mode(material: &gltf::Material) -> Option<AlphaMode> {
    match material.alpha_mode() {
        gltf::material::AlphaMode::Opaque => None,
        gltf::material::AlphaMode::Mask => Some(AlphaMode::Mask {
            cutoff: material.alpha_cutoff().unwrap_or(0.5),
        }),
        gltf::material::AlphaMode::Blend => Some(AlphaMode::Blend),
    }
}

/// One texture a material asks for: its document index, the `TEXCOORD` set it reads and the
/// `KHR_texture_transform` of those coordinates (the identity without one).
#[derive(Debug, Clone, Copy)]
struct Slot {
    index: usize,
    set: u32,
    transform: Affine2,
}

/// What a material asks of the textures: base colour and emission.
#[derive(Debug, Clone, Copy, Default)]
struct Wanted {
    base: Option<Slot>,
    emissive: Option<Slot>,
}

fn wanted(material: &gltf::Material) -> Wanted {
    let base = material
        .pbr_metallic_roughness()
        .base_color_texture()
        .map(|t| slot(&t));
    let emissive = material
        .emissive_texture()
        .filter(|_| material.emissive_factor().iter().any(|&f| f > 0.0))
        .map(|t| slot(&t));
    Wanted { base, emissive }
}

/// The texture, coordinate set and transform of a `textureInfo`: with `KHR_texture_transform`
/// the coordinates used are `offset + R (scale ⊙ uv)` with `R = [[cos r, sin r], [-sin r, cos
/// r]]` (rows; `r` the rotation in radians, counter-clockwise in the image), and its `texCoord`,
/// if given, replaces the `textureInfo`'s.
fn slot(info: &gltf::texture::Info) -> Slot {
    let (set, transform) = match info.texture_transform() {
        Some(t) => (
            t.tex_coord().unwrap_or(info.tex_coord()),
            uv_transform(t.offset(), t.rotation(), t.scale()),
        ),
        None => (info.tex_coord(), Affine2::IDENTITY),
    };
    Slot {
        index: info.texture().index(),
        set,
        transform,
    }
}

/// The `KHR_texture_transform` map `uv -> offset + R (scale ⊙ uv)` (see [`slot`]).
fn uv_transform(offset: [f32; 2], rotation: f32, scale: [f32; 2]) -> Affine2 {
    let (s, c) = rotation.sin_cos();
    let rotate = Mat2::from_cols(Vec2::new(c, -s), Vec2::new(s, c));
    Affine2::from_mat2_translation(
        rotate * Mat2::from_diagonal(Vec2::from(scale)),
        Vec2::from(offset),
    )
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
            alpha_textures: document
                .materials()
                .filter(|m| alpha_mode(m).is_some())
                .filter_map(|m| m.pbr_metallic_roughness().base_color_texture())
                .map(|t| t.texture().index())
                .collect(),
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
        let material = primitive.material();
        let w = wanted(&material);
        let alpha = alpha_mode(&material);
        let buffers = self.buffers;
        let reader = primitive.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let rgba: Option<Vec<[f32; 4]>> =
            reader.read_colors(0).map(|c| c.into_rgba_f32().collect());
        let colors: Option<Vec<Vec3>> = rgba
            .as_ref()
            .map(|c| c.iter().map(|&[r, g, b, _]| Vec3::new(r, g, b)).collect());
        if w.base.is_none() && w.emissive.is_none() && colors.is_none() && alpha.is_none() {
            return Vec3::ONE;
        }
        // each texture's coordinates: its set, transformed
        let coordinates = |slot: Option<Slot>| -> Option<Vec<Vec2>> {
            let slot = slot?;
            let uv = reader.read_tex_coords(slot.set)?.into_f32();
            Some(
                uv.map(|t| {
                    let t = slot.transform.transform_point2(Vec2::from(t));
                    t.clamp(Vec2::splat(-1e6), Vec2::splat(1e6))
                })
                .collect(),
            )
        };
        let (base_uv, emissive_uv) = (coordinates(w.base), coordinates(w.emissive));
        let n = world.len();
        let read = |this: &mut Self, slot: Option<Slot>, uv: &Option<Vec<Vec2>>| {
            // (texture coordinates of another length than the positions: the texture is not used)
            uv.as_ref().filter(|uv| uv.len() == n)?;
            this.texture(slot?.index)
        };
        let base = read(self, w.base, &base_uv);
        let emissive = read(self, w.emissive, &emissive_uv);
        let colors_ok = colors.as_ref().is_none_or(|v| v.len() == n);
        let nothing = base.is_none() && emissive.is_none() && colors.is_none() && alpha.is_none();
        if !colors_ok || nothing {
            return Vec3::ONE;
        }
        let factor_alpha = material.pbr_metallic_roughness().base_color_factor()[3];
        let texel_max = base.map_or(Vec3::ONE, |t| self.maxima[t as usize]);
        let mut reach = Vec3::ZERO;
        if self.out.faces.len() < first_source + triangles.len() {
            self.out.faces.resize(first_source + triangles.len(), None);
        }
        for (k, t) in triangles.iter().enumerate() {
            let at = |i: usize| t[i] as usize;
            let uv_of =
                |uv: &Option<Vec<Vec2>>, i: usize| uv.as_ref().map_or(Vec2::ZERO, |u| u[at(i)]);
            let color_of = |i: usize| colors.as_ref().map_or(Vec3::ONE, |c| c[at(i)]) * scale;
            let uv = [0, 1, 2].map(|i| uv_of(&base_uv, i));
            let emissive_uv = [0, 1, 2].map(|i| uv_of(&emissive_uv, i));
            // NaN texture coordinates: the face keeps its factors
            let finite = |uv: &[Vec2; 3]| uv.iter().all(|u| u.is_finite());
            let (base, emissive) = (
                base.filter(|_| finite(&uv)),
                emissive.filter(|_| finite(&emissive_uv)),
            );
            let uv_ok = base.is_some();
            let texel_max = if uv_ok { texel_max } else { Vec3::ONE };
            for i in 0..3 {
                reach = reach.max(color_of(i) / scale * texel_max);
            }
            self.out.faces[first_source + k] = Some(FaceMapping {
                corners: [world[at(0)], world[at(1)], world[at(2)]],
                uv,
                emissive_uv,
                colors: [color_of(0), color_of(1), color_of(2)],
                base,
                emissive,
                alpha: alpha.map(|mode| FaceAlpha {
                    mode,
                    factor: factor_alpha.clamp(0.0, 1.0),
                    colors: [0, 1, 2].map(|i| rgba.as_ref().map_or(1.0, |c| c[at(i)][3])),
                }),
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
        let decoded = reader.decode().map_err(|e| e.to_string())?;
        // (alpha is linear in glTF; kept for alpha-tested materials only)
        let alpha = (decoded.color().has_alpha() && self.alpha_textures.contains(&texture.index()))
            .then(|| {
                let rgba = decoded.to_rgba8();
                rgba.pixels()
                    .map(|p| f32::from(p.0[3]) / 255.0)
                    .collect::<Vec<f32>>()
            });
        let image = decoded.to_rgb8();
        drop(decoded);
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
        let texture = Texture::new(
            w,
            h,
            texels,
            [mode(sampler.wrap_s()), mode(sampler.wrap_t())],
        )
        .ok_or_else(|| "the image is empty".to_string())?;
        match alpha {
            Some(alpha) => texture
                .with_alpha(alpha)
                .ok_or_else(|| "its alpha does not match its size".to_string()),
            None => Ok(texture),
        }
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
