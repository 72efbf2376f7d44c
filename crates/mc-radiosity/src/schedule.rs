//! Schedules: which estimators run, with how many rays, and how their results merge — the
//! paper's methods behind one interface, each refining a solution step by step.
//!
//! A schedule hands every complete intermediate solution to an observer ([`Step`]), which may
//! draw progress, write an error trace, or stop the run; a stopped run returns the last complete
//! solution, never a half-finished pass. The merge rules live in `combine`.

use crate::context::Context;
use crate::error::Error;
use crate::shoot::{ShootConfig, Shooting, shoot};
use glam::DVec3;
use mcrad_combine::{ByRays, Estimate, EstimateError, merge};
use mcrad_meshing::Mesh;
use mcrad_random::derive_seed;
use mcrad_raycast::RayCaster;
use mcrad_reference::ReferenceConfig;
use std::cell::Cell;
use std::ops::ControlFlow;

pub(crate) mod bidirectional;
pub(crate) mod combined;
pub(crate) mod gather;
pub(crate) mod progressive_gather;
pub(crate) mod progressive_two_pass;
pub(crate) mod prr;
pub(crate) mod reference;
pub(crate) mod samples;
pub(crate) mod shoot;
pub(crate) mod two_pass;
pub(crate) mod two_pass_split;

use crate::method::{Method, StopReason};

/// The default ray budget of a run: two million rays over all passes.
pub const DEFAULT_RAYS: u64 = 2_000_000;

/// The default unshot threshold: shooting ends its waves once the power left unshot is at most
/// this fraction of the emitted power, and a Russian-roulette tail ships the rest at the run's
/// energy per ray (no bias; until issue 36 it was dropped, a bias of up to this fraction). The
/// paper's `0.01` ends the waves sooner, its tail then costs about 1% more rays.
pub const DEFAULT_UNSHOT_THRESHOLD: f64 = 1e-4;

/// Settings shared by the schedules.
#[derive(Debug, Clone, PartialEq)]
pub struct ScheduleConfig {
    /// Total ray budget over all passes; `u64::MAX` for none (then an observer must stop the
    /// run or cap it with [`Step::limit_rays_left`]; passes double from 100 000 rays and
    /// shooting waves grow with the run, so no step is unbounded).
    pub rays: u64,
    /// Seed of the run; passes derive theirs from it.
    pub seed: u64,
    /// Shooting stops at this fraction of the emitted power left unshot, in `[0, 1]`.
    pub unshot_threshold: f64,
    /// Add the ambient term (section 3.1) to shooting solutions.
    pub ambient: bool,
    /// Rays of the first pass of a progressive method; `None`: the budget / 63 (six doubling
    /// passes fill the budget), or 100 000 without a budget.
    pub first_pass_rays: Option<u64>,
    /// The reference solver's settings ([`Method::Reference`] only: accuracy targets and the
    /// patch limit).
    pub reference: ReferenceConfig,
    /// How the estimators draw their rays ([`Sampler`](crate::Sampler)).
    pub sampler: crate::Sampler,
    /// The control variate of patch gathering ([`ControlVariate`](crate::ControlVariate)).
    pub control_variate: crate::ControlVariate,
    /// Lights without a surface (point, spot, sun) in the scene's frame (world coordinates,
    /// not the mesh's local frame), radiometric units; none by default. Every method handles
    /// them: their direct light, sampled with shadow rays from `n` points per patch, becomes
    /// the emission `rho H` of the lit patches before the method runs (a quarter of the
    /// budget at most), and its variance adds to the reported ones.
    pub lights: Vec<mcrad_scene_io::Light>,
    /// The sky (radiance in W/(m² sr) from the directions in which rays leave the scene);
    /// none by default. Handled like the lights: its direct light `H_sky`, sampled with rays
    /// of its own from the same points (cosine for a uniform sky; cosine and the map's
    /// luminance combined by the balance heuristic for a map), joins their `rho H`.
    pub sky: Option<mcrad_scene_io::Sky>,
    /// Under a time budget, the seconds (`> 0`) the lights' direct-light pass may take: it
    /// casts 4 points a patch, then as many more (up to 64 in all) as its speed says fit, and
    /// never more than a ray budget, if there is one too, gives (a quarter of it at most).
    /// `None`: the ray budget's points alone (64 a patch without one).
    pub lights_seconds: Option<f64>,
}

