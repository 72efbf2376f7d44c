//! Cut-out and translucent surfaces (glTF `alphaMode` `MASK` and `BLEND`): where light passes a
//! face (the rules are [`FaceAlpha`]'s).

/// How alpha decides where light passes (glTF `alphaMode`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AlphaMode {
    /// `MASK`: light passes where alpha `< cutoff` (glTF's `alphaCutoff`, default 0.5).
    Mask {
        /// The cut-off, unitless.
        cutoff: f32,
    },
    /// `BLEND`: light passes with probability `1 - alpha`.
    Blend,
}

/// The alpha of one face: at a point `factor × COLOR_0 alpha × texture alpha`, tested by `mode`.
///
/// The alpha of a point of a face is `a = baseColorFactor.a × COLOR_0.a × baseColorTexture.a`
/// (each 1 where absent; the texture's alpha is linear, sampled bilinearly on its full-size
/// level). Under `MASK` light passes where `a < alphaCutoff` and meets an opaque surface
/// elsewhere; under `BLEND` a ray passes with probability `1 - a` (decided by the caller's
/// uniform number, so that a seeded solve gives the same answer on any thread count).
///
/// The rule for radiosity: a patch of such a face is the *opaque part* of its polygon. Its area
/// ([`SceneTextures::coverage`](crate::SceneTextures::coverage)) is the polygon's area times the
/// opaque fraction (`MASK`: the fraction where `a >= alphaCutoff`; `BLEND`: the mean of `a`), so
/// its radiosity `B` is the exitance of the opaque surface and `B × area` its power: light that
/// passes a cut-out texel is neither received nor reflected there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaceAlpha {
    /// `MASK` or `BLEND`.
    pub mode: AlphaMode,
    /// `baseColorFactor`'s alpha, in `[0, 1]`.
    pub factor: f32,
    /// `COLOR_0`'s alpha at the face's corners (1 without), in the order of
    /// [`FaceMapping::corners`](crate::FaceMapping::corners).
    pub colors: [f32; 3],
}

impl AlphaMode {
    /// Whether light passes a point of alpha `alpha`; `u` is a uniform number in `[0, 1)`
    /// (used by `BLEND` only: passes when `u >= alpha`, so with probability `1 - alpha`).
    pub fn passes(self, alpha: f32, u: f32) -> bool {
        match self {
            AlphaMode::Mask { cutoff } => alpha < cutoff,
            AlphaMode::Blend => u >= alpha,
        }
    }

    /// The opaque fraction of a point of alpha `alpha`: 0 or 1 under `MASK`, `alpha` under
    /// `BLEND` (clamped to `[0, 1]`).
    pub fn opacity(self, alpha: f32) -> f32 {
        match self {
            AlphaMode::Mask { cutoff } => f32::from(u8::from(alpha >= cutoff)),
            AlphaMode::Blend => alpha.clamp(0.0, 1.0),
        }
    }
}
