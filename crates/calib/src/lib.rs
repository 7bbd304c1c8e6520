//! The sensor end of stereolink: from two cameras to a rectified pair.
//!
//! # Brief overview
//!
//! The data's way, in module order:
//!
//! * [`board`]: the chessboard's size ([`BoardSize`]) and its corners as
//!   board points.
//! * [`chessboard`]: inner corners found in an image, ordered consistently
//!   between views and refined to subpixel accuracy ([`find_chessboard`]).
//! * [`camera`]: the pinhole + Brown–Conrady model (OpenCV's and the MATLAB
//!   toolbox's 5 coefficients) and rigid poses.
//! * [`mono`]: one camera's calibration, Zhang's closed form then
//!   Levenberg–Marquardt ([`calibrate_camera`]).
//! * [`stereo`]: both cameras and `R`, `T` jointly ([`calibrate_stereo`]).
//! * [`rectify`]: Bouguet's rectification as `cv::stereoRectify`
//!   ([`stereo_rectify`]).
//! * [`rig`]: a calibrated stereo rig ([`StereoRig`]) and its
//!   [`Rectification`], together a [`StereoCalibration`].
//! * [`workflow`]: image pairs to a calibration, as `stereolink calibrate`
//!   runs it: detect, pair, calibrate, name outliers, rectify.
//! * [`files`]: the calibration files, OpenCV `FileStorage` YAML (read and
//!   written) and ROS `camera_info` YAML (written).
//! * [`remap`]: the rectification maps, computed once and applied to every
//!   frame in fixed point ([`RectifyMap`], [`StereoRectifier`]).
//! * [`preview`]: a rectified pair side by side with horizontal guide lines,
//!   for a person to judge a calibration.
//! * [`synthetic`]: chessboard views through a known rig, rigs around a
//!   known rectification and raw views rendered from rectified ones: the
//!   truth of tests and benches.
//!
//! Lengths (translations, the baseline) are in the units of the chessboard's
//! square size: give the square in metres and the baseline comes out in
//! metres.

pub mod board;
pub mod camera;
pub mod chessboard;
mod error;
pub mod files;
mod lm;
pub mod mono;
pub mod preview;
pub mod rectify;
pub mod remap;
pub mod rig;
pub mod stereo;
pub mod synthetic;
pub mod workflow;
mod zhang;

pub use camera::{Camera, Distortion, Pose};
pub use chessboard::{find_chessboard, BoardSize, ChessboardOptions, NotFound};
pub use error::{Error, Result};
pub use mono::{calibrate_camera, MonoCalibration};
pub use rectify::stereo_rectify;
pub use remap::{RectifyMap, StereoRectifier};
pub use rig::{Rectification, StereoCalibration, StereoRig};
pub use stereo::{calibrate_stereo, StereoFit};
