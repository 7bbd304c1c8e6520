//! `stereolink match` and `stereolink bench match`: disparity maps from a pair.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;
use stereolink_image::{colormap, io, pfm, Scene};
use stereolink_pipeline::planes::{disparity, Segments};
use stereolink_pipeline::sender::default_roi;
use stereolink_stereo::depth::region_distance;
use stereolink_stereo::refine::{HoleFill, WeightedMedian};
use stereolink_stereo::ripple::RippleFilter;
use stereolink_stereo::{Algorithm, MatchSpec, Matcher, Refinement};

use super::calib::CalibArgs;

/// Matcher options shared by `match`, `eval` and `bench match`.
#[derive(Debug, Clone, clap::Args)]
pub struct MatcherArgs {
    /// Algorithm: wta (SAD winner-take-all), lg (line growing), sgm
    /// (semi-global) or planes (segment-based: a disparity plane per
    /// segment of the left view, fitted to SGM's LR-checked pixels and
    /// assigned by greedy energy moves over the segment graph).
    #[arg(long, default_value = "sgm", value_parser = parse_algorithm)]
    pub algo: Algorithm,
    /// Window size for wta and lg (odd, 1–15; for wta at most 11 with
    /// 9-bit gray, 7 with 10-bit); default 11 for wta, 5 for lg.
    #[arg(long)]
    pub block: Option<usize>,
    /// WTA gray precision in bits (8–10; default 9).
    #[arg(long)]
    pub gray_bits: Option<u32>,
    /// WTA min filter over the window sums (shiftable windows, as in
    /// SSD+MF), odd side, 0 disables (default 0).
    #[arg(long)]
    pub min_filter: Option<usize>,
    /// Raw matcher output: no LR check, subpixel, median or hole filling.
    #[arg(long)]
    pub raw: bool,
    /// LR-check tolerance in px (0 disables; default 0.5 for wta, 1 for sgm).
    #[arg(long)]
    pub lr_check: Option<f32>,
    /// Median filter size (0 disables; default 5 for sgm, 3 for lg, 0 for
    /// wta, which has the weighted median).
    #[arg(long)]
    pub median: Option<usize>,
    /// Colour-weighted median guided by the left view, radius in pixels; it
    /// runs before and after the fill and replaces the plain median unless
    /// --median is given too. Before the fill it takes 9 samples of a
    /// window half again as wide. Default 6 for wta (`0 --median 5` is a
    /// little faster and less accurate; see docs/tuning.md), 2 for planes
    /// (once, every pixel, reach 250), off (0) for lg and sgm.
    #[arg(long, value_name = "RADIUS")]
    pub weighted_median: Option<usize>,
    /// Colour reach of the weighted median: the summed RGB difference at
    /// which a neighbour's weight falls to zero (1–255; default 150, 250 for
    /// planes).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..))]
    pub wm_reach: Option<u8>,
    /// Sampling step inside the weighted median's window (default 3, 1 for
    /// planes; before the fill, the window's radius).
    #[arg(long)]
    pub wm_step: Option<usize>,
    /// Subpixel parabola fit through the winner's neighbouring costs
    /// (default: off for match, eval and bench, where it raises the bad > 1
    /// px rate; on for the depth report of send and demo).
    #[arg(long, value_name = "BOOL")]
    pub subpixel: Option<bool>,
    /// Leave invalid pixels invalid instead of filling them.
    #[arg(long, conflicts_with = "fill")]
    pub no_fill: bool,
    /// Hole filling: `directions` (median of the nearest valid disparities
    /// in 8 directions; default for wta and sgm) or `row` (the background
    /// end of each invalid run; default for lg).
    #[arg(long, value_name = "MODE")]
    pub fill: Option<HoleFill>,
    /// SGM penalty P1.
    #[arg(long)]
    pub p1: Option<u16>,
    /// SGM base penalty P2.
    #[arg(long)]
    pub p2: Option<u16>,
    /// SGM paths: 4 or 8 (default 8; 4 for the initial map of planes,
    /// which scores better there).
    #[arg(long)]
    pub paths: Option<u8>,
    /// Line-growing threshold on the averaged error energy.
    #[arg(long)]
    pub lg_threshold: Option<f32>,
    /// Line-growing passes of the averaging filter (eq. 16).
    #[arg(long)]
    pub lg_passes: Option<usize>,
    /// Planes: the segments are the connected components of this method's
    /// label map (kmeans, meanshift, otsu, pso, dpso, fodpso) instead of the
    /// default mean shift over-segmentation (h_s 4, h_r 5). `send` always
    /// uses the transmitted left labels.
    #[arg(long, value_name = "METHOD")]
    pub segments: Option<String>,
    /// Planes: levels (classes) of --segments (default 3).
    #[arg(long, default_value_t = 3)]
    pub segment_levels: usize,
    /// Planes: smoothness λ per unit of boundary between segments on
    /// different planes, where both sides have the same colour (default
    /// 192).
    #[arg(long)]
    pub plane_smoothness: Option<f32>,
    /// Planes: colour contrast σ of the smoothness term. A pair of
    /// neighbours across a boundary weighs exp(-Δ/σ), Δ their summed
    /// absolute RGB difference, so that cuts along colour edges are cheap
    /// (default 5; `inf`: every pair weighs 1).
    #[arg(long, value_name = "SIGMA")]
    pub plane_contrast: Option<f32>,
    /// Planes: segments that share a plane and whose boundaries weigh at
    /// least this per unit under --plane-contrast (an even colour across
    /// them) also move together to a neighbour's plane (default 0.1; `inf`:
    /// one segment at a time).
    #[arg(long, value_name = "WEIGHT")]
    pub plane_coupling: Option<f32>,
    /// Planes: truncation of the per-pixel matching cost (census Hamming
    /// bits plus the weighted grey difference), which bounds what an
    /// occluded pixel costs (default 24).
    #[arg(long)]
    pub plane_truncation: Option<f32>,
    /// Planes: weight of the absolute grey difference beside census in the
    /// data term, per grey level, capped at 20 levels (default 1; 0: census
    /// alone).
    #[arg(long)]
    pub plane_intensity: Option<f32>,
    /// Planes: cut segments into tiles of this side (px; default 48, 0
    /// keeps them whole), so that a segment spanning several depths gets
    /// several planes.
    #[arg(long)]
    pub plane_tile: Option<usize>,
    /// Planes: pixels within this distance (px) of another segment choose
    /// among the nearby segments' planes by an adaptive-support cost over
    /// a 17×17 window, weighted by colour likeness in both views (default
    /// 5, at most 8; 0 keeps each segment's plane).
    #[arg(long, value_name = "RADIUS")]
    pub plane_boundary: Option<usize>,
    /// Planes: the census window of that adaptive-support cost, odd sides
    /// up to 9x7 (default 5x3: a narrow window reaches less far across a
    /// depth edge than the 9x7 of the segments' data term).
    #[arg(long, value_name = "WxH", value_parser = parse_census_window)]
    pub plane_boundary_census: Option<[usize; 2]>,
    /// Planes: weight of each census comparison in that cost (default 4,
    /// for the 14 comparisons of 5x3; the data term's 9x7 weighs 1 each).
    #[arg(long, value_name = "WEIGHT")]
    pub plane_boundary_census_weight: Option<f32>,
    /// Planes: a segment whose plane misses more than this fraction of its
    /// reliable pixels by over 1 px is cut by tiles of half the side and
    /// fitted again (0–1, default 0.5; 0: never).
    #[arg(long, value_name = "FRACTION")]
    pub plane_split: Option<f32>,
    /// Planes: rounds of refitting each plane over all the segments that
    /// took it, and assigning again (default 2).
    #[arg(long, value_name = "ROUNDS")]
    pub plane_refits: Option<usize>,
    /// SGM and planes: take a camera's period-2 column ripple out of both
    /// grey views first, with a two-tap average along rows. `auto` does so
    /// when the left view's second differences alternate in sign along
    /// rows far more often than along columns (of the 20 shared
    /// Middlebury scenes, only Tsukuba; see docs/tuning.md).
    #[arg(long, default_value = "auto", value_parser = parse_ripple)]
    pub ripple: RippleFilter,
}

