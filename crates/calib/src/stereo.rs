//! Stereo calibration: each camera calibrated alone, the transform between
//! them started from the median of the per-view transforms, then one joint
//! Levenberg–Marquardt over both cameras' intrinsics, the left board poses
//! and `R`, `T`, as OpenCV's `stereoCalibrate` with
//! `CALIB_USE_INTRINSIC_GUESS` does. The right view of pair `i` sees the
//! board at `R·(R_i·X + t_i) + T`.
//!
//! The stereo RMS error is OpenCV's: `sqrt(Σ|eᵢ|² / N)` over the corners
//! of both views.

use nalgebra::{Point2, Point3, Vector3};

use crate::lm::{minimise, BlockProblem, LmOptions};
use crate::mono::{
    block_rms, calibrate_camera, camera_from, camera_params, check_views, focal_warnings,
    pose_from, pose_params, push_residuals, INTRINSICS,
};
use crate::{Error, MonoCalibration, Pose, Result, StereoRig};

/// The offset of the left poses in the parameter vector: both cameras'
/// intrinsics, then `R` and `T`.
const POSES: usize = 2 * INTRINSICS + 6;

/// A stereo rig's calibration and how well it fits.
#[derive(Clone, Debug)]
pub struct StereoFit {
    /// The rig.
    pub rig: StereoRig,
    /// The left camera calibrated alone (its RMS error is the per-camera figure).
    pub left: MonoCalibration,
    /// The right camera calibrated alone.
    pub right: MonoCalibration,
    /// The joint RMS reprojection error over both views' corners, pixels.
    pub rms: f64,
    /// Each pair's joint RMS error (left and right corners), pixels.
    pub pair_rms: Vec<f64>,
    /// What the user should know (poor constraints, swapped cameras).
    pub warnings: Vec<String>,
}

struct Stereo<'a> {
    object: &'a [Point3<f64>],
    left: &'a [Vec<Point2<f64>>],
    right: &'a [Vec<Point2<f64>>],
    size: (usize, usize),
}

impl BlockProblem for Stereo<'_> {
    fn blocks(&self) -> usize {
        self.left.len()
    }
    fn block_params(&self, b: usize) -> Vec<usize> {
        (0..POSES).chain(POSES + 6 * b..POSES + 6 * b + 6).collect()
    }
    fn residuals(&self, b: usize, x: &[f64], out: &mut Vec<f64>) {
        out.clear();
        let left = camera_from(x, self.size);
        let right = camera_from(&x[INTRINSICS..], self.size);
        let between = pose_from(&x[2 * INTRINSICS..]);
        let pose = pose_from(&x[POSES + 6 * b..]);
        push_residuals(&left, &pose, self.object, &self.left[b], out);
        push_residuals(
            &right,
            &pose.then(&between),
            self.object,
            &self.right[b],
            out,
        );
    }
}

