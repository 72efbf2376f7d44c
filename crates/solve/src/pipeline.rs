//! [`solve`]: mesh, refine, run, under one budget.

use crate::clusters::{ALONE, Groups, PoolCounts, pool_clusters};
use crate::per_patch::PerPatch;
use crate::problem::Input;
use crate::state::Identity;
use crate::stats::ClusterStats;
use crate::stats::{RefinementRound, SetupPhases};
use crate::{
    Budget, Clustering, Error, MeshPlan, PATCH_RAYS, Problem, RunState, RunStats, Settings,
    piece_seed,
};
use glam::DVec3;
use mcrad_combine::{Estimate, relative_error, weighted_quantile};
use mcrad_mc_radiosity::{
    AdaptiveConfig, Error as MethodError, Refined, ScheduleConfig, ShadowSplit, Solution, Step,
    StopReason, refine, run_cancellable, split_shadowed,
};
use mcrad_meshing::{
    AdaptiveBounds, AdaptiveMesh, AdaptiveStart, Carry, ClusterBounds, ClusteredMesh, Clusters,
    CornerGroups, DEFAULT_CLUSTER_CONE_DEGREES, DEFAULT_COARSE_EDGE_FRACTION, History, Mesh,
    Subdivision,
};
use mcrad_random::derive_seed;
use mcrad_raycast::{Bvh, Renumbered};
use mcrad_reference::ReferenceConfig;
use mcrad_scene_io::Scene;
use std::borrow::Cow;
use std::ops::ControlFlow;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

/// The answer of a solve.
///
/// Invariants: `estimate`, `patch` and the mesh's patches have the same length and order.
#[derive(Debug)]
pub struct Answer {
    /// The patches solved for.
    pub mesh: Mesh,
    /// The ray caster over `mesh` (renders and bakes reuse it).
    pub bvh: Bvh,
    /// Radiosity `B_i` per patch and channel (W/m², mesh order), its estimated variance
    /// ((W/m²)²) where the method gives one, and the rays behind it. For a continued run, all
    /// pieces merged.
    pub estimate: Estimate,
    /// Each patch's number in outputs (mesh order): its input face with
    /// [`MeshPlan::PerFace`] (a back side's plus [`Mesh::back_face_offset`]), else its index.
    pub patch: Vec<u32>,
    /// What the run reports of itself.
    pub stats: RunStats,
    /// The run's state, to continue it ([`Problem::resume`]); `None` for a deterministic
    /// method, a new run without [`Problem::keep_state`], or a run stopped in a step that is
    /// not a complete solution (a shooting wave, a Jacobi round).
    pub state: Option<RunState>,
    /// Whether the run ended because the error target was reached.
    pub target_reached: bool,
    /// Whether a step in progress was abandoned through the cancel flag (the answer is the
    /// last complete one).
    pub cancelled: bool,
    /// Whether every step of the method is a complete solution (the progressive methods): a
    /// run stopped between steps then still has a state to continue.
    pub complete_steps: bool,
    /// What the caller should be told (a repair, a setting without effect), one line each.
    pub warnings: Vec<String>,
    /// With punctual lights (point, spot, sun) or a sky: their direct irradiance `H_d,i` per
    /// patch (W/m² per channel, mesh order; the lights' and the sky's together) as this
    /// piece's lights' pre-pass estimated it, the part of `estimate` that is direct light
    /// being `rho_i H_d,i`. A renderer or baker that draws `rho(x) H_d(x)` per pixel with its
    /// own shadow rays takes the rest, `B_i - rho_i H_d,i` (clamped at 0), from the solution.
    /// For a continued or pooled answer the pieces' own estimates of `H_d` differ by their
    /// noise. `None` without lights or sky, or when the run was cancelled within a step.
    /// With clusters as elements of transport, the members of an element share its value.
    pub direct: Option<PerPatch>,
    /// The sky's part of `direct` (W/m² per channel, mesh order; 0 without a sky); `None` when
    /// `direct` is.
    pub sky_direct: Option<PerPatch>,
    /// Per face as outputs number them (its input face, plus [`Mesh::back_face_offset`] for a
    /// back side), per channel: the factor `k_f` by which the variance of the face's
    /// area-weighted mean exceeds `sum_i (A_i / A_f)² V_i` over its patches (taken as
    /// independent) through the correlation between their errors; dimensionless, 1 for a face
    /// of one patch ([`Solution::face_correlation`](mcrad_mc_radiosity::Solution)). A
    /// continued run's pieces
    /// (the same method on the same mesh, merged alike over a face) share this piece's
    /// factors. `None` where the method keeps no error samples, or the run was cancelled
    /// within a step: the patches are then taken as independent.
    pub face_correlation: Option<Vec<DVec3>>,
}

/// A complete step of the run, as the observer of [`solve`] sees it.
pub struct Progress<'a> {
    /// Steps done in this piece (1 for the first).
    pub step: u32,
    /// Rays the method cast so far in this piece (the refinement's not counted).
    pub rays: u64,
    /// The method's ray budget for this piece (`u64::MAX`: none): what `rays` runs up to.
    pub budget_rays: u64,
    /// Seconds since the method started.
    pub seconds: f64,
    /// Whether the step is a complete solution (it carries a variance).
    pub complete: bool,
    run: &'a Run<'a>,
    step_estimate: &'a StepEstimate<'a>,
}

impl Progress<'_> {
    /// The mesh solved (the answer's, patch `i` is `radiosity()[i]`).
    pub fn mesh(&self) -> &Mesh {
        self.run.mesh
    }

    /// This piece's solution after the step (W/m², mesh order).
    pub fn radiosity(&self) -> Result<&[DVec3], Error> {
        Ok(self.step_estimate.get()?.radiosity())
    }

    /// The answer the run would give if it stopped now: the step (pooled over the run's
    /// clusters), or merged with the saved pieces of a continued run.
    pub fn answer(&self) -> Result<Estimate, Error> {
        self.run.answer(Cow::Borrowed(self.step_estimate.get()?))
    }

    /// The run's state after the step, to save and continue; `None` for steps that are not
    /// complete solutions.
    pub fn state(&self) -> Result<Option<RunState>, Error> {
        if !self.complete {
            return Ok(None);
        }
        let (_, state) =
            self.run
                .settle(Cow::Borrowed(self.step_estimate.get()?), self.step, 0, true)?;
        Ok(state)
    }
}

