//! The quasi-Monte Carlo sampler (`Sampler::Qmc`) against exact answers, against the random
//! sampler, and across thread counts.
//!
//! Statistics as in `tests/shooting.rs`: `RUNS = 16` seeds (independent scrambles), the mean
//! compared with the exact value in units of the standard error measured across the runs, a
//! Student-t with 15 degrees of freedom; each test states its `K` and false-failure rate.

use super::common;

use crate::{Context, Sampler, ShootConfig, shoot};
use crate::{Method, ScheduleConfig, run};
use common::{bvh, estimate, furnace, mean_se, on_threads, parallel_squares, spread_over_reported};
use glam::DVec3;
use mcrad_meshing::{Mesh, Subdivision};
use std::ops::ControlFlow;

const RUNS: u64 = 16;

/// The receiver's radiosity of `RUNS` shooting runs of 65 536 rays (one block of the emitter's
/// sequence) with `sampler`.
fn receiver_runs(sampler: Sampler) -> Vec<f64> {
    let mesh = Mesh::build(&parallel_squares(), Subdivision::None).unwrap();
    let bvh = bvh(&mesh);
    let ctx = Context::new(&mesh, &bvh).with_sampler(sampler);
    (0..RUNS)
        .map(|seed| {
            let config = ShootConfig {
                rays: 1 << 16,
                unshot_threshold: 0.0,
                seed: 1000 + seed,
                ..Default::default()
            };
            let r = shoot(&ctx, &config, &mut |_| ControlFlow::Continue(())).unwrap();
            r.estimate.radiosity()[1].x
        })
        .collect()
}

/// Unbiased: the receiver's mean over 16 scrambles is `rho F` within K = 4 standard errors
/// (`P(|t_15| > 4) = 1.2e-3`: one compared value). And stratified: the spread between
/// scrambles is far below the random sampler's. For independent rays the variances' ratio
/// is `F(15, 15)`-distributed about 1; the test asks the random runs' variance to be more than
/// 4 times the QMC runs' (for equal true variances `P(F_{15,15} > 4) = 0.0053`, so a sampler
/// that lost its stratification fails with probability 0.995; measured ratio: see the message).
#[test]
fn qmc_shooting_exchanges_the_analytic_form_factor_with_less_spread() {
    let exact = 0.5 * 0.199825;
    let qmc = receiver_runs(Sampler::Qmc);
    let (mean, se) = mean_se(&qmc);
    assert!(se > 0.0, "the scrambles must differ");
    assert!(
        (mean - exact).abs() <= 4.0 * se,
        "qmc: {mean} vs {exact}: {:.2} standard errors ({se:.2e})",
        (mean - exact).abs() / se
    );
    let random = receiver_runs(Sampler::Random);
    let (_, se_random) = mean_se(&random);
    let ratio = (se_random / se).powi(2);
    eprintln!("parallel squares, 65 536 rays: variance random / qmc = {ratio:.1}");
    assert!(ratio > 4.0, "variance random / qmc only {ratio}");
}

/// The closed furnace under every sampler-using schedule: `B = E / (1 - rho) = 2` exactly on
/// every patch. Per method and patch (24 patches, red channel) the mean over 16 seeds is within
/// K = 4.5 standard errors: `P(|t_15| > 4.5) = 4.2e-4` per value, 3 x 24 = 72 values, a
/// false-failure rate of at most 3%, once, for these fixed seeds (reproducible).
#[test]
fn qmc_schedules_give_the_closed_furnace_exactly_in_expectation() {
    let mesh = Mesh::build(&furnace(0.5), Subdivision::MaxEdge(0.5)).unwrap();
    assert_eq!(mesh.patches().len(), 24);
    let bvh = bvh(&mesh);
    for method in [Method::Shoot, Method::Prr, Method::Combined] {
        let runs: Vec<Vec<f64>> = (0..RUNS)
            .map(|seed| {
                let config = ScheduleConfig {
                    rays: 100_000,
                    seed: 77 + seed,
                    sampler: Sampler::Qmc,
                    ..Default::default()
                };
                run(method, &mesh, &bvh, &config, &mut |_| {
                    ControlFlow::Continue(())
                })
                .unwrap()
                .estimate
                .radiosity()
                .iter()
                .map(|b| b.x)
                .collect()
            })
            .collect();
        for i in 0..mesh.patches().len() {
            let xs: Vec<f64> = runs.iter().map(|r| r[i]).collect();
            let (mean, se) = mean_se(&xs);
            assert!(se > 0.0, "{method:?} patch {i}: no spread");
            assert!(
                (mean - 2.0).abs() <= 4.5 * se,
                "{method:?} patch {i}: {mean} vs 2, {:.2} standard errors ({se:.2e})",
                (mean - 2.0).abs() / se
            );
        }
    }
}

/// Same seed, same answer on one or two threads under QMC (shooting, gathering and the direct
/// light all run in `combined` and `two-pass-split`), and the sampler changes the answer.
#[test]
fn qmc_is_the_same_on_one_or_two_threads() {
    let scene = mcrad_scene_io::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.obj"),
    )
    .unwrap()
    .scene;
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.1)).unwrap();
    let bvh = bvh(&mesh);
    for method in [Method::Combined, Method::TwoPassSplit] {
        let solve = |threads: usize, sampler: Sampler| -> (Vec<DVec3>, Vec<DVec3>) {
            let config = ScheduleConfig {
                rays: 300_000,
                seed: 5,
                sampler,
                ..Default::default()
            };
            on_threads(threads, || estimate(method, &mesh, &bvh, &config))
        };
        let one = solve(1, Sampler::Qmc);
        assert_eq!(one, solve(2, Sampler::Qmc), "{method:?}");
        assert_ne!(one.0, solve(2, Sampler::Random).0, "{method:?}");
    }
}

/// Honest variances under QMC (issue 17): the variances the estimators report assume
/// independent rays, which overstates the stratified rays' error (two-pass-split reported 3.4x
/// its spread between seeds, shooting 1.4x); scaled by the gain the sequences' two interleaved
/// scrambles measure per face, they match it. A furnace of 8 x 8 patches a face, 16 seeds: the
/// pooled spread between seeds / mean reported variance within [0.67, 1.5], the issue's
/// target. Measured (seeds 7000-7015): shoot 1.01, two-pass-split 0.76, combined 0.70 (the
/// gathering methods stay a little conservative in a furnace, as under independent rays:
/// calibrate's furnace-0.5 gives combined 0.86 with random rays); the old code gave
/// two-pass-split 0.29. Fixed seeds: reproducible.
#[test]
fn qmc_variances_match_the_spread_between_seeds() {
    let mesh = Mesh::build(&furnace(0.5), Subdivision::MaxEdge(0.125)).unwrap();
    assert_eq!(mesh.patches().len(), 384);
    let bvh = bvh(&mesh);
    for method in [Method::Shoot, Method::TwoPassSplit, Method::Combined] {
        let runs: Vec<(Vec<DVec3>, Vec<DVec3>)> = (0..RUNS)
            .map(|seed| {
                let config = ScheduleConfig {
                    rays: 100_000,
                    seed: 7000 + seed,
                    sampler: Sampler::Qmc,
                    ..Default::default()
                };
                estimate(method, &mesh, &bvh, &config)
            })
            .collect();
        let ratio = spread_over_reported(runs.iter().map(|r| (&r.0[..], &r.1[..])));
        eprintln!("{method:?}: spread between seeds / reported variance {ratio:.3}");
        assert!(
            (0.67..=1.5).contains(&ratio),
            "{method:?}: spread between seeds / reported variance {ratio:.3}"
        );
    }
}
