//! The method registry: every solution method once, with its command-line name, its place in
//! the paper, a one-line summary, its [`Kind`] and the function that runs it.
//!
//! The one `methods!` invocation below generates the [`Method`] enum, [`Method::ALL`], the
//! name and metadata accessors, [`FromStr`](std::str::FromStr) and [`Display`](fmt::Display),
//! and the dispatch of [`run`](crate::run), every one an exhaustive match over the same list:
//! a method is added by writing its runner, a file `schedule/<name>.rs` with
//! `pub(crate) fn run<C: RayCaster>(ctx: &Context<C>, config: &ScheduleConfig, observer: &mut
//! Observer) -> Result<Solution, Error>` (the dispatch builds the [`Context`] once per run), and
//! one entry here; nothing else can be forgotten.
//!
//! [`StopReason`], why a run ended, lives here too: it is what the run statistics report next
//! to the method.

use crate::context::Context;
use crate::error::Error;
use crate::schedule::{Observer, ScheduleConfig, Solution};
use mcrad_meshing::Mesh;
use mcrad_raycast::RayCaster;
use std::fmt;

/// How a method's intermediate steps relate to its budget: what a caller measuring error
/// against time needs to know.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kind {
    /// Every step is a complete solution of all the rays cast so far, so one unbounded run
    /// (`rays: u64::MAX`), stopped by the observer, gives the whole error-against-time curve.
    Progressive,
    /// Intermediate steps are not complete solutions (shooting waves, Jacobi rounds from
    /// `B = E`), or the method sizes its parts from the budget: a solution for a budget is the
    /// end of a run with that budget.
    Budgeted,
    /// Deterministic: no ray budget and no seed; the run goes to its accuracy target
    /// ([`ScheduleConfig::reference`]) and takes one step.
    Deterministic,
}

/// Why a run ended. The names ([`StopReason::name`]) are what run statistics write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum StopReason {
    /// `converged`: the run reached its accuracy target before its budget (shooting: the
    /// unshot power fell to the threshold; gathering: a round changed the solution by less than
    /// its threshold; the reference solver: its residual target).
    Converged,
    /// `budget`: the ray budget was spent (every budgeted method that was not stopped ends so).
    BudgetSpent,
    /// `stopped`: the observer stopped the run (a time budget, Ctrl-C, an error target); the
    /// answer is the last complete solution.
    Stopped,
}

impl StopReason {
    /// Every reason.
    #[cfg(test)]
    pub(crate) const ALL: [StopReason; 3] = [
        StopReason::Converged,
        StopReason::BudgetSpent,
        StopReason::Stopped,
    ];

    /// The name written to run statistics: `converged`, `budget` or `stopped`.
    pub const fn name(self) -> &'static str {
        match self {
            StopReason::Converged => "converged",
            StopReason::BudgetSpent => "budget",
            StopReason::Stopped => "stopped",
        }
    }
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is not one of a [`Method`], a [`Sampler`](crate::Sampler) or a
/// [`ControlVariate`](crate::ControlVariate): the error of their
/// [`FromStr`](std::str::FromStr), naming the accepted names.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown {what} '{name}' (the {what}s: {known})")]
pub struct UnknownName {
    /// What was named: `method`, `sampler` or `control variate`.
    what: &'static str,
    /// The name given.
    name: String,
    /// The accepted names, comma separated.
    known: String,
}

/// The value of `T` named `s` among `all` (exactly as `name` gives it); `what` names `T` in the
/// error.
pub(crate) fn parse_name<T: Copy>(
    s: &str,
    all: &[T],
    name: fn(T) -> &'static str,
    what: &'static str,
) -> Result<T, UnknownName> {
    all.iter()
        .copied()
        .find(|&v| name(v) == s)
        .ok_or_else(|| UnknownName {
            what,
            name: s.to_string(),
            known: all.iter().map(|&v| name(v)).collect::<Vec<_>>().join(", "),
        })
}