/// The observer of [`solve`]: called after each step (a complete solution or not:
/// [`Progress::complete`]); `Break` stops the run there.
pub type Observer<'o> = dyn FnMut(&Progress) -> ControlFlow<()> + Send + 'o;

/// A step's estimate, on the elements the method ran on, and per patch of the mesh solved
/// when read: carried from the transport's elements on first read
/// ([`Carry::refine`]), so that a step nobody reads costs no array per patch.
struct StepEstimate<'a> {
    /// On the method's elements (the transport's, or the mesh's patches).
    own: Estimate,
    transport: Option<&'a ClusteredMesh>,
    fine: &'a Mesh,
    carried: std::sync::OnceLock<Estimate>,
}

impl<'a> StepEstimate<'a> {
    fn new(own: Estimate, transport: Option<&'a ClusteredMesh>, fine: &'a Mesh) -> Self {
        Self {
            own,
            transport,
            fine,
            carried: std::sync::OnceLock::new(),
        }
    }

    /// The estimate per patch of the mesh solved.
    fn get(&self) -> Result<&Estimate, Error> {
        let Some(c) = self.transport else {
            return Ok(&self.own);
        };
        if let Some(e) = self.carried.get() {
            return Ok(e);
        }
        let e = carried_from(c.carry(), self.fine, &self.own)?;
        Ok(self.carried.get_or_init(|| e))
    }
}

/// What a run knows while it runs.
struct Run<'a> {
    mesh: &'a Mesh,
    history: Option<&'a History>,
    settings: &'a Settings,
    patch: &'a [u32],
    resumed: Option<&'a RunState>,
    lighting: u64,
    /// Small faces that share one estimate of irradiance where the light allows
    /// ([`crate::clusters`]); empty but on the adaptive plan.
    clusters: &'a Clusters,
    /// The smallest span of a cluster that pooling tests and splits (scene units).
    min_span: f64,
    /// The groups of faces that were one element each of the transport (their estimates
    /// already share one irradiance, and their errors are one), and what forming them did.
    transport: (&'a Clusters, PoolCounts),
    /// What the last pooling over `clusters` did, and its groups.
    pooled: std::sync::Mutex<(PoolCounts, Groups)>,
}

impl Run<'_> {
    /// The answer from this piece's `estimate` (see [`Progress::answer`]). An adaptive
    /// refinement's estimates are not pooled into it: they estimate the solutions of the
    /// coarser meshes the refinement went through (each round gathers from values its new
    /// elements inherited), not the refined mesh's, and pooled they biased the answer (see
    /// [`solve`]).
    fn answer(&self, estimate: Cow<'_, Estimate>) -> Result<Estimate, Error> {
        match self.resumed {
            Some(state) => state
                .continued(&self.clustered(estimate)?, 0, 0)?
                .estimate(),
            None => self.clustered(estimate),
        }
    }

    /// `estimate` pooled over the run's clusters (itself without clusters); the groups of
    /// the transport are counted with the pooling's groups. An estimate handed over is
    /// returned as it is where nothing is pooled (not copied: 48 bytes a patch).
    fn clustered(&self, estimate: Cow<'_, Estimate>) -> Result<Estimate, Error> {
        let (transport, formed) = self.transport;
        if self.clusters.is_empty() && transport.is_empty() {
            return Ok(estimate.into_owned());
        }
        let (pooled, mut counts, mut groups) = if self.clusters.is_empty() {
            let alone = vec![ALONE; self.mesh.patches().len()];
            (estimate.into_owned(), PoolCounts::default(), alone)
        } else {
            pool_clusters(self.mesh, self.clusters, estimate, Some(self.min_span))?
        };
        for (k, members) in transport.iter().enumerate() {
            for &i in members {
                groups[i as usize] = (counts.groups + k) as u32;
            }
        }
        counts.groups += formed.groups;
        counts.faces += formed.faces;
        counts.splits += formed.splits;
        if let Ok(mut last) = self.pooled.lock() {
            *last = (counts, groups);
        }
        Ok(pooled)
    }

    /// The answer and the state after this piece's `estimate` (`steps` steps, `escaped_rays`
    /// escaped rays), each made once: the state holds the answer. A new run's state is made
    /// only when `keep` says so ([`Problem::keep_state`]); a continued run's always (its
    /// answer is read from it).
    fn settle(
        &self,
        estimate: Cow<'_, Estimate>,
        steps: u32,
        escaped_rays: u64,
        keep: bool,
    ) -> Result<(Estimate, Option<RunState>), Error> {
        match self.resumed {
            Some(saved) => {
                let state = saved.continued(&self.clustered(estimate)?, steps, escaped_rays)?;
                Ok((state.estimate()?, Some(state)))
            }
            None => {
                let id = Identity {
                    mesh: self.mesh,
                    history: self.history,
                    settings: self.settings,
                    patch: self.patch,
                    lighting: self.lighting,
                };
                let answer = self.answer(estimate)?;
                let state = keep.then(|| RunState::new(&id, &answer, 1, steps, escaped_rays));
                Ok((answer, state))
            }
        }
    }
}

/// Solves `problem`, handing each step to `observer` (which may stop the run with `Break`; the
/// answer is then that step's). Deterministic for a seed on any thread count,
/// except where a time budget decides how many rays are cast.
///
/// On an adaptive mesh the answer is the method's solution of the refined mesh alone: the
/// refinement's estimates place the elements and test the clusters but are not pooled into
/// it. They are estimates of the coarser meshes' solutions, not the refined mesh's: the pilot
/// solves the starting mesh, and each round gathers once from values the new elements
/// inherited from their parents, so where a split separates parts of an element that send
/// their light differently (the floor under a bottomless box, whose light ends on its back
/// faces, from the floor around it) the light the refined mesh keeps in play is still
/// missing, a lag that only further Jacobi steps on the refined mesh take away. Pooled, that
/// lag and weights read from each face's own values left the boxes room's answer short of
/// 2.3-3.5% of its light under `gather` (8 to 17 standard errors of its balance, seeds 0-3,
/// 1e7 rays) and 0.25-0.29% under `shoot` (7-8); unpooled, within 2.2 and 0.4. Extra Jacobi
/// steps on the refined mesh took the refinement's own lag (+1% red) to within its noise.
pub fn solve(problem: &Problem, observer: &mut Observer) -> Result<Answer, Error> {
    match problem.threads {
        Some(n) if n != rayon::current_num_threads() => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|source| Error::Threads { threads: n, source })?;
            pool.install(|| solve_here(problem, observer))
        }
        _ => solve_here(problem, observer),
    }
}

