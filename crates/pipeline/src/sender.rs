//! The sender: segments both views, encodes the pair into a `StereoFrame`,
//! estimates disparity on the original pair (the sender has it, and depth
//! should be as good as possible), and builds the `DepthReport`: depth
//! levels, the target region's distance, the disparity histogram.
//!
//! With a carry margin the right view is made stereo-consistent
//! ([`segment_pair`]): its labels are carried over from the left view's
//! along the codec's stereo shifts where its colours allow, so that it codes
//! far smaller conditioned on the left; the receiver decodes it as any view.
//!
//! The target region defaults to the central ninth of the image (the middle
//! third in each direction), where a robot camera points at what it
//! approaches; `--roi x,y,w,h` chooses another.

use std::collections::BTreeMap;
use std::ops::RangeInclusive;
use std::time::Instant;

use anyhow::Context;
use stereolink_codec::control::Command;
use stereolink_codec::{
    container, labels,
    lossy::ViewCoding,
    planetable::{PlaneTable, TableCoding},
    DepthReport, Message, ReportLevel, SegmentationKind, StereoFrame, View,
};
use stereolink_image::{
    metrics::psnr_rgb, Calibration, DisparityMap, IndexedImage, LabelMap, RgbImage,
};
use stereolink_segment::carry::{carry_over, default_margin, NOTHING};
use stereolink_segment::{segment, Method, Segmentation};
use stereolink_stereo::depth::{depth_levels, depth_of, metric, region_distance, LevelSpec, Roi};
use stereolink_stereo::planes::match_planes;
use stereolink_stereo::{Algorithm, MatchSpec, Matcher};

use crate::coding::{encode_fitted, lossy_frame, lossy_views, CodingSpec};
use crate::planetable;

/// What the sender does with a pair.
#[derive(Clone, Debug)]
pub struct SenderConfig {
    /// Segmentation method.
    pub method: Method,
    /// Levels (classes).
    pub levels: usize,
    /// Seed of the segmentation.
    pub seed: u64,
    /// Stereo-consistent right view with this margin ([`segment_pair`]).
    pub carry_margin: Option<f32>,
    /// Matcher for the depth report.
    pub matcher: MatchSpec,
    /// Target region (default: the central ninth).
    pub roi: Option<Roi>,
    /// How depth levels are counted.
    pub levels_spec: LevelSpec,
    /// How the plane table is coded (with the plane matcher).
    pub plane_table: TableCoding,
    /// How the views are coded, and the frame's budget.
    pub coding: CodingSpec,
}

/// What a command asks of the send loop once the configuration took it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Applied {
    /// The next pair is prepared with the new setting.
    FromNextPair,
    /// A frame is wanted now.
    FrameNow,
}

impl SenderConfig {
    /// Takes a command from the link (`docs/mqtt.md`, "Commands"): levels
    /// and method hold from the next pair (a new method starts from its
    /// default parameters, and a stereo-consistent right view from that
    /// method's default carry margin); a frame request is the send loop's
    /// to honour. A sender has no axis: a stop is refused, with why.
    pub fn apply(&mut self, command: &Command) -> Result<Applied, String> {
        match command {
            Command::SetLevels(n) => self.levels = usize::from(*n),
            Command::SetMethod(name) => {
                self.method = name.parse().map_err(|e| format!("{e}"))?;
                if self.carry_margin.is_some() {
                    self.carry_margin = Some(default_margin(&self.method));
                }
            }
            Command::FrameRequest => return Ok(Applied::FrameNow),
            Command::AxisStop => {
                return Err("this station only sends images: it drives no axis \
                            (stop it on the robot's receiver)"
                    .into())
            }
        }
        Ok(Applied::FromNextPair)
    }
}

