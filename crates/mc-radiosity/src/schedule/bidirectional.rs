//! RenderPark's alternative weighting for combined shooting and gathering: every ray serves
//! both directions, weighted by the balance heuristic (Bekaert's bidirectional stochastic
//! Jacobi; Sbert's global lines are the case of uniform ray density).
//!
//! A step takes a radiosity solution `B` (W/m²) and estimates one Jacobi step
//! `B'_j = E_j + rho_j sum_i F_ji B_i`. Patch `i` is given `t_i = N (P_i / 2 sum P + A_i / 2 sum A)`
//! rays in expectation (`P_i = |B_i| A_i` its power: half the rays follow the power, as
//! shooting would send them, half the area, as gathering would), rounded stochastically, each
//! from a uniform point in a cosine direction. A ray from `i` whose first hit is the front of
//! `j` samples the transfer between them from both ends. With ray densities `p_i = t_i / A_i`
//! (per unit area), the balance heuristic gives the shooting use (`i` lights `j`) the weight
//! `p_i / (p_i + p_j)` and the gathering use (`j` looks at `i`) `p_j / (p_i + p_j)`, and the ray
//! adds
//!
//! ```text
//! rho_j B_i / (A_j (p_i + p_j))   to R_j,        rho_i B_j / (A_i (p_i + p_j))   to R_i.
//! ```
//!
//! In expectation the rays from `i` that reach `j` add `rho_j F_ji B_i p_i / (p_i + p_j)` to
//! `R_j` and those from `j` that reach `i` add `rho_j F_ji B_i p_j / (p_i + p_j)`, which sum to
//! the transfer: the step is unbiased for any densities, and dividing by the expected `t_i`
//! rather than the drawn count keeps it so under stochastic rounding. A small bright light gets
//! many rays (its power) and lights the scene by shooting; a large dim wall gets rays for its
//! area and gathers. The variance reported is `sum c²` over the contributions `c` a patch
//! received.
//!
//! The schedule: the first pass shoots (an unbiased first solution), every later pass is a step
//! from the solution so far, and the passes merge by their rays (as Algorithms 1-3 do).

use super::{Doubling, GATHER_TAG, Observer, Progressive, ScheduleConfig, Solution};
use crate::context::Context;
use crate::error::Error;
use crate::gather::check_input;
use crate::sampling::stochastic_round;
use glam::DVec3;
use mcrad_combine::Estimate;
use mcrad_random::StreamKey;
use mcrad_raycast::RayCaster;
use rayon::prelude::*;

/// Rays per job: the unit of parallel work and of random streams.
const JOB_RAYS: u64 = 4096;
/// Hit record of a ray that hit nothing or a back face.
const NOTHING: u32 = u32::MAX;
/// Sub-stream of a patch's ray-count draw (job streams use `1 + chunk`).
const ALLOCATE: u64 = 0;

/// The bidirectional schedule: see the [module documentation](self).
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mesh = ctx.mesh();
    let min_pass = 2 * mesh.patches().len() as u64;
    let mut passes = Doubling::at_least(config, min_pass);
    let mut run = Progressive::default();
    while let Some(budget) = passes.next().filter(|&b| b >= min_pass) {
        let k = run.steps as u64;
        let estimate = match &run.merged {
            None => run.shoot(ctx, config, budget, k)?.estimate,
            Some(solution) => {
                let e = step(
                    ctx,
                    solution.radiosity(),
                    budget,
                    StreamKey::new(config.seed).derive(GATHER_TAG + k),
                )?;
                run.rays += e.rays();
                e
            }
        };
        if !run.step(estimate, &mut passes, observer)? {
            break;
        }
    }
    let mut solution = run.finish(config.rays)?;
    // A patch no ray reached: "no information", not a zero variance.
    solution.estimate = crate::shoot::unreached_variance(mesh, solution.estimate)?;
    Ok(solution)
}

/// One bidirectional Jacobi step from `input` with about `rays` rays (module documentation).
fn step<C: RayCaster>(
    ctx: &Context<C>,
    input: &[DVec3],
    rays: u64,
    key: StreamKey,
) -> Result<Estimate, Error> {
    let (mesh, sampler, caster) = (ctx.mesh(), ctx.sampler(), ctx.caster());
    check_input(mesh, input)?;
    let patches = mesh.patches();
    let power: Vec<f64> = patches
        .iter()
        .zip(input)
        .map(|(p, b)| b.max(DVec3::ZERO).element_sum() * p.area)
        .collect();
    let (total_power, total_area) = (power.iter().sum::<f64>(), mesh.total_area());
    let expected: Vec<f64> = patches
        .iter()
        .zip(&power)
        .map(|(p, &w)| {
            let by_power = if total_power > 0.0 {
                w / total_power
            } else {
                0.0
            };
            rays as f64 * 0.5 * (by_power + p.area / total_area)
        })
        .collect();
    let density: Vec<f64> = expected
        .iter()
        .zip(patches)
        .map(|(t, p)| t / p.area)
        .collect();
    let mut jobs = Vec::new();
    for (i, t) in expected.iter().enumerate() {
        let draw = key
            .item(i as u64)
            .substream(ALLOCATE)
            .stream()
            .uniform_f64();
        let n = stochastic_round(*t, draw);
        for chunk in 0..n.div_ceil(JOB_RAYS) {
            jobs.push((
                i as u32,
                chunk as u32,
                (n - chunk * JOB_RAYS).min(JOB_RAYS) as u32,
            ));
        }
    }
    let hits: Vec<Vec<u32>> = jobs
        .par_iter()
        .map(|&(patch, chunk, n)| {
            if ctx.cancelled() {
                return Vec::new();
            }
            let mut rng = key.item(patch as u64).substream(1 + chunk as u64).stream();
            (0..n)
                .map(
                    |_| match caster.closest_hit(&sampler.ray(patch as usize, &mut rng)) {
                        Some(hit) if hit.front => hit.id,
                        _ => NOTHING,
                    },
                )
                .collect()
        })
        .collect();
    ctx.check_cancelled()?;
    // Fold in job order: the sums do not depend on the thread count.
    let mut reflected = vec![DVec3::ZERO; patches.len()];
    let mut squares = vec![DVec3::ZERO; patches.len()];
    let mut cast = 0u64;
    for (&(i, _, _), hits) in jobs.iter().zip(&hits) {
        let i = i as usize;
        cast += hits.len() as u64;
        for &j in hits.iter().filter(|&&j| j != NOTHING) {
            let j = j as usize;
            let both = density[i] + density[j];
            let to_j = patches[j].reflectance.as_dvec3() * input[i] / (patches[j].area * both);
            let to_i = patches[i].reflectance.as_dvec3() * input[j] / (patches[i].area * both);
            reflected[j] += to_j;
            squares[j] += to_j * to_j;
            reflected[i] += to_i;
            squares[i] += to_i * to_i;
        }
    }
    let radiosity = patches
        .iter()
        .zip(&reflected)
        .map(|(p, r)| p.emission.as_dvec3() + *r)
        .collect();
    Ok(Estimate::new(radiosity, Some(squares), cast)?)
}
