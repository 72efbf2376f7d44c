//! Adaptive meshing: [`refine`] (whose documentation describes the method) and [`pool`].

use crate::context::Context;
use crate::direct::{DirectSampling, SplitConfig, two_pass_split};
use crate::error::Error;
use crate::sampling::{Frame, cosine_hemisphere_concentric};
use crate::shoot::{ShootConfig, shoot};
use glam::{DVec3, Vec2, Vec3};
use mcrad_combine::{Estimate, EstimateError, Operand, Weighting, merge};
use mcrad_meshing::{
    AdaptiveMesh, ClusteredMesh, Clusters, DEFAULT_CREASE_ANGLE_DEGREES, Mesh, UNGROUPED,
};
use mcrad_random::{Stream, StreamKey, derive_seed};
use mcrad_raycast::{BuildError, Bvh, Ray, RayCaster, Renumbered, SurfacePoint};
use rayon::prelude::*;
use std::ops::ControlFlow;
use std::sync::Arc;
use std::time::Instant;

/// Luminance weights of linear RGB (Rec. 709), used to compare colours by one number.
const LUMINANCE: DVec3 = DVec3::new(0.2126, 0.7152, 0.0722);

/// Seed tags of the refinement's streams (apart from every schedule's).
const PILOT_TAG: u64 = 0xada0_0000;
const GATHER_TAG: u64 = 0xada1_0000;
const SHADOW_TAG: u64 = 0xada2_0000;
const PROXIMITY_TAG: u64 = 0xada3_0000;
const LIGHT_TAG: u64 = 0xada4_0000;

/// The pilot runs on clusters ([`AdaptiveConfig::pilot_clusters`]) when its rays are fewer
/// than this many per leaf: with fewer, most small faces get no ray of their own and the
/// pilot's direct light per leaf costs more than its shooting. On the sun- and sky-lit atrium
/// (docs/atrium.md) at 22 rays a leaf the pilot per leaf gave the lower image error
/// (2.70% / 2.56% against 2.80% / 2.73%, two seeds); at 0.2 a leaf (10^6 faces) the clustered
/// pilot took the refinement from 18.5 to 3.0 s.
const PILOT_RAYS_PER_LEAF: f64 = 8.0;

/// The speed (rays per second and thread) at which a time budget's pilot is planned, to
/// choose its mesh before any ray is cast ([`PILOT_RAYS_PER_LEAF`]): a fixed figure, so the
/// choice does not depend on the machine's load.
const NOMINAL_RAYS_PER_SECOND: f64 = 1e6;

/// Settings of [`refine`].
#[derive(Debug, Clone, PartialEq)]
pub struct AdaptiveConfig {
    /// Rays the refinement may cast in all (pilot, gathering rounds, shadow and proximity
    /// rays): a third for the pilot shooting, the rest shared by the rounds; a round the rest
    /// cannot pay for (its shadow and proximity rays and 16 rays per element) is not started,
    /// and the last one may exceed
    /// the budget by the refinement's growth of the mesh. `u64::MAX`: no ray budget (then
    /// [`AdaptiveConfig::seconds`] bounds the refinement).
    pub rays: u64,
    /// Wall-clock seconds the refinement may take (s), besides `rays`: a third for the pilot
    /// shooting, the rest shared by the rounds, each sized to the rays that fit in the time
    /// left at the speed measured so far (the mesh then depends on the machine's speed).
    /// `None`: the ray budget alone.
    pub seconds: Option<f64>,
    /// The most refinement rounds.
    pub rounds: u32,
    /// Shadow rays per element and round for the visibility test (0: no visibility test).
    pub shadow_rays: u32,
    /// Rays per element and round for the proximity test (0: no proximity test).
    pub proximity_rays: u32,
    /// A difference counts as a gradient beyond this many of its standard deviations.
    pub noise_sigmas: f64,
    /// The smallest relative contrast worth an element (see [`refine`]).
    pub tolerance: f64,
    /// Seed of every random stream.
    pub seed: u64,
    /// The pilot shooting's unshot threshold (fraction of the emitted power).
    pub unshot_threshold: f64,
    /// Lights without a surface (the scene's frame), as in [`ScheduleConfig::lights`](crate::ScheduleConfig::lights): the
    /// pilot and every round solve with their direct light, and an element across which their
    /// shadows change is marked as for an emitting face's.
    pub lights: Vec<mcrad_scene_io::Light>,
    /// The sky, as in [`ScheduleConfig::sky`](crate::ScheduleConfig::sky): solved with like
    /// the lights (its shadows are not marked by the visibility test; the gradient test sees
    /// them).
    pub sky: Option<mcrad_scene_io::Sky>,
    /// Clusters for the pilot: `Some(bounds)` runs the pilot shooting (and its direct light),
    /// when its rays are too few to reach most leaves ([`refine`]), on the mesh with each
    /// cluster of small faces within `bounds`
    /// ([`mcrad_meshing::Clusters::build`]) one element ([`Mesh::clustered`]), its answer
    /// carried back to the faces ([`mcrad_meshing::Carry::refine`]); the pilot then
    /// places the marks only and is not pooled ([`Refined::pooled_valid`]: its members share one
    /// error). `None`: the pilot runs on every element.
    pub pilot_clusters: Option<mcrad_meshing::ClusterBounds>,
    /// The patch budget's growth with the rays: `Some((r, most))` raises the mesh's
    /// `max_patches`, before each round, to one element per `r` rays of the whole run (four
    /// times the refinement's ray budget: its quarter of the run's rays, or of its time at the
    /// speed measured so far), at most `most`, or to one element per input face plus half of
    /// that when this is more ([`mcrad_meshing::AdaptiveBounds::for_faces`]); never lowers it.
    /// `None`: the mesh's bounds as they are.
    pub patch_growth: Option<(u64, usize)>,
}

