//! `cargo xtask regress [--bless]`: golden-image regression of the bundled scenes.
//!
//! Each scene has a recipe `scenes/golden/<name>.json` (the `mcrad solve` arguments, the tile
//! size and the threshold) and a golden render `scenes/golden/<name>.exr`. `regress` renders
//! every recipe with seed 0 and compares it with its golden by
//! [`tile_difference`](mcrad_export::compare::tile_difference): the largest relative difference
//! of tile means over tiles and channels. Monte Carlo noise sets the bar: `--bless` renders
//! seeds 0..SEEDS, keeps seed 0 as the golden, measures the difference of every other seed
//! from it, and records `threshold = MARGIN × the largest`. A change that only reshuffles
//! random numbers stays below it; a systematic change (a wall a few percent brighter) does not.
//! On failure the actual, golden and difference images are written as PNG under
//! `target/regress/` and their paths printed.

use anyhow::{Context, Result, bail};
use mcrad_export::compare::{difference_image, tile_difference};
use mcrad_render::read_exr;
use mcrad_render::{Exposure, Image, write_png};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Seeds rendered by `--bless` to measure the noise.
const SEEDS: u64 = 6;
/// Threshold = MARGIN × the largest seed-to-seed difference seen when blessing.
const MARGIN: f32 = 2.0;

/// How one scene is rendered and judged; stored as `scenes/golden/<name>.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Recipe {
    /// The scene file, relative to the workspace root.
    pub scene: String,
    /// Arguments of `mcrad solve` besides the scene, `--seed` and `--image`.
    pub args: Vec<String>,
    /// Tile side in pixels for the comparison.
    pub tile: u32,
    /// Denominator floor as a fraction of the golden's mean radiance.
    pub relative_floor: f32,
    /// Largest allowed tile difference (set by `--bless`).
    pub threshold: f32,
    /// The seed-to-seed differences measured by `--bless` (seeds 1.. against seed 0).
    pub seed_spread: Vec<f32>,
}

impl Recipe {
    /// The floor in radiance units for a golden image.
    pub fn floor(&self, golden: &Image) -> f32 {
        let sum: f32 = golden.pixels.iter().map(|p| p.x + p.y + p.z).sum();
        self.relative_floor * sum / (3.0 * golden.pixels.len().max(1) as f32)
    }
}

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
        let mut recipe: Recipe = serde_json::from_str(&std::fs::read_to_string(&path)?)
            .with_context(|| format!("could not parse {}", path.display()))?;
        let golden_path = golden_dir(root).join(format!("{name}.exr"));
        if bless {
            let golden = render(root, mcrad, &recipe, 0, &golden_path)?;
            let floor = recipe.floor(&golden);
            recipe.seed_spread = (1..SEEDS)
                .map(|seed| {
                    let img = render(
                        root,
                        mcrad,
                        &recipe,
                        seed,
                        &out_dir.join(format!("{name}-seed{seed}.exr")),
                    )?;
                    Ok(tile_difference(&img, &golden, recipe.tile, floor)?.max_relative)
                })
                .collect::<Result<_>>()?;
            let spread = recipe.seed_spread.iter().copied().fold(0.0, f32::max);
            recipe.threshold = MARGIN * spread;
            std::fs::write(&path, serde_json::to_string_pretty(&recipe)? + "\n")?;
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
        let d = tile_difference(&actual, &golden, recipe.tile, recipe.floor(&golden))?;
        let verdict = if d.max_relative <= recipe.threshold {
            "ok"
        } else {
            "FAILED"
        };
        println!(
            "{name}: {verdict}: largest tile difference {:.4} (threshold {:.4}) at tile {:?}, channel {}",
            d.max_relative,
            recipe.threshold,
            d.worst_tile,
            ["r", "g", "b"][d.worst_channel]
        );
        if d.max_relative > recipe.threshold {
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
