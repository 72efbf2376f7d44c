//! The layering written in ARCHITECTURE.md, checked against the workspace's manifests.
//!
//! The layer of every crate is read from the table between the `layering` markers of
//! ARCHITECTURE.md; the dependencies from `cargo metadata --no-deps`. A crate may depend
//! (normal and build dependencies) only on mcrad crates of a lower layer; `mcrad-combine` and
//! `mcrad-raycast` on no mcrad crate at all; `mcrad-lab` is a normal dependency of the CLI and
//! xtask only. A workspace crate without a row fails, so a new crate forces a rule.

use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// Crates that depend on no other mcrad crate (besides the layer rule).
const STANDALONE: [&str; 2] = ["mcrad-combine", "mcrad-raycast"];
/// The tooling crate, and the only packages that may have it as a normal dependency.
const LAB: &str = "mcrad-lab";
const LAB_USERS: [&str; 2] = ["mcrad", "xtask"];

/// A workspace package and its normal and build dependencies on other workspace packages.
struct Package {
    name: String,
    deps: Vec<String>,
}

/// The layer of every crate named in ARCHITECTURE.md's layering table.
fn layers(architecture: &str) -> BTreeMap<String, u32> {
    let begin = architecture
        .find("<!-- layering:")
        .expect("ARCHITECTURE.md has a layering table");
    let end = architecture
        .find("<!-- layering: end -->")
        .expect("the layering table ends");
    let mut layers = BTreeMap::new();
    for line in architecture[begin..end].lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        // `| layer | package | directory | holds |` -> ["", layer, package, ...]
        if cells.len() < 4 {
            continue;
        }
        let Ok(layer) = cells[1].parse::<u32>() else {
            continue;
        };
        let name = cells[2].trim_matches('`').to_string();
        assert!(
            layers.insert(name.clone(), layer).is_none(),
            "{name} has two rows"
        );
    }
    layers
}

/// Every rule the packages break, one line each.
fn violations(layers: &BTreeMap<String, u32>, packages: &[Package]) -> Vec<String> {
    let mut out = Vec::new();
    for p in packages {
        let Some(&layer) = layers.get(&p.name) else {
            out.push(format!(
                "{} has no row in ARCHITECTURE.md's layering table: give it a layer",
                p.name
            ));
            continue;
        };
        for d in &p.deps {
            match layers.get(d) {
                Some(&l) if l >= layer => out.push(format!(
                    "{} (layer {layer}) depends on {d} (layer {l}): dependencies point down",
                    p.name
                )),
                _ => {}
            }
            if STANDALONE.contains(&p.name.as_str()) {
                out.push(format!(
                    "{} depends on {d}: it depends on no mcrad crate",
                    p.name
                ));
            }
            if d == LAB && !LAB_USERS.contains(&p.name.as_str()) {
                out.push(format!(
                    "{} depends on {LAB}: only {LAB_USERS:?} may (libraries: in tests only)",
                    p.name
                ));
            }
        }
    }
    out
}

/// The workspace's packages from `cargo metadata --no-deps`.
fn workspace() -> Vec<Package> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml");
    let out = Command::new(cargo)
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .arg("--manifest-path")
        .arg(&manifest)
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: Value = serde_json::from_slice(&out.stdout).unwrap();
    let packages = meta["packages"].as_array().unwrap();
    let names: Vec<&str> = packages
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    packages
        .iter()
        .map(|p| Package {
            name: p["name"].as_str().unwrap().to_string(),
            deps: p["dependencies"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|d| d["kind"].as_str() != Some("dev"))
                .map(|d| d["name"].as_str().unwrap())
                .filter(|n| names.contains(n))
                .map(str::to_string)
                .collect(),
        })
        .collect()
}

fn architecture() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("ARCHITECTURE.md")).unwrap()
}

#[test]
fn every_crate_depends_only_on_lower_layers() {
    let layers = layers(&architecture());
    let packages = workspace();
    assert!(packages.len() >= 8, "{} packages", packages.len());
    let v = violations(&layers, &packages);
    assert!(v.is_empty(), "layering broken:\n{}", v.join("\n"));
}

#[test]
fn the_table_names_the_crates_of_the_design() {
    let layers = layers(&architecture());
    for name in [
        "mcrad-scene-io",
        "mcrad-meshing",
        "mcrad-raycast",
        "mcrad-combine",
        "mcrad-mc-radiosity",
        "mcrad",
    ] {
        assert!(layers.contains_key(name), "{name} missing: {layers:?}");
    }
    assert!(layers["mcrad-combine"] < layers["mcrad-mc-radiosity"]);
    assert!(layers["mcrad-mc-radiosity"] < layers["mcrad"]);
}

/// The checker itself can fail: each kind of broken rule is reported.
#[test]
fn broken_layering_is_reported() {
    let layers = layers(&architecture());
    let p = |name: &str, deps: &[&str]| Package {
        name: name.into(),
        deps: deps.iter().map(|d| d.to_string()).collect(),
    };
    let ok = [
        p("mcrad-meshing", &["mcrad-scene-io"]),
        p("mcrad", &["mcrad-mc-radiosity", "mcrad-lab"]),
    ];
    assert!(violations(&layers, &ok).is_empty());
    for (bad, says) in [
        (
            p("mcrad-meshing", &["mcrad-mc-radiosity"]),
            "dependencies point down",
        ),
        (
            p("mcrad-render", &["mcrad-export"]),
            "dependencies point down",
        ),
        (p("mcrad-combine", &["mcrad-random"]), "no mcrad crate"),
        (p("mcrad-mc-radiosity", &["mcrad-lab"]), "only"),
        (p("mcrad-something-new", &[]), "no row"),
    ] {
        let v = violations(&layers, std::slice::from_ref(&bad));
        assert!(v.iter().any(|m| m.contains(says)), "{}: {v:?}", bad.name);
    }
}
