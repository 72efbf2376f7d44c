//! `cargo xtask viewer-check`: a scene baked by `mcrad bake`, rendered by three.js in headless
//! Chromium (Debian's `chromium`, npm's `three` and `playwright-core`, see `xtask/viewer/`), must
//! look like mcrad's own render of the same solution from the same camera: tile means of linear
//! radiance within [`THRESHOLD`]. Writes `target/viewer-check/side-by-side.png` (mcrad left,
//! three.js right) and, with `--docs`, copies it to `docs/bake-cornell.png`.
//!
//! Also the glTF version of the Cornell box (`scenes/cornell-box.gltf` + `.bin`, written by
//! `cargo xtask gen-scenes`): the OBJ's faces fanned into triangles, one primitive per
//! material, and the camera mcrad frames it with.

use anyhow::{Context, Result, bail};
use glam::Vec3;
use mcrad_render::{Camera, Image};
use std::path::Path;
use std::process::Command;

/// Largest relative difference of 16-pixel tile means (with a floor of 25% of the image mean)
/// between three.js and mcrad, over the pixels away from the clipped light: both interpolate the
/// same solution, but three.js reads it from 8-bit texels, bilinearly, at chart resolution, and
/// anti-aliases silhouettes differently (the floor keeps tiles that are mostly background from
/// counting a silhouette's few pixels as a large relative error). Measured: 0.065; a bake that
/// left half of one wall's texels empty gave 0.93.
pub const THRESHOLD: f32 = 0.08;
/// Image size of the check.
const SIZE: u32 = 256;
/// Exposure of both renders, stops (`mcrad --exposure`): the Cornell box's walls near mid-grey.
const STOPS: f32 = 0.0;

