//! Algorithm 4 with a weighting of the caller's choice ([`run_combined_with`]): a weighting
//! defined here runs through it and gives the furnace's exact answer, and the weighting given
//! is the one used.
//!
//! The closed furnace: every patch emits `E = 1` and reflects `rho = 0.5`, so the exact answer
//! is `B = E / (1 - rho) = 2` W/m² everywhere. Tolerance: the mean over `SEEDS` fixed seeds of
//! one patch's value is within `K = 4` standard errors of 2, the standard error measured from
//! the spread between the seeds (Student t with 15 degrees of freedom: `P(|t| > 4) ≈ 1e-3`).

use super::common::{bvh, furnace, mean_se};
use crate::{Method, ScheduleConfig, run, run_combined_with};
use mcrad_combine::{InverseExpectedVariance, Operand, Weighting};
use mcrad_meshing::{Mesh, Subdivision};
use std::ops::ControlFlow;

const SEEDS: u64 = 16;
/// Standard errors allowed (see the module documentation).
const K: f64 = 4.0;
const RHO: f32 = 0.5;
const RAYS: u64 = 100_000;

/// Weights by the rays behind each operand, `w_a = n_a / (n_a + n_b)` (1/2 when both are 0):
/// written here, not taken from `mcrad_combine`, to show a new rule runs through Algorithm 4.
struct ByTheirRays;

impl Weighting for ByTheirRays {
    fn weight(&self, a: &Operand, b: &Operand, _patch: usize, _channel: usize) -> f64 {
        let (na, nb) = (a.estimate.rays() as f64, b.estimate.rays() as f64);
        if na + nb == 0.0 { 0.5 } else { na / (na + nb) }
    }
}

/// Always the first operand (Algorithm 4's shooting estimate): degenerate, but unbiased.
struct ShootingOnly;

impl Weighting for ShootingOnly {
    fn weight(&self, _a: &Operand, _b: &Operand, _patch: usize, _channel: usize) -> f64 {
        1.0
    }
}

fn furnace_mesh() -> Mesh {
    Mesh::build(&furnace(RHO), Subdivision::MaxEdge(0.5)).unwrap()
}

fn config(seed: u64) -> ScheduleConfig {
    ScheduleConfig {
        rays: RAYS,
        seed,
        ..Default::default()
    }
}

#[test]
fn a_new_weighting_through_algorithm_4_gives_the_furnace_answer() {
    let mesh = furnace_mesh();
    let bvh = bvh(&mesh);
    let exact = 1.0 / (1.0 - RHO as f64);
    let values: Vec<f64> = (0..SEEDS)
        .map(|seed| {
            let s = run_combined_with(&mesh, &bvh, &config(seed), &ByTheirRays, &mut |_| {
                ControlFlow::Continue(())
            })
            .unwrap();
            assert!(s.steps >= 2, "Algorithm 4 merged more than one pass");
            s.estimate.radiosity()[0].x
        })
        .collect();
    let (mean, se) = mean_se(&values);
    assert!(se > 0.0, "the seeds differ");
    assert!(
        (mean - exact).abs() <= K * se,
        "patch 0: {mean} ± {se} over {SEEDS} seeds, exact {exact}"
    );
}

#[test]
fn the_weighting_given_is_the_one_used() {
    let mesh = furnace_mesh();
    let bvh = bvh(&mesh);
    let config = config(7);
    let solve = |w: &dyn Weighting| {
        run_combined_with(&mesh, &bvh, &config, w, &mut |_| ControlFlow::Continue(()))
            .unwrap()
            .estimate
    };
    let default = run(Method::Combined, &mesh, &bvh, &config, &mut |_| {
        ControlFlow::Continue(())
    })
    .unwrap()
    .estimate;
    // The method's own weighting given explicitly is the method, bit for bit ...
    assert_eq!(
        solve(&InverseExpectedVariance).radiosity(),
        default.radiosity()
    );
    // ... and another weighting, with the same seed (the same rays), changes the answer.
    let shooting = solve(&ShootingOnly);
    let differ = shooting
        .radiosity()
        .iter()
        .zip(default.radiosity())
        .filter(|(a, b)| a != b)
        .count();
    assert!(
        2 * differ > mesh.patches().len(),
        "{differ} of {} patches differ",
        mesh.patches().len()
    );
    assert_ne!(solve(&ByTheirRays).radiosity(), default.radiosity());
}
