//! Stochastic shooting radiosity with constant energy per ray (Balog, section 1.3; Feda and
//! Purgathofer 1993).
//!
//! The solver runs in waves. In wave `k` every patch `i` holding unshot power `U_i = dB_i A_i`
//! (W, per RGB channel) is given `n_i` rays with `E[n_i] = |U_i| / phi_k`, `floor` or `ceil` of
//! it, where `|.|` sums the channels and `phi_k` is the wave's energy per ray; the counts are
//! drawn by systematic sampling of the cumulative power (one uniform offset per wave), so the
//! wave's total is fixed and the small holders share their rays evenly. Each ray leaves a uniform point of the
//! patch in a cosine-distributed direction carrying `U_i / n_i`, so the power a patch sends is
//! exactly its unshot power whatever `n_i` is, and the expected power reaching patch `j` is
//! `U_i F_ij`: the estimate is unbiased for any `n_i >= 1`. The front face of the first patch hit
//! keeps `rho_j` of it, adding `rho_j U_i / n_i` to both its radiosity and its unshot power; the
//! rest is absorbed. A back-face hit is absorbed whole; a ray that hits nothing escapes.
//! A patch given no ray keeps its unshot power for a later wave.
//!
//! `phi_k = |U| / ((1 - r_k) R_k)` spreads the `R_k` rays still in the budget over the power
//! still to come (`|U| / (1 - r_k)` by the geometric series of reflections), so the energy per
//! ray stays nearly constant over the run. `r_k` is the share of the shot power that returns as
//! unshot power (what front-face hits keep, `rho_j` of a ray's power), measured over the rays
//! cast so far and drawn towards the area-weighted mean reflectance `rho_avg` with the weight
//! of [`PRIOR_RAYS`] rays (before the first wave `r_0 = rho_avg`). In a closed scene the two
//! agree; in an open one most power escapes and `rho_avg` would overstate what is to come by
//! up to `1 / (1 - rho_avg)`, so that every wave cast a sliver of the budget and a scene of
//! many small emitters at high reflectance took thousands of waves of `O(patches)` work each
//! (issue 18: 162k open patches at `rho = 0.999` took 3800 waves for 2e4 rays).
//! The waves end when the unshot power falls below a fraction of the emitted power (the
//! threshold), or when the observer says so. What is left below the threshold is not dropped:
//! the finishing roulette below ships it to the last watt. Dropping it biased every run low by
//! up to the threshold's share of the power (issue 36: `prr` under quasi-Monte Carlo rays,
//! -0.008% of the power at 6 standard errors in a small-light room at the default 1e-4); the
//! roulette costs about `threshold × rays` rays more and a few more waves.
//!
//! **Finishing.** When the budget is spent with more than the threshold still unshot, stopping
//! there would lose the light that power has yet to give, a bias of about the unshot fraction
//! (0.2-0.5% on a 2k-patch Cornell box for budgets of 1e4-1e5 rays). Instead the run finishes
//! with Russian roulette at the run's first energy per ray `phi_0`: a patch holding
//! `|U_i| >= phi_0` shoots as before; one holding less shoots a single ray carrying
//! `U_i phi_0 / |U_i|` with probability `|U_i| / phi_0` and drops its power otherwise. The
//! expected power shot is `U_i` either way, so the result stays unbiased, no power waits for a
//! later wave, and the tail costs about `unshot / ((1 - rho_avg) phi_0)` rays more than the
//! budget (a fraction of a percent of it in a normal run). Near `rho = 1` that cost grows like
//! `1 / (1 - rho)` (at `rho = 0.99999`, 26x the budget). Stopping the tail early and dropping
//! the power left was tried and measured (issue 16): it biases every progressive method low
//! (PRR -5%, combined -56% at `rho = 0.999`). So the tail runs, unbiased, wherever it fits in
//! [`ShootConfig::max_overrun`] of the budget (5% by default; a progressive schedule adds the
//! rays of its later passes, which are charged for it), three standard deviations of its
//! random cost included (`m = |U| / phi_0` walks of geometric length `L = 1 / (1 - r)`: `m L`
//! give or take `sqrt(m) L`). Where it does not fit, the run stops at its budget and
//! extrapolates the light the unshot power has yet to give: shot, `U` returns `r` of itself,
//! then `r` of that, so `|U| r / (1 - r)` of reflected light is still to come (per channel,
//! `r` the measured returning share); it is spread as the reflected light so far (after many
//! bounces, the dominant shape), scaling each patch's reflected light, and its noise, by
//! `1 + x`. Exact in a closed scene of uniform reflectance; the uncertainty of `r / (1 - r)`
//! is added to the variance ([`ShootStats::extrapolated`] holds the power treated so).
//!
//! Power is conserved exactly in every realisation (to floating-point rounding):
//! `emitted + roulette = absorbed + escaped + unshot`, where `roulette` (zero until the finish)
//! is the power the finishing roulette added to survivors less what it dropped; its expectation
//! is zero.
//!
//! **The roulette's net power.** What the roulette adds or drops is spread by the bounces after
//! it over the whole scene: every patch's reflected light is off by about the same share, an
//! error common to all patches that per-patch variances do not hold and that gathering from the
//! solution passes on (issue 16: at rho 0.99-0.999 with passes of a few thousand rays, the
//! total power was off by 2-9 times what the patches' variances allowed). The reflected light
//! is therefore scaled by `(emitted - unshot) / (emitted - unshot + roulette)` per channel
//! (exact in a closed scene of uniform reflectance, where the reflected power is
//! `rho / (1 - rho)` times the absorbed), leaving the patches' own noise; the variances are
//! scaled with it. The bias of this ratio is of the order of the roulette's squared relative
//! size.

use crate::context::Context;
use crate::context::Sampler;
use crate::error::Error;
use crate::jobs::SHOOT_QMC;
use crate::method::StopReason;
use crate::replicates::{self, Waves};
use crate::sampling::stochastic_round;
use crate::surface::{Rays, SurfaceSampler};
use glam::DVec3;
use mcrad_combine::Estimate;

