//! The README's two commands share one build. `cargo run --release` compiles the CLI's
//! dependencies with the features the CLI's dependency graph asks for; `cargo test --workspace
//! --release` unifies features over every package and its dev-dependencies. Where the two
//! disagree on a crate, the test build compiles it, and every crate above it, a second time
//! (measured: 57 crates and 22 minutes on a loaded 2-core machine). The feature pins in the root
//! `Cargo.toml` keep them equal; this test says which pin is missing when a dependency changes.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// Crates allowed to differ, with the reason: their rebuild is small and the alternative is worse.
const ALLOWED: [(&str, &str); 1] = [(
    "mcrad-lab",
    "xtask turns on `plot`; pinning it would link plotters into the CLI (lab and the CLI relink)",
)];

/// `package -> features` of one `cargo tree` over the root package, or the whole workspace.
fn features(workspace: bool) -> BTreeMap<String, String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml");
    let mut cmd = Command::new(cargo);
    cmd.args(["tree", "--offline", "--prefix", "none", "-f", "{p}|{f}"])
        .arg("--manifest-path")
        .arg(&manifest);
    if workspace {
        cmd.args(["--workspace", "-e", "normal,build,dev"]);
    } else {
        cmd.args(["-p", "mcrad", "-e", "normal,build"]);
    }
    let out = cmd.output().expect("cargo tree runs");
    assert!(
        out.status.success(),
        "cargo tree failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    parse(&String::from_utf8_lossy(&out.stdout))
}

/// Parses `cargo tree -f "{p}|{f}"` lines into `name version -> features`.
fn parse(text: &str) -> BTreeMap<String, String> {
    text.lines()
        .filter_map(|line| {
            let (package, features) = line.split_once('|')?;
            let mut words = package.split_whitespace();
            let key = format!("{} {}", words.next()?, words.next()?);
            Some((key, features.trim_end_matches(" (*)").trim().to_string()))
        })
        .collect()
}

/// The crates of the CLI's build whose features the workspace build changes, but for
/// [`ALLOWED`].
fn disagreements(
    root: &BTreeMap<String, String>,
    workspace: &BTreeMap<String, String>,
) -> Vec<String> {
    root.iter()
        .filter(|(package, _)| {
            !ALLOWED
                .iter()
                .any(|(name, _)| package.starts_with(&format!("{name} ")))
        })
        .filter_map(|(package, features)| {
            let other = workspace.get(package)?;
            (other != features).then(|| {
                format!("{package}: the CLI's build has [{features}], the test build [{other}]")
            })
        })
        .collect()
}

#[test]
fn the_test_build_reuses_the_release_build() {
    let found = disagreements(&features(false), &features(true));
    assert!(
        found.is_empty(),
        "pin these features in the root Cargo.toml:\n{}",
        found.join("\n")
    );
}

#[test]
fn a_difference_is_reported() {
    let root = parse("once_cell v1.21.4|alloc,race\nmcrad-lab v0.1.0 (crates/lab)|default\n");
    let workspace = parse(
        "once_cell v1.21.4|alloc,default,race,std\nmcrad-lab v0.1.0 (crates/lab)|default,plot (*)\n",
    );
    let found = disagreements(&root, &workspace);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(found[0].starts_with("once_cell v1.21.4"), "{found:?}");
    assert!(disagreements(&root, &root).is_empty());
}
