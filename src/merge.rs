//! `mcrad merge`: independent runs of one scene (different seeds, e.g. one per machine of a
//! cluster) combined into one solution by inverse variance.
//!
//! The weighting is `combine`'s [`RunWeighting::PooledInverseVariance`]: run `k` is weighted,
//! per channel, by the inverse of its variance summed over the patches every run reports one
//! for, the same weight for every patch (a patch's own variance is correlated with its value
//! and would bias the merge low; the maths and the measurement are on `RunWeighting`). This
//! module reads the runs, refuses runs of different meshes or the same run twice, and writes
//! the merged CSV.

use anyhow::{Context, Result, bail, ensure};
use glam::DVec3;
use mcrad_combine::{self as combine, EstimateError, Run, RunWeighting};
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

/// The merged rows and each run's weight per channel: `combine`'s merge of runs with pooled
/// inverse-variance weights ([`RunWeighting::PooledInverseVariance`], whose documentation has
/// the maths), or equal weights when no run reports variances.
fn merge_runs(paths: &[PathBuf], runs: &[Vec<PatchRow>]) -> Result<(Vec<PatchRow>, Vec<DVec3>)> {
    let estimates: Vec<Run> = runs
        .iter()
        .map(|r| {
            Run::new(
                r.iter().map(|row| row.radiosity).collect(),
                r.iter().map(|row| row.variance).collect(),
            )
        })
        .collect::<Result<_, _>>()?;
    let weighting = if estimates.iter().any(Run::has_variance) {
        RunWeighting::PooledInverseVariance
    } else {
        eprintln!("warning: no run reports variances: merged with equal weights");
        RunWeighting::Equal
    };
    let merged = match combine::merge_runs(&estimates, weighting) {
        Err(EstimateError::RunWithoutVariance { run }) => bail!(
            "{} has no variances, so it cannot be weighted against the other runs: merge \
             runs written by mcrad solve --patches or --save",
            paths[run].display()
        ),
        other => other?,
    };
    let rows = runs[0]
        .iter()
        .zip(merged.run.radiosity().iter().zip(merged.run.variance()))
        .map(|(first, (&radiosity, &variance))| PatchRow {
            patch: first.patch,
            area: first.area,
            radiosity,
            variance,
            face: first.face,
        })
        .collect();
    Ok((rows, merged.weights))
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
