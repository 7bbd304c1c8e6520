//! Depth from a calibration file alone: the focal length, baseline and
//! `doffs` the receiver turns disparities into distances with, from an
//! OpenCV `stereoRectify` YAML (the rectified projection matrices `P2`,
//! and `P1` for `doffs`) or a ROS `camera_info` YAML of the right camera
//! (`projection_matrix`). Both are read by the one FileStorage reader of
//! [`super::opencv`] (ROS's matrices have the same `rows`/`cols`/`data`
//! layout).
//!
//! A rectified right camera's projection matrix is
//! `[f 0 cx' f·Tx; 0 f cy 0; 0 0 1 0]` with `Tx = −b`, so it alone gives
//! the focal length `f` and the baseline `b = −P[0][3] / P[0][0]`; with the
//! left one too, `doffs = cx' − cx`. The baseline is in the units of the
//! calibration: metres for ROS; for OpenCV those of the calibration target,
//! which `metres_per_unit` scales.

use std::path::Path;

use stereolink_image::Calibration;

use super::opencv::Doc;
use crate::Result;

/// Reads focal length, baseline and `doffs` from an OpenCV `stereoRectify`
/// YAML or a ROS right camera's `camera_info` YAML; `path` names the file
/// in errors. `metres_per_unit` converts the file's translation to metres
/// (1 for ROS and for an OpenCV calibration in metres, 0.001 for one in
/// millimetres).
pub fn depth_from_yaml(text: &str, path: &Path, metres_per_unit: f64) -> Result<Calibration> {
    let doc = Doc::parse(text, path);
    let projection = |key: &str| doc.fixed(key, "a rectified projection matrix", 3, 4);
    let (right, left) = if doc.has("P2") {
        let left = doc.has("P1").then(|| projection("P1")).transpose()?;
        (projection("P2")?, left)
    } else if doc.has("projection_matrix") {
        (projection("projection_matrix")?, None)
    } else {
        return Err(doc.error(
            "no projection matrix: expected P1 and P2 (OpenCV stereoRectify) or \
             projection_matrix (ROS camera_info)"
                .into(),
        ));
    };
    let f = right[(0, 0)];
    if !(f.is_finite() && f > 0.0) {
        return Err(doc.error(format!("focal length {f} is not positive")));
    }
    let baseline = -right[(0, 3)] / f * metres_per_unit;
    if !(baseline.is_finite() && baseline > 0.0) {
        return Err(doc.error(format!(
            "baseline {baseline} m is not positive: this is the left camera's matrix \
             (give the right camera's, whose P[0][3] = −f·b)"
        )));
    }
    Ok(Calibration {
        focal_px: Some(f),
        baseline_m: Some(baseline),
        doffs: left.map_or(0.0, |l| right[(0, 2)] - l[(0, 2)]),
        ndisp: 0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// As `cv::FileStorage` writes `stereoRectify`'s output (millimetres).
    const OPENCV: &str = "%YAML:1.0
---
R1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]
P1: !!opencv-matrix
   rows: 3
   cols: 4
   dt: d
   data: [ 7.0e+02, 0., 3.1e+02, 0., 0., 7.0e+02, 2.4e+02, 0., 0., 0.,
       1., 0. ]
P2: !!opencv-matrix
   rows: 3
   cols: 4
   dt: d
   data: [ 7.0e+02, 0., 3.2e+02, -4.2e+04, 0., 7.0e+02, 2.4e+02, 0.,
       0., 0., 1., 0. ]
";

    /// A ROS `camera_info` of the right camera (metres).
    const ROS: &str = "image_width: 640
image_height: 480
camera_name: right
camera_matrix:
  rows: 3
  cols: 3
  data: [700, 0, 320, 0, 700, 240, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [700, 0, 320, -42, 0, 700, 240, 0, 0, 0, 1, 0]
";

    fn read(text: &str, metres_per_unit: f64) -> Result<Calibration> {
        depth_from_yaml(text, Path::new("cam.yaml"), metres_per_unit)
    }

    #[test]
    fn reads_opencv_stereo_rectify_output() {
        let c = read(OPENCV, 0.001).unwrap();
        assert_eq!(c.focal_px, Some(700.0));
        assert!((c.baseline_m.unwrap() - 0.06).abs() < 1e-12);
        assert_eq!(c.doffs, 10.0);
    }

    #[test]
    fn reads_a_ros_right_camera_info() {
        let c = read(ROS, 1.0).unwrap();
        assert_eq!((c.focal_px, c.doffs), (Some(700.0), 0.0));
        assert!((c.baseline_m.unwrap() - 0.06).abs() < 1e-12);
    }

    #[test]
    fn bad_files_are_clear_errors_naming_the_file() {
        let cases = [
            (ROS.replace("-42", "0"), "left camera"),
            ("a: 1".to_string(), "no projection"),
            (ROS.replace("0, 0, 1, 0]", "0, 1]"), "10 values for a 3x4"),
            (ROS.replace("-42", "minus"), "not a finite number"),
            (
                "projection_matrix:\n  rows: 3\n  cols: 4\n  data: [700, 0,".into(),
                "not one [ … ] list",
            ),
            ("projection_matrix:\n  rows: 3\n".into(), "has no cols"),
            (
                ROS.replace("rows: 3\n  cols: 4", "rows: 4\n  cols: 3"),
                "is 4x3, not 3x4",
            ),
        ];
        for (text, want) in cases {
            let e = read(&text, 1.0).unwrap_err().to_string();
            assert!(e.contains("cam.yaml") && e.contains(want), "{want}: {e}");
        }
    }
}
