//! `mcrad merge`: independent runs of one scene (different seeds, e.g. one per machine of a
//! cluster) combined into one solution by inverse variance.
//!
//! **The weights.** Run `k` of `K` is weighted, per channel `c`, by `w_kc ∝ 1 / S_kc` with
//! `S_kc = sum_i V_kic` its reported variance summed over the patches every run reports one
//! for; the merged value of patch `i` is `sum_k w_kc B_kic` and its variance
//! `sum_k w_kc² V_kic`. This is the inverse-variance merge per patch and channel under the model
//! `V_kic = v_ic / e_kc` (the runs differ by an efficiency per run and channel: rays, method),
//! with each run's efficiency estimated from all its patches pooled. A patch's own variance is
//! *not* its weight: it is estimated from the same samples as the value and correlated with it
//! (shot noise: `V ∝ B`), and weights `∝ 1 / V_ki` make the merge a harmonic mean, biased low
//! by about the relative variance of one run whatever the number of runs (measured on the
//! Cornell box, four runs of 5e5 rays: -0.18% in total power, mean z -0.28 against -0.12 with
//! equal weights). A weight pooled over hundreds of patches hardly depends on any one of them,
//! so the merge of unbiased runs is unbiased; runs of equal budgets get equal weights, and the
//! merged variance is about `1/K` of one run's.
//!
//! A patch whose variance a run does not know (blank in its CSV) gets no weight from it: it is
//! left out of `S_kc` for every run, and its merged variance is unknown (blank).

use anyhow::{Context, Result, bail, ensure};
use glam::DVec3;
use mcrad_export::{PatchRow, read_patch_csv, write_patch_csv};
use std::path::{Path, PathBuf};

/// `mcrad merge`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Merge {
    /// The runs: patch CSVs written by `mcrad solve --patches` (`.csv`) or states written by
    /// `--save` (any other name), all of the same scene and mesh, with different seeds.
    #[arg(required = true, num_args = 2.., value_name = "RUN")]
    pub runs: Vec<PathBuf>,
    /// Write the merged solution as a patch CSV: `patch,area,r,g,b,var_r,var_g,var_b`.
    #[arg(long, value_name = "OUT.csv")]
    pub patches: PathBuf,
    /// No summary line.
    #[arg(long, short)]
    pub quiet: bool,
}

/// The largest relative difference between the areas of one patch in two runs: the CSV writes
/// areas exactly, other tools may round them.
const AREA_TOLERANCE: f64 = 1e-6;

pub fn run(args: &Merge) -> Result<()> {
    let runs: Vec<Vec<PatchRow>> = args
        .runs
        .iter()
        .map(|p| read_run(p))
        .collect::<Result<_>>()?;
    check_same_patches(&args.runs, &runs)?;
    check_independent(&args.runs, &runs)?;
    let (merged, weights) = merge_runs(&args.runs, &runs)?;
    let file = std::fs::File::create(&args.patches)
        .with_context(|| format!("could not create {}", args.patches.display()))?;
    write_patch_csv(std::io::BufWriter::new(file), merged)
        .with_context(|| format!("could not write {}", args.patches.display()))?;
    if !args.quiet {
        let shares: Vec<String> = args
            .runs
            .iter()
            .zip(&weights)
            .map(|(p, w)| format!("{} {:.3}", p.display(), w.element_sum() / 3.0))
            .collect();
        println!(
            "{}: {} runs merged, {} patches; weights (mean over channels): {}",
            args.patches.display(),
            runs.len(),
            runs[0].len(),
            shares.join(", ")
        );
    }
    Ok(())
}

/// The rows of one run: a patch CSV by its extension, else a saved state.
fn read_run(path: &Path) -> Result<Vec<PatchRow>> {
    let csv = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"));
    if csv {
        Ok(read_patch_csv(path)?)
    } else {
        crate::state::rows(&crate::state::load(path)?)
    }
}

/// What to do about runs of different meshes: the default adaptive mesh is refined anew by
/// every run.
const SAME_MESH: &str = "runs of different meshes cannot be merged (an adaptive mesh, the \
                         default, is refined anew by every run: solve with --mesh uniform, or \
                         merge their --per-face CSVs)";

