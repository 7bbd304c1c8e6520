//! `--config FILE.toml`: a command's flags kept in a file, for a deployment
//! that runs the same command for months (`gateway` with its 16 stations,
//! `send` and `receive` on a robot).
//!
//! The file has one table per command (`[gateway]`, `[send]`,
//! `[receive]`); its keys are the command's long flag names (`mqtt-ca`, or
//! `mqtt_ca`), its values what the flag takes: a string or a number, `true`
//! for a flag that takes no value, an array for a flag given several times
//! (`link = ["dock-1=udp:…", …]`). A command reads only its own table.
//!
//! The file's flags are put before those of the command line, so that
//! clap checks them as it checks typed ones, and a flag given on the
//! command line replaces the file's (a list as a whole). Every key and value
//! is checked first, so an unknown key or a bad value stops the command
//! with the file, the line and the key. Relative paths are taken from the
//! working directory, as on the command line.

use std::collections::BTreeMap;
use std::ffi::OsString;
use std::path::Path;

use anyhow::{bail, Context};
use clap::{Arg, ArgAction, Command};
use toml::{Spanned, Value};

/// The commands that take `--config`.
pub const COMMANDS: [&str; 3] = ["gateway", "send", "receive"];

/// `--config FILE.toml`, shared by the commands that take it. Read before
/// the arguments are parsed ([`expand`]); the field keeps the file's name.
#[derive(Debug, clap::Args)]
pub struct ConfigArg {
    /// Read this command's flags from the table [COMMAND] of FILE.toml
    /// (keys are the long flag names; an array for a flag given several
    /// times). A flag given on the command line replaces the file's.
    /// Example: deploy/stereolink.toml.
    #[arg(long, value_name = "FILE.toml")]
    pub config: Option<std::path::PathBuf>,
}

/// A table of the file: key → value, with where each stands.
type Table = BTreeMap<Spanned<String>, Spanned<Value>>;

/// The command line with the flags of `--config`'s file put in, or as it
/// was when there is none. `cli` is the whole command-line definition.
pub fn expand(argv: Vec<OsString>, cli: &Command) -> anyhow::Result<Vec<OsString>> {
    let Some(at) = argv
        .iter()
        .skip(1)
        .position(|a| !a.to_string_lossy().starts_with('-'))
        .map(|i| i + 1)
    else {
        return Ok(argv);
    };
    let name = argv[at].to_string_lossy().into_owned();
    let Some(command) = cli
        .find_subcommand(&name)
        .filter(|_| COMMANDS.contains(&name.as_str()))
    else {
        return Ok(argv);
    };
    let Some(path) = config_path(&argv[at + 1..]) else {
        return Ok(argv);
    };
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read the config file {}", path.display()))?;
    let file_args = flags(&text, &path, command, &argv[at + 1..])?;
    let mut out = argv[..=at].to_vec();
    out.extend(file_args);
    out.extend_from_slice(&argv[at + 1..]);
    Ok(out)
}

/// The value of `--config FILE` or `--config=FILE` among a command's
/// arguments.
fn config_path(args: &[OsString]) -> Option<std::path::PathBuf> {
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let a = a.to_string_lossy();
        if a == "--" {
            return None;
        }
        if a == "--config" {
            return it.next().map(Into::into);
        }
        if let Some(v) = a.strip_prefix("--config=") {
            return Some(v.into());
        }
    }
    None
}