/// `WxH` (as `5x3`) to `[W, H]`; the matcher checks the sides.
fn parse_census_window(s: &str) -> Result<[usize; 2], String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("census window {s:?} is not WxH, as 5x3"))?;
    let side = |v: &str| {
        v.trim()
            .parse::<usize>()
            .map_err(|_| format!("census window {s:?} is not WxH, as 5x3"))
    };
    Ok([side(w)?, side(h)?])
}

fn parse_ripple(s: &str) -> Result<RippleFilter, String> {
    match s {
        "auto" => Ok(RippleFilter::Auto),
        "on" => Ok(RippleFilter::On),
        "off" => Ok(RippleFilter::Off),
        _ => Err(format!("unknown ripple filter `{s}`: use auto, on or off")),
    }
}

fn parse_algorithm(s: &str) -> Result<Algorithm, String> {
    s.parse()
        .map_err(|e: stereolink_stereo::StereoError| e.to_string())
}

impl MatcherArgs {
    /// Where the plane matcher's segments come from (seed 1 for the
    /// stochastic methods).
    pub fn segments(&self) -> anyhow::Result<Segments> {
        Ok(match &self.segments {
            None => Segments::OverSegmentation,
            Some(m) => Segments::Method(m.parse()?, self.segment_levels, 1),
        })
    }

