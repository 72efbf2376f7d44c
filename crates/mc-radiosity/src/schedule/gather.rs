//! Jacobi gathering (Balog, section 1.4): a step per round.

use super::{Observer, ScheduleConfig, Solution, Step, per_patch};
use crate::context::Context;
use crate::error::Error;
use crate::gather::{GatherConfig, gather};
use glam::DVec3;
use mcrad_combine::Estimate;
use mcrad_meshing::Mesh;
use mcrad_raycast::RayCaster;
use std::ops::ControlFlow;

/// Jacobi gathering: a step per round.
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mesh = ctx.mesh();
    // The rounds the reflectance asks for: after `m` rounds the series misses at most
    // `rho_max^(m+1)` of the reflected light, so `m` rounds with `rho_max^m <= SERIES_TOLERANCE`
    // (10 at rho 0.5, 66 at 0.9, 688 at 0.99); the budget is spread over them (at least 2 rays
    // per patch and round, so a small budget runs fewer rounds: see `series_remainder`).
    let rounds = rounds_needed(mesh);
    let rays_per_patch = if config.rays == u64::MAX {
        256
    } else {
        per_patch(mesh, config.rays / rounds)
    };
    let gather_config = GatherConfig {
        rays: config.rays,
        rays_per_patch,
        threshold: 1e-3,
        seed: config.seed,
    };
    let per_round = mesh.patches().len() as u64 * rays_per_patch as u64;
    // The last rounds' solutions, newest last, for the series' remainder.
    let mut history: Vec<Vec<DVec3>> = Vec::with_capacity(HISTORY + 1);
    let g = gather(ctx, &gather_config, &mut |p| {
        if history.len() == HISTORY {
            history.remove(0);
        }
        history.push(p.radiosity.to_vec());
        let limit = super::no_limit();
        let flow = observer(&Step {
            index: p.rounds,
            rays: p.rays,
            next_rays: per_round.min(p.budget - p.rays),
            radiosity: p.radiosity,
            variance: None,
            limit: &limit,
        });
        // A round costs what it costs: a cap below it stops the run instead.
        if limit.get() < per_round {
            return ControlFlow::Break(());
        }
        flow
    })?;
    let estimate = with_remainder(mesh, g.estimate, &history, g.rounds, g.stats.noise_free)?;
    Ok(Solution {
        estimate,
        steps: g.rounds,
        escaped_rays: g.stats.escaped_rays,
        unshot_fraction: series_remainder(mesh, g.rounds),
        stop: g.stats.stop,
        direct: None,
        sky_direct: None,
        face_correlation: None,
    })
}

/// The largest remainder of the Jacobi series accepted: rounds run until `rho_max^m` is below it.
const SERIES_TOLERANCE: f64 = 1e-3;

/// The largest reflectance over patches and channels, below 1.
fn rho_max(mesh: &Mesh) -> f64 {
    mesh.patches()
        .iter()
        .map(|p| f64::from(p.reflectance.max_element()))
        .fold(0.0, f64::max)
        .min(1.0 - 1e-12)
}

/// Rounds after which the series' remainder `rho_max^m` is at most [`SERIES_TOLERANCE`]
/// (1 without reflection: one round is then exact).
fn rounds_needed(mesh: &Mesh) -> u64 {
    let rho = rho_max(mesh);
    if rho <= 0.0 {
        1
    } else {
        (SERIES_TOLERANCE.ln() / rho.ln()).ceil().max(1.0) as u64
    }
}

/// A bound on the share of the reflected light still missing after `rounds` Jacobi rounds,
/// `rho_max^rounds` (reported as the solution's unshot fraction: light not yet propagated).
fn series_remainder(mesh: &Mesh, rounds: u32) -> f64 {
    rho_max(mesh).powi(rounds.min(i32::MAX as u32) as i32)
}

/// The drift of the increments' ratio, over `1 - q` ([`with_remainder`]), that rounding alone
/// can make: the increments are differences of powers of about `total` (W per channel), each
/// rounded to `f64`, so `q` carries a relative error of a few `epsilon total / d` with `d` the
/// last increment's power; 16 of them, and at least 1e-9.
fn rounding_drift(total: f64, d: f64, q: f64) -> f64 {
    (16.0 * f64::EPSILON * total.abs() / (d.abs() * (1.0 - q))).max(1e-9)
}

/// Rounds kept for [`with_remainder`]: three increments, two ratios.
const HISTORY: usize = 4;