impl Default for ScheduleConfig {
    /// The command line's defaults: [`DEFAULT_RAYS`], seed 0, [`DEFAULT_UNSHOT_THRESHOLD`], no
    /// ambient term, first pass from the budget, the reference solver's defaults, the default
    /// [`Sampler`](crate::Sampler), the default [`ControlVariate`](crate::ControlVariate).
    fn default() -> Self {
        ScheduleConfig {
            rays: DEFAULT_RAYS,
            seed: 0,
            unshot_threshold: DEFAULT_UNSHOT_THRESHOLD,
            ambient: false,
            first_pass_rays: None,
            reference: ReferenceConfig::default(),
            sampler: crate::Sampler::default(),
            control_variate: crate::ControlVariate::default(),
            lights: Vec::new(),
            sky: None,
            lights_seconds: None,
        }
    }
}

/// A complete intermediate solution, as the observer sees it.
#[derive(Debug, Clone, Copy)]
pub struct Step<'a> {
    /// Steps done (1 for the first).
    pub index: u32,
    /// Rays cast so far.
    pub rays: u64,
    /// Rays the next step will cast (0 when this is the last): lets a caller with a deadline
    /// stop before a step it has no time for.
    pub next_rays: u64,
    /// The current solution `B_i` (W/m²), in mesh order.
    pub radiosity: &'a [DVec3],
    /// The estimated variance of each `B_i` per channel ((W/m²)², mesh order) where the step's
    /// solution is a complete estimate of all the [`Step::rays`] cast so far: the steps of the
    /// progressive schedules (`prr`, `progressive-gather`, `progressive-two-pass`, `combined`,
    /// `bidirectional`). `None` for the steps of the others (a shooting wave or a Jacobi round
    /// is not yet an answer). With `radiosity` and `rays` it is the solution so far, which a
    /// caller can keep (the CLI's `--save`).
    pub variance: Option<&'a [DVec3]>,
    /// The observer's cap on the rays still to cast (`u64::MAX`: none).
    pub(crate) limit: &'a Cell<u64>,
}

impl Step<'_> {
    /// Caps the rays the rest of the run may cast at `rays` (the lowest cap given wins).
    ///
    /// A caller with a deadline predicts how many rays fit in the time left and calls this
    /// instead of stopping: a progressive method sizes its next pass to the cap and ends after
    /// it (a pass below the method's smallest useful pass is not started); `shoot` spreads its
    /// remaining waves over the cap and finishes with its roulette tail; `two-pass` shortens
    /// its gathering step; `gather` stops before a Jacobi round (of fixed cost) that the cap
    /// cannot hold; `reference` has no next step.
    pub fn limit_rays_left(&self, rays: u64) {
        self.limit.set(self.limit.get().min(rays));
    }
}

/// A fresh limit for a [`Step`]: no cap.
pub(crate) fn no_limit() -> Cell<u64> {
    Cell::new(u64::MAX)
}

