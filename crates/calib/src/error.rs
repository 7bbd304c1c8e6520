//! The calibration crate's one error type.

use std::path::PathBuf;

/// What can go wrong between chessboard images and a rectified pair.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An image could not be read or written.
    #[error(transparent)]
    Image(#[from] stereolink_image::Error),
    /// A file could not be read or written (the message names the file; the
    /// I/O error is its source, which a chain such as anyhow's `{:#}` prints
    /// after it, as in `stereolink_image::Error::Io`).
    #[error("{}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// Fewer usable views than a calibration needs.
    #[error("{found} usable view(s), at least {needed} are needed: {hint}")]
    TooFewViews {
        /// Views with a detected board.
        found: usize,
        /// The minimum.
        needed: usize,
        /// What to do.
        hint: String,
    },
    /// Inputs whose sizes disagree.
    #[error("size mismatch: {0}")]
    SizeMismatch(String),
    /// A calibration file that lacks what is needed or holds bad values.
    #[error("{}: {problem}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        problem: String,
    },
    /// An argument outside its range.
    #[error("invalid argument: {0}")]
    Invalid(String),
    /// The optimisation could not find a solution.
    #[error("calibration failed: {0}")]
    Failed(String),
}

/// The crate's result type.
pub type Result<T> = std::result::Result<T, Error>;
