//! Run statistics as JSON.

use crate::ExportError;
use mcrad_mc_radiosity::{Method, RoundStats, Sampler, StopReason};
use serde::Serialize;
use std::io::Write;

/// Statistics of one solver run, written by `--stats F.json`. The first eight fields are the
/// command-line contract; the rest extend it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunStats {
    /// The method that ran, written as its registry name ([`Method::name`]: `shoot`,
    /// `two-pass-split`, ...).
    pub method: Method,
    /// Number of patches solved for.
    pub patches: usize,
    /// Rays cast.
    pub rays: u64,
    /// Wall-clock seconds of the solve (loading and meshing excluded).
    pub seconds: f64,
    /// `rays / seconds`.
    pub rays_per_second: f64,
    /// Iterations of the method (shooting: waves).
    pub iterations: u32,
    /// The run's seed.
    pub seed: u64,
    /// Worker threads used.
    pub threads: usize,
    /// Rays that hit nothing; `None` (written `null`) when the run was stopped in the middle
    /// of a step and the count of its last complete step is not known.
    pub escaped_rays: Option<u64>,
    /// Unshot power left at the end as a fraction of the emitted power (channels summed);
    /// `None` (`null`) as for `escaped_rays`.
    pub unshot_fraction: Option<f64>,
    /// Why the run ended, written as [`StopReason::name`]: `converged` (the accuracy target
    /// was reached), `budget` (the ray budget was spent) or `stopped` (stopped early: a time
    /// budget, an error target or a signal).
    pub stop: StopReason,
    /// Seconds spent loading the scene, meshing and building the BVH.
    pub setup_seconds: f64,
    /// How the rays were drawn, written as [`Sampler::name`]: `random` or `qmc`.
    pub sampler: Sampler,
    /// An adaptive mesh's refinement rounds, in order (elements before the round, elements
    /// marked by a gradient, by a visibility change and by light from close by, split, held at
    /// the minimum edge or the patch budget, unrefinable, rays cast); absent for a fixed mesh.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refinement: Option<Vec<RoundStats>>,
}

impl RunStats {
    /// Writes the statistics as one pretty-printed JSON object.
    pub fn write_json<W: Write>(&self, mut out: W) -> Result<(), ExportError> {
        serde_json::to_writer_pretty(&mut out, self).map_err(|source| ExportError::Json {
            what: "the run statistics",
            reason: source,
        })?;
        writeln!(out)
            .and_then(|_| out.flush())
            .map_err(|source| ExportError::Io {
                what: "the run statistics",
                reason: source,
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contract_fields_are_present() {
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
            sampler: Sampler::Qmc,
            refinement: None,
        };
        let mut buf = Vec::new();
        s.write_json(&mut buf).unwrap();
        let v: serde_json::Value = serde_json::from_slice(&buf).unwrap();
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
        let round = RoundStats {
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
            ..s
        };
        let mut buf = Vec::new();
        refined.write_json(&mut buf).unwrap();
        let v: serde_json::Value = serde_json::from_slice(&buf).unwrap();
        assert_eq!(v["refinement"][0]["split"], 7);
        assert_eq!(v["refinement"][0]["proximity"], 2);
        assert_eq!(v["refinement"][0]["rays"], 4096);
    }
}