/// What a schedule returns.
#[derive(Debug, Clone)]
pub struct Solution {
    /// The final merged estimate (radiosity, variance where known, rays).
    pub estimate: Estimate,
    /// Steps taken.
    pub steps: u32,
    /// Rays that hit nothing, over all passes.
    pub escaped_rays: u64,
    /// Unshot power left by the last shooting pass, as a fraction of the emitted power; for
    /// `gather`, the bound `rho_max^rounds` on the share of the reflected light its Jacobi
    /// rounds have not summed (the answer adds an extrapolation of it, its uncertainty in the
    /// variance).
    pub unshot_fraction: f64,
    /// Why the run ended.
    pub stop: StopReason,
    /// With lights without a surface (`ScheduleConfig::lights`) or a sky: their direct
    /// irradiance `H_d,i` per patch (W/m² per channel, mesh order; the lights' and the sky's
    /// together) as the lights' pre-pass estimated it, so the solution's radiosity holds
    /// `rho_i H_d,i` of direct light and `B_i - rho_i H_d,i` is the rest (emission and
    /// reflected light): what a renderer or baker keeps when it draws the lights' and the
    /// sky's direct light per pixel with its own shadow rays. `None` without lights or sky.
    pub direct: Option<Vec<DVec3>>,
    /// The sky's part of [`direct`](Self::direct) (W/m² per channel, mesh order; 0 without a
    /// sky): a renderer that draws only the lights' direct light per pixel takes
    /// `B_i - rho_i (H_d,i - H_sky,i)` from the solution. `None` when `direct` is.
    pub sky_direct: Option<Vec<DVec3>>,
    /// Per face as outputs number them (its input face, plus
    /// [`Mesh::back_face_offset`](mcrad_meshing::Mesh::back_face_offset) for a back side), per
    /// channel: the factor `k_f` by which the variance of the face's area-weighted mean
    /// exceeds `sum_i a_i² V_i` (`a_i = A_i / A_f`, `V_i` the estimate's variances: the
    /// patches taken as independent) through the correlation between its patches' errors,
    /// estimated from the method's error samples; dimensionless, `>= 0`, exactly 1 for a face
    /// of one patch. `None` where the method keeps no error samples (then the patches are
    /// taken as independent). `shoot` and `prr` give it under quasi-Monte Carlo rays; the
    /// methods that gather from shooting (`two-pass`, `two-pass-split`, `progressive-gather`,
    /// `progressive-two-pass`, `combined`) from their error samples (`schedule::samples`;
    /// not with the ambient term).
    pub face_correlation: Option<Vec<DVec3>>,
}

/// The observer of a schedule.
pub type Observer<'o> = dyn FnMut(&Step) -> ControlFlow<()> + 'o;

/// Runs `method` on `mesh`, casting rays through `caster`. Errors include
/// [`Error::FarFromOrigin`]: a scene too large for its patches in `f32` coordinates (slivers aside).
pub fn run<C: RayCaster>(
    method: Method,
    mesh: &Mesh,
    caster: &C,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    crate::context::check_precision(mesh)?;
    method.dispatch(mesh, caster, config, None, observer)
}

/// [`run`], cancelled when `cancel` becomes true (from another thread: a signal handler):
/// the estimators skip the jobs of rays not yet started, and the run returns
/// [`Error::Cancelled`] within about one job (4096 rays) per worker. The step in progress is
/// abandoned; the last complete one is what the observer saw last. Until `cancel` is set the
/// run is exactly [`run`]'s.
pub fn run_cancellable<C: RayCaster>(
    method: Method,
    mesh: &Mesh,
    caster: &C,
    config: &ScheduleConfig,
    cancel: &std::sync::atomic::AtomicBool,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    crate::context::check_precision(mesh)?;
    method.dispatch(mesh, caster, config, Some(cancel), observer)
}

/// Runs Algorithm 4 ([`Method::Combined`]) on `mesh`, casting rays through `caster`, merging
/// each pass's shooting estimate `S` and gathering estimate `G` per patch and channel into
/// `C_i = w_i S_i + (1 - w_i) G_i` with `weighting` instead of the method's default
/// [`InverseExpectedVariance`](mcrad_combine::InverseExpectedVariance). In
/// [`Weighting::weight`](mcrad_combine::Weighting::weight) the first operand is the shooting
/// estimate, the second the gathering estimate (radiosity in W/m²), each with its expected
/// variance ([`Operand::expected`](mcrad_combine::Operand::expected), (W/m²)²). The split of each
/// pass's rays between shooting and gathering still minimises the error expected under
/// inverse-variance weights, whatever `weighting` is. With `InverseExpectedVariance` the run is
/// exactly [`run`]'s with [`Method::Combined`]. Errors as [`run`]'s.
pub fn run_combined_with<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    config: &ScheduleConfig,
    weighting: &dyn mcrad_combine::Weighting,
    observer: &mut Observer,
) -> Result<Solution, Error> {
    crate::context::check_precision(mesh)?;
    combined::run_with(mesh, caster, config, weighting, observer)
}

