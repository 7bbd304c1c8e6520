//! `--config FILE.toml` (`stereolink::config`): each command takes its own
//! table, the command line wins, and a bad file names the file, the line and
//! the key. Through the library (the arguments parsed, nothing run), and
//! once through the binary.

mod common;

use std::ffi::OsString;

use clap::{CommandFactory, Parser};
use common::stereolink;
use stereolink::cmd::{Cli, Command as Sub};
use stereolink::config::expand;

/// The command line `args` (after the binary) with `toml` as FILE.toml.
fn parse(toml: &str, args: &[&str]) -> anyhow::Result<Cli> {
    let dir = tempfile::tempdir()?;
    let file = dir.path().join("stereolink.toml");
    std::fs::write(&file, toml)?;
    let mut argv: Vec<OsString> = vec!["stereolink".into()];
    argv.extend(
        args.iter()
            .map(|a| a.replace("FILE.toml", file.to_str().unwrap()).into()),
    );
    let argv = expand(argv, &Cli::command())?;
    Ok(Cli::try_parse_from(argv)?)
}

fn receive(cli: Cli) -> stereolink::cmd::receive::Args {
    match cli.command {
        Sub::Receive(args) => args,
        other => panic!("not receive: {other:?}"),
    }
}

#[test]
fn a_command_takes_its_table_and_the_command_line_wins() {
    let toml = "[receive]\nlink = [\"udp:0.0.0.0:9001?peer=10.0.0.2:9000\", \"sim:\"]\n\
                frames = 3\ntimeout-s = 7\nwatchdog_s = 0.25\n\
                [send]\nframes = 9\n";
    let args = receive(parse(toml, &["--json", "receive", "--config", "FILE.toml"]).unwrap());
    assert_eq!(args.link.len(), 2);
    assert_eq!((args.frames, args.timeout_s, args.watchdog_s), (3, 7, 0.25));
    let args = receive(
        parse(
            toml,
            &[
                "receive",
                "--timeout-s=2",
                "--config=FILE.toml",
                "--link",
                "sim:",
            ],
        )
        .unwrap(),
    );
    assert_eq!((args.frames, args.timeout_s), (3, 2));
    assert_eq!(
        args.link,
        ["sim:"],
        "a list on the command line replaces the file's"
    );
}

#[test]
fn unknown_keys_and_bad_values_name_the_file_the_line_and_the_key() {
    let cases = [
        (
            "[receive]\nlink = \"sim:\"\n\nframs = 3\n",
            ":4: unknown key `frams`",
        ),
        (
            "[receive]\nframes = \"many\"\n",
            ":2: bad value for `frames`",
        ),
        ("[receive]\nframes = [1, 2]\n", ":2: bad value for `frames`"),
        ("[receive]\nlink = { a = 1 }\n", ":2: bad value for `link`"),
        (
            "[receive]\nconfig = \"other.toml\"\n",
            ":2: unknown key `config`",
        ),
        ("[recieve]\n", ":1: unknown table [recieve]"),
        ("[receive]\nframes = = 3\n", ":2:"),
    ];
    for (toml, want) in cases {
        let err = parse(toml, &["receive", "--config", "FILE.toml"]).unwrap_err();
        let text = format!("{err:#}");
        assert!(
            text.contains("stereolink.toml") && text.contains(want),
            "{toml:?}: {text}"
        );
    }
}

#[test]
fn commands_without_a_config_file_parse_as_before() {
    let argv: Vec<OsString> = ["stereolink", "receive", "--link", "sim:"]
        .map(Into::into)
        .into();
    assert_eq!(expand(argv.clone(), &Cli::command()).unwrap(), argv);
    let err = parse("", &["receive", "--config", "/nonexistent/x.toml"]).unwrap_err();
    assert!(format!("{err:#}").contains("/nonexistent/x.toml"));
}

#[cfg(all(feature = "gateway", not(target_arch = "arm")))]
#[test]
fn the_shipped_example_configures_16_stations_and_both_ends() {
    let example = concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/stereolink.toml");
    let toml = std::fs::read_to_string(example).unwrap();
    let Sub::Gateway(gw) = parse(&toml, &["gateway", "--config", "FILE.toml"])
        .unwrap()
        .command
    else {
        panic!("not gateway")
    };
    assert_eq!(gw.links.len(), 16);
    assert!(gw.mqtt.starts_with("mqtts://") && gw.mqtt_ca.is_some() && gw.key.is_some());
    let args = receive(parse(&toml, &["receive", "--config", "FILE.toml"]).unwrap());
    assert!(args.keys.key.is_some() && args.watchdog_s > 0.0);
    let send = parse(
        &toml,
        &[
            "send",
            "--config",
            "FILE.toml",
            "--left",
            "l.png",
            "--right",
            "r.png",
        ],
    );
    assert!(matches!(send.unwrap().command, Sub::Send(_)));
}

/// A bad `--config` file is a usage error: exit 2, one line naming the
/// file, the line and the key, before anything is opened.
#[test]
fn a_bad_config_file_is_a_usage_error_naming_file_line_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("robot.toml");
    std::fs::write(&file, "[receive]\nlink = \"sim:\"\nwatchdog-s = \"soon\"\n").unwrap();
    let out = stereolink()
        .args(["receive", "--config"])
        .arg(&file)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8(out.stderr).unwrap();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains("robot.toml:3: bad value for `watchdog-s`"),
        "{err}"
    );
}
