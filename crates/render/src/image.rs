//! The rendered image and its writers: EXR (linear radiance) and PNG (tone-mapped sRGB).

use std::path::{Path, PathBuf};

use glam::Vec3;

use crate::tonemap::{Exposure, to_srgb8};

/// A rendered image of radiance, W/(m² sr) per linear RGB channel, row-major, top row first:
/// pixel `(x, y)` is `pixels[y * width + x]`. Invariant: `pixels.len() == width * height`
/// (the writers check it).
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Radiance per pixel, W/(m² sr), linear RGB.
    pub pixels: Vec<Vec3>,
}

impl Image {
    /// The radiance (W/(m² sr)) at column `x`, row `y` (0 at the top), or `None` outside.
    pub fn get(&self, x: u32, y: u32) -> Option<Vec3> {
        if x >= self.width || y >= self.height {
            return None;
        }
        self.pixels
            .get(y as usize * self.width as usize + x as usize)
            .copied()
    }

    /// Checks the size invariant (`path` is named in the error).
    fn check(&self, path: &Path) -> Result<(), ImageError> {
        if self.width == 0
            || self.height == 0
            || self.pixels.len() as u64 != u64::from(self.width) * u64::from(self.height)
        {
            return Err(ImageError::SizeMismatch {
                path: path.to_path_buf(),
                width: self.width,
                height: self.height,
                pixels: self.pixels.len(),
            });
        }
        Ok(())
    }
}

/// Why an image could not be written.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The image is empty or its pixel count does not match its size (a caller's bug).
    #[error(
        "cannot write {}: a {width}x{height} image needs {} pixels, it has {pixels}",
        path.display(),
        u64::from(*width) * u64::from(*height)
    )]
    SizeMismatch {
        /// The output file.
        path: PathBuf,
        /// Width, pixels.
        width: u32,
        /// Height, pixels.
        height: u32,
        /// Number of pixels held.
        pixels: usize,
    },
    /// The exposure scale is not a positive finite number.
    #[error("cannot write {}: exposure {exposure:?} gives scale {scale}", path.display())]
    BadExposure {
        /// The output file.
        path: PathBuf,
        /// The exposure asked for.
        exposure: Exposure,
        /// The scale it gives (display units per W/(m² sr)).
        scale: f32,
    },
    /// Encoding or writing the EXR file failed.
    #[error("could not write EXR {}: {reason}", path.display())]
    Exr {
        /// The output file.
        path: PathBuf,
        /// The underlying error.
        reason: exr::error::Error,
    },
    /// Encoding or writing the PNG file failed.
    #[error("could not write PNG {}: {reason}", path.display())]
    Png {
        /// The output file.
        path: PathBuf,
        /// The underlying error.
        reason: ::image::ImageError,
    },
}

/// Writes `image` to `path` as OpenEXR: linear radiance (W/(m² sr)) as 32-bit float R, G, B
/// channels, ZIP compression in blocks of 16 scan lines (lossless).
pub fn write_exr(image: &Image, path: &Path) -> Result<(), ImageError> {
    use exr::prelude::{Encoding, Image as ExrImage, SpecificChannels, WritableImage};
    image.check(path)?;
    let width = image.width as usize;
    let channels = SpecificChannels::rgb(|p: exr::math::Vec2<usize>| {
        let v = image.pixels[p.y() * width + p.x()];
        (v.x, v.y, v.z)
    });
    ExrImage::from_encoded_channels(
        (width, image.height as usize),
        Encoding::SMALL_LOSSLESS,
        channels,
    )
    .write()
    .to_file(path)
    .map_err(|source| ImageError::Exr {
        path: path.to_path_buf(),
        reason: source,
    })
}

/// Writes `image` to `path` as an 8-bit sRGB PNG: radiance times the [`Exposure`] scale, the
/// sRGB transfer function, clipped to `[0, 1]`, rounded to 0..=255.
pub fn write_png(image: &Image, path: &Path, exposure: Exposure) -> Result<(), ImageError> {
    image.check(path)?;
    let scale = exposure.scale(image);
    if !(scale.is_finite() && scale > 0.0) {
        return Err(ImageError::BadExposure {
            path: path.to_path_buf(),
            exposure,
            scale,
        });
    }
    ::image::save_buffer_with_format(
        path,
        &to_srgb8(image, scale),
        image.width,
        image.height,
        ::image::ExtendedColorType::Rgb8,
        ::image::ImageFormat::Png,
    )
    .map_err(|source| ImageError::Png {
        path: path.to_path_buf(),
        reason: source,
    })
}

/// Reads an OpenEXR file's RGB channels as linear radiance (the inverse of
/// [`write_exr`]).
pub fn read_exr(path: &Path) -> Result<Image, ImageReadError> {
    let fail = |reason: String| ImageReadError {
        path: path.to_path_buf(),
        reason,
    };
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |size, _| (size.width(), vec![Vec3::ZERO; size.width() * size.height()]),
        |(width, pixels): &mut (usize, Vec<Vec3>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            pixels[pos.y() * *width + pos.x()] = Vec3::new(r, g, b);
        },
    )
    .map_err(|e| fail(e.to_string()))?;
    let size = image.layer_data.size;
    let (_, pixels) = image.layer_data.channel_data.pixels;
    Ok(Image {
        width: u32::try_from(size.width()).map_err(|_| fail("too wide".into()))?,
        height: u32::try_from(size.height()).map_err(|_| fail("too tall".into()))?,
        pixels,
    })
}

