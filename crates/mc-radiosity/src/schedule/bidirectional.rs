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
//! area and gathers. The variance reported for `R_j` is, summed over the source patches `i`
//! whose `n_i` rays reached it, the sample variance of the sum of those rays' contributions
//! `c` to it, `n_i / (n_i - 1) (sum c² - (sum c)² / n_i)` (every ray of `i` is one draw, a
//! contribution 0 where it missed `j`): the rays of one source are drawn `n_i` at a time, not
//! as a Poisson process, so `sum c²` alone would over-report.
//!
//! **Inherited noise.** A step also inherits the error `e` of the solution it starts from:
//! `rho_j sum_i F_ji e_i`. As independent errors its variance would be `rho_j² sum_i F_ji²
//! V_i` (estimated from collisions of consecutive rays of `j`). But in a closed scene the input
//! conserves power: its errors satisfy `sum_i a_i e_i = 0` with `a_i = A_i (1 - rho_i) /
//! rho_i` (what patch `i` absorbs per unit of reflected radiosity), so they are negatively
//! correlated. Taken as independent errors conditioned on that constraint, the variance is
//!
//! ```text
//! rho_j² (sum_i F_ji² V_i - (sum_i F_ji a_i V_i)² / sum_i a_i² V_i)
//! ```
//!
//! with `sum_i F_ji a_i V_i` the mean of `a_i V_i` at the patches `j`'s rays hit. On a
//! subdivided mesh the correction is of the order of one patch's share of the scene and
//! vanishes; in a closed furnace of one patch per face a face's gather of the other five
//! inherits `-0.2 rho` of its own error, a fifth of the independent formula's variance, and
//! the formula made `bidirectional` report 2.8-3.3x its spread there (issue 36, item 2). Where
//! the step's rays show the scene open (more than 1e-4 of them escaped or hit a back face,
//! which absorbs at random) the constraint does not hold and the formula stays.
//!
//! The schedule: the first pass shoots (an unbiased first solution), every later pass is a step
//! from the solution so far, and the passes merge by their rays (as Algorithms 1-3 do).
//!
//! **The merge.** A step's error is `T e + o`: `T e` inherited from the solution's error `e`
//! (`T = rho F` through the step's rays), `o` its own, independent of `e`. Merged with weight
//! `w = n / (N + n)` (its rays over all so far), the solution's error becomes `(1 - w) e +
//! w (T e + o)`, of variance
//!
//! ```text
//! (1 - w)² V_j + w² (H_j + O_j) + 2 w (1 - w) C_j,    C_j = Cov(e_j, (T e)_j)
//! ```
//!
//! with `H_j` the inherited variance above and `O_j` the sample variance of the step's rays.
//! `C_j` has two parts. Conservation: `F_jj = 0`, so under the model above (independent
//! errors conditioned on conservation) `rho_j sum_i F_ji Cov(e_i, e_j) = -rho_j a_j V_j
//! (sum_i F_ji a_i V_i) / sum_i a_i² V_i`, 0 where the scene is open. And the earlier steps'
//! inherited parts, which `e` holds and which are the smooth part of the error, taken as one
//! error with `T e`: `sqrt(H_j) sd_j`, `sd_j` their standard deviations merged by rays (this
//! alone is what the merge did before: the steps' inherited parts summed as correlated, the
//! rest as independent). In a furnace of one patch per face the inherited error is `-0.2 rho
//! e_j`, cancelling a fifth of the solution's own error, and without the first part the merge
//! reported 1.5x the spread there (spread / reported 0.69 at rho 0.9, 0.65 at 0.99; 0.90 and
//! 0.89 with it, 0.97-0.98 with the first part alone, which leaves the open Cornell box of one
//! patch per face reporting 0.67 of its spread). On a subdivided mesh the first part vanishes.
//!
use super::{Doubling, GATHER_TAG, Observer, Progressive, ScheduleConfig, Solution};
use crate::context::Context;
use crate::error::Error;
use crate::gather::check_input;
use crate::sampling::stochastic_round;
use glam::DVec3;
use mcrad_combine::{Estimate, EstimateError};
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
    // The standard deviation of the steps' inherited parts merged by rays (see `Step::merge_into`).
    let mut inherited_sd = vec![DVec3::ZERO; mesh.patches().len()];
    while let Some(budget) = passes.next().filter(|&b| b >= min_pass) {
        let k = run.steps as u64;
        let merged = match run.merged.take() {
            None => {
                let shot = run.shoot(ctx, config, budget, passes.remaining(), k)?;
                // The roulette tail's rays beyond the pass's budget (long near rho = 1) come
                // out of the later passes.
                passes.charge(shot.stats.rays.saturating_sub(budget));
                shot.estimate
            }
            Some(solution) => {
                let s = step(
                    ctx,
                    &solution,
                    budget,
                    StreamKey::new(config.seed).derive(GATHER_TAG + k),
                )?;
                run.rays += s.rays;
                s.merge_into(&solution, &mut inherited_sd)?
            }
        };
        if !run.replace(merged, &mut passes, observer)? {
            break;
        }
    }
    let mut solution = run.finish(config.rays)?;
    // A patch no ray reached: "no information", not a zero variance.
    solution.estimate = crate::shoot::unreached_variance(mesh, solution.estimate)?;
    Ok(solution)
}

