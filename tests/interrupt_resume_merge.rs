//! Nothing is lost: a signalled solve writes its outputs and exits 130, a run cut into pieces
//! with `--save`/`--resume` agrees with one run, and `mcrad merge` of runs with different seeds
//! agrees with one run of all their rays.
//!
//! **Tolerances.** Two independent solutions `a`, `b` of the same mesh are compared per patch
//! and channel by `z = (a - b) / sqrt(V_a + V_b)` with their reported variances; if they
//! estimate the same radiosity with those variances, `mean z² = 1`. The runs' errors are
//! correlated across patches (a gather reads the whole shooting solution), so the mean of
//! 2 800 `z²` is noisier than independent draws would make it: over three seeds each it measured
//! 0.99-1.11 for the pieces and 1.08-1.11 for the merge. The test accepts `[0.6, 1.5]`; reusing
//! a piece's random streams gives 2.3 (measured: its noise counted once, its variance divided by
//! three), dropping a piece fails the ray count.

use mcrad_export::{PatchRow, read_patch_csv};
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const SCENE: &str = "scenes/cornell-box.obj";

fn mcrad(args: &[&str]) -> Output {
    let o = Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("mcrad runs");
    assert!(
        o.status.success(),
        "mcrad {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn path(dir: &Path, name: &str) -> String {
    dir.join(name).to_string_lossy().into_owned()
}

fn read_csv(file: &str) -> Vec<PatchRow> {
    read_patch_csv(Path::new(file)).unwrap()
}

fn stats(file: &str) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(file).unwrap()).unwrap()
}

/// `mean z²` over patches and channels of two solutions (see the module's documentation).
fn mean_z2(a: &[PatchRow], b: &[PatchRow]) -> f64 {
    assert_eq!(a.len(), b.len());
    let mut z2 = Vec::new();
    for (x, y) in a.iter().zip(b) {
        assert_eq!((x.patch, x.area), (y.patch, y.area));
        let v = x.variance.unwrap() + y.variance.unwrap();
        for c in 0..3 {
            if v[c] > 0.0 {
                z2.push((x.radiosity[c] - y.radiosity[c]).powi(2) / v[c]);
            }
        }
    }
    z2.iter().sum::<f64>() / z2.len() as f64
}

/// The reported variances summed over patches and channels.
fn total_variance(rows: &[PatchRow]) -> f64 {
    rows.iter().map(|r| r.variance.unwrap().element_sum()).sum()
}

#[cfg(target_os = "linux")]
/// Sends `signal` (`INT`, `TERM`) to process `pid` with the system's `kill`.
fn signal(pid: u32, signal: &str) {
    let ok = Command::new("kill")
        .args([&format!("-{signal}"), &pid.to_string()])
        .status()
        .expect("kill runs")
        .success();
    assert!(ok, "kill -{signal} {pid}");
}

