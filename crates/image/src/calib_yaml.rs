//! Calibration from the YAML files that stereo calibration tools write: an
//! OpenCV `FileStorage` file with the rectified projection matrices `P1`
//! and `P2` of `cv::stereoRectify`, or a ROS `camera_info` file of the
//! right camera (`projection_matrix`).
//!
//! A rectified right camera's projection matrix is
//! `[f 0 cx' f·Tx; 0 f cy 0; 0 0 1 0]` with `Tx = −b`, so it alone gives
//! the focal length `f` and the baseline `b = −P[0][3] / P[0][0]`; with the
//! left one too, `doffs = cx' − cx`. The baseline is in the units of the
//! calibration: metres for ROS; for OpenCV those of the calibration target,
//! which [`Calibration::parse_yaml`] takes as a scale to metres.
//!
//! Only the matrices are read: each is a key followed, within a few lines,
//! by `data: [ … ]` (OpenCV's `!!opencv-matrix` and ROS's layout both are),
//! which no general YAML parser reads as is (OpenCV writes a `%YAML:1.0`
//! directive that YAML 1.2 parsers refuse).

use crate::scene::Calibration;

/// The numbers of the `data: [ … ]` list of matrix `key`, if the file has it.
fn matrix(text: &str, key: &str) -> Result<Option<Vec<f64>>, String> {
    let mut lines = text.lines();
    while let Some(line) = lines.next() {
        let Some(rest) = line.trim_start().strip_prefix(key) else {
            continue;
        };
        if !rest.trim_start().starts_with(':') {
            continue;
        }
        // `data:` follows within the matrix's few lines (rows, cols, dt).
        let mut list = String::new();
        for line in lines.by_ref().take(8) {
            if let Some(data) = line.trim_start().strip_prefix("data:") {
                list.push_str(data);
                break;
            }
        }
        if list.is_empty() {
            return Err(format!("{key} has no data list"));
        }
        // The list may continue over several lines until its `]`.
        while !list.contains(']') {
            match lines.next() {
                Some(more) => list.push_str(more),
                None => return Err(format!("{key}: the data list does not end")),
            }
        }
        let inner = list
            .trim()
            .strip_prefix('[')
            .and_then(|l| l.split(']').next())
            .ok_or_else(|| format!("{key}: the data is not a [ … ] list"))?;
        let values = inner
            .split(',')
            .map(|v| {
                v.trim()
                    .parse::<f64>()
                    .map_err(|_| format!("{key}: {:?} is not a number", v.trim()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        return Ok(Some(values));
    }
    Ok(None)
}

/// A 3×4 projection matrix of `key`, if present.
fn projection(text: &str, key: &str) -> Result<Option<[f64; 12]>, String> {
    matrix(text, key)?
        .map(|v| {
            <[f64; 12]>::try_from(v.as_slice())
                .map_err(|_| format!("{key} has {} values, not the 12 of a 3×4 matrix", v.len()))
        })
        .transpose()
}

impl Calibration {
    /// Reads focal length, baseline and `doffs` from an OpenCV
    /// `stereoRectify` YAML (`P2`, and `P1` for `doffs`) or a ROS right
    /// camera's `camera_info` YAML (`projection_matrix`). `metres_per_unit`
    /// converts the file's translation to metres (1 for ROS and for an
    /// OpenCV calibration in metres, 0.001 for one in millimetres).
    pub fn parse_yaml(text: &str, metres_per_unit: f64) -> Result<Self, String> {
        let (right, left) = match projection(text, "P2")? {
            Some(p2) => (p2, projection(text, "P1")?),
            None => match projection(text, "projection_matrix")? {
                Some(p) => (p, None),
                None => {
                    return Err("no projection matrix: expected P1 and P2 (OpenCV \
                                stereoRectify) or projection_matrix (ROS camera_info)"
                        .into())
                }
            },
        };
        let f = right[0];
        if !(f.is_finite() && f > 0.0) {
            return Err(format!("focal length {f} is not positive"));
        }
        let baseline = -right[3] / f * metres_per_unit;
        if !(baseline.is_finite() && baseline > 0.0) {
            return Err(format!(
                "baseline {baseline} m is not positive: this is the left camera's matrix \
                 (give the right camera's, whose P[0][3] = −f·b)"
            ));
        }
        Ok(Calibration {
            focal_px: Some(f),
            baseline_m: Some(baseline),
            doffs: left.map_or(0.0, |l| right[2] - l[2]),
            ndisp: 0,
        })
    }
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

    #[test]
    fn reads_opencv_stereo_rectify_output() {
        let c = Calibration::parse_yaml(OPENCV, 0.001).unwrap();
        assert_eq!(c.focal_px, Some(700.0));
        assert!((c.baseline_m.unwrap() - 0.06).abs() < 1e-12);
        assert_eq!(c.doffs, 10.0);
    }

    #[test]
    fn reads_a_ros_right_camera_info() {
        let c = Calibration::parse_yaml(ROS, 1.0).unwrap();
        assert_eq!((c.focal_px, c.doffs), (Some(700.0), 0.0));
        assert!((c.baseline_m.unwrap() - 0.06).abs() < 1e-12);
    }

    #[test]
    fn bad_files_are_clear_errors() {
        let left = ROS.replace("-42", "0");
        assert!(Calibration::parse_yaml(&left, 1.0)
            .unwrap_err()
            .contains("left camera"));
        assert!(Calibration::parse_yaml("a: 1", 1.0)
            .unwrap_err()
            .contains("no projection"));
        let short = ROS.replace("0, 0, 1, 0]", "0, 1]");
        assert!(Calibration::parse_yaml(&short, 1.0)
            .unwrap_err()
            .contains("12"));
        let word = ROS.replace("-42", "minus");
        assert!(Calibration::parse_yaml(&word, 1.0)
            .unwrap_err()
            .contains("not a number"));
        let open = "projection_matrix:\n  data: [700, 0,";
        assert!(Calibration::parse_yaml(open, 1.0)
            .unwrap_err()
            .contains("does not end"));
        let none = "projection_matrix:\n  rows: 3\n";
        assert!(Calibration::parse_yaml(none, 1.0)
            .unwrap_err()
            .contains("no data"));
    }
}
