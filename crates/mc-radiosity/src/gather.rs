//! Gathering stochastic radiosity (Balog, section 1.4): every patch (or vertex) estimates the
//! light it receives by casting cosine-distributed rays and averaging the radiosity they hit.
//!
//! For patch `i` and `n` rays leaving uniform points of `P_i` with the cosine density, the first
//! front face hit by ray `k` is patch `j_k` with probability `F_{i j_k}`, so
//!
//! ```text
//! B'_i = E_i + rho_i (1/n) sum_k input[j_k]        (W/m² per RGB channel)
//! ```
//!
//! is an unbiased estimate of `E_i + rho_i sum_j F_ij input_j`: one Jacobi step of the radiosity
//! system applied to `input` ([`gather_round`]). A ray that escapes, or whose first hit is a back
//! face, brings 0 (a back face absorbs; an escaped ray sees nothing). The rays of a patch are
//! independent, so with `s²` the sample variance of `input[j_k]` over its rays, `rho_i² s² / n`
//! estimates the variance of `B'_i` (conditional on `input`).
//!
//! Iterating from `B = E` gives Jacobi iteration ([`gather`]): after `m` rounds the expected
//! result is the `m`-bounce solution `sum_{k <= m} (rho F)^k E`, since each round uses fresh rays
//! and is linear in its input. [`gather_corners`] gathers at mesh vertices instead of over patches
//! (section 1.5), so smooth shading needs no extrapolation.
//!
//! An example of one round is on the crate's `gather_from`, which runs [`gather_round`].
//!
//! # Randomness and determinism
//!
//! `seed` and `pass` below are the fields of the [`StreamKey`] the
//! caller passes.
//!
//! Patch `i`'s rays in round `pass` come from `Stream::new(seed, pass, i, PATCH_GATHER + chunk)`,
//! one stream per chunk of 4096 rays; vertex group `g`'s from
//! `Stream::new(seed, pass, g, VERTEX_GATHER + chunk)`, and [`direct`](crate::direct())'s
//! samples from `Stream::new(seed, pass, i, DIRECT_LIGHT + chunk)`, with the tags
//! `PATCH_GATHER = 2^40`, `VERTEX_GATHER = 2 · 2^40` and `DIRECT_LIGHT = 3 · 2^40`. The tags keep
//! these streams apart from shooting's (sub-streams `0` and `1 + chunk`) and from each other, so
//! estimators run with the same `(seed, pass)` are independent. Chunks run in parallel and their
//! moments are merged per item in chunk order, so a seed gives bit-identical results on any
//! number of threads. A schedule must give every round it wants independent of the others its
//! own `pass` (or its own seed, e.g. from [`derive_seed`](mcrad_random::derive_seed)).
//!
//! With [`Sampler::Qmc`](crate::Sampler) (the context's [`Context::with_sampler`]) the rays of
//! patch `i` in round `pass` are instead points `0, 1, ...` of the sequence
//! [`Sobol`](mcrad_random::Sobol)`(seed, pass, i, PATCH_GATHER)` (chunk `c` starts at point
//! `4096 c`), vertex groups' of `(seed, pass, g, VERTEX_GATHER)` and the direct light's of
//! `(seed, pass, i, DIRECT_LIGHT)`: stratified within a round, independent between rounds,
//! patches and estimators. The sampling variances are then scaled by the gain the sequences'
//! two interleaved scrambles measure, per input face (module `replicates`).

use crate::context::{Context, Sampler};
use crate::control::Control;
use crate::direct::CosineLight;
use crate::error::Error;
use crate::jobs::{PATCH_GATHER, Seen, Tally, VERTEX_GATHER, fold, look, look_with};
use crate::method::StopReason;
use crate::replicates::{self, Measure};
use crate::sampling::{Frame, cosine_hemisphere_concentric, cosine_hemisphere_rejection};
use crate::surface::Rays;
use glam::{DVec3, Vec3};
use mcrad_combine::Estimate;
use mcrad_meshing::{CornerGroups, Mesh};
use mcrad_random::StreamKey;
use mcrad_raycast::{NO_ID, Ray, RayCaster};
use std::ops::ControlFlow;

/// Whether a gathering result includes the patch's own emission.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Emission {
    /// `B'_i = E_i + rho_i * (mean gathered radiosity)`: a complete radiosity.
    Include,
    /// `B'_i = rho_i * (mean gathered radiosity)`: the reflected part only, to be added to other
    /// parts (the direct/indirect split of [`two_pass_split`](crate::two_pass_split)).
    Exclude,
}

/// Checks that `input` has one finite value per patch of `mesh`.
pub(crate) fn check_input(mesh: &Mesh, input: &[DVec3]) -> Result<(), Error> {
    let patches = mesh.patches().len();
    if input.len() != patches {
        return Err(Error::InputLength {
            patches,
            got: input.len(),
        });
    }
    if patches >= NO_ID as usize {
        return Err(Error::TooManyPatches {
            patches,
            limit: NO_ID as u64,
        });
    }
    match input.iter().position(|b| !b.is_finite()) {
        Some(patch) => Err(Error::NotFinite {
            patch,
            value: input[patch],
        }),
        None => Ok(()),
    }
}

