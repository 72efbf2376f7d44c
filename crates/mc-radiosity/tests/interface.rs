//! The crate's public interface stays narrow (issue 33): every public item is re-exported once
//! at the root from a private module, and there are at most [`MOST_NAMES`] of them. Read from
//! `src/lib.rs` as text: a `pub mod`, a `pub fn` or `pub struct` written in `lib.rs` itself, or
//! a 31st name fails here.

/// The most public names the crate may have.
const MOST_NAMES: usize = 30;

#[test]
fn the_public_interface_is_flat_and_at_most_thirty_names() {
    let lib = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/src/lib.rs")).unwrap();
    // statements outside comments, joined (a `pub use` may span lines)
    let code: String = lib
        .lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join(" ");
    for item in [
        "pub mod ",
        "pub fn ",
        "pub struct ",
        "pub enum ",
        "pub const ",
        "pub type ",
    ] {
        assert!(
            !code.contains(item),
            "lib.rs declares `{item}`: public items live in private modules and are re-exported"
        );
    }
    let mut names = Vec::new();
    for statement in code.split(';') {
        let Some(rest) = statement.trim().strip_prefix("pub use ") else {
            continue;
        };
        let list = match (rest.find('{'), rest.rfind('}')) {
            (Some(a), Some(b)) => &rest[a + 1..b],
            _ => rest.rsplit("::").next().unwrap_or(rest),
        };
        names.extend(
            list.split(',')
                .map(|n| {
                    n.trim()
                        .rsplit(" as ")
                        .next()
                        .unwrap_or("")
                        .trim()
                        .to_string()
                })
                .filter(|n| !n.is_empty()),
        );
    }
    let mut unique = names.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(
        unique.len(),
        names.len(),
        "a name re-exported twice: {names:?}"
    );
    assert!(names.contains(&"run".to_string()) && names.contains(&"Method".to_string()));
    assert!(
        names.len() <= MOST_NAMES,
        "{} public names (at most {MOST_NAMES}): {names:?}",
        names.len()
    );
}