use mcrad_random::{Stream, StreamKey, replicate};
use mcrad_raycast::RayCaster;
use rayon::prelude::*;
use std::cell::Cell;
use std::ops::ControlFlow;

/// Settings of a shooting run.
#[derive(Debug, Clone, PartialEq)]
pub struct ShootConfig {
    /// The ray budget (`>= 1`): the waves cast at most this many rays, and a finishing tail of
    /// Russian-roulette rays ships what is still above the threshold when it is spent (see the
    /// documentation of [`shoot`](crate::shoot())).
    pub rays: u64,
    /// End the waves once the unshot power (summed over patches and channels) is at most this
    /// fraction of the emitted power, in `[0, 1]`; the finishing roulette then ships the rest
    /// (unbiased: nothing is dropped). `0` runs the waves until the budget is spent.
    pub unshot_threshold: f64,
    /// Seed of every random stream of the run.
    pub seed: u64,
    /// The most rays the finishing roulette may be expected to cast beyond `rays`, as a share
    /// of `rays` (`>= 0`). Where the tail would cost more (a reflectance so near 1 that the
    /// light still unshot bounces far longer than the budget allows), the run stops at its
    /// budget and extrapolates the light that power has yet to give instead (see the
    /// documentation of [`shoot`](crate::shoot())).
    pub max_overrun: f64,
}

/// [`ShootConfig::max_overrun`]'s default: a finishing tail may cost 5% more rays.
pub const DEFAULT_MAX_OVERRUN: f64 = 0.05;

impl Default for ShootConfig {
    /// One million rays, stop at [`DEFAULT_UNSHOT_THRESHOLD`](crate::DEFAULT_UNSHOT_THRESHOLD)
    /// unshot (the schedules' default), seed 0, a tail of at most
    /// [`DEFAULT_MAX_OVERRUN`] of the budget.
    fn default() -> Self {
        ShootConfig {
            rays: 1_000_000,
            unshot_threshold: crate::DEFAULT_UNSHOT_THRESHOLD,
            seed: 0,
            max_overrun: DEFAULT_MAX_OVERRUN,
        }
    }
}

/// What the observer sees after each wave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShootProgress<'a> {
    /// Waves done.
    pub waves: u32,
    /// Rays cast so far.
    pub rays: u64,
    /// The budget: the configured one, or lower once the observer has limited it
    /// ([`ShootProgress::limit_rays_left`]); `u64::MAX` for none.
    pub budget: u64,
    /// The most rays the next wave may cast: the budget left, or without a budget the run's
    /// planning horizon (`max(2 × rays so far, 100 000)`) less the rays cast so far.
    pub next_rays: u64,
    /// Unshot power left as a fraction of the emitted power (channels summed).
    pub unshot_fraction: f64,
    /// The solution so far, `B_i = E_i + received_i / A_i` (W/m²), in mesh order.
    pub radiosity: &'a [DVec3],
    /// The observer's cap on the rays still to cast (`u64::MAX`: none).
    pub(crate) limit: &'a Cell<u64>,
}

impl ShootProgress<'_> {
    /// Caps the rays the rest of the run may cast at `rays` (the lowest cap given wins): the
    /// waves spread the power still unshot over them and the finishing roulette ships what is
    /// left, as when the configured budget runs out. A caller with a deadline uses this to size
    /// the rest of the run to the time left.
    pub fn limit_rays_left(&self, rays: u64) {
        self.limit.set(self.limit.get().min(rays));
    }
}

/// Counters and power balance of a run. Powers are in W per RGB channel (scene units² × W/m²).
#[derive(Debug, Clone, PartialEq)]
pub struct ShootStats {
    /// Rays cast.
    pub rays: u64,
    /// Waves run.
    pub waves: u32,
    /// Rays that hit nothing (in a closed scene: rays that slipped through an edge).
    pub escaped_rays: u64,
    /// Rays whose first hit was a back face (absorbed there).
    pub back_face_hits: u64,
    /// Emitted power `sum_i E_i A_i`.
    pub emitted: DVec3,
    /// Power absorbed by surfaces.
    pub absorbed: DVec3,
    /// Power carried away by escaped rays.
    pub escaped: DVec3,
    /// Power carried by all rays cast (`absorbed + escaped + ` the reflected share kept by the
    /// patches hit): what left the patches as rays.
    pub shot: DVec3,
    /// Power left unshot at the end (`sum_i U_i`).
    pub unshot: DVec3,
    /// Power the finishing roulette added to surviving rays less the power it dropped (zero
    /// in expectation; zero when the budget sufficed).
    pub roulette: DVec3,
    /// Rays cast by the finishing roulette, included in `rays`.
    pub finishing_rays: u64,
    /// The unshot power whose light was extrapolated instead of shot (zero unless the
    /// finishing tail would have cost more than [`ShootConfig::max_overrun`]); `unshot` is
    /// then zero: `emitted + roulette = absorbed + escaped + unshot + extrapolated`.
    pub extrapolated: DVec3,
    /// Why the run ended.
    pub stop: StopReason,
}

impl ShootStats {
    /// The share of the shot power that left the scene, `escaped / shot` per channel, in
    /// `[0, 1]` (0 before anything was shot): the escape probability of a watt shot, which the
    /// ambient term ([`ambient`](crate::ambient())) discounts.
    pub fn escape_fraction(&self) -> DVec3 {
        let f = |e: f64, s: f64| {
            if s > 0.0 {
                (e / s).clamp(0.0, 1.0)
            } else {
                0.0
            }
        };
        DVec3::new(
            f(self.escaped.x, self.shot.x),
            f(self.escaped.y, self.shot.y),
            f(self.escaped.z, self.shot.z),
        )
    }
}

