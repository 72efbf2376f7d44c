//! What `mcrad solve` writes besides the patch CSV and the statistics: renders and glTF.

use crate::cli::{ShadingArg, Solve};
use anyhow::{Context, Result, bail};
use glam::DVec3;
use indicatif::ProgressBar;
use mcrad_export::{GltfOptions, write_glb};
use mcrad_meshing::Mesh;
use mcrad_raycast::Bvh;
use mcrad_render::{
    Camera, Image, RenderSettings, Shading, render, render_with_error, write_exr, write_png,
};
use std::borrow::Cow;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

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
    if let Some(path) = &args.error_image
        && image_format(path)? != ImageFormat::Exr
    {
        bail!(
            "--error-image {}: the file name must end in .exr",
            path.display()
        );
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
    if let Some(bake) = &args.bake {
        let ext = |p: &Path| {
            p.extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase)
        };
        if ext(&bake.out).as_deref() != Some("glb") {
            bail!(
                "--out {}: the file name must end in .glb (binary glTF)",
                bake.out.display()
            );
        }
    }
    Ok(())
}

/// Bakes the solution `radiosity` (W/m² per patch) into the scene's glTF (`mcrad bake`):
/// writes the GLB and, beside it, the linear lightmap as EXR. With the answer's `direct` (the
/// scene's lights' and sky's direct irradiance per patch) and no `--no-direct-rays`, that
/// light is drawn per texel.
pub fn bake(
    args: &Solve,
    target: &crate::cli::BakeTarget,
    loaded: &mcrad_scene_io::Loaded,
    answer: &mcrad_solve::Answer,
    bar: &ProgressBar,
) -> Result<serde_json::Value> {
    let (mesh, bvh, estimate) = (&answer.mesh, &answer.bvh, &answer.estimate);
    let direct = drawn_direct(args, answer);
    let direct = direct.as_deref();
    let radiosity = estimate.radiosity();
    let gltf = loaded
        .gltf
        .as_deref()
        .context("bake writes into a glTF scene; give a .gltf or .glb file")?;
    bar.reset();
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {human_pos}/{human_len} charts, {msg}, ETA {eta}",
        )
        .expect("a valid template")
        .progress_chars("=> "),
    );
    bar.set_message("baking the lightmap");
    let progress = |done: u64, total: u64| {
        bar.set_length(total);
        bar.set_position(done);
    };
    let load_options = mcrad_scene_io::LoadOptions {
        allow_outside_paths: args.allow_outside_paths,
        lights: args.sun.iter().cloned().collect(),
        sky: args.sky()?,
        light_efficacy: args.light_efficacy,
        two_sided: args.two_sided,
        ..Default::default()
    };
    let input = mcrad_bake::BakeInput {
        path: &args.scene,
        load_options: &load_options,
        scene: &loaded.scene,
        gltf,
        mesh,
        caster: bvh,
        radiosity,
        variance: estimate.variance(),
        face_correlation: answer.face_correlation.as_deref(),
        progress: Some(&progress),
        direct: direct.map(|irradiance| mcrad_bake::DirectLight {
            lights: loaded.scene.lights(),
            sky: loaded.scene.sky().filter(|_| args.sky_rays > 0),
            irradiance,
        }),
    };
    let options = mcrad_bake::BakeOptions {
        texel: target.texel,
        vertex_colors: target.vertex_colors,
        ..Default::default()
    };
    let baked = mcrad_bake::bake(&input, &options)
        .with_context(|| format!("bake {}", args.scene.display()))?;
    std::fs::write(&target.out, &baked.glb)
        .with_context(|| format!("could not write {}", target.out.display()))?;
    // the linear lightmap moves into the EXR writer (a 4096² atlas is 200 MB)
    let atlas = baked.lightmap.as_ref().map(|l| (l.size, l.covered));
    let exr = match baked.lightmap {
        Some(lightmap) => {
            let path = target.out.with_extension("lightmap.exr");
            let image = mcrad_render::Image {
                width: lightmap.size,
                height: lightmap.size,
                pixels: lightmap.irradiance,
            };
            write_exr(&image, &path)?;
            Some(path.display().to_string())
        }
        None => None,
    };
    let error = baked.texel_error.map(|e| {
        let part = |s: mcrad_bake::ErrorSpread| {
            serde_json::json!({
                "median": finite(s.median), "p95": finite(s.p95), "max": finite(s.max)
            })
        };
        serde_json::json!({
            "texels": e.texels, "median": finite(e.median), "p95": finite(e.p95),
            "max": finite(e.max), "noise": part(e.noise), "mesh": part(e.mesh)
        })
    });
    Ok(serde_json::json!({
        "out": target.out.display().to_string(),
        "lightmap": exr,
        "vertex_colors": atlas.is_none(),
        "primitives": baked.primitives,
        "charts": baked.charts,
        "atlas": atlas.map(|(size, _)| size),
        "texel": atlas.map(|_| baked.texel),
        "texels_covered": atlas.map(|(_, covered)| covered),
        "intensity": baked.intensity,
        "texel_relative_error": error,
    }))
}