fn solve_here(problem: &Problem, observer: &mut Observer) -> Result<Answer, Error> {
    let clock = problem.budget.since.unwrap_or_else(Instant::now);
    let settings = &problem.settings;
    let method = settings.method;
    let deterministic = settings.deterministic();
    let mut warnings = Vec::new();
    if let Some(state) = problem.resume {
        if deterministic {
            return Err(Error::DeterministicResume(method));
        }
        state.settings().agree(settings)?;
    }
    let budget = problem.budget;
    // the default adaptive budget's growth, before the scene is taken; the memory check
    // estimates the run with it
    let grown = problem.grown_patches();
    let patch_growth = match settings.mesh {
        MeshPlan::Adaptive {
            max_patches: None, ..
        } => Some((PATCH_RAYS, grown)),
        _ => None,
    };
    if let Some(limit) = budget.memory {
        let estimate = problem.estimate_within(grown);
        if estimate.bytes > limit {
            return Err(Error::Memory {
                estimate: estimate.bytes,
                elements: estimate.elements,
                per_element: estimate.per_element(),
                scene_bytes: estimate.scene_bytes,
                limit,
            });
        }
    }
    // A scene handed over (`Input::SceneOnce`) is dropped once meshed.
    let mut owned: Option<Scene> = match problem.input {
        Input::SceneOnce(held) => Some(
            held.lock()
                .ok()
                .and_then(|mut s| s.take())
                .ok_or(Error::SceneTaken)?,
        ),
        _ => None,
    };
    let scene: Option<&Scene> = match problem.input {
        Input::Scene(scene) => Some(scene),
        Input::SceneOnce(_) => owned.as_ref(),
        Input::Mesh(_) => None,
    };
    let mut config = schedule_config(settings, &budget);
    if let Some(scene) = scene {
        config.lights = scene.lights().to_vec();
        config.sky = scene.sky().cloned();
    }
    let lighting = crate::state::lighting_fingerprint(&config.lights, config.sky.as_ref());
    let diagonal = scene.map_or(0.0, |s| s.bounds().diagonal());
    // a group of small faces is split no finer than a large face is: twice the smallest edge
    let min_span = scene.map_or(0.0, |s| 2.0 * f64::from(plan_bounds(s, settings).min_edge));

    // The mesh: replayed from a saved run, refined anew, or fixed.
    let history = problem.resume.and_then(RunState::history);
    let mut phases = SetupPhases::default();
    let meshing = Instant::now();
    let mut refined_at: Option<Instant> = None;
    let (mesh, mut refinement, history) = match (problem.input, scene, settings.mesh, history) {
        (Input::Mesh(mesh), ..) => (mesh.clone(), None, None),
        (_, None, ..) => return Err(Error::SceneTaken),
        (_, Some(scene), MeshPlan::Adaptive { .. }, Some(history)) => {
            let mesh = AdaptiveMesh::replay(scene, &history, adaptive_bounds(scene, settings))
                .map_err(Error::StateReplay)?;
            (mesh.into_mesh(), None, Some(history))
        }
        (_, Some(_), MeshPlan::Adaptive { .. }, None) if problem.resume.is_some() => {
            // a state saved from a caller's mesh: its mesh is not the scene's to refine
            let saved = problem.resume.map_or(0, |s| s.patch_numbers().len());
            return Err(Error::StateMesh { saved, now: 0 });
        }
        (_, Some(scene), MeshPlan::Adaptive { .. }, None) if !deterministic => {
            let start = adaptive_start(scene, settings, config.rays)?;
            // a scene handed over goes before the start's mesh is built (what the mesh needs
            // of it, the leaves hold)
            drop(owned.take());
            let start = start.build();
            refined_at = Some(Instant::now());
            let refine_seconds = budget
                .seconds
                .map(|t| refine_share(t, clock.elapsed().as_secs_f64()));
            // with clusters as elements of transport, the pilot runs on them too
            let pilot =
                (problem.clustering == Clustering::Transport).then(|| cluster_bounds(diagonal));
            let (mesh, refined, history) = adaptive_refine(
                start,
                settings,
                (refine_seconds, pilot, patch_growth),
                &config,
                &mut warnings,
            )?;
            if config.rays != u64::MAX {
                // The method gets what the refinement left, and at least half the budget.
                config.rays = config
                    .rays
                    .saturating_sub(refined.rays)
                    .max(config.rays / 2)
                    .max(1);
            }
            (mesh, Some(refined), Some(history))
        }
        (_, Some(scene), plan, _) => {
            let subdivision = match plan {
                MeshPlan::PerFace => Subdivision::None,
                MeshPlan::Uniform { max_edge: Some(l) } => Subdivision::MaxEdge(l),
                _ => Subdivision::default_for(scene),
            };
            // the reference solver refuses a large mesh: stop building it there
            let max_patches = if deterministic {
                config.reference.max_patches
            } else {
                usize::MAX
            };
            let mesh = Mesh::build_at_most(scene, subdivision, max_patches).map_err(|source| {
                Error::Mesh {
                    source,
                    max_edge: match subdivision {
                        Subdivision::None => None,
                        Subdivision::MaxEdge(l) => Some(l),
                    },
                }
            })?;
            (mesh, None, None)
        }
    };
    match refined_at {
        Some(at) => {
            phases.mesh_seconds = (at - meshing).as_secs_f64();
            phases.refine_seconds = at.elapsed().as_secs_f64();
        }
        None => phases.mesh_seconds = meshing.elapsed().as_secs_f64(),
    }
    drop(owned.take());
    warnings.extend(sliver_warning(&mesh));
    // the refinement's caster when it is over the final mesh (the same a build gives), else
    // a new one
    let reused = refinement
        .as_mut()
        .and_then(|r| r.caster.take())
        .and_then(|c| Arc::try_unwrap(c).ok());
    let casting = Instant::now();
    let bvh = match reused {
        Some(bvh) => bvh,
        None => mesh.caster()?,
    };
    phases.caster_seconds = casting.elapsed().as_secs_f64();
    let back = mesh.back_face_offset();
    let patch: Vec<u32> = mesh
        .patches()
        .iter()
        .enumerate()
        .map(|(i, p)| {
            if settings.mesh == MeshPlan::PerFace {
                // a back side: its face number plus the offset (see `Mesh::back_face_offset`)
                p.face + if p.back { back } else { 0 }
            } else {
                i as u32
            }
        })
        .collect();
    if let Some(state) = problem.resume {
        state.check_continues(&mesh, lighting)?;
    }
    // Small neighbouring faces share one estimate of irradiance (the adaptive plan only: a
    // fixed mesh is solved as given).
    let clustering = Instant::now();
    let clusters = match (problem.input, settings.mesh) {
        (Input::Scene(_) | Input::SceneOnce(_), MeshPlan::Adaptive { .. }) if !deterministic => {
            Clusters::build(&mesh, cluster_bounds(diagonal))
        }
        _ => Clusters::default(),
    };
    // Groups of them that are evenly lit are one element each of the transport: the method
    // runs on that coarser mesh, its answers come back per patch, and the answer's pooling
    // leaves those groups alone.
    let transport = match (refinement.as_ref(), problem.clustering) {
        (Some(r), Clustering::Transport) if !clusters.is_empty() && problem.resume.is_none() => {
            let seed = derive_seed(settings.seed, SHADOW_SPLIT_STREAM);
            let sky = config.sky.as_ref();
            let split = ShadowSplit {
                rays: SHADOW_SPLIT_RAYS,
                tolerance: AdaptiveConfig::default().tolerance,
                seed,
                min_span,
            };
            transport_groups(&mesh, &bvh, &clusters, r, (&config.lights, sky), split)?
        }
        _ => None,
    };
    let formed = (clusters.len(), clusters.patches());
    // the answer's pooling: over the clusters less the transport's members
    let clusters = match &transport {
        Some((c, ..)) => {
            let elements = c.mesh.patches();
            clusters.without(|i| elements[c.element[i as usize] as usize].is_cluster())
        }
        None => clusters,
    };
    let (transport, transport_members, transport_counts) = match transport {
        Some((c, members, counts)) => (Some(c), members, counts),
        None => (None, Clusters::default(), PoolCounts::default()),
    };
    // the refinement's estimate has placed the elements and tested the clusters; the answer
    // does not pool it (see `Run::answer`), so it is not kept (48 bytes a patch)
    if let Some(r) = refinement.as_mut() {
        r.pooled = Estimate::default();
    }
    phases.clusters_seconds = clustering.elapsed().as_secs_f64();
    // The caller's work after the solve, timed now that the mesh and caster exist.
    let timing = Instant::now();
    let after_seconds = match (problem.after, budget.seconds) {
        (Some(after), Some(_)) if !deterministic => (after.0)(&mesh, &bvh).max(0.0),
        _ => 0.0,
    };
    phases.after_seconds = timing.elapsed().as_secs_f64();
    let setup_seconds = clock.elapsed().as_secs_f64();
    // Under a time budget the lights' direct-light pass takes a quarter of the time left at
    // most (64 points a patch of a large mesh could take it all).
    if let Some(seconds) = budget.seconds.filter(|_| !deterministic) {
        config.lights_seconds = Some(((seconds - setup_seconds - after_seconds) / 4.0).max(0.0));
    }

    // A continuation is an independent run with its own streams (piece number > 0).
    let piece = problem.resume.map_or(0, RunState::pieces);
    config.seed = piece_seed(settings.seed, piece);
    let rays = config.rays;
    let run = Run {
        mesh: &mesh,
        history: history.as_ref(),
        settings,
        patch: &patch,
        resumed: problem.resume,
        lighting,
        clusters: &clusters,
        min_span,
        transport: (&transport_members, transport_counts),
        pooled: std::sync::Mutex::new((PoolCounts::default(), Groups::new())),
    };
    // The reference solver runs to its accuracy target: no budget, no deadline.
    let deadline = if deterministic { None } else { budget.seconds };
    let after = if problem.closure {
        // the probe's rays and their shadow rays (one per light and the sky)
        let per_probe_ray = (1 + config.lights.len() + usize::from(config.sky.is_some())) as f64;
        After {
            seconds: after_seconds,
            probe_per_ray: per_probe_ray / crate::closure::PROBE_SHARE as f64,
            probe_floor: per_probe_ray
                * crate::closure::probe_budget(0, mesh.patches().len()) as f64,
        }
    } else {
        After {
            seconds: after_seconds,
            ..After::default()
        }
    };
    let start = Instant::now();
    let mut complete_steps = false;
    let mut last_step: Option<Solution> = None;
    let mut target_reached = false;
    let mut failure: Option<Error> = None;
    let never = AtomicBool::new(false);
    let cancel = problem.cancel.unwrap_or(&never);
    // the corner groups the target's mesh error needs, once
    let groups = budget
        .target_error
        .map(|_| mesh.corner_groups(mcrad_meshing::DEFAULT_CREASE_ANGLE_DEGREES));
    let mut observe = |step: &Step| {
        let seconds = start.elapsed().as_secs_f64();
        complete_steps = step.variance.is_some();
        // the last step's copy goes before this one's is made (one copy at a time)
        last_step = None;
        // the step on the method's elements; per patch only where read (a step of a
        // transport's elements carried to a fine mesh's patches is 48 bytes a patch)
        let estimate = match step_estimate(step) {
            Ok(e) => StepEstimate::new(e, transport.as_ref(), &mesh),
            Err(e) => {
                failure = Some(e);
                return ControlFlow::Break(());
            }
        };
        let progress = Progress {
            step: step.index,
            rays: step.rays,
            budget_rays: if deterministic { u64::MAX } else { rays },
            seconds,
            complete: complete_steps,
            run: &run,
            step_estimate: &estimate,
        };
        let flow = observer(&progress);
        let target = match (budget.target_error, step.variance.is_some()) {
            (Some(target), true) => match estimate.get().and_then(|e| run.answer(Cow::Borrowed(e)))
            {
                Ok(answer) => error_p95(&mesh, &answer, groups.as_ref()) <= target,
                Err(e) => {
                    failure = Some(e);
                    return ControlFlow::Break(());
                }
            },
            _ => false,
        };
        last_step = Some(Solution {
            estimate: estimate.own,
            steps: step.index,
            escaped_rays: 0,
            unshot_fraction: f64::NAN,
            stop: StopReason::Stopped,
            direct: None,
            sky_direct: None,
            face_correlation: None,
        });
        if flow.is_break() {
            return ControlFlow::Break(());
        }
        if target {
            target_reached = true;
            return ControlFlow::Break(());
        }
        if let Some(seconds_budget) = deadline {
            // The time left is measured from the budget's clock. At the speed of the run so
            // far, size the rest to what fits: time up is a budget spent, not an
            // interruption (a shooting extrapolates what it could not shoot).
            let left = seconds_budget - clock.elapsed().as_secs_f64();
            let fits = rays_that_fit(left, seconds, step.rays, after);
            if step.next_rays > fits {
                step.limit_rays_left(fits);
            }
        }
        ControlFlow::Continue(())
    };
    let result = match &transport {
        Some(c) => {
            // the transport's elements are groups of the fine mesh's patches: its caster,
            // renumbered, is theirs (one hierarchy for both)
            let caster = Renumbered::new(&bvh, &c.element);
            run_cancellable(method, &c.mesh, &caster, &config, cancel, &mut observe)
        }
        None => run_cancellable(method, &mesh, &bvh, &config, cancel, &mut observe),
    };
    if let Some(e) = failure {
        return Err(e);
    }
    // A cancelled step: the answer is the last complete one.
    let cancelled = matches!(result, Err(MethodError::Cancelled));
    let solution = match result {
        Err(MethodError::Cancelled) => last_step.take().ok_or(Error::CancelledEarly)?,
        Ok(solution) => {
            // the last step's copy, kept for a cancelled step, goes first
            drop(last_step.take());
            solution
        }
        Err(e) => return Err(e.into()),
    };
    // on the method's elements, carried to the patches
    let transport_elements = transport.as_ref().map(|c| c.mesh.patches().len());
    let (mut solution, of_patch) = match transport {
        Some(c) => {
            let (solution, of_patch) = carried_solution(c, &mesh, solution)?;
            (solution, Some(of_patch))
        }
        None => (solution, None),
    };
    let seconds = start.elapsed().as_secs_f64();
    let piece_rays = solution.estimate.rays();
    // the method's share of the budget below its direct light and a ray an element: the
    // method was given a ray an element beyond it
    let elements = transport_elements.unwrap_or(mesh.patches().len());
    let fewest = config.fewest_light_rays(elements);
    if !deterministic
        && fewest > 0
        && rays != u64::MAX
        && fewest.saturating_add(elements as u64) > rays
    {
        warnings.push(format!(
            "the method's share of the ray budget, {rays} rays, could not pay for the direct \
             light of the lights and the sky on {elements} elements ({fewest} rays at 4 points \
             an element) and a ray an element after it: it cast {piece_rays} rays, and its \
             answer is noisier than its budget says; give a larger --rays, or --time"
        ));
    }
    let (direct, sky_direct) = (solution.direct.take(), solution.sky_direct.take());
    // a continued run's pieces (the same method on the same mesh) share the factors
    let face_correlation = solution.face_correlation.take();
    // the solution's estimate goes into the answer (pooled in place)
    let solved = std::mem::take(&mut solution.estimate);
    let (estimate, state) = run.settle(
        Cow::Owned(solved),
        solution.steps,
        solution.escaped_rays,
        problem.keep_state,
    )?;
    // over all pieces (a new run's own without a state)
    let (steps, escaped_rays) = state
        .as_ref()
        .map_or((solution.steps, solution.escaped_rays), |s| {
            (s.steps(), s.escaped_rays())
        });
    // a run stopped in a step that is not an answer lacks part of its light
    let state_complete = solution.stop != StopReason::Stopped || complete_steps;
    let solved_rays = match problem.resume {
        Some(_) => estimate.rays(),
        None => piece_rays,
    };
    let refinement_rays = refinement.as_ref().map_or(0, |r| r.rays);
    // The closure: its probe has its own streams (from this piece's seed), after the run.
    // Not after a cancel (the caller wants out), and sized by this piece's rays.
    let wanted = problem.closure && !cancelled && !cancel.load(std::sync::atomic::Ordering::SeqCst);
    let closure = wanted.then(|| {
        let probe_rays = crate::closure::allocate(
            &mesh,
            estimate.radiosity(),
            crate::closure::probe_budget(piece_rays, mesh.patches().len()),
        );
        let light = crate::closure::light_delivery(
            &mesh,
            &bvh,
            &config.lights,
            config.sky.as_ref(),
            &probe_rays,
            config.seed,
        );
        let probe = crate::closure::probe(&mesh, &bvh, probe_rays, config.seed);
        let pooled = run.pooled.lock().map(|p| p.1.clone()).unwrap_or_default();
        crate::closure::closure(&mesh, &estimate, &probe, &light, &pooled)
    });
    if let Some(c) = &closure {
        warnings.extend(c.warning());
    }
    let stats = RunStats {
        method,
        patches: mesh.patches().len(),
        rays: solved_rays + refinement_rays,
        seconds,
        rays_per_second: piece_rays as f64 / seconds.max(1e-9),
        iterations: steps,
        seed: settings.seed,
        threads: rayon::current_num_threads(),
        // Not counted by the steps: unknown when a step was abandoned.
        escaped_rays: (!cancelled).then_some(escaped_rays),
        unshot_fraction: (!cancelled).then_some(solution.unshot_fraction),
        stop: solution.stop,
        setup_seconds,
        setup: phases,
        sampler: settings.sampler,
        refinement: refinement
            .as_ref()
            .map(|r| r.rounds.iter().map(RefinementRound::from).collect()),
        closure,
        clusters: (formed.0 > 0).then(|| {
            let pooled = run.pooled.lock().map(|c| c.0).unwrap_or_default();
            ClusterStats {
                clusters: formed.0,
                faces: formed.1,
                groups: pooled.groups,
                pooled_faces: pooled.faces,
                splits: pooled.splits,
                elements: mesh.patches().len() - pooled.faces + pooled.groups,
                transport_elements,
            }
        }),
    };
    let no_direct = config.lights.is_empty() && config.sky.as_ref().is_none_or(|s| s.is_dark());
    let per_patch = |values: Option<Vec<DVec3>>| {
        let values = values.filter(|_| !no_direct)?;
        match &of_patch {
            Some(map) => PerPatch::shared(values, Arc::clone(map)),
            None => Some(PerPatch::new(values)),
        }
    };
    Ok(Answer {
        mesh,
        bvh,
        estimate,
        patch,
        stats,
        state: state.filter(|_| !deterministic && state_complete),
        target_reached,
        cancelled,
        complete_steps,
        warnings,
        direct: per_patch(direct),
        sky_direct: per_patch(sky_direct),
        face_correlation: if cancelled { None } else { face_correlation },
    })
}

