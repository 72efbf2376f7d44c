//! `cargo xtask path-trace` (a path-traced ground truth of a scene's picture, issue 15 item 4)
//! and `cargo xtask image-error` (a render's error against such a picture).

use anyhow::{Context, Result};
use mcrad_lab::pathtrace::{PathTraceOptions, path_trace};
use mcrad_meshing::{Mesh, Subdivision};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The arguments of `cargo xtask path-trace`.
#[derive(Debug, Clone, clap::Args)]
pub struct PathTraceArgs {
    /// The scene file
    pub scene: PathBuf,
    /// The camera, as `mcrad render --camera` takes it (eye=x,y,z,look=x,y,z,fov=deg)
    #[arg(long, value_name = "SPEC", value_parser = |s: &str| mcrad_render::parse_camera(s).map_err(|e| e.to_string()))]
    pub camera: mcrad_render::Camera,
    /// The picture's size in pixels
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Paths per pixel
    #[arg(long, value_name = "N")]
    pub spp: u32,
    /// The seed of the paths
    #[arg(long, value_name = "S", default_value_t = 0)]
    pub seed: u64,
    /// The picture (mean radiance)
    #[arg(long, value_name = "R.exr")]
    pub out: PathBuf,
    /// Each pixel's standard error [default: R.error.exr beside the picture]
    #[arg(long, value_name = "E.exr")]
    pub error: Option<PathBuf>,
    /// The sun, as `mcrad solve --sun` takes it (added to the scene's own lights)
    #[arg(long, value_name = "X,Y,Z,E[,DIAM]", allow_negative_numbers = true)]
    pub sun: Option<mcrad_scene_io::Sun>,
    /// A uniform sky, as `mcrad solve --sky` takes it (R,G,B radiance in W/(m² sr))
    #[arg(long, value_name = "R,G,B")]
    pub sky: Option<mcrad_scene_io::Sky>,
}

/// `WxH`, e.g. `256x256`.
fn parse_size(s: &str) -> Result<(u32, u32)> {
    let (w, h) = s.split_once('x').context("takes WxH, e.g. 256x256")?;
    Ok((w.parse()?, h.parse()?))
}

/// `path-trace SCENE --camera SPEC --size WxH --spp N [--seed S] --out R.exr [--error E.exr]`:
/// renders the scene's input faces (no meshing) by diffuse path tracing and writes the mean
/// radiance and, beside it (`R.error.exr` unless `--error` says), each pixel's standard error.
pub fn run_path_trace(args: &PathTraceArgs) -> Result<()> {
    let PathTraceArgs {
        scene,
        camera,
        size: (width, height),
        spp,
        seed,
        out,
        error,
        sun,
        sky,
    } = args.clone();
    let error = error.unwrap_or_else(|| out.with_extension("error.exr"));
    let options = mcrad_scene_io::LoadOptions {
        lights: sun.into_iter().map(mcrad_scene_io::Light::Sun).collect(),
        sky,
        ..Default::default()
    };
    let loaded = mcrad_scene_io::load_with(&scene, &options)
        .with_context(|| format!("could not load {}", scene.display()))?;
    let mesh = Mesh::build(&loaded.scene, Subdivision::None)?;
    let bvh = mesh.caster()?;
    let camera = camera.translated(mesh.origin().as_dvec3());
    let options = PathTraceOptions {
        width,
        height,
        samples_per_pixel: spp,
        seed,
        sky: loaded.scene.sky().cloned(),
    };
    let start = Instant::now();
    let lights: Vec<_> = loaded
        .scene
        .lights()
        .iter()
        .map(|l| l.translated(-mesh.origin()))
        .collect();
    let picture = path_trace(&mesh, &lights, &bvh, &camera, &options)?;
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

/// The arguments of `cargo xtask image-error`.
#[derive(Debug, Clone, clap::Args)]
pub struct ImageErrorArgs {
    /// The picture judged
    #[arg(value_name = "IMAGE.exr")]
    pub image: String,
    /// The ground truth
    #[arg(value_name = "REFERENCE.exr")]
    pub reference: String,
    /// Writes the signed difference here
    #[arg(value_name = "DIFFERENCE.png")]
    pub difference: Option<String>,
    /// The reference's standard error per pixel (its noise is subtracted)
    #[arg(long, value_name = "ERROR.exr")]
    pub reference_error: Option<String>,
    /// Pixels at least this fraction of the reference's brightest luminance (and their
    /// neighbours) count as emitters and are left out; above 1 every pixel is scored (a
    /// sun-lit floor can be that bright)
    #[arg(long, value_name = "F", default_value_t = mcrad_lab::compare::EMITTER_FRACTION)]
    pub emitter_fraction: f32,
    /// The render's reported relative error per pixel (`mcrad solve --error-image`): prints
    /// its median and 95th percentile against the measured error's
    #[arg(long, value_name = "ERROR.exr")]
    pub reported: Option<String>,
    /// A second render of the same settings with another seed: prints the error split into
    /// noise (what changes with the seed) and bias (what both share), per pixel and over
    /// blocks of 2, 5, 10 and 25 pixels averaged
    #[arg(long, value_name = "IMAGE2.exr")]
    pub second: Option<String>,
}

/// `image-error IMAGE.exr REFERENCE.exr [DIFFERENCE.png] [--reference-error E.exr]
/// [--reported E.exr] [--second IMAGE2.exr]`.
pub fn run_image_error(args: &ImageErrorArgs) -> Result<()> {
    let (image, reference, diff, noise) = (
        &args.image,
        &args.reference,
        args.difference.as_ref(),
        args.reference_error.as_ref(),
    );
    let read = |p: &str| mcrad_render::read_exr(Path::new(p));
    let (image, reference) = (read(image)?, read(reference)?);
    let noise = noise.map(|p| read(p)).transpose()?;
    let e = mcrad_lab::compare::image_error_against_noisy(
        &image,
        &reference,
        noise.as_ref(),
        args.emitter_fraction,
    )?;
    if let Some(d) = diff {
        let d_img = mcrad_lab::compare::signed_difference_image(
            &image,
            &reference,
            args.emitter_fraction,
            0.1,
        )?;
        mcrad_render::write_png(&d_img, Path::new(d), mcrad_render::Exposure::Stops(0.0))?;
    }
    println!(
        "img_rel {:.4} dark_third {:.4} pixels {}",
        e.relative, e.dark_third, e.pixels
    );
    if let Some(second) = &args.second {
        let second = read(second)?;
        for block in [1, 2, 5, 10, 25] {
            let s = mcrad_lab::split::error_split(
                &image,
                &second,
                &reference,
                noise.as_ref(),
                args.emitter_fraction,
                block,
            )?;
            println!(
                "blocks of {block:>2} px: error {:.4} noise {:.4} bias {:.4}",
                s.error, s.noise, s.bias
            );
        }
    }
    if let Some(reported) = &args.reported {
        let reported = read(reported)?;
        let c = mcrad_lab::compare::error_check(
            &image,
            &reference,
            noise.as_ref(),
            &reported,
            args.emitter_fraction,
        )?;
        println!(
            "reported median {:.4} p95 {:.4} (noise p95 {:.4}, mesh p95 {:.4}); measured median \
             {:.4} p95 {:.4}; p95 ratio reported/measured {:.2}; pixels {}",
            c.reported_median,
            c.reported_p95,
            c.second_p95,
            c.third_p95,
            c.measured_median,
            c.measured_p95,
            c.reported_p95 / c.measured_p95,
            c.pixels
        );
    }
    Ok(())
}
