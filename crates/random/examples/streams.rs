//! Random streams keyed by what they are for: the same key gives the same numbers whatever ran
//! before (so results do not depend on the thread count), different keys give independent ones.
//!
//! `cargo run --release -p mcrad-random --example streams`

use mcrad_random::{Stream, StreamKey};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // Seed 7, pass 0, patch 42, sub-stream 0: built positionally or field by field.
    let mut a = Stream::new(7, 0, 42, 0);
    let mut b = StreamKey::new(7).item(42).stream();
    let first: Vec<f64> = (0..3).map(|_| a.uniform_f64()).collect();
    let again: Vec<f64> = (0..3).map(|_| b.uniform_f64()).collect();
    println!("patch 42, pass 0:        {first:.6?}");
    println!(
        "the same key again:      {again:.6?} (equal: {})",
        first == again
    );

    let mut next = StreamKey::new(7).pass(1).item(42).stream();
    let next: Vec<f64> = (0..3).map(|_| next.uniform_f64()).collect();
    println!("patch 42, pass 1:        {next:.6?}");

    // A sub-run (a pass of a progressive schedule) derives its own seed from the run's.
    let sub = StreamKey::new(7).derive(3);
    println!("sub-run 3 of seed 7 has seed {:#018x}", sub.seed);

    // Many items, each with its own stream: the mean of their uniforms is 1/2.
    let n = 1_000_000u64;
    let sum: f64 = (0..n)
        .map(|item| StreamKey::new(7).item(item).stream().uniform_f64())
        .sum();
    println!(
        "mean of one uniform from each of {n} streams: {:.4}",
        sum / n as f64
    );
    Ok(())
}
