//! Algorithm 2 of the paper: progressive gathering from one shooting solution.
//!
//! Every gather inherits the same shooting error; the variance reported takes it from the
//! shooting's error samples gathered by the gathers' rays, and the gathers' own noise from
//! their replicates, merged over the rounds as the gathers are ([`samples`](super::samples)).

use super::samples::{GatherRun, ShotSamples};
use super::{
    Doubling, GATHER_TAG, Observer, Progressive, ScheduleConfig, Solution, per_patch, shoot_config,
    unshot_fraction, with_ambient,
};
use crate::context::Context;
use crate::error::Error;
use crate::shoot::shoot;
use mcrad_random::{StreamKey, derive_seed};
use mcrad_raycast::RayCaster;
use std::ops::ControlFlow;

/// Algorithm 2: progressive gathering from one shooting solution.
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mesh = ctx.mesh();
    let shoot_budget = if config.rays == u64::MAX {
        1_000_000
    } else {
        config.rays / 4
    };
    let mut s = shoot(
        ctx,
        &shoot_config(config, shoot_budget, derive_seed(config.seed, 0)),
        &mut |_| ControlFlow::Continue(()),
    )?;
    let mut run = Progressive {
        rays: s.stats.rays,
        escaped_rays: s.stats.escaped_rays,
        unshot_fraction: unshot_fraction(&s),
        ..Default::default()
    };
    let samples = (!config.ambient).then(|| ShotSamples::take(&mut s));
    let shooting = with_ambient(mesh, config, s)?;
    // Without a budget the gathers have none either (an observer stops them): `u64::MAX`
    // less the shot rays would size the first gather at 2^58 rays.
    let rest = if config.rays == u64::MAX {
        u64::MAX
    } else {
        config.rays.saturating_sub(run.rays)
    };
    let min_pass = 2 * mesh.patches().len() as u64;
    let first =
        config
            .first_pass_rays
            .unwrap_or(if rest == u64::MAX { 100_000 } else { rest / 63 });
    let mut passes = Doubling::new(&ScheduleConfig {
        rays: rest,
        first_pass_rays: Some(first.max(min_pass)),
        ..config.clone()
    });
    // Every gather inherits the same shooting noise: their inherited parts add as correlated.
    let mut gathers = GatherRun::default();
    let mut face_correlation = None;
    let qmc = ctx.sampling() == crate::Sampler::Qmc;
    while let Some(budget) = passes.next().filter(|&b| b >= min_pass) {
        let key = StreamKey::new(config.seed).derive(GATHER_TAG + run.steps as u64);
        let per = per_patch(mesh, budget);
        let (rays, escaped) = gathers.round(ctx, &shooting, samples.as_ref(), per, key)?;
        run.rays += rays;
        run.escaped_rays += escaped;
        let (estimate, factors) =
            gathers.estimate(mesh, samples.as_ref(), shooting.variance(), qmc)?;
        face_correlation = factors;
        if !run.replace(estimate, &mut passes, observer)? {
            break;
        }
    }
    let mut solution = run.finish(config.rays)?;
    solution.face_correlation = face_correlation;
    Ok(solution)
}
