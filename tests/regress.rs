//! The golden-image comparison of `cargo xtask regress` must tell noise from a real change:
//! renders of the Cornell box with another seed pass against the stored golden, and a red wall
//! 4% more reflective fails.

use mcrad_lab::recipe::Recipe;
use mcrad_render::read_exr;
use std::path::Path;
use std::process::Command;

fn recipe() -> Recipe {
    Recipe::read(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/golden/cornell-box.json"))
        .unwrap()
}

/// Renders `scene` with the recipe's arguments and `seed`, returning the largest tile difference
/// from the golden.
fn difference(scene: &Path, seed: u64, out: &Path) -> f32 {
    let r = recipe();
    let o = Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .arg("solve")
        .arg(scene)
        .args(&r.args)
        .args(["--seed", &seed.to_string(), "-q", "--image"])
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let golden =
        read_exr(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/golden/cornell-box.exr"))
            .unwrap();
    r.difference(&read_exr(out).unwrap(), &golden)
        .unwrap()
        .max_relative
}

#[test]
fn golden_comparison_passes_noise_and_catches_a_brighter_wall() {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let threshold = recipe().threshold;
    assert!(threshold > 0.0, "the recipe has been blessed");
    // Another seed: noise only. (Seed 0 is the golden itself.)
    let noise = difference(
        &root.join("scenes/cornell-box.obj"),
        7,
        &dir.path().join("seed7.exr"),
    );
    assert!(
        noise <= threshold,
        "a new seed differs by {noise}, over the threshold {threshold}"
    );
    // The red wall 4% more reflective (Kd 0.63 -> 0.655 in red).
    std::fs::copy(
        root.join("scenes/cornell-box.obj"),
        dir.path().join("cornell-box.obj"),
    )
    .unwrap();
    let mtl = std::fs::read_to_string(root.join("scenes/cornell-box.mtl")).unwrap();
    assert!(mtl.contains("Kd 0.63 0.065 0.05"));
    std::fs::write(
        dir.path().join("cornell-box.mtl"),
        mtl.replace("Kd 0.63 0.065 0.05", "Kd 0.655 0.065 0.05"),
    )
    .unwrap();
    let changed = difference(
        &dir.path().join("cornell-box.obj"),
        0,
        &dir.path().join("red.exr"),
    );
    eprintln!(
        "tile difference: seed 7 {noise:.4}, red wall +4% {changed:.4}, threshold {threshold:.4}"
    );
    assert!(
        changed > threshold,
        "a 4% brighter red wall differs by only {changed} (threshold {threshold})"
    );
}
