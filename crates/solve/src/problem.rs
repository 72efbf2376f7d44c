//! What a solve is asked: the scene, the settings that define its answer, the budget.

use crate::{Error, RunState};
use mcrad_mc_radiosity::Kind;
use mcrad_mc_radiosity::{ControlVariate, DEFAULT_UNSHOT_THRESHOLD, Method, Sampler};
use mcrad_meshing::{DEFAULT_MAX_PATCHES, Mesh};
use mcrad_raycast::Bvh;
use mcrad_reference::DEFAULT_VISIBILITY_TOLERANCE;
use mcrad_scene_io::Scene;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

/// How the scene's faces become the patches solved for.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum MeshPlan {
    /// Start coarse and split where the measured light asks for it (the default): the start is
    /// the faces cut to the bounding-box diagonal / 40 (faces smaller than that stay whole)
    /// when the cut adds at most half of the patch budget's elements to one per face, else the
    /// uniform default when it adds at most the budget and fits the rays, else one element per
    /// face; refined with a quarter of the rays, within the budget or one element per face plus
    /// half of it, whichever is more.
    Adaptive {
        /// The most elements (patches), `>= 1`, or one per input face plus half of it when
        /// that is more (`AdaptiveBounds::for_faces`). `None`: [`DEFAULT_MAX_PATCHES`], raised
        /// as the refinement goes to one element per [`PATCH_RAYS`] rays of the run, at most
        /// [`MAX_GROWN_PATCHES`] (a large scene given many rays is refined further).
        max_patches: Option<usize>,
        /// The shortest edge a split may make (scene units, `> 0`); `None`: the diagonal / 640.
        min_edge: Option<f32>,
    },
    /// Every face cut until no patch edge is longer than `max_edge` (scene units, `> 0`);
    /// `None`: the bounding-box diagonal / 20.
    Uniform {
        /// The longest patch edge (scene units).
        max_edge: Option<f32>,
    },
    /// One patch per input face, in face order (patch `i` is input face `i`).
    PerFace,
}

impl Default for MeshPlan {
    /// Adaptive within the default patch budget (growing with the rays), the default minimum
    /// edge.
    fn default() -> Self {
        MeshPlan::Adaptive {
            max_patches: None,
            min_edge: None,
        }
    }
}

/// Rays of the run per element of the default adaptive patch budget
/// ([`MeshPlan::Adaptive`] without `max_patches`): on the generated 100k-triangle atrium, lit by
/// sun and sky, the budget's 122,066 patches held the default to 1.82% image error at
/// `--time 120` where 369k patches gave 1.23% (docs/atrium.md); the Cornell box at 1e8 rays
/// stops short of its budget either way.
pub const PATCH_RAYS: u64 = 1000;

/// The most elements the default patch budget grows to ([`PATCH_RAYS`]): 16 times
/// [`DEFAULT_MAX_PATCHES`] (the memory estimate of a time budget counts it).
pub const MAX_GROWN_PATCHES: usize = 16 * DEFAULT_MAX_PATCHES;

/// What defines a run's answer besides the scene and the budget: a saved run records it, and
/// its continuation runs with it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// The method (the paper's algorithms and their relatives); default `combined`.
    pub method: Method,
    /// How faces become patches.
    pub mesh: MeshPlan,
    /// Seed of every random stream (the answer is a function of it, whatever the threads).
    pub seed: u64,
    /// How rays are drawn: quasi-Monte Carlo (default) or independent.
    pub sampler: Sampler,
    /// Patch gathering's control variate.
    pub control_variate: ControlVariate,
    /// Add the ambient term (Balog, section 3.1) to shooting solutions.
    pub ambient: bool,
    /// Shooting stops at this fraction of the emitted power left unshot, in `[0, 1]`.
    pub unshot_threshold: f64,
    /// The reference solver's visibility target (relative standard deviation of a form-factor
    /// row's visibility; [`Method::Reference`] only).
    pub visibility_tolerance: f64,
}

