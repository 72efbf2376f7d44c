//! Pictures of a radiosity solution: a pinhole [`Camera`] (given, or chosen by
//! [`Camera::frame_scene`]), a parallel ray-cast [`render`] of per-patch or per-corner
//! radiosity into an [`Image`] of radiance, and its writers [`write_exr`] (linear radiance) and
//! [`write_png`] (an [`Exposure`], the sRGB transfer function, 8 bits).
//!
//! Radiosity renders without lighting computations: a diffuse surface of radiosity `B`
//! (W/m²) has radiance `L = B / π` (W/(m² sr)) in every direction, so a pixel averages `B / π`
//! of the front faces its sample rays hit first. A back face is black (patches reflect and
//! emit on their front only); a miss sees the sky's radiance along the ray
//! ([`RenderSettings::sky`]), black without a sky. Lights without a surface can be drawn per
//! sample with shadow rays, and a final gather ([`RenderSettings::gather_rays`]) shows instead
//! the light gathered at each sample's own point, the solution read one bounce away.
//!
//! The render is deterministic: each pixel depends only on its own samples, whose positions
//! are a hash of (pixel, sample), and rows are written in place, so it is the same on any
//! number of threads.
//!
//! ```
//! use glam::{DVec3, Vec3};
//! use mcrad_render::{Camera, RenderSettings, Shading, render};
//! # use mcrad_meshing::{Mesh, Subdivision};
//! # use mcrad_raycast::Bvh;
//! # fn build(dir: &std::path::Path) -> Mesh {
//! #     std::fs::write(dir.join("q.mtl"), "newmtl lamp\nKd 0.5 0.5 0.5\nKe 1 1 1\n").unwrap();
//! #     let obj = "mtllib q.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl lamp\nf 1 2 3 4\n";
//! #     std::fs::write(dir.join("q.obj"), obj).unwrap();
//! #     let scene = mcrad_scene_io::load(&dir.join("q.obj")).unwrap().scene;
//! #     Mesh::build(&scene, Subdivision::None).unwrap()
//! # }
//! # let dir = tempfile::tempdir()?;
//! let mesh: Mesh = build(dir.path()); // one unit square in the xy plane, facing +z
//! let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())?;
//! let camera = Camera::look_at(Vec3::new(0.5, 0.5, 2.0), Vec3::new(0.5, 0.5, 0.0), Vec3::Y, 20.0)?;
//! let b = [DVec3::splat(std::f64::consts::PI)]; // B = π W/m², so L = 1 W/(m² sr)
//! let settings = RenderSettings { width: 8, height: 8, samples_per_pixel: 4, sky: None, lights: vec![], sky_rays: 0, gather_rays: 0 };
//! let image = render(&mesh, &bvh, &camera, Shading::Flat(&b), &settings, &|_rows| {})?;
//! assert!((image.get(4, 4).unwrap() - Vec3::ONE).length() < 1e-6);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod camera;
mod camera_spec;
mod frame;
mod gather;
mod image;
mod jitter;
mod shade;
mod sky;
mod tonemap;

#[cfg(test)]
mod tests;

use std::sync::atomic::{AtomicUsize, Ordering};

use glam::{DVec3, Vec2, Vec3};
use mcrad_meshing::Mesh;
use mcrad_random::Stream;
use mcrad_raycast::RayCaster;
use rayon::prelude::*;

pub use self::camera::{Camera, CameraError};
pub use self::camera_spec::{CameraSpecError, parse_camera};
pub use self::frame::{FRAME_FOV_Y_DEGREES, INSIDE_FOV_Y_DEGREES};
pub use self::image::{Image, ImageError, ImageReadError, read_exr, write_exr, write_png};
pub use self::shade::{Shading, interpolate};
pub use self::sky::sky_irradiance_sample;
pub use self::tonemap::{AUTO_PERCENTILE, AUTO_TARGET, Exposure, luminance, srgb_encode};

/// The pass number of the per-pixel direct light's streams.
const DIRECT_PASS: u64 = 0x5245_4e44_4449_5200;

/// The largest image side [`render`] accepts, pixels.
pub const MAX_SIDE: u32 = 16384;