/// `x`, or `None` (JSON null) when it is not finite (a texel no light reached).
fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// The line `mcrad bake` prints about what it wrote, from [`bake`]'s summary.
pub fn bake_line(summary: &serde_json::Value) -> String {
    let error = match &summary["texel_relative_error"] {
        serde_json::Value::Null => String::new(),
        e => format!(
            "; texel relative error (noise and mesh): median {}, 95th percentile {} \
             (noise {}, mesh {})",
            percent(&e["median"]),
            percent(&e["p95"]),
            percent(&e["noise"]["p95"]),
            percent(&e["mesh"]["p95"])
        ),
    };
    let out = summary["out"].as_str().unwrap_or("?");
    match summary["lightmap"].as_str() {
        Some(exr) => format!(
            "baked {} primitive placements into {out} ({} charts, {}x{} lightmap at {} units per \
             texel{error}; linear lightmap in {exr})",
            summary["primitives"],
            summary["charts"],
            summary["atlas"],
            summary["atlas"],
            summary["texel"],
        ),
        None => format!(
            "baked {} primitive placements into {out} as vertex colours (COLOR_0 = H / {} W/m²{})",
            summary["primitives"],
            summary["intensity"],
            error.replace("texel", "vertex"),
        ),
    }
}

/// A relative error as a percentage ("unbounded" for null: no light reached some texels).
fn percent(x: &serde_json::Value) -> String {
    x.as_f64()
        .map_or_else(|| "unbounded".to_string(), |x| format!("{:.2}%", 100.0 * x))
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

/// The direct irradiance per patch (W/m²) that renders and bakes draw with their own rays and
/// so take out of the solution: the lights' and, unless `--sky-rays 0`, the sky's; `None` with
/// `--no-direct-rays` or without lights and sky.
pub fn drawn_direct(args: &Solve, answer: &mcrad_solve::Answer) -> Option<Vec<DVec3>> {
    let direct = answer.direct.as_ref().filter(|_| !args.no_direct_rays)?;
    match (&answer.sky_direct, args.sky_rays) {
        (Some(sky), 0) => Some(direct.iter().zip(sky.iter()).map(|(d, s)| d - s).collect()),
        _ => Some(direct.iter().collect()),
    }
}

/// [`drawn_direct`] taken out of `answer`, whose direct irradiances go (no copy of them).
pub fn take_drawn_direct(args: &Solve, answer: &mut mcrad_solve::Answer) -> Option<Vec<DVec3>> {
    let sky = answer.sky_direct.take();
    let mut direct = answer
        .direct
        .take()
        .filter(|_| !args.no_direct_rays)?
        .into_vec();
    if let (Some(sky), 0) = (sky, args.sky_rays) {
        for (d, s) in direct.iter_mut().zip(sky.iter()) {
            *d -= s;
        }
    }
    Some(direct)
}

/// `B_i - rho_i H_d,i` per patch (W/m², clamped at 0): the radiosity without the punctual
/// lights' and the sky's direct light `direct` (`H_d` per patch, W/m²) that renders and bakes
/// then draw per sample; `radiosity` itself without `direct`.
pub fn without_direct(mesh: &Mesh, radiosity: &[DVec3], direct: Option<&[DVec3]>) -> Vec<DVec3> {
    let mut b = radiosity.to_vec();
    if let Some(h) = direct {
        take_out_direct(mesh, &mut b, h);
    }
    b
}

/// `B_i - E_i` per patch (W/m², clamped at 0): the reflected part of `radiosity`, which a final
/// gather reads (the emitting faces' own light it draws by area).
pub fn reflected(mesh: &Mesh, radiosity: &[DVec3]) -> Vec<DVec3> {
    radiosity
        .iter()
        .zip(mesh.patches())
        .map(|(&b, p)| (b - p.emission.as_dvec3()).max(DVec3::ZERO))
        .collect()
}

/// [`without_direct`] in place: `radiosity` becomes `B_i - rho_i H_d,i`, clamped at 0.
pub fn take_out_direct(mesh: &Mesh, radiosity: &mut [DVec3], direct: &[DVec3]) {
    for ((b, p), &h) in radiosity.iter_mut().zip(mesh.patches()).zip(direct) {
        *b = (*b - p.reflectance.as_dvec3() * h).max(DVec3::ZERO);
    }
}

/// What the outputs need of the scene after the solve (which may have dropped it).
pub struct Scenery {
    /// The sky, or `None`.
    pub sky: Option<mcrad_scene_io::Sky>,
    /// Punctual lights and the sun, in the scene's frame.
    pub lights: Vec<mcrad_scene_io::Light>,
    /// The scene file's camera, if it has one.
    pub camera: Option<mcrad_scene_io::Camera>,
    /// `--gather-rays auto`'s choice under `--time`, made when the render is timed
    /// ([`image_seconds`]); unset otherwise.
    pub gather: std::sync::OnceLock<u32>,
}

/// The fewest final-gather rays a pixel must get for `--gather-rays auto` to gather: below
/// this the gather's noise outweighs the interpolation's error it removes (on the sun- and
/// sky-lit atrium 256 a pixel made the image error 2.2% against 1.9% without, 1,024 1.1%).
pub const AUTO_GATHER_PIXEL_RAYS: u64 = 512;

/// The most final-gather rays a pixel `--gather-rays auto` casts (over its samples).
pub const AUTO_GATHER_PIXEL_MAX: u64 = 1024;

/// The share of the time left once the mesh is built that `--gather-rays auto` may spend on
/// the final gather under `--time` (under `--rays`, half the solve's rays). Minimising
/// `a² / g + b² / N` (the gather's noise over its rays `g`, the solution's error over its rays
/// `N`) at a fixed time gives the gather the share `a / (a + b)` of the time where its rays cost
/// as much as the solve's; on the sun- and sky-lit atrium its error at equal time was about
/// twice the solution's seen through it (1.1% against 0.4-0.5%).
const AUTO_GATHER_TIME_SHARE: f64 = 2.0 / 3.0;

/// `--gather-rays auto`: the whole rays per sample a budget of `affordable` (rays per sample,
/// may be fractional) allows, at most [`AUTO_GATHER_PIXEL_MAX`] a pixel of `spp` samples (and
/// at least one a sample), or 0 when that gives a pixel fewer than [`AUTO_GATHER_PIXEL_RAYS`].
pub fn auto_gather(spp: u32, affordable: f64) -> u32 {
    let most = (AUTO_GATHER_PIXEL_MAX / u64::from(spp.max(1))).max(1) as f64;
    let g = if affordable.is_finite() {
        affordable.clamp(0.0, most) as u32
    } else {
        0
    };
    if u64::from(spp) * u64::from(g) < AUTO_GATHER_PIXEL_RAYS {
        0
    } else {
        g
    }
}

/// The final gather's rays per sample for `--image` of a solution on `mesh`: `--gather-rays
/// N` as given; `auto`'s choice under `--time` (made when the render was timed); otherwise
/// as many rays (the gather's, and with emitting faces as many shadow rays towards them) as
/// half the solve's `rays_cast`, spread over the image's samples ([`auto_gather`]). 0 without
/// an image, and for `auto` under `--no-direct-rays`.
pub fn gather_rays(args: &Solve, scenery: &Scenery, mesh: &Mesh, rays_cast: u64) -> u32 {
    if args.image.is_none() {
        return 0;
    }
    match args.gather_rays.0 {
        Some(n) => return n,
        None if args.no_direct_rays => return 0,
        None => {}
    }
    if let Some(&g) = scenery.gather.get() {
        return g;
    }
    let samples = f64::from(args.size.0) * f64::from(args.size.1) * f64::from(args.spp);
    let emitters = mesh
        .patches()
        .iter()
        .any(|p| p.emission.max_element() > 0.0);
    let rays_a_gather_ray = if emitters { 2.0 } else { 1.0 };
    auto_gather(
        args.spp,
        rays_cast as f64 / 2.0 / samples / rays_a_gather_ray,
    )
}

/// What lights a render besides the radiosity: the sky rays that leave the scene see, and
/// the lights whose direct light is drawn per sample.
pub struct Lighting<'a> {
    /// The sky, or `None` (black).
    pub sky: Option<mcrad_scene_io::Sky>,
    /// Punctual lights and the sun, in the scene's frame.
    pub lights: &'a [mcrad_scene_io::Light],
    /// Their and the sky's direct light: drawn from the solution, or per sample with shadow
    /// rays instead.
    pub direct: Direct<'a>,
    /// The final gather's rays per sample ([`gather_rays`]; 0: none).
    pub gather_rays: u32,
}

