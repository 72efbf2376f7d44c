//! The hostile-input corpus (`tests/hostile/`, and the bigger reproducers generated here) run
//! through the built `mcrad` binary, each under a time limit: no panic, no hang, exit 0 or an
//! error exit with exactly one `error:` line that says each cause once, in one short line of
//! printable text; and no file outside the scene's folder is read (files named `outside-*`
//! must be refused for that, and are solved when `--allow-outside-paths` allows them, which
//! shows that the refusal is what stopped them).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Longer than any input of the corpus takes (a few tenths of a second each on a shared
/// 2-core machine): a run still going then hangs. A guard, not a speed test.
const HANG_LIMIT: Duration = Duration::from_secs(60);

/// The longest error line accepted: a message quotes at most 60 characters of input.
const MAX_LINE: usize = 600;

/// The outcome of one run.
struct Run {
    code: Option<i32>,
    stderr: String,
}

/// Runs `mcrad solve SCENE --rays 2e4 -q --threads 1 EXTRA...` in `dir` (`--rays` and
/// `--threads` as `extra` gives them, if it does), killed at [`HANG_LIMIT`].
fn solve(dir: &Path, scene: &str, extra: &[&str]) -> Run {
    let mut args = vec!["solve", scene, "-q"];
    for (flag, default) in [("--rays", "2e4"), ("--threads", "1")] {
        if !extra.contains(&flag) {
            args.extend([flag, default]);
        }
    }
    let err_path = dir.join(format!("{scene}.stderr"));
    let err_file = std::fs::File::create(&err_path).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .args(args)
        .args(extra)
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(err_file)
        .spawn()
        .expect("mcrad runs");
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > HANG_LIMIT {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("{scene} {extra:?}: still running after {HANG_LIMIT:?} (a hang)");
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let stderr = String::from_utf8_lossy(&std::fs::read(&err_path).unwrap()).into_owned();
    Run {
        code: status.code(),
        stderr,
    }
}

/// Whether `line` says some cause of 12 or more characters twice in a row (`X: X`).
fn repeats_a_cause(line: &str) -> Option<&str> {
    let b = line.as_bytes();
    for (k, _) in line.match_indices(": ") {
        let right = &b[k + 2..];
        for len in 12..=k.min(right.len()) {
            if b[k - len..k] == right[..len] {
                return Some(&line[k - len..k]);
            }
        }
    }
    None
}

/// Checks the invariants of every run; returns the error line, if any.
fn check(scene: &str, extra: &[&str], run: &Run, allowed: &[i32]) -> Option<String> {
    let what = format!("{scene} {extra:?}");
    let err = &run.stderr;
    assert!(
        !err.contains("panicked") && !err.contains("RUST_BACKTRACE"),
        "{what}: panic\n{err}"
    );
    let code = run
        .code
        .unwrap_or_else(|| panic!("{what}: killed by a signal\n{err}"));
    assert!(allowed.contains(&code), "{what}: exit {code}\n{err}");
    let errors: Vec<&str> = err.lines().filter(|l| l.starts_with("error")).collect();
    if code == 0 {
        assert!(errors.is_empty(), "{what}: success with {errors:?}");
        return None;
    }
    assert_eq!(errors.len(), 1, "{what}: one error line\n{err}");
    for line in err.lines() {
        assert!(
            line.len() <= MAX_LINE,
            "{what}: a line of {} bytes",
            line.len()
        );
        assert!(
            !line.chars().any(char::is_control),
            "{what}: control characters in {line:?}"
        );
    }
    let line = errors[0];
    assert!(line.starts_with("error: "), "{what}: {line}");
    if let Some(cause) = repeats_a_cause(line) {
        panic!("{what}: the cause {cause:?} is said twice in {line:?}");
    }
    Some(line.to_string())
}

/// The corpus copied into `root/scene/`, with the big reproducers generated there, and files
/// outside it that `outside-*` scenes name (valid: reading them would make the scene solve).
fn corpus(root: &Path) -> (PathBuf, Vec<String>) {
    let scene = root.join("scene");
    std::fs::create_dir(&scene).unwrap();
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/hostile");
    for entry in std::fs::read_dir(&source).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, scene.join(path.file_name().unwrap())).unwrap();
    }
    std::fs::write(
        root.join("outside.mtl"),
        "newmtl outside_lamp\nKd 0.5 0.5 0.5\nKe 1 1 1\n",
    )
    .unwrap();
    let triangle: Vec<u8> = [0f32, 0., 0., 1., 0., 0., 0., 1., 0.]
        .iter()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    std::fs::write(root.join("outside.bin"), triangle).unwrap();
    for (name, text) in generated() {
        std::fs::write(scene.join(name), text).unwrap();
    }
    let mut names: Vec<String> = std::fs::read_dir(&scene)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| [".obj", ".gltf", ".glb"].iter().any(|x| n.ends_with(x)))
        .collect();
    names.sort();
    (scene, names)
}

