//! A calibrated stereo rig and its rectification: the numbers that
//! OpenCV's `stereoCalibrate` and `stereoRectify` produce, in one type that
//! the files, the remap and the depth computation share.

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Vector3};

use crate::Camera;

/// Two calibrated cameras and the transform between them: a point `X_l` in
/// the left camera's frame is `X_r = R·X_l + T` in the right's (OpenCV's
/// `R` and `T`). `T` is in the units of the chessboard's square size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StereoRig {
    /// The left camera (the reference view).
    pub left: Camera,
    /// The right camera.
    pub right: Camera,
    /// `R`: left camera frame to right camera frame.
    pub rotation: Matrix3<f64>,
    /// `T`, in the square size's units.
    pub translation: Vector3<f64>,
}

impl StereoRig {
    /// The baseline `|T|`, in the square size's units.
    pub fn baseline(&self) -> f64 {
        self.translation.norm()
    }
}

/// Bouguet's rectification of a rig, as `cv::stereoRectify` returns it.
///
/// `R1`/`R2` rotate each camera's frame into the common rectified frame;
/// `P1`/`P2` project rectified 3-D points to the rectified images
/// (`P2[0][3] = f·Tx` with `Tx = −baseline` for a horizontal rig); `Q`
/// maps `(x, y, d, 1)` to homogeneous 3-D points.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rectification {
    /// Left rectifying rotation.
    pub r1: Matrix3<f64>,
    /// Right rectifying rotation.
    pub r2: Matrix3<f64>,
    /// Left rectified projection.
    pub p1: Matrix3x4<f64>,
    /// Right rectified projection.
    pub p2: Matrix3x4<f64>,
    /// Disparity-to-depth matrix.
    pub q: Matrix4<f64>,
    /// The rectified images' size (width, height).
    pub size: (usize, usize),
}

/// What a stereo calibration file holds: the rig and its rectification.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StereoCalibration {
    /// The cameras and their relative pose.
    pub rig: StereoRig,
    /// How to rectify their images.
    pub rectification: Rectification,
}

impl Rectification {
    /// The depth geometry of the rectified pair, from `P1` and `P2`: the
    /// focal length `f = P1[0][0]` in pixels, the baseline `b =
    /// −P2[0][3]/P2[0][0]` (in the square size's units) and `doffs =
    /// P2[0][2] − P1[0][2]`, so that `Z = b·f / (d + doffs)`.
    pub fn depth_geometry(&self) -> (f64, f64, f64) {
        let (p1, p2) = (&self.p1, &self.p2);
        (
            p1[(0, 0)],
            -p2[(0, 3)] / p2[(0, 0)],
            p2[(0, 2)] - p1[(0, 2)],
        )
    }
}