/// How big a picture to render, how many rays per pixel, and what a ray that leaves the
/// scene sees.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderSettings {
    /// Width, pixels, `1..=MAX_SIDE`.
    pub width: u32,
    /// Height, pixels, `1..=MAX_SIDE`.
    pub height: u32,
    /// Rays per pixel, `>= 1`. One goes through the pixel centre; a square number `m²` is
    /// stratified on an `m × m` grid (jittered within each cell); other counts are jittered
    /// over the whole pixel.
    pub samples_per_pixel: u32,
    /// The sky a ray that leaves the scene sees: its radiance (W/(m² sr)) along the ray's
    /// direction; `None`: black.
    pub sky: Option<mcrad_scene_io::Sky>,
    /// Lights without a surface (point, spot, sun; in the scene's frame, as loaded) whose
    /// direct light is drawn per sample: at each front hit `x` of a patch of reflectance
    /// `rho` and normal `n`, one shadow ray per light ([`Light::arrival`](mcrad_scene_io::Light::arrival),
    /// a sun's direction drawn in its disc) adds radiance `rho E_l(x) max(0, n · w_l) V / π`
    /// (W/(m² sr)) to the shading's. The shading must then hold the radiosity without that
    /// direct light (`B - rho H_d` per patch, W/m²), or it is counted twice (with a final
    /// gather, [`gather_rays`](Self::gather_rays), the reflected part `B - E` instead). Empty (the
    /// default): the shading alone. Shadow rays pass alpha cut-outs as the caster's any-hit
    /// filter says; their random numbers come from a stream keyed by the pixel.
    pub lights: Vec<mcrad_scene_io::Light>,
    /// Rays towards [`sky`](Self::sky) per sample for its direct light, drawn per sample like
    /// the lights': at each front hit `x` of a patch of reflectance `rho`, the mean of
    /// [`sky_irradiance_sample`] over the rays adds radiance `rho H_sky(x) / π` (W/(m² sr)).
    /// The pixel's `samples_per_pixel × sky_rays` ray directions are stratified over the
    /// square together (an `m × m` grid when that is a square number), from a stream keyed by
    /// the pixel of its own. The shading must then hold the radiosity without the sky's direct
    /// light too. 0 (the default, and without a sky): the shading alone.
    pub sky_rays: u32,
    /// Rays per sample of the final gather: when above 0, a front hit `x` of a patch of
    /// emission `E` and reflectance `rho` shows `E / π + rho H(x) / π` (W/(m² sr)), `H(x)`
    /// (W/m²) the irradiance at `x` itself: the [`lights`](Self::lights)' by their shadow rays,
    /// the emitting patches' by `gather_rays` points drawn on them by power with a shadow ray
    /// each, and the rest by `gather_rays` cosine-distributed rays that read the shading where
    /// they land and the [`sky`](Self::sky) where they leave the scene. The shading must then
    /// hold the solution's reflected part, `B - E` per patch or corner (W/m²), and is never
    /// shown directly, only one bounce away: the mesh's discretization is blurred over the
    /// hemisphere instead of drawn at its edges. The pixel's `samples_per_pixel × gather_rays`
    /// directions are stratified together, from a stream of the pixel's own;
    /// [`sky_rays`](Self::sky_rays) is not used (a sky map is drawn by its luminance too, one
    /// more ray a gather ray, by the balance heuristic). 0 (the default): the shading is shown
    /// where a ray lands.
    pub gather_rays: u32,
}

impl Default for RenderSettings {
    /// 512 × 512 pixels, 16 samples per pixel (stratified 4 × 4): `mcrad solve --image`'s.
    fn default() -> Self {
        RenderSettings {
            width: 512,
            height: 512,
            samples_per_pixel: 16,
            sky: None,
            lights: Vec::new(),
            sky_rays: 0,
            gather_rays: 0,
        }
    }
}

/// Why a render could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RenderError {
    /// The image size is zero or above [`MAX_SIDE`].
    #[error("image size must be 1 to {MAX_SIDE} pixels a side, got {width}x{height}")]
    BadSize {
        /// Width asked for, pixels.
        width: u32,
        /// Height asked for, pixels.
        height: u32,
    },
    /// No samples per pixel.
    #[error("samples per pixel must be at least 1")]
    NoSamples,
    /// The radiosity array does not match the mesh.
    #[error("shading needs one radiosity value per {per} ({expected}), got {got}")]
    ShadingLength {
        /// `"patch"` ([`Shading::Flat`]) or `"corner"` ([`Shading::Smooth`]).
        per: &'static str,
        /// Number of patches or corners of the mesh.
        expected: usize,
        /// Length of the array given.
        got: usize,
    },
    /// A radiosity value is NaN or infinite.
    #[error("radiosity {index} is not finite: {value} W/m^2")]
    NonFiniteRadiosity {
        /// Index in the radiosity array.
        index: usize,
        /// The value (W/m²).
        value: DVec3,
    },
}

