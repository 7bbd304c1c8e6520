//! `stereolink encode`, `stereolink decode` and `stereolink bench codec`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;
use stereolink_codec::lossy::ViewCoding;
use stereolink_codec::stereo::Mode;
use stereolink_codec::{container, labels, Limits, Message, SegmentationKind, StereoFrame, View};
use stereolink_image::metrics::{psnr_pair, psnr_rgb, reduction_percent};
use stereolink_image::{io, RgbImage, Scene};
use stereolink_pipeline::coding::{encode_fitted, lossy_frame, lossy_views, CodingSpec};
use stereolink_pipeline::sender::segment_pair;

use super::segment::SegmentArgs;

/// Arguments of `stereolink encode`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Left image; or a folder of pairs (left_0001.png with
    /// right_0001.png, ...) coded in name order as a stream: a key frame
    /// first, then frames predicted from the one before (lossy codings).
    pub left: PathBuf,
    /// Right image (none for a folder).
    pub right: Option<PathBuf>,
    /// Output frame file; for a folder of pairs, the folder to write a
    /// frame file per pair into (frame_0001.slnk, ...).
    #[arg(short, long)]
    pub output: PathBuf,
    /// A stream's key frames: every N pairs (0: the first only).
    #[arg(long, value_name = "N")]
    pub key_every: Option<usize>,
    /// A stream's predicted frames skip a block whose mean absolute
    /// difference from the reference's is at most this (grey levels).
    #[arg(long, value_name = "LEVELS")]
    pub skip_mad: Option<f32>,
    /// ... and each of whose 8x8 quarters' mean moved at most this.
    #[arg(long, value_name = "LEVELS")]
    pub skip_mean: Option<f32>,
    /// Send the original views losslessly instead of segmenting them.
    #[arg(long, conflicts_with_all = ["view_coding", "bytes"])]
    pub original: bool,
    /// Label-map coding: `fast` (the receiver decodes fastest) or `strong`
    /// (smaller, far slower to decode; see docs/tuning.md).
    #[arg(long, default_value = "fast")]
    pub mode: labels::Mode,
    #[command(flatten)]
    /// How the views are coded, and the frame's byte budget.
    pub coding: CodingArgs,
    #[command(flatten)]
    /// The segmentation method and its parameters.
    pub segment: SegmentArgs,
}

/// How the views are coded and the frame's byte budget (`encode`, `send`).
#[derive(Debug, clap::Args)]
pub struct CodingArgs {
    /// How the views are coded. `segmented`: the paper's mode, each view
    /// segmented (--method, --levels) and its label map coded losslessly,
    /// so the receiver shows the segmentation. `webp`: the original views,
    /// lossy, with the most picture per byte; the ARM926 board decodes a
    /// 320x240 pair in time. `jpeg`: lossy, less picture per byte than
    /// WebP, but the cheapest to decode. docs/benchmarks.md compares them.
    #[arg(long, default_value = "segmented", value_name = "CODING")]
    pub view_coding: ViewCoding,
    /// Quality of a lossy coding without --bytes: 0 (smallest; JPEG's
    /// lowest is 1) to 100.
    #[arg(long, default_value_t = 75, value_parser = clap::value_parser!(u8).range(0..=100))]
    pub quality: u8,
    /// Fit the frame (the whole message) in N bytes with the best pair PSNR
    /// the coding gives: the highest quality (jpeg, webp), or the most
    /// classes from 2 up to --levels (segmented), whose frame fits. A
    /// budget below the smallest frame is an error that names its size.
    #[arg(long, value_name = "N")]
    pub bytes: Option<usize>,
    /// A lossy coding's right view: `on`, predicted from the left view as
    /// decoded, shifted by cell disparities the frame carries (the
    /// receiver shows them as its disparity, without matching); `off`,
    /// coded on its own as the left one is.
    #[arg(long, default_value = "on", value_name = "on|off", value_parser = on_off, action = clap::ArgAction::Set)]
    pub stereo_prediction: bool,
}

/// `on` or `off`.
fn on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("{s:?}: on or off")),
    }
}

impl CodingArgs {
    /// The pipeline's coding spec.
    pub fn spec(&self) -> CodingSpec {
        CodingSpec {
            coding: self.view_coding,
            quality: self.quality,
            budget: self.bytes,
            stereo_prediction: self.stereo_prediction,
        }
    }
}

