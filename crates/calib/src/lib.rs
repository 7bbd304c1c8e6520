//! The sensor end of stereolink: from two cameras to a rectified pair.
//!
//! # Brief overview
//!
//! * [`camera`]: the pinhole + Brown–Conrady model (OpenCV's and the MATLAB
//!   toolbox's 5 coefficients) and rigid poses.
//! * [`chessboard`]: inner corners of a chessboard, ordered consistently
//!   between views and refined to subpixel accuracy ([`find_chessboard`]).
//! * [`rig`]: a calibrated stereo rig ([`StereoRig`]) and its Bouguet
//!   [`Rectification`], together a [`StereoCalibration`].
//!
//! Lengths (translations, the baseline) are in the units of the chessboard's
//! square size: give the square in metres and the baseline comes out in
//! metres.

#![deny(missing_docs)]

pub mod board;
pub mod camera;
pub mod chessboard;
mod error;
mod lm;
pub mod mono;
pub mod rectify;
pub mod rig;
pub mod stereo;
pub mod synth;
pub mod workflow;
mod zhang;

pub use camera::{Camera, Distortion, Pose};
pub use chessboard::{find_chessboard, BoardSize, ChessboardOptions, NotFound};
pub use error::{Error, Result};
pub use mono::{calibrate_camera, MonoCalibration};
pub use rectify::stereo_rectify;
pub use rig::{Rectification, StereoCalibration, StereoRig};
pub use stereo::{calibrate_stereo, StereoFit};