/// Refuses runs of different patch sets: counts, patch numbers in order, areas.
fn check_same_patches(paths: &[PathBuf], runs: &[Vec<PatchRow>]) -> Result<()> {
    let (first, a) = (paths[0].display(), &runs[0]);
    ensure!(!a.is_empty(), "{first} has no patches");
    for (path, b) in paths.iter().zip(runs).skip(1) {
        let second = path.display();
        ensure!(
            a.len() == b.len(),
            "{second} has {} patches, {first} has {}: {SAME_MESH}",
            b.len(),
            a.len()
        );
        for (row, (x, y)) in a.iter().zip(b).enumerate() {
            ensure!(
                x.patch == y.patch,
                "row {} of {second} is patch {}, of {first} patch {}: {SAME_MESH}",
                row + 1,
                y.patch,
                x.patch
            );
            let scale = x.area.abs().max(y.area.abs());
            ensure!(
                (x.area - y.area).abs() <= AREA_TOLERANCE * scale,
                "patch {} has area {} in {second} and {} in {first}: {SAME_MESH}",
                x.patch,
                y.area,
                x.area
            );
        }
    }
    Ok(())
}

/// Refuses a run given twice (the same file, or the same seed): its noise would count as
/// independent and the merged variance would be too small.
fn check_independent(paths: &[PathBuf], runs: &[Vec<PatchRow>]) -> Result<()> {
    for (a, x) in runs.iter().enumerate() {
        for (b, y) in runs.iter().enumerate().skip(a + 1) {
            let same = x.iter().zip(y).all(|(p, q)| p.radiosity == q.radiosity);
            ensure!(
                !same,
                "{} and {} hold the same solution (the same run, or the same seed): merge \
                 independent runs, each with its own --seed",
                paths[a].display(),
                paths[b].display()
            );
        }
    }
    Ok(())
}

/// The merged rows and each run's weight per channel (see the module's documentation).
fn merge_runs(paths: &[PathBuf], runs: &[Vec<PatchRow>]) -> Result<(Vec<PatchRow>, Vec<DVec3>)> {
    let count = runs.len();
    let with_variance: Vec<bool> = runs
        .iter()
        .map(|r| r.iter().any(|row| row.variance.is_some()))
        .collect();
    let weights: Vec<DVec3> = if with_variance.iter().all(|&v| !v) {
        eprintln!("warning: no run reports variances: merged with equal weights");
        vec![DVec3::splat(1.0 / count as f64); count]
    } else {
        if let Some(k) = with_variance.iter().position(|&v| !v) {
            bail!(
                "{} has no variances, so it cannot be weighted against the other runs: merge \
                 runs written by mcrad solve --patches or --save",
                paths[k].display()
            );
        }
        // Per run and channel, the variance summed over the patches every run knows it for.
        let mut sums = vec![DVec3::ZERO; count];
        for i in 0..runs[0].len() {
            let known: Option<Vec<DVec3>> = runs.iter().map(|r| r[i].variance).collect();
            if let Some(v) = known {
                for (s, v) in sums.iter_mut().zip(v) {
                    *s += v;
                }
            }
        }
        inverse_weights(&sums)
    };
    let merged = (0..runs[0].len())
        .map(|i| {
            let (mut value, mut variance) = (DVec3::ZERO, Some(DVec3::ZERO));
            for (run, w) in runs.iter().zip(&weights) {
                let row = &run[i];
                value += *w * row.radiosity;
                variance = variance.zip(row.variance).map(|(acc, v)| acc + *w * *w * v);
            }
            PatchRow {
                patch: runs[0][i].patch,
                area: runs[0][i].area,
                radiosity: value,
                variance,
                face: runs[0][i].face,
            }
        })
        .collect();
    Ok((merged, weights))
}

