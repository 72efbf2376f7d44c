//! Two-pass radiosity with the direct/indirect split (Balog, section 1.5): shooting, then
//! direct light by sampling the emitters plus indirect light gathered from the shooting.

use super::{Observer, ScheduleConfig, Solution};
use crate::context::Context;
use crate::error::Error;
use mcrad_raycast::RayCaster;

/// Two-pass with the split: see [the module](self).
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    super::two_pass::run_two_pass(ctx, config, true, observer)
}
