//! Algorithm 3 of the paper: progressive two-pass.

use super::{
    Doubling, GATHER_TAG, Gathers, Observer, Progressive, ScheduleConfig, Solution, accumulate,
    per_patch, with_ambient,
};
use crate::context::Context;
use crate::error::Error;
use crate::gather::{Emission, gather_round_parts};
use mcrad_combine::Estimate;
use mcrad_random::StreamKey;
use mcrad_raycast::RayCaster;

/// Algorithm 3: progressive two-pass. Pass `k` spends half its rays refining the shooting
/// solution (PRR) and half regathering from the refined solution; gathers merge by rays
/// ([`Gathers`]: their inherited noise added as correlated).
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mesh = ctx.mesh();
    let min_pass = 4 * mesh.patches().len() as u64;
    let mut passes = Doubling::at_least(config, min_pass);
    let mut shooting: Option<Estimate> = None;
    let mut run = Progressive::default();
    let mut gathers = Gathers::default();
    while let Some(budget) = passes.next().filter(|&b| b >= min_pass) {
        let k = run.steps as u64;
        let s = run.shoot(ctx, config, budget / 2, passes.remaining(), k)?;
        passes.charge(s.stats.rays.saturating_sub(budget / 2));
        let refined = accumulate(shooting.take(), with_ambient(mesh, config, s)?)?;
        let key = StreamKey::new(config.seed).derive(GATHER_TAG + k);
        let (r, inherited) = gather_round_parts(
            ctx,
            &refined,
            Emission::Include,
            per_patch(mesh, budget / 2),
            key,
        )?;
        shooting = Some(refined);
        run.rays += r.estimate.rays();
        run.escaped_rays += r.escaped_rays;
        // The gathers inherit from nested merges of the same shooting passes.
        gathers.add(r.estimate, &inherited)?;
        if !run.replace(gathers.estimate()?, &mut passes, observer)? {
            break;
        }
    }
    run.finish(config.rays)
}
