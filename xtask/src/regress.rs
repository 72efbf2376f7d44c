//! `cargo xtask regress [--bless]`: golden-image regression of the bundled scenes.
//!
//! Each scene has a recipe `scenes/golden/<name>.json` (the `mcrad solve` arguments, the tile
//! size and the threshold) and a golden render `scenes/golden/<name>.exr`. `regress` renders
//! every recipe with seed 0 and compares it with its golden by
//! [`tile_difference`](mcrad_lab::compare::tile_difference): the largest relative difference
//! of tile means over tiles and channels. Monte Carlo noise sets the bar: `--bless` renders
//! seeds 0..SEEDS, keeps seed 0 as the golden, measures the difference of every other seed
//! from it, and records `threshold = MARGIN × the largest`. A change that only reshuffles
//! random numbers stays below it; a systematic change (a wall a few percent brighter) does not.
//! On failure the actual, golden and difference images are written as PNG under
//! `target/regress/` and their paths printed.

use anyhow::{Context, Result, bail};
use mcrad_lab::compare::difference_image;
use mcrad_lab::recipe::Recipe;
use mcrad_render::{Exposure, Image, read_exr, write_png};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Seeds rendered by `--bless` to measure the noise.
const SEEDS: u64 = 6;
/// Threshold = MARGIN × the largest seed-to-seed difference seen when blessing.
const MARGIN: f32 = 2.0;

fn golden_dir(root: &Path) -> PathBuf {
    root.join("scenes/golden")
}

/// Renders `recipe` with `seed` into `out` (EXR) with the release binary.
fn render(root: &Path, mcrad: &Path, recipe: &Recipe, seed: u64, out: &Path) -> Result<Image> {
    let status = Command::new(mcrad)
        .current_dir(root)
        .arg("solve")
        .arg(&recipe.scene)
        .args(&recipe.args)
        .args(["--seed", &seed.to_string(), "--quiet", "--image"])
        .arg(out)
        .status()
        .context("could not run mcrad")?;
    if !status.success() {
        bail!("mcrad solve {} failed ({status})", recipe.scene);
    }
    Ok(read_exr(out)?)
}

/// Runs the regression (or blesses new goldens) for every recipe in `scenes/golden/`.
pub fn run(root: &Path, mcrad: &Path, bless: bool) -> Result<()> {
    let out_dir = root.join("target/regress");
    std::fs::create_dir_all(&out_dir)?;
    let mut recipes: Vec<PathBuf> = std::fs::read_dir(golden_dir(root))
        .context("scenes/golden/ is missing")?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    recipes.sort();
    if recipes.is_empty() {
        bail!("no recipes in scenes/golden/");
    }
    let mut failed = Vec::new();
    for path in recipes {
        let name = path
            .file_stem()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned();
        let mut recipe = Recipe::read(&path)?;
        let golden_path = golden_dir(root).join(format!("{name}.exr"));
        if bless {
            let golden = render(root, mcrad, &recipe, 0, &golden_path)?;
            recipe.seed_spread = (1..SEEDS)
                .map(|seed| {
                    let img = render(
                        root,
                        mcrad,
                        &recipe,
                        seed,
                        &out_dir.join(format!("{name}-seed{seed}.exr")),
                    )?;
                    Ok(recipe.difference(&img, &golden)?.max_relative)
                })
                .collect::<Result<_>>()?;
            let spread = recipe.seed_spread.iter().copied().fold(0.0, f32::max);
            recipe.threshold = MARGIN * spread;
            recipe.write(&path)?;
            println!(
                "{name}: blessed; seed spread up to {spread:.4}, threshold {:.4}",
                recipe.threshold
            );
            continue;
        }
        let golden = read_exr(&golden_path)?;
        let actual = render(
            root,
            mcrad,
            &recipe,
            0,
            &out_dir.join(format!("{name}-actual.exr")),
        )?;
        let d = recipe.difference(&actual, &golden)?;
        let verdict = if recipe.passes(&d) { "ok" } else { "FAILED" };
        println!(
            "{name}: {verdict}: largest tile difference {:.4} (threshold {:.4}) at tile {:?}, channel {}",
            d.max_relative,
            recipe.threshold,
            d.worst_tile,
            ["r", "g", "b"][d.worst_channel]
        );
        if !recipe.passes(&d) {
            let scale = Exposure::Auto.scale(&golden);
            let fixed = Exposure::Stops(scale.log2());
            for (suffix, image, exposure) in [
                ("actual", &actual, fixed),
                ("golden", &golden, fixed),
                (
                    "diff",
                    &difference_image(&actual, &golden)?,
                    Exposure::Stops(0.0),
                ),
            ] {
                let p = out_dir.join(format!("{name}-{suffix}.png"));
                write_png(image, &p, exposure)?;
                println!("  {suffix}: {}", p.display());
            }
            failed.push(name);
        }
    }
    if !failed.is_empty() {
        bail!(
            "regression in {}: see the images above; if the change is intended, run `cargo xtask regress --bless`",
            failed.join(", ")
        );
    }
    Ok(())
}
