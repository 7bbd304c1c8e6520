//! The `stereolink` command line: parses arguments, runs a command, prints
//! one clear line on failure.
//!
//! Exit codes: 0 success, 1 failure, 2 usage error (clap's own).

use std::process::ExitCode;

use clap::Parser;

use stereolink::cmd::{Cli, Output};

fn main() -> ExitCode {
    let cli = Cli::parse();
    let out = Output { json: cli.json };
    match cli.command.run(&out) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            // A closed pipe (`stereolink ... | head`) is not a failure.
            if err
                .downcast_ref::<std::io::Error>()
                .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
            {
                return ExitCode::SUCCESS;
            }
            eprintln!("stereolink: {err:#}");
            ExitCode::from(1)
        }
    }
}
