//! The paper's experiments rerun on a data folder (`stereolink report`),
//! written as an HTML page (`index.html`, images in `img/`) and
//! `report.json`.
//!
//! Per scene: each segmentation method (the paper's five and the exact
//! multilevel Otsu) with PSNR (Table IV, and beside it the PSNR WebP and
//! JPEG give the original pair in the same bytes), coded size and reduction against the
//! original PNG files (Fig. 12), and time (Fig. 26); then WTA, line growing
//! and SGM on the original pair and on every segmented pair, scored against
//! the ground truth (bad > 1 px, non-occluded) with their depth-level counts
//! (Tables V and VI) and times (Fig. 27). The paper's figures stand beside
//! ours. The plane matcher (`planes`) runs on the original pair with the
//! segments of each input: the connected components of that method's left
//! labels, or the default mean shift over-segmentation for the original
//! pair; the headline says whether segmenting first helps it. Seeds are
//! fixed, so two runs give the same numbers (times aside).
//!
//! This module computes; `html` renders the page from the [`Report`], with
//! the charts of [`svg`] and the paper's figures of [`paper`].

mod html;
pub mod paper;
pub mod svg;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;
use stereolink_codec::labels::Mode;
use stereolink_codec::lossy::LossyCodec;
use stereolink_codec::{container, CodecError, Message, SegmentationKind, StereoFrame, View};
use stereolink_display::{anaglyph, Anaglyph};
use stereolink_image::{colormap, io, metrics, DisparityMap, LabelMap, RgbImage, Scene};
use stereolink_pipeline::coding::{encode_fitted, lossy_frame, lossy_views};
use stereolink_pipeline::planes::{left_segments, Segments};
use stereolink_segment::{segment, Method};
use stereolink_stereo::depth::{depth_levels, LevelSpec};
use stereolink_stereo::{compute_disparity, Algorithm, MatchSpec, Matcher};

/// Classes per method: k = 3 for k-means (the paper's), 3 levels per channel for thresholding.
pub const LEVELS: usize = 3;
/// Seed of every stochastic method.
pub const SEED: u64 = 1;

/// One segmentation of one scene.
#[derive(Clone, Debug, Serialize)]
pub struct SegResult {
    /// PSNR of the segmented left view against the original, dB.
    pub psnr_db: f64,
    /// The paper's PSNR for this scene and method.
    pub paper_psnr_db: Option<f64>,
    /// Bytes of the coded pair (StereoFrame message).
    pub coded_bytes: usize,
    /// Reduction against the original PNG files, percent.
    pub reduction_percent: f64,
    /// Segmentation time of both views, ms.
    pub time_ms: f64,
    /// Classes in the left view's palette.
    pub classes: usize,
    /// PSNR of the left view when the original pair is sent lossy in the
    /// same bytes instead, per codec ("webp", "jpeg"), dB; absent where the
    /// codec's smallest pair is larger.
    pub lossy_psnr_db: BTreeMap<String, f64>,
}

/// One matcher on one input pair of one scene.
#[derive(Clone, Debug, Serialize)]
pub struct MatchResult {
    /// Bad > 1 px over non-occluded pixels, percent.
    pub bad1_nonocc: Option<f64>,
    /// Bad > 2 px over non-occluded pixels, percent.
    pub bad2_nonocc: Option<f64>,
    /// Depth levels (see `stereolink_stereo::depth::LevelSpec`).
    pub levels: usize,
    /// The paper's count (WTA: Table V, line growing: Table VI).
    pub paper_levels: Option<u32>,
    /// Matching time, ms.
    pub time_ms: f64,
}

/// Everything measured on one scene.
#[derive(Clone, Debug, Serialize)]
pub struct SceneReport {
    /// Scene name.
    pub name: String,
    /// Width and height.
    pub size: (usize, usize),
    /// Disparities searched.
    pub ndisp: usize,
    /// Bytes of the original left and right files.
    pub original_bytes: u64,
    /// Per method.
    pub segmentation: BTreeMap<String, SegResult>,
    /// Per input ("original" or a method), per algorithm.
    pub matching: BTreeMap<String, BTreeMap<String, MatchResult>>,
}