    /// [`Self::spec`] for a depth report: the subpixel fit on unless
    /// `--subpixel false`, so that distances are not rounded to whole
    /// disparities.
    pub fn depth_spec(&self, min_disp: usize, max_disp: usize) -> anyhow::Result<MatchSpec> {
        let mut spec = self.spec(min_disp, max_disp)?;
        spec.refine.subpixel = self
            .subpixel
            .unwrap_or(spec.algorithm != Algorithm::LineGrowing);
        Ok(spec)
    }

    /// The validated spec for a disparity range.
    pub fn spec(&self, min_disp: usize, max_disp: usize) -> anyhow::Result<MatchSpec> {
        let mut spec = MatchSpec::new(self.algo, min_disp, max_disp)?;
        if let Some(b) = self.block {
            spec.block = b;
        }
        if self.raw {
            spec.refine = Refinement::NONE;
        }
        if let Some(t) = self.lr_check {
            spec.refine.lr_check = (t > 0.0).then_some(t);
        }
        if let Some(m) = self.median {
            spec.refine.median = m;
        }
        if let Some(s) = self.subpixel {
            spec.refine.subpixel = s;
        }
        spec.gray_bits = self.gray_bits.unwrap_or(spec.gray_bits);
        spec.min_filter = self.min_filter.unwrap_or(spec.min_filter);
        if let Some(radius) = self.weighted_median {
            if radius > 0 && self.median.is_none() {
                spec.refine.median = 0;
            }
            spec.refine.weighted_median = (radius > 0).then(|| WeightedMedian {
                radius,
                ..spec
                    .refine
                    .weighted_median
                    .unwrap_or(WeightedMedian::DEFAULT)
            });
        }
        if let Some(wm) = spec.refine.weighted_median.as_mut() {
            wm.color_reach = self.wm_reach.unwrap_or(wm.color_reach);
            wm.step = self.wm_step.unwrap_or(wm.step);
        }
        if let Some(f) = self.fill {
            spec.refine.fill = Some(f);
        }
        if self.no_fill {
            spec.refine.fill = None;
        }
        spec.sgm.p1 = self.p1.unwrap_or(spec.sgm.p1);
        spec.sgm.p2 = self.p2.unwrap_or(spec.sgm.p2);
        spec.sgm.paths = self.paths.unwrap_or(spec.sgm.paths);
        spec.line_growing.threshold = self.lg_threshold.unwrap_or(spec.line_growing.threshold);
        spec.line_growing.passes = self.lg_passes.unwrap_or(spec.line_growing.passes);
        spec.planes.smoothness = self.plane_smoothness.unwrap_or(spec.planes.smoothness);
        spec.planes.contrast = self.plane_contrast.unwrap_or(spec.planes.contrast);
        spec.planes.coupling = self.plane_coupling.unwrap_or(spec.planes.coupling);
        spec.planes.truncation = self.plane_truncation.unwrap_or(spec.planes.truncation);
        spec.planes.intensity = self.plane_intensity.unwrap_or(spec.planes.intensity);
        spec.planes.tile = self.plane_tile.unwrap_or(spec.planes.tile);
        let boundary = &mut spec.planes.boundary;
        boundary.radius = self.plane_boundary.unwrap_or(boundary.radius);
        boundary.census = self.plane_boundary_census.unwrap_or(boundary.census);
        boundary.census_weight = self
            .plane_boundary_census_weight
            .unwrap_or(boundary.census_weight);
        spec.planes.split = self.plane_split.unwrap_or(spec.planes.split);
        spec.planes.refits = self.plane_refits.unwrap_or(spec.planes.refits);
        spec.ripple = self.ripple;
        Ok(spec)
    }
}

