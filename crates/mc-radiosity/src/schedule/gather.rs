//! Jacobi gathering (Balog, section 1.4): a step per round.

use super::{Observer, ScheduleConfig, Solution, Step, per_patch};
use crate::context::Context;
use crate::error::Error;
use crate::gather::{GatherConfig, gather};
use mcrad_meshing::Mesh;
use mcrad_raycast::RayCaster;
use std::ops::ControlFlow;

/// Jacobi gathering: a step per round.
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mesh = ctx.mesh();
    // The rounds the reflectance asks for: after `m` rounds the series misses at most
    // `rho_max^(m+1)` of the reflected light, so `m` rounds with `rho_max^m <= SERIES_TOLERANCE`
    // (10 at rho 0.5, 66 at 0.9, 688 at 0.99); the budget is spread over them (at least 2 rays
    // per patch and round, so a small budget runs fewer rounds: see `series_remainder`).
    let rounds = rounds_needed(mesh);
    let rays_per_patch = if config.rays == u64::MAX {
        256
    } else {
        per_patch(mesh, config.rays / rounds)
    };
    let gather_config = GatherConfig {
        rays: config.rays,
        rays_per_patch,
        threshold: 1e-3,
        seed: config.seed,
    };
    let per_round = mesh.patches().len() as u64 * rays_per_patch as u64;
    let g = gather(ctx, &gather_config, &mut |p| {
        let limit = super::no_limit();
        let flow = observer(&Step {
            index: p.rounds,
            rays: p.rays,
            next_rays: per_round.min(p.budget - p.rays),
            radiosity: p.radiosity,
            variance: None,
            limit: &limit,
        });
        // A round costs what it costs: a cap below it stops the run instead.
        if limit.get() < per_round {
            return ControlFlow::Break(());
        }
        flow
    })?;
    Ok(Solution {
        estimate: g.estimate,
        steps: g.rounds,
        escaped_rays: g.stats.escaped_rays,
        unshot_fraction: series_remainder(mesh, g.rounds),
        stop: g.stats.stop,
    })
}

/// The largest remainder of the Jacobi series accepted: rounds run until `rho_max^m` is below it.
const SERIES_TOLERANCE: f64 = 1e-3;

/// The largest reflectance over patches and channels, below 1.
fn rho_max(mesh: &Mesh) -> f64 {
    mesh.patches()
        .iter()
        .map(|p| f64::from(p.reflectance.max_element()))
        .fold(0.0, f64::max)
        .min(1.0 - 1e-12)
}

/// Rounds after which the series' remainder `rho_max^m` is at most [`SERIES_TOLERANCE`]
/// (1 without reflection: one round is then exact).
fn rounds_needed(mesh: &Mesh) -> u64 {
    let rho = rho_max(mesh);
    if rho <= 0.0 {
        1
    } else {
        (SERIES_TOLERANCE.ln() / rho.ln()).ceil().max(1.0) as u64
    }
}

/// A bound on the share of the reflected light still missing after `rounds` Jacobi rounds,
/// `rho_max^rounds` (reported as the solution's unshot fraction: light not yet propagated).
fn series_remainder(mesh: &Mesh, rounds: u32) -> f64 {
    rho_max(mesh).powi(rounds.min(i32::MAX as u32) as i32)
}
