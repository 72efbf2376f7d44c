//! `mcrad`: stochastic radiosity from the command line. See `mcrad --help` and README.md.

mod cli;
mod interrupt;
mod merge;
mod output;
mod solve;
mod state;
mod trace;

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    let args = cli::Args::parse();
    let result = match args.command {
        cli::Command::Solve(solve) => solve::run(&solve),
        cli::Command::Merge(merge) => merge::run(&merge).map(|()| solve::Outcome::Done),
        cli::Command::Bake(bake) => {
            let mut solve = bake.solve;
            solve.bake = Some(cli::BakeTarget {
                out: bake.out,
                texel: bake.texel,
                target_error: bake.target_error,
                vertex_colors: bake.vertex_colors,
            });
            solve::run(&solve)
        }
    };
    match result {
        Ok(solve::Outcome::Done) => ExitCode::SUCCESS,
        Ok(solve::Outcome::Interrupted) => ExitCode::from(interrupt::EXIT_INTERRUPTED),
        Err(err) => {
            // One clear line: the error and its causes, joined.
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