/// Weights `∝ 1 / s_kc` per channel, summing to 1 over the runs. Where some sums are zero
/// (runs that claim no noise at all) those runs share the weight equally; where all are, every
/// run does.
fn inverse_weights(sums: &[DVec3]) -> Vec<DVec3> {
    let mut weights = vec![DVec3::ZERO; sums.len()];
    for c in 0..3 {
        let zeros = sums.iter().filter(|s| s[c] <= 0.0).count();
        if zeros > 0 {
            for (w, s) in weights.iter_mut().zip(sums) {
                w[c] = if s[c] <= 0.0 { 1.0 / zeros as f64 } else { 0.0 };
            }
        } else {
            let total: f64 = sums.iter().map(|s| 1.0 / s[c]).sum();
            for (w, s) in weights.iter_mut().zip(sums) {
                w[c] = (1.0 / s[c]) / total;
            }
        }
    }
    weights
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(patch: u32, area: f64, b: f64, v: Option<f64>) -> PatchRow {
        PatchRow {
            patch,
            area,
            radiosity: DVec3::splat(b),
            variance: v.map(DVec3::splat),
            face: None,
        }
    }

    fn paths(n: usize) -> Vec<PathBuf> {
        (0..n)
            .map(|k| PathBuf::from(format!("run{k}.csv")))
            .collect()
    }

    #[test]
    fn runs_are_weighted_by_their_pooled_inverse_variance() {
        // Run 1 has half the variance of run 0 everywhere: weights 1/3 and 2/3 on every patch,
        // whatever the patch's own values and variances.
        let a = vec![row(0, 1.0, 1.0, Some(2.0)), row(1, 1.0, 10.0, Some(4.0))];
        let b = vec![row(0, 1.0, 4.0, Some(1.0)), row(1, 1.0, 7.0, Some(2.0))];
        let (m, w) = merge_runs(&paths(2), &[a, b]).unwrap();
        assert!((w[0].x - 1.0 / 3.0).abs() < 1e-12 && (w[1].x - 2.0 / 3.0).abs() < 1e-12);
        assert!((m[0].radiosity.x - 3.0).abs() < 1e-12);
        assert!((m[1].radiosity.x - 8.0).abs() < 1e-12);
        // (1/3)² 2 + (2/3)² 1 = 2/3.
        assert!((m[0].variance.unwrap().x - 2.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn an_unknown_variance_gives_no_weight_and_an_unknown_merged_variance() {
        // Patch 1's variance is blank in run 0: it is left out of both runs' sums (so run 1's
        // huge variance there does not count against it), and its merged variance is blank.
        let a = vec![row(0, 1.0, 1.0, Some(1.0)), row(1, 1.0, 5.0, None)];
        let b = vec![row(0, 1.0, 3.0, Some(1.0)), row(1, 1.0, 9.0, Some(1e9))];
        let (m, w) = merge_runs(&paths(2), &[a, b]).unwrap();
        assert_eq!(w[0], DVec3::splat(0.5));
        assert_eq!(m[1].radiosity.x, 7.0);
        assert_eq!(m[1].variance, None);
        assert_eq!(m[0].variance, Some(DVec3::splat(0.5)));
        // A run with no variance at all cannot be weighted against runs that have them.
        let c = vec![row(0, 1.0, 3.0, None), row(1, 1.0, 9.0, None)];
        let a = vec![row(0, 1.0, 1.0, Some(1.0)), row(1, 1.0, 5.0, Some(1.0))];
        let err = merge_runs(&paths(2), &[a, c.clone()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("run1.csv has no variances"), "{err}");
        // None has them: equal weights, blank variances.
        let (m, _) = merge_runs(&paths(2), &[c.clone(), c]).unwrap();
        assert_eq!(m[0].variance, None);
        assert_eq!(m[0].radiosity.x, 3.0);
    }

    #[test]
    fn zero_variance_runs_take_the_weight() {
        let w = inverse_weights(&[DVec3::new(0.0, 1.0, 0.0), DVec3::new(2.0, 1.0, 0.0)]);
        assert_eq!(w[0], DVec3::new(1.0, 0.5, 0.5));
        assert_eq!(w[1], DVec3::new(0.0, 0.5, 0.5));
    }

    #[test]
    fn different_patch_sets_are_refused_with_the_reason() {
        let a = vec![row(0, 1.0, 1.0, Some(1.0)), row(1, 2.0, 1.0, Some(1.0))];
        let short = vec![row(0, 1.0, 1.0, Some(1.0))];
        let renumbered = vec![row(0, 1.0, 1.0, Some(1.0)), row(2, 2.0, 1.0, Some(1.0))];
        let resized = vec![row(0, 1.0, 1.0, Some(1.0)), row(1, 2.1, 1.0, Some(1.0))];
        let rounded = vec![
            row(0, 1.0, 1.0, Some(1.0)),
            row(1, 2.000_000_1, 1.0, Some(1.0)),
        ];
        let p = paths(2);
        for (b, expect) in [
            (short, "has 1 patches, run0.csv has 2"),
            (renumbered, "row 2 of run1.csv is patch 2"),
            (resized, "patch 1 has area 2.1 in run1.csv"),
        ] {
            let err = check_same_patches(&p, &[a.clone(), b])
                .unwrap_err()
                .to_string();
            assert!(err.contains(expect), "{err}");
        }
        check_same_patches(&p, &[a.clone(), rounded]).unwrap();
        let err = check_independent(&paths(3), &[a.clone(), short_copy(&a), a])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("run0.csv and run2.csv hold the same solution"),
            "{err}"
        );
    }

    fn short_copy(rows: &[PatchRow]) -> Vec<PatchRow> {
        rows.iter()
            .map(|r| PatchRow {
                radiosity: r.radiosity + 1.0,
                ..*r
            })
            .collect()
    }
}
