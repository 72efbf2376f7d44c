//! Algorithm 1 of the paper: progressive ray refinement (PRR), shooting passes merged by rays.

use super::{Doubling, Observer, Progressive, ScheduleConfig, Solution, with_ambient};
use crate::context::Context;
use crate::error::Error;
use mcrad_raycast::RayCaster;

/// Algorithm 1: progressive ray refinement.
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mesh = ctx.mesh();
    let mut passes = Doubling::new(config);
    let mut run = Progressive::default();
    while let Some(budget) = passes.next() {
        let s = run.shoot(ctx, config, budget, run.steps as u64)?;
        passes.charge(s.stats.rays.saturating_sub(budget));
        if !run.step(with_ambient(mesh, config, s)?, &mut passes, observer)? {
            break;
        }
    }
    let mut solution = run.finish(config.rays)?;
    // A patch no ray reached: "no information", not a zero variance.
    solution.estimate = crate::shoot::unreached_variance(mesh, solution.estimate)?;
    Ok(solution)
}