/// How a render draws the lights' and the sky's direct light ([`Lighting::direct`]).
#[derive(Clone, Copy)]
pub enum Direct<'a> {
    /// From the solution, with the rest of the radiosity.
    InSolution,
    /// Per sample, the radiosity drawn without it: `H_d` per patch in the solution (W/m²),
    /// taken out of the radiosity given (`B - rho H_d`).
    PerSample(&'a [DVec3]),
    /// Per sample, the radiosity given already without it.
    PerSampleTakenOut,
}

impl Direct<'_> {
    /// Whether the direct light is drawn per sample.
    fn per_sample(&self) -> bool {
        !matches!(self, Direct::InSolution)
    }
}

/// The relative error of every patch's incident irradiance, `(noise, mesh)`: the noise its
/// relative standard error (`relative_error` of `B`, `E`, `Var B`), the mesh its
/// discretization error ([`Mesh::discretization_error`] of the part of `H = (B - E) / rho`
/// that is interpolated, `drawn`, with `Var H = Var B / rho²` as its noise) relative to its
/// whole `H`. Both infinite where no light reached a patch that has an error.
pub fn patch_errors(
    mesh: &Mesh,
    radiosity: &[DVec3],
    variance: &[DVec3],
    drawn: &[DVec3],
    crease: f32,
) -> Vec<(f64, f64)> {
    let patches = mesh.patches();
    let rho = |p: &mcrad_meshing::Patch| p.reflectance.as_dvec3();
    let per = |x: f64, r: f64| if r > 1e-6 { x / r } else { 0.0 };
    let h: Vec<DVec3> = patches
        .iter()
        .zip(drawn)
        .map(|(p, &b)| mcrad_bake::incident(b, p.emission.as_dvec3(), rho(p)))
        .collect();
    let var_h: Vec<DVec3> = patches
        .iter()
        .zip(variance)
        .map(|(p, v)| {
            let r = rho(p) * rho(p);
            DVec3::new(per(v.x, r.x), per(v.y, r.y), per(v.z, r.z))
        })
        .collect();
    let groups = mesh.corner_groups(crease);
    let e = mesh.discretization_error(&h, Some(&var_h), &groups);
    patches
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let e_noise =
                mcrad_combine::relative_error(radiosity[i], p.emission.as_dvec3(), variance[i]);
            let full = mcrad_bake::incident(radiosity[i], p.emission.as_dvec3(), rho(p));
            let e_mesh = mcrad_combine::relative_error(full, DVec3::ZERO, e[i] * e[i]);
            (e_noise, e_mesh)
        })
        .collect()
}

