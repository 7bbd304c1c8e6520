//! Image buffers, file formats, colour spaces, metrics, datasets and synthetic
//! scenes: the vocabulary every other stereolink crate speaks.
//!
//! # Brief overview
//!
//! * [`Plane`] is a dense row-major buffer; [`RgbImage`], [`GrayImage`],
//!   [`DisparityMap`] and [`LabelMap`] are its instances, and [`IndexedImage`]
//!   pairs a label map with a palette (a segmentation).
//! * [`io`] reads and writes PNG/PPM/PGM (through the `image` crate) and
//!   [`pfm`] reads and writes PFM disparity files.
//! * [`cpu`] says which instruction sets the kernels may use (AVX2).
//! * [`color`] converts RGB ↔ gray ↔ CIE L\*u\*v\*; [`colormap`] paints
//!   disparity maps for people.
//! * [`cpu`] says whether the AVX2 kernels can run.
//! * [`metrics`] holds MSE/PSNR, compression figures and Middlebury
//!   bad-pixel scoring.
//! * [`scene`] loads stereo scenes (the shared data layout and the original
//!   Middlebury downloads); [`synth`] generates scenes with exact ground truth.
//!
//! # Conventions
//!
//! The left view is the reference: a left pixel `(x, y)` with disparity `d`
//! matches the right pixel `(x − d, y)`. Invalid or unknown disparity is
//! `f32::INFINITY`.
//!
//! # Example
//!
//! ```
//! use stereolink_image::synth::{synthesize, SynthSpec};
//! use stereolink_image::metrics::{bad_pixel_rate, psnr_rgb};
//!
//! let scene = synthesize(&SynthSpec { width: 64, height: 48, max_disp: 16, seed: 1 }).unwrap();
//! let gt = scene.gt_left.as_ref().unwrap();
//! // The ground truth scores perfectly against itself.
//! assert_eq!(bad_pixel_rate(gt, gt, None, 1.0), Some(0.0));
//! assert!(psnr_rgb(&scene.left, &scene.left).unwrap().overall.is_infinite());
//! ```

pub mod color;
pub mod colormap;
pub mod cpu;
mod error;
pub mod io;
pub mod metrics;
pub mod pfm;
mod plane;
pub mod scene;
pub mod segments;
pub mod shared_data;
pub mod synth;

pub use error::{Error, Result};
pub use plane::{DisparityMap, GrayImage, IndexedImage, LabelMap, Mask, Plane, Rgb, RgbImage};
pub use scene::{Calibration, Masks, Scene};
