//! From chessboard image pairs to a stereo calibration, as the
//! `calibrate` command runs it: detect the board in every image (in
//! parallel), keep the pairs where both views have it, calibrate the rig,
//! name the outlier pairs and optionally drop them and calibrate again,
//! then rectify and measure how well rows correspond.

use nalgebra::Point2;
use rayon::prelude::*;
use stereolink_image::GrayImage;

use crate::chessboard::{find_chessboard_with, BoardSize, ChessboardOptions, NotFound};
use crate::mono::{outlier_views, MIN_VIEWS};
use crate::rectify::rectified_point;
use crate::{calibrate_stereo, stereo_rectify, Error, Result, StereoCalibration, StereoFit};

/// How to calibrate.
#[derive(Clone, Copy, Debug)]
pub struct CalibrateOptions {
    /// The board's inner corners.
    pub board: BoardSize,
    /// The side of a square, in the unit the translations should have
    /// (metres for depth in metres).
    pub square: f64,
    /// Rectification's free scaling: 0 keeps only valid pixels, 1 all.
    pub alpha: f64,
    /// Drop the outlier pairs and calibrate again.
    pub drop_outliers: bool,
    /// Corner detection's tuning.
    pub chessboard: ChessboardOptions,
}

/// One image pair's part in the calibration.
#[derive(Clone, Debug, PartialEq)]
pub enum PairStatus {
    /// Both boards found and used.
    Used,
    /// An outlier by its reprojection error, kept or dropped.
    Outlier {
        /// Whether it was left out of the final calibration.
        dropped: bool,
    },
    /// The board was not found in one or both views.
    NoBoard {
        /// Why, in the left view.
        left: Option<NotFound>,
        /// Why, in the right view.
        right: Option<NotFound>,
    },
}

/// One image pair's report.
#[derive(Clone, Debug)]
pub struct PairReport {
    /// What became of it.
    pub status: PairStatus,
    /// The left view's RMS reprojection error (left camera alone), pixels.
    pub left_rms: Option<f64>,
    /// The right view's (right camera alone).
    pub right_rms: Option<f64>,
    /// The pair's joint RMS error in the stereo calibration.
    pub stereo_rms: Option<f64>,
}

/// Everything a calibration run found.
#[derive(Clone, Debug)]
pub struct CalibrationReport {
    /// The rig and its rectification.
    pub calibration: StereoCalibration,
    /// The final fit, with per-camera results.
    pub fit: StereoFit,
    /// One entry per input pair, in input order.
    pub pairs: Vec<PairReport>,
    /// Mean `|y_left − y_right|` of corresponding corners after
    /// rectification, pixels, over the pairs used.
    pub mean_row_offset: f64,
    /// The largest such offset.
    pub max_row_offset: f64,
}

/// The corners of both views of every pair, `None` where not found.
type Detections = Vec<(
    std::result::Result<Vec<Point2<f64>>, NotFound>,
    std::result::Result<Vec<Point2<f64>>, NotFound>,
)>;

