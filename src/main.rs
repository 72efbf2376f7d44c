//! `mcrad`: stochastic radiosity from the command line. See `mcrad --help` and README.md.

mod allocator;
mod cli;
mod interrupt;
mod merge;
mod output;
mod solve;
mod state;
mod trace;

use clap::{CommandFactory, FromArgMatches};
use std::process::ExitCode;

fn main() -> ExitCode {
    allocator::give_back_large_arrays();
    let matches = cli::Args::command().get_matches();
    let args = match cli::Args::from_arg_matches(&matches) {
        Ok(args) => args,
        Err(e) => e.exit(),
    };
    // The flags given on the command line: a continued run takes the rest from its state.
    let given: Vec<String> = matches
        .subcommand()
        .map(|(_, sub)| {
            sub.ids()
                .filter(|id| {
                    sub.value_source(id.as_str()) == Some(clap::parser::ValueSource::CommandLine)
                })
                .map(|id| id.as_str().to_string())
                .collect()
        })
        .unwrap_or_default();
    let result = match args.command {
        cli::Command::Solve(mut solve) => {
            solve.given = given;
            solve::run(&solve)
        }
        cli::Command::Merge(merge) => merge::run(&merge).map(|()| solve::Outcome::Done),
        cli::Command::Bake(bake) => {
            let mut solve = bake.solve;
            solve.given = given;
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
            let unlit = err.chain().any(|e| {
                matches!(
                    e.downcast_ref::<mcrad_scene_io::SceneError>()
                        .map(mcrad_scene_io::SceneError::innermost),
                    Some(mcrad_scene_io::SceneError::NoEmitter { .. })
                )
            });
            if unlit {
                eprintln!("error: {err:#}; or give --sun X,Y,Z,E, --sky R,G,B or --sky-map F");
            } else {
                eprintln!("error: {err:#}");
            }
            ExitCode::FAILURE
        }
    }
}