#[derive(Serialize)]
struct Encoded {
    output: PathBuf,
    bytes: usize,
    original_file_bytes: u64,
    reduction_percent: f64,
    bits_per_pixel: f64,
    /// `segmented`, `jpeg`, `webp` or `rgb` (--original).
    view_coding: &'static str,
    /// The lossy quality the frame was coded at.
    quality: Option<u8>,
    /// The segmentation's classes the frame was coded with.
    levels: Option<u8>,
    /// PSNR of the left and right views as sent.
    psnr_db: Option<(f64, f64)>,
    /// PSNR of the pair as sent: both views, one MSE.
    psnr_pair_db: Option<f64>,
    #[serde(flatten)]
    views: ViewBytes,
}

/// What a frame's views cost, for `--json`.
#[derive(Serialize)]
struct ViewBytes {
    /// The left view's coded bytes (its lossy bitstream), for a lossy
    /// frame.
    left_view_bytes: Option<usize>,
    /// Whether the right view is predicted from the left ([`View::Stereo`]).
    stereo_prediction: bool,
    /// Share of the stereo-predicted right view's blocks that are coded
    /// (the others are the prediction alone).
    stereo_coded_share: Option<f64>,
}

impl ViewBytes {
    fn of(frame: &StereoFrame) -> Self {
        ViewBytes {
            left_view_bytes: match &frame.left {
                View::Lossy(v) => Some(v.bytes().len()),
                _ => None,
            },
            stereo_prediction: matches!(frame.right, View::Stereo(_)),
            stereo_coded_share: match &frame.right {
                View::Stereo(v) => {
                    let coded = v.modes().iter().filter(|&&m| m != Mode::Skip).count();
                    Some(coded as f64 / v.modes().len().max(1) as f64)
                }
                _ => None,
            },
        }
    }
}

/// Segments (unless `--original`) and encodes a pair.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    if args.left.is_dir() {
        anyhow::ensure!(
            args.right.is_none() && !args.original,
            "a folder of pairs is coded as a stream: no right image, no --original"
        );
        return super::stream::run_encode(args, out);
    }
    let Some(right_path) = args.right.as_ref() else {
        anyhow::bail!(
            "encode takes a left and a right image, or a folder of pairs ({} is not a folder)",
            args.left.display()
        )
    };
    let left = io::read_rgb(&args.left)?;
    let right = io::read_rgb(right_path)?;
    anyhow::ensure!(
        left.dims() == right.dims(),
        "{} is {:?} but {} is {:?}",
        args.left.display(),
        left.dims(),
        right_path.display(),
        right.dims()
    );
    let (bytes, frame, setting) = if args.original {
        let f = StereoFrame {
            kind: SegmentationKind::None,
            levels: 0,
            params: String::new(),
            thresholds: None,
            calibration: None,
            left: View::Rgb(left.clone()),
            right: View::Rgb(right.clone()),
            planes: None,
        };
        let msg = Message::StereoFrame(Box::new(f));
        let bytes = container::encode_with(&msg, 1, 0, args.mode);
        let Message::StereoFrame(f) = msg else {
            unreachable!("built as a frame")
        };
        (bytes, *f, None)
    } else {
        let spec = args.coding.spec();
        let settings = spec.settings(args.segment.levels);
        let ids = (1, 0, args.mode);
        let coded = match spec.coding {
            ViewCoding::Lossy(codec) => encode_fitted(settings, spec.budget, ids, |q| {
                let (l, r) = lossy_views((&left, &right), codec, q, spec.stereo_prediction)?;
                Ok(lossy_frame(codec, q, (l, r), None))
            }),
            ViewCoding::Segmented => {
                let method = args.segment.method()?;
                let carry = args.segment.carry_margin()?;
                let seed = args.segment.seed;
                encode_fitted(settings, spec.budget, ids, |levels| {
                    let (sl, sr) =
                        segment_pair((&left, &right), &method, (levels as usize, seed), carry)?;
                    Ok(StereoFrame {
                        kind: SegmentationKind::from_name(method.name())
                            .unwrap_or(SegmentationKind::None),
                        levels,
                        params: format!("seed={seed}"),
                        thresholds: sl.channels.as_ref().map(|c| c.thresholds.clone()),
                        calibration: None,
                        left: View::Indexed(sl.image),
                        right: View::Indexed(sr.image),
                        planes: None,
                    })
                })
            }
        }
        .with_context(|| format!("cannot code the pair as {}", spec.coding.name()))?;
        (coded.bytes, coded.frame, Some(coded.setting))
    };
    let sent: (RgbImage, RgbImage) = (frame.left.to_rgb(), frame.right.to_rgb());
    let psnr = (!args.original)
        .then(|| {
            anyhow::Ok((
                psnr_rgb(&left, &sent.0)?.overall,
                psnr_rgb(&right, &sent.1)?.overall,
            ))
        })
        .transpose()?;
    let psnr_pair_db = (!args.original)
        .then(|| psnr_pair((&left, &right), (&sent.0, &sent.1)))
        .transpose()?;
    let view_coding = frame.left.coding_name();
    let lossy = matches!(frame.left, View::Lossy(_));
    std::fs::write(&args.output, &bytes)
        .with_context(|| format!("cannot write {}", args.output.display()))?;
    let original = std::fs::metadata(&args.left)?.len() + std::fs::metadata(right_path)?.len();
    let e = Encoded {
        output: args.output.clone(),
        bytes: bytes.len(),
        original_file_bytes: original,
        reduction_percent: reduction_percent(original as usize, bytes.len()),
        bits_per_pixel: bytes.len() as f64 * 8.0 / (2 * left.len()) as f64,
        view_coding,
        quality: setting.filter(|_| lossy),
        levels: setting.filter(|_| !lossy),
        psnr_db: psnr,
        psnr_pair_db,
        views: ViewBytes::of(&frame),
    };
    out.emit(&e, || {
        format!(
            "{}: {} B for the pair as {} ({:.3} bit/pixel), {:.1} % smaller than the original files ({} B){}\n",
            e.output.display(),
            e.bytes,
            e.view_coding,
            e.bits_per_pixel,
            e.reduction_percent,
            e.original_file_bytes,
            match (e.psnr_db, e.psnr_pair_db) {
                (Some((l, r)), Some(p)) => format!("; PSNR {l:.2} / {r:.2} dB, pair {p:.2} dB"),
                _ => String::new(),
            }
        )
    })
}