/// The coarser mesh on which the method runs with clusters as elements of transport (see
/// [`solve`]): the `clusters` of `mesh` tested against the refinement's estimate
/// ([`pool_clusters`]) and split where the shadow of a light or of the sky crosses them
/// ([`split_shadowed`] by `split`, shadow rays through `bvh`), its groups as [`Clusters`] and what forming
/// them did; `None` when no group is left.
fn transport_groups(
    mesh: &Mesh,
    bvh: &Bvh,
    clusters: &Clusters,
    refined: &Refined,
    (lights, sky): (&[mcrad_scene_io::Light], Option<&mcrad_scene_io::Sky>),
    split: ShadowSplit,
) -> Result<Option<(ClusteredMesh, Clusters, PoolCounts)>, Error> {
    let test = Some(split.min_span);
    let (_, tested, mut groups) =
        pool_clusters(mesh, clusters, Cow::Borrowed(&refined.pooled), test)?;
    let shadowed = split_shadowed(
        mesh,
        bvh,
        lights,
        sky,
        refined.pooled.radiosity(),
        &mut groups,
        split,
    );
    let coarse = mesh.clustered(&groups).map_err(|source| Error::Mesh {
        source,
        max_edge: None,
    })?;
    if coarse.mesh.patches().len() == mesh.patches().len() {
        return Ok(None);
    }
    let members = coarse.clusters();
    let counts = PoolCounts {
        groups: members.len(),
        faces: members.patches(),
        splits: tested.splits + shadowed,
    };
    Ok(Some((coarse, members, counts)))
}

