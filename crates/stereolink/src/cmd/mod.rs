//! Command-line definitions: one module per command, each with an `Args`
//! (clap derive) and a `run` function.

use clap::{Parser, Subcommand};

pub mod info;
pub mod synth;

/// How commands print results.
#[derive(Clone, Copy, Debug, Default)]
pub struct Output {
    /// Print one JSON object instead of human-readable text.
    pub json: bool,
}

impl Output {
    /// Prints `value` as JSON when `--json` is set, otherwise `human()`.
    pub fn emit<T: serde::Serialize>(
        &self,
        value: &T,
        human: impl FnOnce() -> String,
    ) -> anyhow::Result<()> {
        use std::io::Write;
        let mut stdout = std::io::stdout().lock();
        if self.json {
            serde_json::to_writer_pretty(&mut stdout, value)?;
            writeln!(stdout)?;
        } else {
            write!(stdout, "{}", human())?;
        }
        Ok(())
    }
}

/// Stereo vision for small robots on thin radio links.
///
/// stereolink segments a rectified stereo pair (k-means, mean shift, PSO,
/// DPSO, FO-DPSO), compresses it, estimates disparity and depth (WTA-SAD,
/// line growing, SGM), sends it over an XBee/802.15.4 radio (or serial/UDP),
/// and on the receiving board shows a 3-D view and moves a linear axis by the
/// estimated distance.
///
/// Start with `stereolink demo`: it runs the whole system on a built-in
/// synthetic scene and writes its results to ./demo-out/.
#[derive(Debug, Parser)]
#[command(
    name = "stereolink",
    version,
    propagate_version = true,
    max_term_width = 100
)]
pub struct Cli {
    /// Print one machine-readable JSON object instead of text.
    #[arg(long, global = true)]
    pub json: bool,

    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Describe a stereo scene folder: sizes, disparity range, calibration, ground truth.
    Info(info::Args),
    /// Generate a synthetic stereo scene with exact ground truth.
    Synth(synth::Args),
}

impl Command {
    /// Runs the command.
    pub fn run(self, out: &Output) -> anyhow::Result<()> {
        match self {
            Command::Info(args) => info::run(args, out),
            Command::Synth(args) => synth::run(args, out),
        }
    }
}
