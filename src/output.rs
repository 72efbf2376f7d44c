//! What `mcrad solve` writes besides the patch CSV and the statistics: renders and glTF.

use crate::cli::{ShadingArg, Solve};
use anyhow::{Context, Result, bail};
use glam::DVec3;
use indicatif::ProgressBar;
use mcrad_export::{GltfOptions, write_glb};
use mcrad_meshing::Mesh;
use mcrad_raycast::Bvh;
use mcrad_render::{Camera, RenderSettings, Shading, render, write_exr, write_png};
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

/// Image formats `--image` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ImageFormat {
    Png,
    Exr,
}

fn image_format(path: &Path) -> Result<ImageFormat> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("png") => Ok(ImageFormat::Png),
        Some("exr") => Ok(ImageFormat::Exr),
        _ => bail!(
            "--image {}: the file name must end in .png or .exr",
            path.display()
        ),
    }
}

/// Checks what can be checked before the (possibly long) solve: output file types.
pub fn check(args: &Solve) -> Result<()> {
    if let Some(path) = &args.image {
        image_format(path)?;
    }
    if let Some(path) = &args.gltf {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        if ext.as_deref() != Some("glb") {
            bail!(
                "--gltf {}: the file name must end in .glb (binary glTF)",
                path.display()
            );
        }
    }
    Ok(())
}

/// The camera for renders: `--camera`, else the scene file's, else framed automatically.
fn camera(
    args: &Solve,
    from_file: Option<mcrad_scene_io::Camera>,
    mesh: &Mesh,
    bvh: &Bvh,
) -> Result<Camera> {
    // `--camera` and the file's camera are in world coordinates, the mesh in its local frame
    let origin = mesh.origin().as_dvec3();
    let camera = match (args.camera, from_file) {
        (Some(c), _) => return Ok(c.translated(origin)),
        (None, Some(c)) => Camera::from_scene(&c).map(|c| c.translated(origin)),
        (None, None) => Camera::frame_scene(mesh, bvh),
    };
    camera.context("--camera")
}

/// Writes `--image` and `--gltf` for the per-patch radiosity `radiosity` (W/m²).
pub fn write(
    args: &Solve,
    mesh: &Mesh,
    bvh: &Bvh,
    radiosity: &[DVec3],
    file_camera: Option<mcrad_scene_io::Camera>,
    bar: &ProgressBar,
) -> Result<()> {
    let needs_corners =
        args.gltf.is_some() || (args.image.is_some() && args.shading == ShadingArg::Smooth);
    let corners = needs_corners.then(|| mesh.seamless_corner_radiosity(radiosity, args.crease));
    if let Some(path) = &args.image {
        let format = image_format(path)?;
        let camera = camera(args, file_camera, mesh, bvh)?;
        let shading = match (&corners, args.shading) {
            (Some(c), ShadingArg::Smooth) => Shading::Smooth(c),
            _ => Shading::Flat(radiosity),
        };
        let settings = RenderSettings {
            width: args.size.0,
            height: args.size.1,
            samples_per_pixel: args.spp,
        };
        bar.reset();
        bar.set_length(u64::from(settings.height));
        bar.set_message("rendering rows");
        let done = AtomicU64::new(0);
        let image = render(mesh, bvh, &camera, shading, &settings, &|rows| {
            let rows = done
                .fetch_max(rows as u64, Ordering::Relaxed)
                .max(rows as u64);
            bar.set_position(rows);
        })?;
        match format {
            ImageFormat::Png => write_png(&image, path, args.exposure)?,
            ImageFormat::Exr => write_exr(&image, path)?,
        }
    }
    if let (Some(path), Some(corners)) = (&args.gltf, &corners) {
        let file =
            File::create(path).with_context(|| format!("could not create {}", path.display()))?;
        write_glb(BufWriter::new(file), mesh, corners, &GltfOptions::default())
            .with_context(|| format!("could not write {}", path.display()))?;
    }
    Ok(())
}