/// The result of a shooting run.
#[derive(Debug, Clone)]
pub struct Shooting {
    /// Radiosity `B_i = E_i + (received and reflected power)_i / A_i` (W/m²) with its variance:
    /// each hit adds an independent term `x = rho_j U_i / (n_i A_j)`, and `sum x²` estimates the
    /// variance of the sum (compound Poisson, conditional on the unshot powers that were shot).
    /// A patch no ray reached has variance 0 here (the schedules' outputs replace it with
    /// `unreached_variance`'s "no information"). The reflected part and its variance are
    /// scaled to take out the finishing roulette's net power (module documentation).
    pub estimate: Estimate,
    /// Unshot power left on each patch (W per channel): what the ambient term redistributes.
    pub unshot: Vec<DVec3>,
    /// Counters and the power balance.
    pub stats: ShootStats,
    /// Error samples of `estimate`'s radiosity (W/m² per channel, [`SKETCHES`] per patch,
    /// mesh order, kept for the patches reached only; [`Waves::sketch`] divided by the
    /// areas): for weights `c`,
    /// `sum_g (sum_j c_j z_gj)²` estimates the variance of `sum_j c_j B_j`, the correlation
    /// between patches included. Empty when no wave ran.
    ///
    /// [`SKETCHES`]: crate::replicates::SKETCHES
    pub sketch: crate::replicates::Sketch,
    /// The part of `estimate`'s variance that `sketch` does not hold ((W/m²)², per patch and
    /// channel, by the independent-ray formula): deposits of rays alone in their replicate
    /// in a wave (a roulette tail's, mostly) and an extrapolated remainder's.
    pub unsampled: Vec<DVec3>,
    /// The factor on the variance of a face's total that `sketch` gives
    /// ([`Waves::face_scale`]: the stratification across the waves over a whole face),
    /// dimensionless; 1 without a face of several patches.
    pub face_scale: f64,
}

/// Without a budget (`rays == u64::MAX`, a run the observer stops) the waves plan for a
/// horizon of `max(2 × rays so far, UNBOUNDED_FIRST)` rays, so a wave casts at most as many rays
/// as the run has cast so far (or this many at first) and its jobs stay bounded in memory.
const UNBOUNDED_FIRST: u64 = 100_000;
/// The weight, in rays, of the prior `rho_avg` in the measured share of power that returns
/// (see the module documentation).
const PRIOR_RAYS: f64 = 4.0;
/// Rays traced per job: the unit of parallel work and of random streams.
const JOB_RAYS: u64 = 4096;
/// Rays traced before their hits are folded in, bounding the memory of hit records.
const BATCH_RAYS: u64 = 1 << 22;
/// Hit record of a ray that hit nothing.
const MISS: u32 = u32::MAX;
/// Flag of a hit record whose hit was a back face.
const BACK: u32 = 1 << 31;
/// Sub-stream of a patch's ray-count draw (job streams use `1 + chunk`).
const ALLOCATE: u64 = 0;

/// One job: `rays` rays from `patch`, chunk `chunk` of its rays in the wave, the first of them
/// ray `first` of the patch in the run (its index in the patch's quasi-Monte Carlo sequence).
#[derive(Debug, Clone, Copy)]
struct Job {
    patch: u32,
    chunk: u32,
    rays: u32,
    first: u64,
    /// The power of each of its rays (W per channel): the patch's unshot power over its rays
    /// in the wave (held per job, not per patch).
    power: DVec3,
}

#[inline]
fn total(x: DVec3) -> f64 {
    x.x + x.y + x.z
}