#[cfg(target_os = "linux")]
/// Starts a long solve (`budget`: `--time 600`, or a ray budget), waits until its first step
/// is saved (so it is stepping), sends `signal` and returns its output. `grace` is the
/// environment's `MCRAD_INTERRUPT_GRACE`, the seconds before the step in progress is abandoned.
fn interrupted_solve(dir: &Path, budget: [&str; 2], grace: &str, signal_name: &str) -> Output {
    let state = dir.join("state");
    let mut child = Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .env("MCRAD_INTERRUPT_GRACE", grace)
        .args([
            "solve",
            SCENE,
            "--threads",
            "2",
            "--quiet",
            // the mesh of 943 patches (an adaptive one would refine for a quarter of --time)
            "--mesh",
            "uniform",
            "--save",
            &path(dir, "state"),
            "--patches",
            &path(dir, "p.csv"),
            "--stats",
            &path(dir, "s.json"),
            "--image",
            &path(dir, "i.png"),
            "--size",
            "32x32",
            "--spp",
            "1",
            "--gltf",
            &path(dir, "g.glb"),
        ])
        .args(budget)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("mcrad starts");
    let start = Instant::now();
    while !state.exists() {
        assert!(
            start.elapsed() < Duration::from_secs(60) && child.try_wait().unwrap().is_none(),
            "no step saved: {:?}",
            child.kill().map(|()| child.wait_with_output())
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    signal(child.id(), signal_name);
    child.wait_with_output().unwrap()
}

// Signals through `kill`, the handler seen in `/proc`.
#[cfg(target_os = "linux")]
#[test]
fn a_signal_stops_the_solve_writes_every_output_and_exits_130() {
    // SIGINT in a `--time` run: its next step (2e5 rays) ends within the grace of 1 s.
    // SIGTERM in a run whose second step is 1.3e6 rays, with no grace: that step is abandoned.
    for (sig, budget, grace, abandoned) in [
        ("INT", ["--time", "600"], "1", false),
        ("TERM", ["--rays", "4e7"], "0", true),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let o = interrupted_solve(dir.path(), budget, grace, sig);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(130), "SIG{sig}: {err}");
        assert!(err.contains("interrupted: "), "{err}");
        assert_eq!(err.contains("abandoned;"), abandoned, "{err}");
        let rows = read_csv(&path(dir.path(), "p.csv"));
        assert_eq!(rows.len(), 943);
        assert!(rows.iter().all(|r| r.variance.is_some()));
        let s = stats(&path(dir.path(), "s.json"));
        assert_eq!(s["stop"], "stopped", "{s}");
        // The abandoned step's counts are unknown, not made up.
        assert_eq!(s["escaped_rays"].is_null(), abandoned, "{s}");
        assert!(s["rays"].as_u64().unwrap() >= 100_000, "{s}");
        let png = std::fs::read(dir.path().join("i.png")).unwrap();
        assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"));
        let glb = std::fs::read(dir.path().join("g.glb")).unwrap();
        assert!(glb.starts_with(b"glTF"));
        // The state saved at the stop holds the solution written (merged with it, the
        // same solution is refused) and continues.
        let o = Command::new(env!("CARGO_BIN_EXE_mcrad"))
            .args([
                "merge",
                &path(dir.path(), "state"),
                &path(dir.path(), "p.csv"),
                "--patches",
                &path(dir.path(), "x.csv"),
            ])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("hold the same solution"), "{err}");
        let more = path(dir.path(), "s2.json");
        mcrad(&[
            "solve",
            SCENE,
            "--threads",
            "2",
            "-q",
            "--rays",
            "1e5",
            "--resume",
            &path(dir.path(), "state"),
            "--stats",
            &more,
        ]);
        let total = stats(&more)["rays"].as_u64().unwrap();
        let before = s["rays"].as_u64().unwrap();
        assert!(
            total > before && total <= before + 100_000,
            "{before} then {total}"
        );
    }
    // A second signal stops at once, with nothing written: see the next test.
}

#[cfg(target_os = "linux")]
/// True once process `pid` catches SIGINT (its handler is installed): bit 2 of `SigCgt` in
/// `/proc/PID/status`.
fn catches_sigint(pid: u32) -> bool {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("SigCgt:"))
        .and_then(|mask| u64::from_str_radix(mask.trim(), 16).ok())
        .is_some_and(|mask| mask & (1 << 1) != 0)
}