/// The result of one gathering round over all patches.
#[derive(Debug, Clone, PartialEq)]
pub struct GatherRound {
    /// `B'_i` per patch (W/m², with or without `E_i` as asked) and its variance
    /// `rho_i² s_i² / n` ((W/m²)², conditional on the input); `rays` = rays cast.
    pub estimate: Estimate,
    /// Rays that hit nothing (contributing 0).
    pub escaped_rays: u64,
    /// Rays whose first hit was a back face (contributing 0).
    pub back_face_hits: u64,
    /// Where the caller gave the input's error samples ([`crate::replicates::Row`], W/m²):
    /// their gathered image per patch, `rho_i (1/n) sum_k z_g[j_k]`, the error the round
    /// inherits from its input, sample by sample; empty otherwise.
    pub(crate) sketch: Vec<crate::replicates::Row>,
    /// Where `sketch` is: per patch, the replicates' estimate of the variance of its image
    /// over the round's rays, summed over the samples ((W/m²)² per channel,
    /// `rho_i² / n_i²` times [`Seen::sketch_variance`]): the part of the round's own noise
    /// that comes from the input's error, which the image holds too; empty otherwise.
    pub(crate) sketch_variance: Vec<DVec3>,
    /// Per patch, the replicates' signed error sample of the round's own noise (W/m² per
    /// channel, `rho_i` times [`Halves::error_of_mean`](crate::replicates::Halves) of the
    /// values its rays saw): mean zero given the input, its square unbiased for the variance
    /// of the patch's stratified rays with one degree of freedom.
    pub(crate) errors: Vec<DVec3>,
}

/// One Jacobi gathering round (Balog, section 1.4): every patch `i` casts `rays_per_patch`
/// cosine-distributed rays from uniform points of itself (a uniform point, a cosine-distributed direction) and gets
///
/// ```text
/// B'_i = [E_i] + rho_i (1/n) sum_k input[j_k]      (W/m² per channel)
/// ```
///
/// with `j_k` the patch whose front ray `k` hits first (a miss or a back-face hit contributes 0)
/// and `E_i` added for [`Emission::Include`]. `input` is a radiosity per patch (W/m²), e.g. the
/// previous round's result or a shooting solution. The expected value is
/// `[E_i] + rho_i sum_j F_ij input_j`.
///
/// The variance reported per patch and channel is `rho_i² s² / n`, `s²` the unbiased sample
/// variance of `input[j_k]` over the patch's `n` rays: the variance of the mean given `input`
/// (noise already in `input` is not included). It is 0 when every ray of a patch saw the same
/// value, which for few rays can happen by chance. `Estimate::rays` is `patches × n`.
///
/// Parallel over chunks of rays; random streams `(seed, pass, patch, PATCH_GATHER + chunk)`, so
/// the result depends on `(seed, pass)` only, not on the thread count.
///
/// Errors: `input` not one finite value per patch, or `rays_per_patch < 2`.
pub fn gather_round<C: RayCaster>(
    ctx: &Context<C>,
    input: &[DVec3],
    emission: Emission,
    rays_per_patch: u32,
    key: StreamKey,
) -> Result<GatherRound, Error> {
    round(ctx, input, None, emission, rays_per_patch, key)
}

/// [`gather_round`] from an estimate: the same values, and the variance reported per patch
/// adds the noise the input's own variance `V_j` carries into the gather,
/// `rho_i² sum_j F_ij² V_j`, estimated from the same rays: a ray hits `j` with probability
/// `F_ij`, so the mean over the rays of `F̂_ij V_j` estimates it, with `F̂_ij` the form factor
/// from the ray's origin to a disc of patch `j`'s area at the hit (`A_j cos_i cos_j /
/// (pi r² + A_j)`, Wallace et al. 1989; near and large patches make it approximate). Earlier
/// the estimate counted collisions of consecutive rays (two independent rays hit the same `j`
/// with probability `F_ij²`): unbiased, but with 1,600 patches about one pair in a thousand
/// collides, so it was zero for most patches and large for a few, and a patch's `z²` followed
/// its luck (`cargo xtask calibrate`, 16 seeds: `combined`'s mean `z²` 1.31-1.38 at rho
/// 0.9-0.999, `progressive-gather` 1.34-1.50 and a pooled spread/reported of 1.54 at 0.99;
/// with the disc, 0.94-1.02 and 0.93-1.05). On a coarse mesh this dominates (the Cornell box's 19 faces: a block face's gathered variance was
/// 20 times the conditional one); on a fine one it is small. An input without variances adds
/// nothing.
pub fn gather_round_from<C: RayCaster>(
    ctx: &Context<C>,
    input: &Estimate,
    emission: Emission,
    rays_per_patch: u32,
    key: StreamKey,
) -> Result<GatherRound, Error> {
    round(
        ctx,
        input.radiosity(),
        input.variance(),
        emission,
        rays_per_patch,
        key,
    )
}

/// [`gather_round_from`] with the inherited part of its variance apart: the round, and per
/// patch and channel `rho_i² sum_j F_ij² V_j` ((W/m²)², the estimate above; zeros for an
/// input without variances), which the round's variance includes. A schedule that gathers
/// several times from inputs sharing their noise (nested merges of the same shooting passes)
/// needs it apart: the inherited parts of those gathers are correlated, their own parts are not.
///
/// With `sketch` (the input's error samples per patch), the round's rays also gather them
/// into their image ([`GatherRound::sketch`]): the error the round inherits, sample by sample.
pub(crate) fn gather_round_parts<C: RayCaster>(
    ctx: &Context<C>,
    input: &Estimate,
    sketch: Option<&[crate::replicates::Row]>,
    emission: Emission,
    rays_per_patch: u32,
    key: StreamKey,
) -> Result<(GatherRound, Vec<DVec3>), Error> {
    round_parts(
        ctx,
        input.radiosity(),
        input.variance(),
        emission,
        rays_per_patch,
        key,
        Side {
            sketch,
            ..Side::default()
        },
    )
}

