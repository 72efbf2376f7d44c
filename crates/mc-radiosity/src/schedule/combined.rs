//! Algorithm 4 of the paper, with the weighting it left open: iterative combined shooting and
//! gathering, merged per patch and channel by inverse variance.
//!
//! Pass `k` (budgets doubling as in the other progressive methods) does three things:
//!
//! 1. **Shoot** with a share `f_k` of its rays; the passes merge by their rays (Algorithm 1)
//!    into the shooting estimate `S`.
//! 2. **Gather** with the rest from the shooting estimate `S`, with the direct/indirect split:
//!    direct light by sampling the emitters, indirect light by gathering `S - E`
//!    ([`two_pass_split`](crate::two_pass_split), its direct samples sized by what they cost). The gathers merge by
//!    their rays (Algorithm 3) into the gathering estimate `G`.
//!
//!    Not from the combination `C`, as the paper's Algorithm 4 does: `C`'s errors are
//!    correlated between patches (every gather smooths its input's errors over the patches
//!    that see them, and gathering from `C` feeds that back), so what a gather inherits from
//!    it is neither known nor small, and `C` itself carries the previous merge's weights.
//!    Measured by `cargo xtask calibrate` (8 seeds): gathering from `C`, spread between seeds
//!    / reported variance was 4.3 at rho 0.9, 21 at 0.99, and the total power +0.17% (4.3
//!    standard errors) at rho 0.5, +3.1% (4.7) at 0.9, +0.32% (4.2) in the tiny-light room;
//!    gathering from `S`, 1.07 / 1.53 / 2.2, and no bias beyond 1.7 standard errors. `S`'s
//!    errors are nearly independent between patches, so a gather inherits from it what the
//!    inherited-noise estimate measures, `rho_i² sum_j F_ij² V_j`; the gathers of the passes inherit
//!    from nested merges of the same shooting passes, so those parts are summed as correlated
//!    (`Gathers`).
//! 3. **Combine**: `C_i = w_i S_i + (1 - w_i) G_i` per patch and channel with a
//!    [`Weighting`]. The default ([`run`], the registry's `combined`) is
//!    [`InverseExpectedVariance`]: `w_i = V^G_i / (V^S_i + V^G_i)`, the minimum-variance weights
//!    of two independent unbiased estimates, from the expected variances below;
//!    [`run_with`] (the crate's `run_combined_with`) takes any other weighting (it sees those expected variances in
//!    its [`Operand`]s).
//!
//! **The variances.** Weights by the estimates' own sample variances bias the merge (they are
//! computed from the samples they weight; see [`mcrad_combine::expected`], measured there at
//! 0.5-3.8% low per face of the 2k-patch Cornell box). The weights use *expected* variances at
//! the reflected radiosity `R_i` of the previous combination (of `S` in the first pass):
//! shooting's shot noise `m_i R_i / A_i`, `m_i = rho_i ×` the mean ray power (what a hit
//! deposits, whether or not one landed; estimated from the deposits it biased the merge at
//! high reflectance), and gathering's relative variance pooled over the patch's input face
//! times `R_i²`, so a patch whose few gathering rays all saw the same value gets its face's
//! relative variance: zero samples mean "unknown", never a zero variance that would take all
//! the weight.
//!
//! **The budget.** A budget under 8 rays per patch (too few to gather everywhere) is spent on
//! shooting alone. Otherwise the first pass shoots with half its rays. Later passes choose the share
//! `f` in `[0.1, 0.9]` that minimises the area-weighted variance the final combination is
//! expected to reach: with per-ray constants `c^S_i = V^S_i n_S` and `c^G_i = V^G_i n_G` from
//! the run so far, the remaining budget `R` would give
//! `sum_i A_i / ((n_S + f R)/c^S_i + (n_G + (1 - f) R)/c^G_i)`. The rays go where they reduce
//! the total error most: to shooting where the scene's patches are mostly lit directly and
//! gathering is noisy, to gathering where shooting's hit counts are the bottleneck.

use super::samples::{self, GatherSamples, Parts, ShotSamples};
use super::{
    Doubling, GATHER_TAG, Gathers, Observer, Progressive, ScheduleConfig, Solution, accumulate,
};
use crate::context::Context;
use crate::direct::{Split, split_with_budget};
use crate::error::Error;
use glam::DVec3;
use mcrad_combine::expected::{pooled_relative_of, shot_noise};
use mcrad_combine::{
    Estimate, EstimateError, InverseExpectedVariance, Operand, Weighting, merge_weighted,
};
use mcrad_meshing::Mesh;
use mcrad_random::StreamKey;
use mcrad_raycast::RayCaster;