/// One Jacobi gathering round from a given solution (Balog, section 1.4): each patch `i` casts
/// `rays_per_patch` cosine-distributed rays from uniform points and estimates
/// `B_i = E_i + rho_i mean_k input(hit_k)` (W/m², mesh order), rays that escape seeing 0. The
/// rays depend on `seed` and `sampler` only, so rounds from different inputs with the same seed
/// share their rays (common random numbers). The variance reported per patch and channel is
/// that of the mean given `input`, `rho_i² s² / n` ((W/m²)²; noise already in `input` is not
/// included); the estimate's rays are `patches × rays_per_patch`.
///
/// Errors: `input` not one finite value per patch, `rays_per_patch < 2`, or
/// [`Error::FarFromOrigin`].
///
/// # Example
///
/// ```
/// use glam::{DVec3, Vec3};
/// use mcrad_mc_radiosity::{Sampler, gather_from};
/// use mcrad_meshing::{Mesh, Subdivision};
/// use mcrad_raycast::Bvh;
/// use mcrad_scene_io::{Face, Material, Scene};
///
/// // A closed unit cube, every face emitting 1 W/m² with reflectance 0.5: B = E / (1 - ρ) = 2.
/// let positions: Vec<Vec3> = (0..8)
///     .map(|k| Vec3::new((k & 1) as f32, (k >> 1 & 1) as f32, (k >> 2) as f32))
///     .collect();
/// let quads = [[1, 3, 2, 0], [6, 7, 5, 4], [4, 5, 1, 0], [3, 7, 6, 2], [2, 6, 4, 0], [5, 7, 3, 1]];
/// let faces = quads
///     .iter()
///     .enumerate()
///     .map(|(k, q)| Face { vertices: q.to_vec(), material: 0, source: k as u32 })
///     .collect();
/// let material = Material { name: "m".into(), reflectance: Vec3::splat(0.5), emission: Vec3::ONE };
/// let scene = Scene::new(positions, faces, vec![material]).unwrap().0;
/// let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
/// let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
///
/// // Gathering from the exact solution reproduces it: every ray sees B = 2.
/// let exact = vec![DVec3::splat(2.0); 6];
/// let round = gather_from(&mesh, &bvh, &exact, 100, 0, Sampler::Random).unwrap();
/// assert_eq!(round.rays(), 600);
/// for b in round.radiosity() {
///     assert!((b.x - 2.0).abs() < 0.02); // exact unless a ray slipped through an edge
/// }
/// ```
pub fn gather_from<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    input: &[DVec3],
    rays_per_patch: u32,
    seed: u64,
    sampler: crate::Sampler,
) -> Result<Estimate, Error> {
    crate::context::check_precision(mesh)?;
    let ctx = Context::new(mesh, caster).with_sampler(sampler);
    let round = crate::gather::gather_round(
        &ctx,
        input,
        crate::gather::Emission::Include,
        rays_per_patch,
        mcrad_random::StreamKey::new(seed),
    )?;
    Ok(round.estimate)
}