/// [`gather_round`] with the input variance of [`gather_round_from`] optional.
fn round<C: RayCaster>(
    ctx: &Context<C>,
    input: &[DVec3],
    input_variance: Option<&[DVec3]>,
    emission: Emission,
    rays_per_patch: u32,
    key: StreamKey,
) -> Result<GatherRound, Error> {
    Ok(round_parts(
        ctx,
        input,
        input_variance,
        emission,
        rays_per_patch,
        key,
        Side::default(),
    )?
    .0)
}

/// [`gather_round_parts`] whose rays also carry the cosine half of the direct light's multiple
/// importance sampling: a ray of patch `i` whose first hit is the front of an emitter adds
/// `light`'s share of its emission ([`CosineLight::share`]) to the input it sees there, so the
/// round's mean is `rho_i sum_j F_ij input_j` plus the cosine strategy's part of `D_i`, with one
/// sample variance over both (they come from the same rays). Gathers with
/// [`Emission::Exclude`]: the light emitted is the direct light's business. Without `light`
/// (a scene without emitters) this is [`gather_round_parts`] with [`Emission::Exclude`].
pub(crate) fn gather_round_parts_with_light<C: RayCaster>(
    ctx: &Context<C>,
    input: &[DVec3],
    input_variance: Option<&[DVec3]>,
    light: Option<&CosineLight>,
    sketch: Option<&[crate::replicates::Row]>,
    rays_per_patch: u32,
    key: StreamKey,
) -> Result<(GatherRound, Vec<DVec3>), Error> {
    round_parts(
        ctx,
        input,
        input_variance,
        Emission::Exclude,
        rays_per_patch,
        key,
        Side {
            light,
            pool: None,
            sketch,
        },
    )
}

/// What a round does besides gathering its input ([`round_parts`]).
#[derive(Default)]
struct Side<'a> {
    /// The cosine half of the direct light's multiple importance sampling, carried by the
    /// rays ([`gather_round_parts_with_light`]).
    light: Option<&'a CosineLight<'a>>,
    /// The emission seen by the earlier rounds of a Jacobi run ([`gather`]), which this
    /// round's joins and which takes the place of this round's own in the variances.
    pool: Option<&'a mut EmittedPool>,
    /// The input's error samples per patch, gathered by the same rays
    /// ([`GatherRound::sketch`]).
    sketch: Option<&'a [crate::replicates::Row]>,
}

/// The emission `E_j` the rays of a Jacobi run's rounds saw, per input face: the sums over
/// the face's patches and the rounds so far of the within-patch sums of squared deviations
/// (W/m²)², and their degrees of freedom. Every round of [`gather`] sees the emitters through
/// the same geometry, so this is one sample of the same distribution growing round by round,
/// while a single round's may have missed a small light altogether.
#[derive(Debug, Default)]
struct EmittedPool {
    m2: Vec<DVec3>,
    dof: Vec<u64>,
}

/// [`gather_round_from`] of round `k` of a Jacobi run ([`gather`]), whose input includes the
/// emission (`B_k`), with the emission's variance pooled over the run's rounds in `pool`.
fn gather_round_pooled<C: RayCaster>(
    ctx: &Context<C>,
    input: &Estimate,
    rays_per_patch: u32,
    key: StreamKey,
    pool: &mut EmittedPool,
) -> Result<GatherRound, Error> {
    Ok(round_parts(
        ctx,
        input.radiosity(),
        input.variance(),
        Emission::Include,
        rays_per_patch,
        key,
        Side {
            light: None,
            pool: Some(pool),
            sketch: None,
        },
    )?
    .0)
}