/// One bidirectional Jacobi step: its estimate and the parts of its error's variance (per
/// patch and channel, (W/m²)²), to be merged into the solution it started from.
struct Step {
    /// `R_j = E_j + rho_j sum_i F̂_ji B_i` (W/m²).
    radiosity: Vec<DVec3>,
    /// The variance of the step's own noise (its rays given the input).
    own: Vec<DVec3>,
    /// The variance of the error it inherits, `rho_j sum_i F_ji e_i`.
    inherited: Vec<DVec3>,
    /// The covariance of that inherited error with the input's own error at the patch, `rho_j
    /// sum_i F_ji Cov(e_i, e_j)` (negative where the input conserves power).
    cross: Vec<DVec3>,
    /// Rays cast.
    rays: u64,
}

impl Step {
    /// The step merged by rays into `solution` (the input it started from): with `w = n /
    /// (N + n)` its share of the rays, `B = (1 - w) B + w R` and, the step's error being
    /// `T e + o` (`T e` inherited, `o` its own),
    /// `V = (1 - w)² V + w² (inherited + own) + 2 w (1 - w) C`, with `C` the covariance of
    /// `T e` with `e`: the conservation's `cross`, plus `sqrt(inherited) sd` with `sd` the
    /// standard deviation of the earlier steps' inherited parts merged by rays (`inherited_sd`,
    /// updated here), as if the inherited parts were one error (module documentation).
    fn merge_into(
        self,
        solution: &Estimate,
        inherited_sd: &mut [DVec3],
    ) -> Result<Estimate, Error> {
        let v = solution.variance().ok_or(EstimateError::MissingVariance)?;
        let total = solution.rays() + self.rays;
        let w = self.rays as f64 / total.max(1) as f64;
        let radiosity = solution
            .radiosity()
            .iter()
            .zip(&self.radiosity)
            .map(|(b, r)| (1.0 - w) * *b + w * *r)
            .collect();
        let variance = v
            .iter()
            .zip(self.own.iter().zip(&self.inherited))
            .zip(self.cross.iter().zip(inherited_sd.iter_mut()))
            .map(|((v, (o, h)), (c, sd))| {
                let h_sd = h.max(DVec3::ZERO).sqrt();
                let c = *c + h_sd * *sd;
                *sd = (1.0 - w) * *sd + w * h_sd;
                ((1.0 - w) * (1.0 - w) * *v + w * w * (*o + *h) + 2.0 * w * (1.0 - w) * c)
                    .max(DVec3::ZERO)
            })
            .collect();
        Ok(Estimate::new(radiosity, Some(variance), total)?)
    }
}

