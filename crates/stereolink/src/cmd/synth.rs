//! `stereolink synth OUT_DIR`: write a synthetic scene in the shared data layout.

use std::path::PathBuf;

use anyhow::Context;
use serde::Serialize;
use stereolink_image::synth::{synthesize, SynthSpec};

/// Arguments of `stereolink synth`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder to write left.png, right.png, gt_left.pfm, gt_right.pfm, mask_*.png and calib.txt into.
    pub out_dir: PathBuf,
    /// Seed of the scene layout and textures; the same seed gives the same scene.
    #[arg(long, default_value_t = SynthSpec::default().seed)]
    pub seed: u64,
    /// Image width in pixels.
    #[arg(long, default_value_t = SynthSpec::default().width)]
    pub width: usize,
    /// Image height in pixels.
    #[arg(long, default_value_t = SynthSpec::default().height)]
    pub height: usize,
    /// Disparity search range; ground truth lies within 10–95 % of it.
    #[arg(long, default_value_t = SynthSpec::default().max_disp)]
    pub max_disp: usize,
}

#[derive(Serialize)]
struct Written {
    out_dir: PathBuf,
    width: usize,
    height: usize,
    max_disp: usize,
    seed: u64,
    nonocc_fraction: f64,
}

/// Generates the scene and writes it.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let spec = SynthSpec {
        width: args.width,
        height: args.height,
        max_disp: args.max_disp,
        seed: args.seed,
    };
    let scene = synthesize(&spec)?;
    scene
        .save(&args.out_dir)
        .with_context(|| format!("cannot write the scene to {}", args.out_dir.display()))?;
    let nonocc = scene
        .masks
        .nonocc
        .as_ref()
        .expect("synthetic scenes have masks");
    let written = Written {
        out_dir: args.out_dir.clone(),
        width: spec.width,
        height: spec.height,
        max_disp: spec.max_disp,
        seed: spec.seed,
        nonocc_fraction: nonocc.as_slice().iter().filter(|&&b| b).count() as f64
            / nonocc.len() as f64,
    };
    out.emit(&written, || {
        format!(
            "wrote a {}x{} synthetic scene (seed {}, disparities 0..{}) to {}\n",
            spec.width,
            spec.height,
            spec.seed,
            spec.max_disp,
            args.out_dir.display()
        )
    })
}