/// The reproducers too big to commit: (file name, contents).
fn generated() -> Vec<(String, String)> {
    let head = "mtllib lamp.mtl\nusemtl lamp\n";
    let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    let mut out = Vec::new();
    // a face of 60000 corners, and 40 faces of 999 (self-touching: the slowest to split)
    out.push((
        "huge-polygon.obj".into(),
        format!("{head}{tri}f{}\n", " 1 2 3".repeat(20_000)),
    ));
    out.push((
        "many-self-touching-polygons.obj".into(),
        format!(
            "{head}{tri}{}",
            format!("f{}\n", " 1 2 3".repeat(333)).repeat(40)
        ),
    ));
    // convex n-gons: 10000 corners (refused), 1000 (split or kept, in bounded time)
    for n in [10_000, 1000] {
        let mut s = head.to_string();
        for i in 0..n {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            writeln!(s, "v {} {} 0", a.cos(), a.sin()).unwrap();
        }
        s.push('f');
        for i in 1..=n {
            write!(s, " {i}").unwrap();
        }
        s.push('\n');
        out.push((format!("convex-{n}-gon.obj"), s));
    }
    // 12000 coincident faces
    out.push((
        "coincident-faces.obj".into(),
        format!("{head}{tri}{}", "f 1 2 3\n".repeat(12_000)),
    ));
    // one 400 KB line
    out.push((
        "long-line.obj".into(),
        format!("{head}{tri}v 1 2 {}\n", "x".repeat(400_000)),
    ));
    // 100 stacked unit squares: 20k patches by default, more than the reference solver takes
    let mut stacked = head.to_string();
    for i in 0..100 {
        let z = i as f64 * 1e-3;
        writeln!(stacked, "v 0 0 {z}\nv 1 0 {z}\nv 1 1 {z}\nv 0 1 {z}").unwrap();
        let k = 4 * i + 1;
        writeln!(stacked, "f {} {} {} {}", k, k + 1, k + 2, k + 3).unwrap();
    }
    out.push(("stacked-squares.obj".into(), stacked));
    // glTF: 2000 nested nodes each with a mesh, and 50000 instances of one mesh
    let nested: Vec<String> = (0..2000)
        .map(|i| {
            let child = if i + 1 < 2000 {
                format!(",\"children\":[{}]", i + 1)
            } else {
                String::new()
            };
            format!("{{\"mesh\":0,\"translation\":[0.001,0,0]{child}}}")
        })
        .collect();
    out.push(("nested-nodes.gltf".into(), gltf(&nested.join(","), "0")));
    let instances = vec!["{\"mesh\":0}"; 50_000].join(",");
    let roots: Vec<String> = (0..50_000).map(|i| i.to_string()).collect();
    out.push(("instances.gltf".into(), gltf(&instances, &roots.join(","))));
    out
}

/// A glTF document of one emitting triangle mesh with these nodes and scene roots.
///
/// Its base colour is glTF's default white (reflectance 0.999 once repaired): the nested nodes'
/// 162k coplanar patches in the open once took 3800 shooting waves of `O(patches)` work for
/// 2e4 rays (25 s), planned by the mean reflectance; planned by the measured share of power
/// that returns, they take a few (0.4 s).
fn gltf(nodes: &str, roots: &str) -> String {
    // the triangle (0,0,0) (1,0,0) (0,1,0), 36 bytes
    let data = "AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA";
    format!(
        r#"{{"asset":{{"version":"2.0"}},
"buffers":[{{"byteLength":36,"uri":"data:application/octet-stream;base64,{data}"}}],
"bufferViews":[{{"buffer":0,"byteLength":36}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
"materials":[{{"emissiveFactor":[1,1,1],"pbrMetallicRoughness":{{"baseColorFactor":[1,1,1,1]}}}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"material":0}}]}}],
"nodes":[{nodes}],"scenes":[{{"nodes":[{roots}]}}],"scene":0}}"#
    )
}

