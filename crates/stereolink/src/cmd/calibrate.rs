//! `stereolink calibrate`: chessboard image pairs to a stereo calibration
//! file (OpenCV `FileStorage` YAML), a ROS `camera_info` per camera, and a
//! rectified preview with guide lines to judge it by eye.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{bail, Context};
use rayon::prelude::*;
use serde::Serialize;
use stereolink_calib::chessboard::SubpixOptions;
use stereolink_calib::files::{write_camera_info, write_opencv, Side};
use stereolink_calib::preview::side_by_side_with_guides;
use stereolink_calib::workflow::{
    calibrate_images, CalibrateOptions, CalibrationReport, PairStatus,
};
use stereolink_calib::{BoardSize, Camera, ChessboardOptions, StereoRectifier};
use stereolink_image::{color, io, GrayImage};

/// Guide-line spacing of the preview, in rows.
const GUIDE_ROWS: usize = 32;

/// Arguments of `stereolink calibrate`.
#[derive(Debug, clap::Args)]
#[command(after_long_help = "\
Examples:
  stereolink calibrate --board 9x6 --square 0.025 \\
      --left 'shots/left_*.png' --right 'shots/right_*.png' -o stereo.yml
  stereolink capture --camera-left /dev/video0 --camera-right /dev/video2 --out shots --frames 25 --interval-s 3
  stereolink rectify L.png R.png --calib stereo.yml -o rectified/ --guides

Take 15-30 pairs with the whole board in both views, tilted 20-45° in
several directions and covering the image's corners. The translation T and
the baseline come out in the unit of --square: give it in metres for
distances in metres.")]
pub struct Args {
    /// The board's inner corners, COLSxROWS (a board of 10x7 squares is 9x6).
    #[arg(long)]
    pub board: BoardSize,
    /// The side of one square, in metres (T and the baseline take its unit).
    #[arg(long)]
    pub square: f64,
    /// Left images: a glob pattern in quotes ('shots/left*.jpg') or a list of files.
    #[arg(long, num_args = 1.., required = true)]
    pub left: Vec<String>,
    /// Right images, paired with the left ones in name order.
    #[arg(long, num_args = 1.., required = true)]
    pub right: Vec<String>,
    /// The calibration file to write (OpenCV FileStorage YAML: M1, D1, M2,
    /// D2, R, T, R1, R2, P1, P2, Q). ROS camera_info files NAME-left.yaml and
    /// NAME-right.yaml and the preview NAME-preview.png go beside it.
    #[arg(short, long, value_name = "FILE")]
    pub out: PathBuf,
    /// Rectification's free scaling: 0 crops to pixels valid in both views,
    /// 1 keeps every source pixel (black borders).
    #[arg(long, default_value_t = 0.0)]
    pub alpha: f64,
    /// Leave out the pairs whose reprojection error stands out (named in the
    /// output either way) and calibrate again.
    #[arg(long)]
    pub drop_outliers: bool,
    /// Largest half side of the subpixel refinement's window, pixels
    /// (OpenCV's cornerSubPix winSize); smaller on boards whose squares are
    /// too small for it.
    #[arg(long, default_value_t = SubpixOptions::default().half_window)]
    pub corner_window: usize,
    /// Gaussian smoothing before the refinement's gradients, pixels (0 is
    /// OpenCV's cornerSubPix; the default removes the bias of sharp,
    /// aliased edges).
    #[arg(long, default_value_t = SubpixOptions::default().sigma)]
    pub corner_sigma: f64,
}

#[derive(Serialize)]
struct CameraJson {
    rms_px: f64,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    distortion: [f64; 5],
    std_devs: [f64; 9],
}

#[derive(Serialize)]
struct PairJson {
    left: String,
    right: String,
    status: &'static str,
    reason: Option<String>,
    left_rms_px: Option<f64>,
    right_rms_px: Option<f64>,
    stereo_rms_px: Option<f64>,
}

#[derive(Serialize)]
struct Calibrated {
    board: String,
    square: f64,
    image_width: usize,
    image_height: usize,
    pairs_used: usize,
    pairs_given: usize,
    left: CameraJson,
    right: CameraJson,
    stereo_rms_px: f64,
    translation: [f64; 3],
    baseline: f64,
    rotation_deg: f64,
    rectified_focal_px: f64,
    mean_row_offset_px: f64,
    max_row_offset_px: f64,
    pairs: Vec<PairJson>,
    warnings: Vec<String>,
    files: Vec<PathBuf>,
    seconds: f64,
}

