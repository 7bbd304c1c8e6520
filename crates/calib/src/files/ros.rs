//! ROS `camera_info` YAML, one file per camera, in the layout of ROS's
//! `camera_calibration_parsers` (what `camera_calibration` writes and
//! `camera_info_manager` loads): the camera matrix, `plumb_bob` distortion
//! (the same 5 coefficients), the rectifying rotation and the rectified
//! projection. ROS expects the projection's `Tx` in metres: calibrate with
//! the square size in metres.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Matrix3, Matrix3x4};

use crate::{Camera, Error, Result, StereoCalibration};

/// Which camera of the rig.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// The left (reference) camera: `R1`, `P1`.
    Left,
    /// The right camera: `R2`, `P2`.
    Right,
}

impl Side {
    /// `left` or `right`, the default camera name.
    pub fn name(self) -> &'static str {
        match self {
            Side::Left => "left",
            Side::Right => "right",
        }
    }
}

/// Appends a `rows`/`cols`/`data` mapping, data on one line.
fn write_matrix(out: &mut String, key: &str, rows: usize, cols: usize, data: &[f64]) {
    let list: Vec<String> = data.iter().map(|v| format!("{v:?}")).collect();
    let _ = write!(
        out,
        "{key}:\n  rows: {rows}\n  cols: {cols}\n  data: [{}]\n",
        list.join(", ")
    );
}

/// One camera's `camera_info` YAML; `name` is its `camera_name`.
pub fn to_camera_info_yaml(calib: &StereoCalibration, side: Side, name: &str) -> String {
    let rect = &calib.rectification;
    let (cam, r, p): (&Camera, &Matrix3<f64>, &Matrix3x4<f64>) = match side {
        Side::Left => (&calib.rig.left, &rect.r1, &rect.p1),
        Side::Right => (&calib.rig.right, &rect.r2, &rect.p2),
    };
    let rows = |m: &[f64], cols: usize| -> Vec<f64> {
        // nalgebra stores columns; ROS lists rows.
        let n = m.len() / cols;
        (0..n)
            .flat_map(|i| (0..cols).map(move |j| m[j * n + i]))
            .collect()
    };
    let mut out = String::new();
    let _ = writeln!(out, "image_width: {}", cam.width);
    let _ = writeln!(out, "image_height: {}", cam.height);
    let _ = writeln!(out, "camera_name: {name}");
    write_matrix(
        &mut out,
        "camera_matrix",
        3,
        3,
        &rows(cam.matrix().as_slice(), 3),
    );
    out.push_str("distortion_model: plumb_bob\n");
    write_matrix(
        &mut out,
        "distortion_coefficients",
        1,
        5,
        &cam.distortion.to_array(),
    );
    write_matrix(
        &mut out,
        "rectification_matrix",
        3,
        3,
        &rows(r.as_slice(), 3),
    );
    write_matrix(&mut out, "projection_matrix", 3, 4, &rows(p.as_slice(), 4));
    out
}

/// Writes [`to_camera_info_yaml`] to `path`.
pub fn write_camera_info(path: &Path, calib: &StereoCalibration, side: Side) -> Result<()> {
    std::fs::write(path, to_camera_info_yaml(calib, side, side.name())).map_err(|source| {
        Error::Io {
            path: path.to_owned(),
            source,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::files::tests::calibration;

    /// The `data` list of `key`.
    fn data(text: &str, key: &str) -> Vec<f64> {
        let at = text.find(&format!("{key}:\n")).unwrap();
        let list = &text[at..];
        let list = &list[list.find("data: [").unwrap() + 7..];
        list[..list.find(']').unwrap()]
            .split(", ")
            .map(|v| v.parse().unwrap())
            .collect()
    }

    #[test]
    fn holds_each_cameras_matrices_row_major() {
        let c = calibration();
        let left = to_camera_info_yaml(&c, Side::Left, "left");
        assert!(left.starts_with("image_width: 640\nimage_height: 480\ncamera_name: left\n"));
        assert!(left.contains("distortion_model: plumb_bob\n"));
        let k = data(&left, "camera_matrix");
        assert_eq!(
            k,
            [
                c.rig.left.fx,
                0.0,
                c.rig.left.cx,
                0.0,
                c.rig.left.fy,
                c.rig.left.cy,
                0.0,
                0.0,
                1.0
            ]
        );
        assert_eq!(
            data(&left, "distortion_coefficients"),
            c.rig.left.distortion.to_array()
        );
        let right = to_camera_info_yaml(&c, Side::Right, "right");
        let p = data(&right, "projection_matrix");
        assert_eq!(p.len(), 12);
        for (i, v) in p.iter().enumerate() {
            assert_eq!(*v, c.rectification.p2[(i / 4, i % 4)]);
        }
        let r = data(&right, "rectification_matrix");
        assert_eq!(r[1], c.rectification.r2[(0, 1)]);
    }

    #[test]
    fn the_right_camera_info_gives_the_depth() {
        let c = calibration();
        let text = to_camera_info_yaml(&c, Side::Right, "right");
        let path = std::path::Path::new("right.yaml");
        let depth = super::super::depth_from_yaml(&text, path, 1.0).unwrap();
        let (f, b, _) = c.rectification.depth_geometry();
        assert_eq!(depth.focal_px, Some(f));
        assert!((depth.baseline_m.unwrap() - b).abs() < 1e-12);
    }
}