/// The per-component median of the transforms from each left board pose
/// to the right one.
fn median_transform(left: &[Pose], right: &[Pose]) -> Pose {
    let transforms: Vec<Pose> = left
        .iter()
        .zip(right)
        .map(|(l, r)| {
            let rot = r.matrix() * l.matrix().transpose();
            Pose::from_matrix(&rot, r.translation - rot * l.translation)
        })
        .collect();
    let median = |f: &dyn Fn(&Pose) -> f64| {
        let mut v: Vec<f64> = transforms.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    Pose {
        rotation: Vector3::new(
            median(&|p| p.rotation.x),
            median(&|p| p.rotation.y),
            median(&|p| p.rotation.z),
        ),
        translation: Vector3::new(
            median(&|p| p.translation.x),
            median(&|p| p.translation.y),
            median(&|p| p.translation.z),
        ),
    }
}

/// Calibrates a stereo rig from pairs of views of the planar target
/// `object`: `left[i]` and `right[i]` are the corners of pair `i`, in the
/// order of `object`; both cameras' images are `size` (width, height).
pub fn calibrate_stereo(
    object: &[Point3<f64>],
    left: &[Vec<Point2<f64>>],
    right: &[Vec<Point2<f64>>],
    size: (usize, usize),
) -> Result<StereoFit> {
    if left.len() != right.len() {
        return Err(Error::SizeMismatch(format!(
            "{} left views but {} right views",
            left.len(),
            right.len()
        )));
    }
    check_views(object, left)?;
    check_views(object, right)?;
    let mono_left = calibrate_camera(object, left, size)?;
    let mono_right = calibrate_camera(object, right, size)?;
    let between = median_transform(&mono_left.poses, &mono_right.poses);
    let mut x0: Vec<f64> = camera_params(&mono_left.camera).to_vec();
    x0.extend(camera_params(&mono_right.camera));
    x0.extend(pose_params(&between));
    x0.extend(mono_left.poses.iter().flat_map(pose_params));
    let problem = Stereo {
        object,
        left,
        right,
        size,
    };
    let fit = minimise(&problem, x0, LmOptions::default());
    let between = pose_from(&fit.x[2 * INTRINSICS..]);
    let rig = StereoRig {
        left: camera_from(&fit.x, size),
        right: camera_from(&fit.x[INTRINSICS..], size),
        rotation: between.matrix(),
        translation: between.translation,
    };
    let (pair_rms, all) = block_rms(&problem, &fit.x);
    let sd = fit.std_devs();
    let mut warnings = focal_warnings(&rig.left, &std::array::from_fn(|i| sd[i]));
    warnings.extend(focal_warnings(
        &rig.right,
        &std::array::from_fn(|i| sd[INTRINSICS + i]),
    ));
    warnings.dedup();
    let t = rig.translation;
    if t.x.abs() >= t.y.abs() && t.x > 0.0 {
        warnings.push(format!(
            "the right camera is to the left of the left one (T = {:.4}, {:.4}, {:.4}): \
             swap the left and right images, or disparities will be negative",
            t.x, t.y, t.z
        ));
    }
    Ok(StereoFit {
        rig,
        left: mono_left,
        right: mono_right,
        rms: all,
        pair_rms,
        warnings,
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use nalgebra::Rotation3;

    use super::*;
    use crate::board::tests::spread_poses;
    use crate::mono::tests::{c310, views, CORNER_SIGMA};
    use crate::BoardSize;
    use crate::{Camera, Distortion};

    /// Two C-310-like cameras 6 cm apart, the right one turned by about 1°.
    pub(crate) fn rig() -> StereoRig {
        let right = Camera {
            fx: 668.3,
            fy: 666.0,
            cx: 325.2,
            cy: 236.8,
            distortion: Distortion {
                k1: -0.19,
                k2: 0.07,
                p1: -0.0006,
                p2: 0.0009,
                k3: 0.0,
            },
            ..c310()
        };
        StereoRig {
            left: c310(),
            right,
            rotation: *Rotation3::from_scaled_axis(Vector3::new(0.004, -0.015, 0.003)).matrix(),
            translation: Vector3::new(-0.06, 0.0008, -0.0012),
        }
    }

    /// Each view's corners.
    type Views = Vec<Vec<Point2<f64>>>;

    /// Noisy corners of the board seen by both cameras of `rig`.
    pub(crate) fn pair_views(rig: &StereoRig, seed: u64) -> (Views, Views) {
        // Boards centred between the cameras.
        let poses: Vec<Pose> = spread_poses(0.025, 25)
            .into_iter()
            .map(|p| Pose {
                translation: p.translation + Vector3::new(0.03, 0.0, 0.0),
                ..p
            })
            .collect();
        let between = Pose::from_matrix(&rig.rotation, rig.translation);
        let right_poses: Vec<Pose> = poses.iter().map(|p| p.then(&between)).collect();
        (
            views(&rig.left, &poses, CORNER_SIGMA, seed),
            views(&rig.right, &right_poses, CORNER_SIGMA, seed + 1000),
        )
    }

    #[test]
    fn recovers_the_rig_from_noisy_corners() {
        // RMS over ten draws, as for one camera.
        let truth = rig();
        let object = BoardSize::new(9, 6).points(0.025);
        let (mut f_sq, mut pp_sq, mut b_sq) = (0.0, 0.0, 0.0);
        let draws = 10;
        for seed in 0..draws {
            let (l, r) = pair_views(&truth, seed);
            let fit = calibrate_stereo(&object, &l, &r, (640, 480)).unwrap();
            for (c, t) in [(fit.rig.left, truth.left), (fit.rig.right, truth.right)] {
                f_sq += ((c.fx / t.fx - 1.0).powi(2) + (c.fy / t.fy - 1.0).powi(2)) / 4.0;
                pp_sq += ((c.cx - t.cx).powi(2) + (c.cy - t.cy).powi(2)) / 4.0;
            }
            b_sq += (fit.rig.baseline() / truth.baseline() - 1.0).powi(2);
            assert!((fit.rms - 0.2).abs() < 0.02, "rms {}", fit.rms);
            assert!(fit.warnings.is_empty(), "{:?}", fit.warnings);
        }
        let n = draws as f64;
        let (f_rms, pp_rms, b_rms) = ((f_sq / n).sqrt(), (pp_sq / n).sqrt(), (b_sq / n).sqrt());
        assert!(
            f_rms < 1e-3,
            "focal length RMS error {:.3} %",
            100.0 * f_rms
        );
        assert!(pp_rms < 0.5, "principal point RMS error {pp_rms} px");
        assert!(b_rms < 2e-3, "baseline RMS error {:.3} %", 100.0 * b_rms);
    }

    #[test]
    fn swapped_cameras_are_named() {
        let truth = rig();
        let object = BoardSize::new(9, 6).points(0.025);
        let (l, r) = pair_views(&truth, 1);
        let fit = calibrate_stereo(&object, &r, &l, (640, 480)).unwrap();
        assert!(
            fit.warnings.iter().any(|w| w.contains("swap")),
            "{:?}",
            fit.warnings
        );
    }

    #[test]
    fn unequal_view_counts_are_refused() {
        let truth = rig();
        let (l, mut r) = pair_views(&truth, 1);
        r.pop();
        let err =
            calibrate_stereo(&BoardSize::new(9, 6).points(0.025), &l, &r, (640, 480)).unwrap_err();
        assert!(
            err.to_string().contains("25 left views but 24 right"),
            "{err}"
        );
    }
}
