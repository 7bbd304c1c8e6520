//! Calibration files: OpenCV `FileStorage` YAML for the pair ([`opencv`],
//! read and written, so that OpenCV users and we load each other's files),
//! ROS `camera_info` YAML for each camera ([`ros`], written), and the depth
//! geometry alone from either ([`depth`], read through the one OpenCV
//! reader).
//!
//! Translations (`T`, `P2[0][3]`) are in the units of the chessboard's
//! square size, as the calibration measured them; `docs/calibration.md`
//! describes the files.

pub mod depth;
pub mod opencv;
pub mod ros;

pub use depth::depth_from_yaml;
pub use opencv::{
    from_opencv_yaml, is_opencv_yaml, read_opencv, read_text, to_opencv_yaml, write_opencv,
};
pub use ros::{to_camera_info_yaml, write_camera_info, Side};

#[cfg(test)]
pub(crate) mod tests {
    use nalgebra::{Rotation3, Vector3};

    use crate::synthetic::{rig_around, RectifiedGeometry};
    use crate::{Camera, Distortion, StereoCalibration};

    /// A C-310-like rig with distortion, turned cameras and a 6 cm
    /// baseline, around a known rectification.
    pub(crate) fn calibration() -> StereoCalibration {
        let cam = |fx: f64, k1: f64| Camera {
            fx,
            fy: fx - 1.5,
            cx: 322.25,
            cy: 238.75,
            distortion: Distortion {
                k1,
                k2: 0.12,
                p1: 0.001,
                p2: -0.0015,
                k3: -0.02,
            },
            width: 640,
            height: 480,
        };
        let r1 = *Rotation3::from_scaled_axis(Vector3::new(0.01, -0.02, 0.005)).matrix();
        let r2 = *Rotation3::from_scaled_axis(Vector3::new(-0.008, 0.015, -0.004)).matrix();
        rig_around(
            cam(670.5, -0.3),
            cam(668.0, -0.28),
            r1,
            r2,
            &RectifiedGeometry {
                focal: 655.0,
                cx: 318.5,
                cy: 241.0,
                doffs: 3.5,
                baseline: 0.06,
                size: (640, 480),
            },
        )
    }
}
