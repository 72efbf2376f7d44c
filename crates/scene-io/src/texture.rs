//! Textured albedo and emission: decoded textures with their mip chains, and how each face maps
//! onto them.
//!
//! A face of a glTF scene whose material has a `baseColorTexture` or `emissiveTexture`, or whose
//! primitive has vertex colours `COLOR_0`, gets a [`FaceMapping`]: its three corners, their
//! texture coordinates and colours. The reflectance of any planar polygon lying in that face
//! (a patch, an adaptive element) is then the material's `baseColorFactor` times the mean, over
//! the polygon's area, of `COLOR_0 × baseColorTexture`; its emission likewise the factor times
//! the mean of `emissiveTexture` ([`SceneTextures::average`]). Textures are decoded from sRGB
//! to linear (as glTF specifies for colour textures) and sampled bilinearly at the mip level
//! where each of the polygon's samples covers about one texel, so the mean is area-correct
//! for polygons of any size against the texture's detail.

use std::sync::Arc;

use glam::{Vec2, Vec3};

use crate::FaceAlpha;

/// How texture coordinates outside `[0, 1]` wrap (glTF sampler `wrapS`/`wrapT`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Wrap {
    /// `REPEAT` (glTF's default).
    #[default]
    Repeat,
    /// `CLAMP_TO_EDGE`.
    Clamp,
    /// `MIRRORED_REPEAT`.
    Mirror,
}

/// One mip level: linear RGB texels, row-major, top row first (`v = 0`).
#[derive(Debug, Clone, PartialEq)]
struct Level {
    width: u32,
    height: u32,
    texels: Vec<Vec3>,
}

/// A decoded texture: linear RGB (unitless factors in `[0, 1]`), with its mip chain down to
/// 1 × 1 (each level the 2 × 2 box average of the one above, odd edges clamped).
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    levels: Vec<Level>,
    wrap: [Wrap; 2],
    /// The full-size level's alpha (linear, `[0, 1]`, row-major like the texels), kept for
    /// alpha-tested materials only ([`Texture::with_alpha`]).
    alpha: Option<Vec<f32>>,
}

/// sRGB-encoded `[0, 1]` to linear.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

impl Texture {
    /// A texture of `width × height` linear texels (row-major, top row first) wrapping as
    /// `wrap` (`[s, t]`); `None` when the sizes do not match or are zero.
    pub fn new(width: u32, height: u32, texels: Vec<Vec3>, wrap: [Wrap; 2]) -> Option<Texture> {
        if width == 0 || height == 0 || texels.len() as u64 != u64::from(width) * u64::from(height)
        {
            return None;
        }
        let mut levels = vec![Level {
            width,
            height,
            texels,
        }];
        while let Some(top) = levels.last().filter(|l| l.width > 1 || l.height > 1) {
            let (w, h) = (top.width.div_ceil(2), top.height.div_ceil(2));
            let mut texels = Vec::with_capacity((w * h) as usize);
            for y in 0..h {
                for x in 0..w {
                    let at = |dx: u32, dy: u32| {
                        let (sx, sy) = (
                            (2 * x + dx).min(top.width - 1),
                            (2 * y + dy).min(top.height - 1),
                        );
                        top.texels[(sy * top.width + sx) as usize]
                    };
                    texels.push((at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1)) / 4.0);
                }
            }
            levels.push(Level {
                width: w,
                height: h,
                texels,
            });
        }
        Some(Texture {
            levels,
            wrap,
            alpha: None,
        })
    }

    /// This texture with an alpha channel: `alpha` holds one value in `[0, 1]` per texel of the
    /// full-size level, in the same order; `None` when the count does not match.
    pub fn with_alpha(self, alpha: Vec<f32>) -> Option<Texture> {
        let l = &self.levels[0];
        if alpha.len() != l.texels.len() {
            return None;
        }
        Some(Texture {
            alpha: Some(alpha),
            ..self
        })
    }

    /// The bilinear lookup of the alpha channel at `uv` on the full-size level (wrapping as the
    /// colours do); 1 for a texture without alpha.
    pub fn alpha(&self, uv: Vec2) -> f32 {
        let (Some(alpha), l) = (&self.alpha, &self.levels[0]) else {
            return 1.0;
        };
        bilinear(uv, l.width, l.height, self.wrap, |i| alpha[i])
    }

    /// The largest texel of the full-resolution level, per channel (unitless).
    pub fn max(&self) -> Vec3 {
        self.levels[0]
            .texels
            .iter()
            .fold(Vec3::ZERO, |m, &t| m.max(t))
    }

    /// Width and height of the full-resolution level, texels.
    pub fn size(&self) -> (u32, u32) {
        (self.levels[0].width, self.levels[0].height)
    }

    /// The bilinear lookup at `uv` (glTF convention: `(0, 0)` the top-left corner of the image)
    /// on mip level `level` (clamped to the chain).
    pub fn sample(&self, uv: Vec2, level: usize) -> Vec3 {
        let l = &self.levels[level.min(self.levels.len() - 1)];
        bilinear(uv, l.width, l.height, self.wrap, |i| l.texels[i])
    }
}