/// One bidirectional Jacobi step from `solution` with about `rays` rays (module
/// documentation).
fn step<C: RayCaster>(
    ctx: &Context<C>,
    solution: &Estimate,
    rays: u64,
    key: StreamKey,
) -> Result<Step, Error> {
    let (mesh, sampler, caster) = (ctx.mesh(), ctx.sampler(), ctx.caster());
    let input = solution.radiosity();
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
    // Fold in job order: the sums do not depend on the thread count. The jobs of a patch are
    // consecutive; its rays are one sample set per receiver, whose mean is taken out of the
    // squares once the patch is done (see `SampleSets`).
    let mut reflected = vec![DVec3::ZERO; patches.len()];
    let mut squares = vec![DVec3::ZERO; patches.len()];
    let mut cast = 0u64;
    let mut sets = SampleSets::default();
    // `sum_i F_ji² V_i` of patch `j` from its own rays: two independent cosine rays of `j` hit
    // the same `i` with probability `F_ji²` (collisions of consecutive rays, as gathers did before their disc estimate).
    let (mut collisions, mut pairs) = (vec![DVec3::ZERO; patches.len()], vec![0u64; patches.len()]);
    let input_variance = solution.variance();
    // The conservation of the input's power (module documentation, "Inherited noise"): the
    // weights `a_i`, and per patch `j` the sum over its rays of `a_i V_i` at the patch hit.
    let absorbing: Vec<DVec3> = patches
        .iter()
        .map(|p| {
            let rho = p.reflectance.as_dvec3();
            let a = |r: f64| if r > 0.0 { p.area * (1.0 - r) / r } else { 0.0 };
            DVec3::new(a(rho.x), a(rho.y), a(rho.z))
        })
        .collect();
    let mut weighted = vec![DVec3::ZERO; patches.len()];
    let mut rays_of = vec![0u64; patches.len()];
    let mut lost = 0u64;
    for (&(i, _, _), hits) in jobs.iter().zip(&hits) {
        let i = i as usize;
        if let Some(v) = input_variance {
            for pair in hits.windows(2) {
                pairs[i] += 1;
                if pair[0] == pair[1] && pair[0] != NOTHING {
                    collisions[i] += v[pair[0] as usize];
                }
            }
            for &h in hits {
                if h == NOTHING {
                    lost += 1;
                } else {
                    weighted[i] += absorbing[h as usize] * v[h as usize];
                }
            }
        }
        if sets.source != Some(i) {
            sets.finish(&mut squares);
            sets.source = Some(i);
        }
        cast += hits.len() as u64;
        rays_of[i] += hits.len() as u64;
        sets.rays += hits.len() as u64;
        for &j in hits.iter().filter(|&&j| j != NOTHING) {
            let j = j as usize;
            let both = density[i] + density[j];
            let to_j = patches[j].reflectance.as_dvec3() * input[i] / (patches[j].area * both);
            let to_i = patches[i].reflectance.as_dvec3() * input[j] / (patches[i].area * both);
            reflected[j] += to_j;
            reflected[i] += to_i;
            sets.to.push((j, to_j));
            sets.to.push((i, to_i));
        }
    }
    sets.finish(&mut squares);
    let radiosity = patches
        .iter()
        .zip(&reflected)
        .map(|(p, r)| p.emission.as_dvec3() + *r)
        .collect();
    // `sum_i a_i² V_i` over the scene, where the input conserves power (no ray of the step
    // escaped or hit a back face beyond 1e-4 of them).
    let closed = lost as f64 <= 1e-4 * cast as f64;
    let total: DVec3 = match input_variance {
        Some(v) if closed => absorbing.iter().zip(v).map(|(a, v)| *a * *a * *v).sum(),
        _ => DVec3::ZERO,
    };
    let shared = |m: DVec3| {
        let part = |m: f64, t: f64| if t > 0.0 { m * m / t } else { 0.0 };
        DVec3::new(part(m.x, total.x), part(m.y, total.y), part(m.z, total.z))
    };
    let (mut inherited, mut cross) = (Vec::new(), Vec::new());
    for (j, p) in patches.iter().enumerate() {
        let rho = p.reflectance.as_dvec3();
        let (n, r) = (pairs[j], rays_of[j]);
        let (h, c) = match input_variance {
            Some(v) if n > 0 && r > 0 => {
                let m = weighted[j] / r as f64;
                // `Cov(e_i, e_j) = V_j delta_ij - a_i V_i a_j V_j / sum a² V`, and `F_jj = 0`.
                let c = DVec3::select(
                    total.cmpgt(DVec3::ZERO),
                    -absorbing[j] * v[j] * m / total,
                    DVec3::ZERO,
                );
                (
                    rho * rho * (collisions[j] / n as f64 - shared(m)).max(DVec3::ZERO),
                    rho * c,
                )
            }
            _ => (DVec3::ZERO, DVec3::ZERO),
        };
        inherited.push(h);
        cross.push(c);
    }
    Ok(Step {
        radiosity,
        own: squares,
        inherited,
        cross,
        rays: cast,
    })
}

/// The contributions of one source patch's rays, gathered to add each receiver's sample
/// variance to its squares: per receiver, of `n` draws (the source's rays, 0 where a ray did
/// not reach it), `n / (n - 1) (sum c² - (sum c)² / n)`, the unbiased variance estimate of their
/// sum; `sum c²` for a source of one ray (no spread to measure; the Poisson bound).
#[derive(Default)]
struct SampleSets {
    /// The source patch, or none before the first.
    source: Option<usize>,
    /// Rays the source cast (every ray a draw, hit or not).
    rays: u64,
    /// `(receiver, contribution)` of the source's rays, the shooting use to the patch hit and
    /// the gathering use to the source itself, in ray order.
    to: Vec<(usize, DVec3)>,
}

impl SampleSets {
    /// Adds the source's per-receiver variances to `squares` and starts afresh.
    fn finish(&mut self, squares: &mut [DVec3]) {
        if self.source.take().is_some() {
            let n = self.rays as f64;
            // Stable sort: equal receivers keep ray order, so the sums are reproducible.
            self.to.sort_by_key(|&(j, _)| j);
            let mut start = 0;
            while start < self.to.len() {
                let j = self.to[start].0;
                let end = start + self.to[start..].partition_point(|&(k, _)| k == j);
                let (sum, sum_sq) = self.to[start..end]
                    .iter()
                    .fold((DVec3::ZERO, DVec3::ZERO), |(s, q), &(_, c)| {
                        (s + c, q + c * c)
                    });
                squares[j] += if self.rays > 1 {
                    ((sum_sq - sum * sum / n) * (n / (n - 1.0))).max(DVec3::ZERO)
                } else {
                    sum_sq
                };
                start = end;
            }
        }
        self.rays = 0;
        self.to.clear();
    }
}