/// The weight, in patches of the passes' degrees of freedom, of the scene's measured scale of
/// the gathers' own noise in a face's ([`Parts::prior`](samples::Parts)).
const PRIOR_OWN: f64 = 4.0;

/// Bounds of the shooting share of a pass.
const SHARE: (f64, f64) = (0.1, 0.9);

/// The shooting estimate with what its expected variance needs.
struct Shots {
    /// Passes merged by rays (Algorithm 1).
    merged: Estimate,
    /// Its error samples and the part of its variance they do not hold, the passes' merged
    /// with the same weights (the passes are independent, so samples of the same group add).
    samples: ShotSamples,
    /// Mean power carried by a shooting ray, weighted as the merge weights the passes:
    /// `sum_k w_k² p_k` with `w_k = n_k / n` (W per channel).
    ray_power: DVec3,
}

/// Algorithm 4 with its default weighting, [`InverseExpectedVariance`]: see the
/// [module documentation](self).
pub(crate) fn run<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    with_context(ctx, config, &InverseExpectedVariance, observer)
}

/// Algorithm 4 of Balog's paper, iterative combined shooting and gathering, merging the
/// shooting estimate `S` and the gathering estimate `G` of every pass into
/// `C_i = w_i S_i + (1 - w_i) G_i` with `weighting` (per patch and channel). Each operand
/// carries its expected variance ([`Operand::expected`]: shooting's shot noise `m_i R_i / A_i`,
/// gathering's pooled relative variance times `R_i²`, at the reflected radiosity `R_i` of the
/// previous combination), which [`InverseExpectedVariance`] (the `combined` method's default)
/// weights by. The split of each pass's rays between shooting and gathering still minimises
/// the error expected under inverse-variance weights, whatever `weighting` is.
pub(crate) fn run_with<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    config: &ScheduleConfig,
    weighting: &dyn Weighting,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    with_context(
        &Context::new(mesh, caster)
            .with_sampler(config.sampler)
            .with_control_variate(config.control_variate),
        config,
        weighting,
        observer,
    )
}