/// [`round`] and the inherited part of its variance ([`gather_round_parts`]), its rays also
/// scoring `light` where given ([`gather_round_parts_with_light`]).
fn round_parts<C: RayCaster>(
    ctx: &Context<C>,
    input: &[DVec3],
    input_variance: Option<&[DVec3]>,
    emission: Emission,
    rays_per_patch: u32,
    key: StreamKey,
    side: Side<'_>,
) -> Result<(GatherRound, Vec<DVec3>), Error> {
    let Side {
        light,
        pool,
        sketch,
    } = side;
    if let Some(z) = sketch
        && z.len() != input.len()
    {
        return Err(Error::InputLength {
            patches: input.len(),
            got: z.len(),
        });
    }
    let (mesh, sampler, caster) = (ctx.mesh(), ctx.sampler(), ctx.caster());
    check_input(mesh, input)?;
    if let Some(v) = input_variance {
        check_input(mesh, v)?;
    }
    if rays_per_patch < 2 {
        return Err(Error::TooFewRays(rays_per_patch));
    }
    let patches = mesh.patches();
    // Without the control variate, none: every patch's is the default (no control).
    let controls = match ctx.coverage() {
        Some(coverage) => coverage.controls(patches.len(), rays_per_patch),
        None => Vec::new(),
    };
    let control = |i: usize| controls.get(i).copied().unwrap_or_default();
    // What the round keeps per patch, made as the jobs come (nothing per job): its answer,
    // the noise it inherits, the image of the input's error samples, its input face's sums
    // and what the face pooling reads of it ([`Own`]); with the control variate, what the
    // coverage learns.
    let n = patches.len();
    let mut out = Finish::with_capacity(n);
    let mut inherited: Vec<DVec3> = Vec::with_capacity(n);
    let mut image: Vec<crate::replicates::Row> =
        Vec::with_capacity(if sketch.is_some() { n } else { 0 });
    let mut image_variance: Vec<DVec3> = Vec::with_capacity(if sketch.is_some() { n } else { 0 });
    // (its input faces numbered densely: a coarser mesh's elements carry face numbers up to
    // the finer mesh's face count, and the sums are per face)
    let face = crate::replicates::dense_faces(patches.iter().map(|p| p.face));
    let mut faces = FaceSums::new(face.iter().max().map_or(0, |&f| f as usize + 1));
    let mut own: Vec<Own> = Vec::with_capacity(n);
    let coverage = ctx.coverage();
    let mut learned: Vec<(u64, u64, DVec3)> =
        Vec::with_capacity(if coverage.is_some() { n } else { 0 });
    let gathered = |job: &crate::jobs::Job| {
        if ctx.cancelled() {
            return Seen::default();
        }
        let mut rays = Rays::for_chunk(
            ctx.sampling(),
            key.item(job.item as u64),
            PATCH_GATHER,
            job.chunk,
        );
        let ray = || rays.ray(sampler, job.item as usize);
        let beta = control(job.item as usize).beta;
        let inherit = input_variance.map(|v| (v, patches));
        match light {
            None if sketch.is_none() => look(job.rays, caster, input, inherit, beta, ray),
            None => look_with(
                job.rays,
                caster,
                input,
                inherit,
                sketch,
                beta,
                ray,
                |_, _| DVec3::ZERO,
            ),
            Some(light) => look_with(
                job.rays,
                caster,
                input,
                inherit,
                sketch,
                beta,
                ray,
                |r, h| light.share(job.item as usize, r, h),
            ),
        }
    };
    fold(n, rays_per_patch, gathered, |i, s| {
        let (p, c) = (&patches[i], control(i));
        if sketch.is_some() {
            let rho = p.reflectance / s.moments.n.max(1) as f32;
            image.push(crate::replicates::scaled(&s.sketch, rho));
            let rho = p.reflectance.as_dvec3() / s.moments.n.max(1) as f64;
            image_variance.push(rho * rho * s.sketch_variance);
        }
        let t = Tally::from(&s);
        if coverage.is_some() {
            let n = t.moments.n;
            let hits = n - u64::from(t.escaped) - u64::from(t.back_faces);
            // The mean of `x` over the hits: the rays' mean of `h (x - beta)` times `n / hits`,
            // plus `beta`.
            let hit_mean = if hits > 0 {
                c.beta + t.moments.mean * (n as f64 / hits as f64)
            } else {
                DVec3::ZERO
            };
            learned.push((n, hits, hit_mean));
        }
        let rho = p.reflectance.as_dvec3();
        inherited.push(rho * rho * (t.inherited_mean + c.offset_variance));
        out.push((p.reflectance, p.emission), &t, c, emission);
        faces.push(face[i], &t);
        own.push(Own::of(&t));
    });
    ctx.check_cancelled()?;
    if let Some(coverage) = coverage {
        coverage.learn(learned.into_iter());
    }
    let mut round = out.done(n as u64 * rays_per_patch as u64)?;
    round.sketch = image;
    round.sketch_variance = image_variance;
    let qmc = ctx.sampling() == Sampler::Qmc;
    round.estimate = with_face_pooled(mesh, &face, &own, faces, round.estimate, pool, qmc)?;
    Ok((round, inherited))
}

/// What the face pooling ([`with_face_pooled`]) reads of a patch's rays: 48 bytes where a
/// [`Tally`] takes 168.
#[derive(Debug, Clone, Copy)]
struct Own {
    /// Rays cast.
    n: u64,
    /// The rays' own variance of their mean (`Moments::variance_of_mean`), (W/m²)².
    own: DVec3,
    /// The replicates' estimate of it ([`Halves::variance_of_mean`](crate::replicates::Halves)).
    replicate: Option<f64>,
}

impl Own {
    fn of(t: &Tally) -> Own {
        Own {
            n: t.moments.n,
            own: t.moments.variance_of_mean(),
            replicate: t.halves.variance_of_mean(t.moments.n),
        }
    }
}

/// Per input face (numbered densely, [`crate::replicates::dense_faces`]) the sums
/// [`with_face_pooled`] pools: the patches' sums of squared
/// deviations ((W/m²)²), their degrees of freedom, the emission's part of them, added patch
/// by patch in mesh order; and whether every ray recorded the emission ([`Tally::tracked`]).
struct FaceSums {
    m2: Vec<DVec3>,
    dof: Vec<u64>,
    emitted: Vec<DVec3>,
    tracked: bool,
}

impl FaceSums {
    fn new(faces: usize) -> FaceSums {
        FaceSums {
            m2: vec![DVec3::ZERO; faces],
            dof: vec![0; faces],
            emitted: vec![DVec3::ZERO; faces],
            tracked: true,
        }
    }

    /// Adds a patch of face `face`.
    fn push(&mut self, face: u32, t: &Tally) {
        let f = face as usize;
        self.m2[f] += t.moments.m2;
        self.dof[f] += t.moments.n.saturating_sub(1);
        self.emitted[f] += t.emitted_m2;
        self.tracked &= t.tracked;
    }
}

