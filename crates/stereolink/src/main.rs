//! The `stereolink` command line: parses arguments, runs a command, prints
//! one clear line on failure.
//!
//! Exit codes: 0 success, 1 failure, 2 usage error (clap's own, or a bad
//! `--config` file).

use std::process::ExitCode;

use clap::{CommandFactory, Parser};

use stereolink::cmd::{Cli, Output};
use stereolink::config;

/// Diagnostics (`tracing`) go to stderr, filtered by `RUST_LOG` (default
/// `info`; `RUST_LOG=debug` shows the link's decisions); under systemd
/// (`JOURNAL_STREAM` set) without time stamps, which journald adds itself;
/// coloured only on a terminal. A command's own output stays on stdout.
fn init_logging() {
    use std::io::IsTerminal;
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let fmt = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal());
    if std::env::var_os("JOURNAL_STREAM").is_some() {
        fmt.without_time().init();
    } else {
        fmt.init();
    }
}

fn main() -> ExitCode {
    init_logging();
    let argv = match config::expand(std::env::args_os().collect(), &Cli::command()) {
        Ok(argv) => argv,
        Err(err) => {
            eprintln!("stereolink: {err:#}");
            return ExitCode::from(2);
        }
    };
    let cli = Cli::parse_from(argv);
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