/// The whole report.
#[derive(Debug, Serialize)]
pub struct Report {
    /// Per scene.
    pub scenes: Vec<SceneReport>,
    /// Total run time, seconds.
    pub seconds: f64,
}

/// Methods in report order: the paper's five, then the exact optimum.
pub fn methods() -> Vec<Method> {
    ["meanshift", "kmeans", "pso", "dpso", "fodpso", "otsu"]
        .iter()
        .map(|m| m.parse().expect("known method"))
        .collect()
}

fn img_name(scene: &str, what: &str) -> String {
    format!("img/{scene}-{what}.png")
}

/// The left view's PSNR when the original pair is coded by each lossy
/// codec in at most `bytes` (the whole frame, as `encode --bytes` fits it),
/// for the codecs whose smallest pair fits.
fn lossy_at(scene: &Scene, bytes: usize) -> anyhow::Result<BTreeMap<String, f64>> {
    let mut psnr = BTreeMap::new();
    for codec in [LossyCodec::Webp, LossyCodec::Jpeg] {
        let fitted = encode_fitted(codec.qualities(), Some(bytes), (0, 0, Mode::Fast), |q| {
            let views = lossy_views((&scene.left, &scene.right), codec, q, true)?;
            Ok(lossy_frame(codec, q, views, None))
        });
        match fitted {
            Ok(coded) => {
                let left = coded.frame.left.to_rgb();
                psnr.insert(
                    codec.name().into(),
                    metrics::psnr_rgb(&scene.left, &left)?.overall,
                );
            }
            Err(e) if matches!(e.downcast_ref(), Some(CodecError::BudgetTooSmall { .. })) => {}
            Err(e) => return Err(e),
        }
    }
    Ok(psnr)
}