/// A patch's sampling variance from all the patches of its input face (`face[i]`, patch
/// `i`'s, numbered as [`FaceSums`] numbers them):
/// `rho_i² s_f²/n_i`, with `s_f²` the sample variance of the values seen by the rays of the
/// face's patches, pooled within patches (`sum m2 / sum (n - 1)` over the face's patches).
/// Unbiased for the variance where the face's patches see nearly the same scene, and nearly
/// independent of patch `i`'s own rays on a face of many patches. (The inherited part, the
/// noise of the input, stays the patch's own: it depends on where the patch sits, e.g. near a
/// corner.) A face of one patch keeps the patch's own.
///
/// A rare bright value (a small light seen by one ray in a thousand) leaves most patches'
/// rays without it: their own sample variance is small and their value low, while the few
/// that saw it are high with a large variance; right on average, but the unlucky majority
/// claim a precision they do not have, and an estimate that includes the patch's own rays
/// follows its luck (the tiny-light room of `cargo xtask calibrate`: mean `z²` 700-3000 for
/// `two-pass` and the progressive gathers with the own variance, 0.35-0.42 with half own and
/// half the face's). The face's rays include the lucky patch's own: with the other patches'
/// only, a patch whose ray alone on its face saw the light in a round claimed the face's small
/// variance (`gather` 51.7, `two-pass` 1.08, the progressive gathers 1.05-1.09; with them
/// 6.9, 0.98, 0.99). With `pool` (a Jacobi run), the part of `s_f²` due to the emission seen,
/// which is the same in every round, is the run's so far rather than this round's (a round
/// whose face missed the light claimed no direct-light noise).
///
/// What stays is the nature of a rare event: most patches' spread over 16 seeds is far
/// below their true variance (the median column of `cargo xtask calibrate`).
fn with_face_pooled(
    mesh: &Mesh,
    face: &[u32],
    own: &[Own],
    faces: FaceSums,
    estimate: Estimate,
    pool: Option<&mut EmittedPool>,
    qmc: bool,
) -> Result<Estimate, Error> {
    let patches = mesh.patches();
    let FaceSums {
        m2,
        dof,
        emitted,
        tracked,
    } = faces;
    let faces = m2.len();
    // Per face, the sample variance of the values seen, its emission part the run's so far
    // (made over the sums it is made from).
    let mut face_variance = m2;
    for (v, &dof) in face_variance.iter_mut().zip(&dof) {
        *v = if dof == 0 {
            DVec3::ZERO
        } else {
            *v / dof as f64
        };
    }
    // Every ray's emission is recorded where the input's variance is known (`inherit`).
    if let Some(pool) = pool.filter(|_| tracked) {
        pool.m2.resize(faces, DVec3::ZERO);
        pool.dof.resize(faces, 0);
        for f in 0..faces {
            pool.m2[f] += emitted[f];
            pool.dof[f] += dof[f];
            if dof[f] > 0 {
                face_variance[f] += (pool.m2[f] / pool.dof[f] as f64) - emitted[f] / dof[f] as f64;
            }
        }
    }
    drop(emitted);
    if estimate.variance().is_none() {
        return Ok(estimate);
    }
    let (radiosity, variance, rays) = estimate.into_parts();
    let mut variance = variance.unwrap_or_default();
    // The sampling variance each patch reports (before `rho²`): the face's, or its own
    // (made where read, twice, rather than held).
    let model = |f: u32, o: &Own| {
        let f = f as usize;
        if dof[f] <= o.n.saturating_sub(1) || o.n == 0 {
            o.own
        } else {
            face_variance[f].max(DVec3::ZERO) / o.n as f64
        }
    };
    let gains = if qmc {
        replicates::gains(
            face.iter().zip(own).map(|(&f, o)| Measure {
                face: f,
                replicate: o.replicate,
                model: model(f, o).element_sum(),
                dof: 1.0,
                deposits: 0.0,
            }),
            replicates::Toward::Formula,
        )
    } else {
        vec![1.0; patches.len()]
    };
    // (Each patch's variance made over its own.)
    for ((((p, &f), o), v), g) in patches
        .iter()
        .zip(face)
        .zip(own)
        .zip(variance.iter_mut())
        .zip(&gains)
    {
        let rho = p.reflectance.as_dvec3();
        *v = (*v + rho * rho * (model(f, o) * *g - o.own)).max(DVec3::ZERO);
    }
    Ok(Estimate::new(radiosity, Some(variance), rays)?)
}

/// Turns each item's moments into `[E] + rho (mean + offset)` and
/// `rho² (s²/n + collisions + offset variance)`, with the item's control (`crate::control`;
/// none where `controls` is shorter).
fn finish(
    materials: impl Iterator<Item = (Vec3, Vec3)>,
    seen: &[Tally],
    controls: &[Control],
    emission: Emission,
    rays: u64,
) -> Result<GatherRound, Error> {
    let mut out = Finish::with_capacity(seen.len());
    for (i, (m, s)) in materials.zip(seen).enumerate() {
        out.push(m, s, controls.get(i).copied().unwrap_or_default(), emission);
    }
    out.done(rays)
}

/// A [`GatherRound`] made item by item ([`finish`]).
struct Finish {
    radiosity: Vec<DVec3>,
    variance: Vec<DVec3>,
    errors: Vec<DVec3>,
    escaped_rays: u64,
    back_face_hits: u64,
}

impl Finish {
    fn with_capacity(n: usize) -> Finish {
        Finish {
            radiosity: Vec::with_capacity(n),
            variance: Vec::with_capacity(n),
            errors: Vec::with_capacity(n),
            escaped_rays: 0,
            back_face_hits: 0,
        }
    }

    /// Adds the next item, of reflectance `rho` and emission `e`, its rays `s`, its control `c`:
    /// `[E] + rho (mean + offset)` and `rho² (s²/n + collisions + offset variance)`.
    fn push(&mut self, (rho, e): (Vec3, Vec3), s: &Tally, c: Control, emission: Emission) {
        let rho = rho.as_dvec3();
        let own = match emission {
            Emission::Include => e.as_dvec3(),
            Emission::Exclude => DVec3::ZERO,
        };
        self.radiosity.push(own + rho * (s.moments.mean + c.offset));
        self.errors.push(rho * s.halves.error_of_mean(s.moments.n));
        self.variance.push(
            rho * rho * (s.moments.variance_of_mean() + s.inherited_mean + c.offset_variance),
        );
        self.escaped_rays += u64::from(s.escaped);
        self.back_face_hits += u64::from(s.back_faces);
    }