/// Renders `mesh` as seen by `camera`: for each pixel, the mean radiance `B / π`
/// (W/(m² sr)) of what its sample rays hit first (see [`RenderSettings`] for the samples, the
/// lights drawn per sample and the final gather, the module docs for misses and back faces).
/// `caster` holds the mesh's triangles tagged with their patch indices
/// (`Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())`).
///
/// Rows run in parallel on the current rayon pool; `progress` is called (from worker threads)
/// with the number of rows finished so far after each row (1 to `height`, each once; calls
/// from different threads may arrive slightly out of order, so show the largest). The result
/// does not depend on the number of threads.
pub fn render<C: RayCaster + ?Sized>(
    mesh: &Mesh,
    caster: &C,
    camera: &Camera,
    shading: Shading<'_>,
    settings: &RenderSettings,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Image, RenderError> {
    render_with_error(mesh, caster, camera, shading, settings, progress).map(|(image, _)| image)
}

/// [`render`], and each pixel's standard error: per channel `sqrt(s² / n)` (W/(m² sr)), `s²`
/// the sample variance of the radiance over the pixel's `n` samples. It counts what varies
/// from sample to sample (where the samples land in the pixel, the lights' shadow rays, a
/// final gather's rays), not the shading's own error. The samples' rays are stratified
/// together, so it overstates the error of their mean rather than understates it. Infinite
/// with one sample a pixel (no spread to tell).
pub fn render_with_error<C: RayCaster + ?Sized>(
    mesh: &Mesh,
    caster: &C,
    camera: &Camera,
    shading: Shading<'_>,
    settings: &RenderSettings,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<(Image, Image), RenderError> {
    let (width, height, spp) = (settings.width, settings.height, settings.samples_per_pixel);
    if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
        return Err(RenderError::BadSize { width, height });
    }
    if spp == 0 {
        return Err(RenderError::NoSamples);
    }
    let shader = shade::Shader::new(mesh, shading)?;
    let direct = shade::Direct::new(mesh, &settings.lights);
    // the sky's direct light per sample: `sky_rays` rays each
    let gather_rays = settings.gather_rays as usize;
    let sky_direct = settings
        .sky
        .as_ref()
        .filter(|s| gather_rays == 0 && settings.sky_rays > 0 && !s.is_dark());
    let sky_rays = settings.sky_rays as usize;
    let far = mesh.escape_distance();
    let emitters = if gather_rays > 0 {
        gather::Emitters::new(mesh)
    } else {
        gather::Emitters::empty()
    };
    // per pixel: (mean radiance, its standard error)
    let mut pixels = vec![(Vec3::ZERO, Vec3::ZERO); width as usize * height as usize];
    let rows_done = AtomicUsize::new(0);
    pixels
        .par_chunks_mut(width as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let y = y as u32;
            for (x, out) in (0u32..).zip(row.iter_mut()) {
                let (mut sum, mut squares) = (DVec3::ZERO, DVec3::ZERO);
                let pixel_index = u64::from(y) * u64::from(width) + u64::from(x);
                let mut rng = Stream::new(0, DIRECT_PASS, pixel_index, 0);
                // the pixel's directions (and, for a map, its map draws), stratified: towards
                // the sky, and of the gather
                let strata = |sub: u64, rays: usize, sky: Option<&mcrad_scene_io::Sky>| {
                    let mut rng = Stream::new(0, DIRECT_PASS, pixel_index, sub);
                    let n = spp as usize * rays;
                    let u = sky::stratified(n, &mut rng);
                    let v = match sky {
                        Some(mcrad_scene_io::Sky::Map(_)) => sky::stratified(n, &mut rng),
                        _ => Vec::new(),
                    };
                    (u, v)
                };
                let strata_sky = sky_direct.map(|sky| strata(1, sky_rays, Some(sky)));
                let (gather_u, gather_v) = if gather_rays > 0 {
                    strata(2, gather_rays, settings.sky.as_ref())
                } else {
                    (Vec::new(), Vec::new())
                };
                for s in 0..spp {
                    let offset = jitter::sample_offset(x, y, s, spp);
                    let pixel = Vec2::new(x as f32, y as f32) + offset;
                    let ray = camera.ray(pixel, width, height);
                    let l = match (caster.closest_hit(&ray), &settings.sky) {
                        (None, Some(sky)) => sky.radiance(ray.dir.as_dvec3().normalize()),
                        (hit, _) if gather_rays > 0 => {
                            let range = s as usize * gather_rays..(s as usize + 1) * gather_rays;
                            shade::emitted_radiance(mesh, hit)
                                + gather::gathered_radiance(
                                    mesh,
                                    caster,
                                    &shader,
                                    settings.sky.as_ref(),
                                    far,
                                    hit,
                                    (&gather_u, &gather_v),
                                    range,
                                )
                                + emitters.radiance(mesh, caster, hit, gather_rays, &mut rng)
                                + direct.radiance(mesh, caster, hit, &mut rng)
                        }
                        (hit, _) => {
                            let mut l = shader.radiance(mesh, hit).as_dvec3()
                                + direct.radiance(mesh, caster, hit, &mut rng);
                            if let (Some(sky), Some((u, v))) = (sky_direct, &strata_sky) {
                                let range = s as usize * sky_rays..(s as usize + 1) * sky_rays;
                                l += shade::sky_radiance(mesh, caster, sky, far, hit, u, v, range);
                            }
                            l
                        }
                    };
                    sum += l;
                    squares += l * l;
                }
                let n = f64::from(spp);
                let mean = sum / n;
                let error = if spp > 1 {
                    ((squares - mean * sum).max(DVec3::ZERO) / (n - 1.0) / n).sqrt()
                } else {
                    DVec3::INFINITY
                };
                *out = (mean.as_vec3(), error.as_vec3());
            }
            progress(rows_done.fetch_add(1, Ordering::Relaxed) + 1);
        });
    let (pixels, errors) = pixels.into_iter().unzip();
    let image = |pixels| Image {
        width,
        height,
        pixels,
    };
    Ok((image(pixels), image(errors)))
}