impl Default for Settings {
    /// The command line's defaults: `combined`, an adaptive mesh, seed 0, QMC, the default
    /// control variate, no ambient term, [`DEFAULT_UNSHOT_THRESHOLD`] and
    /// [`DEFAULT_VISIBILITY_TOLERANCE`].
    fn default() -> Self {
        Settings {
            method: Method::default(),
            mesh: MeshPlan::default(),
            seed: 0,
            sampler: Sampler::default(),
            control_variate: ControlVariate::default(),
            ambient: false,
            unshot_threshold: DEFAULT_UNSHOT_THRESHOLD,
            visibility_tolerance: DEFAULT_VISIBILITY_TOLERANCE,
        }
    }
}

impl Settings {
    /// Each setting, named, as it reads in messages (`("method", "prr")`, `("mesh", "uniform,
    /// max edge 0.1")`, ...).
    pub fn described(&self) -> Vec<(&'static str, String)> {
        let mesh = match self.mesh {
            MeshPlan::Adaptive {
                max_patches,
                min_edge,
            } => format!(
                "adaptive, at most {} patches, minimum edge {}",
                max_patches.map_or_else(
                    || format!("{DEFAULT_MAX_PATCHES} (or one per {PATCH_RAYS} rays)"),
                    |n| n.to_string()
                ),
                min_edge.map_or_else(|| "the default".to_string(), |l| l.to_string())
            ),
            MeshPlan::Uniform { max_edge } => format!(
                "uniform, maximum edge {}",
                max_edge.map_or_else(|| "the default".to_string(), |l| l.to_string())
            ),
            MeshPlan::PerFace => "one patch per face".to_string(),
        };
        vec![
            ("method", self.method.name().to_string()),
            ("mesh", mesh),
            ("seed", self.seed.to_string()),
            ("sampler", self.sampler.name().to_string()),
            ("control variate", self.control_variate.name().to_string()),
            (
                "ambient term",
                if self.ambient { "on" } else { "off" }.into(),
            ),
            ("unshot threshold", self.unshot_threshold.to_string()),
            (
                "visibility tolerance",
                self.visibility_tolerance.to_string(),
            ),
        ]
    }

    /// Checks that `given` asks for the same run as these (saved) settings; the error names
    /// the first setting that differs with both values ([`Error::Disagree`]).
    pub fn agree(&self, given: &Settings) -> Result<(), Error> {
        for ((what, saved), (_, now)) in self.described().into_iter().zip(given.described()) {
            if saved != now {
                return Err(Error::Disagree {
                    what,
                    saved,
                    given: now,
                });
            }
        }
        Ok(())
    }

    /// Whether the method is deterministic (the reference solver: no seed, no budget, no state).
    pub fn deterministic(&self) -> bool {
        self.method.kind() == Kind::Deterministic
    }
}

/// When a run ends: the first of its limits reached.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Budget {
    /// Total rays over the refinement and the method; `None`: [`crate::DEFAULT_RAYS`], or no
    /// limit with `seconds`.
    pub rays: Option<u64>,
    /// Wall-clock seconds (`> 0`), counted from [`Budget::since`].
    pub seconds: Option<f64>,
    /// When the clock of `seconds` started (e.g. before loading the scene); `None`: when
    /// [`crate::solve`] starts.
    pub since: Option<Instant>,
    /// Stop once the 95th percentile by area of the patches' relative error of incident
    /// irradiance is at most this (a fraction, `> 0`); progressive methods only. The error
    /// counts the Monte Carlo noise (the relative standard error) and the mesh's
    /// discretization ([`mcrad_meshing::Mesh::discretization_error`]) as a root sum of
    /// squares, so a target below the mesh's own error runs to the rays or seconds.
    pub target_error: Option<f64>,
    /// The most memory the solve may take at its peak (bytes, the whole process's); `None`: no
    /// limit. A problem whose estimate ([`Problem::memory_estimate`]) exceeds it is refused
    /// before any work ([`Error::Memory`]).
    pub memory: Option<u64>,
}

impl Budget {
    /// The ray budget the run starts from: the rays asked, [`crate::DEFAULT_RAYS`] without a
    /// limit, or `u64::MAX` (none) under a time budget alone.
    pub fn total_rays(&self) -> u64 {
        self.rays.unwrap_or(if self.seconds.is_some() {
            u64::MAX
        } else {
            crate::DEFAULT_RAYS
        })
    }
}