/// Arguments of `stereolink decode`.
#[derive(Debug, clap::Args)]
pub struct DecodeArgs {
    /// Frame file written by `stereolink encode` (or received); or a folder
    /// of a stream's frame files, decoded in name order.
    pub input: PathBuf,
    /// Folder to write left.png and right.png into (for a stream,
    /// left_0001.png, right_0001.png, ...).
    #[arg(long)]
    pub out: PathBuf,
    /// For a stream: the folder of the pairs coded, to report PSNR.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["left", "right"])]
    pub originals: Option<PathBuf>,
    /// Original left image, to report PSNR.
    #[arg(long)]
    pub left: Option<PathBuf>,
    /// Original right image, to report PSNR.
    #[arg(long)]
    pub right: Option<PathBuf>,
}

#[derive(Serialize)]
struct Decoded {
    frame_id: u32,
    kind: String,
    /// `segmented`, `jpeg`, `webp` or `rgb`.
    view_coding: &'static str,
    width: usize,
    height: usize,
    bytes: usize,
    psnr_db: Option<(f64, f64)>,
    /// PSNR of the pair: both views, one MSE.
    psnr_pair_db: Option<f64>,
    #[serde(flatten)]
    views: ViewBytes,
}

/// Decodes a frame file into its two views.
pub fn run_decode(args: DecodeArgs, out: &super::Output) -> anyhow::Result<()> {
    if args.input.is_dir() {
        return super::stream::run_decode(&args.input, &args.out, args.originals.as_deref(), out);
    }
    let bytes = std::fs::read(&args.input)
        .with_context(|| format!("cannot read {}", args.input.display()))?;
    let (header, msg) = container::decode(&bytes, &Limits::default())
        .with_context(|| format!("{} is not a valid frame", args.input.display()))?;
    let Message::StereoFrame(frame) = msg else {
        anyhow::bail!(
            "{} holds a message of type {}, not a stereo frame",
            args.input.display(),
            header.kind
        )
    };
    let (l, r) = (frame.left.to_rgb(), frame.right.to_rgb());
    std::fs::create_dir_all(&args.out)?;
    io::write_rgb(args.out.join("left.png"), &l)?;
    io::write_rgb(args.out.join("right.png"), &r)?;
    let (psnr, psnr_pair_db) = match (&args.left, &args.right) {
        (Some(a), Some(b)) => {
            let (a, b) = (io::read_rgb(a)?, io::read_rgb(b)?);
            (
                Some((psnr_rgb(&a, &l)?.overall, psnr_rgb(&b, &r)?.overall)),
                Some(psnr_pair((&a, &b), (&l, &r))?),
            )
        }
        _ => (None, None),
    };
    let d = Decoded {
        frame_id: header.frame_id,
        kind: frame.kind.name().into(),
        view_coding: frame.left.coding_name(),
        width: l.width(),
        height: l.height(),
        bytes: bytes.len(),
        psnr_db: psnr,
        psnr_pair_db,
        views: ViewBytes::of(&frame),
    };
    out.emit(&d, || {
        format!(
            "frame {} ({}, {}, {}x{}, {} B) written to {}{}\n",
            d.frame_id,
            d.view_coding,
            d.kind,
            d.width,
            d.height,
            d.bytes,
            args.out.display(),
            d.psnr_db
                .map_or(String::new(), |(a, b)| format!("; PSNR {a:.2} / {b:.2} dB"))
        )
    })
}

