//! Measuring one method on one scene with one seed: a curve of (seconds, rays, rms_rel) points.
//!
//! Two ways, by the method's [`Kind`] in the registry:
//! - **progressive** ([`Kind::Progressive`]: `prr`, `progressive-two-pass`, `combined`,
//!   `bidirectional`): every step is a complete solution of all the rays so far, so one
//!   unbounded run (passes doubling from `first` rays) gives the curve: one point per step, time
//!   from the start of the run.
//! - **ladder** ([`Kind::Budgeted`]): a step of `shoot` is a wave (not a converged solution
//!   until the last), `gather` iterates from `B = E`, and the two-pass methods and
//!   `progressive-gather` size their parts from the budget. So each point is a separate run
//!   with budget `first × 2^k`, and its final (time, error).
//!
//! The deterministic reference ([`Kind::Deterministic`]) is what the curves are measured
//! against, not a curve ([`Method::monte_carlo`]).
//!
//! Either way the curve stops at the first point below the target error, or before a point
//! predicted to end after the time limit (a ladder rung takes about twice the previous one).

use mcrad_lab::trace::Reference;
use mcrad_mc_radiosity::{
    ControlVariate, DEFAULT_UNSHOT_THRESHOLD, Kind, Method, Sampler, ScheduleConfig, run,
};
use mcrad_meshing::Mesh;
use mcrad_raycast::Bvh;
use std::ops::ControlFlow;
use std::time::{Duration, Instant};

/// Shooting stops below this fraction of the emitted power unshot: the library's and the CLI's
/// default. The paper's 1e-2 would leave a bias of the order of 1% rms_rel, which would floor
/// every shooting-based curve.
pub const UNSHOT_THRESHOLD: f64 = DEFAULT_UNSHOT_THRESHOLD;

/// One measured solution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    /// Wall-clock seconds from the start of the run (excluding the error measurement).
    pub seconds: f64,
    /// Rays cast.
    pub rays: u64,
    /// Error against the reference.
    pub rms_rel: f64,
}

/// When a curve stops.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// No point is started that is predicted to end after this many seconds.
    pub seconds: f64,
    /// The curve stops at the first point with `rms_rel` below this.
    pub target: f64,
    /// Ladder rungs at most (a guard for methods that do not slow down with more rays).
    pub max_points: u32,
}

/// What a curve needs: the scene and its reference.
pub struct Problem<'a> {
    /// The mesh.
    pub mesh: &'a Mesh,
    /// Its BVH.
    pub bvh: &'a Bvh,
    /// The reference solution the error is measured against.
    pub reference: Reference,
    /// How the runs draw their rays.
    pub sampler: Sampler,
    /// The control variate of patch gathering.
    pub control_variate: ControlVariate,
}

impl<'a> Problem<'a> {
    /// The problem of `mesh` against `reference`.
    pub fn new(mesh: &'a Mesh, bvh: &'a Bvh, reference: Reference) -> Self {
        Problem {
            mesh,
            bvh,
            reference,
            sampler: Sampler::default(),
            control_variate: ControlVariate::default(),
        }
    }

    fn error(&self, b: &[glam::DVec3]) -> f64 {
        self.reference.rms_rel(b)
    }

    /// Rays of the first point: 1e5, or 50 per patch on large meshes.
    pub fn first_rays(&self) -> u64 {
        (50 * self.mesh.patches().len() as u64).max(100_000)
    }
}

/// True for the methods measured by one unbounded run (the registry's [`Kind::Progressive`]).
pub fn progressive(method: Method) -> bool {
    method.kind() == Kind::Progressive
}

fn config(rays: u64, seed: u64, first: Option<u64>, problem: &Problem) -> ScheduleConfig {
    ScheduleConfig {
        sampler: problem.sampler,
        control_variate: problem.control_variate,
        rays,
        seed,
        unshot_threshold: UNSHOT_THRESHOLD,
        ambient: false,
        first_pass_rays: first,
        ..Default::default()
    }
}

/// The curve of `method` with `seed`; failed runs are reported in the `String`s (a ladder
/// goes on to its next rung).
pub fn curve(
    problem: &Problem,
    method: Method,
    seed: u64,
    limits: &Limits,
) -> (Vec<Point>, Vec<String>) {
    if progressive(method) {
        progressive_curve(problem, method, seed, limits)
    } else {
        ladder_curve(problem, method, seed, limits)
    }
}

fn progressive_curve(
    problem: &Problem,
    method: Method,
    seed: u64,
    limits: &Limits,
) -> (Vec<Point>, Vec<String>) {
    let mut points = Vec::new();
    let mut measuring = Duration::ZERO;
    let start = Instant::now();
    let config = config(u64::MAX, seed, Some(problem.first_rays()), problem);
    let result = run(method, problem.mesh, problem.bvh, &config, &mut |step| {
        let seconds = (start.elapsed() - measuring).as_secs_f64();
        let t = Instant::now();
        let rms_rel = problem.error(step.radiosity);
        measuring += t.elapsed();
        points.push(Point {
            seconds,
            rays: step.rays,
            rms_rel,
        });
        let next = seconds * (step.rays + step.next_rays) as f64 / step.rays.max(1) as f64;
        if rms_rel < limits.target || next > limits.seconds || step.next_rays == 0 {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    let errors = match result {
        Ok(_) => vec![],
        Err(e) => vec![format!("{}: {e}", method.name())],
    };
    (points, errors)
}

fn ladder_curve(
    problem: &Problem,
    method: Method,
    seed: u64,
    limits: &Limits,
) -> (Vec<Point>, Vec<String>) {
    let (mut points, mut errors) = (Vec::new(), Vec::new());
    let mut budget = problem.first_rays();
    for _ in 0..limits.max_points {
        let start = Instant::now();
        let result = run(
            method,
            problem.mesh,
            problem.bvh,
            &config(budget, seed, None, problem),
            &mut |_| ControlFlow::Continue(()),
        );
        let seconds = start.elapsed().as_secs_f64();
        match result {
            Ok(solution) => {
                let rms_rel = problem.error(solution.estimate.radiosity());
                points.push(Point {
                    seconds,
                    rays: solution.estimate.rays(),
                    rms_rel,
                });
                if rms_rel < limits.target {
                    break;
                }
            }
            Err(e) => errors.push(format!("{} with {budget} rays: {e}", method.name())),
        }
        if 2.0 * seconds > limits.seconds {
            break;
        }
        budget = budget.saturating_mul(2);
    }
    (points, errors)
}
