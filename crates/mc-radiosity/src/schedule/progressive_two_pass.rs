//! Algorithm 3 of the paper: progressive two-pass.
//!
//! The gathers inherit from nested merges of the same shooting passes; the variance reported
//! takes that from the passes' error samples (merged as the passes are) gathered by the
//! gathers' rays, and the gathers' own noise from their replicates, merged over the passes as
//! the gathers are ([`samples`](super::samples)).

use super::samples::{GatherRun, ShotSamples};
use super::{
    Doubling, GATHER_TAG, Observer, Progressive, ScheduleConfig, Solution, accumulate, per_patch,
    with_ambient,
};
use crate::context::Context;
use crate::error::Error;
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
    // The gathers, their images of the shooting's samples and their own noise measured.
    let mut gathers = GatherRun::default();
    // The shooting's error samples merged as its passes are (`None` with the ambient term).
    let mut samples: Option<ShotSamples> = None;
    let mut face_correlation = None;
    let qmc = ctx.sampling() == crate::Sampler::Qmc;
    while let Some(budget) = passes.next().filter(|&b| b >= min_pass) {
        let k = run.steps as u64;
        let mut s = run.shoot(ctx, config, budget / 2, passes.remaining(), k)?;
        passes.charge(s.stats.rays.saturating_sub(budget / 2));
        let pass = (!config.ambient).then(|| ShotSamples::take(&mut s));
        let pass_rays = s.estimate.rays();
        let refined = accumulate(shooting.take(), with_ambient(mesh, config, s)?)?;
        // The passes merge by the rays asked of them (`accumulate`): so do their samples.
        samples = match (samples.take(), pass) {
            (Some(old), Some(new)) => {
                Some(old.merge(new, pass_rays as f64 / refined.rays() as f64))
            }
            (_, new) => new,
        };
        let key = StreamKey::new(config.seed).derive(GATHER_TAG + k);
        // The gathers inherit from nested merges of the same shooting passes.
        let per = per_patch(mesh, budget / 2);
        let (rays, escaped) = gathers.round(ctx, &refined, samples.as_ref(), per, key)?;
        run.rays += rays;
        run.escaped_rays += escaped;
        let (estimate, factors) =
            gathers.estimate(mesh, samples.as_ref(), refined.variance(), qmc)?;
        shooting = Some(refined);
        face_correlation = factors;
        if !run.replace(estimate, &mut passes, observer)? {
            break;
        }
    }
    let mut solution = run.finish(config.rays)?;
    solution.face_correlation = face_correlation;
    Ok(solution)
}
