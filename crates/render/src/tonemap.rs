//! From linear radiance to 8-bit sRGB: exposure, the sRGB transfer function, clipping.

use glam::Vec3;

use crate::image::Image;

/// The percentile of lit-pixel luminance that [`Exposure::Auto`] maps to [`AUTO_TARGET`].
pub const AUTO_PERCENTILE: f32 = 0.99;

/// The linear value (before the sRGB transfer) [`Exposure::Auto`] maps that percentile to.
pub const AUTO_TARGET: f32 = 0.9;

/// How radiance (W/(m² sr)) becomes a display value in `[0, 1]` before the sRGB transfer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Exposure {
    /// Scale so that the 99th percentile ([`AUTO_PERCENTILE`], nearest rank) of the luminance
    /// `Y = 0.2126 R + 0.7152 G + 0.0722 B` (Rec. 709) over the *lit* pixels (`Y > 0`, finite)
    /// maps to 0.9 ([`AUTO_TARGET`]). So the brightest 1% (typically the light source) clip to
    /// white and the rest keeps its contrast. An image without lit pixels uses scale 1.
    Auto,
    /// Multiply radiance by `2^stops` (`Stops(0.0)`: radiance 1 W/(m² sr) is display white).
    Stops(f32),
}

impl Exposure {
    /// The factor (display units per W/(m² sr)) this exposure multiplies `image`'s radiance by;
    /// non-finite for `Stops` of a non-finite or huge number.
    pub fn scale(&self, image: &Image) -> f32 {
        match *self {
            Exposure::Stops(stops) => stops.exp2(),
            Exposure::Auto => {
                let mut lit: Vec<f32> = image
                    .pixels
                    .iter()
                    .map(|&p| luminance(p))
                    .filter(|y| y.is_finite() && *y > 0.0)
                    .collect();
                if lit.is_empty() {
                    return 1.0;
                }
                let rank =
                    ((AUTO_PERCENTILE * lit.len() as f32).ceil() as usize).clamp(1, lit.len());
                let (_, &mut y, _) = lit.select_nth_unstable_by(rank - 1, f32::total_cmp);
                AUTO_TARGET / y
            }
        }
    }
}

/// Rec. 709 / sRGB relative luminance of linear RGB.
pub fn luminance(rgb: Vec3) -> f32 {
    rgb.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// The sRGB transfer function (IEC 61966-2-1) of a linear value, clipped to `[0, 1]` first
/// (NaN counts as 0).
pub fn srgb_encode(linear: f32) -> f32 {
    let v = if linear.is_nan() {
        0.0
    } else {
        linear.clamp(0.0, 1.0)
    };
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// `image` as 8-bit sRGB, row-major, top row first, 3 bytes per pixel, after multiplying by
/// `scale` (display units per W/(m² sr)).
pub(crate) fn to_srgb8(image: &Image, scale: f32) -> Vec<u8> {
    image
        .pixels
        .iter()
        .flat_map(|&p| (p * scale).to_array())
        .map(|v| (srgb_encode(v) * 255.0).round() as u8)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_matches_known_values() {
        assert_eq!(srgb_encode(0.0), 0.0);
        assert!((srgb_encode(1.0) - 1.0).abs() < 1e-6);
        assert_eq!(srgb_encode(7.0), srgb_encode(1.0));
        assert_eq!(srgb_encode(-1.0), 0.0);
        assert_eq!(srgb_encode(f32::NAN), 0.0);
        assert!((srgb_encode(0.5) - 0.735_356_6).abs() < 1e-6);
        assert!((srgb_encode(0.002) - 0.025_84).abs() < 1e-6);
    }

    #[test]
    fn auto_maps_the_99th_percentile_to_0_9() {
        // 200 lit pixels of luminance 1..=200 (grey), plus black ones that do not count
        let mut pixels: Vec<Vec3> = (1..=200).map(|i| Vec3::splat(i as f32)).collect();
        pixels.extend([Vec3::ZERO; 50]);
        let image = Image {
            width: 250,
            height: 1,
            pixels,
        };
        // nearest rank: ceil(0.99 · 200) = 198
        let s = Exposure::Auto.scale(&image);
        assert!((s - 0.9 / 198.0).abs() < 1e-7 * s, "{s}");
        let dark = Image {
            width: 2,
            height: 1,
            pixels: vec![Vec3::ZERO; 2],
        };
        assert_eq!(Exposure::Auto.scale(&dark), 1.0);
        assert_eq!(Exposure::Stops(-2.0).scale(&dark), 0.25);
    }
}