/// `estimate`, per element of a coarser mesh, carried back to the patches of `fine`
/// ([`Carry::refine`]).
fn carried_from(transport: Carry<'_>, fine: &Mesh, estimate: &Estimate) -> Result<Estimate, Error> {
    Ok(Estimate::new(
        transport.refine(fine, estimate.radiosity(), true),
        estimate
            .variance()
            .map(|v| transport.refine_variance(fine, v)),
        estimate.rays(),
    )?)
}

/// `solution`, solved on the elements of `transport`, carried back to the patches of `fine`:
/// the estimate as [`carried_from`], the faces' correlation factors by face (1 for a
/// cluster's members, each a face of one patch); the direct irradiances stay per element,
/// shared by its members through the map returned (each fine patch's element).
fn carried_solution(
    transport: ClusteredMesh,
    fine: &Mesh,
    mut solution: Solution,
) -> Result<(Solution, Arc<Vec<u32>>), Error> {
    let coarse_offset = transport.mesh.back_face_offset();
    // the coarser mesh's geometry goes first: its corners and triangles are as many as the
    // fine mesh's (29 MB at the 1M atrium)
    let carrier = transport.into_carrier();
    let transport = carrier.carry();
    // The coarse factors are numbered by face, as many as the fine mesh's: each table is
    // dropped once read, before the next is made (at 10M faces, 240 MB each).
    let face_correlation = solution.face_correlation.take().map(|mut k| {
        let fine_offset = fine.back_face_offset();
        let key = |p: &mcrad_meshing::Patch, offset: u32| {
            (p.face + if p.back { offset } else { 0 }) as usize
        };
        let faces = fine
            .patches()
            .iter()
            .map(|p| key(p, fine_offset) + 1)
            .max()
            .unwrap_or(0);
        if fine_offset == coarse_offset {
            // The same numbering (an element that is no cluster is a fine patch, of the same
            // face and side): the table is made in place, its rows read by no such element
            // set to 1 (at 10M faces, 240 MB less at the run's end).
            let mut read = vec![false; faces];
            for (p, &e) in fine.patches().iter().zip(transport.element) {
                if !transport.elements[e as usize].is_cluster() {
                    read[key(p, fine_offset)] = true;
                }
            }
            k.resize(faces, DVec3::ONE);
            for (v, _) in k.iter_mut().zip(&read).filter(|(_, read)| !**read) {
                *v = DVec3::ONE;
            }
            return k;
        }
        let mut out = vec![DVec3::ONE; faces];
        for (p, &e) in fine.patches().iter().zip(transport.element) {
            let q = &transport.elements[e as usize];
            if let (false, Some(v)) = (q.is_cluster(), k.get(key(q, coarse_offset))) {
                out[key(p, fine_offset)] = *v;
            }
        }
        out
    });
    let estimate = carried_from(transport, fine, &solution.estimate)?;
    solution.estimate = Estimate::default();
    // the direct irradiances stay per element, shared by its members
    let of_patch = Arc::new(carrier.element);
    Ok((
        Solution {
            estimate,
            face_correlation,
            ..solution
        },
        of_patch,
    ))
}

