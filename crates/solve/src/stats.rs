//! What a run reports of itself: the `--stats` JSON.

use crate::Closure;
use mcrad_mc_radiosity::RoundStats;
use mcrad_mc_radiosity::{Method, Sampler, StopReason};
use serde::{Serialize, Serializer};

/// Statistics of one solve, ready for serde (`mcrad solve --stats F.json` writes them as JSON).
/// The first eight fields are the command-line contract; the rest extend it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunStats {
    /// The method that ran, written as its registry name ([`Method::name`]).
    #[serde(serialize_with = "by_name")]
    pub method: Method,
    /// Patches solved for.
    pub patches: usize,
    /// Rays cast by the refinement and the method (over every piece of a continued run).
    pub rays: u64,
    /// Wall-clock seconds of the solve (loading and meshing excluded).
    pub seconds: f64,
    /// This piece's method rays over `seconds` (rays/s).
    pub rays_per_second: f64,
    /// Steps of the method over every piece (shooting: waves).
    pub iterations: u32,
    /// The run's seed.
    pub seed: u64,
    /// Worker threads used.
    pub threads: usize,
    /// Rays that hit nothing; `None` (written `null`) when a step was abandoned and the count
    /// of the last complete step is not known.
    pub escaped_rays: Option<u64>,
    /// Unshot power left at the end as a fraction of the emitted power (channels summed);
    /// `None` (`null`) as for `escaped_rays`.
    pub unshot_fraction: Option<f64>,
    /// Why the run ended, written as [`StopReason::name`]: `converged`, `budget` or `stopped`
    /// (a time budget, an error target, an observer or a cancellation).
    #[serde(serialize_with = "by_name")]
    pub stop: StopReason,
    /// Seconds from the start of the budget's clock ([`crate::Budget::since`]: the CLI starts
    /// it before loading the scene) to the start of the method: loading, meshing, refining and
    /// building the ray caster (s).
    pub setup_seconds: f64,
    /// Where `setup_seconds` after loading went, phase by phase.
    pub setup: SetupPhases,
    /// How the rays were drawn, written as [`Sampler::name`]: `random` or `qmc`.
    #[serde(serialize_with = "by_name")]
    pub sampler: Sampler,
    /// An adaptive mesh's refinement rounds, in order; absent for a fixed mesh.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refinement: Option<Vec<RefinementRound>>,
    /// Where the emitted power went, per RGB channel (W): emitted, absorbed, escaped, their
    /// balance and its standard error ([`Closure`]); absent unless [`Problem::closure`] asked
    /// for it.
    ///
    /// [`Problem::closure`]: crate::Problem::closure
    #[serde(skip_serializing_if = "Option::is_none")]
    pub closure: Option<Closure>,
    /// Clusters of small faces that share one estimate of irradiance, and what the answer's
    /// pooling over them did; absent where none formed (every mesh but an adaptive one's).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub clusters: Option<ClusterStats>,
}

/// The phases of a solve's setup after loading, wall-clock seconds each: what
/// [`RunStats::setup_seconds`] holds beside the loading (which the caller times: the CLI's
/// `load_seconds`).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct SetupPhases {
    /// The mesh before any refinement: an adaptive mesh's start (its candidates counted, the
    /// one taken built), a replayed history, or a fixed mesh (s).
    pub mesh_seconds: f64,
    /// An adaptive mesh's refinement: its ray caster (built again after each round that
    /// splits), the pilot shooting and the rounds (s); 0 for a fixed mesh.
    pub refine_seconds: f64,
    /// The ray caster over the final mesh, where the refinement's could not be reused (s).
    pub caster_seconds: f64,
    /// The clusters of small faces (s).
    pub clusters_seconds: f64,
    /// Timing the caller's work after the solve ([`crate::Problem::after`]: the CLI renders
    /// `--image` at an eighth of its size), under a time budget (s).
    pub after_seconds: f64,
}