/// Generates [`Method`] and everything read from the list (see the module documentation).
/// Each entry: the variant's documentation, the variant, then `name` (command line and
/// statistics, kebab-case), `paper` (where Balog's paper describes it, if it does), `summary`
/// (one line: the command line's help), `kind` (a [`Kind`] variant) and `runner` (a path to
/// the function that runs it).
macro_rules! methods {
    ($(
        $(#[doc = $doc:literal])*
        $variant:ident {
            name: $name:literal,
            paper: $paper:expr,
            summary: $summary:literal,
            kind: $kind:ident,
            runner: $runner:path $(,)?
        }
    )*) => {
        /// The solution methods, in the order experiments list them. One entry of the
        /// registry in `method.rs` each.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum Method {
            $($(#[doc = $doc])* $variant,)*
        }

        impl Method {
            /// Every method, in the order experiments list them.
            pub const ALL: [Method; [$($name),*].len()] = [$(Method::$variant),*];

            /// The name used on the command line and in statistics (kebab-case).
            pub const fn name(self) -> &'static str {
                match self {
                    $(Method::$variant => $name,)*
                }
            }

            /// Where Balog's paper describes the method (`section 1.3`, `Algorithm 1`), if it
            /// does.
            pub const fn paper(self) -> Option<&'static str> {
                match self {
                    $(Method::$variant => $paper,)*
                }
            }

            /// One line saying what the method does (the command line's help).
            pub const fn summary(self) -> &'static str {
                match self {
                    $(Method::$variant => $summary,)*
                }
            }

            /// How the method's steps relate to its budget.
            pub const fn kind(self) -> Kind {
                match self {
                    $(Method::$variant => Kind::$kind,)*
                }
            }

            /// Runs the method: the dispatch behind [`run`](crate::run).
            pub(crate) fn dispatch<C: RayCaster>(
                self,
                mesh: &Mesh,
                caster: &C,
                config: &ScheduleConfig,
                cancel: Option<&std::sync::atomic::AtomicBool>,
                observer: &mut Observer,
            ) -> Result<Solution, Error> {
                if !config.lights.is_empty() || config.sky.is_some() {
                    // Lights without a surface: their direct light becomes emission
                    // (`crate::lights`), then the method runs without them.
                    let lit = if matches!(self, Method::Reference) {
                        crate::lights::exact_light_mesh(mesh, caster, config)
                    } else {
                        crate::lights::light_mesh(mesh, caster, config, cancel)?
                    };
                    if let Some(dark) = lit.dark(observer) {
                        // nothing reached a surface (a closed room under the sky): B = 0
                        return dark;
                    }
                    let mut rest = config.clone();
                    rest.lights = Vec::new();
                    rest.sky = None;
                    if rest.rays != u64::MAX {
                        // A budget the direct light took (4 points a patch at least) still
                        // gives the method a ray a patch, beyond the budget: one ray carrying
                        // all the power made a 479 kW/m² wall of a 100k-face atrium at 1e6.
                        rest.rays = rest
                            .rays
                            .saturating_sub(lit.rays)
                            .max(mesh.patches().len() as u64);
                    }
                    let mut seen = |step: &crate::schedule::Step| lit.observe(step, observer);
                    let solution = self.dispatch(&lit.mesh, caster, &rest, cancel, &mut seen)?;
                    return lit.finish(solution);
                }
                let ctx = Context::new(mesh, caster)
                    .with_cancel(cancel)
                    .with_sampler(config.sampler)
                    .with_control_variate(config.control_variate);
                match self {
                    $(Method::$variant => $runner(&ctx, config, observer),)*
                }
            }
        }
    };
}

methods! {
    /// Stochastic shooting (section 1.3); a step is a wave.
    Shoot {
        name: "shoot",
        paper: Some("section 1.3"),
        summary: "Stochastic shooting with constant energy per ray",
        kind: Budgeted,
        runner: crate::schedule::shoot::run,
    }
    /// Jacobi gathering (section 1.4) from `B = E`; a step is a round.
    Gather {
        name: "gather",
        paper: Some("section 1.4"),
        summary: "Jacobi gathering: each patch gathers rho * mean(B_hit) over its rays",
        kind: Budgeted,
        runner: crate::schedule::gather::run,
    }
    /// Two-pass (section 1.5): shooting with half the budget, then one gathering round from it
    /// with the other half.
    TwoPass {
        name: "two-pass",
        paper: Some("section 1.5"),
        summary: "Shooting with half the budget, then one gathering round from it; see --split",
        kind: Budgeted,
        runner: crate::schedule::two_pass::run,
    }
    /// Two-pass with Shirley's direct/indirect split: the second half computes direct light by
    /// sampling the emitters with shadow rays and gathers only the indirect light.
    TwoPassSplit {
        name: "two-pass-split",
        paper: Some("section 1.5"),
        summary: "Two-pass with Shirley and Wang's split: direct light by sampling the \
                  emitters, only the indirect light gathered",
        kind: Budgeted,
        runner: crate::schedule::two_pass_split::run,
    }
    /// Progressive ray refinement (Algorithm 1): complete shooting passes with doubling rays
    /// (halving energy per ray), merged with weights proportional to their rays, i.e.
    /// inversely proportional to their energy per ray.
    Prr {
        name: "prr",
        paper: Some("Algorithm 1"),
        summary: "Progressive ray refinement: shooting passes with doubling rays, merged by \
                  their rays",
        kind: Progressive,
        runner: crate::schedule::prr::run,
    }
    /// Progressive gathering (Algorithm 2): one shooting solution (a quarter of the budget),
    /// then gathering rounds from it with doubling rays per patch, merged by rays per patch.
    ProgressiveGather {
        name: "progressive-gather",
        paper: Some("Algorithm 2"),
        summary: "Progressive gathering: one shooting solution, gathering rounds from it with \
                  doubling rays",
        kind: Budgeted,
        runner: crate::schedule::progressive_gather::run,
    }
    /// Progressive two-pass (Algorithm 3): shooting refined pass by pass as in PRR, each
    /// refinement regathered with doubling rays per patch; gathers merged by rays per patch.
    ProgressiveTwoPass {
        name: "progressive-two-pass",
        paper: Some("Algorithm 3"),
        summary: "Progressive two-pass: shooting refined as in prr, regathered every pass",
        kind: Progressive,
        runner: crate::schedule::progressive_two_pass::run,
    }
    /// Iterative combined shooting and gathering (Algorithm 4): each pass shoots (merged as in
    /// PRR), gathers from the current combination with the direct/indirect split (merged by
    /// rays), and combines the two per patch and channel by inverse variance, the shooting
    /// share of the next pass chosen to minimise the expected error (see `combined.rs`).
    Combined {
        name: "combined",
        paper: Some("Algorithm 4"),
        summary: "Iterative combined shooting and gathering, merged per patch by inverse \
                  variance",
        kind: Progressive,
        runner: crate::schedule::combined::run,
    }
    /// RenderPark's alternative to [`Method::Combined`]: every ray used for both shooting and
    /// gathering, weighted by the balance heuristic (bidirectional stochastic Jacobi steps from
    /// the solution so far, merged by rays; see `bidirectional.rs`).
    Bidirectional {
        name: "bidirectional",
        paper: None,
        summary: "RenderPark's alternative to combined: every ray used for shooting and \
                  gathering, weighted by the balance heuristic",
        kind: Progressive,
        runner: crate::schedule::bidirectional::run,
    }
    /// The deterministic reference solver (crate `mcrad-reference`): explicit form factors and
    /// Gauss-Seidel, up to [`ReferenceConfig::max_patches`](mcrad_reference::ReferenceConfig)
    /// patches, to the accuracy of [`ScheduleConfig::reference`]; the ray budget and the seed
    /// do not apply.
    Reference {
        name: "reference",
        paper: None,
        summary: "Deterministic reference: explicit form factors and Gauss-Seidel (up to 10k \
                  patches); --rays does not apply",
        kind: Deterministic,
        runner: crate::schedule::reference::run,
    }
}