/// Solves radiosity on `mesh` by shooting, casting rays through `caster`. `observer` sees the
/// progress after each wave and may stop the run, which then returns the solution so far.
pub fn shoot<C: RayCaster>(
    ctx: &Context<C>,
    config: &ShootConfig,
    observer: &mut dyn FnMut(&ShootProgress) -> ControlFlow<()>,
) -> Result<Shooting, Error> {
    let (mesh, caster) = (ctx.mesh(), ctx.caster());
    if config.rays == 0 {
        return Err(Error::NoRays);
    }
    crate::context::check_precision(mesh)?;
    if !(0.0..=1.0).contains(&config.unshot_threshold) {
        return Err(Error::BadUnshotThreshold(config.unshot_threshold));
    }
    if config.max_overrun.is_nan() || config.max_overrun < 0.0 {
        return Err(Error::BadMaxOverrun(config.max_overrun));
    }
    let patches = mesh.patches();
    if patches.len() >= BACK as usize {
        return Err(Error::TooManyPatches {
            patches: patches.len(),
            limit: BACK as u64,
        });
    }
    // Areas and reflectances are read from the patches (`f64` copies would hold 32 bytes per
    // patch through the run).
    let mut unshot: Vec<DVec3> = patches
        .iter()
        .map(|p| p.emission.as_dvec3() * p.area)
        .collect();
    let emitted: DVec3 = unshot.iter().sum();
    if total(emitted) <= 0.0 {
        return Err(Error::NoEmission);
    }
    let total_area: f64 = patches.iter().map(|p| p.area).sum();
    let rho_avg = (patches
        .iter()
        .map(|p| total(p.reflectance.as_dvec3()) / 3.0 * p.area)
        .sum::<f64>()
        / total_area)
        .min(0.999);
    let sampler = ctx.sampler();
    // Rays each patch has cast in the waves so far: where its sequence goes on.
    let mut cast = vec![0u64; patches.len()];

    // Quasi-Monte Carlo rays: each patch's deposits split by the replicate of the ray's source
    // sequence, wave by wave (crate::replicates).
    // Kept under either sampler: their error samples (`Waves::sketch`) serve both. They also
    // hold, for the patches a deposit reaches only, the sum of the squares of the deposits
    // and the part of it the error samples do not hold (deposits of rays alone in their
    // replicate, `replicate_scale`), made dense once the waves end (`Waves::deposits`).
    // (their tables per face take the faces numbered densely: a coarser mesh's few elements
    // carry face numbers up to the finer mesh's face count)
    let face = replicates::dense_faces(patches.iter().map(|p| p.face));
    let mut waves = Waves::new(face.clone());
    // The reflected power per patch, dense: every wave reads it in patch order.
    let mut reflected = vec![DVec3::ZERO; patches.len()];
    // The radiosity the observer sees, made after every wave (held, not made anew: a fresh
    // array a wave cost its page faults every wave).
    let mut radiosity = vec![DVec3::ZERO; patches.len()];
    // Rays alone in their replicate, waiting for their pair (`replicates::LoneRays`).
    let mut lone = replicates::LoneRays::default();
    let mut stats = ShootStats {
        rays: 0,
        waves: 0,
        escaped_rays: 0,
        back_face_hits: 0,
        emitted,
        absorbed: DVec3::ZERO,
        escaped: DVec3::ZERO,
        shot: DVec3::ZERO,
        unshot: emitted,
        roulette: DVec3::ZERO,
        finishing_rays: 0,
        extrapolated: DVec3::ZERO,
        stop: StopReason::BudgetSpent,
    };
    // The energy per ray of the first wave: the finishing roulette's.
    let mut phi_0: Option<f64> = None;
    // The budget, lowered when the observer limits the rays left.
    let mut budget = config.rays;
    let limit = Cell::new(u64::MAX);
    // The power shot and the part of it kept as unshot power by front-face hits, per channel
    // (W): the measured share of power that returns ([`Returning`]).
    let mut returning = Returning::default();
    let mut extrapolate = false;
    loop {
        let left = total(unshot.iter().sum::<DVec3>());
        // Below the threshold the waves end and the finishing roulette ships what is left, to
        // the last watt: dropping it would bias the run low by up to the threshold's share
        // (module documentation, "Finishing").
        let below = left <= config.unshot_threshold * total(emitted);
        if below {
            stats.stop = StopReason::Converged;
            if left <= 0.0 || phi_0.is_none() {
                break;
            }
        }
        let budget_left = if below {
            0
        } else {
            horizon(budget, stats.rays).saturating_sub(stats.rays)
        };
        let wave = stats.waves as u64;
        let counts = if budget_left > 0 {
            let r = returning_share(&returning, stats.rays, rho_avg);
            let phi = left / ((1.0 - r) * budget_left as f64);
            phi_0.get_or_insert(phi);
            allocate(&unshot, phi, budget_left, config.seed, wave)
        } else {
            let phi = *phi_0.get_or_insert(left / (1.0 - rho_avg));
            // The tail's cost: `m = |U| / phi` walks of `1 / (1 - r)` rays on average, each
            // about as long as its standard deviation (geometric), so the cost is `m L` give
            // or take `sqrt(m) L`; it must fit, three standard deviations included.
            let r = returning.total_share().unwrap_or(rho_avg);
            let (walks, length) = (left / phi, 1.0 / (1.0 - r));
            let tail = (walks + 3.0 * walks.sqrt()) * length;
            if stats.finishing_rays == 0
                && stats.rays as f64 + tail > budget as f64 * (1.0 + config.max_overrun)
            {
                extrapolate = true;
                break;
            }
            let held: Vec<bool> = unshot.iter().map(|u| total(*u) > 0.0).collect();
            let counts = roulette(&mut unshot, phi, config.seed, wave, &mut stats.roulette);
            stats.finishing_rays += counts.iter().sum::<u64>();
            // The error power pending with the power the roulette dropped goes with it.
            for (i, (&held, &n)) in held.iter().zip(&counts).enumerate() {
                if held && n == 0 {
                    waves.drop_pending(i);
                }
            }
            counts
        };
        let mut jobs = wave_jobs(&counts, &cast);
        waves.begin_wave(&counts);
        for job in &mut jobs {
            let i = job.patch as usize;
            job.power = unshot[i] / counts[i] as f64;
        }
        for (u, &n) in unshot.iter_mut().zip(&counts) {
            if n > 0 {
                *u = DVec3::ZERO;
            }
        }
        for batch in batches(&jobs) {
            let hits: Vec<Vec<u32>> = batch
                .par_iter()
                .map(|job| {
                    if ctx.cancelled() {
                        return Vec::new();
                    }
                    trace(job, sampler, ctx.sampling(), caster, config.seed, wave)
                })
                .collect();
            ctx.check_cancelled()?;
            // Fold in job order: the sums do not depend on the thread count.
            for (job, hits) in batch.iter().zip(&hits) {
                let p = job.power;
                // Each replicate's deposits scaled to the whole wave: a patch casting an odd
                // number of rays gives one replicate a ray more, a difference of mean `rho p`
                // on the patches its rays reach that is no error (crate::replicates,
                // `Waves::push`). Made per job, not held per patch.
                let i = job.patch as usize;
                let scale = replicate_scale(cast[i], counts[i]);
                let signs = crate::replicates::source_signs(job.patch as usize);
                let (mut absorbed, mut escaped) = (DVec3::ZERO, 0u64);
                let mut kept_sum = DVec3::ZERO;
                let mut kept_squares = DVec3::ZERO;
                // The error power the rays carry, if any, goes on with them (`Waves::ray`).
                let rho = |j: usize| patches[j].reflectance;
                for (t, &h) in hits.iter().enumerate() {
                    let front = (h != MISS && h & BACK == 0).then_some(h as usize);
                    waves.ray(i, job.first + t as u64, front, rho);
                }
                for (t, &h) in hits.iter().enumerate() {
                    if h == MISS {
                        escaped += 1;
                    } else if h & BACK != 0 {
                        absorbed += p;
                        stats.back_face_hits += 1;
                    } else {
                        let j = h as usize;
                        let kept = patches[j].reflectance.as_dvec3() * p;
                        reflected[j] += kept;
                        unshot[j] += kept;
                        // (with the square of the deposit)
                        let r = replicate(job.first + t as u64);
                        waves.push(j, r, kept, scale.map(|h| h[r]), &signs);
                        kept_sum += kept;
                        kept_squares += kept * kept;
                        absorbed += p - kept;
                    }
                }
                if let (None, [h]) = (scale, hits.as_slice()) {
                    // A ray alone in its replicate: paired with the patch's next lone ray of
                    // the other replicate (`replicates::LoneRays`), or left to the formula.
                    let front = (*h != MISS && *h & BACK == 0).then_some(*h);
                    let rho = |j: u32| patches[j as usize].reflectance.as_dvec3();
                    let r = replicate(job.first);
                    if let Some((j, kept)) = lone.ray(job.patch, r, front, p, &mut waves, rho) {
                        waves.add_unsampled(j as usize, kept * kept);
                    }
                }
                returning.add(p, hits.len() as f64, kept_sum, kept_squares);
                stats.absorbed += absorbed;
                stats.escaped += p * escaped as f64;
                stats.shot += p * hits.len() as f64;
                stats.escaped_rays += escaped;
                stats.rays += hits.len() as u64;
            }
        }
        for (c, n) in cast.iter_mut().zip(&counts) {
            *c += n;
        }
        stats.waves += 1;
        waves.end_wave();
        for ((b, p), r) in radiosity.iter_mut().zip(patches).zip(&reflected) {
            *b = p.emission.as_dvec3() + *r / p.area;
        }
        let progress = ShootProgress {
            waves: stats.waves,
            rays: stats.rays,
            budget,
            next_rays: horizon(budget, stats.rays).saturating_sub(stats.rays),
            unshot_fraction: total(unshot.iter().sum::<DVec3>()) / total(emitted),
            radiosity: &radiosity,
            limit: &limit,
        };
        if observer(&progress).is_break() {
            stats.stop = StopReason::Stopped;
            break;
        }
        budget = budget.min(stats.rays.saturating_add(limit.get()));
    }
    stats.unshot = unshot.iter().sum();
    // What the waves needed goes before the replicates' gains are measured (the run's peak).
    drop(cast);
    waves.end_run();
    drop(radiosity);
    // The sums of squares assume independent rays: scale them by the gain the replicates
    // measure, wave by wave (crate::replicates). Measured before the dense sums are made
    // (its per-face sums, 36 bytes a face, go first, as do the face scale's, 28).
    let face_scale = waves.face_scale();
    let gains = (ctx.sampling() == Sampler::Qmc).then(|| waves.gains(face.iter().copied()));
    let (mut squares, mut unsampled) = waves.deposits();
    for (j, kept) in lone.unpaired(|j| patches[j as usize].reflectance.as_dvec3()) {
        unsampled[j as usize] += kept * kept;
    }
    if let Some(gains) = gains {
        replicates::scale(&mut squares, &gains);
        replicates::scale(&mut unsampled, &gains);
    }
    let (mut sketch, pending, dropped) = waves.sketch();
    if extrapolate {
        let (scale, remainder_variance) = remainder(&reflected, &unshot, &returning);
        // The extrapolation `reflected_i (1 + x)`, `x = |U| r / ((1 - r) sum reflected)`, is
        // linear in the unshot power and the reflected light so far: their errors move it
        // by `z_i (1 + x) + reflected_i x (dU / |U| - sum z / sum reflected)`.
        let (u, so_far): (DVec3, DVec3) = (unshot.iter().sum(), reflected.iter().sum());
        let x = scale - DVec3::ONE;
        let mut sums = [DVec3::ZERO; crate::replicates::SKETCHES];
        for row in sketch.iter() {
            for (g, s) in sums.iter_mut().enumerate() {
                *s += crate::replicates::sample(row, g);
            }
        }
        let shift: Vec<DVec3> = (0..crate::replicates::SKETCHES)
            .map(|g| x * (ratio(pending[g], u) - ratio(sums[g], so_far)))
            .collect();
        // (a patch without a row was reached by no deposit: nothing reflected, its samples
        // stay zero)
        for (i, q) in reflected.iter().enumerate() {
            let Some(row) = sketch.get_mut(i) else {
                continue;
            };
            for (g, shift) in shift.iter().enumerate() {
                let z = crate::replicates::sample(row, g) * scale + *q * *shift;
                row[3 * g..3 * g + 3].copy_from_slice(&z.as_vec3().to_array());
            }
        }
        for (i, (r, q)) in reflected.iter_mut().zip(&mut squares).enumerate() {
            *r *= scale;
            *q = *q * scale * scale + remainder_variance[i];
            unsampled[i] = unsampled[i] * scale * scale + remainder_variance[i];
        }

        stats.extrapolated = stats.unshot;
        stats.unshot = DVec3::ZERO;
        unshot.iter_mut().for_each(|u| *u = DVec3::ZERO);
    }
    // The roulette's net power, a random surplus or deficit that the later bounces spread over
    // every patch: take it out of the reflected light (see the module documentation).
    let scale = roulette_correction(&stats);
    if !extrapolate && stats.unshot == DVec3::ZERO {
        // A finished run: the error power left pending (on patches that will not shoot again:
        // the roulette dropped their power, or the carry of `Waves::ray` reached them after
        // their last shot) and the roulette's dropped error power have a future the samples
        // lack. The roulette's correction `s = kept / actual` restores dropped power over the
        // scene as the light reflected so far, so an error `e` there moves patch `i`'s
        // reflected power by `reflected_i e / actual` (before `s`): so it is added, which
        // also gives the samples the total over the scene that shooting conserves (without it,
        // `sum_i z_i = -(r / (1 - r)) e` in a closed scene of reflectance `r`).
        let actual = stats.emitted - stats.unshot + stats.roulette;
        let shift: Vec<DVec3> = dropped
            .iter()
            .zip(&pending)
            .map(|(d, p)| ratio(*d + *p, actual))
            .collect();
        if shift.iter().any(|s| *s != DVec3::ZERO) {
            for (i, q) in reflected.iter().enumerate() {
                let Some(row) = sketch.get_mut(i) else {
                    continue;
                };
                for (g, shift) in shift.iter().enumerate() {
                    crate::replicates::add_sample(row, g, *q * *shift);
                }
            }
        }
    }
    for (r, q) in reflected.iter_mut().zip(&mut squares) {
        *r *= scale;
        *q *= scale * scale;
    }
    if !sketch.is_empty() {
        for (i, (u, p)) in unsampled.iter_mut().zip(patches).enumerate() {
            let a = p.area;
            if let Some(row) = sketch.get_mut(i) {
                *row = crate::replicates::scaled(row, (scale / a).as_vec3());
            }
            *u *= (scale / a) * (scale / a);
        }
    }
    // The answer in the arrays of the sums (made in place, not beside them).
    let mut radiosity = reflected;
    for (b, p) in radiosity.iter_mut().zip(patches) {
        *b = p.emission.as_dvec3() + *b / p.area;
    }
    let mut variance = squares;
    for (v, p) in variance.iter_mut().zip(patches) {
        *v /= p.area * p.area;
    }
    let estimate = Estimate::new(radiosity, Some(variance), stats.rays)?;
    Ok(Shooting {
        estimate,
        unshot,
        stats,
        sketch,
        unsampled,
        face_scale,
    })
}