/// Writes `--error-image`: each pixel the mean over its samples of the relative error
/// ([`patch_errors`]) of the patch a sample sees, red the total `sqrt(noise² + mesh²)`, green
/// the noise, blue the mesh (flat per patch, through the camera of `--image`); nothing
/// without variances.
#[allow(clippy::too_many_arguments)]
pub fn write_error_image(
    args: &Solve,
    mesh: &Mesh,
    bvh: &Bvh,
    radiosity: &[DVec3],
    variance: Option<&[DVec3]>,
    direct: Option<&[DVec3]>,
    file_camera: Option<mcrad_scene_io::Camera>,
    gathered: Option<&(Image, Image)>,
) -> Result<()> {
    let (Some(path), Some(variance)) = (&args.error_image, variance) else {
        return Ok(());
    };
    let drawn = without_direct(mesh, radiosity, direct);
    // as radiosity, so the render's radiance (B / pi) is the error itself
    let shown: Vec<DVec3> = patch_errors(mesh, radiosity, variance, &drawn, args.crease)
        .into_iter()
        .map(|(noise, mesh_part)| {
            let finite = |x: f64| if x.is_finite() { x.min(1e30) } else { 1e30 };
            std::f64::consts::PI
                * DVec3::new(
                    finite(noise.hypot(mesh_part)),
                    finite(noise),
                    finite(mesh_part),
                )
        })
        .collect();
    let camera = camera(args, file_camera, mesh, bvh)?;
    let settings = RenderSettings {
        width: args.size.0,
        height: args.size.1,
        samples_per_pixel: args.spp,
        sky: None,
        lights: Vec::new(),
        sky_rays: 0,
        gather_rays: 0,
    };
    let mut image = render(
        mesh,
        bvh,
        &camera,
        Shading::Flat(&shown),
        &settings,
        &|_| {},
    )?;
    // A final gather's picture: its noise is its own samples' spread (the solution's, read
    // one bounce away over many patches, is left out); the mesh's part stays the solution's
    // as shown without the gather, which the gather only lessens.
    if let Some((picture, error)) = gathered {
        let lum = |p: glam::Vec3| f64::from(mcrad_render::luminance(p));
        for ((e, &l), &s) in image
            .pixels
            .iter_mut()
            .zip(&picture.pixels)
            .zip(&error.pixels)
        {
            let noise = if lum(l) > 0.0 {
                (lum(s) / lum(l)).min(1e30)
            } else {
                0.0
            };
            let mesh_part = f64::from(e.z);
            *e = DVec3::new(noise.hypot(mesh_part), noise, mesh_part).as_vec3();
        }
    }
    write_exr(&image, path)?;
    Ok(())
}