/// The Jacobi series' remainder added to a truncated gathering, with its uncertainty.
///
/// After round `m` the increments `d_m = B_m - B_{m-1}` shrink geometrically by the dominant
/// eigenvalue of `rho F`, so the light still missing is about `d_m q / (1 - q)`. Per channel,
/// `q` is the ratio of the increments' total powers `sum_i A_i d_m,i / sum_i A_i d_{m-1},i`
/// (in `[0, rho_max]`); the remainder is spread as the reflected light `B_m - E` is,
/// `B_i += (B_m,i - E_i) r` with `r = q sum_i A_i d_m,i / ((1 - q) sum_i A_i (B_m,i - E_i))`
/// (exact in a furnace, where every round is a uniform multiple of the last). Its variance,
/// added to the last round's, is `(B_m,i - E_i)² r² delta²` with `delta` the relative
/// uncertainty of `q / (1 - q)`: the change of the ratio between the last two pairs of rounds
/// over `1 - q`, plus the relative noise of `sum A d_m` (its rounds' variances), at least
/// `1e-3` unless every round of the run was noise-free (`noise_free`:
/// [`GatherStats::noise_free`](crate::GatherStats::noise_free)) and the drift is within what
/// rounding makes (`rounding_drift`: rounds in a geometric ratio to rounding): the remainder
/// is then exact, and so is its variance 0. A series that cannot be sized (fewer than 3
/// rounds, an increment within two standard deviations of its noise, or not shrinking) adds
/// nothing to `B`, and to the variance the bound `rho_max / (1 - rho_max)` times the last
/// increment (or its noise) in power, spread as the reflected light, and never more than
/// `rho_max^m / (1 - rho_max^m)` of it after `m` rounds: missing light is reported, not
/// hidden.
fn with_remainder(
    mesh: &Mesh,
    last: Estimate,
    history: &[Vec<DVec3>],
    rounds: u32,
    noise_free: bool,
) -> Result<Estimate, Error> {
    let patches = mesh.patches();
    let Some(variance) = last.variance() else {
        return Ok(last);
    };
    let b = last.radiosity();
    if history.len() < 2 || history.last().map(Vec::as_slice) != Some(b) {
        return Ok(last);
    }
    let rho = rho_max(mesh);
    let power = |x: &dyn Fn(usize) -> DVec3| -> DVec3 {
        patches.iter().enumerate().map(|(i, p)| x(i) * p.area).sum()
    };
    let n = history.len();
    let incr = |k: usize| power(&|i| history[k][i] - history[k - 1][i]);
    let d1 = incr(n - 1);
    let reflected = power(&|i| (b[i] - patches[i].emission.as_dvec3()).max(DVec3::ZERO));
    let total = power(&|i| b[i]);
    // The variance of `sum_i A_i B_m,i` as if the patches' errors were independent.
    let noise: DVec3 = patches
        .iter()
        .zip(variance)
        .map(|(p, v)| *v * p.area * p.area)
        .sum();
    // Per channel: the remainder's share `r` of the reflected light, its relative uncertainty
    // `delta`, and the standard deviation `open` of a remainder that cannot be sized, as a
    // share of the reflected light.
    let (mut r, mut delta, mut open) = (DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
    for c in 0..3 {
        if reflected[c] <= 0.0 {
            continue;
        }
        // `sum A d_m` is the difference of two rounds' powers.
        let sd = (2.0 * noise[c]).sqrt();
        let q = (n >= 3).then(|| d1[c] / incr(n - 2)[c]);
        match q {
            Some(q) if q.is_finite() && d1[c] > 2.0 * sd && q > 0.0 && q < 1.0 => {
                let q = q.min(rho);
                let drift = if n >= 4 {
                    let q0 = incr(n - 2)[c] / incr(n - 3)[c];
                    if q0.is_finite() {
                        (q - q0).abs() / (1.0 - q)
                    } else {
                        1.0
                    }
                } else {
                    1.0
                };
                r[c] = q / (1.0 - q) * d1[c] / reflected[c];
                // Rounds without noise that shrink by the same ratio to rounding (a furnace:
                // every ray sees the same value) make the remainder exact; otherwise the
                // geometric model is trusted to no better than 1e-3. (Rounding alone moved
                // the ratio by 1.3e-9 of `1 - q` on the rho 0.99 furnace of one patch per
                // face, which a fixed 1e-9 took for a drift.)
                delta[c] = if noise_free && drift <= rounding_drift(total[c], d1[c], q) {
                    0.0
                } else {
                    (drift + sd / d1[c]).max(1e-3)
                };
            }
            // Converged to the noise, or not geometric yet: what is missing is at most the
            // last increment (or its noise) times `rho_max / (1 - rho_max)`.
            // Never beyond what the reflectance allows after `rounds` rounds,
            // `rho_max^m / (1 - rho_max^m)` of the light gathered.
            _ => {
                let bound = series_remainder(mesh, rounds);
                open[c] = (rho / (1.0 - rho) * (d1[c].max(0.0) + sd) / reflected[c])
                    .min(bound / (1.0 - bound).max(1e-12));
            }
        }
    }
    let (radiosity, variance) = b
        .iter()
        .zip(variance)
        .zip(patches)
        .map(|((b, v), p)| {
            let refl = (*b - p.emission.as_dvec3()).max(DVec3::ZERO);
            let (add, open) = (refl * r, refl * open);
            (*b + add, *v + add * add * delta * delta + open * open)
        })
        .unzip();
    Ok(Estimate::new(radiosity, Some(variance), last.rays())?)
}