/// Arguments of `stereolink match`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Left (reference) image.
    pub left: PathBuf,
    /// Right image.
    pub right: PathBuf,
    /// Output disparity map (PFM, `inf` = invalid).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Largest disparity searched. Without it: the range the left image's
    /// scene folder states (its `calib.txt` `ndisp`, or its entry in the
    /// folder's `../manifest.json`), less one; otherwise OpenCV's sample
    /// default, a sixteenth multiple of about an eighth of the width, less
    /// one. `match` says which it used.
    #[arg(long)]
    pub max_disp: Option<usize>,
    /// Smallest disparity searched.
    #[arg(long, default_value_t = 0)]
    pub min_disp: usize,
    /// Also write a colour-mapped PNG with a colour bar.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Focal length, baseline and doffs for the distance of the central
    /// region; with a stereo calibration YAML (`--calib stereo.yml`) the
    /// raw pair is rectified first and depth comes from P1/P2.
    #[command(flatten)]
    /// The rig's calibration: focal length, baseline and doffs, or a stereo calibration file.
    pub calib: CalibArgs,
    #[command(flatten)]
    /// The matcher and its parameters.
    pub matcher: MatcherArgs,
}

#[derive(Serialize)]
struct Matched {
    output: PathBuf,
    algorithm: Algorithm,
    /// The largest disparity searched, and where it came from.
    max_disp: usize,
    max_disp_from: String,
    width: usize,
    height: usize,
    time_ms: f64,
    valid_fraction: f64,
    rectified: bool,
    focal_px: Option<f64>,
    baseline_m: Option<f64>,
    doffs: f64,
    /// Distance of the central ninth (median disparity), when calibrated.
    distance_m: Option<f64>,
}

/// The largest disparity to search: `--max-disp`, the range the left
/// image's scene folder states, or a default for a `width` px view; and
/// where it came from.
fn max_disparity(args: &Args, width: usize) -> (usize, String) {
    if let Some(d) = args.max_disp {
        return (d, "--max-disp".into());
    }
    let folder = args.left.parent().unwrap_or(std::path::Path::new("."));
    match stereolink_image::scene::stated_ndisp(folder) {
        Some((n, from)) => (
            n.saturating_sub(1),
            format!("ndisp {n} of {}", from.display()),
        ),
        None => {
            let n = ((width / 8).div_ceil(16) * 16).max(16);
            (
                n - 1,
                format!("no range stated beside the images: {n} levels for {width} px"),
            )
        }
    }
}

/// Matches a pair and writes the disparity map.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let (left, right) = (io::read_rgb(&args.left)?, io::read_rgb(&args.right)?);
    let (max_disp, range_from) = max_disparity(&args, left.width());
    if args.max_disp.is_none() {
        eprintln!("disparities {}..={max_disp} ({range_from})", args.min_disp);
    }
    let sensor = args.calib.sensor(max_disp + 1)?;
    if let Some(w) = sensor.range_warning() {
        eprintln!("warning: {w}");
    }
    let (left, right) = sensor.rectify(
        left,
        right,
        &format!("{} and {}", args.left.display(), args.right.display()),
    )?;
    let spec = args.matcher.spec(args.min_disp, max_disp)?;
    let segments = args.matcher.segments()?;
    let start = Instant::now();
    let disp =
        disparity(&mut Matcher::new(), (&left, &right), &spec, &segments).with_context(|| {
            format!(
                "cannot match {} against {}",
                args.left.display(),
                args.right.display()
            )
        })?;
    let time_ms = start.elapsed().as_secs_f64() * 1e3;
    pfm::write(&args.output, &disp)?;
    if let Some(png) = &args.png {
        io::write_rgb(
            png,
            &colormap::colorize_with_bar(&disp, args.min_disp as f32, max_disp as f32),
        )?;
    }
    let valid =
        disp.as_slice().iter().filter(|d| d.is_finite()).count() as f64 / disp.len().max(1) as f64;
    let c = sensor.depth;
    let roi = default_roi(disp.width(), disp.height());
    let m = Matched {
        output: args.output.clone(),
        algorithm: spec.algorithm,
        max_disp,
        max_disp_from: range_from,
        width: left.width(),
        height: left.height(),
        time_ms,
        valid_fraction: valid,
        rectified: sensor.stereo.is_some(),
        focal_px: c.focal_px,
        baseline_m: c.baseline_m,
        doffs: c.doffs,
        distance_m: region_distance(&disp, roi, &c).ok().flatten(),
    };
    out.emit(&m, || {
        let distance = m.distance_m.map_or(String::new(), |z| {
            format!(
                "; central region at {z:.3} m (f {:.1} px, baseline {:.4} m, doffs {:.2} px)",
                m.focal_px.unwrap_or(0.0),
                m.baseline_m.unwrap_or(0.0),
                m.doffs
            )
        });
        format!(
            "{} disparity map {}x{}{} written to {} in {:.1} ms ({:.1} % valid){distance}\n",
            m.algorithm,
            m.width,
            m.height,
            if m.rectified {
                " (rectified first)"
            } else {
                ""
            },
            m.output.display(),
            m.time_ms,
            m.valid_fraction * 100.0
        )
    })
}