/// The seconds `--image` will take (0 without one): a render's fixed part (checking the
/// shading, setting up the lights: at 10^7 patches most of a small render's time) and its part
/// per pixel, told apart by rendering a dark solution with the sky and the lights drawn as they
/// will be at 1 x 1 and at an eighth of the size each way (at least 16 pixels a side) at the
/// same samples per pixel ([`predicted_render_seconds`]); plus the reconstruction at the
/// corners, timed once and counted as often as [`write()`] makes it.
///
/// Under `--gather-rays auto` with `seconds_left` (the `--time` left), a render of a quarter of
/// the size each way is timed with one and two gather rays a sample, and the final gather gets
/// the rays a sample that fit in two thirds of the time left ([`auto_gather`]); the choice is
/// kept in `scenery`.
pub fn image_seconds(
    args: &Solve,
    scenery: &Scenery,
    mesh: &Mesh,
    bvh: &Bvh,
    seconds_left: Option<f64>,
) -> f64 {
    if args.image.is_none() {
        return 0.0;
    }
    let (w, h) = args.size;
    let small = ((w / 8).max(16).min(w), (h / 8).max(16).min(h));
    // as `drawn_direct`: the lights' and the sky's direct light drawn per sample
    let per_sample = !args.no_direct_rays && (!scenery.lights.is_empty() || scenery.sky.is_some());
    // allocated zeroed, so that reading it maps no memory (at 10^7 patches 240 MB)
    let zeros: Vec<DVec3> = bytemuck::zeroed_vec(mesh.patches().len());
    let smooth = args.shading == ShadingArg::Smooth;
    let clock = Instant::now();
    let corners = (smooth || args.gltf.is_some())
        .then(|| mesh.seamless_corner_radiosity(&zeros, args.crease));
    let corner_seconds = clock.elapsed().as_secs_f64();
    let Ok(camera) = camera(args, scenery.camera, mesh, bvh) else {
        // the render proper will say what is wrong
        return 0.0;
    };
    let shading = match &corners {
        Some(c) if smooth => Shading::Smooth(c),
        _ => Shading::Flat(&zeros),
    };
    let seconds = |(width, height): (u32, u32), gather_rays: u32| {
        let settings = RenderSettings {
            width,
            height,
            samples_per_pixel: args.spp,
            sky: scenery.sky.clone(),
            lights: if per_sample || gather_rays > 0 {
                scenery.lights.clone()
            } else {
                Vec::new()
            },
            sky_rays: if per_sample { args.sky_rays } else { 0 },
            gather_rays,
        };
        let clock = Instant::now();
        // a final gather reads per-patch values (as `write`)
        let shading = if gather_rays > 0 {
            Shading::Flat(&zeros)
        } else {
            shading
        };
        render(mesh, bvh, &camera, shading, &settings, &|_| {})
            .ok()
            .map(|_| clock.elapsed().as_secs_f64())
    };
    let pixels = |(w, h): (u32, u32)| f64::from(w) * f64::from(h);
    let predict = |gather_rays: u32| {
        let (Some(one), Some(eighth)) = (seconds((1, 1), gather_rays), seconds(small, gather_rays))
        else {
            return None;
        };
        Some(predicted_render_seconds(
            (1.0, one),
            (pixels(small), eighth),
            pixels(args.size),
        ))
    };
    let gather_rays = match (args.gather_rays.0, seconds_left) {
        (Some(n), _) => n,
        (None, _) if args.no_direct_rays => 0,
        (None, Some(left)) => {
            // the full render's seconds per gather ray a sample, from a quarter's each way
            // (an eighth's takes too short a time to tell one ray a sample apart) at one and
            // two rays a sample (so that what a gathering render sets up once cancels); none
            // when timing noise hides the difference
            let quarter = ((w / 4).max(16).min(w), (h / 4).max(16).min(h));
            // After an untimed one, and two rays a sample first: the first render over a
            // large scene faults in its mesh's and BVH's pages, and timed first at one ray a
            // sample it made a ray look nearly free (at 10M triangles 64 rays a sample were
            // chosen where fewer than 10 fit); any warming left now counts against the gather.
            let _ = seconds(quarter, 1);
            let two = seconds(quarter, 2);
            let g = match (seconds(quarter, 1), two) {
                (Some(one), Some(two)) if two > one => {
                    let per_ray = (two - one) * pixels(args.size) / pixels(quarter);
                    auto_gather(args.spp, AUTO_GATHER_TIME_SHARE * left.max(0.0) / per_ray)
                }
                _ => 0,
            };
            *scenery.gather.get_or_init(|| g)
        }
        (None, None) => 0,
    };
    let Some(render_seconds) = predict(gather_rays) else {
        return 0.0;
    };
    // as `write`: the solution's for the GLB or a smooth image without drawn direct light, the
    // drawn part's for a smooth image with it (the reflected part's, for a final gather)
    let (gather, drawn_apart) = (gather_rays > 0, per_sample && gather_rays == 0);
    let corner_passes = u32::from(args.gltf.is_some() || (smooth && !drawn_apart && !gather))
        + u32::from(smooth && drawn_apart);
    f64::from(corner_passes) * corner_seconds + render_seconds
}