/// A pair ready to send, with what the sender measured on the way.
pub struct Prepared {
    /// The encoded StereoFrame message.
    pub frame_bytes: Vec<u8>,
    /// The encoded DepthReport message.
    pub report_bytes: Vec<u8>,
    /// The views as sent (segmented, or decoded from their lossy coding).
    pub sent: (RgbImage, RgbImage),
    /// The coding's setting the frame was made at (levels or quality).
    pub setting: u8,
    /// The sender's disparity map.
    pub disparity: DisparityMap,
    /// The depth report.
    pub report: DepthReport,
    /// PSNR of the left and right views as sent against the originals.
    pub psnr_db: (f64, f64),
    /// Segmentation, encoding and matching times (ms), summed over the
    /// settings tried when fitting a budget.
    pub times_ms: (f64, f64, f64),
}

/// The central ninth of a `w`×`h` image.
pub fn default_roi(w: usize, h: usize) -> Roi {
    Roi {
        x: w / 3,
        y: h / 3,
        w: (w / 3).max(1),
        h: (h / 3).max(1),
    }
}

/// Segments both views of a pair (in parallel) with `method`, `levels` and
/// `seed`. With `carry_margin`, the right view is then made stereo-consistent
/// ([`carry_over`]): each right pixel is offered the left view's label at
/// x + s in the right view's numbering, s the stereo shift of its block and
/// row that the label coder would choose for the independent segmentation
/// ([`labels::plan_shifts`] against [`container::right_prediction`]), and
/// takes it where its colour is consistent with that class within the
/// margin (levels per channel for the thresholding methods, RGB distance
/// for the others); pixels shifted past the right edge keep their label.
/// Carrying along the coder's own shifts makes the carried labels exactly
/// what it predicts.
pub fn segment_pair(
    (left, right): (&RgbImage, &RgbImage),
    method: &Method,
    (levels, seed): (usize, u64),
    carry_margin: Option<f32>,
) -> anyhow::Result<(Segmentation, Segmentation)> {
    let (sl, sr) = rayon::join(
        || segment(left, method, levels, seed),
        || segment(right, method, levels, seed),
    );
    let (sl, sr) = (
        sl.context("segmenting the left view")?,
        sr.context("segmenting the right view")?,
    );
    let Some(margin) = carry_margin else {
        return Ok((sl, sr));
    };
    let predicted = container::right_prediction(&sl.image, &sr.image);
    let shifts = labels::plan_shifts(sr.image.labels(), &predicted, container::SHIFT_SEARCH);
    let (w, h) = predicted.dims();
    let blocks = w.div_ceil(labels::BLOCK);
    let carried = LabelMap::from_fn(w, h, |x, y| {
        let xs = x + shifts[y * blocks + x / labels::BLOCK] as usize;
        if xs < w {
            predicted.get(xs, y)
        } else {
            NOTHING
        }
    });
    let sr = carry_over(right, &sr, &carried, margin);
    Ok((sl, sr))
}

/// The plane matcher's disparity on the original pair, with the planes
/// fitted to the transmitted left labels: its map is the one its plane
/// table rebuilds, the very map a receiver rebuilds from the frame.
fn plane_depth(
    (left, right): (&RgbImage, &RgbImage),
    left_labels: &LabelMap,
    cfg: &SenderConfig,
) -> anyhow::Result<(DisparityMap, PlaneTable)> {
    // The table carries a plane per segment of the labels cut by the
    // tiles, as the receiver finds them: no further cut of bent segments,
    // and no per-pixel boundary step, which would be thrown away.
    let mut spec = cfg.matcher.clone();
    spec.planes.split = 0.0;
    spec.planes.boundary.radius = 0;
    let matched = match_planes(left, right, left_labels, &spec)?;
    let table = planetable::table_of(&matched, &spec, cfg.plane_table)?;
    let mut disparity = DisparityMap::default();
    planetable::rebuild_into(left_labels, &table, &mut disparity)?;
    Ok((disparity, table))
}