/// `a / b` per channel, 0 where `b` is not positive (no power to measure against).
fn ratio(a: DVec3, b: DVec3) -> DVec3 {
    DVec3::new(
        if b.x > 0.0 { a.x / b.x } else { 0.0 },
        if b.y > 0.0 { a.y / b.y } else { 0.0 },
        if b.z > 0.0 { a.z / b.z } else { 0.0 },
    )
}

/// The factors `n / (2 n_r)` that scale the deposits of replicate `r` of a patch's `n` rays in a
/// wave, points `first .. first + n` of its sequence (`n_r` of them of replicate `r`), to
/// estimates of the whole wave's: `None` when a replicate has no ray (a lone ray's error
/// cannot be told from its value, and a difference of mean `rho p` would be taken for one).
fn replicate_scale(first: u64, n: u64) -> Option<[f64; 2]> {
    let even = (first + n).div_ceil(2) - first.div_ceil(2);
    let odd = n - even;
    if even == 0 || odd == 0 {
        return None;
    }
    let n = n as f64;
    Some([n / (2.0 * even as f64), n / (2.0 * odd as f64)])
}

/// The share of shot power that returns as unshot power, per channel: `r = sum kept / sum p`
/// over the rays (`p` a ray's power, `kept` what the patch it hit keeps, `rho_j p`, or 0),
/// with the sums that give the ratio's variance,
/// `var r = sum (kept - r p)² / (sum p)²`.
#[derive(Debug, Default, Clone, Copy)]
struct Returning {
    sent: DVec3,
    kept: DVec3,
    kept_squares: DVec3,
    kept_sent: DVec3,
    sent_squares: DVec3,
}

