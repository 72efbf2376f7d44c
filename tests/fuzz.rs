//! A seeded fuzzer of the whole pipeline on stable Rust: the corpus of `tests/hostile/` and the
//! bundled scenes, mutated (hostile numbers, byte flips, deleted, repeated and truncated
//! spans, hostile statements), each loaded, meshed, put in a BVH and solved in-process on a
//! tiny budget by a method of the registry. Every step may refuse its input; none may panic.
//!
//! The normal test suite runs [`DEFAULT_CASES`] cases (a few seconds); `MCRAD_FUZZ_CASES=N`
//! runs more and `MCRAD_FUZZ_SEED=S` others (the seed and case of a failure are printed, and
//! the input is kept in `fuzz-failures/` under Cargo's test scratch directory, to be added to
//! the corpus); `MCRAD_FUZZ_VERBOSE=1` prints why each refused input was refused.

use mcrad_mc_radiosity::{Kind, Method, ScheduleConfig};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_random::Stream;
use mcrad_raycast::Bvh;
use std::ops::ControlFlow;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};

/// Cases of a normal test run.
const DEFAULT_CASES: u64 = 600;

/// The most patches a case solves (more are meshed, then skipped: this is about input
/// handling, not speed).
const MAX_SOLVED_PATCHES: usize = 5_000;

/// Numbers that have broken or could break a loader or a solver.
const HOSTILE_NUMBERS: &[&str] = &[
    "0",
    "-0",
    "-1",
    "1e38",
    "-1e38",
    "3.4028235e38",
    "3.5e38",
    "1e18",
    "1e19",
    "1e-38",
    "1e-45",
    "nan",
    "inf",
    "-inf",
    "4294967295",
    "4294967296",
    "2147483648",
    "18446744073709551615",
    "99999999999999999999",
    "0.999",
    "1",
    "1.0",
    "2",
    "1e7",
    "1e-12",
    "0x10",
    "",
];

/// Statements and fragments inserted whole.
const HOSTILE_TOKENS: &[&str] = &[
    "\n",
    "\r",
    "\0",
    "\u{1b}[2J",
    "\u{fffd}",
    " ",
    "/",
    "#",
    "\nf 1 2 3 1 2 3 1 2 3 1 2 3\n",
    "\nf -1 -2 -3\n",
    "\nv 1e38 1e38 1e38\n",
    "\nmtllib /dev/zero\n",
    "\nmtllib ../../../../../../etc/passwd\n",
    "\nmtllib .\n",
    "\nusemtl\n",
    "\nusemtl lamp\n",
    "\nKd 1 1 1\n",
    "\nKe -1 0 0\n",
    "\nnewmtl lamp\n",
    "\"uri\":\"/dev/zero\",",
    "\"uri\":\"file:///etc/passwd\",",
    "\"children\":[0],",
    "\"matrix\":[0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0],",
    "\"mode\":0,",
    "{",
    "}",
    "[",
    "]",
    "\"",
    ",",
];

/// A small random source: one stream per case, from the fuzz seed.
struct Rng(Stream);

impl Rng {
    /// A uniform integer in `0..n` (`n > 0`).
    fn below(&mut self, n: usize) -> usize {
        ((self.0.uniform_f64() * n as f64) as usize).min(n - 1)
    }
}

/// Numbers JSON accepts (glTF mutants stay parseable more often).
fn json_number(n: &str) -> bool {
    !n.is_empty() && !n.starts_with("0x") && !n.contains("nan") && !n.contains("inf")
}

