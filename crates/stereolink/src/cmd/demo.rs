//! `stereolink demo` (being built).

/// Arguments (none yet).
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Not implemented yet.
pub fn run(_args: Args, _out: &super::Output) -> anyhow::Result<()> {
    anyhow::bail!("this command is not implemented yet")
}
