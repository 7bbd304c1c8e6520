//! `stereolink encode DIR -o OUT/` and `stereolink decode OUT/ --out DIR`:
//! the pairs of a folder coded as a stream, one frame file per pair, a key
//! frame first and then frames predicted from the one before
//! (`stereolink_pipeline::stream`); and the stream decoded back, each
//! predicted frame from the frames decoded before it.

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;
use stereolink_codec::container::{self, Body};
use stereolink_codec::temporal::{RefId, References, SkipSpec};
use stereolink_codec::Limits;
use stereolink_image::metrics::psnr_pair;
use stereolink_image::{io, Calibration, RgbImage};
use stereolink_pipeline::sender::SenderConfig;
use stereolink_pipeline::stream::{FrameKind, StreamEncoder};
use stereolink_pipeline::watch::{Pair, Watcher};
use stereolink_stereo::depth::LevelSpec;
use stereolink_stereo::{Algorithm, MatchSpec};

use super::codec::Args;

/// The pairs of folder `dir`, in name order.
fn pairs(dir: &Path) -> anyhow::Result<Vec<Pair>> {
    let found = Watcher::new()
        .pending(dir)
        .with_context(|| format!("cannot read the folder {}", dir.display()))?;
    anyhow::ensure!(
        !found.is_empty(),
        "{} holds no pairs (left*.png with right*.png of the same name)",
        dir.display()
    );
    Ok(found)
}

fn read_pair(p: &Pair) -> anyhow::Result<(RgbImage, RgbImage)> {
    let left =
        io::read_rgb(&p.left).with_context(|| format!("cannot read {}", p.left.display()))?;
    let right =
        io::read_rgb(&p.right).with_context(|| format!("cannot read {}", p.right.display()))?;
    anyhow::ensure!(
        left.dims() == right.dims(),
        "{} is {:?} but {} is {:?}",
        p.left.display(),
        left.dims(),
        p.right.display(),
        right.dims()
    );
    Ok((left, right))
}

#[derive(Serialize)]
struct StreamFrame {
    file: PathBuf,
    frame_id: u32,
    /// `key` or `predicted`.
    kind: &'static str,
    /// The frame a predicted frame is predicted from.
    reference: Option<u32>,
    bytes: usize,
    /// The lossy quality (or the segmentation's classes).
    setting: u8,
    /// PSNR of the pair as rebuilt: both views, one MSE.
    psnr_pair_db: f64,
}

#[derive(Serialize)]
struct Stream {
    output: PathBuf,
    view_coding: &'static str,
    frames: Vec<StreamFrame>,
    key_frames: usize,
    predicted_frames: usize,
    /// Mean bytes of the key frames and of the predicted frames.
    key_bytes_mean: Option<f64>,
    predicted_bytes_mean: Option<f64>,
    /// Mean pair PSNR of the key frames and of the predicted frames.
    key_psnr_pair_db_mean: Option<f64>,
    predicted_psnr_pair_db_mean: Option<f64>,
}

fn mean(v: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// Codes the pairs of `args.left` (a folder) into `args.output` (a folder).
pub fn run_encode(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let dir = &args.left;
    let found = pairs(dir)?;
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("cannot create {}", args.output.display()))?;
    let skip = SkipSpec {
        max_mad: args.skip_mad.unwrap_or(SkipSpec::default().max_mad),
        max_mean: args.skip_mean.unwrap_or(SkipSpec::default().max_mean),
    };
    // The frames' depth reports are not written: a cheap matcher.
    let cfg = SenderConfig {
        method: args.segment.method()?,
        levels: args.segment.levels,
        seed: args.segment.seed,
        carry_margin: args.segment.carry_margin()?,
        matcher: MatchSpec::new(Algorithm::Wta, 0, 16)?,
        roi: None,
        levels_spec: LevelSpec::default(),
        plane_table: Default::default(),
        coding: args.coding.spec(),
    };
    let calib = Calibration {
        focal_px: None,
        baseline_m: None,
        doffs: 0.0,
        ndisp: 16,
    };
    let mut stream = StreamEncoder::new(skip);
    let mut frames = Vec::with_capacity(found.len());
    let mut size = None;
    for (i, p) in found.iter().enumerate() {
        let (left, right) = read_pair(p)?;
        anyhow::ensure!(
            *size.get_or_insert(left.dims()) == left.dims(),
            "{}: the pairs of a stream must have one size ({:?}, not {:?})",
            p.left.display(),
            size.unwrap_or_default(),
            left.dims()
        );
        let frame_id = u32::try_from(i + 1).context("too many pairs")?;
        let want_key = args.key_every.is_some_and(|n| n > 0 && i % n == 0);
        let ids = (frame_id, u64::from(frame_id) * 100_000);
        let (prepared, kind) = stream
            .prepare((&left, &right), &calib, &cfg, ids, want_key)
            .with_context(|| format!("cannot code {}", p.left.display()))?;
        let stem = p.name.strip_suffix(".png").unwrap_or(&p.name);
        let file = args.output.join(format!("frame{stem}.slnk"));
        std::fs::write(&file, &prepared.frame_bytes)
            .with_context(|| format!("cannot write {}", file.display()))?;
        // A frame written is a frame delivered.
        stream.acknowledge(frame_id);
        frames.push(StreamFrame {
            file,
            frame_id,
            kind: kind.name(),
            reference: kind.reference(),
            bytes: prepared.frame_bytes.len(),
            setting: prepared.setting,
            psnr_pair_db: psnr_pair((&left, &right), (&prepared.sent.0, &prepared.sent.1))?,
        });
    }
    let key = |f: &&StreamFrame| f.kind == FrameKind::Key.name();
    let of = |want: bool, value: fn(&StreamFrame) -> f64| {
        mean(frames.iter().filter(|f| key(f) == want).map(value))
    };
    let s = Stream {
        output: args.output.clone(),
        view_coding: args.coding.view_coding.name(),
        key_frames: frames.iter().filter(key).count(),
        predicted_frames: frames.iter().filter(|f| !key(f)).count(),
        key_bytes_mean: of(true, |f| f.bytes as f64),
        predicted_bytes_mean: of(false, |f| f.bytes as f64),
        key_psnr_pair_db_mean: of(true, |f| f.psnr_pair_db),
        predicted_psnr_pair_db_mean: of(false, |f| f.psnr_pair_db),
        frames,
    };
    out.emit(&s, || {
        let fmt = |v: Option<f64>, unit: &str| v.map_or("-".into(), |v| format!("{v:.1} {unit}"));
        format!(
            "{} pairs of {} coded into {} as {}: {} key frames ({}, {}), {} predicted ({}, {})\n",
            s.frames.len(),
            dir.display(),
            s.output.display(),
            s.view_coding,
            s.key_frames,
            fmt(s.key_bytes_mean, "B"),
            fmt(s.key_psnr_pair_db_mean, "dB"),
            s.predicted_frames,
            fmt(s.predicted_bytes_mean, "B"),
            fmt(s.predicted_psnr_pair_db_mean, "dB"),
        )
    })
}

