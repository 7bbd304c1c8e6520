//! Chessboard inner-corner detection with subpixel refinement.
//!
//! Three stages, each in its own module:
//!
//! 1. `saddle`: candidate X-junctions, the saddle points of the smoothed
//!    image (positive `Ixy² − Ixx·Iyy`, the negated Hessian determinant, as
//!    in Chen & Zhang 2005, "Sub-pixel detection of X-corners"), kept when a
//!    ring around them crosses four alternating light/dark sectors bounded by
//!    two straight edges.
//! 2. `grid`: a 3x3 seed grid grown row by row and column by column, in the
//!    manner of Geiger et al. 2012, "Automatic camera and range sensor
//!    calibration using a single shot" (ICRA), §III-B, with square colours
//!    checked instead of an energy: a grid line is added only when every
//!    predicted corner is found and the new squares alternate dark/light.
//! 3. `subpix` ([`refine_corners`]): the gradient-orthogonality refinement
//!    of OpenCV's `cornerSubPix` (Förstner & Gülch 1987), so the corners
//!    agree with the OpenCV tool chain.
//!
//! # Ordering
//!
//! Corners come row by row, `cols` per row; corner `k` is board point
//! `(k % cols, k / cols)`. The rule (OpenCV's, checked on the shared set):
//! the row direction `u` (corner 0 → 1) and the column direction `v`
//! (corner 0 → `cols`) turn clockwise on screen, `u × v > 0` with `y` down, and
//! the board square outside corner 0 is dark. When `cols + rows` is odd (as
//! 9x6), that square's colour tells the two 180°-rotated readings apart, so
//! the order follows the board and is the same in both cameras. When it is
//! even the board is symmetric and the reading whose corner 0 is nearer the
//! image's top-left (smaller `x + y`) is chosen, which is consistent between
//! nearby viewpoints unless the board is seen at about 45°.
//!
//! # Limits
//!
//! Squares should be at least about 12 px (twice
//! [`ChessboardOptions::ring_radius`] plus a margin), every inner corner at
//! least `ring_radius + 2` px inside the image, and the whole board visible.
//!
//! How it compares with OpenCV's `findChessboardCorners` + `cornerSubPix`
//! on the shared chessboard set (`bench/chessboard_vs_opencv.py`) is in
//! docs/benchmarks.md, “Chessboard”.

mod grid;
mod saddle;
mod subpix;

use nalgebra::Point2;
use stereolink_image::{GrayImage, RgbImage};

pub use crate::board::BoardSize;

pub use subpix::{refine_corners, SubpixOptions, MAX_HALF_WINDOW};

/// Why no board was returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum NotFound {
    /// The requested size cannot be detected (fewer than 3 corners a side).
    #[error("board size {0} is too small: at least 3x3 inner corners are needed")]
    BoardTooSmall(BoardSize),
    /// The image is too small to hold a board.
    #[error("image {width}x{height} is too small to hold a chessboard")]
    ImageTooSmall {
        /// Image width.
        width: usize,
        /// Image height.
        height: usize,
    },
    /// No chessboard-like grid of at least 3x3 inner corners.
    #[error("no chessboard found (no grid of at least 3x3 inner corners)")]
    NoGrid,
    /// A grid was found, smaller than the board in some direction: the board is
    /// probably cut by the image border, occluded or too oblique.
    #[error(
        "only a {found} grid of inner corners was found, {expected} expected: \
         the board may be cut by the image border, occluded or blurred"
    )]
    Partial {
        /// The largest grid found, oriented like `expected` (both wider than
        /// tall, or both taller).
        found: BoardSize,
        /// The requested size.
        expected: BoardSize,
    },
    /// A grid larger than the requested board in some direction: the size is
    /// probably wrong. (A transposed size, 6x9 for 9x6, is no error: it reads
    /// the board by columns.)
    #[error(
        "found a {found} grid of inner corners, {expected} expected: check the board \
         size (count inner corners, not squares)"
    )]
    WrongSize {
        /// The largest grid found, oriented like `expected`.
        found: BoardSize,
        /// The requested size.
        expected: BoardSize,
    },
}