/// Radiosity gathered directly at the mesh's vertices from the solution `input` (W/m² per
/// patch, mesh order): Balog's per-vertex gathering (section 1.5), the smooth display without
/// extrapolating patch values to corners. Each group of corners of `groups`
/// ([`Mesh::corner_groups`]: the corners that meet at one point within the crease angle) casts
/// `rays_per_vertex` cosine rays about the group's normal from the shared point and estimates
/// `E + rho mean_k input(hit_k)`; every corner of the group gets that value. The result is
/// indexed by global corner ([`Mesh::corner_offset`]`(p) + k`), its variance that of the mean
/// given `input`. The rays depend on `seed` and `sampler` only; deterministic on any thread
/// count.
///
/// Errors: `input` not one finite value per patch, `groups` made for another mesh,
/// `rays_per_vertex < 2`, or [`Error::FarFromOrigin`].
///
/// # Example
///
/// ```
/// use glam::{DVec3, Vec3};
/// use mcrad_mc_radiosity::{Sampler, gather_at_vertices};
/// use mcrad_meshing::{Mesh, Subdivision};
/// use mcrad_raycast::Bvh;
/// use mcrad_scene_io::{Face, Material, Scene};
///
/// // A closed unit cube, every face emitting 1 W/m² with reflectance 0.5: B = 2 everywhere.
/// let positions: Vec<Vec3> = (0..8)
///     .map(|k| Vec3::new((k & 1) as f32, (k >> 1 & 1) as f32, (k >> 2) as f32))
///     .collect();
/// let quads = [[1, 3, 2, 0], [6, 7, 5, 4], [4, 5, 1, 0], [3, 7, 6, 2], [2, 6, 4, 0], [5, 7, 3, 1]];
/// let faces = quads
///     .iter()
///     .enumerate()
///     .map(|(k, q)| Face { vertices: q.to_vec(), material: 0, source: k as u32 })
///     .collect();
/// let material = Material { name: "m".into(), reflectance: Vec3::splat(0.5), emission: Vec3::ONE };
/// let scene = Scene::new(positions, faces, vec![material]).unwrap().0;
/// let mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.5)).unwrap();
/// let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
/// let groups = mesh.corner_groups(30.0);
///
/// // Gathering from the exact solution reproduces it at every vertex.
/// let exact = vec![DVec3::splat(2.0); mesh.patches().len()];
/// let corners = gather_at_vertices(&mesh, &bvh, &groups, &exact, 64, 0, Sampler::Qmc).unwrap();
/// assert_eq!(corners.radiosity.len(), mesh.corner_count());
/// for b in &corners.radiosity {
///     assert!((b.x - 2.0).abs() < 0.02); // exact unless a ray slipped through an edge
/// }
/// ```
pub fn gather_at_vertices<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    groups: &mcrad_meshing::CornerGroups,
    input: &[DVec3],
    rays_per_vertex: u32,
    seed: u64,
    sampler: crate::Sampler,
) -> Result<crate::gather::CornerGathering, Error> {
    crate::context::check_precision(mesh)?;
    let ctx = Context::new(mesh, caster).with_sampler(sampler);
    crate::gather::gather_corners(
        &ctx,
        groups,
        input,
        crate::gather::Emission::Include,
        rays_per_vertex,
        mcrad_random::StreamKey::new(seed),
    )
}

fn shoot_config(config: &ScheduleConfig, rays: u64, seed: u64) -> ShootConfig {
    ShootConfig {
        rays,
        unshot_threshold: config.unshot_threshold,
        seed,
        ..Default::default()
    }
}

fn unshot_fraction(s: &Shooting) -> f64 {
    let t = |x: DVec3| x.x + x.y + x.z;
    t(s.stats.unshot) / t(s.stats.emitted)
}

/// The shooting estimate, with the ambient term (its unshot power spread as
/// `rho_i * A_amb`) added when the configuration asks for it.
fn with_ambient(mesh: &Mesh, config: &ScheduleConfig, s: Shooting) -> Result<Estimate, Error> {
    if !config.ambient {
        return Ok(s.estimate);
    }
    let a = crate::ambient::ambient(mesh, &s.unshot, s.stats.escape_fraction())?;
    crate::ambient::with_ambient(mesh, &s.estimate, a)
}

/// Seed tags: shooting pass `k` uses `k`, gathering pass `k` uses `GATHER_TAG + k`.
const GATHER_TAG: u64 = 1 << 32;

/// Rays per patch for a gathering budget (at least 2, as the variance needs).
fn per_patch(mesh: &Mesh, rays: u64) -> u32 {
    (rays / mesh.patches().len().max(1) as u64).clamp(2, u32::MAX as u64) as u32
}

/// Merges `next` into `acc` by their rays ([`ByRays`], the passes of Algorithms 1-3).
fn accumulate(acc: Option<Estimate>, next: Estimate) -> Result<Estimate, Error> {
    Ok(match acc {
        None => next,
        Some(a) => merge(&a, &next, &ByRays)?,
    })
}

