//! Tests of the constant control variate of patch gathering (`--control-variate constant`):
//! unbiased in open scenes (where RenderPark's is not), exact where gathering is, honest in its
//! variance, lower in variance where rays escape, and deterministic.
//!
//! Statistical tests run `RUNS = 16` independent seeds and compare with Student's t on 15
//! degrees of freedom: `P(|t| > 4) = 1.2e-3` per compared value.

use crate::{
    Context, ControlVariate, Emission, GatherConfig, Method, ScheduleConfig, gather, gather_round,
    run,
};
use glam::DVec3;
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_random::StreamKey;
use std::ops::ControlFlow;

use super::common;
use common::{bvh, furnace, mean_se, on_threads, parallel_squares};

const RUNS: u64 = 16;
const K: f64 = 4.0;

/// Mean and sample variance of `xs`.
fn mean_var(xs: &[f64]) -> (f64, f64) {
    let (mean, se) = mean_se(xs);
    (mean, se * se * xs.len() as f64)
}

/// `rounds` gathering rounds of `n` rays per patch from `input` on a fresh context with
/// `control`, seed `seed`; the last round.
fn last_round(
    mesh: &Mesh,
    control: ControlVariate,
    input: &[DVec3],
    rounds: u64,
    n: u32,
    seed: u64,
) -> mcrad_combine::Estimate {
    let bvh = bvh(mesh);
    let ctx = Context::new(mesh, &bvh).with_control_variate(control);
    let mut last = None;
    for pass in 0..rounds {
        let key = StreamKey::new(seed).pass(pass);
        last = Some(
            gather_round(&ctx, input, Emission::Include, n, key)
                .unwrap()
                .estimate,
        );
    }
    last.unwrap()
}

/// The receiver of two parallel unit squares sees the lamp (input 1) through `F = 0.199825` of
/// its hemisphere and nothing through the rest: RenderPark's control variate (coverage 1) would
/// give `rho · 1 = 0.5` there. Here the third round's value is `rho Ŝ` with `Ŝ` from the first
/// round: its mean over 16 seeds is `rho F` within K standard errors (one value: 0.12% false
/// failures), and its reported variance `rho² Ŝ (1 - Ŝ) / N` agrees with the spread between
/// seeds (the ratio of a 15-dof sample variance to its expectation lies in [0.33, 2.0] with
/// probability 0.99).
#[test]
fn unbiased_where_rays_escape_with_an_honest_variance() {
    let mesh = Mesh::build(&parallel_squares(), Subdivision::None).unwrap();
    let input = [DVec3::ONE, DVec3::ZERO];
    let (values, variances): (Vec<f64>, Vec<f64>) = (0..RUNS)
        .map(|seed| {
            let e = last_round(&mesh, ControlVariate::Constant, &input, 3, 256, seed);
            (e.radiosity()[1].x, e.variance().unwrap()[1].x)
        })
        .unzip();
    let exact = 0.5 * 0.199825;
    let (mean, spread) = mean_var(&values);
    let se = (spread / RUNS as f64).sqrt();
    assert!(se > 0.0);
    assert!(
        (mean - exact).abs() <= K * se,
        "receiver {mean:.5} vs rho F = {exact:.5}: {:.1} standard errors",
        (mean - exact).abs() / se
    );
    let reported = variances.iter().sum::<f64>() / RUNS as f64;
    let ratio = spread / reported;
    assert!(
        (0.33..=2.0).contains(&ratio),
        "spread {spread:.3e} / reported {reported:.3e} = {ratio:.2}"
    );
}

/// In a closed furnace every ray hits a front face, the coverage is exactly 1 and the control
/// changes nothing but rounding: the same values as plain gathering from a noisy input.
#[test]
fn changes_nothing_in_a_closed_scene() {
    let mesh = Mesh::build(&furnace(0.5), Subdivision::MaxEdge(0.5)).unwrap();
    let input: Vec<DVec3> = (0..mesh.patches().len())
        .map(|i| DVec3::new(1.0, 2.0, 3.0) * (1 + i % 4) as f64)
        .collect();
    let plain = last_round(&mesh, ControlVariate::Off, &input, 3, 64, 7);
    let controlled = last_round(&mesh, ControlVariate::Constant, &input, 3, 64, 7);
    for (a, b) in plain.radiosity().iter().zip(controlled.radiosity()) {
        assert!((*a - *b).abs().max_element() <= 1e-12 * a.abs().max_element());
    }
    for (a, b) in plain
        .variance()
        .unwrap()
        .iter()
        .zip(controlled.variance().unwrap())
    {
        assert!((*a - *b).abs().max_element() <= 1e-9 * a.abs().max_element().max(1e-300));
    }
}