/// The bilinear interpolation at `uv` of the texels `texel(index)` of a `width × height` image
/// (row-major, top row first), wrapping as `modes`.
fn bilinear<T>(uv: Vec2, width: u32, height: u32, modes: [Wrap; 2], texel: impl Fn(usize) -> T) -> T
where
    T: std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T>,
{
    let x = uv.x * width as f32 - 0.5;
    let y = uv.y * height as f32 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let at = |i: f32, j: f32| {
        let i = wrap(i as i64, width, modes[0]);
        let j = wrap(j as i64, height, modes[1]);
        texel((j * width + i) as usize)
    };
    let top = at(x0, y0) * (1.0 - fx) + at(x0 + 1.0, y0) * fx;
    let bottom = at(x0, y0 + 1.0) * (1.0 - fx) + at(x0 + 1.0, y0 + 1.0) * fx;
    top * (1.0 - fy) + bottom * fy
}

/// Texel index `i` wrapped into `0..n`.
fn wrap(i: i64, n: u32, mode: Wrap) -> u32 {
    let n = i64::from(n);
    let r = match mode {
        Wrap::Repeat => i.rem_euclid(n),
        Wrap::Clamp => i.clamp(0, n - 1),
        Wrap::Mirror => {
            let m = i.rem_euclid(2 * n);
            if m < n { m } else { 2 * n - 1 - m }
        }
    };
    r as u32
}

/// How one triangle face maps onto its textures and vertex colours.
#[derive(Debug, Clone, PartialEq)]
pub struct FaceMapping {
    /// The face's corners (scene units), in the order of `uv` and `colors`.
    pub corners: [Vec3; 3],
    /// Texture coordinates of the corners on the base-colour texture (the set it names, with
    /// its `KHR_texture_transform` applied).
    pub uv: [Vec2; 3],
    /// Texture coordinates of the corners on the emissive texture (likewise).
    pub emissive_uv: [Vec2; 3],
    /// Linear vertex colours (`COLOR_0` rgb, 1 without).
    pub colors: [Vec3; 3],
    /// The base-colour texture (index into [`SceneTextures::textures`]).
    pub base: Option<u32>,
    /// The emissive texture.
    pub emissive: Option<u32>,
    /// Where light passes the face (glTF `alphaMode` `MASK` or `BLEND`); `None`: opaque.
    pub alpha: Option<FaceAlpha>,
}

/// The textures of a scene and the mapping of each textured face, by face source number
/// ([`Face::source`](crate::Face::source)).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SceneTextures {
    /// The decoded textures.
    pub textures: Vec<Arc<Texture>>,
    /// `faces[source]`: the mapping of the face with that source number, if it has one.
    pub faces: Vec<Option<FaceMapping>>,
}

