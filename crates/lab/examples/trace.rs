//! Measures a made-up solution against a reference: two unit squares facing each other, one
//! emitting; the "solution" has the reflected light 10% too bright, so its rms_rel is 0.1.
//! Writes the trace (`seconds,rays,rms_rel`) to standard output and compares two tiny images.
//!
//! `cargo run -p mcrad-lab --example trace`

use glam::{DVec3, Vec3};
use mcrad_lab::compare::tile_difference;
use mcrad_lab::trace::{Reference, Trace};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_render::Image;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = tempfile::tempdir()?;
    std::fs::write(
        dir.path().join("pair.mtl"),
        "newmtl grey\nKd 0.5 0.5 0.5\nnewmtl lamp\nKd 0 0 0\nKe 1 1 1\n",
    )?;
    std::fs::write(
        dir.path().join("pair.obj"),
        "mtllib pair.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 0 1 1\nv 1 1 1\nv 1 0 1\n\
         usemtl grey\nf 1 2 3 4\nusemtl lamp\nf 5 6 7 8\n",
    )?;
    let scene = mcrad_scene_io::load(&dir.path().join("pair.obj"))?.scene;
    let mesh = Mesh::build(&scene, Subdivision::None)?;
    // A stand-in reference: every patch reflects 0.2 W/m² on top of what it emits.
    let exact: Vec<DVec3> = mesh
        .patches()
        .iter()
        .map(|p| p.emission.as_dvec3() + DVec3::splat(0.2))
        .collect();
    let brighter: Vec<DVec3> = mesh
        .patches()
        .iter()
        .map(|p| p.emission.as_dvec3() + DVec3::splat(0.22))
        .collect();
    let mut trace = Trace::new(std::io::stdout(), Reference::new(&mesh, exact.clone())?)?;
    trace.record(0.5, 1_000, &brighter)?;
    let e = trace.record(1.0, 2_000, &exact)?;
    assert_eq!(e, 0.0);

    let image = |v: f32| Image {
        width: 4,
        height: 4,
        pixels: vec![Vec3::splat(v); 16],
    };
    let d = tile_difference(&image(1.04), &image(1.0), 2, 0.0)?;
    println!(
        "tile difference of a 4% brighter image: {:.3}",
        d.max_relative
    );
    Ok(())
}