/// Applies `count` random mutations to `bytes` (`json`: keep numbers JSON).
fn mutate(bytes: &mut Vec<u8>, rng: &mut Rng, count: usize, json: bool) {
    for _ in 0..count {
        let len = bytes.len();
        match rng.below(7) {
            // a number replaced by a hostile one
            0 | 1 => {
                let starts: Vec<usize> = (0..len)
                    .filter(|&i| {
                        bytes[i].is_ascii_digit() && (i == 0 || !bytes[i - 1].is_ascii_digit())
                    })
                    .collect();
                if starts.is_empty() {
                    continue;
                }
                let mut start = starts[rng.below(starts.len())];
                let end = (start..len)
                    .find(|&i| !(bytes[i].is_ascii_digit() || b".eE-+".contains(&bytes[i])))
                    .unwrap_or(len);
                if start > 0 && bytes[start - 1] == b'-' {
                    start -= 1;
                }
                let numbers: Vec<&str> = HOSTILE_NUMBERS
                    .iter()
                    .copied()
                    .filter(|n| !json || json_number(n))
                    .collect();
                let number = numbers[rng.below(numbers.len())];
                bytes.splice(start..end, number.bytes());
            }
            // a byte changed
            2 if len > 0 => {
                let at = rng.below(len);
                bytes[at] = rng.below(256) as u8;
            }
            // a span deleted
            3 if len > 0 => {
                let at = rng.below(len);
                let end = (at + 1 + rng.below(64)).min(len);
                bytes.drain(at..end);
            }
            // a span repeated (long faces, repeated statements, nested brackets)
            4 if len > 0 => {
                let at = rng.below(len);
                let end = (at + 1 + rng.below(256)).min(len);
                let span = bytes[at..end].to_vec();
                for _ in 0..1 + rng.below(8) {
                    bytes.splice(end..end, span.iter().copied());
                }
            }
            // cut short
            5 if len > 0 => bytes.truncate(rng.below(len)),
            // a hostile statement inserted
            _ => {
                let at = rng.below(len + 1);
                let token = HOSTILE_TOKENS[rng.below(HOSTILE_TOKENS.len())];
                bytes.splice(at..at, token.bytes());
            }
        }
    }
}

/// How far a case got.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Reached {
    Refused,
    Loaded,
    Meshed,
    Built,
    Solved,
}

/// Loads, meshes, builds and solves `scene` on a tiny budget; errors anywhere are fine.
fn pipeline(scene: &Path, method: Method, seed: u64) -> Reached {
    let loaded = match mcrad_scene_io::load(scene) {
        Ok(l) => l,
        Err(e) => {
            if std::env::var("MCRAD_FUZZ_VERBOSE").is_ok() {
                eprintln!("refused: {e}");
            }
            return Reached::Refused;
        }
    };
    let subdivision = match seed % 3 {
        0 => Subdivision::None,
        _ => Subdivision::default_for(&loaded.scene),
    };
    let limit = if method.kind() == Kind::Deterministic {
        100
    } else {
        MAX_SOLVED_PATCHES
    };
    let Ok(mesh) = Mesh::build_at_most(&loaded.scene, subdivision, limit) else {
        return Reached::Loaded;
    };
    let Ok(bvh) = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()) else {
        return Reached::Meshed;
    };
    let config = ScheduleConfig {
        rays: 500 + seed % 4000,
        seed,
        // the reference solver to a rough tolerance (1e-4 takes seconds on a small light)
        reference: mcrad_reference::ReferenceConfig {
            visibility_tolerance: 0.1,
            ..Default::default()
        },
        ..ScheduleConfig::default()
    };
    match mcrad_mc_radiosity::run(method, &mesh, &bvh, &config, &mut |_| {
        ControlFlow::Continue(())
    }) {
        Ok(_) => Reached::Solved,
        Err(_) => Reached::Built,
    }
}

/// The scene files to mutate (`.obj`, `.gltf`, `.glb`) and the directory of their companions.
fn seeds() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files: Vec<PathBuf> = std::fs::read_dir(root.join("tests/hostile"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("");
            ["obj", "gltf", "glb", "mtl"].contains(&ext)
        })
        .collect();
    files.push(root.join("scenes/furnace.obj"));
    files.push(root.join("scenes/cornell-small-light.obj"));
    files.sort();
    files
}