/// Samples per fan triangle of a polygon (a 4 × 4 stratified pattern).
const SAMPLES: usize = 16;

/// Samples per fan triangle of a polygon for its opaque fraction (a 32 × 32 stratified
/// pattern: a cut-out edge crossing a patch is placed to about 1/32 of its size).
const COVERAGE_SAMPLES: usize = 32;

impl FaceMapping {
    /// The barycentric weights of a point in the face (projected onto its plane), and the
    /// squared length of the face's doubled normal; `None` for a degenerate face.
    fn weights(&self) -> Option<(impl Fn(glam::DVec3) -> [f32; 3], f64)> {
        let [a, b, c] = self.corners.map(|p| p.as_dvec3());
        let (e1, e2) = (b - a, c - a);
        let n = e1.cross(e2);
        let nn = n.length_squared();
        if nn <= 0.0 || !nn.is_finite() {
            return None;
        }
        let weights = move |p: glam::DVec3| {
            let d = p - a;
            let u = d.cross(e2).dot(n) / nn;
            let v = e1.cross(d).dot(n) / nn;
            [1.0 - u - v, u, v].map(|w| w as f32)
        };
        Some((weights, nn))
    }

    /// The alpha at the point of barycentric weights `w`: `factor × COLOR_0 alpha × texture
    /// alpha` (see [`FaceAlpha`]), or `None` for an opaque face.
    fn alpha_at(&self, textures: &[Arc<Texture>], w: [f32; 3]) -> Option<(crate::AlphaMode, f32)> {
        let a = self.alpha.as_ref()?;
        let color = a.colors[0] * w[0] + a.colors[1] * w[1] + a.colors[2] * w[2];
        let texture = self
            .base
            .and_then(|t| textures.get(t as usize))
            .map_or(1.0, |t| {
                t.alpha(self.uv[0] * w[0] + self.uv[1] * w[1] + self.uv[2] * w[2])
            });
        Some((a.mode, a.factor * color * texture))
    }
}

impl SceneTextures {
    /// Bytes of the decoded texels (every mip level, and the alpha kept for alpha tests) and
    /// of the faces' mappings: what the textures hold in memory, allocator overhead not counted.
    pub fn heap_bytes(&self) -> usize {
        let texels: usize = self
            .textures
            .iter()
            .map(|t| {
                t.levels
                    .iter()
                    .map(|l| l.texels.len() * size_of::<Vec3>())
                    .sum::<usize>()
                    + t.alpha.as_ref().map_or(0, |a| a.len() * size_of::<f32>())
            })
            .sum();
        texels + self.faces.len() * size_of::<Option<FaceMapping>>()
    }