/// Clusters of small faces ([`mcrad_meshing::Clusters`]) and the answer's pooling over them:
/// each group shares one incident irradiance, each face keeps its own reflectance and
/// emission. Counts of patches (here, whole input faces).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct ClusterStats {
    /// Clusters formed from the geometry (at least two faces each).
    pub clusters: usize,
    /// Faces in them.
    pub faces: usize,
    /// Groups that share one estimate after the test of the light across them (a cluster
    /// the light varies across is split in two, again and again, down to single faces).
    pub groups: usize,
    /// Faces in those groups.
    pub pooled_faces: usize,
    /// Splits made by that test.
    pub splits: usize,
    /// Independent estimates in the answer: the patches less the pooled faces plus the
    /// groups.
    pub elements: usize,
    /// Elements the method's transport ran on ([`crate::Clustering::Transport`]): the patches
    /// outside the groups the refinement's estimate showed evenly lit, plus one per such
    /// group; `None` when it ran per patch.
    pub transport_elements: Option<usize>,
}

/// What one round of an adaptive mesh's refinement did (counts of elements, and rays).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct RefinementRound {
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
    /// Marked elements not split: at the minimum edge or beyond the patch budget.
    pub held: usize,
    /// Marked elements that could not be split into valid elements (kept).
    pub unrefinable: usize,
    /// Rays cast in the round.
    pub rays: u64,
}

impl From<&RoundStats> for RefinementRound {
    fn from(r: &RoundStats) -> Self {
        RefinementRound {
            elements: r.elements,
            gradient: r.gradient,
            visibility: r.visibility,
            proximity: r.proximity,
            split: r.split,
            held: r.held,
            unrefinable: r.unrefinable,
            rays: r.rays,
        }
    }
}

/// Things named on the command line and in statistics.
trait Named {
    fn name(&self) -> &'static str;
}

impl Named for Method {
    fn name(&self) -> &'static str {
        Method::name(*self)
    }
}

impl Named for StopReason {
    fn name(&self) -> &'static str {
        StopReason::name(*self)
    }
}

impl Named for Sampler {
    fn name(&self) -> &'static str {
        Sampler::name(*self)
    }
}

fn by_name<T: Named, S: Serializer>(value: &T, serializer: S) -> Result<S::Ok, S::Error> {
    serializer.serialize_str(value.name())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contract_fields_are_written_by_name() {
        let s = RunStats {
            method: Method::TwoPassSplit,
            patches: 32,
            rays: 1000,
            seconds: 0.5,
            rays_per_second: 2000.0,
            iterations: 7,
            seed: 3,
            threads: 2,
            escaped_rays: Some(0),
            unshot_fraction: Some(0.01),
            stop: StopReason::BudgetSpent,
            setup_seconds: 0.1,
            setup: SetupPhases::default(),
            sampler: Sampler::Qmc,
            refinement: None,
            clusters: None,
            closure: Some(Closure {
                emitted: [1.0, 2.0, 3.0],
                absorbed: [0.5, 1.0, 1.5],
                escaped: [0.5, 1.0, 1.5],
                balance: [0.0; 3],
                balance_se: Some([0.01; 3]),
                rays: 64,
            }),
        };
        let v = serde_json::to_value(&s).unwrap();
        for key in [
            "method",
            "patches",
            "rays",
            "seconds",
            "rays_per_second",
            "iterations",
            "seed",
            "threads",
        ] {
            assert!(v.get(key).is_some(), "missing {key}");
        }
        assert_eq!(v["method"], "two-pass-split");
        assert_eq!(v["stop"], "budget");
        assert_eq!(v["sampler"], "qmc");
        assert_eq!(v["rays"], 1000);
        assert!(
            v.get("refinement").is_none(),
            "a fixed mesh writes no rounds"
        );
        let round = RefinementRound {
            elements: 100,
            gradient: 3,
            visibility: 5,
            proximity: 2,
            split: 7,
            held: 1,
            unrefinable: 0,
            rays: 4096,
        };
        let refined = RunStats {
            refinement: Some(vec![round]),
            clusters: None,
            ..s
        };
        let v = serde_json::to_value(&refined).unwrap();
        assert_eq!(v["refinement"][0]["split"], 7);
        assert_eq!(v["refinement"][0]["proximity"], 2);
        assert_eq!(v["refinement"][0]["rays"], 4096);
        assert_eq!(v["closure"]["emitted"], serde_json::json!([1.0, 2.0, 3.0]));
        assert_eq!(v["closure"]["balance_se"][2], 0.01);
    }
}
