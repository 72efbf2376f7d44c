//! Renders a unit square lamp seen head-on and writes it as PNG and OpenEXR: the square has
//! radiosity `B = π` W/m², so its radiance is `L = B / π = 1` W/(m² sr).
//!
//! `cargo run -p mcrad-render --example picture -- OUT_DIR` (default: a temporary directory).

use glam::{DVec3, Vec3};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_raycast::Bvh;
use mcrad_render::{Camera, Exposure, RenderSettings, Shading, render, write_exr, write_png};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let tmp = tempfile::tempdir()?;
    let out = std::env::args_os()
        .nth(1)
        .map_or_else(|| tmp.path().to_path_buf(), Into::into);
    std::fs::create_dir_all(&out)?;
    std::fs::write(out.join("q.mtl"), "newmtl lamp\nKd 0.5 0.5 0.5\nKe 1 1 1\n")?;
    std::fs::write(
        out.join("q.obj"),
        "mtllib q.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl lamp\nf 1 2 3 4\n",
    )?;
    let scene = mcrad_scene_io::load(&out.join("q.obj"))?.scene;
    let mesh = Mesh::build(&scene, Subdivision::None)?;
    let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch())?;
    let camera = Camera::look_at(
        Vec3::new(0.5, 0.5, 2.0),
        Vec3::new(0.5, 0.5, 0.0),
        Vec3::Y,
        40.0,
    )?;
    let b = [DVec3::splat(std::f64::consts::PI)];
    let settings = RenderSettings {
        width: 64,
        height: 64,
        samples_per_pixel: 4,
        sky: None,
        lights: Vec::new(),
        sky_rays: 0,
        gather_rays: 0,
    };
    let image = render(&mesh, &bvh, &camera, Shading::Flat(&b), &settings, &|_| {})?;
    println!(
        "centre radiance {} W/(m^2 sr)",
        image.get(32, 32).unwrap_or_default()
    );
    write_png(&image, &out.join("square.png"), Exposure::Stops(0.0))?;
    write_exr(&image, &out.join("square.exr"))?;
    println!("wrote square.png and square.exr in {}", out.display());
    Ok(())
}
