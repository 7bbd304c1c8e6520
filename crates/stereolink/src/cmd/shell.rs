//! `stereolink completions SHELL` and `stereolink man`: shell completions
//! and man pages, generated from the same clap definitions that parse the
//! arguments (`clap_complete`, `clap_mangen`), so they never drift from
//! `--help`.

use std::path::PathBuf;

use anyhow::Context;
use clap::CommandFactory;

use super::Cli;

/// Arguments of `stereolink completions`.
#[derive(Debug, clap::Args)]
pub struct CompletionArgs {
    /// The shell: bash, zsh, fish, elvish or powershell. For bash, e.g.
    /// `stereolink completions bash > /etc/bash_completion.d/stereolink`.
    pub shell: clap_complete::Shell,
}

/// Arguments of `stereolink man`.
#[derive(Debug, clap::Args)]
pub struct ManArgs {
    /// Write a page per command into this folder (`stereolink.1`,
    /// `stereolink-send.1`, ...; e.g. /usr/local/share/man/man1) instead
    /// of the main page to stdout.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Prints the completion script for the shell (made in memory first:
/// the generator panics on a failed write, such as a closed pipe).
pub fn completions(args: CompletionArgs) -> anyhow::Result<()> {
    use std::io::Write;
    let mut script = Vec::new();
    clap_complete::generate(args.shell, &mut Cli::command(), "stereolink", &mut script);
    std::io::stdout().lock().write_all(&script)?;
    Ok(())
}

/// Prints the main man page, or writes every command's into a folder.
pub fn man(args: ManArgs, out: &super::Output) -> anyhow::Result<()> {
    let cli = Cli::command();
    let Some(dir) = args.out else {
        clap_mangen::Man::new(cli).render(&mut std::io::stdout())?;
        return Ok(());
    };
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    clap_mangen::generate_to(cli, &dir)
        .with_context(|| format!("cannot write the man pages into {}", dir.display()))?;
    let mut pages: Vec<String> = std::fs::read_dir(&dir)?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.starts_with("stereolink") && n.ends_with(".1"))
        .collect();
    pages.sort();
    out.emit(
        &serde_json::json!({ "folder": dir, "pages": pages }),
        || format!("{} man pages written to {}\n", pages.len(), dir.display()),
    )
}