/// The seconds a render of `pixels` pixels takes, from two renders of `a.0` and `b.0` pixels
/// (`a.0 < b.0`) that took `a.1` and `b.1` seconds: `t = c + k p`, a fixed part `c` and `k`
/// a pixel, both at least 0 (when timing noise makes the larger render the faster, all of it
/// counts per pixel).
fn predicted_render_seconds(a: (f64, f64), b: (f64, f64), pixels: f64) -> f64 {
    let all_per_pixel = b.1 / b.0 * pixels;
    if b.0 <= a.0 {
        return all_per_pixel;
    }
    let per_pixel = (b.1 - a.1) / (b.0 - a.0);
    if per_pixel.is_nan() || per_pixel <= 0.0 {
        return all_per_pixel;
    }
    let fixed = (b.1 - per_pixel * b.0).max(0.0);
    fixed + per_pixel * pixels
}

/// Writes `--image` and `--gltf` for the per-patch radiosity `radiosity` (W/m²); the image
/// with `lighting`'s sky and, as `lighting.direct` says, its lights' direct light drawn per
/// sample in place of the solution's (the GLB's vertex colours keep the solution's: with
/// [`Direct::PerSampleTakenOut`] there is none). Returns, for a final gather and
/// `--error-image`, the image and each pixel's standard error ([`render_with_error`]): what
/// [`write_error_image`] reports as the render's noise.
pub fn write(
    args: &Solve,
    mesh: &Mesh,
    bvh: &Bvh,
    radiosity: &[DVec3],
    lighting: Lighting<'_>,
    file_camera: Option<mcrad_scene_io::Camera>,
    bar: &ProgressBar,
) -> Result<Option<(Image, Image)>> {
    let mut gathered = None;
    let smooth = args.image.is_some() && args.shading == ShadingArg::Smooth;
    // the solution's corners: for the GLB, and for a smooth image that draws no direct light
    // a final gather reads the solution's reflected part, and draws the lights per sample
    let gather_rays = lighting.gather_rays;
    let gather = gather_rays > 0;
    let per_sample = lighting.direct.per_sample() && !gather;
    // the image reads the radiosity less what it draws per sample
    let apart = per_sample || gather;
    let corners = (args.gltf.is_some() || (smooth && !apart))
        .then(|| mesh.seamless_corner_radiosity(radiosity, args.crease));
    if let Some(path) = &args.image {
        let drawn = match lighting.direct {
            // a final gather reads the reflected part, `B - E`
            _ if gather => Cow::Owned(reflected(mesh, radiosity)),
            Direct::PerSample(direct) => Cow::Owned(without_direct(mesh, radiosity, Some(direct))),
            _ => Cow::Borrowed(radiosity),
        };
        let lights = if per_sample || gather {
            lighting.lights.to_vec()
        } else {
            Vec::new()
        };
        // A final gather reads per-patch values: one bounce away their steps blur over the
        // hemisphere (the atrium's image error the same within 0.01%, the render a third
        // faster without the reconstruction and the interpolation).
        let drawn_corners =
            (smooth && per_sample).then(|| mesh.seamless_corner_radiosity(&drawn, args.crease));
        let corners = drawn_corners.as_ref().or(corners.as_ref());
        let radiosity: &[DVec3] = &drawn;
        let format = image_format(path)?;
        let camera = camera(args, file_camera, mesh, bvh)?;
        let shading = match (corners, args.shading) {
            (Some(c), ShadingArg::Smooth) if !gather => Shading::Smooth(c),
            _ => Shading::Flat(radiosity),
        };
        // the sky's direct light (in `direct` with the lights') drawn per sample as well
        let sky_rays = if per_sample { args.sky_rays } else { 0 };
        let settings = RenderSettings {
            width: args.size.0,
            height: args.size.1,
            samples_per_pixel: args.spp,
            sky: lighting.sky,
            lights,
            sky_rays,
            gather_rays,
        };
        bar.reset();
        bar.set_length(u64::from(settings.height));
        bar.set_message("rendering rows");
        let done = AtomicU64::new(0);
        let progress = |rows: usize| {
            let rows = done
                .fetch_max(rows as u64, Ordering::Relaxed)
                .max(rows as u64);
            bar.set_position(rows);
        };
        let (image, error) = if gather && args.error_image.is_some() {
            let (image, error) =
                render_with_error(mesh, bvh, &camera, shading, &settings, &progress)?;
            (image, Some(error))
        } else {
            (
                render(mesh, bvh, &camera, shading, &settings, &progress)?,
                None,
            )
        };
        match format {
            ImageFormat::Png => write_png(&image, path, args.exposure)?,
            ImageFormat::Exr => write_exr(&image, path)?,
        }
        gathered = error.map(|e| (image, e));
    }
    if let (Some(path), Some(corners)) = (&args.gltf, &corners) {
        let file =
            File::create(path).with_context(|| format!("could not create {}", path.display()))?;
        write_glb(BufWriter::new(file), mesh, corners, &GltfOptions::default())
            .with_context(|| format!("could not write {}", path.display()))?;
    }
    Ok(gathered)
}