/// [`run_with`] on a context built by the caller.
fn with_context<C: RayCaster>(
    ctx: &Context<C>,
    config: &ScheduleConfig,
    weighting: &dyn Weighting,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    let mesh = ctx.mesh();
    let patches = mesh.patches();
    // A pass must pay for 2 direct samples and 2 gathering rays per patch (at most 4 rays), and a
    // shooting share.
    let min_pass = 8 * patches.len() as u64;
    if config.rays < min_pass {
        // Too few rays to gather at every patch even once: shooting alone is the best use.
        return super::shoot::run(ctx, config, observer);
    }
    let mut passes = Doubling::at_least(config, min_pass);
    let mut run = Progressive::default();
    let mut shots: Option<Shots> = None;
    // The gathering estimate `G` is `gathers.estimate()`, made where it is read (the
    // combination, the next pass's share), not held between passes.
    let mut gathers = Gathers::default();
    // The gathers' images of the shooting's error samples and their own noise measured by
    // their replicates, merged by rays as the gathers are.
    let mut gather_samples = GatherSamples::default();
    let (mut shot_rays, mut gather_rays) = (0u64, 0u64);
    // The last combination's correlation factors per face (`Solution::face_correlation`).
    let mut face_correlation = None;
    while let Some(budget) = passes.next().filter(|&b| b >= min_pass) {
        // (The last pass's factors go: this pass sets its own or ends the run with an error.)
        drop(face_correlation.take());
        let k = run.steps as u64;
        let share = match (&shots, gathers.own().is_some(), &run.merged) {
            (Some(s), true, Some(c)) => {
                let vg = gathering_variance(mesh, &gathers.estimate()?, c)?;
                best_share(
                    mesh,
                    &shooting_variance(mesh, s, c),
                    shot_rays,
                    &vg,
                    gather_rays,
                    budget + passes.remaining(),
                )
            }
            _ => 0.5,
        };
        let shoot_budget = ((budget as f64 * share) as u64).max(1);
        let mut s = run.shoot(ctx, config, shoot_budget, passes.remaining(), k)?;
        let pass_rays = s.stats.rays;
        let ray_power = s.stats.shot / pass_rays.max(1) as f64;
        // The passes merge by the rays asked of them (see `Progressive::shoot`).
        let asked = s.estimate.rays();
        // (The unshot power per patch is not read here: it goes before the gathering.)
        drop(std::mem::take(&mut s.unshot));
        shot_rays += asked;
        shots = Some(match shots.take() {
            None => Shots {
                samples: ShotSamples::take(&mut s),
                merged: s.estimate,
                ray_power,
            },
            Some(old) => {
                let w = asked as f64 / shot_rays as f64;
                Shots {
                    samples: old.samples.merge(ShotSamples::take(&mut s), w),
                    merged: accumulate(Some(old.merged), s.estimate)?,
                    ray_power: old.ray_power * (1.0 - w).powi(2) + ray_power * w * w,
                }
            }
        });
        let shots_now = shots.as_ref().expect("just set");

        // Gather from the shooting estimate, whose errors are (nearly) independent between
        // patches, so what a gather inherits from it is the inherited-noise term; not from the
        // combination, whose errors the gathers themselves correlate (module documentation).
        let gather_budget = budget.saturating_sub(pass_rays);
        let Split {
            estimate: g,
            inherited,
            image,
            own_errors,
            image_variance,
        } = split_with_budget(
            ctx,
            &shots_now.merged,
            Some(&shots_now.samples.sketch),
            gather_budget,
            StreamKey::new(config.seed).derive(GATHER_TAG + k),
        )?;
        // What the pass did not use (rays per patch are whole) goes to the passes after it.
        passes.refund(budget.saturating_sub(pass_rays + g.rays()));
        // And what the shooting cast beyond its share (its roulette tail) is taken from them.
        passes.charge((pass_rays + g.rays()).saturating_sub(budget));
        gather_rays += g.rays();
        run.rays += g.rays();
        // This gather's image of the shooting's samples, and its own noise measured: its
        // independent parts' error samples (the indirect gathering's and the direct light's
        // replicates).
        gather_samples.add(
            image,
            &[&own_errors[0], &own_errors[1]],
            &image_variance,
            g.rays(),
        );
        // (What the pass's parts held goes as soon as it is added in: the combination below
        // is the run's peak of memory.)
        drop((own_errors, image_variance));
        gathers.add(g, &inherited)?;
        drop(inherited);
        let g = gathers.estimate()?;
        let own = gathers.own().ok_or(EstimateError::MissingVariance)?;
        let (c, factors) = combine(
            mesh,
            shots_now,
            (&g, own, &gather_samples),
            ctx.sampling() == crate::Sampler::Qmc,
            run.merged.as_ref(),
            weighting,
        )?;
        face_correlation = factors;
        drop(g);
        if !run.replace(c, &mut passes, observer)? {
            break;
        }
    }
    let mut solution = run.finish(config.rays)?;
    solution.face_correlation = face_correlation;
    Ok(solution)
}

/// The reflected radiosity `R_i = (B_i - E_i)^+` of patch `i` the expected variances scale
/// with (W/m²), from `proxy`: the previous combination, or the shooting estimate before there
/// is one.
fn reflected(mesh: &Mesh, proxy: &Estimate, i: usize) -> DVec3 {
    (proxy.radiosity()[i] - mesh.patches()[i].emission.as_dvec3()).max(DVec3::ZERO)
}

/// The expected variance of the shooting estimate per patch and channel, `m_i R_i / A_i`
/// ((W/m²)², [`shot_noise`]), with `m_i = rho_i` times the mean power a ray carried (what a hit
/// deposits, known whatever landed: see [`mcrad_combine::expected`] for why not the deposits'
/// own mean) and `R_i` the [`reflected`] radiosity of `proxy`.
fn shooting_variance(mesh: &Mesh, shots: &Shots, proxy: &Estimate) -> Vec<DVec3> {
    mesh.patches()
        .iter()
        .enumerate()
        .map(|(i, p)| {
            shot_noise(
                p.reflectance.as_dvec3() * shots.ray_power,
                p.area,
                reflected(mesh, proxy, i),
            )
        })
        .collect()
}