    /// The round of the items pushed, `rays` rays in all.
    fn done(self, rays: u64) -> Result<GatherRound, Error> {
        Ok(GatherRound {
            sketch: Vec::new(),
            sketch_variance: Vec::new(),
            errors: self.errors,
            estimate: Estimate::new(self.radiosity, Some(self.variance), rays)?,
            escaped_rays: self.escaped_rays,
            back_face_hits: self.back_face_hits,
        })
    }
}

/// Settings of a Jacobi gathering run ([`gather`]).
#[derive(Debug, Clone, PartialEq)]
pub struct GatherConfig {
    /// The ray budget over all rounds; a round costs `patches × rays_per_patch` rays and only
    /// whole rounds run, so at most this many rays are cast.
    pub rays: u64,
    /// Rays each patch casts per round (`>= 2`).
    pub rays_per_patch: u32,
    /// Stop once the largest change of a round relative to the largest reflected radiosity,
    /// `max_{i,c} |B'_ic - B_ic| / max_{i,c} (B'_ic - E_ic)` (emission left out: a bright
    /// light would otherwise hide every change), times the remainder factor
    /// `max(1, rho / (1 - rho))` of the largest reflectance `rho` (the bounces still missing),
    /// is at most this (finite, `>= 0`; `0` runs until the budget is spent). A round that saw
    /// no reflected light never stops the run (see [`gather`]).
    pub threshold: f64,
    /// Seed of every random stream of the run.
    pub seed: u64,
}

impl Default for GatherConfig {
    /// One million rays, 64 per patch and round, stop at a relative change of 1e-3, seed 0.
    fn default() -> Self {
        GatherConfig {
            rays: 1_000_000,
            rays_per_patch: 64,
            threshold: 1e-3,
            seed: 0,
        }
    }
}

/// What the observer of [`gather`] sees after each round.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GatherProgress<'a> {
    /// Rounds done.
    pub rounds: u32,
    /// Rays cast so far.
    pub rays: u64,
    /// The budget.
    pub budget: u64,
    /// The round's largest change relative to the largest reflected radiosity (see
    /// [`GatherConfig::threshold`]).
    pub change: f64,
    /// The round's solution `B_i` (W/m²), in mesh order.
    pub radiosity: &'a [DVec3],
}

/// Counters of a Jacobi gathering run.
#[derive(Debug, Clone, PartialEq)]
pub struct GatherStats {
    /// Rays cast.
    pub rays: u64,
    /// Rounds run.
    pub rounds: u32,
    /// Rays that hit nothing.
    pub escaped_rays: u64,
    /// Rays whose first hit was a back face.
    pub back_face_hits: u64,
    /// The last round's relative change.
    pub change: f64,
    /// Why the run ended.
    pub stop: StopReason,
    /// Every round's variance was exactly 0 on every patch and no ray escaped or hit a back
    /// face: every ray of a patch saw the same value in every round (a furnace), so the rounds
    /// are the Jacobi iterates themselves, without noise.
    pub noise_free: bool,
}

/// The result of [`gather`].
#[derive(Debug, Clone)]
pub struct Gathering {
    /// The last round's radiosity (W/m²) and variance `rho_i² s_i² / n`, which is conditional on
    /// the previous round: the noise of earlier rounds, propagated through the input (damped by
    /// `rho` per round), is not in it, so it understates the error of the iterated answer.
    /// `rays` counts every round.
    pub estimate: Estimate,
    /// Rounds run (the number of light bounces the answer holds).
    pub rounds: u32,
    /// Counters.
    pub stats: GatherStats,
}