/// Tuning of [`find_chessboard_with`]. The defaults suit squares of 12 px to
/// a few hundred px in 8-bit images.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChessboardOptions {
    /// Standard deviation (px) of the Gaussian smoothing before the Hessian:
    /// 1.5 px tolerates JPEG noise and still separates corners 12 px apart.
    pub sigma: f64,
    /// Candidates are local maxima of the saddle response within this radius
    /// (px).
    pub nms_radius: usize,
    /// Candidates need a saddle response of at least this fraction of the
    /// image's strongest (0.002: contrast can vary 20-fold under a lighting
    /// gradient; the ring test removes the weak false ones).
    pub min_response_ratio: f64,
    /// Radius (px) of the ring sampled around a candidate; must stay below
    /// half the smallest square side.
    pub ring_radius: f64,
    /// Least gray-level range on the ring and least difference between
    /// adjacent squares (8-bit levels).
    pub min_contrast: f64,
    /// Tolerance (radians) on the two edges through a corner being straight:
    /// opposite ring transitions must be π ± this apart.
    pub edge_tolerance: f64,
    /// A predicted corner matches the nearest candidate within this fraction
    /// of the local square side.
    pub match_tolerance: f64,
    /// At most this many candidates (the strongest) are kept, bounding the
    /// work on cluttered or noisy images.
    pub max_candidates: usize,
    /// The subpixel refinement.
    pub subpix: SubpixOptions,
}

impl Default for ChessboardOptions {
    fn default() -> Self {
        ChessboardOptions {
            sigma: 1.5,
            nms_radius: 3,
            min_response_ratio: 0.002,
            ring_radius: 5.0,
            min_contrast: 10.0,
            edge_tolerance: 0.6,
            match_tolerance: 0.35,
            max_candidates: 2000,
            subpix: SubpixOptions::default(),
        }
    }
}

/// Finds the inner corners of a `pattern` chessboard with the default
/// options; see [`find_chessboard_with`].
pub fn find_chessboard(
    image: &GrayImage,
    pattern: BoardSize,
) -> Result<Vec<Point2<f64>>, NotFound> {
    find_chessboard_with(image, pattern, &ChessboardOptions::default())
}

/// [`find_chessboard`] on an RGB image (converted to BT.601 luma first).
pub fn find_chessboard_rgb(
    image: &RgbImage,
    pattern: BoardSize,
) -> Result<Vec<Point2<f64>>, NotFound> {
    find_chessboard(&stereolink_image::color::rgb_to_gray(image), pattern)
}

/// Finds the `pattern.count()` inner corners of a chessboard, refined to
/// subpixel accuracy, in the order of the [module documentation](self).
///
/// Pixel centres are at integer coordinates (OpenCV's convention). Every
/// inner corner must be visible; the board may be tilted, blurred, noisy or
/// unevenly lit.
pub fn find_chessboard_with(
    image: &GrayImage,
    pattern: BoardSize,
    options: &ChessboardOptions,
) -> Result<Vec<Point2<f64>>, NotFound> {
    if pattern.cols < 3 || pattern.rows < 3 {
        return Err(NotFound::BoardTooSmall(pattern));
    }
    let (width, height) = image.dims();
    let margin = saddle::margin(options);
    if width < margin.saturating_mul(4) || height < margin.saturating_mul(4) {
        return Err(NotFound::ImageTooSmall { width, height });
    }
    let smooth = saddle::smooth(image, options.sigma);
    let candidates = saddle::candidates(&smooth, options);
    let board = grid::find_grid(&smooth, &candidates, pattern, options)?;
    let mut corners = board.ordered(&smooth, pattern);
    let subpix = SubpixOptions {
        half_window: refinement_window(&corners, pattern, options.subpix.half_window),
        ..options.subpix
    };
    refine_corners(image, &mut corners, &subpix);
    Ok(corners)
}

/// The refinement's half window: at most `largest`, and at most 0.75 of
/// the shortest distance between neighbouring corners, so that the window
/// never reaches the next corner (at least 2 px); docs/tuning.md, “Corner
/// refinement window: 0.75 of the corner spacing”.
fn refinement_window(corners: &[Point2<f64>], pattern: BoardSize, largest: usize) -> usize {
    let mut shortest = f64::INFINITY;
    for r in 0..pattern.rows {
        for c in 0..pattern.cols {
            let p = corners[r * pattern.cols + c];
            if c + 1 < pattern.cols {
                shortest = shortest.min((corners[r * pattern.cols + c + 1] - p).norm());
            }
            if r + 1 < pattern.rows {
                shortest = shortest.min((corners[(r + 1) * pattern.cols + c] - p).norm());
            }
        }
    }
    ((0.75 * shortest) as usize).clamp(2, largest.max(2))
}

#[cfg(test)]
mod tests;