impl Default for AdaptiveConfig {
    /// 500 000 rays, 5 rounds, 16 shadow rays, 16 proximity rays, 2 standard deviations, 2%
    /// contrast, seed 0, unshot threshold 1e-3 (on the table room, 2 deviations and 2% gave
    /// 3.2% image error at 2e6 rays against 3.7% with 3 and 5%).
    fn default() -> Self {
        AdaptiveConfig {
            rays: 500_000,
            seconds: None,
            rounds: 5,
            shadow_rays: 16,
            proximity_rays: 16,
            noise_sigmas: 2.0,
            tolerance: 0.02,
            seed: 0,
            unshot_threshold: 1e-3,
            lights: Vec::new(),
            sky: None,
            pilot_clusters: None,
            patch_growth: None,
        }
    }
}

/// Why [`refine`] failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AdaptiveError {
    /// An estimator refused the mesh or its input.
    #[error(transparent)]
    Solve(#[from] Error),
    /// The ray caster could not be built over the refined mesh.
    #[error("could not build the ray caster of the refined mesh: {0}")]
    Caster(#[from] BuildError),
    /// The pilot's clusters could not be made into elements.
    #[error("could not make the pilot's clusters elements: {0}")]
    Clusters(#[from] mcrad_meshing::MeshError),
}

/// Raises `mesh`'s patch budget to `patches` (at most `most`), or to one element per input
/// face plus half of that when this is more; never lowers it.
fn grow_budget(mesh: &mut AdaptiveMesh, patches: u64, most: usize) {
    let bounds = mesh.bounds();
    let patches = usize::try_from(patches).unwrap_or(usize::MAX).min(most);
    let grown = mcrad_meshing::AdaptiveBounds {
        max_patches: patches,
        ..bounds
    }
    .for_faces(mesh.mesh().face_count());
    if grown.max_patches > bounds.max_patches {
        // a larger budget of valid bounds is valid: this cannot fail
        let _ = mesh.set_bounds(grown);
    }
}

/// What one round of [`refine`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RoundStats {
    /// Elements before the round.
    pub elements: usize,
    /// Elements marked by a gradient beyond the noise.
    pub gradient: usize,
    /// Elements marked by a visibility change (some also by a gradient).
    pub visibility: usize,
    /// Elements marked by light reflected from close by (some also by the other tests).
    pub proximity: usize,
    /// Elements split.
    pub split: usize,
    /// Marked elements not split: at the minimum edge, beyond the patch budget, or beyond the
    /// round's share of it (see [`refine`]).
    pub held: usize,
    /// Marked elements that could not be split into valid elements (kept).
    pub unrefinable: usize,
    /// Rays cast in the round (shadow and proximity rays and the gathering round).
    pub rays: u64,
}

/// What [`refine`] returns.
#[derive(Debug, Clone)]
pub struct Refined {
    /// The last round's gathering, one per leaf of the refined mesh (W/m² and its variance):
    /// the children of the last split inherit their parent's value and were gathered once from
    /// it. Empty (no patches, no rays) when no round gathered: the pilot's estimate is then
    /// [`Refined::pooled`]'s, handed over rather than copied (at 10^7 leaves 480 MB).
    pub estimate: Estimate,
    /// Every estimate the refinement made of each leaf's own value, pooled ([`pool`]): a leaf
    /// not split since the pilot pools the pilot and every round's gathering; a leaf made by a
    /// split starts from the gathering that followed it (its parent's estimates are of the
    /// parent's mean, not of the leaf's value, and are dropped). W/m² and its variance; a
    /// reflecting leaf the pilot did not reach carries the variance of one hit of the pilot's
    /// (`(rho p / A)²`, `p` its mean power per ray), not 0, until a round gathers it.
    pub pooled: Estimate,
    /// Whether `pooled` may be pooled into the answer: false when it holds only a pilot that
    /// the clock stopped before it shipped all its power (short of light), or one solved on
    /// clusters (its members share one error).
    pub pooled_valid: bool,
    /// Rays cast by the refinement (pilot, shadow and proximity rays, gathering rounds).
    pub rays: u64,
    /// Each round's counts.
    pub rounds: Vec<RoundStats>,
    /// The ray caster over the refined mesh as it is now ([`Mesh::caster`] of
    /// [`AdaptiveMesh::mesh`]), when the refinement's last one was built after its last split
    /// (the same layout a new build gives): a caller solving the refined mesh can take it
    /// instead of building it again. `None` when the refinement dropped it.
    pub caster: Option<Arc<Bvh>>,
}

impl Refined {
    /// Elements that could not be split into valid elements, over all rounds.
    pub fn unrefinable(&self) -> usize {
        self.rounds.iter().map(|r| r.unrefinable).sum()
    }
}

/// Refines `mesh` where the solution needs it and returns the last estimate on the refined
/// mesh. Deterministic for a seed on any thread count.
///
/// [`refine`] solves a pilot on the starting mesh (shooting; on its clusters of small faces when
/// the pilot's rays are fewer than 8 a leaf and
/// [`AdaptiveConfig::pilot_clusters`] asks for them) and then, for a few rounds, marks
/// the elements whose solution is not resolved, splits them ([`AdaptiveMesh::refine`]), lets
/// the children start from their parent's estimate and re-estimates them by one split
/// gathering step from that inherited solution (the two-pass split of section 1.5:
/// `B_i = E_i + D_i + rho_i mean_k (B - E)(hit_k)`, the direct light `D` by sampling the
/// emitters, the indirect light gathered from the solution learned so far: nothing restarts
/// from zero, and the new shadows and contact lines show at once, even of a small light that
/// gathering rays would rarely hit). An element is marked when
///
/// - **a real gradient the display cannot follow**: its luminance differs from the mean of the
///   vertex values around it ([`Mesh::seamless_corner_radiosity`], what renders interpolate)
///   by more than `noise_sigmas` standard deviations of its own estimate, from the variance it
///   reports, *and* by more than `tolerance` of the larger (a difference the picture would
///   show). A field linear across an element and its neighbours is interpolated exactly and
///   splits nothing, however steep: elements go where the light bends (corners, penumbrae,
///   the edge of a light's pool), not where it falls off evenly; or
/// - **a visibility change**: of `shadow_rays` shadow rays from uniform points of the element
///   to points on the emitters (drawn by power), some reach the emitter and some are blocked,
///   and the direct light that varies, `rho D min(f, 1 - f)` (`D` the unoccluded direct
///   irradiance estimate, `f` its visible share), is more than `tolerance` of the element's
///   luminance: shadow boundaries and the contact lines of objects resting on a surface
///   (lights without a surface, [`AdaptiveConfig::lights`]: the same contrast from the shadow
///   rays that estimate their direct light, which the pilot and every round solve with); or
/// - **light reflected from close by**: of `proximity_rays` cosine-distributed rays from
///   uniform points of the element, those that hit a surface nearer than the element's size
///   `h = sqrt(A)` (a share `q` of them) bring the reflected irradiance `H_near`, all of them
///   `H` (each hit counting its reflected radiosity `B - E`, W/m²); the element is marked when
///   `rho |H_near - q H|`, how far the near surfaces' light departs from what the same share
///   of the view brings on average, is more than `tolerance` of its luminance. Near a crease
///   or a contact with a surface lit otherwise than the rest of the view (the dark top of a
///   wall under a ceiling, a box's side on the floor) the light varies at the element's own
///   scale, non-linearly (a linear slope of one surface makes a `d ln d` in the other's
///   radiosity at the distance `d` from the crease), which the display's linear interpolation
///   cannot follow and the gradient test cannot see in the element means; in an evenly lit
///   enclosure (a furnace) the contrast is only the noise of the estimates `B` however close
///   the walls (the furnace test marks nothing). Measured at 1e8 rays
///   (render --spp 256, docs/meshing.md): Cornell box, 16,000-element budget, image error
///   0.73% -> 0.59%; `rho H_near / 2` alone (not against the rest of the view) marked
///   every crease of the rooms and took the budget from their shadows (table room, 8,000
///   elements: 0.51% -> 0.66%). A hit counts its reflected radiosity alone, as one ray of 16
///   that hits a light would outweigh the rest (counting the emitted light too measured no
///   better: 8,000-element budgets, Cornell box 0.76% either way, table room 0.60% against
///   0.59%, boxes room default 2.94% against 2.97%, with an even share of the budget per
///   round).
///
/// Marked elements are split largest contrast first (the contrast times the element's size),
/// within the mesh's minimum edge and patch budget. A round adds at most half of the elements
/// the budget has left, rounded up ([`AdaptiveMesh::refine_within`]; all of them in the last
/// round the rays can pay for), so that later rounds, which see the refined solution, still
/// have elements to place: without it the proximity marks of the first round took the boxes
/// room's budget (image error at 1e8 rays 3.23%, 2.90% with it). This is RenderPark's hierarchical refinement turned around:
/// RenderPark's power oracle splits an element whose received power is large, lit evenly or
/// not; here an element splits only where the measured solution varies beyond its own noise,
/// its visibility of the light changes or light from close by varies across it.
///
/// Every random number comes from a stream keyed by (seed, round, element), and the marks are
/// folded in element order, so the mesh is the same for a seed on any thread count (with a ray
/// budget; a time budget, [`AdaptiveConfig::seconds`], sizes the rounds by the machine's speed).
pub fn refine(mesh: &mut AdaptiveMesh, config: &AdaptiveConfig) -> Result<Refined, AdaptiveError> {
    let start = Instant::now();
    let pilot_rays = if config.rays == u64::MAX {
        u64::MAX
    } else {
        (config.rays / 3).max(1)
    };
    // The pilot's mesh: the leaves, or clusters of the small ones (dropped after the pilot).
    let planned = match config.seconds {
        Some(s) if pilot_rays == u64::MAX => {
            s / 3.0 * rayon::current_num_threads() as f64 * NOMINAL_RAYS_PER_SECOND
        }
        _ => pilot_rays as f64,
    };
    let coarse = match config.pilot_clusters {
        Some(bounds) if planned < PILOT_RAYS_PER_LEAF * mesh.len() as f64 => {
            pilot_clusters(mesh.mesh(), bounds)?
        }
        _ => None,
    };
    // One hierarchy over the leaves' triangles: the pilot's clusters see it renumbered.
    let bvh = caster(mesh.mesh())?;
    let pilot = match &coarse {
        Some(c) => {
            let caster = Renumbered::new(&bvh, &c.element);
            run_pilot(&c.mesh, &caster, config, (pilot_rays, start))?
        }
        None => run_pilot(mesh.mesh(), &bvh, config, (pilot_rays, start))?,
    };
    let Pilot {
        mut lit,
        estimate,
        mut rays,
        complete: mut pilot_complete,
    } = pilot;
    let Some(mut estimate) = estimate else {
        // Nothing lit (a closed room under the sky): B = 0 exactly, nothing to refine.
        drop(coarse);
        let zero = vec![DVec3::ZERO; mesh.len()];
        let estimate = Estimate::new(zero.clone(), Some(zero), rays).map_err(Error::from)?;
        return Ok(Refined {
            pooled: estimate.clone(),
            pooled_valid: true,
            estimate,
            rays,
            rounds: Vec::new(),
            caster: Some(Arc::new(bvh)),
        });
    };
    // The caster over the mesh as it is (built anew after each split): a round's marks and the
    // caller reuse it.
    let mut current = Some(bvh);
    if let Some(c) = &coarse {
        // carried back to the leaves; the clusters' mesh goes
        let fine = mesh.mesh();
        estimate = Estimate::new(
            c.carry().refine(fine, estimate.radiosity(), true),
            estimate
                .variance()
                .map(|v| c.carry().refine_variance(fine, v)),
            estimate.rays(),
        )
        .map_err(Error::from)?;
        if let Some(l) = &mut lit {
            l.penumbra = c.element.iter().map(|&e| l.penumbra[e as usize]).collect();
        }
        // its members share one error: the pilot places the marks only
        pilot_complete = false;
    }
    drop(coarse);
    // What the pilot says of a patch no ray reached is no information, not a certain 0: the
    // pool carries it with the variance of one hit (the schedules' final outputs' floor), so
    // that pooling it with a later estimate does not trust it fully (a floor of many tiny
    // faces, most of them unreached, would be pooled to a fraction of its light). The marks
    // read the pilot's own variances.
    // It is made from the pilot's estimate where a round first needs it (a copy, 48 bytes a
    // leaf), or at the end from the estimate itself when no round gathered.
    let mut pooled: Option<Estimate> = None;
    let mut rounds = Vec::new();
    for round in 0..config.rounds {
        // The budget: the rays, or those that fit in the time at the speed so far.
        let budget = match config.seconds {
            Some(seconds) => config
                .rays
                .min(rays.saturating_add(rays_that_fit(seconds, start, rays))),
            None => config.rays,
        };
        if let Some((per, most)) = config.patch_growth
            && budget != u64::MAX
        {
            grow_budget(mesh, budget.saturating_mul(4) / per.max(1), most);
        }
        // A round costs its shadow and proximity rays and at least 8 gathering rays and 4
        // emitter samples (two rays each) per element: stop when the budget cannot pay for it.
        let tests = u64::from(config.shadow_rays) + u64::from(config.proximity_rays);
        let cheapest = (tests + 16) * mesh.len() as u64;
        if rays.saturating_add(cheapest) > budget {
            break;
        }
        // A ray budget: what the pilot's third leaves, shared evenly by the rounds (the mesh
        // depends on the budget alone); a time budget: what is left, by the rounds left.
        let round_rays = match config.seconds {
            Some(_) => (budget - rays.min(budget)) / u64::from(config.rounds - round),
            None => (config.rays - pilot_rays.min(config.rays)) / u64::from(config.rounds),
        };
        let bvh = match current.take() {
            Some(bvh) => bvh,
            None => caster(mesh.mesh())?,
        };
        let ctx = Context::new(mesh.mesh(), &bvh);
        let key = StreamKey::new(derive_seed(config.seed, SHADOW_TAG)).pass(u64::from(round));
        let penumbra = lit.as_ref().map(|l| l.penumbra.as_slice());
        let marks = marks(&ctx, &estimate, config, key, penumbra);
        let mut order: Vec<(f64, u32)> = marks
            .iter()
            .enumerate()
            .filter(|(_, m)| m.score > 0.0)
            .map(|(i, m)| (m.score, i as u32))
            .collect();
        order.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut stats = RoundStats {
            elements: mesh.len(),
            gradient: marks.iter().filter(|m| m.gradient).count(),
            visibility: marks.iter().filter(|m| m.visibility).count(),
            proximity: marks.iter().filter(|m| m.proximity).count(),
            split: 0,
            held: 0,
            unrefinable: 0,
            rays: tests * mesh.len() as u64,
        };
        rays += stats.rays;
        drop(ctx);
        let order: Vec<u32> = order.into_iter().map(|(_, i)| i).collect();
        // The round's share of what the patch budget has left: half of it (rounded up), or all
        // of it in the last round the rays can pay for (this one's gathering and the next one's
        // tests on the grown mesh).
        let left = mesh.bounds().max_patches.saturating_sub(mesh.len());
        let next = (tests + 16).saturating_mul((mesh.len() + left / 2) as u64);
        let last = round + 1 == config.rounds
            || rays.saturating_add(round_rays).saturating_add(next) > budget;
        let share = if last { left } else { left.div_ceil(2) };
        // Nothing marked, or no room for a child: the mesh stays as it is, and so does its
        // caster; else the caster goes before the split builds the new mesh.
        if order.is_empty() || share == 0 {
            current = Some(bvh);
        } else {
            drop(bvh);
        }
        let earlier = match pooled.take() {
            Some(p) => p,
            None => crate::shoot::unreached_variance(mesh.mesh(), estimate.clone())?,
        };
        let r = mesh.refine_within(&order, share);
        stats.split = r.split;
        stats.held = r.held;
        stats.unrefinable = r.unrefinable;
        if r.split == 0 {
            pooled = Some(earlier);
            rounds.push(stats);
            break;
        }
        // Children start from their parent's estimate and gather once from it.
        let inherit = |v: &[DVec3]| r.parent.iter().map(|&p| v[p as usize]).collect();
        let inherited = Estimate::new(
            inherit(estimate.radiosity()),
            estimate.variance().map(inherit),
            estimate.rays(),
        )
        .map_err(Error::from)?;
        let bvh = caster(mesh.mesh())?;
        lit = light(mesh.mesh(), &bvh, config, round_rays, u64::from(round) + 1)?;
        let ctx = Context::new(lit.as_ref().map_or(mesh.mesh(), |l| &l.mesh), &bvh);
        // Half the round's rays gather the indirect light, half sample the emitters (two rays a
        // sample).
        let per_patch = (round_rays / 2 / mesh.len() as u64).clamp(8, 1024) as u32;
        let key = StreamKey::new(derive_seed(config.seed, GATHER_TAG)).pass(u64::from(round));
        let split = SplitConfig {
            rays_per_patch: per_patch,
            samples_per_patch: (per_patch / 2).max(2),
            sampling: DirectSampling::EmittersAndCosine,
        };
        let mut gathered = two_pass_split(&ctx, &inherited, &split, key)?;
        if let Some(l) = &lit {
            rays += l.rays;
            stats.rays += l.rays;
            gathered = l.include(gathered)?;
        }
        stats.rays += gathered.rays();
        rays += gathered.rays();
        // A leaf kept as it was pools this round's estimate with its earlier ones; a child
        // starts from this round's.
        let mut children = vec![0u32; r.parent.last().map_or(0, |&p| p as usize + 1)];
        for &p in &r.parent {
            children[p as usize] += 1;
        }
        let kept: Vec<bool> = r
            .parent
            .iter()
            .map(|&p| children[p as usize] == 1 && (pilot_complete || !rounds.is_empty()))
            .collect();
        let carried = Estimate::new(
            inherit(earlier.radiosity()),
            earlier.variance().map(inherit),
            earlier.rays(),
        )
        .map_err(Error::from)?;
        drop(earlier);
        pooled = Some(pool(mesh.mesh(), &gathered, &carried, &kept).map_err(Error::from)?);
        estimate = gathered;
        rounds.push(stats);
        drop(ctx);
        current = Some(bvh);
    }
    // Without a gathering round the pool holds the pilot alone, and the pilot's estimate is
    // handed over to it (not copied).
    // (a round that split gathered; one that did not stopped the refinement)
    let any_gathered = rounds.iter().any(|r| r.split > 0);
    let pooled_valid = pilot_complete || any_gathered;
    let pooled = match pooled {
        Some(p) if any_gathered => p,
        _ => crate::shoot::unreached_variance(mesh.mesh(), std::mem::take(&mut estimate))?,
    };
    Ok(Refined {
        estimate,
        pooled,
        pooled_valid,
        rays,
        rounds,
        caster: current.map(Arc::new),
    })
}

/// Pools two independent estimates of the same leaves' values, `fresh` (trusted: its variance
/// is taken as reported) and `earlier` (its variance checked against `fresh`), by weights
/// constant over each input face (`Patch::face`) and channel:
///
/// - `V_f`, `V_e`: the mean reported variances of the two over the face's leaves where
///   `earlier_valid` is true, `D` the mean squared difference `(X_f - X_e)²` there;
/// - the earlier estimate's variance is taken as `max(V_e, D - V_f)` (`D` estimates
///   `V_f + V_e` plus any bias or correlated error between the two that the reported
///   variances miss, e.g. a refinement gathered from an inherited solution);
/// - `w_f = V_e' / (V_f + V_e')`, and `1` where both are 0 or `earlier_valid` is false.
///
/// The weights read the values only through means over a whole face, so the pooled value of a
/// leaf is, to that extent, the weighted mean of two unbiased estimates with weights that do
/// not depend on it: unbiased (per-leaf inverse variances would bias it low where the variance
/// grows with the value: see `mcrad_combine::expected`). Its variance is `w² V_f + (1 - w)²
/// V_e` from the reported variances, its rays the sum. Without a variance on either side,
/// `fresh` is returned. Errors: lengths differ from the mesh's patch count.
pub fn pool(
    mesh: &Mesh,
    fresh: &Estimate,
    earlier: &Estimate,
    earlier_valid: &[bool],
) -> Result<Estimate, EstimateError> {
    match pool_weights(mesh, fresh, earlier, earlier_valid)? {
        Some(weights) => merge(fresh, earlier, &Given(weights)),
        None => Ok(fresh.clone()),
    }
}

/// The factors of the correlation between each face's patches
/// ([`Solution::face_correlation`](crate::Solution)) in [`pool`]'s answer, `k` those of
/// `fresh`: `earlier`'s part is taken as independent between patches (its own correlation is
/// not known), so per face and channel `k'_f = (k_f S_f + E_f) / (S_f + E_f)` with
/// `S_f = sum_i A_i² w_i² V_f,i` and `E_f = sum_i A_i² (1 - w_i)² V_e,i` ([`pool`]'s weights
/// `w` on `fresh`). `k` itself where [`pool`] returns `fresh`. Errors as [`pool`]'s.
pub fn pool_correlation(
    mesh: &Mesh,
    fresh: &Estimate,
    earlier: &Estimate,
    earlier_valid: &[bool],
    k: &[DVec3],
) -> Result<Vec<DVec3>, EstimateError> {
    let mut k = k.to_vec();
    let (Some(weights), Some(vf), Some(ve)) = (
        pool_weights(mesh, fresh, earlier, earlier_valid)?,
        fresh.variance(),
        earlier.variance(),
    ) else {
        return Ok(k);
    };
    // Each part made where it is read (not two arrays of 24 bytes a patch).
    let own = |i: usize| weights[i] * weights[i] * vf[i];
    let added = |i: usize| {
        let w = DVec3::ONE - weights[i];
        w * w * ve[i]
    };
    crate::correlation::with_independent(mesh, &mut k, own, added);
    Ok(k)
}

/// [`pool`]'s weights on `fresh` per patch and channel; `None` without a variance on either
/// side. Errors as [`pool`]'s.
fn pool_weights(
    mesh: &Mesh,
    fresh: &Estimate,
    earlier: &Estimate,
    earlier_valid: &[bool],
) -> Result<Option<Vec<DVec3>>, EstimateError> {
    let n = mesh.patches().len();
    for len in [fresh.len(), earlier.len(), earlier_valid.len()] {
        if len != n {
            return Err(EstimateError::PatchCountMismatch { a: n, b: len });
        }
    }
    let (Some(vf), Some(ve)) = (fresh.variance(), earlier.variance()) else {
        return Ok(None);
    };
    let faces = mesh.face_count();
    // Per face: leaves counted, sums of V_f, V_e and (X_f - X_e)².
    let mut sums = vec![(0.0, DVec3::ZERO, DVec3::ZERO, DVec3::ZERO); faces];
    for (i, p) in mesh.patches().iter().enumerate() {
        if earlier_valid[i] {
            let d = fresh.radiosity()[i] - earlier.radiosity()[i];
            let s = &mut sums[p.face as usize];
            s.0 += 1.0;
            s.1 += vf[i].max(DVec3::ZERO);
            s.2 += ve[i].max(DVec3::ZERO);
            s.3 += d * d;
        }
    }
    // (the sums go as the weights are made: 80 bytes a face)
    let face_weight: Vec<DVec3> = sums
        .into_iter()
        .map(|(count, vf, ve, d)| {
            if count == 0.0 {
                return DVec3::ONE;
            }
            let (vf, ve, d) = (vf / count, ve / count, d / count);
            let ve = ve.max(d - vf);
            let total = vf + ve;
            DVec3::select(total.cmpgt(DVec3::ZERO), ve / total, DVec3::ONE)
        })
        .collect();
    let weights: Vec<DVec3> = mesh
        .patches()
        .iter()
        .zip(earlier_valid)
        .map(|(p, &valid)| {
            if valid {
                face_weight[p.face as usize]
            } else {
                DVec3::ONE
            }
        })
        .collect();
    Ok(Some(weights))
}

/// Weights given per patch and channel (the weight of the first operand).
struct Given(Vec<DVec3>);

impl Weighting for Given {
    fn weight(&self, _: &Operand, _: &Operand, patch: usize, channel: usize) -> f64 {
        self.0[patch][channel].clamp(0.0, 1.0)
    }
}

/// The rays that fit in what is left of `seconds` since `start`, at the speed of the `rays`
/// cast since then (0 when no time is left; `u64::MAX` before the first ray).
fn rays_that_fit(seconds: f64, start: Instant, rays: u64) -> u64 {
    let elapsed = start.elapsed().as_secs_f64();
    if elapsed >= seconds {
        return 0;
    }
    if rays == 0 || elapsed <= 0.0 {
        return u64::MAX;
    }
    ((seconds - elapsed) * rays as f64 / elapsed).min(u64::MAX as f64) as u64
}

/// What the refinement's pilot found (see [`run_pilot`]).
struct Pilot {
    /// The lights' direct light on the pilot's mesh, if the scene has lights or a sky.
    lit: Option<crate::lights::Lit>,
    /// The pilot's estimate per element of its mesh; `None` when nothing is lit (no emitter,
    /// and no light reaches a surface).
    estimate: Option<Estimate>,
    /// Rays cast, the lights' included.
    rays: u64,
    /// Whether the shooting shipped all its power: a pilot stopped by the clock is short of
    /// light, and its estimate places the marks but is not pooled into the answer.
    complete: bool,
}

/// The refinement's pilot on `mesh` through `caster`: the lights' direct light, then a
/// shooting of `pilot_rays` (or of a third of the time, from `start`).
fn run_pilot<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    config: &AdaptiveConfig,
    (pilot_rays, start): (u64, Instant),
) -> Result<Pilot, AdaptiveError> {
    let pilot_seconds = config.seconds.map(|s| s / 3.0);
    let lit = light(mesh, caster, config, pilot_rays, 0)?;
    if let Some(l) = &lit
        && l.mesh
            .patches()
            .iter()
            .all(|p| p.emission.max_element() <= 0.0)
    {
        let rays = l.rays;
        return Ok(Pilot {
            lit,
            estimate: None,
            rays,
            complete: true,
        });
    }
    let ctx = Context::new(lit.as_ref().map_or(mesh, |l| &l.mesh), caster);
    let s = shoot(
        &ctx,
        &ShootConfig {
            rays: pilot_rays,
            unshot_threshold: config.unshot_threshold,
            seed: derive_seed(config.seed, PILOT_TAG),
            ..Default::default()
        },
        &mut |p| {
            if let Some(seconds) = pilot_seconds {
                let fits = rays_that_fit(seconds, start, p.rays);
                if fits == 0 {
                    return ControlFlow::Break(());
                }
                p.limit_rays_left(fits);
            }
            ControlFlow::Continue(())
        },
    )?;
    let complete =
        s.stats.unshot.element_sum() <= 1e-9 * s.stats.emitted.element_sum().max(f64::MIN_POSITIVE);
    let (estimate, rays) = match &lit {
        Some(l) => (l.include(s.estimate)?, s.stats.rays + l.rays),
        None => (s.estimate, s.stats.rays),
    };
    Ok(Pilot {
        lit,
        estimate: Some(estimate),
        rays,
        complete,
    })
}

