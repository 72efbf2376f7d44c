//! Two-pass radiosity (Balog, section 1.5): shooting, then one gathering round from it.
//!
//! The variance reported is the gather's own noise plus what it inherits from the shooting,
//! both from error samples ([`samples`](super::samples)): the shooting's samples gathered by
//! the gather's rays carry the inherited error with the correlation that conservation puts
//! between the shooting's patches, and the gather's replicates measure its own noise (one
//! difference a patch and part, a face's scale drawn towards the scene's). Summed as
//! independent by the formulas, both overstated the error 7-8 times on faces of one patch
//! (`cargo xtask calibrate`, cases `furnace-*-faces` and `slivers`).

use super::samples::{GatherRun, ShotSamples};
use super::{
    GATHER_TAG, Observer, ScheduleConfig, Solution, Step, budget_or_stopped, per_patch,
    shoot_config, unshot_fraction, with_ambient,
};
use crate::context::Context;
use crate::direct::split_with_budget;
use crate::error::Error;
use crate::method::StopReason;
use crate::shoot::shoot;
use glam::DVec3;
use mcrad_combine::Estimate;
use mcrad_random::{StreamKey, derive_seed};
use mcrad_raycast::RayCaster;
use std::ops::ControlFlow;

/// Two-pass: shooting with half the budget, then one gathering round (or the direct/indirect
/// split) from it with the other half. Two steps.
pub(super) fn run_two_pass<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    split: bool,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mesh = ctx.mesh();
    if config.rays == u64::MAX {
        return unbounded(ctx, config, split, observer);
    }
    let budget = config.rays;
    let mut s = shoot(
        ctx,
        &shoot_config(config, budget / 2, derive_seed(config.seed, 0)),
        &mut |_| ControlFlow::Continue(()),
    )?;
    let (shot_rays, escaped_rays, unshot) =
        (s.stats.rays, s.stats.escaped_rays, unshot_fraction(&s));
    let samples = shot_samples(config, &mut s);
    let shooting = with_ambient(mesh, config, s)?;
    let mut gather_budget = budget.saturating_sub(shot_rays);
    let limit = super::no_limit();
    if observer(&Step {
        index: 1,
        rays: shot_rays,
        next_rays: gather_budget,
        radiosity: shooting.radiosity(),
        variance: None,
        limit: &limit,
    })
    .is_break()
    {
        return Ok(Solution {
            estimate: shooting,
            steps: 1,
            escaped_rays,
            unshot_fraction: unshot,
            stop: StopReason::Stopped,
            direct: None,
            sky_direct: None,
            face_correlation: None,
        });
    }
    gather_budget = gather_budget.min(limit.get());
    let shot = Shot {
        shooting,
        samples,
        rays: shot_rays,
        escaped_rays,
        unshot,
        steps: 1,
    };
    finish(ctx, config, split, shot, gather_budget, observer)
}

/// The shooting half of a run: its solution (with the ambient term if asked), rays, escapes,
/// unshot fraction and the steps shown so far.
struct Shot {
    shooting: Estimate,
    /// Its error samples (`None` with the ambient term, which they do not hold).
    samples: Option<ShotSamples>,
    rays: u64,
    escaped_rays: u64,
    unshot: f64,
    steps: u32,
}