/// Solves radiosity by Jacobi gathering (Balog, section 1.4): starting from `B_0 = E`, round
/// `k = 0, 1, ...` computes `B_{k+1} = gather_round(input = B_k, Emission::Include)` with pass
/// `k`, so that `E[B_m] = sum_{k <= m} (rho F)^k E`. The run stops when a round's largest change
/// relative to the largest reflected radiosity is at most `config.threshold` ([`StopReason::Converged`]),
/// when the next round would exceed the budget ([`StopReason::BudgetSpent`]) or when `observer`,
/// called after every round, breaks ([`StopReason::Stopped`]). The test is on the remainder the
/// last change implies: the bounces still missing add about `rho / (1 - rho)` times the last
/// change (`rho` the largest reflectance), so the run stops when
/// `change · max(1, rho / (1 - rho)) <= threshold`. A round that saw no reflected light at all
/// (no ray reached an emitter: `B' = E`) carries no information and never counts as converged
/// unless no patch reflects. With few rays per patch the change never falls below the noise.
///
/// Errors: `config.rays_per_patch < 2`, a bad threshold, or a budget below one round.
pub fn gather<C: RayCaster>(
    ctx: &Context<C>,
    config: &GatherConfig,
    observer: &mut dyn FnMut(&GatherProgress) -> ControlFlow<()>,
) -> Result<Gathering, Error> {
    let mesh = ctx.mesh();
    if !(config.threshold.is_finite() && config.threshold >= 0.0) {
        return Err(Error::BadGatherThreshold(config.threshold));
    }
    if config.rays_per_patch < 2 {
        return Err(Error::TooFewRays(config.rays_per_patch));
    }
    let round = mesh.patches().len() as u64 * config.rays_per_patch as u64;
    if config.rays < round {
        return Err(Error::BudgetBelowRound {
            budget: config.rays,
            round,
        });
    }
    let mut b: Vec<DVec3> = mesh
        .patches()
        .iter()
        .map(|p| p.emission.as_dvec3())
        .collect();
    let mut stats = GatherStats {
        rays: 0,
        rounds: 0,
        escaped_rays: 0,
        back_face_hits: 0,
        change: f64::INFINITY,
        stop: StopReason::BudgetSpent,
        noise_free: true,
    };
    let mut last = Estimate::new(b.clone(), Some(vec![DVec3::ZERO; b.len()]), 0)?;
    // The change a round leaves to the rounds after it: about `rho / (1 - rho)` times its own.
    let rho_max = mesh
        .patches()
        .iter()
        .map(|p| f64::from(p.reflectance.max_element()))
        .fold(0.0, f64::max)
        .min(1.0 - 1e-12);
    let tail = rho_max / (1.0 - rho_max);
    let mut pool = EmittedPool::default();
    while stats.rays + round <= config.rays {
        let r = gather_round_pooled(
            ctx,
            &last,
            config.rays_per_patch,
            StreamKey::new(config.seed).pass(stats.rounds as u64),
            &mut pool,
        )?;
        let next = r.estimate.radiosity();
        let largest = next.iter().zip(mesh.patches()).fold(0.0f64, |m, (x, p)| {
            m.max((*x - p.emission.as_dvec3()).max_element())
        });
        let diff = next
            .iter()
            .zip(&b)
            .fold(0.0f64, |m, (x, y)| m.max((*x - *y).abs().max_element()));
        // No reflected light seen yet (no ray reached an emitter) is no information, not
        // convergence, unless nothing reflects at all.
        stats.change = if largest > 0.0 {
            diff / largest
        } else if rho_max > 0.0 {
            f64::INFINITY
        } else {
            0.0
        };
        stats.rays += r.estimate.rays();
        stats.rounds += 1;
        stats.escaped_rays += r.escaped_rays;
        stats.back_face_hits += r.back_face_hits;
        stats.noise_free &= r.escaped_rays == 0
            && r.back_face_hits == 0
            && r.estimate
                .variance()
                .is_some_and(|v| v.iter().all(|v| *v == DVec3::ZERO));
        b.copy_from_slice(next);
        last = r.estimate;
        let progress = GatherProgress {
            rounds: stats.rounds,
            rays: stats.rays,
            budget: config.rays,
            change: stats.change,
            radiosity: &b,
        };
        if observer(&progress).is_break() {
            stats.stop = StopReason::Stopped;
            break;
        }
        if stats.change * tail.max(1.0) <= config.threshold {
            stats.stop = StopReason::Converged;
            break;
        }
    }
    let estimate = Estimate::new(b, last.variance().map(<[DVec3]>::to_vec), stats.rays)?;
    Ok(Gathering {
        estimate,
        rounds: stats.rounds,
        stats,
    })
}

/// Radiosity gathered at mesh vertices ([`gather_at_vertices`](crate::gather_at_vertices)), one entry per patch corner.
#[derive(Debug, Clone, PartialEq)]
pub struct CornerGathering {
    /// Radiosity at each corner (W/m² per channel), indexed by global corner
    /// ([`Mesh::corner_offset`]`(p) + k`): the value of the corner's group.
    pub radiosity: Vec<DVec3>,
    /// Its estimated variance `rho² s² / n` ((W/m²)², conditional on the input).
    pub variance: Vec<DVec3>,
    /// Rays cast: `groups × rays_per_vertex`.
    pub rays: u64,
    /// Rays that hit nothing.
    pub escaped_rays: u64,
    /// Rays whose first hit was a back face.
    pub back_face_hits: u64,
}