/// The expected variance of the gathering estimate per patch and channel, `k_f R_i²`
/// ((W/m²)²), with `k_f` the gather's relative variance pooled over the input face `f` of the
/// patch ([`pooled_relative_of`]), so a patch whose few rays all saw the same value (a sample
/// variance of zero) is not taken as exact, and `R_i` the [`reflected`] radiosity of `proxy`.
fn gathering_variance(
    mesh: &Mesh,
    gathered: &Estimate,
    proxy: &Estimate,
) -> Result<Vec<DVec3>, Error> {
    let v = gathered.variance().ok_or(EstimateError::MissingVariance)?;
    let patches = mesh.patches();
    // (the faces numbered densely: a coarser mesh's elements carry face numbers up to the
    // finer mesh's face count)
    let face = crate::replicates::dense_faces(patches.iter().map(|p| p.face));
    let faces = face.iter().max().map_or(0, |&f| f as usize + 1);
    let k = pooled_relative_of(
        faces,
        patches
            .iter()
            .zip(&face)
            .zip(v)
            .zip(gathered.radiosity())
            .map(|(((p, &f), v), g)| (f as usize, *v, *g - p.emission.as_dvec3())),
    );
    Ok((0..patches.len())
        .map(|i| {
            let r = reflected(mesh, proxy, i);
            k[face[i] as usize] * r * r
        })
        .collect())
}

/// `S` and `G` merged by `weighting`, each operand carrying its expected variance at the
/// reflected radiosity of `previous` (the last combination; `S` in the first pass).
///
/// The variance reported is the merge's error, `C_i - B_i = w_i e^S_i + (1 - w_i) e^G_i`, with
/// `e^G_i` made of the gathers' own noise (their rays and emitter samples, independent of `S`)
/// and what they inherit from `S`, `rho_i sum_j F̂_ij e^S_j`, which is correlated with `e^S_i`
/// and between patches (shooting conserves power: in a closed furnace of one patch per face a
/// gather inherits `-0.2 rho e^S_i`, not `rho² sum_j F_ij² V_j`). Both parts of `e^S` come
/// from the same error samples `z_g` ([`Row`]: `S`'s and their images through the gathers,
/// `y_g`), so
/// `V_i = (1 - w_i)² own^G_i + sum_g (w_i z_gi + (1 - w_i) y_gi)²`, per channel, for what
/// the samples hold. ([`samples::variance`] computes it; the methods that gather from a
/// shooting alone use it with `w = 0`.)
///
/// **The gathers' own noise** `own^G_i` is, under quasi-Monte Carlo rays, what their
/// replicates measure (`measured`: per pass the squares of the indirect gathering's and the
/// direct light's signed replicate differences, merged by rays as the gathers are; unbiased,
/// one degree of freedom a pass and part): the independent-ray formula `own` keeps its shape
/// over the patches of an input face `f` and takes the face's measured scale,
/// `own_i sum_f measured / sum_f own`. A face of many patches measures it with many degrees
/// of freedom; a face of one patch (`--no-subdivide`) with one per pass and part, where the
/// formula (drawn towards by each round's own gain) overstated its stratified rays' noise
/// about ten times (the slivers room of `cargo xtask calibrate`). So few degrees of freedom
/// inflate `z²`: a face's measured scale is drawn towards the scene's with the weight of
/// `PRIOR_OWN` patches. The values a gather's rays see carry the shooting's error, so its
/// measured noise holds the rays' sampling of that error, `(T̂ - T) e^S`, which the images
/// `y_g = T̂ z_g` (the same rays) hold as well: each pass takes out of its measure the
/// replicates' variance of its images (`Split::image_variance`). In a furnace, where every
/// patch has the same radiosity, that is all of the gathers' noise; counted twice, `combined`
/// reported 1.2-1.8 times its spread on the subdivided furnaces (the median patch), 0.96-1.01
/// without (`cargo xtask calibrate`, 32 seeds).
///
/// **What the samples miss**: rays alone in their replicate (a roulette tail's most of all)
/// are shooting's error of the same transport, so it is taken to reach the combination as the
/// held part does over the scene: `t sum_g z_g² -> sum_g (w z_g + (1 - w) y_g)²` summed over
/// every patch gives the factor `t` (per channel), and patch `i` adds `t U_i M_f / U_f`, with
/// `U_i` the lone rays' independent-ray formula and `M_f` the missed part of its input face
/// `f`: at most what the gain-calibrated total `V^S_f` leaves beyond the samples' `Z_f =
/// sum_g z_g²` and at most `U_f` (each overstates it somewhere: `U` under stratified rays,
/// `V^S` on faces of one patch, whose gain is drawn towards the formula). (The face's own
/// factor `1 + M_f / Z_f` on the sampled term, with 8 samples of a face of one patch in its
/// denominator, made a few patches of the slivers room report thousands of times their
/// spread: pooled spread / reported 0.000 over 64 seeds, 0.77 now.) Or, where smaller, the
/// two summed as independent ([`samples`](super::samples)).
/// (`w² V_S + (1 - w)² V_G`, the two as independent, overstated the error 3-14 times on faces
/// of one patch; summing `U` and `phi H` as independent of the samples overstated it 5 times
/// on the rho 0.99 furnace of one patch per face and 1.5 times on the subdivided one:
/// `cargo xtask calibrate`, cases `furnace-*`, `*-faces` and `slivers`.)
fn combine(
    mesh: &Mesh,
    shots: &Shots,
    (gathered, own, gather_samples): (&Estimate, &Estimate, &GatherSamples),
    measured: bool,
    previous: Option<&Estimate>,
    weighting: &dyn Weighting,
) -> Result<(Estimate, Option<Vec<DVec3>>), Error> {
    let (ea, eb) = (&shots.merged, gathered);
    // The weights `w_i` per channel, as `merge` would weight; the expected variances they are
    // made from go before the variance's sums (this is the run's peak of memory: one array a
    // patch at a time, beside the result).
    let weights = {
        let proxy = previous.unwrap_or(&shots.merged);
        let vs = shooting_variance(mesh, shots, proxy);
        let vg = gathering_variance(mesh, gathered, proxy)?;
        mcrad_combine::weights(
            &Operand::with_expected(ea, &vs),
            &Operand::with_expected(eb, &vg),
            weighting,
        )?
    };
    let own = own.variance().ok_or(EstimateError::MissingVariance)?;
    let parts = Parts {
        shot: &shots.samples,
        shot_variance: shots
            .merged
            .variance()
            .ok_or(EstimateError::MissingVariance)?,
        gathered: gathered.variance().ok_or(EstimateError::MissingVariance)?,
        own,
        gathers: gather_samples,
        measured,
        // Each pass gathers once: its own noise is measured with a degree of freedom a pass
        // and part, so a face of one patch is drawn towards the scene's scale with the
        // weight of `PRIOR_OWN` patches (mean z² 1.63 -> 1.33 in calibrate's slivers
        // corridor, spread / reported in target before and after).
        prior: PRIOR_OWN * gather_samples.rounds().max(1.0),
        // its samples' part mixes shooting's own samples with the gathers' images
        sample_prior: 0.0,
    };
    let sampled = samples::variance(mesh, &parts, &weights);
    // `w S + (1 - w) G`, with `merge`'s variance `w² V_S + (1 - w)² V_G` where the samples do
    // not fit.
    let merged = merge_weighted(ea, eb, &weights)?;
    drop(weights);
    let Some((variance, factors)) = sampled else {
        return Ok((merged, None));
    };
    let (radiosity, _, rays) = merged.into_parts();
    Ok((
        Estimate::new(radiosity, Some(variance), rays)?,
        Some(factors),
    ))
}