/// Writes `scenes/cornell-box.gltf` and `.bin` from `scenes/cornell-box.obj`.
pub fn write_cornell_gltf(root: &Path) -> Result<()> {
    let loaded = mcrad_scene_io::load(&root.join("scenes/cornell-box.obj"))?;
    let mesh = mcrad_meshing::Mesh::build(&loaded.scene, mcrad_meshing::Subdivision::None)?;
    let bvh = mesh.caster()?;
    let camera = Camera::frame_scene(&mesh, &bvh)?;
    let camera = mcrad_scene_io::Camera {
        eye: camera.eye(),
        forward: camera.forward(),
        up: camera.up(),
        fov_y_degrees: camera.fov_y_degrees(),
    };
    let (json, bin) =
        mcrad_bake::gltf_from_scene(&loaded.scene, Some(&camera), Some("cornell-box.bin"));
    for (name, bytes) in [
        ("cornell-box.gltf", json.into_bytes()),
        ("cornell-box.bin", bin),
    ] {
        let path = root.join("scenes").join(name);
        std::fs::write(&path, bytes)
            .with_context(|| format!("could not write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// `cargo xtask viewer-check [--docs]`.
pub fn run(root: &Path, mcrad: &Path, docs: bool) -> Result<()> {
    let out = root.join("target/viewer-check");
    std::fs::create_dir_all(&out)?;
    let viewer = root.join("xtask/viewer");
    if !viewer.join("node_modules/three").exists() {
        let status = Command::new("npm")
            .args(["install", "--no-audit", "--no-fund"])
            .current_dir(&viewer)
            .status()
            .context("npm (Node.js) is needed for the viewer check")?;
        if !status.success() {
            bail!("npm install failed in {}", viewer.display());
        }
    }
    let glb = out.join("cornell.glb");
    let ours = out.join("mcrad.exr");
    let start = std::time::Instant::now();
    let size = format!("{SIZE}x{SIZE}");
    let status = Command::new(mcrad)
        .args(["bake", "scenes/cornell-box.gltf", "--out"])
        .arg(&glb)
        .args([
            "--rays",
            "4e6",
            "--seed",
            "1",
            "--max-edge",
            "0.05",
            "--texel",
            "0.004",
        ])
        .args(["--size", &size, "--spp", "16", "--image"])
        .arg(&ours)
        .current_dir(root)
        .status()?;
    if !status.success() {
        bail!("mcrad bake failed");
    }
    let shot = out.join("three.png");
    let status = Command::new("node")
        .arg(viewer.join("check.mjs"))
        .arg(&glb)
        .arg(&shot)
        .args([SIZE.to_string(), SIZE.to_string(), STOPS.to_string()])
        .status()
        .context("node (Node.js) is needed for the viewer check")?;
    if !status.success() {
        bail!("the three.js render failed (is Debian's chromium installed? apt install chromium)");
    }
    let three = read_srgb_png(&shot, STOPS)?;
    let shown = (mcrad_render::read_exr(&ours)?, three.clone());
    // The screenshot clips at white (the light), per anti-aliasing sample: leave out the
    // pixels either image shows as white and their neighbours within 2 pixels (there the
    // difference is clipping, not the solution).
    let mut ours = mcrad_render::read_exr(&ours)?;
    let mut three = three;
    let white = 2f32.powf(-STOPS);
    let n = SIZE as i64;
    let bright: Vec<bool> = (0..ours.pixels.len())
        .map(|i| {
            ours.pixels[i].max_element() >= white || three.pixels[i].max_element() >= 0.99 * white
        })
        .collect();
    for y in 0..n {
        for x in 0..n {
            let near = (-2..=2).any(|dy: i64| {
                (-2..=2).any(|dx: i64| {
                    let (a, b) = (x + dx, y + dy);
                    (0..n).contains(&a) && (0..n).contains(&b) && bright[(b * n + a) as usize]
                })
            });
            if near {
                ours.pixels[(y * n + x) as usize] = Vec3::ZERO;
                three.pixels[(y * n + x) as usize] = Vec3::ZERO;
            }
        }
    }
    let mean = ours.pixels.iter().sum::<Vec3>().element_sum() / (3 * ours.pixels.len()) as f32;
    let d = mcrad_lab::compare::tile_difference(&three, &ours, 16, 0.25 * mean)?;
    let both = side_by_side(&shown.0, &shown.1);
    let picture = out.join("side-by-side.png");
    mcrad_render::write_png(&both, &picture, mcrad_render::Exposure::Stops(STOPS))?;
    if docs {
        std::fs::copy(&picture, root.join("docs/bake-cornell.png"))?;
    }
    println!(
        "viewer check: largest tile difference {:.4} (threshold {THRESHOLD}) at tile {:?}, \
         channel {}; {:.1} s; {}",
        d.max_relative,
        d.worst_tile,
        d.worst_channel,
        start.elapsed().as_secs_f64(),
        picture.display()
    );
    if d.max_relative > THRESHOLD {
        bail!("three.js and mcrad disagree beyond the threshold");
    }
    Ok(())
}

/// A screenshot (8-bit sRGB, tone-mapped linearly at 2^stops) back to linear radiance.
fn read_srgb_png(path: &Path, stops: f32) -> Result<Image> {
    let img = image::open(path)
        .with_context(|| format!("could not read {}", path.display()))?
        .to_rgb8();
    let decode = |c: u8| mcrad_scene_io::srgb_to_linear(f32::from(c) / 255.0);
    let scale = 2f32.powf(-stops);
    Ok(Image {
        width: img.width(),
        height: img.height(),
        pixels: img
            .pixels()
            .map(|p| Vec3::new(decode(p[0]), decode(p[1]), decode(p[2])) * scale)
            .collect(),
    })
}

/// `a` and `b` next to each other.
fn side_by_side(a: &Image, b: &Image) -> Image {
    let (w, h) = (a.width + b.width, a.height.max(b.height));
    let mut pixels = vec![Vec3::ZERO; (w * h) as usize];
    for (img, x0) in [(a, 0), (b, a.width)] {
        for y in 0..img.height {
            for x in 0..img.width {
                pixels[(y * w + x0 + x) as usize] = img.get(x, y).unwrap_or(Vec3::ZERO);
            }
        }
    }
    Image {
        width: w,
        height: h,
        pixels,
    }
}