/// The depth of one pair: the sender's disparity map, the plane table
/// that rebuilds it (plane matcher only) and the depth report.
pub struct Depth {
    /// The sender's disparity map.
    pub disparity: DisparityMap,
    /// The plane table (with the plane matcher).
    pub planes: Option<PlaneTable>,
    /// The depth report.
    pub report: DepthReport,
    /// Matching time, ms.
    pub match_ms: f64,
}

/// Matches a pair and builds its depth report. The plane matcher fits its
/// planes to the left view's labels: those transmitted when given, else the
/// left view is segmented for them (a report sent without a frame).
pub fn measure_depth(
    (left, right): (&RgbImage, &RgbImage),
    left_labels: Option<&LabelMap>,
    calib: &Calibration,
    cfg: &SenderConfig,
) -> anyhow::Result<Depth> {
    anyhow::ensure!(
        left.dims() == right.dims(),
        "left is {:?} but right is {:?}",
        left.dims(),
        right.dims()
    );
    let t = Instant::now();
    let (disparity, planes) = if cfg.matcher.algorithm != Algorithm::Planes {
        (Matcher::new().compute(left, right, &cfg.matcher)?, None)
    } else {
        let segmented;
        let labels = match left_labels {
            Some(l) => l,
            None => {
                segmented = segment(left, &cfg.method, cfg.levels, cfg.seed)
                    .context("segmenting the left view")?;
                segmented.image.labels()
            }
        };
        let (disparity, table) = plane_depth((left, right), labels, cfg)?;
        (disparity, Some(table))
    };
    let match_ms = t.elapsed().as_secs_f64() * 1e3;
    let report = depth_report(&disparity, calib, cfg);
    Ok(Depth {
        disparity,
        planes,
        report,
        match_ms,
    })
}

/// The depth report of a disparity map: the target region's distance,
/// the depth levels with their distances, the histogram.
fn depth_report(disparity: &DisparityMap, calib: &Calibration, cfg: &SenderConfig) -> DepthReport {
    let (w, h) = disparity.dims();
    let roi = cfg.roi.unwrap_or_else(|| default_roi(w, h));
    let distance = region_distance(disparity, roi, calib).ok().flatten();
    let levels = depth_levels(disparity, &cfg.levels_spec);
    let focal_baseline = metric(calib).ok();
    let metric = |d: f32| {
        focal_baseline
            .and_then(|(f, b)| depth_of(d, f, b, calib.doffs))
            .map_or(f32::NAN, |z| z as f32)
    };
    DepthReport {
        target_distance_m: distance.map_or(f32::NAN, |d| d as f32),
        target_region: [roi.x, roi.y, roi.w, roi.h].map(|v| v.min(u16::MAX as usize) as u16),
        levels: levels
            .levels
            .iter()
            .map(|l| ReportLevel {
                disparity: l.disparity,
                distance_m: metric(l.disparity),
                share: l.share as f32,
            })
            .collect(),
        histogram: levels.histogram,
    }
}

/// A depth report as the message of pair `pair_id`, captured at
/// `captured_us`.
pub fn report_message(report: &DepthReport, pair_id: u32, captured_us: u64) -> Vec<u8> {
    container::encode(&Message::DepthReport(report.clone()), pair_id, captured_us)
}

/// Codes the views (segmented or lossy, fitted to the budget), matches,
/// encodes and reports pair `frame_id`, captured at `captured_us` (the
/// messages' time stamp).
pub fn prepare(
    left: &RgbImage,
    right: &RgbImage,
    calib: &Calibration,
    cfg: &SenderConfig,
    ids: (u32, u64),
) -> anyhow::Result<Prepared> {
    prepare_with(left, right, calib, cfg, ids, None)
}

/// A pair of segmentations.
pub(crate) type SegmentedPair = (Segmentation, Segmentation);