/// Arguments of `stereolink bench match`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Scene folder (its ndisp sets the range unless --max-disp is given).
    #[arg(long)]
    pub scene: PathBuf,
    /// Largest disparity searched (default: the scene's ndisp − 1).
    #[arg(long)]
    pub max_disp: Option<usize>,
    /// Timed runs after one warm-up run.
    #[arg(long, default_value_t = 10)]
    pub iters: usize,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    #[command(flatten)]
    /// The matcher and its parameters.
    pub matcher: MatcherArgs,
}

#[derive(Serialize)]
struct Bench {
    algorithm: Algorithm,
    scene: String,
    width: usize,
    height: usize,
    ndisp: usize,
    iters: usize,
    threads: usize,
    median_ms: f64,
    min_ms: f64,
    bad_1_nonocc: Option<f64>,
}

/// Times the matcher alone (images in memory, after a warm-up).
pub fn run_bench(args: BenchArgs, out: &super::Output) -> anyhow::Result<()> {
    let scene = Scene::load(&args.scene)?;
    let max_disp = args.max_disp.unwrap_or(scene.calib.ndisp.saturating_sub(1));
    let spec = args.matcher.spec(0, max_disp)?;
    let segments = args.matcher.segments()?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads.unwrap_or(0))
        .build()?;
    let (times, disp) = pool.install(|| -> anyhow::Result<_> {
        // One matcher for every run, as for the frames of a video.
        let mut matcher = Matcher::new();
        let pair = (&scene.left, &scene.right);
        let disp = disparity(&mut matcher, pair, &spec, &segments)?;
        let mut times = Vec::with_capacity(args.iters);
        for _ in 0..args.iters.max(1) {
            let t = Instant::now();
            std::hint::black_box(disparity(&mut matcher, pair, &spec, &segments)?);
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        Ok((times, disp))
    })?;
    let mut sorted = times.clone();
    sorted.sort_by(f64::total_cmp);
    let bad = scene.gt_left.as_ref().and_then(|gt| {
        stereolink_image::metrics::bad_pixel_rate(&disp, gt, scene.masks.nonocc.as_ref(), 1.0)
    });
    let b = Bench {
        algorithm: spec.algorithm,
        scene: scene.name.clone(),
        width: scene.left.width(),
        height: scene.left.height(),
        ndisp: spec.ndisp(),
        iters: sorted.len(),
        threads: pool.current_num_threads(),
        median_ms: sorted[sorted.len() / 2],
        min_ms: sorted[0],
        bad_1_nonocc: bad,
    };
    out.emit(&b, || {
        format!(
            "{} on {} ({}x{}, {} disparities, {} threads): median {:.2} ms, min {:.2} ms over {} runs{}\n",
            b.algorithm,
            b.scene,
            b.width,
            b.height,
            b.ndisp,
            b.threads,
            b.median_ms,
            b.min_ms,
            b.iters,
            b.bad_1_nonocc.map_or(String::new(), |v| format!("; bad>1px nonocc {v:.2} %"))
        )
    })
}
