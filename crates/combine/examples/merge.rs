//! Merges two independent noisy estimates of the same three patches, by rays and by inverse
//! variance, and measures each against the exact answer with `rms_rel`. The estimates are made
//! up here (means of random samples around a known radiosity); in mcrad they come from the
//! estimators of `mcrad-mc-radiosity`.
//!
//! `cargo run --release -p mcrad-combine --example merge`

use glam::DVec3;
use mcrad_combine::{ByRays, Estimate, InverseVariance, merge, rms_rel};
use mcrad_random::StreamKey;

/// The exact radiosity `B_i` of three patches, W/m² (RGB).
const EXACT: [DVec3; 3] = [
    DVec3::new(1.0, 0.8, 0.6),
    DVec3::new(2.0, 2.0, 2.0),
    DVec3::new(0.5, 0.1, 0.1),
];

/// An unbiased estimate from `samples` samples per patch and channel, each `2 u B` with `u`
/// uniform in [0, 1): the mean of the samples, and the sample variance of that mean.
fn noisy(seed: u64, samples: u64) -> Result<Estimate, Box<dyn std::error::Error>> {
    let (mut value, mut variance) = (Vec::new(), Vec::new());
    for (i, exact) in EXACT.iter().enumerate() {
        let mut rng = StreamKey::new(seed).item(i as u64).stream();
        let (mut mean, mut var) = (DVec3::ZERO, DVec3::ZERO);
        for c in 0..3 {
            let xs: Vec<f64> = (0..samples)
                .map(|_| 2.0 * rng.uniform_f64() * exact[c])
                .collect();
            let m = xs.iter().sum::<f64>() / samples as f64;
            let s2 = xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (samples - 1) as f64;
            mean[c] = m;
            var[c] = s2 / samples as f64;
        }
        value.push(mean);
        variance.push(var);
    }
    Ok(Estimate::new(
        value,
        Some(variance),
        samples * EXACT.len() as u64,
    )?)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let area = [1.0, 0.5, 2.0]; // A_i, units²
    let emission = [DVec3::ZERO; 3]; // E_i, W/m²: nothing emits, all light is "reflected"
    let error = |e: &Estimate| rms_rel(&area, &emission, e.radiosity(), &EXACT);

    // One pair of estimates, merged both ways.
    let a = noisy(1, 100)?;
    let b = noisy(2, 400)?;
    let by_rays = merge(&a, &b, &ByRays)?;
    let by_variance = merge(&a, &b, &InverseVariance)?;
    let named = [
        ("a", &a),
        ("b", &b),
        ("a + b by rays", &by_rays),
        ("a + b by inverse variance", &by_variance),
    ];
    for (name, e) in named {
        println!(
            "{name:<26} {:>5} rays, patch 1: B = {:.3} W/m², rms_rel {:.4}",
            e.rays(),
            e.radiosity()[1],
            error(e)
        );
    }

    // One pair is luck; over many pairs, merging beats either input.
    let trials = 200;
    let mut mean = [0.0; 4];
    for t in 0..trials {
        let a = noisy(2 * t + 1, 100)?;
        let b = noisy(2 * t + 2, 400)?;
        let merged = [merge(&a, &b, &ByRays)?, merge(&a, &b, &InverseVariance)?];
        for (m, e) in mean.iter_mut().zip([&a, &b, &merged[0], &merged[1]]) {
            *m += error(e) / trials as f64;
        }
    }
    println!(
        "mean rms_rel over {trials} pairs: a {:.4}, b {:.4}, by rays {:.4}, by inverse \
         variance {:.4}",
        mean[0], mean[1], mean[2], mean[3]
    );
    Ok(())
}
