//! End-to-end tests of the `mcrad` binary: the command-line contract, outputs and errors.

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

/// Parses the patch CSV into (patch, area, rgb, variance).
fn read_csv(file: &str) -> Vec<(u32, f64, [f64; 3], [f64; 3])> {
    let text = std::fs::read_to_string(file).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("patch,area,r,g,b,var_r,var_g,var_b"));
    lines
        .map(|l| {
            let f: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            (f[0] as u32, f[1], [f[2], f[3], f[4]], [f[5], f[6], f[7]])
        })
        .collect()
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
        rows.iter().map(|r| r.0).collect::<Vec<_>>(),
        (0..19).collect::<Vec<_>>()
    );
    // The light (face 8) emits pi * (17, 12, 4); everything else only reflects.
    let light = rows[8].2;
    assert!(
        (light[0] - 17.0 * std::f64::consts::PI).abs() < 1.0,
        "{light:?}"
    );
    assert!(
        rows.iter()
            .all(|r| r.1 > 0.0 && r.2.iter().all(|b| b.is_finite() && *b >= 0.0))
    );
    // The floor (face 0) is lit (about 0.36 W/m² red); the red wall (face 7) reflects more red than green.
    assert!(rows[0].2[0] > 0.2, "{:?}", rows[0]);
    assert!(rows[7].2[0] > 3.0 * rows[7].2[1]);
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
    assert!(stats["rays"].as_u64().unwrap() <= 200_000);
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
    let mean: f64 =
        rows.iter().map(|r| r.2[0] * r.1).sum::<f64>() / rows.iter().map(|r| r.1).sum::<f64>();
    assert!((mean - 2.0).abs() < 0.02, "{mean}");
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
fn readme_image_is_what_the_readme_command_writes() {
    // The README's first command, with its outputs sent to a temporary directory.
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md")).unwrap();
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
            _ => args.push(w.to_string()),
        }
    }
    args.push("-q".into());
    let o = mcrad(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "{}", stderr(&o));
    let written = std::fs::read(dir.path().join("cornell.png")).unwrap();
    let stored =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/cornell.png")).unwrap();
    assert!(
        written == stored,
        "docs/cornell.png is not what the README's command writes now: run that command to refresh it"
    );
}