/// Arguments of `stereolink bench codec`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Scene folder.
    #[arg(long)]
    pub scene: PathBuf,
    /// Timed runs after a warm-up.
    #[arg(long, default_value_t = 10)]
    pub iters: usize,
    /// Label-map coding: `fast` (the receiver decodes fastest) or `strong`
    /// (smaller, far slower to decode; see docs/tuning.md).
    #[arg(long, default_value = "fast")]
    pub mode: labels::Mode,
    #[command(flatten)]
    /// The segmentation method and its parameters.
    pub segment: SegmentArgs,
}

#[derive(Serialize)]
struct CodecBench {
    scene: String,
    method: String,
    mode: &'static str,
    width: usize,
    height: usize,
    palette_left: usize,
    palette_right: usize,
    bytes_left: usize,
    bytes_right_alone: usize,
    bytes_right_conditioned: usize,
    frame_bytes: usize,
    bits_per_pixel: f64,
    conditioned_gain_percent: f64,
    /// PSNR of the segmented right view against the original (dB).
    psnr_right_db: f64,
    encode_ms: f64,
    decode_ms: f64,
    decode_mpixel_s: f64,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Sizes and speeds of the label coder on a scene's segmented pair.
pub fn run_bench(args: BenchArgs, out: &super::Output) -> anyhow::Result<()> {
    let scene = Scene::load(&args.scene)?;
    let (sl, sr) = args.segment.run_pair(&scene.left, &scene.right)?;
    let (l, r) = (&sl.image, &sr.image);
    let nl = l.palette().len();
    let nr = r.palette().len();
    let mode = args.mode;
    let left_bytes = labels::encode(l.labels(), l.palette(), None, 0, mode);
    let right_alone = labels::encode(r.labels(), r.palette(), None, 0, mode);
    let frame = StereoFrame {
        kind: SegmentationKind::None,
        levels: 0,
        params: String::new(),
        thresholds: None,
        calibration: None,
        left: View::Indexed(l.clone()),
        right: View::Indexed(r.clone()),
        planes: None,
    };
    let msg = Message::StereoFrame(Box::new(frame));
    let bytes = container::encode_with(&msg, 1, 0, mode);
    let right_cond = container::conditioned_payload(l, r, mode).len();
    let (mut enc, mut dec) = (Vec::new(), Vec::new());
    for _ in 0..=args.iters.max(1) {
        let t = Instant::now();
        let b = container::encode_with(&msg, 1, 0, mode);
        enc.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        std::hint::black_box(container::decode(&b, &Limits::default())?);
        dec.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let (encode_ms, decode_ms) = (median(enc[1..].to_vec()), median(dec[1..].to_vec()));
    let px = scene.left.len();
    let b = CodecBench {
        scene: scene.name.clone(),
        method: args.segment.method()?.name().into(),
        mode: mode.name(),
        width: scene.left.width(),
        height: scene.left.height(),
        palette_left: nl,
        palette_right: nr,
        bytes_left: left_bytes.len(),
        bytes_right_alone: right_alone.len(),
        bytes_right_conditioned: right_cond,
        frame_bytes: bytes.len(),
        bits_per_pixel: left_bytes.len() as f64 * 8.0 / px as f64,
        conditioned_gain_percent: 100.0 * (1.0 - right_cond as f64 / right_alone.len() as f64),
        psnr_right_db: psnr_rgb(&scene.right, &sr.to_rgb())?.overall,
        encode_ms,
        decode_ms,
        decode_mpixel_s: 2.0 * px as f64 / decode_ms / 1e3,
    };
    out.emit(&b, || {
        format!(
            "{} {} {} ({}x{}): left {} B ({:.3} bit/px), right alone {} B, conditioned {} B ({:.1} % smaller); encode {:.2} ms, decode {:.2} ms ({:.0} Mpixel/s)\n",
            b.scene,
            b.method,
            b.mode,
            b.width,
            b.height,
            b.bytes_left,
            b.bits_per_pixel,
            b.bytes_right_alone,
            b.bytes_right_conditioned,
            b.conditioned_gain_percent,
            b.encode_ms,
            b.decode_ms,
            b.decode_mpixel_s
        )
    })
}