/// The shooting share `f` in [`SHARE`] of the next `remaining` rays that minimises the expected
/// area-weighted variance of the final combination (module documentation), on a grid of 0.05.
fn best_share(
    mesh: &Mesh,
    shooting_variance: &[DVec3],
    shot_rays: u64,
    gv: &[DVec3],
    gather_rays: u64,
    remaining: u64,
) -> f64 {
    let (ns, ng, r) = (shot_rays as f64, gather_rays as f64, remaining as f64);
    let expected = |f: f64| -> f64 {
        mesh.patches()
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let cs = shooting_variance[i] * ns;
                let cg = gv[i] * ng;
                let mut v = 0.0;
                for c in 0..3 {
                    let precision = |c_: f64, n: f64| if c_ > 0.0 { n / c_ } else { f64::INFINITY };
                    let total = precision(cs[c], ns + f * r) + precision(cg[c], ng + (1.0 - f) * r);
                    v += if total.is_finite() { 1.0 / total } else { 0.0 };
                }
                p.area * v
            })
            .sum()
    };
    let steps = ((SHARE.1 - SHARE.0) / 0.05).round() as usize;
    (0..=steps)
        .map(|s| SHARE.0 + 0.05 * s as f64)
        .min_by(|a, b| expected(*a).total_cmp(&expected(*b)))
        .unwrap_or(0.5)
}
