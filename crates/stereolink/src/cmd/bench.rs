//! `stereolink bench`: time one stage alone, images already in memory, after
//! a warm-up; prints the median so a script can compare it with another tool
//! measured in the same run.

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
}

/// Runs the chosen benchmark.
pub fn run(target: Target, out: &super::Output) -> anyhow::Result<()> {
    match target {
        Target::Match(args) => super::matching::run_bench(args, out),
        Target::Segment(args) => super::segment::run_bench(args, out),
        Target::Codec(args) => super::codec::run_bench(args, out),
        Target::Rectify(args) => super::rectify::run_bench(args, out),
        Target::Open(args) => super::secure_bench::run_bench(args, out),
    }
}