/// The BVH of `mesh`'s triangles tagged with their patch indices.
fn caster(mesh: &Mesh) -> Result<Bvh, BuildError> {
    mesh.caster()
}

/// `mesh` with its clusters of small faces within `bounds` made one element each, for the
/// pilot ([`AdaptiveConfig::pilot_clusters`]); `None` when no cluster forms.
fn pilot_clusters(
    mesh: &Mesh,
    bounds: mcrad_meshing::ClusterBounds,
) -> Result<Option<ClusteredMesh>, AdaptiveError> {
    let clusters = Clusters::build(mesh, bounds);
    if clusters.is_empty() {
        return Ok(None);
    }
    let mut group = vec![UNGROUPED; mesh.patches().len()];
    for (k, members) in clusters.iter().enumerate() {
        for &i in members {
            group[i as usize] = k as u32;
        }
    }
    let coarse = mesh.clustered(&group)?;
    Ok((coarse.mesh.patches().len() < mesh.patches().len()).then_some(coarse))
}

/// Why an element is marked, and how urgently (0: not marked).
#[derive(Debug, Clone, Copy, Default)]
struct Mark {
    score: f64,
    gradient: bool,
    visibility: bool,
    proximity: bool,
}

pub(crate) fn luminance(x: DVec3) -> f64 {
    x.dot(LUMINANCE)
}

