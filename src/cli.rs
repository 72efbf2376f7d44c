//! The command line (its flags are the contract of `ARCHITECTURE.md`).

use clap::{Parser, Subcommand, ValueEnum};
use std::path::PathBuf;

/// Stochastic (Monte Carlo) radiosity.
#[derive(Debug, Parser)]
#[command(name = "mcrad", version, about)]
pub struct Args {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Solve a scene's radiosity and write the results.
    Solve(Solve),
}

/// The solution methods.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Method {
    /// Stochastic shooting with constant energy per ray (paper, section 1.3).
    Shoot,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Shoot => "shoot",
        }
    }
}

#[derive(Debug, clap::Args)]
pub struct Solve {
    /// The scene: .obj (with the .mtl files it names), .gltf or .glb.
    pub scene: PathBuf,
    /// Solution method.
    #[arg(long, value_enum, default_value_t = Method::Shoot)]
    pub method: Method,
    /// Total ray budget over all passes (accepts 2000000 and 2e6).
    #[arg(long, default_value = "2e6", value_parser = parse_count)]
    pub rays: u64,
    /// Seed of all random streams: the same seed gives the same answer on any thread count.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    pub threads: Option<u16>,
    /// One patch per input face, faces in file order.
    #[arg(long, conflicts_with = "max_edge")]
    pub no_subdivide: bool,
    /// Subdivide until no patch edge is longer than L (scene units). Default: the scene's
    /// bounding-box diagonal / 20.
    #[arg(long, value_name = "L", allow_negative_numbers = true)]
    pub max_edge: Option<f32>,
    /// Stop shooting when the unshot power is below this fraction of the emitted power.
    #[arg(long, default_value_t = 0.01, value_name = "FRACTION")]
    pub unshot_threshold: f64,
    /// Write per-patch radiosity: `patch,area,r,g,b,var_r,var_g,var_b`.
    #[arg(long, value_name = "F.csv")]
    pub patches: Option<PathBuf>,
    /// Write run statistics as JSON.
    #[arg(long, value_name = "F.json")]
    pub stats: Option<PathBuf>,
    /// No progress bar and no summary line (errors and warnings still go to stderr).
    #[arg(long, short)]
    pub quiet: bool,
}

/// Parses a count written as an integer (`2000000`) or in float notation (`2e6`).
fn parse_count(s: &str) -> Result<u64, String> {
    if let Ok(n) = s.parse::<u64>() {
        return if n >= 1 {
            Ok(n)
        } else {
            Err("must be at least 1".into())
        };
    }
    let x: f64 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !x.is_finite() || x < 1.0 || x.fract() != 0.0 || x > u64::MAX as f64 {
        return Err(format!("'{s}' is not a whole number of at least 1"));
    }
    Ok(x as u64)
}

#[cfg(test)]
mod tests {
    use super::parse_count;

    #[test]
    fn counts_accept_integers_and_float_notation() {
        assert_eq!(parse_count("2000000"), Ok(2_000_000));
        assert_eq!(parse_count("2e6"), Ok(2_000_000));
        assert_eq!(parse_count("1.5e3"), Ok(1500));
        for bad in ["0", "-5", "1.5", "abc", "nan", "inf", "1e30"] {
            assert!(parse_count(bad).is_err(), "{bad}");
        }
    }
}
