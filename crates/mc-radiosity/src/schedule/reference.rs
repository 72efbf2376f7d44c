//! [`Method::Reference`](crate::method::Method::Reference): the deterministic reference solver
//! of crate `mcrad-reference` (explicit form factors, Gauss-Seidel) as a schedule of one step.
//! The ray budget and the seed do not apply; [`ScheduleConfig::reference`] sets the accuracy
//! and the patch limit.

use super::{Observer, ScheduleConfig, Solution, Step};
use crate::context::Context;
use crate::error::Error;
use crate::method::StopReason;
use mcrad_raycast::RayCaster;

/// Runs the reference solver and shows its solution to the observer as the one step (its rays
/// are the shadow rays cast). The solution has no variance; `steps` counts the Gauss-Seidel
/// sweeps. It ends [`StopReason::Converged`] (the solver fails rather than stop short), or
/// [`StopReason::Stopped`] if the observer breaks at that step.
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let (mesh, caster) = (ctx.mesh(), ctx.caster());
    let r = mcrad_reference::reference(mesh, caster, &config.reference, &|_| {})?;
    let stopped = observer(&Step {
        index: 1,
        rays: r.estimate.rays(),
        next_rays: 0,
        radiosity: r.estimate.radiosity(),
        variance: None,
        limit: &super::no_limit(),
    })
    .is_break();
    Ok(Solution {
        estimate: r.estimate,
        steps: u32::try_from(r.stats.iterations).unwrap_or(u32::MAX),
        escaped_rays: 0,
        unshot_fraction: 0.0,
        stop: if stopped {
            StopReason::Stopped
        } else {
            StopReason::Converged
        },
        direct: None,
        sky_direct: None,
        face_correlation: None,
    })
}