impl Method {
    /// Whether [`ScheduleConfig::ambient`](crate::ScheduleConfig::ambient) can change
    /// this method's result: the methods whose answer, or whose gathering's input, is a
    /// shooting solution (`shoot`, `prr`, `two-pass`, `two-pass-split`, `progressive-gather`,
    /// `progressive-two-pass`). `gather`, `bidirectional` and `reference` shoot nothing or only
    /// to start their own steps, and `combined` weights its shooting by its own variance model
    /// without the term (it adds it only when its budget is too small for a pass and it falls
    /// back to `shoot`).
    pub const fn uses_ambient(self) -> bool {
        matches!(
            self,
            Method::Shoot
                | Method::Prr
                | Method::TwoPass
                | Method::TwoPassSplit
                | Method::ProgressiveGather
                | Method::ProgressiveTwoPass
        )
    }

    /// The Monte Carlo methods (every one but the [`Kind::Deterministic`]), in registry order.
    pub fn monte_carlo() -> impl Iterator<Item = Method> {
        Method::ALL
            .into_iter()
            .filter(|m| m.kind() != Kind::Deterministic)
    }
}

impl Default for Method {
    /// [`Method::Combined`], the fastest measured.
    fn default() -> Self {
        Method::Combined
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = UnknownName;

    /// The method of a [name](Method::name) (exactly, as the statistics write it).
    fn from_str(s: &str) -> Result<Method, UnknownName> {
        parse_name(s, &Method::ALL, Method::name, "method")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn every_method_round_trips_through_its_name_and_names_are_unique() {
        let mut names = HashSet::new();
        for m in Method::ALL {
            assert_eq!(m.name().parse::<Method>(), Ok(m));
            assert_eq!(m.to_string(), m.name());
            assert!(names.insert(m.name()), "{} twice", m.name());
            let kebab = m.name().chars().all(|c| c.is_ascii_lowercase() || c == '-');
            assert!(kebab && !m.summary().is_empty(), "{}", m.name());
        }
        assert!("teleport".parse::<Method>().is_err());
        assert!("Shoot".parse::<Method>().is_err());
        let e = "teleport".parse::<Method>().unwrap_err().to_string();
        assert!(
            e.contains("teleport") && e.contains("two-pass-split"),
            "{e}"
        );
    }

    #[test]
    fn the_reference_is_the_one_deterministic_method() {
        let deterministic: Vec<Method> = Method::ALL
            .into_iter()
            .filter(|m| m.kind() == Kind::Deterministic)
            .collect();
        assert_eq!(deterministic, vec![Method::Reference]);
        assert_eq!(Method::monte_carlo().count(), Method::ALL.len() - 1);
    }

    #[test]
    fn stop_reason_names_are_the_documented_ones() {
        let names = StopReason::ALL.map(StopReason::name);
        assert_eq!(names, ["converged", "budget", "stopped"]);
    }
}