#[test]
fn mutated_scenes_never_panic_any_stage() {
    let cases: u64 = std::env::var("MCRAD_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(DEFAULT_CASES);
    let fuzz_seed: u64 = std::env::var("MCRAD_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(18);
    let seeds = seeds();
    let dir = tempfile::tempdir().unwrap();
    // the corpus and the bundled scenes' material libraries, for the mutants to name
    for file in &seeds {
        std::fs::copy(file, dir.path().join(file.file_name().unwrap())).unwrap();
    }
    for mtl in ["cornell-small-light.mtl", "furnace.mtl"] {
        let from = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scenes")
            .join(mtl);
        if from.exists() {
            std::fs::copy(from, dir.path().join(mtl)).unwrap();
        }
    }
    let scenes: Vec<&PathBuf> = seeds
        .iter()
        .filter(|p| p.extension().is_some_and(|e| e != "mtl"))
        .collect();
    // most of the corpus is refused as it is: three cases in four mutate a scene that loads
    let valid: Vec<&PathBuf> = scenes
        .iter()
        .copied()
        .filter(|p| mcrad_scene_io::load(&dir.path().join(p.file_name().unwrap())).is_ok())
        .collect();
    assert!(valid.len() >= 5, "{valid:?}");
    if std::env::var("MCRAD_FUZZ_VERBOSE").is_ok() {
        eprintln!("valid: {valid:?}");
    }
    let mtls: Vec<&PathBuf> = seeds
        .iter()
        .filter(|p| p.extension().is_some_and(|e| e == "mtl"))
        .collect();
    let mut failures = Vec::new();
    let mut reached = std::collections::BTreeMap::new();
    for case in 0..cases {
        let mut rng = Rng(Stream::new(fuzz_seed, 0, case, 0));
        let base = if rng.below(4) == 0 {
            scenes[rng.below(scenes.len())]
        } else {
            valid[rng.below(valid.len())]
        };
        let ext = base.extension().unwrap().to_string_lossy().into_owned();
        let mut bytes = std::fs::read(base).unwrap();
        let scene = dir.path().join(format!("case.{ext}"));
        let text = String::from_utf8_lossy(&bytes).into_owned();
        let own_mtl = text
            .lines()
            .find_map(|l| l.strip_prefix("mtllib "))
            .map(|name| dir.path().join(name.trim()))
            .filter(|p| p.is_file());
        if let (true, Some(own)) = (ext == "obj" && rng.below(4) == 0, own_mtl) {
            // mutate its material library (or, more rarely, another one) instead, and name it
            let mtl = if rng.below(4) == 0 {
                mtls[rng.below(mtls.len())].clone()
            } else {
                own
            };
            let mut lib = std::fs::read(mtl).unwrap();
            let count = 1 + rng.below(2);
            mutate(&mut lib, &mut rng, count, false);
            std::fs::write(dir.path().join("case.mtl"), lib).unwrap();
            let named: String = text
                .lines()
                .map(|l| {
                    if l.starts_with("mtllib") {
                        "mtllib case.mtl"
                    } else {
                        l
                    }
                })
                .collect::<Vec<_>>()
                .join("\n");
            bytes = named.into_bytes();
        } else {
            // mostly one mutation: more rarely leave a file that loads
            let count = [1, 1, 1, 2, 2, 3, 4][rng.below(7)];
            mutate(&mut bytes, &mut rng, count, ext == "gltf");
        }
        std::fs::write(&scene, &bytes).unwrap();
        let method = Method::ALL[rng.below(Method::ALL.len())];
        let start = std::time::Instant::now();
        let outcome = catch_unwind(AssertUnwindSafe(|| pipeline(&scene, method, case)));
        if std::env::var("MCRAD_FUZZ_VERBOSE").is_ok() {
            eprintln!(
                "case {case}: {} {method}, {:.3} s, {outcome:?}",
                base.display(),
                start.elapsed().as_secs_f64()
            );
        }
        if let Ok(r) = outcome {
            *reached.entry(r).or_insert(0u64) += 1;
        } else {
            let keep = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fuzz-failures");
            std::fs::create_dir_all(&keep).unwrap();
            let kept = keep.join(format!("seed{fuzz_seed}-case{case}.{ext}"));
            std::fs::write(&kept, &bytes).unwrap();
            failures.push(format!(
                "case {case} (from {}, --method {method}): a panic; input kept in {}",
                base.display(),
                kept.display()
            ));
        }
    }
    eprintln!("{cases} cases: {reached:?}");
    // the mutants reach every stage (a fuzzer whose inputs all fail to load tests little)
    let solved = reached.get(&Reached::Solved).copied().unwrap_or(0);
    assert!(
        solved * 20 >= cases,
        "only {solved} of {cases} cases solved: {reached:?}"
    );
    assert!(
        failures.is_empty(),
        "{} of {cases} cases panicked (MCRAD_FUZZ_SEED={fuzz_seed}):\n{}",
        failures.len(),
        failures.join("\n")
    );
}