/// The standard deviation of an estimate's luminance from its per-channel variances (channels
/// taken as fully correlated, the larger bound).
fn luminance_sigma(v: DVec3) -> f64 {
    v.max(DVec3::ZERO)
        .to_array()
        .iter()
        .zip(LUMINANCE.to_array())
        .map(|(v, w)| w * v.sqrt())
        .sum()
}

/// `mesh` lit by `config.lights` ([`crate::lights::light_mesh`] with a budget of `rays`, its
/// streams keyed by the seed and `stage`); `None` without lights.
fn light<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    config: &AdaptiveConfig,
    rays: u64,
    stage: u64,
) -> Result<Option<crate::lights::Lit>, Error> {
    if config.lights.is_empty() && config.sky.is_none() {
        return Ok(None);
    }
    let schedule = crate::schedule::ScheduleConfig {
        rays,
        seed: derive_seed(config.seed, LIGHT_TAG + stage),
        lights: config.lights.clone(),
        sky: config.sky.clone(),
        // without a ray budget: a quarter of the pilot's third of the time
        lights_seconds: config.seconds.map(|s| s / 12.0),
        ..Default::default()
    };
    crate::lights::light_mesh(mesh, caster, &schedule, None).map(Some)
}

/// The marks of every element of `ctx`'s mesh for the solution `estimate` (`penumbra`: the
/// lights' shadow contrast per element, [`crate::lights::Lit::penumbra`]).
fn marks<C: RayCaster>(
    ctx: &Context<C>,
    estimate: &Estimate,
    config: &AdaptiveConfig,
    key: StreamKey,
    penumbra: Option<&[f64]>,
) -> Vec<Mark> {
    let mesh = ctx.mesh();
    let patches = mesh.patches();
    let b = estimate.radiosity();
    let v = estimate.variance();
    let lum: Vec<f64> = b.iter().map(|&x| luminance(x)).collect();
    let sigma: Vec<f64> = match v {
        Some(v) => v.iter().map(|&x| luminance_sigma(x)).collect(),
        None => vec![0.0; b.len()],
    };
    let size: Vec<f64> = patches.iter().map(|p| p.area.sqrt()).collect();
    let mut marks = vec![Mark::default(); patches.len()];

    // Gradients the display cannot follow: the element's own value against the mean of the
    // vertex values interpolated around it (equal for a field linear across its neighbours).
    let corners = mesh.seamless_corner_radiosity(b, DEFAULT_CREASE_ANGLE_DEGREES);
    for (i, p) in patches.iter().enumerate() {
        let offset = mesh.corner_offset(i);
        let n = mesh.corners(p).len();
        let interpolated = (offset..offset + n)
            .map(|c| luminance(corners[c]))
            .sum::<f64>()
            / n as f64;
        let deviation = (lum[i] - interpolated).abs();
        let bright = lum[i].max(interpolated);
        if deviation > config.noise_sigmas * sigma[i] && deviation > config.tolerance * bright {
            let m = &mut marks[i];
            m.gradient = true;
            m.score = m.score.max(deviation / bright * size[i]);
        }
    }

    // Visibility changes: shadow rays to the emitters.
    if config.shadow_rays > 0
        && let Some(lights) = Lights::new(mesh)
    {
        let contrast: Vec<f64> = (0..patches.len())
            .into_par_iter()
            .map(|i| {
                let mut stream = key.item(i as u64).stream();
                visibility_contrast(ctx, &lights, i, lum[i], config.shadow_rays, &mut stream)
            })
            .collect();
        mark_contrasts(&mut marks, &contrast, &size, config.tolerance, |m| {
            m.visibility = true
        });
    }
    // Visibility changes of the lights without a surface, from the shadow rays that lit the
    // mesh.
    if config.shadow_rays > 0
        && let Some(penumbra) = penumbra
    {
        let contrast: Vec<f64> = penumbra
            .iter()
            .zip(&lum)
            .map(|(p, l)| p / l.max(1e-300))
            .collect();
        mark_contrasts(&mut marks, &contrast, &size, config.tolerance, |m| {
            m.visibility = true
        });
    }
    // Light reflected from close by: rays to the surfaces around.
    if config.proximity_rays > 0 {
        let reflected: Vec<f64> = patches
            .iter()
            .zip(b)
            .map(|(p, &x)| luminance(x - p.emission.as_dvec3()).max(0.0))
            .collect();
        let key = key.substream(PROXIMITY_TAG);
        let contrast: Vec<f64> = (0..patches.len())
            .into_par_iter()
            .map(|i| {
                let mut stream = key.item(i as u64).stream();
                let rays = config.proximity_rays;
                proximity_contrast(ctx, &reflected, i, size[i], lum[i], rays, &mut stream)
            })
            .collect();
        mark_contrasts(&mut marks, &contrast, &size, config.tolerance, |m| {
            m.proximity = true
        });
    }
    marks
}

