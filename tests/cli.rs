//! End-to-end tests of the `mcrad` binary: the command-line contract, outputs and errors.

use mcrad_export::{PatchRow, read_patch_csv};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn mcrad(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("mcrad runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn path(dir: &Path, name: &str) -> String {
    dir.join(name).to_string_lossy().into_owned()
}

/// Reads the patch CSV with the one reader (`mcrad_export::read_patch_csv`).
fn read_csv(file: &str) -> Vec<PatchRow> {
    read_patch_csv(Path::new(file)).unwrap()
}

#[test]
fn solve_cornell_box_writes_patches_stats_and_a_summary() {
    let dir = tempfile::tempdir().unwrap();
    let (csv, json) = (path(dir.path(), "p.csv"), path(dir.path(), "s.json"));
    let o = mcrad(&[
        "solve",
        "scenes/cornell-box.obj",
        "--method",
        "shoot",
        "--rays",
        "2e5",
        "--seed",
        "7",
        "--threads",
        "2",
        "--no-subdivide",
        "--patches",
        &csv,
        "--stats",
        &json,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rows = read_csv(&csv);
    assert_eq!(rows.len(), 19, "one patch per face of the Cornell box");
    // With --no-subdivide the patch column is the input face index, in file order.
    assert_eq!(
        rows.iter().map(|r| r.patch).collect::<Vec<_>>(),
        (0..19).collect::<Vec<_>>()
    );
    // The light (face 8) emits pi * (17, 12, 4); everything else only reflects.
    let light = rows[8].radiosity;
    assert!(
        (light.x - 17.0 * std::f64::consts::PI).abs() < 1.0,
        "{light:?}"
    );
    assert!(
        rows.iter()
            .all(|r| r.area > 0.0 && r.radiosity.is_finite() && r.radiosity.min_element() >= 0.0)
    );
    // The floor (face 0) is lit (about 0.36 W/m² red); the red wall (face 7) reflects more red than green.
    assert!(rows[0].radiosity.x > 0.2, "{:?}", rows[0]);
    assert!(
        rows.iter().all(|r| r.variance.is_some()),
        "shooting writes variances"
    );
    assert!(rows[7].radiosity.x > 3.0 * rows[7].radiosity.y);
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    for key in [
        "method",
        "patches",
        "rays",
        "seconds",
        "rays_per_second",
        "iterations",
        "seed",
        "threads",
    ] {
        assert!(stats.get(key).is_some(), "stats lacks {key}: {stats}");
    }
    assert_eq!(stats["method"], "shoot");
    assert!(
        matches!(stats["stop"].as_str(), Some("converged" | "budget")),
        "{stats}"
    );
    assert_eq!(stats["patches"], 19);
    assert_eq!(stats["seed"], 7);
    assert_eq!(stats["threads"], 2);
    // The budget, and the finishing roulette's tail beyond it (at most 5% of it by default).
    assert!(stats["rays"].as_u64().unwrap() <= 210_000, "{stats}");
    let summary = stdout(&o);
    assert!(
        summary.contains("19 patches") && summary.contains("rays") && summary.contains("Mrays/s"),
        "{summary}"
    );
}

#[test]
fn same_seed_same_csv_on_one_or_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    let run = |threads: &str, seed: &str| {
        let csv = path(dir.path(), &format!("t{threads}s{seed}.csv"));
        let o = mcrad(&[
            "solve",
            "scenes/cornell-box.obj",
            "--rays",
            "100000",
            "--max-edge",
            "0.1",
            "--seed",
            seed,
            "--threads",
            threads,
            "--patches",
            &csv,
            "-q",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(stdout(&o).is_empty(), "--quiet prints nothing");
        std::fs::read_to_string(csv).unwrap()
    };
    assert_eq!(run("1", "5"), run("2", "5"));
    assert_ne!(run("2", "5"), run("2", "6"));
}

#[test]
fn furnace_from_the_command_line_is_near_two() {
    let dir = tempfile::tempdir().unwrap();
    let csv = path(dir.path(), "f.csv");
    let o = mcrad(&[
        "solve",
        "scenes/furnace.obj",
        "--rays",
        "3e5",
        "--unshot-threshold",
        "1e-5",
        "--patches",
        &csv,
        "--max-edge",
        "0.5",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rows = read_csv(&csv);
    assert_eq!(rows.len(), 24);
    // Loose here (a few percent): the statistical test lives in mc-radiosity's tests.
    let mean: f64 = rows.iter().map(|r| r.radiosity.x * r.area).sum::<f64>()
        / rows.iter().map(|r| r.area).sum::<f64>();
    assert!((mean - 2.0).abs() < 0.02, "{mean}");
}

/// An unlit plane (reflectance 0.5): refused with the ways to light it; under `--sun` at 30
/// degrees elevation with 1000 W/m² and a delta disk, `B = rho E sin(elevation) = 250` exactly.
#[test]
fn an_unlit_scene_is_refused_and_the_sun_lights_it() {
    let dir = tempfile::tempdir().unwrap();
    let plane = write(
        dir.path(),
        "plane.obj",
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
    );
    let plane = plane.to_str().unwrap();
    assert_clean_failure(&["solve", plane, "-q"], "--sun X,Y,Z,E");
    assert_clean_failure(&["solve", plane, "-q"], "--sky R,G,B or --sky-map F");
    let csv = path(dir.path(), "p.csv");
    let sun = format!("{},0,{},1000,0", 30f64.to_radians().cos(), 0.5);
    let o = mcrad(&[
        "solve",
        plane,
        "-q",
        "--rays",
        "2e4",
        "--sun",
        &sun,
        "--patches",
        &csv,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for row in read_csv(&csv) {
        assert!((row.radiosity.x - 250.0).abs() < 1e-3, "{row:?}");
    }
    assert_clean_failure(
        &["solve", plane, "--sun", "0,0,0,5"],
        "direction towards the sun is zero",
    );
}

/// `--two-sided` on an open plane (reflectance 0.5) lit from below by a delta sun at 30 degrees
/// elevation with 1000 W/m²: the back side has `B = rho E sin(elevation) = 250` exactly and the
/// front 0; `--per-face` writes face 0 (the front) and face 1 (its back, face + 1 face). One-
/// sided, the light reaches no front: B = 0 everywhere. A glTF scene refuses `--two-sided`.
#[test]
fn two_sided_faces_reflect_on_their_back_with_a_row_of_their_own() {
    let dir = tempfile::tempdir().unwrap();
    let plane = write(
        dir.path(),
        "plane.obj",
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
    );
    let plane = plane.to_str().unwrap();
    let sun = format!("{},0,{},1000,0", 30f64.to_radians().cos(), -0.5);
    // One-sided, the sun reaches no front: the exact answer is dark everywhere.
    let dark = path(dir.path(), "dark.csv");
    let o = mcrad(&["solve", plane, "-q", "--sun", &sun, "--patches", &dark]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        read_csv(&dark)
            .iter()
            .all(|r| r.radiosity == glam::DVec3::ZERO)
    );
    for per_face in [true, false] {
        let csv = path(dir.path(), "p.csv");
        let mut args = vec![
            "solve",
            plane,
            "-q",
            "--rays",
            "2e4",
            "--sun",
            &sun,
            "--two-sided",
            "--patches",
            &csv,
        ];
        if per_face {
            args.push("--per-face");
        }
        let o = mcrad(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let rows = read_csv(&csv);
        if per_face {
            assert_eq!(rows.iter().map(|r| r.patch).collect::<Vec<_>>(), [0, 1]);
        }
        assert!(rows.iter().any(|r| r.face == Some(1)) || per_face);
        for row in rows {
            let back = if per_face {
                row.patch == 1
            } else {
                row.face == Some(1)
            };
            let exact = if back { 250.0 } else { 0.0 };
            assert!((row.radiosity.x - exact).abs() < 1e-3, "{row:?}");
        }
    }
    assert_clean_failure(
        &["solve", "scenes/any.gltf", "--two-sided"],
        "--two-sided applies to OBJ scenes",
    );
}

/// Runs a bad invocation and checks for one clear error line, a non-zero exit and no panic.
fn assert_clean_failure(args: &[&str], expect: &str) {
    let o = mcrad(args);
    let err = stderr(&o);
    assert!(!o.status.success(), "{args:?} should fail");
    assert!(
        !err.contains("panicked") && !err.contains("RUST_BACKTRACE"),
        "{err}"
    );
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error")).collect();
    assert_eq!(lines.len(), 1, "one error line: {err}");
    assert!(err.contains(expect), "expected {expect:?} in {err}");
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// `plane.obj` in `dir`: the unit square at y = 0, facing up (+Y), without a material.
fn upward_plane(dir: &Path) -> PathBuf {
    write(
        dir,
        "plane.obj",
        "v 0 0 0\nv 0 0 1\nv 1 0 1\nv 1 0 0\nf 1 2 3 4\n",
    )
}

#[test]
fn bad_input_gets_one_clear_error_line() {
    let dir = tempfile::tempdir().unwrap();
    assert_clean_failure(&["solve", "no/such/scene.obj"], "scene.obj");
    assert_clean_failure(
        &["solve", "scenes/cornell-box.obj", "--rays", "0"],
        "--rays",
    );
    assert_clean_failure(
        &["solve", "scenes/cornell-box.obj", "--max-edge", "-1"],
        "max-edge",
    );
    assert_clean_failure(
        &["solve", "scenes/cornell-box.obj", "--method", "magic"],
        "magic",
    );
    let nan = write(
        dir.path(),
        "nan.obj",
        "mtllib nan.mtl\nv 0 0 0\nv 1 0 0\nv nan 1 0\nusemtl lamp\nf 1 2 3\n",
    );
    write(
        dir.path(),
        "nan.mtl",
        "newmtl lamp\nKd 0.5 0.5 0.5\nKe 1 1 1\n",
    );
    assert_clean_failure(&["solve", nan.to_str().unwrap()], "nan.obj");
    let dark = write(
        dir.path(),
        "dark.obj",
        "mtllib dark.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl grey\nf 1 2 3\n",
    );
    write(dir.path(), "dark.mtl", "newmtl grey\nKd 0.5 0.5 0.5\n");
    assert_clean_failure(&["solve", dark.to_str().unwrap()], "emit");
    let nomtl = write(
        dir.path(),
        "nomtl.obj",
        "mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    );
    assert_clean_failure(&["solve", nomtl.to_str().unwrap()], "missing.mtl");
    let out = path(dir.path(), "no/such/dir/p.csv");
    assert_clean_failure(
        &[
            "solve",
            "scenes/furnace.obj",
            "--rays",
            "1000",
            "--patches",
            &out,
        ],
        "p.csv",
    );
}

#[test]
fn the_readme_command_writes_its_image_csv_and_stats() {
    // The README's first command with its outputs sent to a temporary directory and a small
    // ray budget (the picture's content is checked by `cargo xtask regress`, not here): every
    // flag it shows still works, and the image has the size of the one the README shows.
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let command = readme
        .lines()
        .find(|l| l.starts_with("cargo run --release -- solve "))
        .expect("the README's first command");
    let dir = tempfile::tempdir().unwrap();
    let mut args: Vec<String> = Vec::new();
    let mut words = command
        .trim_start_matches("cargo run --release -- ")
        .split_whitespace();
    while let Some(w) = words.next() {
        match w {
            "--image" | "--patches" | "--stats" => {
                let file = words.next().unwrap();
                let name = Path::new(file).file_name().unwrap().to_str().unwrap();
                args.extend([w.to_string(), path(dir.path(), name)]);
            }
            "--rays" => {
                words.next().expect("a ray budget after --rays");
                args.extend(["--rays".to_string(), "2e5".to_string()]);
            }
            _ => args.push(w.to_string()),
        }
    }
    args.push("-q".into());
    let o = mcrad(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "{}", stderr(&o));
    let png_size = |bytes: &[u8]| -> (u32, u32) {
        assert!(
            bytes.len() > 24 && bytes[..8] == *b"\x89PNG\r\n\x1a\n" && bytes[12..16] == *b"IHDR"
        );
        let be = |i: usize| u32::from_be_bytes(bytes[i..i + 4].try_into().unwrap());
        (be(16), be(20))
    };
    let written = png_size(&std::fs::read(dir.path().join("cornell.png")).unwrap());
    let shown = png_size(&std::fs::read(root.join("docs/cornell.png")).unwrap());
    assert_eq!(
        written, shown,
        "the README's picture has another size than its command writes"
    );
    let csv = std::fs::read_to_string(dir.path().join("cornell.csv")).unwrap();
    assert!(
        csv.starts_with("patch,area,r,g,b,var_r,var_g,var_b"),
        "{csv:.80}"
    );
    assert!(csv.lines().count() > 1000, "{} lines", csv.lines().count());
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("cornell.json")).unwrap())
            .unwrap();
    assert_eq!(
        stats["patches"].as_u64(),
        Some(csv.lines().count() as u64 - 1),
        "{stats}"
    );
    assert!(stats["rays"].as_u64().is_some_and(|r| r > 0), "{stats}");
}

/// A cheap solve of the Cornell box with `extra` arguments; returns the run's output.
fn cheap_solve(extra: &[&str]) -> Output {
    let mut args = vec![
        "solve",
        "scenes/cornell-box.obj",
        "--no-subdivide",
        "--threads",
        "2",
        "--quiet",
    ];
    args.extend_from_slice(extra);
    mcrad(&args)
}

#[test]
fn options_that_do_nothing_with_the_method_are_warned() {
    let cases: [(&[&str], &str); 5] = [
        (
            &["--method", "gather", "--ambient", "--rays", "2e4"],
            "warning: --ambient has no effect with --method gather",
        ),
        (
            &["--method", "combined", "--ambient", "--rays", "2e4"],
            "warning: --ambient has no effect with --method combined",
        ),
        (
            &[
                "--method",
                "shoot",
                "--visibility-tolerance",
                "1e-3",
                "--rays",
                "2e4",
            ],
            "warning: --visibility-tolerance applies to --method reference only",
        ),
        (
            &["--method", "prr", "--split", "--rays", "2e4"],
            "warning: --split applies to --method two-pass only",
        ),
        (
            &[
                "--method",
                "reference",
                "--rays",
                "2e4",
                "--visibility-tolerance",
                "2e-3",
            ],
            "warning: --rays and --time do not apply to --method reference",
        ),
    ];
    for (args, warning) in cases {
        let o = cheap_solve(args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(warning), "{args:?}: {}", stderr(&o));
    }
    // Where the options act, no warning.
    for args in [
        &["--method", "shoot", "--ambient", "--rays", "2e4"][..],
        &[
            "--method",
            "two-pass",
            "--split",
            "--ambient",
            "--rays",
            "2e4",
        ],
    ] {
        let o = cheap_solve(args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        assert!(!stderr(&o).contains("warning"), "{args:?}: {}", stderr(&o));
    }
}

#[test]
fn an_outside_reference_without_variances_is_read_and_areas_are_compared_relatively() {
    let dir = tempfile::tempdir().unwrap();
    let (csv, trace) = (path(dir.path(), "p.csv"), path(dir.path(), "t.csv"));
    let o = cheap_solve(&["--method", "shoot", "--rays", "2e4", "--patches", &csv]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rows = read_csv(&csv);
    // As another tool writes it: five columns, areas to six significant digits (up to 5e-6 off), and one
    // area `scale` off.
    let write = |name: &str, scale: f64| {
        let mut text = String::from("patch,area,r,g,b\n");
        for (k, r) in rows.iter().enumerate() {
            let area = if k == 3 { r.area * scale } else { r.area };
            let b = r.radiosity;
            text += &format!("{},{area:.5e},{},{},{}\n", r.patch, b.x, b.y, b.z);
        }
        let file = path(dir.path(), name);
        std::fs::write(&file, text).unwrap();
        file
    };
    let rounded = write("rounded.csv", 1.0);
    let off = write("off.csv", 1.001);
    let run = |reference: &str| {
        cheap_solve(&[
            "--method",
            "shoot",
            "--rays",
            "2e4",
            "--reference",
            reference,
            "--trace",
            &trace,
        ])
    };
    let o = run(&rounded);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("warning"), "{}", stderr(&o));
    assert!(std::fs::read_to_string(&trace).unwrap().lines().count() >= 2);
    let o = run(&off);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("warning: --reference")
            && stderr(&o).contains(": 1 of the reference's patch areas"),
        "{}",
        stderr(&o)
    );
}

/// `--method shoot --time T` without `--rays` used to queue jobs for 2^64 rays in its first
/// wave, and `progressive-gather` sized its first gather at 2^58 rays (both killed for
/// memory); now shooting waves grow with the run, gathers double from 100 000 rays, and the
/// deadline sizes the rest.
#[test]
fn a_time_and_no_ray_budget_finishes() {
    let dir = tempfile::tempdir().unwrap();
    let json = path(dir.path(), "s.json");
    for method in ["shoot", "progressive-gather"] {
        let o = cheap_solve(&["--method", method, "--time", "0.3", "--stats", &json]);
        assert!(o.status.success(), "{method}: {}", stderr(&o));
        let stats: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert!(stats["rays"].as_u64().unwrap() > 0, "{method}: {stats}");
    }
}

/// `--mesh adaptive --per-face` against a fine uniform mesh's face means: equal within their
/// reported noise (4 standard deviations of the difference, shooting on both, one seed each;
/// the face variance is `sum (A_i/A)² V_i`), and the per-patch CSV lists leaf elements with
/// their input face, within the patch budget.
#[test]
fn adaptive_face_means_match_the_uniform_mesh_within_noise() {
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, extra: &[&str]| {
        let csv = path(dir.path(), name);
        let mut args = vec![
            "solve",
            "scenes/cornell-box.obj",
            "--method",
            "shoot",
            "--rays",
            "4e6",
            "--threads",
            "2",
            "--quiet",
            "--patches",
            &csv,
        ];
        args.extend_from_slice(extra);
        let o = mcrad(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        csv
    };
    let adaptive = read_csv(&run(
        "a.csv",
        &[
            "--mesh",
            "adaptive",
            "--max-patches",
            "3000",
            "--seed",
            "1",
            "--per-face",
        ],
    ));
    // A fine uniform mesh: the default one's face means differ by its discretisation (the
    // blocks' faces by 3-5%, the contact shadows washed out), a fine one's agree.
    let uniform = read_csv(&run(
        "u.csv",
        &["--max-edge", "0.01", "--seed", "2", "--per-face"],
    ));
    assert_eq!(adaptive.len(), 19);
    assert_eq!(uniform.len(), 19);
    for (a, u) in adaptive.iter().zip(&uniform) {
        assert_eq!(a.patch, u.patch);
        assert!(
            (a.area - u.area).abs() < 1e-6 * u.area,
            "face {} area",
            a.patch
        );
        assert_eq!(a.face, None, "--per-face keeps today's header");
        let (va, vu) = (a.variance.unwrap(), u.variance.unwrap());
        for c in 0..3 {
            let z = (a.radiosity[c] - u.radiosity[c]) / (va[c] + vu[c]).sqrt().max(1e-300);
            assert!(z.abs() < 4.0, "face {} channel {c}: z = {z}", a.patch);
        }
    }
    // The leaf elements: a face for each, within the budget, areas adding up per face.
    let leaves = read_csv(&run(
        "l.csv",
        &["--mesh", "adaptive", "--max-patches", "3000", "--seed", "1"],
    ));
    assert!(
        leaves.len() > 943 && leaves.len() <= 3000,
        "{}",
        leaves.len()
    );
    for face in &adaptive {
        let area: f64 = leaves
            .iter()
            .filter(|l| l.face == Some(face.patch))
            .map(|l| l.area)
            .sum();
        assert!(
            (area - face.area).abs() < 1e-6 * face.area,
            "face {}",
            face.patch
        );
    }
}

#[test]
fn adaptive_meshes_refuse_uniform_options() {
    for (extra, message) in [
        (&["--max-edge", "0.1"][..], "--max-edge sets a uniform mesh"),
        (
            &["--min-edge", "0"][..],
            "'0' is not a positive finite length",
        ),
        (
            &["--method", "reference"][..],
            "--method reference solves a fixed mesh",
        ),
    ] {
        let mut args = vec!["--mesh", "adaptive", "--rays", "1e4"];
        args.extend_from_slice(extra);
        let mut full = vec![
            "solve",
            "scenes/cornell-box.obj",
            "--threads",
            "1",
            "--quiet",
        ];
        full.extend_from_slice(&args);
        let o = mcrad(&full);
        assert!(!o.status.success());
        assert!(
            stderr(&o).starts_with("error: ") && stderr(&o).contains(message),
            "{}",
            stderr(&o)
        );
    }
}

/// Without `--mesh` the mesh is adaptive, unless an option needs a fixed mesh (here
/// `--max-edge`): then it is uniform. `--save` keeps it adaptive (the state holds the mesh).
#[test]
fn the_default_mesh_is_adaptive_unless_an_option_needs_a_fixed_one() {
    let dir = tempfile::tempdir().unwrap();
    let patches = |extra: &[&str]| -> (usize, String) {
        let csv = path(dir.path(), "p.csv");
        let mut args = vec![
            "solve",
            "scenes/cornell-box.obj",
            "--rays",
            "3e5",
            "--threads",
            "2",
            "--patches",
            &csv,
        ];
        args.extend_from_slice(extra);
        let o = mcrad(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        (read_csv(&csv).len(), stdout(&o) + &stderr(&o))
    };
    let state = path(dir.path(), "s.state");
    let (uniform, _) = patches(&["--mesh", "uniform"]);
    let (default, said) = patches(&[]);
    let (saved, _) = patches(&["--save", &state]);
    let (sized, _) = patches(&["--max-edge", "0.2"]);
    assert!(said.contains("adaptive mesh:"), "{said}");
    assert_ne!(default, uniform);
    assert_eq!(saved, default);
    assert!(sized < uniform);
}

/// Every Monte Carlo method runs on an adaptive mesh (the method solves the refined mesh).
#[test]
fn every_method_solves_an_adaptive_mesh() {
    let dir = tempfile::tempdir().unwrap();
    for method in mcrad_mc_radiosity::Method::ALL {
        if method == mcrad_mc_radiosity::Method::Reference {
            continue; // deterministic and slow on thousands of patches; nothing adaptive-specific
        }
        let csv = path(dir.path(), &format!("{method}.csv"));
        let o = cheap_adaptive(&["--method", method.name(), "--patches", &csv]);
        assert!(o.status.success(), "{method}: {}", stderr(&o));
        let rows = read_csv(&csv);
        assert!(
            rows.len() > 943 && rows.len() <= 1500,
            "{method}: {}",
            rows.len()
        );
        assert!(
            rows.iter()
                .all(|r| r.radiosity.is_finite() && r.face.is_some())
        );
    }
}

/// A budget too small for the refinement still solves: the rounds it cannot pay for are not
/// started and the method keeps at least half the rays.
#[test]
fn a_small_budget_still_solves_an_adaptive_mesh() {
    let o = mcrad(&[
        "solve",
        "scenes/cornell-box.obj",
        "--mesh",
        "adaptive",
        "--rays",
        "3e4",
        "--method",
        "gather",
        "--threads",
        "2",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// A ray budget the sun's and the sky's direct light takes (4 points a patch, 5 shadow rays a
/// point, on 400 patches: 8000 rays) solves, the method given a ray a patch beyond it, and says
/// so; a budget that pays for both does not.
#[test]
fn a_budget_the_direct_light_takes_is_warned() {
    let dir = tempfile::tempdir().unwrap();
    let plane = upward_plane(dir.path());
    let plane = plane.to_str().unwrap();
    let run = |rays: &str| {
        let lit = ["--sun", "0.3,1,0.2,500", "--sky", "10,10,10", "-q"];
        mcrad(
            &[
                &["solve", plane, "--max-edge", "0.05", "--rays", rays][..],
                &lit,
            ]
            .concat(),
        )
    };
    let warned = "could not pay for the direct light of the lights and the sky";
    let o = run("8e3");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains(warned), "{}", stderr(&o));
    let o = run("1e5");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains(warned), "{}", stderr(&o));
}

/// An adaptive solve of the Cornell box on a small budget: its refinement's quarter of the 4e5
/// rays pays for the pilot and one round (shadow, proximity and 16 gathering rays per element)
/// on the 943-element start.
fn cheap_adaptive(extra: &[&str]) -> Output {
    let mut args = vec![
        "solve",
        "scenes/cornell-box.obj",
        "--mesh",
        "adaptive",
        "--max-patches",
        "1500",
        "--rays",
        "4e5",
        "--threads",
        "2",
        "--quiet",
    ];
    args.extend_from_slice(extra);
    mcrad(&args)
}

/// A convex cube (faces outward: +X, -X, +Y, -Y, +Z, -Z, reflectance 0.5) under a 102 x 51
/// map black but for one pixel of radiance 1000 W/(m² sr) centred on +X (column 76, row 25:
/// within 1.8 degrees of it). The +X face gets `rho L Omega` (`Omega` the pixel's solid angle;
/// cos within 5e-4 of 1), the -X face exactly nothing, the others under 2 % of +X (grazing
/// light from the pixel's rim). Turned by 90 degrees (counter-clockwise from above), the
/// pixel looks along -Z: the -Z face takes the light.
#[test]
fn a_sky_map_lights_the_face_that_looks_at_its_bright_pixel() {
    use std::f64::consts::PI;
    let dir = tempfile::tempdir().unwrap();
    let cube = write(
        dir.path(),
        "cube.obj",
        "v -1 -1 -1\nv 1 -1 -1\nv -1 1 -1\nv 1 1 -1\nv -1 -1 1\nv 1 -1 1\nv -1 1 1\nv 1 1 1\n\
         f 2 4 8 6\nf 1 5 7 3\nf 3 7 8 4\nf 1 2 6 5\nf 5 6 8 7\nf 1 3 4 2\n",
    );
    let (w, h) = (102u32, 51u32);
    let mut pixels = vec![glam::Vec3::ZERO; (w * h) as usize];
    pixels[(25 * w + 76) as usize] = glam::Vec3::splat(1000.0);
    let map = dir.path().join("sky.exr");
    let image = mcrad_render::Image {
        width: w,
        height: h,
        pixels,
    };
    mcrad_render::write_exr(&image, &map).unwrap();
    let omega = 2.0 * PI / f64::from(w)
        * ((25.0 * PI / f64::from(h)).cos() - (26.0 * PI / f64::from(h)).cos());
    let lit = 0.5 * 1000.0 * omega;
    for (rotate, face) in [("0", 0usize), ("90", 5)] {
        let csv = path(dir.path(), "p.csv");
        let o = mcrad(&[
            "solve",
            cube.to_str().unwrap(),
            "-q",
            "--no-subdivide",
            "--rays",
            "2e4",
            "--sky-map",
            map.to_str().unwrap(),
            "--sky-rotate",
            rotate,
            "--patches",
            &csv,
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let rows = read_csv(&csv);
        assert_eq!(rows.len(), 6);
        for row in &rows {
            let b = row.radiosity.x;
            if row.patch as usize == face {
                assert!(
                    (b - lit).abs() < 0.01 * lit,
                    "rotate {rotate}: {row:?} vs {lit}"
                );
            } else {
                assert!(b < 0.02 * lit, "rotate {rotate}: {row:?}");
            }
        }
        let opposite = if face == 0 { 1 } else { 4 };
        assert_eq!(rows[opposite].radiosity.x, 0.0, "rotate {rotate}");
    }
}

/// A Radiance HDR map of radiance 1 everywhere is a uniform sky: an open upward plane of
/// reflectance 0.5 gets `rho pi` on average (loose here: the statistics are tested in
/// mc-radiosity), and through `--sky 1,1,1` exactly.
/// Bad maps are refused with the file and the reason.
#[test]
fn sky_maps_are_read_from_hdr_files_and_bad_ones_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let plane = upward_plane(dir.path());
    let plane = plane.to_str().unwrap();
    // RGBE 1.0 = mantissa 128, exponent 129; 4 x 2 pixels, flat (no run-length encoding)
    let mut hdr = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 4\n".to_vec();
    for _ in 0..8 {
        hdr.extend([128u8, 128, 128, 129]);
    }
    let map = dir.path().join("sky.hdr");
    std::fs::write(&map, &hdr).unwrap();
    let csv = path(dir.path(), "p.csv");
    let o = mcrad(&[
        "solve",
        plane,
        "-q",
        "--rays",
        "2e4",
        "--sky-map",
        map.to_str().unwrap(),
        "--patches",
        &csv,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    // the area mean (225 patches of about 4 % standard error each: 0.3 %) within 1 %
    let rows = read_csv(&csv);
    let mean = rows.iter().map(|r| r.radiosity.x * r.area).sum::<f64>()
        / rows.iter().map(|r| r.area).sum::<f64>();
    let exact = 0.5 * std::f64::consts::PI;
    assert!((mean - exact).abs() < 0.01 * exact, "{mean} vs {exact}");
    // a uniform sky through --sky: exact
    let o = mcrad(&[
        "solve",
        plane,
        "-q",
        "--rays",
        "2e4",
        "--sky",
        "1,1,1",
        "--patches",
        &csv,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for row in read_csv(&csv) {
        // exact up to the f32 of the mesh's emission
        assert!(
            (row.radiosity.x - 0.5 * std::f64::consts::PI).abs() < 1e-6,
            "{row:?}"
        );
    }
    let square = dir.path().join("square.exr");
    let image = mcrad_render::Image {
        width: 4,
        height: 4,
        pixels: vec![glam::Vec3::ONE; 16],
    };
    mcrad_render::write_exr(&image, &square).unwrap();
    assert_clean_failure(
        &["solve", plane, "--sky-map", square.to_str().unwrap()],
        "twice as wide as high",
    );
    let missing = dir.path().join("missing.exr");
    assert_clean_failure(
        &["solve", plane, "--sky-map", missing.to_str().unwrap()],
        "missing.exr",
    );
    assert_clean_failure(&["solve", plane, "--sky", "1,-1,0"], "--sky");
    assert_clean_failure(
        &[
            "solve",
            plane,
            "--sky",
            "1,1,1",
            "--sky-map",
            square.to_str().unwrap(),
        ],
        "cannot be used with",
    );
}

/// A scene whose estimated peak memory exceeds `--max-memory` is refused before any work, with
/// the estimate and the limit in one error line (exit 1); a bad value is a usage error.
#[test]
fn max_memory_refuses_a_scene_that_would_not_fit() {
    let o = mcrad(&[
        "solve",
        "scenes/cornell-box.obj",
        "--rays",
        "1e5",
        "--max-memory",
        "10M",
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = stderr(&o);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains("would need about") && err.contains("more than the 10.0 MiB"),
        "{err}"
    );
    assert!(err.contains("--max-memory 10485760"), "{err}");
    let o = mcrad(&[
        "solve",
        "scenes/cornell-box.obj",
        "--rays",
        "1e5",
        "--max-memory",
        "2G",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = mcrad(&["solve", "scenes/cornell-box.obj", "--max-memory", "3X"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
}

/// `--error-image`: per pixel the relative error of what it sees, red the total, green the
/// noise, blue the mesh. The box seen through its open front: nearly every pixel sees a
/// surface and is positive, every one finite, the total at least each part, and the mesh's
/// part shows (the blocks' shadows and contact lines on a coarse uniform mesh). A `.png` is
/// refused before the solve.
#[test]
fn an_error_image_reports_noise_and_mesh_per_pixel() {
    let dir = tempfile::tempdir().unwrap();
    // the box solved and its error image written to `exr`, with `extra` options
    let error_image = |exr: &str, extra: &[&str]| {
        let mut args = vec![
            "solve",
            "scenes/cornell-box.obj",
            "--rays",
            "3e5",
            "--mesh",
            "uniform",
            "--threads",
            "2",
            "--size",
            "32x32",
            "--spp",
            "4",
            "--camera",
            "eye=0.278,0.273,-0.8,look=0.278,0.273,0,fov=39.3",
            "--error-image",
            exr,
            "-q",
        ];
        args.extend_from_slice(extra);
        let o = mcrad(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        mcrad_render::read_exr(Path::new(exr)).unwrap()
    };
    let exr = path(dir.path(), "e.exr");
    let image = error_image(&exr, &[]);
    assert_eq!((image.width, image.height), (32, 32));
    let (mut seen, mut mesh_seen) = (0, 0);
    for p in &image.pixels {
        assert!(p.is_finite() && p.min_element() >= 0.0, "{p}");
        assert!(p.x >= p.y * 0.999 && p.x >= p.z * 0.999, "{p}");
        seen += usize::from(p.x > 0.0);
        mesh_seen += usize::from(p.z > 0.0);
    }
    assert!(
        seen > 32 * 32 * 9 / 10 && mesh_seen > 32,
        "{seen} {mesh_seen}"
    );
    // With a final gather in --image, the noise is the render's own (its samples' spread):
    // another noise than the solution's, positive wherever a surface is seen, and the total
    // still the two parts' root sum of squares.
    let gathered_image = path(dir.path(), "g-image.exr");
    let gathered = error_image(
        &path(dir.path(), "g.exr"),
        &["--image", &gathered_image, "--gather-rays", "4"],
    );
    let mut differ = 0;
    for (g, p) in gathered.pixels.iter().zip(&image.pixels) {
        assert!(g.is_finite() && g.min_element() >= 0.0, "{g}");
        assert!((g.x - g.y.hypot(g.z)).abs() <= 1e-3 * g.x, "{g}");
        assert_eq!(g.z, p.z, "the mesh's part is the solution's");
        if p.x > 0.0 {
            assert!(g.y > 0.0, "{g}");
        }
        differ += usize::from((g.y - p.y).abs() > 1e-3 * p.y);
    }
    assert!(differ > 32 * 32 / 2, "{differ}");
    let o = mcrad(&[
        "solve",
        "scenes/cornell-box.obj",
        "--error-image",
        &path(dir.path(), "e.png"),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("--error-image"), "{}", stderr(&o));
}
