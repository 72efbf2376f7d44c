//! Jacobi gathering (Balog, section 1.4): a step per round.

use super::{Observer, ScheduleConfig, Solution, Step, per_patch};
use crate::context::Context;
use crate::error::Error;
use crate::gather::{GatherConfig, gather};
use mcrad_raycast::RayCaster;
use std::ops::ControlFlow;

/// Jacobi gathering: a step per round.
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mesh = ctx.mesh();
    // About ten rounds' worth of rays per patch (the bounces a typical scene needs).
    let rays_per_patch = if config.rays == u64::MAX {
        256
    } else {
        per_patch(mesh, config.rays / 10)
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
        unshot_fraction: 0.0,
        stop: g.stats.stop,
    })
}
