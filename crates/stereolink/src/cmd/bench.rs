//! `stereolink bench`: time one stage alone, images already in memory, after
//! a warm-up; prints the median so a script can compare it with another tool
//! measured in the same run. `bench live` instead runs the whole live chain
//! on a recorded sequence.

use clap::Subcommand;

/// What to benchmark.
#[derive(Debug, Subcommand)]
pub enum Target {
    /// Time a stereo matcher (JSON key `median_ms`).
    Match(super::matching::BenchArgs),
    /// Time a segmentation method (JSON keys `median_ms`, fitness).
    Segment(super::segment::BenchArgs),
    /// Time the codec (JSON keys `encode_ms`, `decode_ms`, bytes per view).
    Codec(super::codec::BenchArgs),
    /// Time the rectification of a raw pair (JSON keys `gray_median_ms`,
    /// `rgb_median_ms`).
    Rectify(super::rectify::BenchArgs),
    /// Verify and decrypt a sealed frame, as the board does (JSON key `median_ms`).
    Open(super::secure_bench::BenchArgs),
    /// Play a recorded sequence through the sender, the simulated radio and
    /// the board in real time (JSON keys `sender`, `receiver`: reports and
    /// frames a second, report latency p50/p99, bytes).
    Live(Box<super::live_bench::Args>),
}

/// Runs the chosen benchmark.
pub fn run(target: Target, out: &super::Output) -> anyhow::Result<()> {
    match target {
        Target::Match(args) => super::matching::run_bench(args, out),
        Target::Segment(args) => super::segment::run_bench(args, out),
        Target::Codec(args) => super::codec::run_bench(args, out),
        Target::Rectify(args) => super::rectify::run_bench(args, out),
        Target::Open(args) => super::secure_bench::run_bench(args, out),
        Target::Live(args) => super::live_bench::run(*args, out),
    }
}
