//! Algorithm 1 of the paper: progressive ray refinement (PRR), shooting passes merged by rays.

use super::samples::{blend, by_rays};
use super::{Doubling, Observer, Progressive, ScheduleConfig, Solution, with_ambient};
use crate::context::Context;
use crate::correlation::face_factors;
use crate::error::Error;
use crate::replicates::Row;
use glam::DVec3;
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
    // Rays asked of and cast by the passes so far. A pass overruns its budget by its finishing
    // roulette's tail, a random share of it that grows near rho = 1 (0-30% per pass at rho
    // 0.999, one roulette path there being ~1000 rays), and charging it to the later passes
    // leaves the last one's uncovered (PRR used up to 105% of its budget). So the last pass is
    // sized to what is left over the share the passes so far cast per ray asked, which the
    // small early passes (the largest shares) make conservative, and what its tail leaves
    // unspent goes to further passes sized alike, down to 1% of the budget.
    let (mut asked, mut cast) = (0u64, 0u64);
    // The passes' error samples and their independent remainder, merged as the passes are
    // (by the rays asked), for the correlation between a face's patches.
    let mut rows: Vec<Row> = Vec::new();
    let mut unsampled: Vec<DVec3> = Vec::new();
    // Their face scales (`Shooting::face_scale`) averaged by rays.
    let mut face_scale = 0.0;
    loop {
        let left = passes.remaining();
        // Rays kept back from the last pass, given back after it.
        let mut held = 0;
        if asked > 0 && cast > asked && passes.peek() == left {
            let size = (left as f64 * asked as f64 / cast as f64) as u64;
            if size < config.rays / 100 {
                break;
            }
            passes.cap(size);
            held = left - size;
        }
        let Some(budget) = passes.next() else { break };
        let mut s = run.shoot(ctx, config, budget, passes.remaining(), run.steps as u64)?;
        asked += budget;
        cast += s.stats.rays;
        let w = budget as f64 / asked as f64;
        face_scale = (1.0 - w) * face_scale + w * s.face_scale;
        if rows.is_empty() {
            (rows, unsampled) = (
                std::mem::take(&mut s.sketch).into_dense(),
                std::mem::take(&mut s.unsampled),
            );
        } else if s.sketch.len() == rows.len() {
            rows = blend(rows, s.sketch.iter(), w);
            unsampled = by_rays(&unsampled, &s.unsampled, w);
        }
        passes.refund(held);
        passes.charge(s.stats.rays.saturating_sub(budget));
        if !run.step(with_ambient(mesh, config, s)?, &mut passes, observer)? {
            break;
        }
    }
    let mut solution = run.finish(config.rays)?;
    if ctx.sampling() == crate::Sampler::Qmc && rows.len() == mesh.patches().len() {
        solution.face_correlation = Some(face_factors(mesh, &rows, &unsampled, face_scale));
    }
    // A patch no ray reached: "no information", not a zero variance.
    solution.estimate = crate::shoot::unreached_variance(mesh, solution.estimate)?;
    Ok(solution)
}