/// Calibrates from pairs of chessboard images; `names` label the pairs in
/// errors. `progress` is called once per image searched.
pub fn calibrate_images(
    pairs: &[(GrayImage, GrayImage)],
    names: &[String],
    options: &CalibrateOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<CalibrationReport> {
    let size = check_sizes(pairs, names)?;
    if !(options.square.is_finite() && options.square > 0.0) {
        return Err(Error::Invalid(format!(
            "the square size {} is not positive",
            options.square
        )));
    }
    let detections: Detections = pairs
        .par_iter()
        .map(|(l, r)| {
            let find = |img: &GrayImage| {
                let found = find_chessboard_with(img, options.board, &options.chessboard);
                progress();
                found
            };
            (find(l), find(r))
        })
        .collect();
    let mut status: Vec<PairStatus> = detections
        .iter()
        .map(|(l, r)| match (l, r) {
            (Ok(_), Ok(_)) => PairStatus::Used,
            _ => PairStatus::NoBoard {
                left: l.as_ref().err().copied(),
                right: r.as_ref().err().copied(),
            },
        })
        .collect();
    let object = options.board.points(options.square);
    let fit_used = |status: &[PairStatus]| -> Result<(Vec<usize>, StereoFit)> {
        let used: Vec<usize> = (0..pairs.len())
            .filter(|&i| {
                status[i] == PairStatus::Used || status[i] == PairStatus::Outlier { dropped: false }
            })
            .collect();
        if used.len() < MIN_VIEWS {
            return Err(too_few(&detections, names, used.len(), options.board));
        }
        let corners = |right: bool| -> Vec<Vec<Point2<f64>>> {
            used.iter()
                .map(|&i| {
                    let d = if right {
                        &detections[i].1
                    } else {
                        &detections[i].0
                    };
                    d.clone().unwrap_or_default()
                })
                .collect()
        };
        let fit = calibrate_stereo(&object, &corners(false), &corners(true), size)?;
        Ok((used, fit))
    };
    let (mut used, mut fit) = fit_used(&status)?;
    let outliers: Vec<usize> = outlier_views(&fit.pair_rms)
        .into_iter()
        .map(|k| used[k])
        .collect();
    for &i in &outliers {
        status[i] = PairStatus::Outlier {
            dropped: options.drop_outliers,
        };
    }
    if options.drop_outliers && !outliers.is_empty() {
        (used, fit) = fit_used(&status)?;
    }
    let rectification = stereo_rectify(&fit.rig, options.alpha)?;
    let calibration = StereoCalibration {
        rig: fit.rig,
        rectification,
    };

    let (r1, k1) = rectification.view(false);
    let (r2, k2) = rectification.view(true);
    let mut offsets = Vec::new();
    for &i in &used {
        if let (Ok(l), Ok(r)) = &detections[i] {
            for (p, q) in l.iter().zip(r) {
                let a = rectified_point(&fit.rig.left, &r1, &k1, *p);
                let b = rectified_point(&fit.rig.right, &r2, &k2, *q);
                offsets.push((a.y - b.y).abs());
            }
        }
    }
    let mean_row_offset = offsets.iter().sum::<f64>() / offsets.len().max(1) as f64;
    let max_row_offset = offsets.iter().copied().fold(0.0, f64::max);

    let mut reports: Vec<PairReport> = status
        .into_iter()
        .map(|status| PairReport {
            status,
            left_rms: None,
            right_rms: None,
            stereo_rms: None,
        })
        .collect();
    for (k, &i) in used.iter().enumerate() {
        reports[i].left_rms = Some(fit.left.view_rms[k]);
        reports[i].right_rms = Some(fit.right.view_rms[k]);
        reports[i].stereo_rms = Some(fit.pair_rms[k]);
    }
    Ok(CalibrationReport {
        calibration,
        fit,
        pairs: reports,
        mean_row_offset,
        max_row_offset,
    })
}

/// The common size of all images, or an error naming the odd one.
fn check_sizes(pairs: &[(GrayImage, GrayImage)], names: &[String]) -> Result<(usize, usize)> {
    let Some((first, _)) = pairs.first() else {
        return Err(Error::TooFewViews {
            found: 0,
            needed: MIN_VIEWS,
            hint: "no image pairs were given".into(),
        });
    };
    let size = first.dims();
    for (i, (l, r)) in pairs.iter().enumerate() {
        let name = names.get(i).map(String::as_str).unwrap_or("?");
        for (side, img) in [("left", l), ("right", r)] {
            if img.dims() != size {
                return Err(Error::SizeMismatch(format!(
                    "pair {name}: the {side} image is {}x{}, the first left image {}x{}; \
                     all images must come from cameras at one resolution",
                    img.width(),
                    img.height(),
                    size.0,
                    size.1
                )));
            }
        }
    }
    Ok(size)
}

/// The error for too few usable pairs, naming the images without a board
/// and suggesting a transposed or different board size where detection
/// saw one.
fn too_few(detections: &Detections, names: &[String], found: usize, board: BoardSize) -> Error {
    let mut missing = Vec::new();
    let mut other_size = None;
    for (i, (l, r)) in detections.iter().enumerate() {
        for (side, d) in [("left", l), ("right", r)] {
            if let Err(reason) = d {
                let name = names.get(i).map(String::as_str).unwrap_or("?");
                missing.push(format!("{name} ({side}): {reason}"));
                if let NotFound::WrongSize { found, .. } | NotFound::Partial { found, .. } = reason
                {
                    other_size.get_or_insert(*found);
                }
            }
        }
    }
    let shown = missing.len().min(6);
    let mut hint = format!("no board in {}", missing[..shown].join("; "));
    if missing.len() > shown {
        hint.push_str(&format!("; and {} more", missing.len() - shown));
    }
    match other_size {
        Some(s) if s == board.transposed() => hint.push_str(&format!(
            "; the board size may be transposed: try --board {s}"
        )),
        Some(s) => hint.push_str(&format!("; a {s} grid was seen: is --board {board} right?")),
        None => {}
    }
    Error::TooFewViews {
        found,
        needed: MIN_VIEWS,
        hint,
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use super::*;
    use crate::board::tests::spread_poses;
    use crate::stereo::tests::rig;
    use crate::synthetic::{render_board, RenderSpec};
    use crate::Pose;

    const BOARD: BoardSize = BoardSize { cols: 9, rows: 6 };

    fn options() -> CalibrateOptions {
        CalibrateOptions {
            board: BOARD,
            square: 0.025,
            alpha: 0.0,
            drop_outliers: false,
            chessboard: ChessboardOptions::default(),
        }
    }

    /// `n` rendered pairs of the test rig.
    fn rendered_pairs(n: usize) -> (Vec<(GrayImage, GrayImage)>, Vec<String>) {
        let rig = rig();
        let between = Pose::from_matrix(&rig.rotation, rig.translation);
        let spec = RenderSpec {
            board: BOARD,
            square: 0.025,
            samples: 3,
            noise: 2.0,
            seed: 0,
        };
        let pairs = spread_poses(0.025, n)
            .into_iter()
            .enumerate()
            .map(|(i, p)| {
                let p = Pose {
                    translation: p.translation.component_mul(&Vector3::new(0.5, 0.5, 2.0))
                        + Vector3::new(0.03, 0.0, 0.0),
                    ..p
                };
                let l = render_board(
                    &rig.left,
                    &p,
                    &RenderSpec {
                        seed: 2 * i as u64,
                        ..spec
                    },
                );
                let r = render_board(
                    &rig.right,
                    &p.then(&between),
                    &RenderSpec {
                        seed: 2 * i as u64 + 1,
                        ..spec
                    },
                );
                (l, r)
            })
            .collect();
        (pairs, (1..=n).map(|i| format!("{i:02}")).collect())
    }

    #[test]
    fn rendered_views_calibrate_back_to_the_rig() {
        let truth = rig();
        let (pairs, names) = rendered_pairs(12);
        let report = calibrate_images(&pairs, &names, &options(), &|| {}).unwrap();
        let got = report.calibration.rig;
        assert!(
            report.pairs.iter().all(|p| p.status == PairStatus::Used),
            "{:?}",
            report.pairs
        );
        assert!(report.fit.rms < 0.1, "rms {}", report.fit.rms);
        for (c, t) in [(got.left, truth.left), (got.right, truth.right)] {
            assert!((c.fx / t.fx - 1.0).abs() < 2e-3, "{c:?}");
            assert!(
                (c.cx - t.cx).abs() < 2.0 && (c.cy - t.cy).abs() < 2.0,
                "{c:?}"
            );
        }
        assert!(
            (got.baseline() / truth.baseline() - 1.0).abs() < 5e-3,
            "{}",
            got.baseline()
        );
        // Rows agree to the corners' own noise (about 0.06 px RMS here).
        assert!(report.mean_row_offset < 0.1, "{}", report.mean_row_offset);
    }

    #[test]
    fn pairs_without_a_board_are_named_and_too_few_refused() {
        let (mut pairs, names) = rendered_pairs(3);
        pairs[1].1 = GrayImage::new(640, 480, 128);
        let err = calibrate_images(&pairs, &names, &options(), &|| {})
            .unwrap_err()
            .to_string();
        assert!(err.contains("2 usable view(s), at least 3"), "{err}");
        assert!(err.contains("02 (right)"), "{err}");
    }

    #[test]
    fn a_transposed_board_size_is_suggested() {
        let (pairs, names) = rendered_pairs(3);
        let opts = CalibrateOptions {
            board: BoardSize { cols: 6, rows: 9 },
            ..options()
        };
        match calibrate_images(&pairs, &names, &opts, &|| {}) {
            // A detector that reads the board either way round is fine too.
            Ok(report) => assert!(report.fit.rms < 0.1),
            Err(e) => assert!(e.to_string().contains("transposed"), "{e}"),
        }
    }

    #[test]
    fn mismatched_sizes_are_refused() {
        let (mut pairs, names) = rendered_pairs(3);
        pairs[2].1 = GrayImage::new(320, 240, 0);
        let err = calibrate_images(&pairs, &names, &options(), &|| {})
            .unwrap_err()
            .to_string();
        assert!(err.contains("pair 03: the right image is 320x240"), "{err}");
    }
}