/// The files a pattern or list names, sorted.
fn expand(patterns: &[String], side: &str) -> anyhow::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for p in patterns {
        if Path::new(p).is_file() {
            files.push(PathBuf::from(p));
            continue;
        }
        let matches =
            glob::glob(p).with_context(|| format!("--{side} {p:?} is not a valid glob pattern"))?;
        let before = files.len();
        files.extend(matches.filter_map(|m| m.ok()).filter(|m| m.is_file()));
        if files.len() == before {
            bail!("--{side} {p:?} matches no file");
        }
    }
    files.sort();
    Ok(files)
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.display().to_string())
}

fn camera_json(c: &Camera, rms: f64, std_devs: [f64; 9]) -> CameraJson {
    CameraJson {
        rms_px: rms,
        fx: c.fx,
        fy: c.fy,
        cx: c.cx,
        cy: c.cy,
        distortion: c.distortion.to_array(),
        std_devs,
    }
}

/// `out` with its extension replaced by `suffix` (`stereo.yml` → `stereo-left.yaml`).
fn beside(out: &Path, suffix: &str) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "stereo".into());
    out.with_file_name(format!("{stem}{suffix}"))
}

/// Calibrates and writes the files.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let start = Instant::now();
    let left = expand(&args.left, "left")?;
    let right = expand(&args.right, "right")?;
    if left.len() != right.len() {
        bail!(
            "{} left images but {} right images: each left image needs the right image taken with it",
            left.len(),
            right.len()
        );
    }
    let bar = super::progress(2 * left.len() as u64, "chessboards");
    let pairs: Vec<(GrayImage, GrayImage)> = left
        .par_iter()
        .zip(right.par_iter())
        .map(|(l, r)| Ok((io::read_gray(l)?, io::read_gray(r)?)))
        .collect::<anyhow::Result<_>>()?;
    let names: Vec<String> = left
        .iter()
        .zip(&right)
        .map(|(l, r)| format!("{} + {}", file_name(l), file_name(r)))
        .collect();
    let searched = AtomicUsize::new(0);
    let options = CalibrateOptions {
        board: args.board,
        square: args.square,
        alpha: args.alpha,
        drop_outliers: args.drop_outliers,
        chessboard: ChessboardOptions {
            subpix: SubpixOptions {
                half_window: args.corner_window,
                sigma: args.corner_sigma,
                ..SubpixOptions::default()
            },
            ..ChessboardOptions::default()
        },
    };
    let report = calibrate_images(&pairs, &names, &options, &|| {
        bar.set_position(searched.fetch_add(1, Ordering::Relaxed) as u64 + 1);
    })?;
    bar.finish_and_clear();

    let calib = report.calibration;
    write_opencv(&args.out, &calib)?;
    let mut files = vec![args.out.clone()];
    for (side, suffix) in [(Side::Left, "-left.yaml"), (Side::Right, "-right.yaml")] {
        let path = beside(&args.out, suffix);
        write_camera_info(&path, &calib, side)?;
        files.push(path);
    }
    let preview = beside(&args.out, "-preview.png");
    write_preview(&report, &pairs, &preview)?;
    files.push(preview);

    let summary = summarise(
        &args,
        &report,
        &left,
        &right,
        files,
        start.elapsed().as_secs_f64(),
    );
    out.emit(&summary, || human(&summary))
}

/// The first pair used, rectified side by side with guide lines.
fn write_preview(
    report: &CalibrationReport,
    pairs: &[(GrayImage, GrayImage)],
    path: &Path,
) -> anyhow::Result<()> {
    let first = report
        .pairs
        .iter()
        .position(|p| p.status == PairStatus::Used)
        .unwrap_or(0);
    let rectifier = StereoRectifier::new(&report.calibration)?;
    let (l, r) = &pairs[first];
    let (l, r) = rectifier.rectify(&color::gray_to_rgb(l), &color::gray_to_rgb(r))?;
    io::write_rgb(path, &side_by_side_with_guides(&l, &r, GUIDE_ROWS))?;
    Ok(())
}