// Signals through `kill`, the handler seen in `/proc`.
#[cfg(target_os = "linux")]
#[test]
fn a_second_signal_stops_at_once_and_writes_nothing() {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let csv = path(dir.path(), "p.csv");
    // One shooting wave of a 1e10-ray budget takes minutes: the first signal waits for it.
    let mut child = Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .args([
            "solve",
            SCENE,
            "--method",
            "shoot",
            "--rays",
            "1e10",
            "--threads",
            "2",
            "-q",
            "--patches",
            &csv,
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stderr(Stdio::piped())
        .spawn()
        .expect("mcrad starts");
    let start = Instant::now();
    while !catches_sigint(child.id()) {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no handler in 60 s"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    signal(child.id(), "INT");
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let first = lines.next().unwrap().unwrap();
    let first = if first.is_empty() {
        lines.next().unwrap().unwrap()
    } else {
        first
    };
    assert!(
        first.starts_with("interrupted: stopping at the end of the current step"),
        "{first}"
    );
    signal(child.id(), "TERM");
    let rest: Vec<String> = lines.map(Result::unwrap).collect();
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{rest:?}");
    assert!(
        rest.iter().any(|l| l.contains("stopped at once")),
        "{rest:?}"
    );
    assert!(!Path::new(&csv).exists());
}

#[test]
fn a_run_in_three_pieces_agrees_with_one_run() {
    // combined (the default) and prr: mean z² 0.99-1.11 and 0.99-1.00 measured.
    for method in ["combined", "prr"] {
        three_pieces_against_one_run(method);
    }
}

/// `method` run in three pieces of 3e5 rays (`--save`, then `--resume` twice, naming no
/// setting again: the state holds them) against one run of 9e5 rays with another seed.
fn three_pieces_against_one_run(method: &str) {
    let dir = tempfile::tempdir().unwrap();
    let state = path(dir.path(), "state");
    let [first, plain, pieces, one] =
        ["first", "plain", "pieces", "one"].map(|n| path(dir.path(), &format!("{n}.csv")));
    let (pieces_json, one_json) = (path(dir.path(), "p.json"), path(dir.path(), "o.json"));
    // One run and the pieces on the same mesh: a uniform one (an adaptive mesh depends on the
    // budget and the seed).
    let base = ["solve", SCENE, "--threads", "2", "-q"];
    let run = |extra: &[&str]| {
        let mut args = base.to_vec();
        args.extend_from_slice(extra);
        mcrad(&args);
    };
    let settings = [
        "--rays", "3e5", "--mesh", "uniform", "--method", method, "--seed", "1",
    ];
    let mut first_piece = settings.to_vec();
    first_piece.extend_from_slice(&["--save", &state, "--patches", &first]);
    run(&first_piece);
    run(&["--rays", "3e5", "--resume", &state, "--save", &state]);
    run(&[
        "--rays",
        "3e5",
        "--resume",
        &state,
        "--patches",
        &pieces,
        "--stats",
        &pieces_json,
    ]);
    run(&[
        "--mesh",
        "uniform",
        "--method",
        method,
        "--rays",
        "9e5",
        "--seed",
        "101",
        "--patches",
        &one,
        "--stats",
        &one_json,
    ]);
    // The first piece is the plain run: --save changes nothing.
    let mut plain_run = settings.to_vec();
    plain_run.extend_from_slice(&["--patches", &plain]);
    run(&plain_run);
    assert_eq!(read_csv(&first), read_csv(&plain), "{method}");
    // The rays add up: three pieces of 3e5 cast what one run of 9e5 casts (each method
    // spends its budget to within its pass sizes: 2%).
    let rays = |f: &str| stats(f)["rays"].as_u64().unwrap() as f64;
    let (r3, r1) = (rays(&pieces_json), rays(&one_json));
    assert!(
        (r3 - r1).abs() < 0.02 * r1,
        "{method}: pieces {r3} rays, one run {r1}"
    );
    assert_eq!(stats(&pieces_json)["method"], method);
    assert_eq!(stats(&pieces_json)["seed"], 1);
    let (first, pieces, one) = (read_csv(&first), read_csv(&pieces), read_csv(&one));
    let z2 = mean_z2(&pieces, &one);
    assert!((0.6..1.5).contains(&z2), "{method}: mean z² {z2}");
    // Three pieces report about a third of one piece's variance (0.33-0.35 measured).
    let ratio = total_variance(&pieces) / total_variance(&first);
    assert!(
        (0.25..0.42).contains(&ratio),
        "{method}: variance ratio {ratio}"
    );
}

#[test]
fn an_adaptive_run_is_saved_and_continued_on_its_own_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let state = path(dir.path(), "state");
    let [first, plain, pieces] = ["first", "plain", "pieces"].map(|n| path(dir.path(), n));
    let json = path(dir.path(), "p.json");
    let base = ["solve", SCENE, "--threads", "2", "-q", "--rays", "4e5"];
    let run = |extra: &[&str]| {
        let mut args = base.to_vec();
        args.extend_from_slice(extra);
        mcrad(&args);
    };
    // The default mesh is adaptive: --save keeps it (and the answer) as it is without --save.
    run(&["--seed", "3", "--save", &state, "--patches", &first]);
    run(&["--seed", "3", "--patches", &plain, "--stats", &json]);
    assert_eq!(read_csv(&first), read_csv(&plain));
    assert!(
        stats(&json).get("refinement").is_some(),
        "the default run is adaptive"
    );
    // Continued twice with no setting named: the saved seed, method and mesh.
    run(&["--resume", &state, "--save", &state]);
    run(&["--resume", &state, "--patches", &pieces, "--stats", &json]);
    let (first, pieces) = (read_csv(&first), read_csv(&pieces));
    assert_eq!(first.len(), pieces.len(), "the same mesh");
    for (a, b) in first.iter().zip(&pieces) {
        assert_eq!((a.patch, a.area), (b.patch, b.area));
    }
    assert_eq!(stats(&json)["seed"], 3);
    // Three pieces of which the first pooled the refinement's estimates: well under half of
    // the first piece's variance.
    let ratio = total_variance(&pieces) / total_variance(&first);
    assert!((0.2..0.5).contains(&ratio), "variance ratio {ratio}");
}

#[test]
fn a_resume_of_another_run_is_refused_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let state = path(dir.path(), "state");
    mcrad(&[
        "solve",
        SCENE,
        "--threads",
        "2",
        "-q",
        "--rays",
        "1e5",
        "--save",
        &state,
    ]);
    for (extra, expect) in [
        (
            &["--method", "prr"][..],
            "method combined, this run asks for prr",
        ),
        (&["--seed", "4"][..], "seed 0, this run asks for 4"),
        (
            &["--max-edge", "0.2"][..],
            "this run asks for uniform, maximum edge 0.2",
        ),
        (
            &["--unshot-threshold", "0.01"][..],
            "unshot threshold 0.0001, this run asks for 0.01",
        ),
    ] {
        let mut args = vec![
            "solve",
            SCENE,
            "--threads",
            "2",
            "-q",
            "--rays",
            "1e5",
            "--resume",
            &state,
        ];
        args.extend_from_slice(extra);
        let o = Command::new(env!("CARGO_BIN_EXE_mcrad"))
            .args(&args)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {err}");
        assert!(
            err.starts_with("error: ") && err.contains(expect) && err.lines().count() == 1,
            "{extra:?}: {err}"
        );
    }
    let o = Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .args([
            "solve",
            "scenes/furnace.obj",
            "--threads",
            "2",
            "--rays",
            "1e5",
            "--resume",
            &state,
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("another scene or mesh"), "{err}");
    // A file that is not a state.
    let o = Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .args(["solve", SCENE, "--rays", "1e5", "--resume", SCENE])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("is not a state saved by mcrad --save"),
        "{err}"
    );
    assert_eq!(o.status.code(), Some(1));
}

/// Under independent rays (`--sampler random`) four merged runs are as good as one run of four
/// times the rays. (Under the default quasi-Monte Carlo rays one long run is better than the
/// merge, 1.47x less variance measured: its rays stay stratified over all its rays; the merge
/// stays unbiased and honest, the mean z² checked below holds for it too.)
#[test]
fn four_seeds_merged_agree_with_one_run_of_four_times_the_rays() {
    let dir = tempfile::tempdir().unwrap();
    let mut runs = Vec::new();
    for seed in 1..=4 {
        let csv = path(dir.path(), &format!("s{seed}.csv"));
        mcrad(&[
            "solve",
            SCENE,
            "--mesh",
            "uniform",
            "--threads",
            "2",
            "--sampler",
            "random",
            "-q",
            "--rays",
            "2e5",
            "--seed",
            &seed.to_string(),
            "--patches",
            &csv,
        ]);
        runs.push(csv);
    }
    let one = path(dir.path(), "one.csv");
    mcrad(&[
        "solve",
        SCENE,
        "--mesh",
        "uniform",
        "--threads",
        "2",
        "--sampler",
        "random",
        "-q",
        "--rays",
        "8e5",
        "--seed",
        "99",
        "--patches",
        &one,
    ]);
    let merged = path(dir.path(), "merged.csv");
    let mut args = vec!["merge"];
    args.extend(runs.iter().map(String::as_str));
    args.extend_from_slice(&["--patches", &merged]);
    let o = mcrad(&args);
    assert!(String::from_utf8_lossy(&o.stdout).contains("4 runs merged"));
    let (merged, one) = (read_csv(&merged), read_csv(&one));
    let z2 = mean_z2(&merged, &one);
    assert!((0.6..1.5).contains(&z2), "mean z² {z2}");
    // The merge reports about a quarter of one run's variance, which is what one run of four
    // times the rays reports (1.00-1.02 of it measured with 5e5-ray runs).
    let single = runs
        .iter()
        .map(|r| total_variance(&read_csv(r)))
        .sum::<f64>()
        / 4.0;
    let quarter = total_variance(&merged) / single;
    assert!((0.2..0.3).contains(&quarter), "merged / single {quarter}");
    let against_one = total_variance(&merged) / total_variance(&one);
    assert!(
        (0.8..1.25).contains(&against_one),
        "merged / 4x run {against_one}"
    );
    // Runs of different meshes are refused.
    let coarse = path(dir.path(), "coarse.csv");
    mcrad(&[
        "solve",
        SCENE,
        "--threads",
        "2",
        "-q",
        "--rays",
        "1e5",
        "--no-subdivide",
        "--patches",
        &coarse,
    ]);
    let o = Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .args([
            "merge",
            &runs[0],
            &coarse,
            "--patches",
            &path(dir.path(), "x.csv"),
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("different meshes"), "{err}");
}