/// Why an image could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("could not read {}: {reason}", path.display())]
pub struct ImageReadError {
    /// The file.
    pub path: PathBuf,
    /// What went wrong.
    pub reason: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gradient(width: u32, height: u32) -> Image {
        let pixels = (0..height)
            .flat_map(|y| {
                (0..width).map(move |x| {
                    Vec3::new(x as f32 * 0.37, y as f32 / 3.0, 1e-7 + x as f32 * y as f32)
                })
            })
            .collect();
        Image {
            width,
            height,
            pixels,
        }
    }

    #[test]
    fn exr_round_trip_is_exact() {
        use exr::prelude::{ReadChannels, ReadLayers, read};
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.exr");
        let image = gradient(37, 19);
        write_exr(&image, &path).unwrap();
        let back = read()
            .no_deep_data()
            .largest_resolution_level()
            .rgb_channels(
                |size, _| vec![Vec3::ZERO; size.width() * size.height()],
                |pixels: &mut Vec<Vec3>, p, (r, g, b): (f32, f32, f32)| {
                    pixels[p.y() * 37 + p.x()] = Vec3::new(r, g, b);
                },
            )
            .first_valid_layer()
            .all_attributes()
            .from_file(&path)
            .unwrap();
        let layer = &back.layer_data;
        assert_eq!(layer.size.width(), 37);
        assert_eq!(layer.size.height(), 19);
        assert_eq!(layer.channel_data.pixels, image.pixels);
        let (r, g, b) = &layer.channel_data.channels;
        for c in [r, g, b] {
            assert_eq!(c.sample_type, exr::meta::attribute::SampleType::F32);
        }
        assert_eq!(
            layer.encoding.compression,
            exr::compression::Compression::ZIP16
        );
    }

    #[test]
    fn png_has_the_size_and_srgb_values_of_known_radiance() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.png");
        // radiance 0.5, 0.2, 2 (clips), 0, 1, the linear-segment end, a bad pixel, 0.25; at 0 stops
        let image = Image {
            width: 3,
            height: 2,
            pixels: vec![
                Vec3::new(0.5, 0.2, 2.0),
                Vec3::ZERO,
                Vec3::ONE,
                Vec3::splat(0.0031308),
                Vec3::new(-1.0, f32::NAN, f32::INFINITY),
                Vec3::splat(0.25),
            ],
        };
        write_png(&image, &path, Exposure::Stops(0.0)).unwrap();
        let png = ::image::open(&path).unwrap().to_rgb8();
        assert_eq!(png.dimensions(), (3, 2));
        assert_eq!(png.get_pixel(0, 0).0, [188, 124, 255]);
        assert_eq!(png.get_pixel(1, 0).0, [0, 0, 0]);
        assert_eq!(png.get_pixel(2, 0).0, [255, 255, 255]);
        assert_eq!(png.get_pixel(0, 1).0, [10, 10, 10]);
        assert_eq!(png.get_pixel(1, 1).0, [0, 0, 255]);
        assert_eq!(png.get_pixel(2, 1).0, [137, 137, 137]);
        // one stop up doubles radiance: 0.25 shows as 0.5 did
        write_png(&image, &path, Exposure::Stops(1.0)).unwrap();
        let png = ::image::open(&path).unwrap().to_rgb8();
        assert_eq!(png.get_pixel(2, 1).0, [188, 188, 188]);
    }

    #[test]
    fn bad_input_is_a_typed_error_naming_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.png");
        let mut image = gradient(4, 4);
        let err = write_png(&image, &path, Exposure::Stops(f32::NAN)).unwrap_err();
        assert!(matches!(err, ImageError::BadExposure { .. }), "{err}");
        assert!(err.to_string().contains("x.png"), "{err}");
        image.pixels.pop();
        let err = write_exr(&image, &dir.path().join("x.exr")).unwrap_err();
        assert!(
            err.to_string().contains("needs 16 pixels, it has 15"),
            "{err}"
        );
        let err = write_png(
            &gradient(2, 2),
            &dir.path().join("no/such/dir/x.png"),
            Exposure::Auto,
        )
        .unwrap_err();
        assert!(matches!(err, ImageError::Png { .. }), "{err}");
        assert!(err.to_string().contains("no/such/dir/x.png"), "{err}");
        let err = write_exr(&gradient(2, 2), &dir.path().join("no/such/dir/x.exr")).unwrap_err();
        assert!(matches!(err, ImageError::Exr { .. }), "{err}");
    }

    #[test]
    fn exr_reads_back_what_was_written() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.exr");
        let a = gradient(7, 5);
        write_exr(&a, &path).unwrap();
        assert_eq!(read_exr(&path).unwrap(), a);
        let err = read_exr(&dir.path().join("missing.exr")).unwrap_err();
        assert!(err.to_string().contains("missing.exr"), "{err}");
    }
}