impl Returning {
    /// `r` over the channels summed, below 1 (`None` before anything was shot).
    fn total_share(&self) -> Option<f64> {
        let sent = total(self.sent);
        (sent > 0.0).then(|| (total(self.kept) / sent).min(1.0 - 1e-12))
    }

    /// Adds `n` rays of power `p` that kept `kept` in all, `kept_squares` the sum of squares.
    fn add(&mut self, p: DVec3, n: f64, kept: DVec3, kept_squares: DVec3) {
        self.sent += p * n;
        self.kept += kept;
        self.kept_squares += kept_squares;
        self.kept_sent += kept * p;
        self.sent_squares += p * p * n;
    }

    /// `r` per channel, below 1, and its variance.
    fn share(&self) -> (DVec3, DVec3) {
        let f = |sent: f64, kept: f64, kk: f64, ks: f64, ss: f64| {
            if sent <= 0.0 {
                return (0.0, 0.0);
            }
            let r = (kept / sent).clamp(0.0, 1.0 - 1e-12);
            let v = ((kk - 2.0 * r * ks + r * r * ss) / (sent * sent)).max(0.0);
            (r, v)
        };
        let (x, y, z) = (
            f(
                self.sent.x,
                self.kept.x,
                self.kept_squares.x,
                self.kept_sent.x,
                self.sent_squares.x,
            ),
            f(
                self.sent.y,
                self.kept.y,
                self.kept_squares.y,
                self.kept_sent.y,
                self.sent_squares.y,
            ),
            f(
                self.sent.z,
                self.kept.z,
                self.kept_squares.z,
                self.kept_sent.z,
                self.sent_squares.z,
            ),
        );
        (DVec3::new(x.0, y.0, z.0), DVec3::new(x.1, y.1, z.1))
    }
}

/// The light the unshot power `U` has yet to give, extrapolated when the finishing tail cannot
/// be afforded: per channel, shooting `U` returns `r` of it, which returns `r` of that, and so
/// on, so the reflected light still to come is `|U| r / (1 - r)`, with `r` the measured
/// returning share ([`Returning`]). It is spread as the reflected light so far, whose shape
/// the many bounces at a reflectance near 1 have already made the dominant one, as a factor
/// `1 + x` on each patch's reflected power, `x = |U| r / ((1 - r) sum_i reflected_i)`. Exact
/// in a closed scene of uniform reflectance, up to the noise of the reflected light so far.
///
/// Returns the factor and the variance to add per patch, `(reflected_i x delta)²` (W², the
/// units of the patches' sums of squared deposits, which the caller divides by `A_i²`), with
/// `delta` the relative uncertainty of `r / (1 - r)`, `sd(r) / (r (1 - r))`, at least 1e-3 (the
/// shape is a model) unless `r` is measured without noise (every hit keeps the same share).
fn remainder(reflected: &[DVec3], unshot: &[DVec3], returning: &Returning) -> (DVec3, Vec<DVec3>) {
    let (r, var_r) = returning.share();
    let u: DVec3 = unshot.iter().sum();
    let so_far: DVec3 = reflected.iter().sum();
    let mut x = DVec3::ZERO;
    let mut delta = DVec3::ZERO;
    for c in 0..3 {
        if so_far[c] <= 0.0 || r[c] <= 0.0 {
            continue;
        }
        x[c] = u[c] * r[c] / ((1.0 - r[c]) * so_far[c]);
        let rel = var_r[c].sqrt() / (r[c] * (1.0 - r[c]));
        delta[c] = if var_r[c] == 0.0 { 0.0 } else { rel.max(1e-3) };
    }
    let variance = reflected
        .iter()
        .map(|q| {
            let add = *q * x * delta;
            add * add
        })
        .collect();
    (DVec3::ONE + x, variance)
}