/// Marks (by `flag`) the elements whose relative `contrast` is over `tolerance`, scored by the
/// contrast times the element's `size`.
fn mark_contrasts(
    marks: &mut [Mark],
    contrast: &[f64],
    size: &[f64],
    tolerance: f64,
    flag: impl Fn(&mut Mark),
) {
    for ((m, &c), &h) in marks.iter_mut().zip(contrast).zip(size) {
        if c > tolerance {
            flag(m);
            m.score = m.score.max(c * h);
        }
    }
}

/// The contrast of the light reflected from close by onto element `i` (see the module
/// documentation): `rho |H_near - q H|` relative to the larger of `luminance_i` and `rho H`
/// (what the rays say the element reflects, where its own estimate is still 0); 0 when the
/// surfaces nearer than the element's size `size` (scene units) reflect what the rest of its
/// view does. `reflected`: per patch, the luminance of the radiosity it reflects, `B - E`
/// (W/m²).
fn proximity_contrast<C: RayCaster>(
    ctx: &Context<C>,
    reflected: &[f64],
    i: usize,
    size: f64,
    luminance_i: f64,
    rays: u32,
    stream: &mut Stream,
) -> f64 {
    let mesh = ctx.mesh();
    let patch = &mesh.patches()[i];
    let rho = luminance(patch.reflectance.as_dvec3());
    if rho <= 0.0 || rays == 0 {
        return 0.0;
    }
    let frame = Frame::from_normal(patch.normal);
    let (mut close, mut all, mut hits_close) = (0.0, 0.0, 0u32);
    for _ in 0..rays {
        let x = point_on(mesh, i, stream);
        let u = Vec2::new(stream.uniform(), stream.uniform());
        let dir = frame.to_world(cosine_hemisphere_concentric(u));
        let ray = Ray::from_surface(x, patch.normal, dir, i as u32);
        if let Some(hit) = ctx.caster().closest_hit(&ray)
            && hit.front
        {
            let b = reflected[hit.id as usize];
            all += b;
            if f64::from(hit.distance) < size {
                close += b;
                hits_close += 1;
            }
        }
    }
    let n = f64::from(rays);
    let contrast = rho * (close / n - f64::from(hits_close) / n * all / n).abs();
    if contrast > 0.0 {
        contrast / luminance_i.max(rho * all / n)
    } else {
        0.0
    }
}

