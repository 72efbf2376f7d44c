//! `cargo xtask experiment speed-vs-error`: every method on every experiment scene, error
//! against time.

pub mod scenes;