/// The factor per channel that takes the finishing roulette's net power out of the reflected
/// light: `(emitted - unshot) / (emitted - unshot + roulette)`, 1 without a roulette (see the
/// module documentation). In a closed scene of uniform reflectance the reflected power is
/// `rho / (1 - rho)` times the absorbed, `emitted + roulette - unshot`, so this factor makes
/// it exact; elsewhere it removes the part common to all patches.
fn roulette_correction(stats: &ShootStats) -> DVec3 {
    let kept = stats.emitted - stats.unshot;
    let actual = kept + stats.roulette;
    let f = |k: f64, a: f64, r: f64| {
        if r != 0.0 && k > 0.0 && a > 0.0 {
            k / a
        } else {
            1.0
        }
    };
    DVec3::new(
        f(kept.x, actual.x, stats.roulette.x),
        f(kept.y, actual.y, stats.roulette.y),
        f(kept.z, actual.z, stats.roulette.z),
    )
}

/// The share of shot power that returns as unshot power, `r` in `[0, 0.999]`: the channels'
/// sum measured over `rays` rays ([`Returning::total_share`]), drawn towards `prior` (the mean
/// reflectance) with the weight of [`PRIOR_RAYS`] rays.
fn returning_share(returning: &Returning, rays: u64, prior: f64) -> f64 {
    let measured = returning.total_share().unwrap_or(prior);
    let n = rays as f64;
    ((measured * n + prior * PRIOR_RAYS) / (n + PRIOR_RAYS)).clamp(0.0, 0.999)
}

/// The ray count the waves plan for: the budget, or without one (`u64::MAX`) a horizon that
/// doubles with the rays cast (see [`UNBOUNDED_FIRST`]).
fn horizon(budget: u64, rays: u64) -> u64 {
    if budget == u64::MAX {
        rays.saturating_mul(2).max(UNBOUNDED_FIRST)
    } else {
        budget
    }
}

/// The jobs of one wave: each patch's `counts[i]` rays in chunks of at most [`JOB_RAYS`], its
/// first ray numbered `cast[i]` (the rays it cast in earlier waves).
fn wave_jobs(counts: &[u64], cast: &[u64]) -> Vec<Job> {
    let mut jobs = Vec::new();
    for (i, (&n, &before)) in counts.iter().zip(cast).enumerate() {
        for chunk in 0..n.div_ceil(JOB_RAYS) {
            let rays = (n - chunk * JOB_RAYS).min(JOB_RAYS) as u32;
            jobs.push(Job {
                patch: i as u32,
                chunk: chunk as u32,
                rays,
                first: before + chunk * JOB_RAYS,
                power: DVec3::ZERO,
            });
        }
    }
    jobs
}

/// Ray counts of one wave: systematic sampling of the cumulative power, `n_i = floor(C_i + u) -
/// floor(C_{i-1} + u)` with `C_i = sum_{k <= i} |U_k| / phi` and one uniform `u` for the wave,
/// so `E[n_i] = |U_i| / phi` (each `n_i` is `floor` or `ceil` of it, as stochastic rounding
/// gives) while the wave's total is `C_n` rounded, not a sum of independent roundings. At most
/// `budget` in all, and at least one ray somewhere while power is left.
fn allocate(unshot: &[DVec3], mut phi: f64, budget: u64, seed: u64, wave: u64) -> Vec<u64> {
    let offset = Stream::new(seed, wave, u64::MAX, ALLOCATE).uniform_f64();
    loop {
        let mut cumulative = offset;
        let mut floor_before = offset.floor();
        let counts: Vec<u64> = unshot
            .iter()
            .map(|u| {
                cumulative += total(*u) / phi;
                let f = cumulative.floor();
                let n = (f - floor_before) as u64;
                floor_before = f;
                n
            })
            .collect();
        let sum: u64 = counts.iter().sum();
        if sum > budget {
            // Rare: the draws overshot the budget. Raise the energy per ray and draw again.
            phi *= sum as f64 / budget as f64 * (1.0 + 1e-9);
            continue;
        }
        if sum == 0 {
            // Power is left but every patch rounded down: the largest holder shoots one ray.
            let mut counts = vec![0; unshot.len()];
            let best = (0..unshot.len())
                .max_by(|&a, &b| total(unshot[a]).total_cmp(&total(unshot[b])))
                .expect("a mesh has patches");
            counts[best] = 1;
            return counts;
        }
        return counts;
    }
}

/// Ray counts of a finishing wave at energy per ray `phi` (Russian roulette, see the module
/// documentation): `|U_i| >= phi` gives `round_stochastic(|U_i| / phi)` rays; less gives one ray
/// with probability `|U_i| / phi`, its power scaled to `U_i phi / |U_i|` in `unshot`, or none and
/// the power dropped. What the roulette adds or drops is added to `roulette`.
fn roulette(
    unshot: &mut [DVec3],
    phi: f64,
    seed: u64,
    wave: u64,
    roulette: &mut DVec3,
) -> Vec<u64> {
    unshot
        .iter_mut()
        .enumerate()
        .map(|(i, u)| {
            let size = total(*u);
            if size <= 0.0 {
                return 0;
            }
            let draw = Stream::new(seed, wave, i as u64, ALLOCATE).uniform_f64();
            if size >= phi {
                return stochastic_round(size / phi, draw);
            }
            let before = *u;
            *u = if draw < size / phi {
                before * (phi / size)
            } else {
                DVec3::ZERO
            };
            *roulette += *u - before;
            u64::from(size > 0.0 && *u != DVec3::ZERO)
        })
        .collect()
}

/// Splits jobs into consecutive batches of about [`BATCH_RAYS`] rays.
fn batches(jobs: &[Job]) -> impl Iterator<Item = &[Job]> {
    let mut rest = jobs;
    std::iter::from_fn(move || {
        if rest.is_empty() {
            return None;
        }
        let mut rays = 0u64;
        let end = rest
            .iter()
            .position(|j| {
                rays += j.rays as u64;
                rays > BATCH_RAYS
            })
            .unwrap_or(rest.len())
            .max(1);
        let (head, tail) = rest.split_at(end);
        rest = tail;
        Some(head)
    })
}

