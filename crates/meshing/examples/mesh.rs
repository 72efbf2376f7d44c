//! Meshes the Cornell box twice, one patch per face and subdivided to the default patch size,
//! and prints patch counts, areas (preserved by subdivision) and the shared corners that vertex
//! radiosity is reconstructed at.
//!
//! `cargo run --release -p mcrad-meshing --example mesh`

use mcrad_meshing::{DEFAULT_CREASE_ANGLE_DEGREES, Mesh, Subdivision};
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.obj");
    let scene = mcrad_scene_io::load(&path)?.scene;

    for subdivision in [Subdivision::None, Subdivision::default_for(&scene)] {
        let mesh = Mesh::build(&scene, subdivision)?;
        let patches = mesh.patches();
        let emitters = patches.iter().filter(|p| p.emission.max_element() > 0.0);
        let smallest = patches.iter().map(|p| p.area).fold(f64::INFINITY, f64::min);
        println!(
            "{subdivision:?}: {} faces -> {} patches ({} emitting), {} triangles, \
             total area {:.4} units², smallest patch {smallest:.2e} units²",
            scene.faces().len(),
            patches.len(),
            emitters.count(),
            mesh.triangles().len(),
            mesh.total_area(),
        );
        // Vertex radiosity averages patch values over the patches meeting at a corner on the
        // same surface; here the "solution" is the emission, so only the light's corners glow.
        let emission: Vec<_> = patches.iter().map(|p| p.emission.as_dvec3()).collect();
        let at_corners = mesh.corner_radiosity(&emission, DEFAULT_CREASE_ANGLE_DEGREES);
        let lit = at_corners.iter().filter(|b| b.max_element() > 0.0).count();
        let groups = mesh.corner_groups(DEFAULT_CREASE_ANGLE_DEGREES);
        println!(
            "  {} patch corners in {} shared groups; {lit} corners carry the light's E",
            mesh.corner_count(),
            groups.len(),
        );
    }
    Ok(())
}