    /// The factors a polygon lying in face `source` applies to its material: `(albedo,
    /// emission)`, each the mean over the polygon's area of `COLOR_0 × baseColorTexture` and of
    /// `emissiveTexture` (1 where the face has none). `points` are the polygon's corners in scene
    /// units, convex and planar, fanned from the first. `None` when the face has no mapping.
    pub fn average(&self, source: u32, points: &[Vec3]) -> Option<(Vec3, Vec3)> {
        let m = self.faces.get(source as usize)?.as_ref()?;
        let (weights, nn) = m.weights()?;
        let uv_area = |uv: &[Vec2; 3]| (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]).abs() / 2.0;
        let uv_area_face = [uv_area(&m.uv), uv_area(&m.emissive_uv)];
        let face_area = (nn.sqrt() / 2.0) as f32;
        let (mut albedo, mut emission, mut total) = (Vec3::ZERO, Vec3::ZERO, 0.0f32);
        let p0 = points.first()?.as_dvec3();
        for w in points.get(1..)?.windows(2) {
            let (p1, p2) = (w[0].as_dvec3(), w[1].as_dvec3());
            let area = ((p1 - p0).cross(p2 - p0).length() / 2.0) as f32;
            if area.is_nan() || area <= 0.0 {
                continue;
            }
            // texels each sample covers, on the base level, of the larger texture
            let level = |t: Option<u32>, uv_area_face: f32| {
                let uv_area = uv_area_face * area / face_area;
                t.and_then(|t| self.textures.get(t as usize))
                    .map_or(0, |t| {
                        let (w, h) = t.size();
                        let per_sample = uv_area * w as f32 * h as f32 / SAMPLES as f32;
                        per_sample.max(1.0).sqrt().log2().floor() as usize
                    })
            };
            let base_level = level(m.base, uv_area_face[0]);
            let emissive_level = level(m.emissive, uv_area_face[1]);
            let (mut sa, mut se) = (Vec3::ZERO, Vec3::ZERO);
            for k in 0..SAMPLES {
                // stratified point of the unit square, warped uniformly onto the triangle
                let (i, j) = ((k % 4) as f64, (k / 4) as f64);
                let (s, t) = ((i + 0.5) / 4.0, (j + 0.5) / 4.0);
                let r = s.sqrt();
                let p = p0 * (1.0 - r) + p1 * (r * (1.0 - t)) + p2 * (r * t);
                let wts = weights(p);
                let at = |uv: &[Vec2; 3]| uv[0] * wts[0] + uv[1] * wts[1] + uv[2] * wts[2];
                let color = m.colors[0] * wts[0] + m.colors[1] * wts[1] + m.colors[2] * wts[2];
                let tex = |t: Option<u32>, uv: &[Vec2; 3], level: usize| {
                    t.and_then(|t| self.textures.get(t as usize))
                        .map_or(Vec3::ONE, |t| t.sample(at(uv), level))
                };
                sa += color * tex(m.base, &m.uv, base_level);
                se += tex(m.emissive, &m.emissive_uv, emissive_level);
            }
            albedo += sa / SAMPLES as f32 * area;
            emission += se / SAMPLES as f32 * area;
            total += area;
        }
        (total > 0.0).then(|| (albedo / total, emission / total))
    }

    /// Whether some face is alpha-tested ([`FaceMapping::alpha`]).
    pub fn has_alpha(&self) -> bool {
        self.faces.iter().flatten().any(|m| m.alpha.is_some())
    }

    /// Whether light passes face `source` at `point` (scene units, on the face): its
    /// [`AlphaMode`](crate::AlphaMode) applied to the alpha there, `u` a uniform number in
    /// `[0, 1)` for `BLEND`. `false` for an opaque face.
    pub fn passes(&self, source: u32, point: Vec3, u: f32) -> bool {
        let Some(m) = self.faces.get(source as usize).and_then(Option::as_ref) else {
            return false;
        };
        if m.alpha.is_none() {
            return false;
        }
        m.weights()
            .and_then(|(weights, _)| m.alpha_at(&self.textures, weights(point.as_dvec3())))
            .is_some_and(|(mode, alpha)| mode.passes(alpha, u))
    }

    /// The opaque fraction of a polygon lying in face `source` (see [`FaceAlpha`](crate::FaceAlpha)): under
    /// `MASK` the fraction of its area where alpha `>= alphaCutoff`, under `BLEND` its mean
    /// alpha, from a stratified pattern of 32 × 32 points per fan triangle. `points` as for
    /// [`SceneTextures::average`]. `None` for a face that is not alpha-tested.
    pub fn coverage(&self, source: u32, points: &[Vec3]) -> Option<f32> {
        let m = self.faces.get(source as usize)?.as_ref()?;
        m.alpha.as_ref()?;
        let (weights, _) = m.weights()?;
        let p0 = points.first()?.as_dvec3();
        let (mut opaque, mut total) = (0.0f64, 0.0f64);
        let n = COVERAGE_SAMPLES;
        for w in points.get(1..)?.windows(2) {
            let (p1, p2) = (w[0].as_dvec3(), w[1].as_dvec3());
            let area = (p1 - p0).cross(p2 - p0).length() / 2.0;
            if area.is_nan() || area <= 0.0 {
                continue;
            }
            let mut sum = 0.0f64;
            for k in 0..n * n {
                let (i, j) = ((k % n) as f64, (k / n) as f64);
                let (s, t) = ((i + 0.5) / n as f64, (j + 0.5) / n as f64);
                let r = s.sqrt();
                let p = p0 * (1.0 - r) + p1 * (r * (1.0 - t)) + p2 * (r * t);
                if let Some((mode, alpha)) = m.alpha_at(&self.textures, weights(p)) {
                    sum += f64::from(mode.opacity(alpha));
                }
            }
            opaque += sum / (n * n) as f64 * area;
            total += area;
        }
        (total > 0.0).then(|| (opaque / total) as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker(n: u32) -> Texture {
        let texels = (0..n * n)
            .map(|i| {
                let (x, y) = (i % n, i / n);
                Vec3::splat(((x + y) % 2) as f32)
            })
            .collect();
        Texture::new(n, n, texels, [Wrap::Repeat; 2]).unwrap()
    }

    #[test]
    fn mips_average_and_lookups_wrap() {
        let t = checker(8);
        assert_eq!(t.levels.len(), 4);
        assert_eq!(t.levels[3].texels, vec![Vec3::splat(0.5)]);
        // texel centres are exact; repeat wraps by the texture's size
        assert_eq!(t.sample(Vec2::new(0.5 / 8.0, 0.5 / 8.0), 0), Vec3::ZERO);
        assert_eq!(t.sample(Vec2::new(1.5 / 8.0, 0.5 / 8.0), 0), Vec3::ONE);
        assert_eq!(
            t.sample(Vec2::new(1.0 + 1.5 / 8.0, 0.5 / 8.0), 0),
            Vec3::ONE
        );
        assert_eq!(wrap(-1, 4, Wrap::Clamp), 0);
        assert_eq!(wrap(5, 4, Wrap::Mirror), 2);
        assert!(Texture::new(2, 2, vec![Vec3::ONE; 3], [Wrap::Repeat; 2]).is_none());
    }

    #[test]
    fn a_polygon_takes_the_mean_of_its_footprint() {
        // a unit square face (two triangles share the mapping of one: corners (0,0) (1,0) (0,1))
        let t = Arc::new(checker(64));
        let half = Texture::new(2, 1, vec![Vec3::ONE, Vec3::ZERO], [Wrap::Clamp; 2]).unwrap();
        let face = |base| FaceMapping {
            corners: [Vec3::ZERO, Vec3::X, Vec3::Y],
            uv: [Vec2::ZERO, Vec2::X, Vec2::Y],
            emissive_uv: [Vec2::ZERO, Vec2::X, Vec2::Y],
            colors: [Vec3::ONE, Vec3::new(0.0, 1.0, 1.0), Vec3::ONE],
            base: Some(base),
            emissive: None,
            alpha: None,
        };
        let scene = SceneTextures {
            textures: vec![t, Arc::new(half)],
            faces: vec![Some(face(0)), Some(face(1))],
        };
        let square = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
        // the fine checker averages to 1/2 however it is cut; red follows COLOR_0 (x -> 0),
        // whose mean over the square is 1/2 too
        let (albedo, emission) = scene.average(0, &square).unwrap();
        assert!(
            (albedo - Vec3::new(0.25, 0.5, 0.5)).abs().max_element() < 0.02,
            "{albedo}"
        );
        assert_eq!(emission, Vec3::ONE);
        // the left half of the two-texel image is white: the left half square sees it whole
        // (blended towards the other texel only within half a texel of the middle)
        let left = [
            Vec3::ZERO,
            Vec3::new(0.25, 0.0, 0.0),
            Vec3::new(0.25, 1.0, 0.0),
            Vec3::Y,
        ];
        let (albedo, _) = scene.average(1, &left).unwrap();
        assert!((albedo.y - 1.0).abs() < 1e-6, "{albedo}");
        assert!(scene.average(2, &square).is_none());
    }
}