fn summarise(
    args: &Args,
    report: &CalibrationReport,
    left: &[PathBuf],
    right: &[PathBuf],
    files: Vec<PathBuf>,
    seconds: f64,
) -> Calibrated {
    let fit = &report.fit;
    let rig = &report.calibration.rig;
    let pairs: Vec<PairJson> = report
        .pairs
        .iter()
        .zip(left.iter().zip(right))
        .map(|(p, (l, r))| {
            let (status, reason) = match &p.status {
                PairStatus::Used => ("used", None),
                PairStatus::Outlier { dropped: true } => ("outlier, dropped", None),
                PairStatus::Outlier { dropped: false } => ("outlier, kept", None),
                PairStatus::NoBoard { left, right } => {
                    let why = |side: &str, r: &Option<stereolink_calib::NotFound>| {
                        r.map(|r| format!("{side}: {r}"))
                    };
                    let reasons: Vec<String> = [why("left", left), why("right", right)]
                        .into_iter()
                        .flatten()
                        .collect();
                    ("no board", Some(reasons.join("; ")))
                }
            };
            PairJson {
                left: file_name(l),
                right: file_name(r),
                status,
                reason,
                left_rms_px: p.left_rms,
                right_rms_px: p.right_rms,
                stereo_rms_px: p.stereo_rms,
            }
        })
        .collect();
    let mut warnings = fit.left.warnings.clone();
    warnings.extend(fit.right.warnings.iter().cloned());
    warnings.extend(fit.warnings.iter().cloned());
    warnings.sort();
    warnings.dedup();
    let t = rig.translation;
    Calibrated {
        board: args.board.to_string(),
        square: args.square,
        image_width: rig.left.width,
        image_height: rig.left.height,
        pairs_used: report
            .pairs
            .iter()
            .filter(|p| p.stereo_rms.is_some())
            .count(),
        pairs_given: report.pairs.len(),
        left: camera_json(&rig.left, fit.left.rms, fit.left.std_devs),
        right: camera_json(&rig.right, fit.right.rms, fit.right.std_devs),
        stereo_rms_px: fit.rms,
        translation: [t.x, t.y, t.z],
        baseline: rig.baseline(),
        rotation_deg: nalgebra::Rotation3::from_matrix(&rig.rotation)
            .angle()
            .to_degrees(),
        rectified_focal_px: report.calibration.rectification.p1[(0, 0)],
        mean_row_offset_px: report.mean_row_offset,
        max_row_offset_px: report.max_row_offset,
        pairs,
        warnings,
        files,
        seconds,
    }
}

fn human(s: &Calibrated) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "calibrated from {} of {} pairs ({} board, square {}, {}x{} images) in {:.2} s",
        s.pairs_used, s.pairs_given, s.board, s.square, s.image_width, s.image_height, s.seconds
    );
    let _ = writeln!(
        o,
        "camera  RMS px       fx       fy       cx       cy  k1, k2, p1, p2, k3"
    );
    for (name, c) in [("left", &s.left), ("right", &s.right)] {
        let d = c.distortion;
        let _ = writeln!(
            o,
            "{name:<6} {:>7.4} {:>8.2} {:>8.2} {:>8.2} {:>8.2}  {:.4}, {:.4}, {:.5}, {:.5}, {:.4}",
            c.rms_px, c.fx, c.fy, c.cx, c.cy, d[0], d[1], d[2], d[3], d[4]
        );
    }
    let _ = writeln!(
        o,
        "stereo RMS {:.4} px; baseline {:.5} (T = {:.5}, {:.5}, {:.5}), cameras turned {:.2}° apart",
        s.stereo_rms_px, s.baseline, s.translation[0], s.translation[1], s.translation[2], s.rotation_deg
    );
    let _ = writeln!(
        o,
        "rectified: focal {:.2} px; rows of corresponding corners differ by {:.3} px on average, {:.3} px at most",
        s.rectified_focal_px, s.mean_row_offset_px, s.max_row_offset_px
    );
    let _ = writeln!(
        o,
        "pair                                  left px  right px  stereo px  status"
    );
    let fmt = |v: Option<f64>| v.map(|v| format!("{v:.4}")).unwrap_or_else(|| "-".into());
    for p in &s.pairs {
        let name = format!("{} + {}", p.left, p.right);
        let _ = writeln!(
            o,
            "{name:<37} {:>8} {:>9} {:>10}  {}{}",
            fmt(p.left_rms_px),
            fmt(p.right_rms_px),
            fmt(p.stereo_rms_px),
            p.status,
            p.reason
                .as_ref()
                .map(|r| format!(" ({r})"))
                .unwrap_or_default()
        );
    }
    for w in &s.warnings {
        let _ = writeln!(o, "warning: {w}");
    }
    let files: Vec<String> = s.files.iter().map(|f| f.display().to_string()).collect();
    let _ = write!(o, "wrote {}", files.join(", "));
    o
}