#[derive(Serialize)]
struct DecodedFrame {
    file: PathBuf,
    frame_id: u32,
    /// `key` or `predicted`.
    kind: &'static str,
    bytes: usize,
    /// PSNR of the pair against the originals, with `--originals`.
    psnr_pair_db: Option<f64>,
}

#[derive(Serialize)]
struct DecodedStream {
    frames: Vec<DecodedFrame>,
}

/// Decodes the frame files of `input` (a folder, in name order) into
/// `left_NNNN.png`/`right_NNNN.png` of `out_dir`; with `originals` (the
/// folder of pairs coded), the PSNR of each.
pub fn run_decode(
    input: &Path,
    out_dir: &Path,
    originals: Option<&Path>,
    out: &super::Output,
) -> anyhow::Result<()> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(input)
        .with_context(|| format!("cannot read {}", input.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "slnk"))
        .collect();
    files.sort();
    anyhow::ensure!(
        !files.is_empty(),
        "{} holds no frame files (*.slnk)",
        input.display()
    );
    let originals = originals.map(pairs).transpose()?;
    std::fs::create_dir_all(out_dir)?;
    let mut refs = References::default();
    let mut frames = Vec::with_capacity(files.len());
    for (i, file) in files.iter().enumerate() {
        let bytes =
            std::fs::read(file).with_context(|| format!("cannot read {}", file.display()))?;
        let what = || format!("{} is not a valid frame of the stream", file.display());
        let (header, body) = container::parse(&bytes, &Limits::default()).with_context(what)?;
        let Body::StereoFrame(frame) = body else {
            anyhow::bail!("{} holds no stereo frame", file.display())
        };
        let kind = match frame.references().next() {
            Some(_) => "predicted",
            None => "key",
        };
        let decoded = frame.decode_with(&refs).with_context(what)?;
        let (l, r) = (decoded.left.to_rgb(), decoded.right.to_rgb());
        let id = RefId {
            frame_id: header.frame_id,
            timestamp_us: header.timestamp_us,
        };
        match (decoded.left.indexed(), decoded.right.indexed()) {
            (Some(a), Some(b)) => {
                refs.keep_labels(id, [(a.labels(), a.palette()), (b.labels(), b.palette())])
            }
            _ => refs.keep(id, (&l, &r)),
        }
        let stem = file.file_stem().and_then(|s| s.to_str()).unwrap_or("");
        let stem = stem.strip_prefix("frame").unwrap_or(stem);
        io::write_rgb(out_dir.join(format!("left{stem}.png")), &l)?;
        io::write_rgb(out_dir.join(format!("right{stem}.png")), &r)?;
        let psnr_pair_db = match originals.as_ref().and_then(|o| o.get(i)) {
            Some(p) => {
                let (a, b) = read_pair(p)?;
                Some(psnr_pair((&a, &b), (&l, &r))?)
            }
            None => None,
        };
        frames.push(DecodedFrame {
            file: file.clone(),
            frame_id: header.frame_id,
            kind,
            bytes: bytes.len(),
            psnr_pair_db,
        });
    }
    let d = DecodedStream { frames };
    out.emit(&d, || {
        format!(
            "{} frames of {} decoded into {} ({} key)\n",
            d.frames.len(),
            input.display(),
            out_dir.display(),
            d.frames.iter().filter(|f| f.kind == "key").count()
        )
    })
}