/// Gathers merged by their rays (Algorithm 3), with their variance in two parts. A gather's
/// own noise (its rays and direct-light samples) is independent of every other's; the noise it
/// inherits from the shooting estimate it gathers from is not, when the gathers draw from the
/// same shooting estimate (`progressive-gather`) or from nested merges of the same shooting
/// passes (`progressive-two-pass`, `combined`). With `a_k = n_k / n` the
/// share of gather `k`'s rays, the merged variance is
/// `sum_k a_k² own_k + (sum_k a_k sqrt(inherited_k))²`: the own parts independent, the
/// inherited ones fully correlated (exact for one input, an upper bound that nested merges
/// nearly reach). Measured by `cargo xtask calibrate` (8 seeds, spread between seeds /
/// reported variance, furnaces rho 0.5-0.999): `progressive-gather` 2.0-2.4 with the parts
/// summed as independent. Where the shooting kept error samples the schedules report the
/// variance from those instead ([`samples`]); this one stands without them (the ambient
/// term).
#[derive(Default)]
pub(crate) struct Gathers {
    /// The gathers merged by rays, with their own variances only.
    own: Option<Estimate>,
    /// `sum_k n_k sqrt(inherited_k)` per patch and channel (rays · W/m²).
    inherited_sd: Vec<DVec3>,
}

impl Gathers {
    /// Adds a gather `g` whose variance includes `inherited` (per patch and channel).
    pub(crate) fn add(&mut self, g: Estimate, inherited: &[DVec3]) -> Result<(), Error> {
        let n = g.rays() as f64;
        let v = g.variance().ok_or(EstimateError::MissingVariance)?;
        let own = v
            .iter()
            .zip(inherited)
            .map(|(v, h)| (*v - *h).max(DVec3::ZERO))
            .collect();
        if self.inherited_sd.is_empty() {
            self.inherited_sd = vec![DVec3::ZERO; inherited.len()];
        }
        for (sd, h) in self.inherited_sd.iter_mut().zip(inherited) {
            *sd += n * h.max(DVec3::ZERO).sqrt();
        }
        let g = Estimate::new(g.radiosity().to_vec(), Some(own), g.rays())?;
        self.own = Some(accumulate(self.own.take(), g)?);
        Ok(())
    }

    /// The gathers merged by rays with their own variances only (the inherited parts left
    /// out); `None` before the first.
    pub(crate) fn own(&self) -> Option<&Estimate> {
        self.own.as_ref()
    }

    /// The merged gathering estimate with its whole variance.
    pub(crate) fn estimate(&self) -> Result<Estimate, Error> {
        let own = self.own.as_ref().ok_or(EstimateError::MissingVariance)?;
        let n = own.rays().max(1) as f64;
        let v = own.variance().ok_or(EstimateError::MissingVariance)?;
        let variance = v
            .iter()
            .zip(&self.inherited_sd)
            .map(|(v, sd)| *v + (*sd / n) * (*sd / n))
            .collect();
        Ok(Estimate::new(
            own.radiosity().to_vec(),
            Some(variance),
            own.rays(),
        )?)
    }
}

/// Pass budgets: `first, 2 first, 4 first, ...` until the budget is spent; a pass that would
/// leave less than itself takes the rest, so no pass is a sliver.
pub(crate) struct Doubling {
    next: u64,
    left: u64,
}

impl Doubling {
    pub(crate) fn new(config: &ScheduleConfig) -> Doubling {
        let first = config
            .first_pass_rays
            .unwrap_or(if config.rays == u64::MAX {
                100_000
            } else {
                (config.rays / 63).max(1)
            })
            .max(1);
        Doubling {
            next: first,
            left: config.rays,
        }
    }

    /// Passes as [`Doubling::new`] makes them, the first at least `min_pass` rays.
    pub(crate) fn at_least(config: &ScheduleConfig, min_pass: u64) -> Doubling {
        let first = Doubling::new(config).peek().max(min_pass);
        Doubling::new(&ScheduleConfig {
            first_pass_rays: Some(first),
            ..config.clone()
        })
    }

