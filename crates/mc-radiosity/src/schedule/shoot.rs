//! Plain shooting (Balog, section 1.3): one pass, a step per wave.

use super::{
    Observer, ScheduleConfig, Solution, Step, shoot_config, unshot_fraction, with_ambient,
};
use crate::context::Context;
use crate::error::Error;
use crate::shoot::shoot;
use mcrad_raycast::RayCaster;

/// Plain shooting: one pass, a step per wave.
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mesh = ctx.mesh();
    let mut steps = 0;
    let s = shoot(
        ctx,
        &shoot_config(config, config.rays, config.seed),
        &mut |p| {
            steps = p.waves;
            observer(&Step {
                index: p.waves,
                rays: p.rays,
                next_rays: p.next_rays,
                radiosity: p.radiosity,
                variance: None,
                limit: p.limit,
            })
        },
    )?;
    let stop = s.stats.stop;
    let unshot_fraction = unshot_fraction(&s);
    let escaped_rays = s.stats.escaped_rays;
    let face_correlation = (ctx.sampling() == crate::Sampler::Qmc
        && s.sketch.len() == mesh.patches().len())
    .then(|| {
        crate::correlation::factors_of(
            mesh,
            |i, g| crate::replicates::sample(s.sketch.get(i), g),
            |i| s.unsampled[i],
            s.face_scale,
        )
    });
    Ok(Solution {
        // A patch no ray reached: "no information", not a zero variance.
        estimate: crate::shoot::unreached_variance(mesh, with_ambient(mesh, config, s)?)?,
        steps,
        escaped_rays,
        unshot_fraction,
        stop,
        direct: None,
        sky_direct: None,
        face_correlation,
    })
}
