//! Loads a scene and prints what the solver will see: faces, materials with their reflectance
//! `rho` and emitted radiosity `E` (W/m²), the area of light sources, the bounding box and any
//! repairs made on the way. Bad input is a `SceneError` that names the file and the value.
//!
//! `cargo run --release -p mcrad-scene-io --example load -- [SCENE]` (default: the bundled
//! `scenes/cornell-box.obj`; `.obj`, `.gltf` and `.glb` are read).

use std::path::{Path, PathBuf};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args_os().nth(1).map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.obj"),
        PathBuf::from,
    );
    let loaded = mcrad_scene_io::load(&path)?;
    for w in &loaded.warnings {
        println!("warning: {w}");
    }
    let scene = &loaded.scene;
    println!(
        "{}: {} faces, {} vertices, {} materials",
        path.file_name()
            .map_or(path.display(), |name| Path::new(name).display()),
        scene.faces().len(),
        scene.positions().len(),
        scene.materials().len()
    );
    for (m, material) in scene.materials().iter().enumerate() {
        let faces = scene.faces().iter().filter(|f| f.material as usize == m);
        let area: f64 = faces.clone().map(|f| scene.face_area(f)).sum();
        println!(
            "  {:<8} faces: {:>2}, area {area:.3} units², rho {:.3}, E {:.3} W/m²",
            material.name,
            faces.count(),
            material.reflectance,
            material.emission
        );
    }
    let bounds = scene.bounds();
    println!(
        "bounds {} .. {}, diagonal {:.3}",
        bounds.min,
        bounds.max,
        bounds.diagonal()
    );
    // Bad input is an error value with a readable message, never a panic.
    if let Err(e) = mcrad_scene_io::load(Path::new("notes.txt")) {
        println!("loading notes.txt fails: {e}");
    }
    Ok(())
}