/// Traces one job's rays, returning one hit record per ray: random rays from the stream
/// `(seed, wave, patch, 1 + chunk)`, or quasi-Monte Carlo rays `first, first + 1, ...` of the
/// patch's sequence `(seed, 0, patch, SHOOT_QMC)`, one sequence over all the run's waves.
fn trace<C: RayCaster>(
    job: &Job,
    sampler: &SurfaceSampler,
    choice: Sampler,
    caster: &C,
    seed: u64,
    wave: u64,
) -> Vec<u32> {
    let patch = job.patch as u64;
    let mut rays = match choice {
        Sampler::Random => Rays::Random(Stream::new(seed, wave, patch, 1 + job.chunk as u64)),
        Sampler::Qmc => Rays::Qmc {
            sequence: StreamKey::new(seed)
                .item(patch)
                .substream(SHOOT_QMC)
                .sobol(),
            next: job.first,
        },
    };
    (0..job.rays)
        .map(|_| {
            let ray = rays.ray(sampler, job.patch as usize);
            match caster.closest_hit(&ray) {
                None => MISS,
                Some(hit) if hit.front => hit.id,
                Some(hit) => hit.id | BACK,
            }
        })
        .collect()
}

/// Replaces the zero variance of a patch that reflects but that no ray reached (no information,
/// not certainty) in a shooting-based final estimate: per channel with `rho_ic > 0` and
/// `V_ic = 0`, `V_ic = (rho_ic p_c / A_i)²`, the variance of one hit's deposit, with
/// `p_c = sum_j B_jc A_j / N` the mean power per ray (every watt leaving a patch is shot; `N`
/// the estimate's rays). With no hit seen, the mean number of hits expected under a flat prior
/// is 1, so this is what one hit would have said; `z` against any reference stays finite.
/// Applied to a method's final output only, so the combination's variance models (which read
/// the passes' own variances) are unchanged. Patches that do not reflect keep `V = 0`: their
/// `B = E` is certain.
pub(crate) fn unreached_variance(
    mesh: &mcrad_meshing::Mesh,
    estimate: Estimate,
) -> Result<Estimate, Error> {
    if estimate.variance().is_none() || estimate.rays() == 0 {
        return Ok(estimate);
    }
    let patches = mesh.patches();
    let power: DVec3 = estimate
        .radiosity()
        .iter()
        .zip(patches)
        .map(|(b, p)| *b * p.area)
        .sum();
    let rays = estimate.rays();
    let per_ray = power / rays as f64;
    // In place: the estimate's arrays are handed on, not copied.
    let (radiosity, variance, _) = estimate.into_parts();
    let mut variance = variance.unwrap_or_default();
    for (v, p) in variance.iter_mut().zip(patches) {
        let x = p.reflectance.as_dvec3() * per_ray / p.area;
        *v = DVec3::select(v.cmpeq(DVec3::ZERO), x * x, *v);
    }
    Ok(Estimate::new(radiosity, Some(variance), rays)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The quasi-Monte Carlo counter goes on across waves: over a run's waves, the jobs of a
    /// patch cover the indices `0..(its rays in all waves)` of its sequence once each, in
    /// order, whatever the chunking; so any aligned run of `2^m` of its rays is a net.
    #[test]
    fn sequence_indices_continue_across_waves() {
        let waves: [&[u64]; 4] = [
            &[3, 0, 9000],
            &[0, 1, 4096],
            &[5000, 2, 1],
            &[1, 0, 2 * JOB_RAYS + 7],
        ];
        let mut cast = vec![0u64; 3];
        let mut next = vec![0u64; 3];
        for counts in waves {
            let jobs = wave_jobs(counts, &cast);
            for job in &jobs {
                let i = job.patch as usize;
                assert_eq!(job.first, next[i], "patch {i}");
                next[i] += job.rays as u64;
            }
            for (c, n) in cast.iter_mut().zip(counts) {
                *c += n;
            }
            assert_eq!(next, cast);
        }
        assert_eq!(cast, vec![5004, 3, 9000 + 4096 + 1 + 2 * JOB_RAYS + 7]);
    }

    /// Systematic allocation: every count is `floor` or `ceil` of `|U_i| / phi`, the wave's total
    /// is `floor` or `ceil` of their sum, and over many waves each patch's mean count is
    /// `|U_i| / phi` (unbiased). The mean is checked to k = 5 standard errors of a count whose
    /// fractional part is Bernoulli, `sqrt(f (1 - f) / waves)`: a false failure has probability
    /// about 6e-7 per patch, 6e-6 for the test.
    #[test]
    fn systematic_counts_are_unbiased_with_a_fixed_total() {
        let unshot: Vec<DVec3> = [0.3, 2.7, 0.05, 1.0, 0.0, 4.45, 0.2, 0.9, 0.61, 0.33]
            .iter()
            .map(|&u| DVec3::splat(u / 3.0))
            .collect();
        let phi = 0.5;
        let x: Vec<f64> = unshot.iter().map(|u| total(*u) / phi).collect();
        let c: f64 = x.iter().sum();
        let waves = 20_000u64;
        let mut sums = vec![0u64; x.len()];
        for wave in 0..waves {
            let counts = allocate(&unshot, phi, u64::MAX, 7, wave);
            for ((n, x), s) in counts.iter().zip(&x).zip(&mut sums) {
                assert!(
                    *n == x.floor() as u64 || *n == x.ceil() as u64,
                    "{n} from {x}"
                );
                *s += n;
            }
            let total: u64 = counts.iter().sum();
            assert!(
                total == c.floor() as u64 || total == c.ceil() as u64,
                "{total} of {c}"
            );
        }
        for (s, x) in sums.iter().zip(&x) {
            let f = x - x.floor();
            let se = (f * (1.0 - f) / waves as f64).sqrt();
            let mean = *s as f64 / waves as f64;
            assert!(
                (mean - x).abs() <= 5.0 * se + 1e-12,
                "mean {mean} for {x} (se {se})"
            );
        }
    }
}