/// The emitters, drawn in proportion to their luminous power.
pub(crate) struct Lights {
    /// Emitting patches and the cumulative share of power up to and including each.
    patches: Vec<u32>,
    cumulative: Vec<f64>,
    total: f64,
}

impl Lights {
    pub(crate) fn new(mesh: &Mesh) -> Option<Lights> {
        let (mut patches, mut cumulative, mut total) = (Vec::new(), Vec::new(), 0.0);
        for (i, p) in mesh.patches().iter().enumerate() {
            let power = luminance(p.emission.as_dvec3()) * p.area;
            if power > 0.0 {
                total += power;
                patches.push(i as u32);
                cumulative.push(total);
            }
        }
        (total > 0.0).then_some(Lights {
            patches,
            cumulative,
            total,
        })
    }

    /// An emitter drawn by power and the probability of drawing it.
    pub(crate) fn draw(&self, mesh: &Mesh, u: f64) -> (usize, f64) {
        let x = u * self.total;
        let k = self
            .cumulative
            .partition_point(|&c| c <= x)
            .min(self.patches.len() - 1);
        let patch = self.patches[k] as usize;
        let p = &mesh.patches()[patch];
        (
            patch,
            luminance(p.emission.as_dvec3()) * p.area / self.total,
        )
    }
}