/// What is solved: the scene or a mesh of it.
#[derive(Debug, Clone, Copy)]
pub enum Input<'a> {
    /// A scene, meshed by the settings' [`MeshPlan`].
    Scene(&'a Scene),
    /// A scene that [`crate::solve`] takes out of the mutex and drops once it is meshed, before
    /// the refinement and the run build their ray casters: its faces and positions (about 70
    /// bytes a triangle) are not held beside the mesh at the solve's peak. Otherwise as
    /// [`Input::Scene`], with the same answer. The caller finds `None` there after the solve
    /// (also after an error that came after the take); an empty mutex is
    /// [`crate::Error::SceneTaken`].
    SceneOnce(&'a std::sync::Mutex<Option<Scene>>),
    /// A mesh built by the caller (the plan is not used).
    Mesh(&'a Mesh),
}

/// A solve: the input, the settings that define its answer, the budget and how to run it.
#[derive(Debug, Clone, Copy)]
pub struct Problem<'a> {
    /// What is solved.
    pub input: Input<'a>,
    /// The settings; a continued run's must agree with the saved ones ([`Settings::agree`]).
    pub settings: Settings,
    /// When to stop.
    pub budget: Budget,
    /// Worker threads; `None`: rayon's current pool. The answer does not depend on it.
    pub threads: Option<usize>,
    /// A saved run to continue: this run is its next piece, and the answer the two merged.
    pub resume: Option<&'a RunState>,
    /// Set (from any thread) to abandon the step in progress; the answer is then the last
    /// complete step's.
    pub cancel: Option<&'a AtomicBool>,
    /// Report where the power went ([`crate::RunStats::closure`]), with probe rays of about a
    /// sixteenth of the method's beyond the budget.
    pub closure: bool,
    /// The caller's work after the solve on the clock of [`Budget::seconds`] (a render); `None`:
    /// none. Under a time budget the solve leaves it its time.
    pub after: Option<AfterSolve<'a>>,
    /// How clusters of small faces serve an adaptive solve.
    pub clustering: Clustering,
    /// Make a new run's state to continue it ([`Answer::state`](crate::Answer::state)):
    /// `false` leaves it out (about 60 bytes a patch, made at the end of the solve beside the
    /// answer) when nothing will be saved. A continued run's state is always made.
    pub keep_state: bool,
}

/// How the clusters of small faces ([`mcrad_meshing::Clusters`]) serve a new solve on the
/// adaptive plan (a fixed mesh and a continued run are solved per patch as given).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Clustering {
    /// Each group of faces that the refinement's estimate shows evenly lit (the pooling's
    /// test) is one element of the transport ([`mcrad_meshing::Mesh::clustered`]): its rays
    /// leave and arrive on its members' triangles, and each member gets `E_f + rho_f H` from
    /// the group's irradiance `H`. The answer is then pooled over the clusters as with
    /// [`Clustering::Pool`]. The default.
    #[default]
    Transport,
    /// The transport runs per patch, each with rays of its own; the answer's estimates are
    /// pooled over the clusters after (a group the light varies across is split).
    Pool,
}

/// The caller's work after a solve, on its clock ([`Problem::after`]): asked once, when the
/// mesh and its ray caster are built, for the wall-clock seconds it will take (`>= 0`; e.g. a
/// render timed on a small image). Under [`Budget::seconds`] the solve then stops early
/// enough to leave them, as it leaves the closure probe's rays their time.
#[derive(Clone, Copy)]
pub struct AfterSolve<'a>(pub &'a (dyn Fn(&Mesh, &Bvh) -> f64 + Sync));

impl std::fmt::Debug for AfterSolve<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("AfterSolve(..)")
    }
}

impl<'a> Problem<'a> {
    /// The default solve of `scene`: default settings and budget, all threads, a new run.
    pub fn new(scene: &'a Scene) -> Problem<'a> {
        Problem {
            input: Input::Scene(scene),
            settings: Settings::default(),
            budget: Budget::default(),
            threads: None,
            resume: None,
            cancel: None,
            closure: false,
            after: None,
            clustering: Clustering::default(),
            keep_state: true,
        }
    }
}
