//! `cargo xtask path-trace` (a path-traced ground truth of a scene's picture, issue 15 item 4)
//! and `cargo xtask image-error` (a render's error against such a picture).

use anyhow::{Context, Result, bail};
use mcrad_lab::pathtrace::{PathTraceOptions, path_trace};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use std::path::{Path, PathBuf};
use std::time::Instant;

const PATH_TRACE_USAGE: &str = "usage: cargo xtask path-trace SCENE --camera SPEC --size WxH \
    --spp N [--seed S] --out PICTURE.exr [--error ERROR.exr]";

/// `path-trace SCENE --camera SPEC --size WxH --spp N [--seed S] --out R.exr [--error E.exr]`:
/// renders the scene's input faces (no meshing) by diffuse path tracing and writes the mean
/// radiance and, beside it (`R.error.exr` unless `--error` says), each pixel's standard error.
pub fn run_path_trace(args: &[String]) -> Result<()> {
    let mut scene = None;
    let (mut camera, mut size, mut spp, mut seed, mut out, mut error) =
        (None, None, None, 0u64, None, None);
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().context(PATH_TRACE_USAGE);
        match a.as_str() {
            "--camera" => camera = Some(mcrad_render::parse_camera(value()?)?),
            "--size" => {
                let v = value()?;
                let (w, h) = v
                    .split_once('x')
                    .context("--size takes WxH, e.g. 256x256")?;
                size = Some((w.parse::<u32>()?, h.parse::<u32>()?));
            }
            "--spp" => spp = Some(value()?.parse::<u32>()?),
            "--seed" => seed = value()?.parse()?,
            "--out" => out = Some(PathBuf::from(value()?)),
            "--error" => error = Some(PathBuf::from(value()?)),
            s if !s.starts_with("--") && scene.is_none() => scene = Some(PathBuf::from(s)),
            other => bail!("unknown argument '{other}'\n{PATH_TRACE_USAGE}"),
        }
    }
    let (Some(scene), Some(camera), Some((width, height)), Some(spp), Some(out)) =
        (scene, camera, size, spp, out)
    else {
        bail!(PATH_TRACE_USAGE);
    };
    let error = error.unwrap_or_else(|| out.with_extension("error.exr"));
    let loaded = mcrad_scene_io::load(&scene)
        .with_context(|| format!("could not load {}", scene.display()))?;
    let mesh = Mesh::build(&loaded.scene, Subdivision::None)?;
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())?;
    let camera = camera.translated(mesh.origin().as_dvec3());
    let options = PathTraceOptions {
        width,
        height,
        samples_per_pixel: spp,
        seed,
    };
    let start = Instant::now();
    let picture = path_trace(&mesh, &bvh, &camera, &options)?;
    let seconds = start.elapsed().as_secs_f64();
    mcrad_render::write_exr(&picture.radiance, &out)?;
    mcrad_render::write_exr(&picture.standard_error, &error)?;
    let noise = mcrad_lab::compare::relative_noise(
        &picture.radiance,
        &picture.standard_error,
        mcrad_lab::compare::EMITTER_FRACTION,
    )?;
    println!(
        "{}: {width}x{height}, {spp} paths per pixel, {:.3e} rays in {seconds:.1} s; its own noise \
         sqrt(sum se² / sum L²) = {:.3}% over the pixels the image error scores; wrote {} and {}",
        scene.display(),
        picture.rays as f64,
        100.0 * noise,
        out.display(),
        error.display()
    );
    Ok(())
}

const IMAGE_ERROR_USAGE: &str = "usage: cargo xtask image-error IMAGE.exr REFERENCE.exr \
    [DIFFERENCE.png] [--reference-error ERROR.exr]";

/// `image-error IMAGE.exr REFERENCE.exr [DIFFERENCE.png] [--reference-error E.exr]`.
pub fn run_image_error(args: &[String]) -> Result<()> {
    let (mut files, mut noise) = (Vec::new(), None);
    let mut it = args.iter();
    while let Some(a) = it.next() {
        if a == "--reference-error" {
            noise = Some(it.next().context(IMAGE_ERROR_USAGE)?.clone());
        } else {
            files.push(a.clone());
        }
    }
    let (image, reference, diff) = match files.as_slice() {
        [i, r] => (i, r, None),
        [i, r, d] => (i, r, Some(d)),
        _ => bail!(IMAGE_ERROR_USAGE),
    };
    let read = |p: &str| mcrad_render::read_exr(Path::new(p));
    let (image, reference) = (read(image)?, read(reference)?);
    let noise = noise.as_deref().map(read).transpose()?;
    let e = mcrad_lab::compare::image_error_against_noisy(
        &image,
        &reference,
        noise.as_ref(),
        mcrad_lab::compare::EMITTER_FRACTION,
    )?;
    if let Some(d) = diff {
        let d_img = mcrad_lab::compare::signed_difference_image(
            &image,
            &reference,
            mcrad_lab::compare::EMITTER_FRACTION,
            0.1,
        )?;
        mcrad_render::write_png(&d_img, Path::new(d), mcrad_render::Exposure::Stops(0.0))?;
    }
    println!(
        "img_rel {:.4} dark_third {:.4} pixels {}",
        e.relative, e.dark_third, e.pixels
    );
    Ok(())
}