/// A uniform point on patch `i` of `mesh`.
pub(crate) fn point_on(mesh: &Mesh, i: usize, stream: &mut Stream) -> Vec3 {
    let patch = &mesh.patches()[i];
    let triangles = mesh.patch_triangles(patch);
    let positions = mesh.positions();
    let area = |t: &[u32; 3]| {
        let [a, b, c] = t.map(|v| positions[v as usize].as_dvec3());
        (b - a).cross(c - a).length()
    };
    let total: f64 = triangles.iter().map(area).sum();
    let mut x = stream.uniform_f64() * total;
    let mut pick = triangles[triangles.len() - 1];
    for t in triangles {
        let a = area(t);
        if x < a {
            pick = *t;
            break;
        }
        x -= a;
    }
    let [a, b, c] = pick.map(|v| positions[v as usize].as_dvec3());
    let (r1, r2) = (stream.uniform_f64().sqrt(), stream.uniform_f64());
    (a * (1.0 - r1) + b * (r1 * (1.0 - r2)) + c * (r1 * r2)).as_vec3()
}

/// The contrast of the direct light across element `i` (see [`refine`]): 0 when
/// every shadow ray that can carry light agrees.
fn visibility_contrast<C: RayCaster>(
    ctx: &Context<C>,
    lights: &Lights,
    i: usize,
    luminance_i: f64,
    rays: u32,
    stream: &mut Stream,
) -> f64 {
    let mesh = ctx.mesh();
    let patch = &mesh.patches()[i];
    let rho = luminance(patch.reflectance.as_dvec3());
    if rho <= 0.0 {
        return 0.0;
    }
    let (mut all, mut visible, mut seen, mut blocked) = (0.0, 0.0, 0u32, 0u32);
    for _ in 0..rays {
        let x = point_on(mesh, i, stream);
        let (light, probability) = lights.draw(mesh, stream.uniform_f64());
        if light == i {
            continue;
        }
        let y = point_on(mesh, light, stream);
        let l = &mesh.patches()[light];
        let d = (y - x).as_dvec3();
        let r2 = d.length_squared();
        if r2 <= 0.0 {
            continue;
        }
        let w = d / r2.sqrt();
        let (cx, cy) = (patch.normal.as_dvec3().dot(w), -l.normal.as_dvec3().dot(w));
        if cx <= 0.0 || cy <= 0.0 {
            continue;
        }
        // Irradiance from this sample: E_l cos cos / (pi r^2) / (p_l / A_l).
        let g = luminance(l.emission.as_dvec3()) * cx * cy / (std::f64::consts::PI * r2) * l.area
            / probability;
        all += g;
        let a = SurfacePoint::new(x, patch.normal, i as u32);
        let b = SurfacePoint::new(y, l.normal, light as u32);
        if ctx.caster().occluded(&a, &b) {
            blocked += 1;
        } else {
            visible += g;
            seen += 1;
        }
    }
    if seen == 0 || blocked == 0 || all <= 0.0 {
        return 0.0;
    }
    let f = visible / all;
    let direct = rho * all / f64::from(rays);
    direct * f.min(1.0 - f) / luminance_i.max(1e-300)
}