/// Gathers radiosity directly at the vertices (Balog, section 1.5), instead of extrapolating
/// per-patch values to corners.
///
/// For each group `g` of `groups` ([`Mesh::corner_groups`]: the corners that
/// [`Mesh::corner_radiosity`] would average over the same patches at the same point), with `x`
/// the shared point, `n` the unit area-weighted normal `sum_q A_q n_q / |.|` of the group's
/// patches (the first patch's normal if that sum vanishes) and `rho`, `E` the group's material:
///
/// ```text
/// B(x) = [E] + rho (1/n) sum_k input[j_k]      (W/m² per channel)
/// ```
///
/// over `rays_per_vertex` rays from `x` in cosine-distributed directions about `n`; `j_k` and the
/// variance `rho² s² / n` as in [`gather_round`]. The expectation is the radiosity leaving the
/// point `x` of a surface with normal `n`: `[E] + rho sum_j F_{x j} input_j`, with `F_{x j}` the
/// point-to-patch form factor. Every corner of the group gets the group's value.
///
/// # Rays from a vertex
///
/// A vertex lies on every patch of its group (and often on others: the foot of a wall), so a
/// ray from it must not be tested against one excluded patch: it is cast with the group normal
/// as its surface normal and **no** excluded id. The caster lifts the origin along `n` by its
/// epsilon, above every plane of the group (their normals lie within the crease angle of `n`),
/// and its window rule decides crossings next to the origin by orientation: the planes the
/// ray leaves are crossed from behind and never count, while a surface the ray walks into at
/// distance ~0 counts from its front, whether it is a creased neighbour inside the group
/// (a valley), another surface at the point (the wall at the foot of which a floor vertex
/// lies: rays heading into it see the wall, as a point next to it would) or the corner's own
/// patch. Excluding one patch instead would let rays pass through it on a bent group.
///
/// Random streams `(seed, pass, g, VERTEX_GATHER + chunk)`; deterministic on any thread count.
///
/// Errors: `input` not one finite value per patch, `groups` made for another mesh, or
/// `rays_per_vertex < 2`.
pub fn gather_corners<C: RayCaster>(
    ctx: &Context<C>,
    groups: &CornerGroups,
    input: &[DVec3],
    emission: Emission,
    rays_per_vertex: u32,
    key: StreamKey,
) -> Result<CornerGathering, Error> {
    let (mesh, caster) = (ctx.mesh(), ctx.caster());
    check_input(mesh, input)?;
    if rays_per_vertex < 2 {
        return Err(Error::TooFewRays(rays_per_vertex));
    }
    if groups.corner_groups().len() != mesh.corner_count() {
        return Err(Error::GroupsMismatch {
            corners: mesh.corner_count(),
            got: groups.corner_groups().len(),
        });
    }
    let patches = mesh.patches();
    let frames: Vec<Frame> = (0..groups.len())
        .map(|g| {
            let members = groups.patches(g);
            let sum: DVec3 = members
                .iter()
                .map(|&q| patches[q as usize].normal.as_dvec3() * patches[q as usize].area)
                .sum();
            let total: f64 = members.iter().map(|&q| patches[q as usize].area).sum();
            let normal = if sum.length() > 1e-6 * total {
                sum.normalize().as_vec3()
            } else {
                patches[members[0] as usize].normal
            };
            Frame::from_normal(normal)
        })
        .collect();
    let mut seen: Vec<Tally> = Vec::with_capacity(groups.len());
    let gathered = |job: &crate::jobs::Job| {
        if ctx.cancelled() {
            return Seen::default();
        }
        let g = job.item as usize;
        let mut rays =
            Rays::for_chunk(ctx.sampling(), key.item(g as u64), VERTEX_GATHER, job.chunk);
        let (origin, frame) = (groups.point(g), &frames[g]);
        look(job.rays, caster, input, None, DVec3::ZERO, || {
            let local = match &mut rays {
                Rays::Random(rng) => cosine_hemisphere_rejection(|| rng.uniform()),
                qmc => {
                    let u = qmc.next_point();
                    cosine_hemisphere_concentric(glam::Vec2::new(u[0], u[1]))
                }
            };
            Ray {
                origin,
                dir: frame.to_world(local),
                origin_normal: frame.normal,
                exclude: NO_ID,
            }
        })
    };
    fold(groups.len(), rays_per_vertex, gathered, |_, s| {
        seen.push(Tally::from(&s))
    });
    ctx.check_cancelled()?;
    let round = finish(
        (0..groups.len()).map(|g| {
            let p = &patches[groups.patches(g)[0] as usize];
            (p.reflectance, p.emission)
        }),
        &seen,
        &[],
        emission,
        groups.len() as u64 * rays_per_vertex as u64,
    )?;
    let (values, mut variances) = (
        round.estimate.radiosity(),
        round
            .estimate
            .variance()
            .expect("gathering has variances")
            .to_vec(),
    );
    if ctx.sampling() == Sampler::Qmc {
        // The variances are the rays' `rho² s² / n` alone (no input noise): scale them by the
        // gain the replicates measure, per input face.
        let gains = replicates::gains(
            seen.iter().enumerate().map(|(g, s)| Measure {
                face: patches[groups.patches(g)[0] as usize].face,
                replicate: s.halves.variance_of_mean(s.moments.n),
                model: s.moments.variance_of_mean().element_sum(),
                dof: 1.0,
                deposits: 0.0,
            }),
            replicates::Toward::Formula,
        );
        replicates::scale(&mut variances, &gains);
    }
    let corners = groups.corner_groups();
    Ok(CornerGathering {
        radiosity: corners.iter().map(|&g| values[g as usize]).collect(),
        variance: corners.iter().map(|&g| variances[g as usize]).collect(),
        rays: round.estimate.rays(),
        escaped_rays: round.escaped_rays,
        back_face_hits: round.back_face_hits,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::jobs::{JOB_RAYS, Moments, jobs};

    #[test]
    fn moments_merge_like_one_pass() {
        let xs: Vec<DVec3> = (0..1000)
            .map(|i| {
                let t = i as f64;
                DVec3::new((t * 0.37).sin(), t * 1e-3 + 5.0, (i % 7) as f64)
            })
            .collect();
        let mut all = Moments::default();
        xs.iter().for_each(|&x| all.push(x));
        let mut parts = Moments::default();
        for chunk in xs.chunks(97) {
            let mut m = Moments::default();
            chunk.iter().for_each(|&x| m.push(x));
            parts = parts.merge(m);
        }
        let n = xs.len() as f64;
        let mean: DVec3 = xs.iter().sum::<DVec3>() / n;
        let var: DVec3 = xs.iter().map(|x| (*x - mean) * (*x - mean)).sum::<DVec3>() / (n - 1.0);
        for m in [all, parts] {
            assert_eq!(m.n, 1000);
            assert!((m.mean - mean).abs().max_element() < 1e-12);
            assert!((m.variance_of_mean() * n - var).abs().max_element() < 1e-10);
        }
        let mut constant = Moments::default();
        (0..10).for_each(|_| constant.push(DVec3::splat(0.3)));
        assert_eq!(constant.variance_of_mean(), DVec3::ZERO);
    }

    #[test]
    fn jobs_split_items_into_chunks() {
        let j = jobs(3, 2 * JOB_RAYS + 5);
        assert_eq!(j.len(), 9);
        assert_eq!(
            j.iter().map(|j| j.rays as u64).sum::<u64>(),
            3 * (2 * JOB_RAYS as u64 + 5)
        );
        assert_eq!((j[5].item, j[5].chunk, j[5].rays), (1, 2, 5));
    }
}
