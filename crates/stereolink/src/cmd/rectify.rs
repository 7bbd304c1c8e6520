//! `stereolink rectify` and `stereolink bench rectify`: a raw pair through
//! the rectification maps of a stereo calibration YAML.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;
use stereolink_calib::files::{self, Side};
use stereolink_calib::preview::side_by_side_with_guides;
use stereolink_calib::StereoRectifier;
use stereolink_image::{io, Plane};
use stereolink_pipeline::sensor::{depth_of_rectified, read_stereo_yaml};

use super::calib::metres_per_unit;

/// Guide-line spacing of the preview, in rows.
const GUIDE_ROWS: usize = 32;

/// Arguments of `stereolink rectify`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Raw left image.
    pub left: PathBuf,
    /// Raw right image.
    pub right: PathBuf,
    /// Stereo calibration YAML (OpenCV FileStorage with M1, D1, M2, D2, R,
    /// T, R1, R2, P1, P2, Q, image_width and image_height).
    #[arg(long, value_name = "FILE")]
    pub calib: PathBuf,
    /// Unit of the calibration's T, the chessboard square's: m, cm or mm.
    #[arg(long, default_value = "m", value_parser = ["m", "cm", "mm"])]
    pub calib_units: String,
    /// Output folder: left.png, right.png and calib.txt (Middlebury, depth
    /// from P1/P2), a scene folder that match, eval and demo --scene read.
    #[arg(short, long, value_name = "DIR")]
    pub out: PathBuf,
    /// Disparity range written to calib.txt (default: a quarter of the width).
    #[arg(long)]
    pub ndisp: Option<usize>,
    /// Also write preview.png: the rectified pair side by side with a
    /// horizontal guide line every 32 rows, to judge the calibration by eye.
    #[arg(long)]
    pub guides: bool,
    /// Also write the calibration as stereolink writes it: stereo.yml
    /// (OpenCV FileStorage) and left.yaml, right.yaml (ROS camera_info).
    #[arg(long)]
    pub export: bool,
}

#[derive(Serialize)]
struct Rectified {
    out: PathBuf,
    width: usize,
    height: usize,
    focal_px: f64,
    baseline_m: f64,
    doffs: f64,
    maps_ms: f64,
    rectify_ms: f64,
    files: Vec<String>,
}

/// Rectifies the pair into the output folder.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let calib = read_stereo_yaml(&args.calib)?;
    let t = Instant::now();
    let rectifier = StereoRectifier::new(&calib).with_context(|| {
        format!(
            "cannot build rectification maps from {}",
            args.calib.display()
        )
    })?;
    let maps_ms = t.elapsed().as_secs_f64() * 1e3;
    let left = io::read_rgb(&args.left)?;
    let right = io::read_rgb(&args.right)?;
    let t = Instant::now();
    let (left, right) = rectifier.rectify(&left, &right).with_context(|| {
        format!(
            "cannot rectify {} and {} with {}",
            args.left.display(),
            args.right.display(),
            args.calib.display()
        )
    })?;
    let rectify_ms = t.elapsed().as_secs_f64() * 1e3;
    let (width, height) = left.dims();
    let depth = depth_of_rectified(
        &calib,
        metres_per_unit(&args.calib_units),
        args.ndisp.unwrap_or(width / 4).max(1),
        &args.calib,
    )?;
    let dir = &args.out;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut written = vec!["left.png", "right.png", "calib.txt"];
    io::write_rgb(dir.join("left.png"), &left)?;
    io::write_rgb(dir.join("right.png"), &right)?;
    let calib_txt = dir.join("calib.txt");
    std::fs::write(&calib_txt, depth.to_middlebury(width, height))
        .with_context(|| format!("cannot write {}", calib_txt.display()))?;
    if args.guides {
        io::write_rgb(
            dir.join("preview.png"),
            &side_by_side_with_guides(&left, &right, GUIDE_ROWS),
        )?;
        written.push("preview.png");
    }
    if args.export {
        files::write_opencv(&dir.join("stereo.yml"), &calib)?;
        files::write_camera_info(&dir.join("left.yaml"), &calib, Side::Left)?;
        files::write_camera_info(&dir.join("right.yaml"), &calib, Side::Right)?;
        written.extend(["stereo.yml", "left.yaml", "right.yaml"]);
    }
    let r = Rectified {
        out: dir.clone(),
        width,
        height,
        focal_px: depth.focal_px.unwrap_or(0.0),
        baseline_m: depth.baseline_m.unwrap_or(0.0),
        doffs: depth.doffs,
        maps_ms,
        rectify_ms,
        files: written.iter().map(|f| f.to_string()).collect(),
    };
    out.emit(&r, || {
        format!(
            "rectified {}x{} pair written to {} ({}); maps {:.1} ms, rectify {:.2} ms\n\
             depth from P1/P2: f {:.2} px, baseline {:.4} m, doffs {:.2} px\n",
            r.width,
            r.height,
            r.out.display(),
            r.files.join(", "),
            r.maps_ms,
            r.rectify_ms,
            r.focal_px,
            r.baseline_m,
            r.doffs
        )
    })
}