    /// The next pass's rays without taking it (0 when the budget is spent).
    pub(crate) fn peek(&self) -> u64 {
        let n = self.next.min(self.left);
        if self.left - n < n { self.left } else { n }
    }

    /// Lowers the rays left to at most `rays` (an observer's [`Step::limit_rays_left`]): the
    /// next pass takes what is left if that is less than twice its doubling size, and is the
    /// last.
    pub(crate) fn cap(&mut self, rays: u64) {
        self.left = self.left.min(rays);
    }

    /// Gives back `rays` a pass was given and did not use, for the passes after it.
    pub(crate) fn refund(&mut self, rays: u64) {
        self.left = self.left.saturating_add(rays);
    }

    /// Takes `rays` a pass cast beyond what it was given (a shooting pass's roulette tail)
    /// from the passes after it, so the run's total stays near its budget.
    pub(crate) fn charge(&mut self, rays: u64) {
        self.left = self.left.saturating_sub(rays);
    }

    /// Rays left in the budget after the passes taken so far.
    pub(crate) fn remaining(&self) -> u64 {
        self.left
    }
}

impl Iterator for Doubling {
    type Item = u64;
    fn next(&mut self) -> Option<u64> {
        let n = self.peek();
        if n == 0 {
            return None;
        }
        self.left -= n;
        self.next = self.next.saturating_mul(2);
        Some(n)
    }
}

/// [`StopReason::Stopped`] if the observer stopped the run, else [`StopReason::BudgetSpent`]:
/// the end of a method that runs until its budget is spent.
fn budget_or_stopped(stopped: bool) -> StopReason {
    if stopped {
        StopReason::Stopped
    } else {
        StopReason::BudgetSpent
    }
}

/// The bookkeeping of a progressive schedule: the merged solution so far and the counters.
#[derive(Default)]
struct Progressive {
    merged: Option<Estimate>,
    steps: u32,
    rays: u64,
    escaped_rays: u64,
    unshot_fraction: f64,
    stopped: bool,
}

impl Progressive {
    /// Merges `estimate` into the solution by work, counts the step and shows the merged
    /// solution to the observer, telling it the size of the next of `passes`. `Ok(false)` when
    /// the observer stops the run; a cap the observer sets lowers what is left of `passes`.
    fn step(
        &mut self,
        estimate: Estimate,
        passes: &mut Doubling,
        observer: &mut Observer,
    ) -> Result<bool, Error> {
        let merged = accumulate(self.merged.take(), estimate)?;
        self.replace(merged, passes, observer)
    }

    /// Makes `merged` the solution (merged by the caller), counts the step and shows it to the
    /// observer as [`Progressive::step`] does. `Ok(false)` when the observer stops the run.
    fn replace(
        &mut self,
        merged: Estimate,
        passes: &mut Doubling,
        observer: &mut Observer,
    ) -> Result<bool, Error> {
        self.steps += 1;
        let limit = no_limit();
        let step = Step {
            index: self.steps,
            rays: self.rays,
            next_rays: passes.peek(),
            radiosity: merged.radiosity(),
            variance: merged.variance(),
            limit: &limit,
        };
        self.stopped = observer(&step).is_break();
        passes.cap(limit.get());
        self.merged = Some(merged);
        Ok(!self.stopped)
    }

