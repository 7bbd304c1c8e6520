//! `stereolink info SCENE`: what a scene folder holds.

use std::path::PathBuf;

use anyhow::Context;
use serde::Serialize;
use stereolink_image::{colormap::finite_range, Scene};

/// Arguments of `stereolink info`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Scene folder (stereolink layout, or an original Middlebury 2001/2003/2005/2006/2014 download).
    pub scene: PathBuf,
}

#[derive(Serialize)]
struct Info {
    name: String,
    width: usize,
    height: usize,
    ndisp: usize,
    focal_px: Option<f64>,
    baseline_m: Option<f64>,
    doffs: f64,
    gt_left_range: Option<(f32, f32)>,
    gt_left_known_fraction: Option<f64>,
    gt_right: bool,
    masks: Vec<&'static str>,
}

/// Loads the scene and prints its description.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let scene = Scene::load(&args.scene).context("cannot load the scene")?;
    let gt = scene.gt_left.as_ref();
    let info = Info {
        name: scene.name.clone(),
        width: scene.left.width(),
        height: scene.left.height(),
        ndisp: scene.calib.ndisp,
        focal_px: scene.calib.focal_px,
        baseline_m: scene.calib.baseline_m,
        doffs: scene.calib.doffs,
        gt_left_range: gt.and_then(finite_range),
        gt_left_known_fraction: gt.map(|g| {
            g.as_slice().iter().filter(|d| d.is_finite()).count() as f64 / g.len().max(1) as f64
        }),
        gt_right: scene.gt_right.is_some(),
        masks: [
            ("nonocc", scene.masks.nonocc.is_some()),
            ("all", scene.masks.all.is_some()),
            ("disc", scene.masks.disc.is_some()),
        ]
        .into_iter()
        .filter_map(|(n, present)| present.then_some(n))
        .collect(),
    };
    out.emit(&info, || {
        let opt = |v: Option<f64>, unit: &str| v.map_or("unknown".to_string(), |v| format!("{v} {unit}"));
        format!(
            "scene       {}\nsize        {}x{}\ndisparities 0..{} (ndisp {})\nfocal       {}\nbaseline    {}\ndoffs       {}\n\
             ground truth {}\nmasks       {}\n",
            info.name,
            info.width,
            info.height,
            info.ndisp.saturating_sub(1),
            info.ndisp,
            opt(info.focal_px, "px"),
            opt(info.baseline_m, "m"),
            info.doffs,
            match (info.gt_left_range, info.gt_left_known_fraction) {
                (Some((lo, hi)), Some(f)) => format!(
                    "left {lo:.2}..{hi:.2} px, {:.1} % known{}",
                    f * 100.0,
                    if info.gt_right { "; right view too" } else { "" }
                ),
                _ => "none".into(),
            },
            if info.masks.is_empty() { "none".into() } else { info.masks.join(", ") },
        )
    })
}
