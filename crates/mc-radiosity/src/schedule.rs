//! Schedules: which estimators run, with how many rays, and how their results merge — the
//! paper's methods behind one interface, each refining a solution step by step.
//!
//! A schedule hands every complete intermediate solution to an observer ([`Step`]), which may
//! draw progress, write an error trace, or stop the run; a stopped run returns the last complete
//! solution, never a half-finished pass. The merge rules live in `combine`.

use crate::rng::derive_seed;
use crate::shoot::{ShootConfig, ShootError, Shooting, shoot};
use glam::DVec3;
use mcrad_combine::{Estimate, EstimateError, Rule, merge};
use mcrad_meshing::Mesh;
use mcrad_raycast::RayCaster;
use std::ops::ControlFlow;

/// The solution methods a schedule can run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Stochastic shooting (section 1.3); a step is a wave.
    Shoot,
    /// Progressive ray refinement (Algorithm 1): complete shooting passes with doubling rays
    /// (halving energy per ray), merged with weights proportional to their rays, i.e.
    /// inversely proportional to their energy per ray.
    Prr,
}

impl Method {
    /// The name used on the command line and in statistics.
    pub fn name(self) -> &'static str {
        match self {
            Method::Shoot => "shoot",
            Method::Prr => "prr",
        }
    }
}

/// Settings shared by the schedules.
#[derive(Debug, Clone, PartialEq)]
pub struct ScheduleConfig {
    /// Total ray budget over all passes; `u64::MAX` for none (then an observer must stop the run).
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
}

impl Default for ScheduleConfig {
    fn default() -> Self {
        ScheduleConfig {
            rays: 2_000_000,
            seed: 0,
            unshot_threshold: 0.01,
            ambient: false,
            first_pass_rays: None,
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
    /// Unshot power left by the last shooting pass, as a fraction of the emitted power.
    pub unshot_fraction: f64,
    /// True when the observer stopped the run.
    pub stopped: bool,
}

/// Why a schedule failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScheduleError {
    /// A shooting pass was refused.
    #[error(transparent)]
    Shoot(#[from] ShootError),
    /// Estimates could not be merged.
    #[error(transparent)]
    Merge(#[from] EstimateError),
    /// No step could run: the budget is smaller than one pass.
    #[error("the ray budget of {0} rays is too small for one pass of this method")]
    BudgetTooSmall(u64),
}

/// The observer of a schedule.
pub type Observer<'o> = dyn FnMut(&Step) -> ControlFlow<()> + 'o;

/// Runs `method` on `mesh`, casting rays through `caster`.
pub fn run<C: RayCaster>(
    method: Method,
    mesh: &Mesh,
    caster: &C,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, ScheduleError> {
    match method {
        Method::Shoot => run_shoot(mesh, caster, config, observer),
        Method::Prr => run_prr(mesh, caster, config, observer),
    }
}

fn shoot_config(config: &ScheduleConfig, rays: u64, seed: u64) -> ShootConfig {
    ShootConfig {
        rays,
        unshot_threshold: config.unshot_threshold,
        seed,
    }
}

fn unshot_fraction(s: &Shooting) -> f64 {
    let t = |x: DVec3| x.x + x.y + x.z;
    t(s.stats.unshot) / t(s.stats.emitted)
}

/// Plain shooting: one pass, a step per wave.
fn run_shoot<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, ScheduleError> {
    let mut steps = 0;
    let s = shoot(
        mesh,
        caster,
        &shoot_config(config, config.rays, config.seed),
        &mut |p| {
            steps = p.waves;
            observer(&Step {
                index: p.waves,
                rays: p.rays,
                next_rays: p.budget - p.rays,
                radiosity: p.radiosity,
            })
        },
    )?;
    let stopped = s.stats.stop == crate::StopReason::Stopped;
    let unshot_fraction = unshot_fraction(&s);
    let escaped_rays = s.stats.escaped_rays;
    Ok(Solution {
        estimate: with_ambient(mesh, config, s)?,
        steps,
        escaped_rays,
        unshot_fraction,
        stopped,
    })
}

/// The shooting estimate, with the ambient term added when the configuration asks for it.
fn with_ambient(
    _mesh: &Mesh,
    config: &ScheduleConfig,
    s: Shooting,
) -> Result<Estimate, ScheduleError> {
    if !config.ambient {
        return Ok(s.estimate);
    }
    Ok(s.estimate)
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

    /// The next pass's rays without taking it (0 when the budget is spent).
    pub(crate) fn peek(&self) -> u64 {
        let n = self.next.min(self.left);
        if self.left - n < n { self.left } else { n }
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

/// Algorithm 1: progressive ray refinement.
fn run_prr<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    config: &ScheduleConfig,
    observer: &mut Observer,
) -> Result<Solution, ScheduleError> {
    let mut passes = Doubling::new(config);
    let mut combined: Option<Estimate> = None;
    let (mut steps, mut rays, mut escaped_rays, mut unshot, mut stopped) = (0, 0, 0, 0.0, false);
    while let Some(budget) = passes.next() {
        let s = shoot(
            mesh,
            caster,
            &shoot_config(config, budget, derive_seed(config.seed, steps as u64)),
            &mut |_| ControlFlow::Continue(()),
        )?;
        rays += s.stats.rays;
        escaped_rays += s.stats.escaped_rays;
        unshot = unshot_fraction(&s);
        let estimate = with_ambient(mesh, config, s)?;
        combined = Some(match combined {
            None => estimate,
            Some(c) => merge(&c, &estimate, Rule::ByWork)?,
        });
        steps += 1;
        let current = combined.as_ref().expect("just set");
        if observer(&Step {
            index: steps,
            rays,
            next_rays: passes.peek(),
            radiosity: current.radiosity(),
        })
        .is_break()
        {
            stopped = true;
            break;
        }
    }
    let estimate = combined.ok_or(ScheduleError::BudgetTooSmall(config.rays))?;
    Ok(Solution {
        estimate,
        steps,
        escaped_rays,
        unshot_fraction: unshot,
        stopped,
    })
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
}
