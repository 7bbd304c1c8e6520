//! Command-line definitions: one module per command, each with an `Args`
//! (clap derive) and a `run` function.

use clap::{Parser, Subcommand};

pub mod bench;
pub mod calib;
pub mod calibrate;
pub mod camera;
pub mod capture;
pub mod codec;
pub mod demo;
pub mod depth;
pub mod eval;
#[cfg(all(feature = "gateway", not(target_arch = "arm")))]
pub mod gateway;
pub mod info;
pub mod keygen;
pub mod link_test;
pub mod live_bench;
pub mod matching;
pub mod radio;
pub mod receive;
pub mod record;
pub mod rectify;
pub mod report;
pub mod secure_bench;
pub mod segment;
pub mod send;
pub mod service;
pub mod shell;
pub mod stream;
pub mod synth;

/// A progress bar on stderr, hidden when stderr is not a terminal.
pub fn progress(len: u64, what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::with_draw_target(
        Some(len),
        indicatif::ProgressDrawTarget::stderr(),
    );
    bar.set_style(
        indicatif::ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_prefix(what.to_string());
    bar
}

/// Parses a link specification (`serial:`, `udp:`, `sim:`, `fallback:`).
pub fn link_spec(text: &str) -> anyhow::Result<stereolink_link::spec::LinkSpec> {
    text.parse().map_err(|e: String| anyhow::anyhow!("{e}"))
}

/// Opens the links given with `--link`: one, or a bond of several.
pub fn open_links(
    texts: &[String],
) -> anyhow::Result<Box<dyn stereolink_link::transport::Transport>> {
    use anyhow::Context;
    let specs = texts
        .iter()
        .map(|t| link_spec(t))
        .collect::<anyhow::Result<Vec<_>>>()?;
    stereolink_link::spec::open_all(&specs)
        .with_context(|| format!("cannot open link {}", links_name(texts)))
}

/// How the links given with `--link` are named in messages.
pub fn links_name(texts: &[String]) -> String {
    texts.join(" + ")
}

/// The long help of `--link` where it may be repeated.
pub const LINK_HELP: &str = "Link: serial:/dev/ttyUSB0?baud=115200&api=2, \
udp:BIND?peer=ADDR, fallback:A,B.

Give --link several times to bond several radio pairs into one link: packets \
are striped across them, the least loaded pair first, each pair paced by its \
own radio. A pair that fails or falls silent is dropped (said on stderr) and \
what it held is sent again over the others; with every pair down the command \
fails naming them. Both ends give a --link for each pair (in any order).";

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
/// line growing, SGM, segment-based disparity planes), sends it over an
/// XBee/802.15.4 radio (or serial/UDP), and on the receiving board shows a
/// 3-D view and moves a linear axis by the estimated distance.
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
    /// Run the whole system on a synthetic scene over a simulated lossy XBee link.
    Demo(demo::Args),
    /// Describe a stereo scene folder: sizes, disparity range, calibration, ground truth.
    Info(info::Args),
    /// Generate a synthetic stereo scene with exact ground truth.
    Synth(synth::Args),
    /// Segment an image or a stereo pair (k-means, mean shift, PSO, DPSO, FO-DPSO, exact Otsu).
    Segment(segment::Args),
    /// Calibrate a stereo pair of cameras from chessboard image pairs.
    Calibrate(calibrate::Args),
    /// Rectify a raw stereo pair with a stereo calibration YAML.
    Rectify(rectify::Args),
    /// Compute a disparity map (WTA-SAD, line growing, SGM, disparity planes).
    #[command(name = "match")]
    Match(matching::Args),
    /// Turn a disparity map into depth, a point cloud and region distances.
    Depth(depth::Args),
    /// Score matchers against Middlebury ground truth.
    Eval(eval::Args),
    /// Segment and encode a stereo pair into a frame file (or a folder of
    /// pairs into a stream of frame files).
    Encode(codec::Args),
    /// Decode a frame file back into the two views (or a stream's folder
    /// of frame files into its pairs).
    Decode(codec::DecodeArgs),
    /// Send test messages over a link and report goodput, loss and retransmissions.
    LinkTest(link_test::Args),
    /// Ask the local XBee radio what it is: firmware, hardware, API mode, NP, addresses, channel, PAN.
    Radio(radio::Args),
    /// Capture stereo pairs from two cameras (V4L2 or GStreamer sources) into PNG files.
    Capture(capture::Args),
    /// Sender: segment, encode, match and send frames and depth reports.
    Send(Box<send::Args>),
    /// Receiver: rebuild, match, display and drive the axis.
    Receive(receive::Args),
    /// Make a device's key pair for the secure link (NAME.key, NAME.pub).
    Keygen(keygen::Args),
    /// Bridge many stations to an MQTT broker: depth, frames, link stats, availability, commands.
    #[cfg(all(feature = "gateway", not(target_arch = "arm")))]
    Gateway(gateway::Args),
    /// Reproduce the paper's tables on a data folder as an HTML report.
    Report(report::Args),
    /// Time one stage alone (for comparing with other tools in one run).
    #[command(subcommand)]
    Bench(bench::Target),
    /// Print the shell completion script (bash, zsh, fish, elvish, powershell).
    Completions(shell::CompletionArgs),
    /// Print the man page, or write one per command with --out DIR.
    Man(shell::ManArgs),
}

impl Command {
    /// Runs the command.
    pub fn run(self, out: &Output) -> anyhow::Result<()> {
        match self {
            Command::Demo(args) => demo::run(args, out),
            Command::Info(args) => info::run(args, out),
            Command::Synth(args) => synth::run(args, out),
            Command::Segment(args) => segment::run(args, out),
            Command::Calibrate(args) => calibrate::run(args, out),
            Command::Rectify(args) => rectify::run(args, out),
            Command::Match(args) => matching::run(args, out),
            Command::Depth(args) => depth::run(args, out),
            Command::Eval(args) => eval::run(args, out),
            Command::Encode(args) => codec::run(args, out),
            Command::Decode(args) => codec::run_decode(args, out),
            Command::LinkTest(args) => link_test::run(args, out),
            Command::Radio(args) => radio::run(args, out),
            Command::Capture(args) => capture::run(args, out),
            Command::Send(args) => send::run(*args, out),
            Command::Receive(args) => receive::run(args, out),
            Command::Keygen(args) => keygen::run(args, out),
            #[cfg(all(feature = "gateway", not(target_arch = "arm")))]
            Command::Gateway(args) => gateway::run(args, out),
            Command::Report(args) => report::run(args, out),
            Command::Bench(target) => bench::run(target, out),
            Command::Completions(args) => shell::completions(args),
            Command::Man(args) => shell::man(args, out),
        }
    }
}