/// The stream tag of the shadow rays that split the transport's groups
/// ([`split_shadowed`]), distinct from every method's.
const SHADOW_SPLIT_STREAM: u64 = 0x5eed_c1a5;

/// Shadow rays per test of a transport group ([`split_shadowed`]): a shadow over more than
/// about a 32nd of a group (along its longest extent) is seen.
const SHADOW_SPLIT_RAYS: u32 = 32;

/// This step's solution as an estimate.
fn step_estimate(step: &Step) -> Result<Estimate, Error> {
    Ok(Estimate::new(
        step.radiosity.to_vec(),
        step.variance.map(<[_]>::to_vec),
        step.rays,
    )?)
}

/// The schedules' settings for `settings` and `budget`.
fn schedule_config(settings: &Settings, budget: &Budget) -> ScheduleConfig {
    ScheduleConfig {
        rays: budget.total_rays(),
        seed: settings.seed,
        unshot_threshold: settings.unshot_threshold,
        ambient: settings.ambient,
        first_pass_rays: None,
        sampler: settings.sampler,
        control_variate: settings.control_variate,
        reference: ReferenceConfig {
            visibility_tolerance: settings.visibility_tolerance,
            ..Default::default()
        },
        lights: Vec::new(),
        sky: None,
        lights_seconds: None,
    }
}

