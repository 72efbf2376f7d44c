//! `mcrad`: stochastic radiosity from the command line. See `mcrad --help` and README.md.

mod camera_arg;
mod cli;
mod output;
mod solve;
mod trace;

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    let args = cli::Args::parse();
    let result = match args.command {
        cli::Command::Solve(solve) => solve::run(&solve),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            // One clear line: the error and its causes, joined.
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