    /// A complete shooting pass of `rays` rays, seeded by `tag`, its rays, escapes and unshot
    /// power counted in the run.
    ///
    /// The estimate's `rays` are the rays *asked* (`rays`), not those cast: the passes merge by
    /// rays ([`ByRays`]), and the rays a pass casts beyond its budget (its roulette tail, long
    /// at a reflectance near 1) grow with the power its paths carried, so weights from them
    /// would favour the passes that came out high (PRR at rho 0.999, 20k rays: +37% at 2.5
    /// standard errors). Weights fixed before the pass keep the merge unbiased.
    ///
    /// `spare`: rays of the passes after this one, which take what its finishing tail casts
    /// beyond `rays` ([`Doubling::charge`]): the tail may cost them as well as
    /// [`DEFAULT_MAX_OVERRUN`](crate::shoot::DEFAULT_MAX_OVERRUN) of `rays` before the rest
    /// of the light is extrapolated ([`ShootConfig::max_overrun`]).
    fn shoot<C: RayCaster>(
        &mut self,
        ctx: &Context<C>,
        config: &ScheduleConfig,
        rays: u64,
        spare: u64,
        tag: u64,
    ) -> Result<Shooting, Error> {
        // Without a ray budget (a run against the clock) the passes after this one are
        // sized later, to the time left: the tail may not count on them.
        let spare = if config.rays == u64::MAX { 0 } else { spare };
        let mut s = shoot(
            ctx,
            &ShootConfig {
                max_overrun: crate::shoot::DEFAULT_MAX_OVERRUN + spare as f64 / rays.max(1) as f64,
                ..shoot_config(config, rays, derive_seed(config.seed, tag))
            },
            &mut |_| ControlFlow::Continue(()),
        )?;
        self.rays += s.stats.rays;
        self.escaped_rays += s.stats.escaped_rays;
        self.unshot_fraction = unshot_fraction(&s);
        s.estimate = Estimate::new(
            s.estimate.radiosity().to_vec(),
            s.estimate.variance().map(<[DVec3]>::to_vec),
            rays.max(1),
        )?;
        Ok(s)
    }

    /// The solution: the merged estimate, its work counted as every ray the run cast.
    fn finish(self, budget: u64) -> Result<Solution, Error> {
        let m = self.merged.ok_or(Error::BudgetTooSmall(budget))?;
        let estimate = Estimate::new(
            m.radiosity().to_vec(),
            m.variance().map(<[DVec3]>::to_vec),
            self.rays,
        )?;
        Ok(Solution {
            estimate,
            steps: self.steps,
            escaped_rays: self.escaped_rays,
            unshot_fraction: self.unshot_fraction,
            stop: budget_or_stopped(self.stopped),
            direct: None,
            sky_direct: None,
            face_correlation: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passes_double_and_fill_the_budget_without_slivers() {
        let config = ScheduleConfig {
            rays: 1000,
            first_pass_rays: Some(10),
            ..Default::default()
        };
        let passes: Vec<u64> = Doubling::new(&config).collect();
        assert_eq!(passes, vec![10, 20, 40, 80, 160, 320, 370]);
        assert_eq!(passes.iter().sum::<u64>(), 1000);
        let config = ScheduleConfig {
            rays: 63_000,
            ..Default::default()
        };
        let passes: Vec<u64> = Doubling::new(&config).collect();
        assert_eq!(passes, vec![1000, 2000, 4000, 8000, 16000, 32000]);
        let unbounded = ScheduleConfig {
            rays: u64::MAX,
            ..Default::default()
        };
        assert_eq!(
            Doubling::new(&unbounded).take(3).collect::<Vec<_>>(),
            vec![100_000, 200_000, 400_000]
        );
    }

    #[test]
    fn a_cap_makes_the_next_pass_the_last_and_sized_to_it() {
        let unbounded = ScheduleConfig {
            rays: u64::MAX,
            ..Default::default()
        };
        let mut passes = Doubling::new(&unbounded);
        assert_eq!(passes.next(), Some(100_000));
        passes.cap(150_000);
        assert_eq!(passes.peek(), 150_000);
        assert_eq!(passes.collect::<Vec<_>>(), vec![150_000]);
        // A cap above the doubling size but below twice it: the pass takes all of it.
        let mut passes = Doubling::new(&unbounded);
        passes.next();
        passes.cap(390_000);
        assert_eq!(passes.collect::<Vec<_>>(), vec![390_000]);
        // A cap above twice the doubling size leaves passes of the usual size.
        let mut passes = Doubling::new(&unbounded);
        passes.next();
        passes.cap(700_000);
        assert_eq!(passes.collect::<Vec<_>>(), vec![200_000, 500_000]);
    }
}