/// Two-pass without a budget (`rays == u64::MAX`, `--time` without `--rays`): the shooting
/// runs as `shoot` does without one (waves within a doubling horizon), each wave a step whose
/// `next_rays` counts the next wave and a gather as large as the shooting then; a cap `c` on
/// the rays left splits so that both halves end equal (the shooting gets `(c - shot) / 2` more,
/// the gather the rest). Without a cap the shooting runs until it converges or the observer
/// stops it.
fn unbounded<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    split: bool,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mut gather_cap = u64::MAX;
    let mut stopped = false;
    let mut steps = 0;
    let mut s = shoot(
        ctx,
        &shoot_config(config, u64::MAX, derive_seed(config.seed, 0)),
        &mut |p| {
            steps = p.waves;
            let limit = super::no_limit();
            let flow = observer(&Step {
                index: p.waves,
                rays: p.rays,
                next_rays: p.next_rays.saturating_mul(2).saturating_add(p.rays),
                radiosity: p.radiosity,
                variance: None,
                limit: &limit,
            });
            stopped = flow.is_break();
            let c = limit.get();
            if c != u64::MAX {
                let more = c.saturating_sub(p.rays) / 2;
                p.limit_rays_left(more);
                gather_cap = gather_cap.min(c - more);
            }
            flow
        },
    )?;
    let (shot_rays, escaped_rays, unshot) =
        (s.stats.rays, s.stats.escaped_rays, unshot_fraction(&s));
    let samples = shot_samples(config, &mut s);
    let shooting = with_ambient(ctx.mesh(), config, s)?;
    if stopped {
        return Ok(Solution {
            estimate: shooting,
            steps,
            escaped_rays,
            unshot_fraction: unshot,
            stop: StopReason::Stopped,
            direct: None,
            sky_direct: None,
            face_correlation: None,
        });
    }
    let shot = Shot {
        shooting,
        samples,
        rays: shot_rays,
        escaped_rays,
        unshot,
        steps,
    };
    finish(
        ctx,
        config,
        split,
        shot,
        shot_rays.min(gather_cap),
        observer,
    )
}

/// The gathering half: one round (or the split) from `shot` with `gather_budget` rays, shown
/// to the observer as the last step.
fn finish<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    split: bool,
    shot: Shot,
    gather_budget: u64,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mesh = ctx.mesh();
    let Shot {
        shooting,
        samples,
        rays: shot_rays,
        mut escaped_rays,
        unshot,
        steps,
    } = shot;
    let key = StreamKey::new(config.seed).derive(GATHER_TAG);
    let mut gathers = GatherRun::default();
    if split {
        // Half for the direct light, sized by what its samples really cost; the rest gathers.
        let sketch = samples.as_ref().map(|s| &s.sketch[..]);
        let s = split_with_budget(ctx, &shooting, sketch, gather_budget, key)?;
        let errors = [&s.own_errors[0][..], &s.own_errors[1][..]];
        gathers.add(
            s.estimate,
            &s.inherited,
            s.image,
            &errors,
            &s.image_variance,
        )?;
    } else {
        let per = per_patch(mesh, gather_budget);
        escaped_rays += gathers.round(ctx, &shooting, samples.as_ref(), per, key)?.1;
    }
    let (gathered, face_correlation) = gathers.estimate(
        mesh,
        samples.as_ref(),
        shooting.variance(),
        ctx.sampling() == crate::Sampler::Qmc,
    )?;
    // The answer's work is everything it took: the shooting and the gathering.
    let rays = shot_rays + gathered.rays();
    let estimate = Estimate::new(
        gathered.radiosity().to_vec(),
        gathered.variance().map(<[DVec3]>::to_vec),
        rays,
    )?;
    let stopped = observer(&Step {
        index: steps + 1,
        rays,
        next_rays: 0,
        radiosity: estimate.radiosity(),
        variance: None,
        limit: &super::no_limit(),
    })
    .is_break();
    Ok(Solution {
        estimate,
        steps: steps + 1,
        escaped_rays,
        unshot_fraction: unshot,
        stop: budget_or_stopped(stopped),
        direct: None,
        sky_direct: None,
        face_correlation,
    })
}

/// The error samples of the shooting half (taken out of `s`), or `None` with the ambient term,
/// whose spread of the unshot power they do not hold.
fn shot_samples(config: &ScheduleConfig, s: &mut crate::shoot::Shooting) -> Option<ShotSamples> {
    (!config.ambient).then(|| ShotSamples::take(s))
}

/// Two-pass without the split: shooting, then one gathering round.
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    run_two_pass(ctx, config, false, observer)
}