/// Where rays escape, the control removes the hit-or-miss part of the variance: on the two
/// squares' receiver (input 1 on the lamp), plain gathering's per-ray variance is
/// `F (1 - F) = 0.16`, and the control removes the share `w = N / (N + n)` of it, `N` the rays
/// of all rounds but the last two, `n` the last round's. With 20 rounds the true ratio of the
/// variances is 19; the test asks the spread between seeds to be more than 4 times lower with
/// the control (fails when the ratio of two 15-dof sample variances falls below 4/19:
/// probability 0.2%).
#[test]
fn fewer_errors_where_rays_escape() {
    let mesh = Mesh::build(&parallel_squares(), Subdivision::None).unwrap();
    let input = [DVec3::ONE, DVec3::ZERO];
    let spread = |control| {
        let xs: Vec<f64> = (0..RUNS)
            .map(|seed| last_round(&mesh, control, &input, 20, 256, 100 + seed).radiosity()[1].x)
            .collect();
        mean_var(&xs).1
    };
    let (plain, controlled) = (
        spread(ControlVariate::Off),
        spread(ControlVariate::Constant),
    );
    assert!(
        controlled * 4.0 < plain,
        "spread controlled {controlled:.3e} vs plain {plain:.3e}"
    );
}

/// Jacobi gathering on an open scene with the control gives the same expected answer as
/// without: the means of 16 seeds differ by less than K of their combined standard errors
/// (Welch; two values compared: 0.3% false failures at about 30 degrees of freedom).
#[test]
fn jacobi_gathering_agrees_with_and_without_the_control() {
    let mesh = Mesh::build(&parallel_squares(), Subdivision::MaxEdge(0.5)).unwrap();
    let bvh = bvh(&mesh);
    let config = |seed| GatherConfig {
        rays: 4 * mesh.patches().len() as u64 * 64,
        rays_per_patch: 64,
        threshold: 0.0,
        seed,
    };
    let receiver_mean = |control| {
        let xs: Vec<f64> = (0..RUNS)
            .map(|seed| {
                let ctx = Context::new(&mesh, &bvh).with_control_variate(control);
                let g = gather(&ctx, &config(seed), &mut |_| ControlFlow::Continue(())).unwrap();
                assert_eq!(g.rounds, 4);
                // The receiver's patches (the lamp's emit and reflect nothing).
                mesh.patches()
                    .iter()
                    .zip(g.estimate.radiosity())
                    .filter(|(p, _)| p.emission.x == 0.0)
                    .map(|(p, b)| b.x * p.area)
                    .sum::<f64>()
            })
            .collect();
        mean_var(&xs)
    };
    let (a, va) = receiver_mean(ControlVariate::Off);
    let (b, vb) = receiver_mean(ControlVariate::Constant);
    let se = ((va + vb) / RUNS as f64).sqrt();
    assert!(
        (a - b).abs() <= K * se,
        "plain {a:.5} vs controlled {b:.5}: {:.1} standard errors",
        (a - b).abs() / se
    );
}

/// Same seed, same answer on one and two threads: the coverage is learned in round order.
#[test]
fn same_seed_same_answer_on_any_thread_count() {
    let mesh = Mesh::build(&parallel_squares(), Subdivision::MaxEdge(0.25)).unwrap();
    let bvh = bvh(&mesh);
    let solve = |threads| {
        on_threads(threads, || {
            let config = ScheduleConfig {
                rays: 400_000,
                seed: 5,
                control_variate: ControlVariate::Constant,
                ..Default::default()
            };
            run(Method::Combined, &mesh, &bvh, &config, &mut |_| {
                ControlFlow::Continue(())
            })
            .unwrap()
            .estimate
        })
    };
    assert_eq!(solve(1), solve(2));
}
