//! `stereolink codec` (being built).

/// Arguments (none yet).
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Not implemented yet.
pub fn run(_args: Args, _out: &super::Output) -> anyhow::Result<()> {
    anyhow::bail!("this command is not implemented yet")
}

/// Arguments of the `bench` subcommand (none yet).
#[derive(Debug, clap::Args)]
pub struct BenchArgs {}

/// Not implemented yet.
pub fn run_bench(_args: BenchArgs, _out: &super::Output) -> anyhow::Result<()> {
    anyhow::bail!("this benchmark is not implemented yet")
}

/// Arguments of `stereolink decode` (none yet).
#[derive(Debug, clap::Args)]
pub struct DecodeArgs {}

/// Not implemented yet.
pub fn run_decode(_args: DecodeArgs, _out: &super::Output) -> anyhow::Result<()> {
    anyhow::bail!("this command is not implemented yet")
}