/// The flags of `command`'s table in the file `text`, checked, leaving out
/// those that `typed` (the command line) gives itself.
fn flags(
    text: &str,
    path: &Path,
    command: &Command,
    typed: &[OsString],
) -> anyhow::Result<Vec<OsString>> {
    let at = |offset: usize| format!("{}:{}", path.display(), line_of(text, offset));
    let tables: BTreeMap<Spanned<String>, Spanned<Table>> =
        toml::from_str(text).map_err(|e| match e.span() {
            Some(span) => anyhow::anyhow!("{}: {}", at(span.start), e.message().trim_end()),
            None => anyhow::anyhow!("{}: {}", path.display(), e.message().trim_end()),
        })?;
    for name in tables.keys() {
        if !COMMANDS.contains(&name.get_ref().as_str()) {
            bail!(
                "{}: unknown table [{}] (the tables are {})",
                at(name.span().start),
                name.get_ref(),
                COMMANDS.map(|c| format!("[{c}]")).join(", ")
            );
        }
    }
    let Some((_, table)) = tables
        .iter()
        .find(|(name, _)| name.get_ref() == command.get_name())
    else {
        return Ok(Vec::new());
    };
    let mut out = Vec::new();
    for (key, value) in table.get_ref() {
        let where_ = at(key.span().start);
        let long = key.get_ref().replace('_', "-");
        let arg = command
            .get_arguments()
            .find(|a| a.get_long() == Some(long.as_str()) && long != "config")
            .with_context(|| {
                format!(
                    "{where_}: unknown key `{}` for `stereolink {}` (see `stereolink {} --help`)",
                    key.get_ref(),
                    command.get_name(),
                    command.get_name()
                )
            })?;
        let values = values(arg, value.get_ref())
            .map_err(|e| anyhow::anyhow!("{where_}: bad value for `{}`: {e}", key.get_ref()))?;
        for v in &values {
            check(arg, v)
                .map_err(|e| anyhow::anyhow!("{where_}: bad value for `{}`: {e}", key.get_ref()))?;
        }
        if given(arg, typed) {
            continue;
        }
        let flag = OsString::from(format!("--{long}"));
        if takes_no_value(arg) {
            if values.first().is_some_and(|v| v == "true") {
                out.push(flag);
            }
        } else {
            for v in values {
                out.push(flag.clone());
                out.push(v.into());
            }
        }
    }
    Ok(out)
}

/// The flag's values for a TOML value, as they would be typed.
fn values(arg: &Arg, value: &Value) -> Result<Vec<String>, String> {
    let one = |v: &Value| match v {
        Value::String(s) => Ok(s.clone()),
        Value::Integer(i) => Ok(i.to_string()),
        Value::Float(f) => Ok(f.to_string()),
        Value::Boolean(b) => Ok(b.to_string()),
        _ => Err(format!("a {} is not a flag's value", v.type_str())),
    };
    match value {
        Value::Array(items) if repeats(arg) => items.iter().map(one).collect(),
        Value::Array(_) => Err(format!("--{} takes one value, not an array", long(arg))),
        Value::Boolean(_) if takes_no_value(arg) => one(value).map(|v| vec![v]),
        _ if takes_no_value(arg) => Err(format!("--{} is a switch: true or false", long(arg))),
        _ => one(value).map(|v| vec![v]),
    }
}

/// Checks one value as clap will (by its value parser alone, on a command
/// that has only this flag), so that a bad one is named with its line.
fn check(arg: &Arg, value: &str) -> Result<(), String> {
    if takes_no_value(arg) {
        return Ok(());
    }
    let alone = Arg::new("value")
        .value_parser(arg.get_value_parser().clone())
        .allow_hyphen_values(true);
    Command::new("stereolink")
        .no_binary_name(true)
        .arg(alone)
        .try_get_matches_from([value])
        .map(drop)
        .map_err(|e| {
            // "error: invalid value 'x' for '<value>': why" and clap's tips.
            let text = e.to_string().replace(" for '[value]'", "");
            let lines = text.lines().map(str::trim).filter(|l| !l.is_empty());
            let kept: Vec<_> = lines.take_while(|l| !l.starts_with("For more")).collect();
            kept.join(" ").trim_start_matches("error: ").to_string()
        })
}

/// Whether the command line gives this flag itself.
fn given(arg: &Arg, typed: &[OsString]) -> bool {
    let long = format!("--{}", long(arg));
    let short = arg.get_short();
    typed
        .iter()
        .map(|t| t.to_string_lossy())
        .take_while(|t| t != "--")
        .any(|t| {
            t == long
                || t.strip_prefix(&long).is_some_and(|r| r.starts_with('='))
                || short.is_some_and(|s| !t.starts_with("--") && t.starts_with(&format!("-{s}")))
        })
}

fn long(arg: &Arg) -> &str {
    arg.get_long().unwrap_or_default()
}

fn takes_no_value(arg: &Arg) -> bool {
    matches!(arg.get_action(), ArgAction::SetTrue | ArgAction::SetFalse)
}

fn repeats(arg: &Arg) -> bool {
    matches!(arg.get_action(), ArgAction::Append)
}

/// The line (from 1) of a byte offset.
fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}
