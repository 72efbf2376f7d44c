//! The library's default solve ([`mcrad_solve::solve`] with [`mcrad_solve::Problem::new`]) is
//! `mcrad solve`'s: the same patch CSV, byte for byte (what the example `solve` of
//! `mcrad-solve` writes).

use mcrad_export::{patch_rows, write_patch_csv};
use std::ops::ControlFlow;
use std::process::Command;

#[test]
fn the_library_default_answer_is_the_cli_answer_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    for (scene, rays, seed) in [
        ("scenes/cornell-box.obj", 3e5, 7u64),
        ("scenes/table-room.obj", 2e5, 0),
    ] {
        let csv = dir.path().join("cli.csv");
        let o = Command::new(env!("CARGO_BIN_EXE_mcrad"))
            .args(["solve", scene, "-q", "--rays"])
            .arg(rays.to_string())
            .args(["--seed", &seed.to_string(), "--patches"])
            .arg(&csv)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(scene);
        let scene = mcrad_scene_io::load(&path).unwrap().scene;
        let mut problem = mcrad_solve::Problem::new(&scene);
        problem.settings.seed = seed;
        problem.budget.rays = Some(rays as u64);
        // one thread here, the machine's in the CLI: the answer does not depend on it
        problem.threads = Some(1);
        let answer = mcrad_solve::solve(&problem, &mut |_| ControlFlow::Continue(())).unwrap();
        assert!(
            answer.stats.refinement.is_some(),
            "the default mesh is adaptive"
        );
        let (b, var) = (answer.estimate.radiosity(), answer.estimate.variance());
        let rows = patch_rows(&answer.mesh, &answer.patch, b, var);
        let mut library = Vec::new();
        write_patch_csv(&mut library, rows).unwrap();
        let cli = std::fs::read(&csv).unwrap();
        assert!(
            library == cli,
            "{}: the library's CSV ({} bytes) differs from the CLI's ({} bytes)",
            path.display(),
            library.len(),
            cli.len()
        );
    }
}