#[cfg(test)]
mod tests {
    use super::{AUTO_GATHER_PIXEL_MAX, auto_gather, predicted_render_seconds};

    #[test]
    fn the_automatic_gather_takes_what_is_affordable_or_nothing() {
        // whole rays a sample, at most 1024 a pixel
        assert_eq!(auto_gather(256, 3.9), 3);
        assert_eq!(auto_gather(256, 1e9), 4);
        assert_eq!(auto_gather(16, 1e9), 64);
        assert_eq!(auto_gather(4096, 1e9), 1);
        assert_eq!(AUTO_GATHER_PIXEL_MAX, 1024);
        // 512 a pixel at least: 2 x 256 and 32 x 16 are enough, 1 x 256 and 31 x 16 are not
        assert_eq!(auto_gather(256, 2.0), 2);
        assert_eq!(auto_gather(256, 1.99), 0);
        assert_eq!(auto_gather(16, 32.5), 32);
        assert_eq!(auto_gather(16, 31.9), 0);
        // nothing affordable, or a broken estimate
        assert_eq!(auto_gather(256, 0.0), 0);
        assert_eq!(auto_gather(256, -3.0), 0);
        assert_eq!(auto_gather(256, f64::NAN), 0);
        assert_eq!(auto_gather(256, f64::INFINITY), 0);
    }

    #[test]
    fn a_renders_fixed_part_is_not_scaled_by_the_pixels() {
        // 0.4 s fixed and 1e-5 s a pixel (the 10M atrium's timing: a 64 x 64 render of 0.44 s
        // had predicted 28 s for 512 x 512, which took 2.6 s)
        let t = |p: f64| 0.4 + 1e-5 * p;
        let (small, full) = (64.0 * 64.0, 512.0 * 512.0);
        let got = predicted_render_seconds((1.0, t(1.0)), (small, t(small)), full);
        assert!((got - t(full)).abs() < 1e-9, "{got}");
        // timing noise that makes the larger render the faster: all of it per pixel
        let noisy = predicted_render_seconds((1.0, 0.5), (small, 0.45), full);
        assert!((noisy - 0.45 / small * full).abs() < 1e-9, "{noisy}");
        // one size only (a 1 x 1 image): its time per pixel
        assert_eq!(predicted_render_seconds((1.0, 0.3), (1.0, 0.3), 1.0), 0.3);
    }
}