/// How a stream codes a predicted frame ([`crate::stream`]).
pub(crate) enum Predict<'a> {
    /// Lossy views: the qualities the frame may take, and its views at a
    /// quality.
    Lossy {
        qualities: RangeInclusive<u8>,
        views: &'a mut dyn FnMut(u8) -> anyhow::Result<(View, View)>,
    },
    /// Segmented views: the segmentations made consistent with the
    /// reference's (before the plane matcher fits them), and the views the
    /// label maps of a number of classes are coded as.
    Labels {
        carry: &'a mut dyn FnMut(SegmentedPair) -> SegmentedPair,
        views: &'a mut dyn FnMut(u8, IndexedImage, IndexedImage) -> (View, View),
    },
}

/// [`prepare`], with the views coded by `predict` when given.
pub(crate) fn prepare_with(
    left: &RgbImage,
    right: &RgbImage,
    calib: &Calibration,
    cfg: &SenderConfig,
    (frame_id, captured_us): (u32, u64),
    mut predict: Option<Predict>,
) -> anyhow::Result<Prepared> {
    anyhow::ensure!(
        left.dims() == right.dims(),
        "left is {:?} but right is {:?}",
        left.dims(),
        right.dims()
    );
    let planes = cfg.matcher.algorithm == Algorithm::Planes;
    let ids = (frame_id, captured_us, labels::Mode::default());
    let settings = cfg.coding.settings(cfg.levels);
    let (mut seg_ms, mut match_ms) = (0.0, 0.0);
    let t_all = Instant::now();
    // The plane matcher's map comes with each segmentation tried; any
    // other matcher's does not depend on it and is computed once.
    let mut plane_maps = BTreeMap::new();
    let coded = match cfg.coding.coding {
        ViewCoding::Lossy(codec) => {
            anyhow::ensure!(
                !planes,
                "the plane matcher's table needs segmented views (--view-coding segmented)"
            );
            let settings = match &predict {
                Some(Predict::Lossy { qualities, .. }) => qualities.clone(),
                _ => settings,
            };
            encode_fitted(settings, cfg.coding.budget, ids, |q| {
                let (l, r) = match predict.as_mut() {
                    Some(Predict::Lossy { views, .. }) => views(q)?,
                    _ => lossy_views((left, right), codec, q, cfg.coding.stereo_prediction)?,
                };
                Ok(lossy_frame(codec, q, (l, r), Some(*calib)))
            })?
        }
        ViewCoding::Segmented => encode_fitted(settings, cfg.coding.budget, ids, |levels| {
            let t = Instant::now();
            let mut pair = segment_pair(
                (left, right),
                &cfg.method,
                (levels as usize, cfg.seed),
                cfg.carry_margin,
            )?;
            if let Some(Predict::Labels { carry, .. }) = predict.as_mut() {
                pair = carry(pair);
            }
            let (sl, sr) = pair;
            seg_ms += t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            let table = if planes {
                let (map, table) = plane_depth((left, right), sl.image.labels(), cfg)?;
                plane_maps.insert(levels, map);
                Some(table)
            } else {
                None
            };
            match_ms += t.elapsed().as_secs_f64() * 1e3;
            let thresholds = sl.channels.as_ref().map(|c| c.thresholds.clone());
            let (l, r) = match predict.as_mut() {
                Some(Predict::Labels { views, .. }) => views(levels, sl.image, sr.image),
                _ => (View::Indexed(sl.image), View::Indexed(sr.image)),
            };
            Ok(StereoFrame {
                kind: SegmentationKind::from_name(cfg.method.name())
                    .unwrap_or(SegmentationKind::None),
                levels,
                params: format!("seed={}", cfg.seed),
                thresholds,
                calibration: Some(*calib),
                left: l,
                right: r,
                planes: table,
            })
        })?,
    };
    let enc_ms = t_all.elapsed().as_secs_f64() * 1e3 - seg_ms - match_ms;
    let disparity = match plane_maps.remove(&coded.setting) {
        Some(d) => d,
        None => {
            let t = Instant::now();
            let d = Matcher::new().compute(left, right, &cfg.matcher)?;
            match_ms += t.elapsed().as_secs_f64() * 1e3;
            d
        }
    };
    let sent = (coded.frame.left.to_rgb(), coded.frame.right.to_rgb());
    let psnr_db = (
        psnr_rgb(left, &sent.0)?.overall,
        psnr_rgb(right, &sent.1)?.overall,
    );
    let frame_bytes = coded.bytes;
    let report = depth_report(&disparity, calib, cfg);
    let report_bytes = report_message(&report, frame_id, captured_us);
    Ok(Prepared {
        frame_bytes,
        report_bytes,
        sent,
        setting: coded.setting,
        disparity,
        report,
        psnr_db,
        times_ms: (seg_ms, enc_ms, match_ms),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereolink_image::synth::{synthesize, SynthSpec};

    fn config() -> SenderConfig {
        SenderConfig {
            method: Method::KMeans,
            levels: 3,
            seed: 1,
            carry_margin: Some(20.0),
            matcher: MatchSpec::new(Algorithm::Wta, 0, 16).unwrap(),
            roi: None,
            levels_spec: LevelSpec::default(),
            plane_table: TableCoding::default(),
            coding: CodingSpec::default(),
        }
    }

    /// A budget holds the segmented frame at the most classes that fit;
    /// lossy views with the plane matcher (which needs labels) are refused.
    #[test]
    fn a_segmented_pair_is_fitted_to_its_budget() {
        let s = synthesize(&SynthSpec {
            width: 96,
            height: 64,
            max_disp: 16,
            seed: 4,
        })
        .unwrap();
        let calib = s.calib;
        let mut cfg = SenderConfig {
            levels: 8,
            ..config()
        };
        let at = |cfg: &SenderConfig| prepare(&s.left, &s.right, &calib, cfg, (1, 0)).unwrap();
        let (two, eight) = (
            at(&SenderConfig {
                levels: 2,
                ..cfg.clone()
            }),
            at(&cfg),
        );
        assert!(two.frame_bytes.len() < eight.frame_bytes.len());
        let budget = (two.frame_bytes.len() + eight.frame_bytes.len()) / 2;
        cfg.coding.budget = Some(budget);
        let fitted = at(&cfg);
        assert!(fitted.frame_bytes.len() <= budget);
        assert!(
            (2..8).contains(&fitted.setting),
            "{} classes",
            fitted.setting
        );
        cfg.coding.budget = Some(two.frame_bytes.len() - 1);
        let e = prepare(&s.left, &s.right, &calib, &cfg, (1, 0))
            .err()
            .unwrap();
        assert!(e.to_string().contains("smallest frame"), "{e}");
        cfg.coding = CodingSpec {
            coding: ViewCoding::Lossy(stereolink_codec::lossy::LossyCodec::Webp),
            ..CodingSpec::default()
        };
        cfg.matcher = MatchSpec::new(Algorithm::Planes, 0, 16).unwrap();
        let e = prepare(&s.left, &s.right, &calib, &cfg, (1, 0))
            .err()
            .unwrap();
        assert!(e.to_string().contains("--view-coding segmented"), "{e}");
    }

    #[test]
    fn commands_change_the_next_pairs_settings_and_a_stop_is_refused() {
        let mut cfg = config();
        assert_eq!(cfg.apply(&Command::SetLevels(5)), Ok(Applied::FromNextPair));
        assert_eq!(cfg.levels, 5);
        let fodpso = Command::SetMethod("fodpso".into());
        assert_eq!(cfg.apply(&fodpso), Ok(Applied::FromNextPair));
        assert_eq!(cfg.method.name(), "fodpso");
        assert_eq!(cfg.carry_margin, Some(default_margin(&cfg.method)));
        assert_eq!(cfg.apply(&Command::FrameRequest), Ok(Applied::FrameNow));
        let stop = cfg.apply(&Command::AxisStop);
        assert!(stop.is_err_and(|e| e.contains("no axis")));
        assert_eq!((cfg.levels, cfg.method.name()), (5, "fodpso"));
    }
}
