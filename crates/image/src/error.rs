//! The one error type of this crate: what went wrong, and with which input.

use std::path::PathBuf;

/// Result alias for this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong reading, writing or checking images and scenes.
///
/// Variants that concern a file carry its path, so the message names the input.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The file could not be opened, read or written (the message names the
    /// file; the I/O error is its source, which a chain such as anyhow's
    /// `{:#}` prints after it).
    #[error("{}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The bytes are not a valid image of the expected format.
    #[error("{}: cannot decode: {reason}", path.display())]
    Decode {
        /// The file (empty when decoding from memory).
        path: PathBuf,
        /// What is wrong with the bytes.
        reason: String,
    },
    /// The image could not be encoded.
    #[error("{}: cannot encode: {reason}", path.display())]
    Encode {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
    /// Two images that must agree in size do not.
    #[error(
        "{what}: size {found_w}x{found_h} differs from the expected {expected_w}x{expected_h}"
    )]
    SizeMismatch {
        /// Which image (usually a path or a role such as "right view").
        what: String,
        /// Expected width.
        expected_w: usize,
        /// Expected height.
        expected_h: usize,
        /// Actual width.
        found_w: usize,
        /// Actual height.
        found_h: usize,
    },
    /// An image is larger than the configured limit.
    #[error("{what}: {width}x{height} exceeds the limit of {max_pixels} pixels")]
    TooLarge {
        /// Which image.
        what: String,
        /// Declared width.
        width: usize,
        /// Declared height.
        height: usize,
        /// The limit.
        max_pixels: usize,
    },
    /// A folder is not a stereo scene this crate can read.
    #[error("{}: {reason}", path.display())]
    Scene {
        /// The folder or file.
        path: PathBuf,
        /// What is missing or inconsistent.
        reason: String,
    },
    /// A parameter is outside its valid range.
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
}

impl Error {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }

    pub(crate) fn decode(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Decode {
            path: path.into(),
            reason: reason.into(),
        }
    }

    pub(crate) fn scene(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Scene {
            path: path.into(),
            reason: reason.into(),
        }
    }
}