/// The 95th percentile by area of the patches' relative error of incident irradiance `H`:
/// per patch the root sum of squares of the noise (its relative standard error,
/// [`relative_error`]) and the mesh's discretization ([`Mesh::discretization_error`] of
/// `H = (B - E) / rho`, its noise floor subtracted, relative to `H`; left out without
/// `groups`): what a target error holds a solve to. Infinite without variances.
fn error_p95(mesh: &Mesh, answer: &Estimate, groups: Option<&CornerGroups>) -> f64 {
    let Some(variance) = answer.variance() else {
        return f64::INFINITY;
    };
    let patches = mesh.patches();
    let per = |x: f64, r: f64| if r > 1e-6 { x / r } else { 0.0 };
    let (h, var_h): (Vec<DVec3>, Vec<DVec3>) = patches
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let rho = p.reflectance.as_dvec3();
            let r = (answer.radiosity()[i] - p.emission.as_dvec3()).max(DVec3::ZERO);
            let v = variance[i];
            (
                DVec3::new(per(r.x, rho.x), per(r.y, rho.y), per(r.z, rho.z)),
                DVec3::new(
                    per(v.x, rho.x * rho.x),
                    per(v.y, rho.y * rho.y),
                    per(v.z, rho.z * rho.z),
                ),
            )
        })
        .unzip();
    let discretization = groups.map(|g| mesh.discretization_error(&h, Some(&var_h), g));
    let errors: Vec<f64> = patches
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let noise = relative_error(answer.radiosity()[i], p.emission.as_dvec3(), variance[i]);
            let mesh_part = discretization
                .as_ref()
                .map_or(0.0, |e| relative_error(h[i], DVec3::ZERO, e[i] * e[i]));
            noise.hypot(mesh_part)
        })
        .collect();
    let areas: Vec<f64> = patches.iter().map(|p| p.area).collect();
    weighted_quantile(&errors, &areas, 0.95).unwrap_or(f64::INFINITY)
}

/// One warning for the slivers of `mesh` too thin for `f32` coordinates at the scene's size:
/// faces kept whole rather than cut ([`Mesh::kept_whole`]) and patches smaller than the
/// coordinates resolve ([`Mesh::unresolved_patches`]); `None` without any.
fn sliver_warning(mesh: &Mesh) -> Option<String> {
    let kept = mesh.kept_whole();
    let (small, _) = mesh.unresolved_patches();
    let size = mesh.resolved_size();
    let approximate = "their own radiosity is approximate";
    match (kept, small) {
        (0, 0) => None,
        (0, _) => Some(format!(
            "{small} patches are smaller than f32 coordinates resolve at the scene's size \
             ({size:.1e} scene units across): {approximate}"
        )),
        (_, 0) => Some(format!(
            "{kept} faces were kept whole: cut as asked, their pieces would be smaller than f32 \
             coordinates resolve at the scene's size ({size:.1e} scene units across; slivers)"
        )),
        _ => Some(format!(
            "{kept} faces were kept whole: cut as asked, their pieces would be smaller than f32 \
             coordinates resolve at the scene's size ({size:.1e} scene units across; slivers), \
             and {small} patches are that small whole: {approximate}"
        )),
    }
}

/// The adaptive plan's bounds on `scene`: its settings' ([`plan_bounds`]) for the scene's
/// face count ([`AdaptiveBounds::for_faces`]).
fn adaptive_bounds(scene: &Scene, settings: &Settings) -> AdaptiveBounds {
    plan_bounds(scene, settings).for_faces(scene.faces().len())
}

/// The adaptive plan's bounds on `scene` as its settings give them.
fn plan_bounds(scene: &Scene, settings: &Settings) -> AdaptiveBounds {
    let mut bounds = AdaptiveBounds::default_for(scene);
    if let MeshPlan::Adaptive {
        max_patches,
        min_edge,
    } = settings.mesh
    {
        if let Some(n) = max_patches {
            bounds.max_patches = n;
        }
        if let Some(l) = min_edge {
            bounds.min_edge = l;
        }
    }
    bounds
}

/// The adaptive mesh's start: the scene cut to the diagonal / 40 when the cut adds at most
/// 1 / [`START_SHARE`] of the patch budget to one element per face (small faces stay whole:
/// only faces larger than the cut are split), else to the uniform default when that adds at
/// most the budget, else one element per face (every start within the elements the ray budget
/// pays [`START_RAYS_PER_ELEMENT`] for), within the budget raised to one element per face plus
/// half of it ([`AdaptiveBounds::for_faces`]): no count of input faces switches the refinement
/// off. Its leaves, the mesh built by [`AdaptiveStart::build`] (which needs the scene no more),
/// then refined by [`adaptive_refine`].
fn adaptive_start(scene: &Scene, settings: &Settings, rays: u64) -> Result<AdaptiveStart, Error> {
    let bounds = adaptive_bounds(scene, settings);
    let affordable = usize::try_from(rays / START_RAYS_PER_ELEMENT).unwrap_or(usize::MAX);
    let (faces, asked) = (
        scene.faces().len(),
        plan_bounds(scene, settings).max_patches,
    );
    let fits = |len: usize, share: usize| {
        len.saturating_sub(faces) <= asked / share && len <= bounds.max_patches.min(affordable)
    };
    let mesh_error = |start: Subdivision| {
        move |source| Error::Mesh {
            source,
            max_edge: match start {
                Subdivision::None => None,
                Subdivision::MaxEdge(l) => Some(l),
            },
        }
    };
    // Each start is counted before it is built: only the one taken is built.
    let diagonal = scene.bounds().diagonal() as f32;
    let coarse = Subdivision::MaxEdge(diagonal * DEFAULT_COARSE_EDGE_FRACTION);
    let uniform = Subdivision::default_for(scene);
    let count = |start| AdaptiveMesh::start_len(scene, start, bounds).map_err(mesh_error(start));
    let start = if fits(count(coarse)?, START_SHARE) {
        coarse
    } else if fits(count(uniform)?, 1) {
        uniform
    } else {
        Subdivision::None
    };
    AdaptiveMesh::leaves(scene, start, bounds).map_err(mesh_error(start))
}

/// The bounds of the clusters of small faces of a scene whose bounding box's diagonal is
/// `diagonal` (scene units).
fn cluster_bounds(diagonal: f64) -> ClusterBounds {
    ClusterBounds {
        max_size: diagonal as f32 * DEFAULT_COARSE_EDGE_FRACTION,
        cone_degrees: DEFAULT_CLUSTER_CONE_DEGREES,
    }
}