#[test]
fn the_hostile_corpus_gives_results_or_one_clear_error_line() {
    let root = tempfile::tempdir().unwrap();
    let (dir, names) = corpus(root.path());
    assert!(names.len() >= 60, "{} files", names.len());
    let mut table = String::new();
    let mut failures = 0;
    for name in &names {
        let start = Instant::now();
        let run = solve(&dir, name, &[]);
        eprintln!("{name}: {:.2} s", start.elapsed().as_secs_f64());
        let line = check(name, &[], &run, &[0, 1]);
        if name.starts_with("outside-") {
            let line = line.as_deref().unwrap_or("(solved)");
            assert!(
                line.contains("outside the scene's folder") && line.contains(name.as_str()),
                "{name} must be refused for naming a file outside its folder: {line}"
            );
        }
        failures += usize::from(line.is_some());
        writeln!(table, "{name}: {}", line.as_deref().unwrap_or("ok")).unwrap();
    }
    // the messages of the reproducers of issue 18
    let expect = [
        (
            "far-triangle-1e38.obj",
            "vertex 1 has a coordinate beyond ±1e18",
        ),
        ("node-translation-1e38.gltf", "scale the scene down"),
        ("tiny-light.obj", "emitting face was dropped as degenerate"),
        (
            "huge-polygon.obj",
            "a face has 60000 vertices, more than the 1024 supported",
        ),
        ("convex-10000-gon.obj", "10000 vertices"),
        ("long-line.obj", "bytes)"),
        ("outside-mtllib-dev-zero.obj", "it is an absolute path"),
        ("outside-buffer-file-uri.gltf", "it is a file: URI"),
        ("outside-buffer-dotdot.gltf", "its '..' climbs out of it"),
    ];
    for (name, part) in expect {
        let line = table.lines().find(|l| l.starts_with(name)).unwrap();
        assert!(line.contains(part), "{line}\nshould contain {part:?}");
    }
    for name in [
        "coincident-faces.obj",
        "instances.gltf",
        "nested-nodes.gltf",
        "box.obj",
    ] {
        assert!(
            table.contains(&format!("{name}: ok")),
            "{name} should solve:\n{table}"
        );
    }
    assert!(failures > 40, "{failures} errors:\n{table}");
    eprintln!("{table}");
}

#[test]
fn hostile_options_are_refused_at_once_or_bounded() {
    let root = tempfile::tempdir().unwrap();
    let (dir, _) = corpus(root.path());
    let usage = [
        (&["--threads", "1000"][..], "1000 is not in 1..=256"),
        (&["--rays", "1e30"][..], "'1e30' is too large"),
        (&["--max-edge", "inf"][..], "not a positive finite length"),
    ];
    for (extra, part) in usage {
        let run = solve(&dir, "box.obj", extra);
        let line = check("box.obj", extra, &run, &[2]).unwrap();
        assert!(line.contains(part), "{line}");
    }
    // a device as the reference solution: refused, not read forever
    let extra = ["--reference", "/dev/zero", "--trace", "t.csv"];
    let line = check("box.obj", &extra, &solve(&dir, "box.obj", &extra), &[1]).unwrap();
    assert!(line.contains("/dev/zero is not a regular file"), "{line}");
    // millions of patches for the reference solver: refused before the mesh is built
    let extra = ["--method", "reference", "--max-edge", "0.0004"];
    let line = check("box.obj", &extra, &solve(&dir, "box.obj", &extra), &[1]).unwrap();
    assert!(line.contains("at most 10000 patches"), "{line}");
    assert!(line.contains("choose a larger --max-edge"), "{line}");
    // the user never passed --max-edge: the advice says what the default is
    let extra = ["--method", "reference"];
    let scene = "stacked-squares.obj";
    let line = check(scene, &extra, &solve(&dir, scene, &extra), &[1]).unwrap();
    assert!(line.contains("the default subdivision"), "{line}");
}

#[test]
fn outside_files_are_read_only_when_allowed_and_then_only_regular_files() {
    let root = tempfile::tempdir().unwrap();
    let (dir, _) = corpus(root.path());
    let allow = ["--allow-outside-paths"];
    for name in [
        "outside-mtllib-sentinel.obj",
        "outside-buffer-sentinel.gltf",
    ] {
        let run = solve(&dir, name, &allow);
        assert_eq!(check(name, &allow, &run, &[0]), None);
    }
    for name in [
        "outside-mtllib-dev-zero.obj",
        "outside-buffer-dev-zero.gltf",
    ] {
        let run = solve(&dir, name, &allow);
        let line = check(name, &allow, &run, &[1]).unwrap();
        assert!(line.contains("/dev/zero is not a regular file"), "{line}");
    }
}

#[test]
fn a_repeated_cause_is_found() {
    assert_eq!(
        repeats_a_cause("error: x.obj: the scene has no faces: the scene has no faces"),
        Some("the scene has no faces")
    );
    assert_eq!(
        repeats_a_cause("error: x.obj line 3: vertex 1 is bad"),
        None
    );
}