/// Arguments of `stereolink bench rectify`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Stereo calibration YAML.
    #[arg(long, value_name = "FILE")]
    pub calib: PathBuf,
    /// Raw left image.
    #[arg(long)]
    pub left: PathBuf,
    /// Raw right image.
    #[arg(long)]
    pub right: PathBuf,
    /// Timed runs after one warm-up run, for gray and for RGB.
    #[arg(long, default_value_t = 100)]
    pub iters: usize,
    /// Worker threads (the two views run in parallel with 2 or more).
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
}

#[derive(Serialize)]
struct Bench {
    width: usize,
    height: usize,
    threads: usize,
    iters: usize,
    maps_ms: f64,
    gray_median_ms: f64,
    gray_min_ms: f64,
    rgb_median_ms: f64,
    rgb_min_ms: f64,
}

/// Median and minimum of `iters` timed pair rectifications into reused
/// buffers, after a warm-up.
fn time_pair<P: stereolink_calib::remap::Pixel>(
    rectifier: &StereoRectifier,
    left: &Plane<P>,
    right: &Plane<P>,
    iters: usize,
) -> anyhow::Result<(f64, f64)> {
    let (mut a, mut b) = (Plane::default(), Plane::default());
    rectifier.rectify_into(left, right, &mut a, &mut b)?;
    let mut times = Vec::with_capacity(iters);
    for _ in 0..iters.max(1) {
        let t = Instant::now();
        rectifier.rectify_into(left, right, &mut a, &mut b)?;
        std::hint::black_box((&a, &b));
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    Ok((times[times.len() / 2], times[0]))
}

/// Times the rectification of a pair (maps built once, images in memory).
pub fn run_bench(args: BenchArgs, out: &super::Output) -> anyhow::Result<()> {
    let calib = read_stereo_yaml(&args.calib)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads.max(1))
        .build()?;
    let t = Instant::now();
    let rectifier = StereoRectifier::new(&calib)?;
    let maps_ms = t.elapsed().as_secs_f64() * 1e3;
    let (gl, gr) = (io::read_gray(&args.left)?, io::read_gray(&args.right)?);
    let (cl, cr) = (io::read_rgb(&args.left)?, io::read_rgb(&args.right)?);
    let (gray, rgb) = pool.install(|| -> anyhow::Result<_> {
        Ok((
            time_pair(&rectifier, &gl, &gr, args.iters)?,
            time_pair(&rectifier, &cl, &cr, args.iters)?,
        ))
    })?;
    let (width, height) = rectifier.left.size();
    let b = Bench {
        width,
        height,
        threads: pool.current_num_threads(),
        iters: args.iters.max(1),
        maps_ms,
        gray_median_ms: gray.0,
        gray_min_ms: gray.1,
        rgb_median_ms: rgb.0,
        rgb_min_ms: rgb.1,
    };
    out.emit(&b, || {
        format!(
            "rectify {}x{} pair ({} threads, {} runs): gray median {:.3} ms (min {:.3}), \
             RGB median {:.3} ms (min {:.3}); maps built once in {:.1} ms\n",
            b.width,
            b.height,
            b.threads,
            b.iters,
            b.gray_median_ms,
            b.gray_min_ms,
            b.rgb_median_ms,
            b.rgb_min_ms,
            b.maps_ms
        )
    })
}
