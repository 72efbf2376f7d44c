//! Golden-image recipes: how `cargo xtask regress` renders a bundled scene and how far its
//! render may stray from the stored golden (`scenes/golden/<name>.json` beside
//! `scenes/golden/<name>.exr`).

use crate::compare::{CompareError, TileDifference, tile_difference};
use mcrad_render::Image;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// How one scene is rendered and judged; stored as `scenes/golden/<name>.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Recipe {
    /// The scene file, relative to the workspace root.
    pub scene: String,
    /// Arguments of `mcrad solve` besides the scene, `--seed` and `--image`.
    pub args: Vec<String>,
    /// Tile side in pixels for the comparison.
    pub tile: u32,
    /// Denominator floor as a fraction of the golden's mean radiance (dimensionless).
    pub relative_floor: f32,
    /// Largest allowed tile difference (dimensionless; set by `--bless`).
    pub threshold: f32,
    /// The seed-to-seed differences measured by `--bless` (seeds 1.. against seed 0).
    pub seed_spread: Vec<f32>,
}

/// Why a recipe could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum RecipeError {
    /// The file could not be read or written.
    #[error("could not access {}: {reason}", path.display())]
    Io {
        /// The recipe file.
        path: PathBuf,
        /// The underlying error.
        reason: std::io::Error,
    },
    /// The file is not a recipe.
    #[error("could not parse {}: {reason}", path.display())]
    Json {
        /// The recipe file.
        path: PathBuf,
        /// The underlying error.
        reason: serde_json::Error,
    },
}

impl Recipe {
    /// Reads the recipe at `path`.
    pub fn read(path: &Path) -> Result<Recipe, RecipeError> {
        let text = std::fs::read_to_string(path).map_err(|source| RecipeError::Io {
            path: path.to_path_buf(),
            reason: source,
        })?;
        serde_json::from_str(&text).map_err(|source| RecipeError::Json {
            path: path.to_path_buf(),
            reason: source,
        })
    }

    /// Writes the recipe to `path` as pretty-printed JSON with a final newline.
    pub fn write(&self, path: &Path) -> Result<(), RecipeError> {
        let text = serde_json::to_string_pretty(self).map_err(|source| RecipeError::Json {
            path: path.to_path_buf(),
            reason: source,
        })?;
        std::fs::write(path, text + "\n").map_err(|source| RecipeError::Io {
            path: path.to_path_buf(),
            reason: source,
        })
    }

    /// The denominator floor for `golden`, radiance (W/(m² sr)): `relative_floor` times the
    /// golden's mean radiance over pixels and channels.
    pub fn floor(&self, golden: &Image) -> f32 {
        let sum: f32 = golden.pixels.iter().map(|p| p.x + p.y + p.z).sum();
        self.relative_floor * sum / (3.0 * golden.pixels.len().max(1) as f32)
    }

    /// Compares `actual` with `golden` by [`tile_difference`] with this recipe's tile and floor.
    pub fn difference(
        &self,
        actual: &Image,
        golden: &Image,
    ) -> Result<TileDifference, CompareError> {
        tile_difference(actual, golden, self.tile, self.floor(golden))
    }

    /// Whether a difference passes: at most [`Recipe::threshold`].
    pub fn passes(&self, difference: &TileDifference) -> bool {
        difference.max_relative <= self.threshold
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn recipe() -> Recipe {
        Recipe {
            scene: "scenes/x.obj".into(),
            args: vec!["--rays".into(), "1e5".into()],
            tile: 2,
            relative_floor: 0.5,
            threshold: 0.1,
            seed_spread: vec![0.02, 0.03],
        }
    }

    #[test]
    fn round_trips_and_measures_with_its_floor() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.json");
        let r = recipe();
        r.write(&path).unwrap();
        assert_eq!(Recipe::read(&path).unwrap(), r);
        let golden = Image {
            width: 2,
            height: 2,
            pixels: vec![Vec3::splat(2.0); 4],
        };
        // Floor 0.5 × mean 2 = 1; a tile 0.3 brighter differs by 0.3 / (2 + 1) = 0.1.
        assert_eq!(r.floor(&golden), 1.0);
        let actual = Image {
            pixels: vec![Vec3::splat(2.3); 4],
            ..golden.clone()
        };
        let d = r.difference(&actual, &golden).unwrap();
        assert!((d.max_relative - 0.1).abs() < 1e-6, "{d:?}");
        let brighter = Image {
            pixels: vec![Vec3::splat(2.6); 4],
            ..golden.clone()
        };
        assert!(!r.passes(&r.difference(&brighter, &golden).unwrap()));
        std::fs::write(&path, "{").unwrap();
        assert!(matches!(Recipe::read(&path), Err(RecipeError::Json { .. })));
        assert!(matches!(
            Recipe::read(&dir.path().join("missing.json")),
            Err(RecipeError::Io { .. })
        ));
    }
}