/// The adaptive mesh `mesh` ([`adaptive_start`]) refined with a quarter of the ray budget and
/// `seconds` of the time ([`refine_share`]; `config`: the run's schedule, with the scene's
/// lights and sky; `pilot`: [`AdaptiveConfig::pilot_clusters`]; `patch_growth`:
/// [`AdaptiveConfig::patch_growth`]), as a mesh, the refinement and
/// its history.
fn adaptive_refine(
    mut mesh: AdaptiveMesh,
    settings: &Settings,
    (seconds, pilot, patch_growth): (Option<f64>, Option<ClusterBounds>, Option<(u64, usize)>),
    config: &ScheduleConfig,
    warnings: &mut Vec<String>,
) -> Result<(Mesh, Refined, History), Error> {
    let rays = config.rays;
    let config = AdaptiveConfig {
        rays: if rays == u64::MAX {
            u64::MAX
        } else {
            (rays / 4).max(1)
        },
        seconds,
        seed: settings.seed,
        lights: config.lights.clone(),
        sky: config.sky.clone(),
        pilot_clusters: pilot,
        patch_growth,
        ..Default::default()
    };
    let mut refined = refine(&mut mesh, &config)?;
    // The clusters' test reads the refinement's `pooled` estimate only: its last estimate
    // would hold 48 bytes per element through the whole run.
    refined.estimate = Estimate::default();
    let unrefinable = refined.unrefinable();
    if unrefinable > 0 {
        warnings.push(format!(
            "{unrefinable} elements could not be split into valid elements (slivers, or faces \
             too small for f32 coordinates at the scene's size); kept as they are"
        ));
    }
    let history = mesh.history().clone();
    Ok((mesh.into_mesh(), refined, history))
}

/// The refinement's share of a time budget of `seconds` of which `elapsed` are spent
/// (loading and the start mesh, on the budget's clock): a quarter of the time left, none when
/// none is left. The method then takes the time left after the refinement.
fn refine_share(seconds: f64, elapsed: f64) -> f64 {
    ((seconds - elapsed) / 4.0).max(0.0)
}

/// The finer start (the diagonal / 40) is taken when it holds at most `1 / START_SHARE` of the
/// patch budget: the refinement's marks leave large starting elements as they are where the
/// light bends gently, so a finer start measured better at equal budgets (docs/meshing.md).
const START_SHARE: usize = 2;

/// The fewest rays of the budget per element of an adaptive run's starting mesh: a finer start
/// would leave the refinement's rounds and the method too few rays per element.
const START_RAYS_PER_ELEMENT: u64 = 16;

/// The share of the time left a time budget plans to fill: the rest absorbs the per-step
/// work that does not scale with rays and the writing of the outputs.
const TIME_FILL: f64 = 0.97;

/// What runs after the method on the same clock: the caller's work ([`Problem::after`]), and
/// the closure probe's rays, a share of the method's.
#[derive(Debug, Clone, Copy, Default)]
struct After {
    /// The caller's work, seconds.
    seconds: f64,
    /// The closure probe's rays per ray of the method: its rays
    /// ([`crate::closure::PROBE_SHARE`]) and their shadow rays (one per light and the sky); 0
    /// without a closure.
    probe_per_ray: f64,
    /// The fewest rays the closure probe casts whatever the method's (its rays' floor per
    /// patch, [`crate::closure::probe_budget`], and their shadow rays): at 10^7 patches, more
    /// than a minute's method casts. 0 without a closure.
    probe_floor: f64,
}

/// The rays that fit in `left` seconds at the speed of a run that cast `rays` rays in
/// `seconds` seconds, with [`TIME_FILL`]'s margin, once what runs after the method has its
/// time: `n` more rays cost `n + max(p (rays + n), f)` rays' time, `p` the probe's rays per
/// method ray and `f` its floor, after `after.seconds` (0 when no time is left).
fn rays_that_fit(left: f64, seconds: f64, rays: u64, after: After) -> u64 {
    if left <= 0.0 {
        return 0;
    }
    if rays == 0 {
        return u64::MAX;
    }
    let per_ray = seconds / rays as f64;
    if per_ray <= 0.0 {
        return u64::MAX;
    }
    let p = after.probe_per_ray;
    let time = TIME_FILL * (left - after.seconds) / per_ray;
    // n + p (rays + n) <= time and n + f <= time
    let n = ((time - p * rays as f64) / (1.0 + p)).min(time - after.probe_floor);
    if n <= 0.0 {
        return 0;
    }
    n.min(u64::MAX as f64) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_refinement_takes_a_quarter_of_the_time_left_after_the_setup() {
        // 20 s of a 60 s budget spent loading and meshing: 10 s for the refinement
        assert_eq!(refine_share(60.0, 20.0), 10.0);
        assert_eq!(refine_share(60.0, 0.0), 15.0);
        // a setup that took the whole budget leaves the refinement nothing
        assert_eq!(refine_share(20.0, 27.0), 0.0);
        assert_eq!(refine_share(20.0, 20.0), 0.0);
    }

    #[test]
    fn the_method_fits_its_rays_in_the_time_left_after_the_renders() {
        // 1e6 rays took 1 s: 10 s left, 2 s of them the render's, fill 97% of 8 s
        let after = After {
            seconds: 2.0,
            ..After::default()
        };
        let fits = rays_that_fit(10.0, 1.0, 1_000_000, after);
        assert!(fits.abs_diff((TIME_FILL * 8.0 * 1e6) as u64) <= 1, "{fits}");
        // the render alone takes the time left: no more rays
        assert_eq!(rays_that_fit(1.5, 1.0, 1_000_000, after), 0);
        assert_eq!(rays_that_fit(0.0, 1.0, 1_000_000, After::default()), 0);
    }

    #[test]
    fn the_closure_probe_takes_its_share_of_the_rays_or_its_floor() {
        // 1e6 rays took 1 s, 10 s left; the probe casts 1 ray per 8 of the method's
        let share = After {
            seconds: 0.0,
            probe_per_ray: 0.125,
            probe_floor: 0.0,
        };
        let time = TIME_FILL * 10.0 * 1e6;
        let fits = rays_that_fit(10.0, 1.0, 1_000_000, share) as f64;
        // n + (1e6 + n) / 8 fills the time
        assert!((fits + (1e6 + fits) / 8.0 - time).abs() <= 2.0, "{fits}");
        // a floor above the share: the method gets the time less the floor
        let floor = After {
            probe_floor: 4e6,
            ..share
        };
        let fits = rays_that_fit(10.0, 1.0, 1_000_000, floor) as f64;
        assert!((fits - (time - 4e6)).abs() <= 1.0, "{fits}");
        // a floor below the share changes nothing
        let low = After {
            probe_floor: 1e5,
            ..share
        };
        assert_eq!(
            rays_that_fit(10.0, 1.0, 1_000_000, low),
            rays_that_fit(10.0, 1.0, 1_000_000, share)
        );
        // a floor that takes the whole time leaves the method nothing
        let all = After {
            probe_floor: 2e7,
            ..share
        };
        assert_eq!(rays_that_fit(10.0, 1.0, 1_000_000, all), 0);
    }
}