/// Computes one scene, writing its images under `out/img/`.
pub fn scene_report(scene: &Scene, dir: &Path, out: &Path) -> anyhow::Result<SceneReport> {
    let (w, h) = scene.left.dims();
    let ndisp = scene.calib.ndisp.clamp(2, w - 1);
    let original_bytes = ["left.png", "right.png", "im0.png", "im1.png"]
        .iter()
        .filter_map(|f| std::fs::metadata(dir.join(f)).ok())
        .map(|m| m.len())
        .sum::<u64>()
        .max(1);
    let save =
        |what: &str, img: &RgbImage| io::write_rgb(out.join(img_name(&scene.name, what)), img);
    save("left", &scene.left)?;
    save(
        "anaglyph",
        &anaglyph(&scene.left, &scene.right, Anaglyph::Dubois),
    )?;
    let mut pairs: Vec<(String, RgbImage, RgbImage)> =
        vec![("original".into(), scene.left.clone(), scene.right.clone())];
    // The plane matcher's segments per input.
    let mut segments: BTreeMap<String, LabelMap> = BTreeMap::new();
    segments.insert(
        "original".into(),
        left_segments(&scene.left, &Segments::OverSegmentation)?,
    );
    let mut segmentation = BTreeMap::new();
    for method in methods() {
        let t = Instant::now();
        let (sl, sr) = rayon::join(
            || segment(&scene.left, &method, LEVELS, SEED),
            || segment(&scene.right, &method, LEVELS, SEED),
        );
        let (sl, sr) = (sl?, sr?);
        let time_ms = t.elapsed().as_secs_f64() * 1e3;
        let (l, r) = (sl.to_rgb(), sr.to_rgb());
        let classes = sl.image.palette().len();
        segments.insert(method.name().to_string(), sl.image.labels().clone());
        let frame = StereoFrame {
            kind: SegmentationKind::from_name(method.name()).unwrap_or(SegmentationKind::None),
            levels: LEVELS as u8,
            params: String::new(),
            thresholds: None,
            calibration: None,
            left: View::Indexed(sl.image),
            right: View::Indexed(sr.image),
            planes: None,
        };
        let coded_bytes = container::encode(&Message::StereoFrame(Box::new(frame)), 0, 0).len();
        let lossy_psnr_db = lossy_at(scene, coded_bytes)?;
        save(&format!("seg-{}", method.name()), &l)?;
        segmentation.insert(
            method.name().to_string(),
            SegResult {
                psnr_db: metrics::psnr_rgb(&scene.left, &l)?.overall,
                paper_psnr_db: paper::psnr(&scene.name, method.name()),
                coded_bytes,
                reduction_percent: metrics::reduction_percent(original_bytes as usize, coded_bytes),
                time_ms,
                classes,
                lossy_psnr_db,
            },
        );
        pairs.push((method.name().to_string(), l, r));
    }
    let mut matching = BTreeMap::new();
    let level_spec = LevelSpec::default();
    for (input, l, r) in &pairs {
        let mut per_algo = BTreeMap::new();
        for algo in Algorithm::ALL.into_iter().chain([Algorithm::Planes]) {
            let spec = MatchSpec::new(algo, 0, ndisp - 1)?;
            let t = Instant::now();
            let d = match algo {
                Algorithm::Planes => Matcher::new().compute_segmented(
                    &scene.left,
                    &scene.right,
                    Some(&segments[input]),
                    &spec,
                )?,
                _ => compute_disparity(l, r, &spec)?,
            };
            let time_ms = t.elapsed().as_secs_f64() * 1e3;
            let score = |th| {
                scene
                    .gt_left
                    .as_ref()
                    .and_then(|gt| metrics::bad_pixel_rate(&d, gt, scene.masks.nonocc.as_ref(), th))
            };
            let table: &[(&str, [u32; 6])] = match algo {
                Algorithm::Wta => &paper::TABLE_V,
                Algorithm::LineGrowing => &paper::TABLE_VI,
                Algorithm::Sgm | Algorithm::Planes => &[],
            };
            if input == "original" || input == "fodpso" {
                save(
                    &format!("disp-{input}-{}", algo.name()),
                    &colormap::colorize_with_bar(&d, 0.0, (ndisp - 1) as f32),
                )?;
            }
            if input == "original" && algo == Algorithm::Sgm {
                if let Some(gt) = &scene.gt_left {
                    save("error-sgm", &error_map(&d, gt))?;
                }
            }
            per_algo.insert(
                algo.name().to_string(),
                MatchResult {
                    bad1_nonocc: score(1.0),
                    bad2_nonocc: score(2.0),
                    levels: depth_levels(&d, &level_spec).levels.len(),
                    paper_levels: paper::levels(table, &scene.name, input),
                    time_ms,
                },
            );
        }
        matching.insert(input.clone(), per_algo);
    }
    Ok(SceneReport {
        name: scene.name.clone(),
        size: (w, h),
        ndisp,
        original_bytes,
        segmentation,
        matching,
    })
}

/// Green where |d − gt| ≤ 1, red where larger, black where the ground truth is unknown.
fn error_map(d: &DisparityMap, gt: &DisparityMap) -> RgbImage {
    RgbImage::from_fn(d.width(), d.height(), |x, y| {
        let (e, g) = (d.get(x, y), gt.get(x, y));
        if !g.is_finite() {
            [0, 0, 0]
        } else if e.is_finite() && (e - g).abs() <= 1.0 {
            [40, 160, 60]
        } else {
            [220, 40, 40]
        }
    })
}

/// Runs the report over the scene folders and writes it into `out`.
pub fn run(dirs: &[PathBuf], out: &Path, progress: &dyn Fn(&str)) -> anyhow::Result<Report> {
    let start = Instant::now();
    std::fs::create_dir_all(out.join("img"))
        .with_context(|| format!("cannot create {}", out.display()))?;
    let mut scenes = Vec::new();
    for dir in dirs {
        let scene = Scene::load(dir)?;
        progress(&scene.name);
        scenes
            .push(scene_report(&scene, dir, out).with_context(|| format!("scene {}", scene.name))?);
    }
    let report = Report {
        scenes,
        seconds: start.elapsed().as_secs_f64(),
    };
    std::fs::write(
        out.join("report.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    std::fs::write(out.join("index.html"), html::page(&report))?;
    Ok(report)
}
