//! Compact lossless coding of segmented stereo frames, lossy coding of
//! unsegmented ones, and the versioned frame container the sender and the
//! receiver exchange.
//!
//! # Brief overview
//!
//! * [`labels`] codes a label map with an adaptive context model and a binary
//!   range coder, in a fast or a strong (`mixer`: contexts mixed) mode;
//!   the right view can be coded *conditioned on the left* (predicted
//!   through per-block disparity shifts). `channels` models a label as
//!   its colour channels' classes for the strong mode.
//! * [`lossy`] codes unsegmented views with a stock codec (JPEG, WebP) for
//!   the best picture per byte, and [`rate`] fits a frame in a byte budget.
//! * [`temporal`] predicts a view from the same view of an earlier frame
//!   the receiver holds: a lossy view by conditional replenishment (only
//!   the blocks that changed beyond sensor noise are coded), a label map
//!   coded with the reference's labels as its prediction; it keeps the
//!   receiver's references.
//! * [`motion`] predicts a lossy view from the same view of an earlier
//!   frame shifted by the sender's motion vectors (what the sender's
//!   stream now sends for a lossy view, still or moving), through
//!   [`shift`], the coding by shifted cells it shares with [`stereo`].
//! * [`stereo`] predicts a lossy right view from the decoded left one,
//!   shifted by the sender's cell disparities (which the receiver then
//!   shows as its disparity), coding only the blocks the shift misses.
//! * `rgb` codes unsegmented RGB losslessly (MED predictor), so the
//!   original pair can be sent for comparison.
//! * [`container`] frames [`Message`]s ([`StereoFrame`], [`DepthReport`],
//!   [`Message::Control`]) with a header (magic, version, type, frame id,
//!   timestamp, body length, CRC-32). The byte layout is in
//!   `docs/wire-format.md`. A frame may carry a [`planetable`]: the
//!   sender's disparity as planes over the left view's segments.
//! * [`control`] writes and reads the Control body: the commands a station
//!   takes and its replies.
//!
//! The parts only the coders use (the range coder, the context mixer, the
//! channel model, the lossless RGB coder) are private to the crate.
//!
//! Decoding any byte string gives either the exact message or a
//! [`CodecError`]: sizes declared in the data are checked against [`Limits`]
//! before anything is allocated.
//!
//! # Example
//!
//! ```
//! use stereolink_codec::{container, DepthReport, Limits, Message};
//!
//! let report = DepthReport { target_distance_m: 1.25, target_region: [0, 0, 8, 8], levels: vec![], histogram: vec![3, 4] };
//! let bytes = container::encode(&Message::DepthReport(report.clone()), 7, 1_000);
//! let (header, msg) = container::decode(&bytes, &Limits::default()).unwrap();
//! assert_eq!(header.frame_id, 7);
//! assert_eq!(msg, Message::DepthReport(report));
//! ```

pub(crate) mod channels;
pub mod container;
pub mod control;
pub mod labels;
pub mod lossy;
pub(crate) mod mixer;
pub mod motion;
pub mod planetable;
pub(crate) mod rangecoder;
pub mod rate;
pub(crate) mod rgb;
pub mod shift;
pub mod stereo;
pub mod temporal;

use stereolink_image::{Calibration, IndexedImage, RgbImage};

/// Everything that makes bytes undecodable.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CodecError {
    /// The bytes end before the structure does.
    #[error("truncated {0}")]
    Truncated(&'static str),
    /// The bytes do not start with the stereolink magic.
    #[error("not a stereolink message (bad magic)")]
    BadMagic,
    /// A version this decoder does not know.
    #[error("message version {0} is not supported (this build reads version {v})", v = container::VERSION)]
    UnsupportedVersion(u8),
    /// A message type this decoder does not know.
    #[error("unknown message type {0}")]
    UnknownType(u8),
    /// The body's CRC-32 does not match.
    #[error("CRC mismatch: the message is corrupt")]
    Crc,
    /// A declared size exceeds the configured limit.
    #[error("{what} of {value} exceeds the limit of {max}")]
    TooLarge {
        /// Which size.
        what: &'static str,
        /// Declared value.
        value: u64,
        /// The limit.
        max: u64,
    },
    /// A decoded label has no palette entry.
    #[error("label {label} out of range for a palette of {labels}")]
    LabelOutOfRange {
        /// The label.
        label: u32,
        /// Palette size.
        labels: usize,
    },
    /// No setting of the coding fits the frame in the byte budget.
    #[error("a budget of {budget} B is below the smallest frame this coding makes, {minimum} B")]
    BudgetTooSmall {
        /// The budget (bytes).
        budget: usize,
        /// The smallest frame (bytes).
        minimum: usize,
    },
    /// A predicted view's reference frame is not held by the decoder.
    #[error("the reference frame {frame_id} (time stamp {timestamp_us} µs) is not held: a key frame is needed")]
    MissingReference {
        /// The reference's frame id.
        frame_id: u32,
        /// The reference's time stamp.
        timestamp_us: u64,
    },
    /// Any other inconsistency.
    #[error("invalid message: {0}")]
    Invalid(String),
}

/// Upper bounds the decoder enforces before allocating.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Largest body in bytes.
    pub max_body: usize,
    /// Largest view in pixels.
    pub max_pixels: usize,
    /// Largest palette.
    pub max_palette: usize,
    /// Longest disparity histogram.
    pub max_histogram: usize,
}

impl Default for Limits {
    /// 64 MiB bodies, 16 Mpixel views, 65536 colours, 65536 histogram bins.
    fn default() -> Self {
        Limits {
            max_body: 64 << 20,
            max_pixels: 1 << 24,
            max_palette: 1 << 16,
            max_histogram: 1 << 16,
        }
    }
}

/// How a view was segmented (carried so the receiver can label its display).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum SegmentationKind {
    /// Not segmented (the original image).
    None = 0,
    /// k-means.
    KMeans = 1,
    /// Mean shift.
    MeanShift = 2,
    /// Exact multilevel Otsu.
    Otsu = 3,
    /// PSO.
    Pso = 4,
    /// Darwinian PSO.
    Dpso = 5,
    /// Fractional-order Darwinian PSO.
    Fodpso = 6,
}

impl SegmentationKind {
    /// From a method name (`kmeans`, `meanshift`, `otsu`, `pso`, `dpso`, `fodpso`, `none`).
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "none" | "original" => Self::None,
            "kmeans" => Self::KMeans,
            "meanshift" => Self::MeanShift,
            "otsu" => Self::Otsu,
            "pso" => Self::Pso,
            "dpso" => Self::Dpso,
            "fodpso" => Self::Fodpso,
            _ => return None,
        })
    }

    /// The method name.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::KMeans => "kmeans",
            Self::MeanShift => "meanshift",
            Self::Otsu => "otsu",
            Self::Pso => "pso",
            Self::Dpso => "dpso",
            Self::Fodpso => "fodpso",
        }
    }

    fn from_u8(v: u8) -> Option<Self> {
        [
            Self::None,
            Self::KMeans,
            Self::MeanShift,
            Self::Otsu,
            Self::Pso,
            Self::Dpso,
            Self::Fodpso,
        ]
        .get(v as usize)
        .copied()
    }
}

/// One view of a frame.
#[derive(Clone, Debug, PartialEq)]
pub enum View {
    /// A segmented view: labels and palette.
    Indexed(IndexedImage),
    /// An unsegmented view, coded losslessly.
    Rgb(RgbImage),
    /// An unsegmented view, coded lossily ([`lossy`]).
    Lossy(lossy::LossyView),
    /// An unsegmented view predicted from an earlier frame ([`temporal`]).
    Predicted(temporal::PredictedView),
    /// A segmented view predicted from an earlier frame ([`temporal`]).
    PredictedLabels(temporal::PredictedLabels),
    /// A right view predicted from the frame's left view ([`stereo`]).
    Stereo(stereo::StereoView),
    /// An unsegmented view predicted by motion from an earlier frame
    /// ([`motion`]).
    Motion(motion::MotionView),
}

impl View {
    /// The view as an RGB image.
    pub fn to_rgb(&self) -> RgbImage {
        match self {
            View::Indexed(i) => i.to_rgb(),
            View::Rgb(r) => r.clone(),
            View::Lossy(v) => v.image().clone(),
            View::Predicted(v) => v.image().clone(),
            View::PredictedLabels(v) => v.image().to_rgb(),
            View::Stereo(v) => v.image().clone(),
            View::Motion(v) => v.image().clone(),
        }
    }

    /// How the view is coded: `segmented`, `rgb` (lossless), the lossy
    /// codec's name, `predicted`, `stereo` or `motion`.
    pub fn coding_name(&self) -> &'static str {
        match self {
            View::Indexed(_) => lossy::ViewCoding::Segmented.name(),
            View::Rgb(_) => "rgb",
            View::Lossy(v) => v.codec().name(),
            View::Predicted(_) => "predicted",
            View::PredictedLabels(_) => lossy::ViewCoding::Segmented.name(),
            View::Stereo(_) => "stereo",
            View::Motion(_) => "motion",
        }
    }

    /// The labels and palette of a segmented view.
    pub fn indexed(&self) -> Option<&IndexedImage> {
        match self {
            View::Indexed(i) => Some(i),
            View::PredictedLabels(v) => Some(v.image()),
            View::Rgb(_)
            | View::Lossy(_)
            | View::Predicted(_)
            | View::Stereo(_)
            | View::Motion(_) => None,
        }
    }

    /// `(width, height)`.
    pub fn dims(&self) -> (usize, usize) {
        match self {
            View::Indexed(i) => i.labels().dims(),
            View::Rgb(r) => r.dims(),
            View::Lossy(v) => v.image().dims(),
            View::Predicted(v) => v.image().dims(),
            View::PredictedLabels(v) => v.image().labels().dims(),
            View::Stereo(v) => v.image().dims(),
            View::Motion(v) => v.image().dims(),
        }
    }
}

/// A stereo pair as sent: both views, how they were made, and the calibration.
#[derive(Clone, Debug, PartialEq)]
pub struct StereoFrame {
    /// Segmentation method.
    pub kind: SegmentationKind,
    /// Levels (classes) requested.
    pub levels: u8,
    /// Free-form parameters of the method (UTF-8, at most 255 bytes).
    pub params: String,
    /// Per-channel thresholds, for the thresholding methods.
    pub thresholds: Option<[Vec<u8>; 3]>,
    /// Calibration of the camera pair.
    pub calibration: Option<Calibration>,
    /// Left (reference) view.
    pub left: View,
    /// Right view (coded conditioned on the left when both are indexed; a
    /// lossy or stereo-predicted right view goes with a lossy left one).
    pub right: View,
    /// The sender's disparity as planes over the left view's segments.
    pub planes: Option<planetable::PlaneTable>,
}

/// One depth level of a report.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReportLevel {
    /// Peak disparity (px).
    pub disparity: f32,
    /// Its distance in metres (non-finite if unknown).
    pub distance_m: f32,
    /// Share of the valid pixels (0..1).
    pub share: f32,
}

/// The sender's depth estimate: levels, the target's distance, the histogram.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthReport {
    /// Distance to the target region in metres (non-finite or ≤ 0: unknown).
    pub target_distance_m: f32,
    /// Target region `[x, y, w, h]` in pixels.
    pub target_region: [u16; 4],
    /// Depth levels, nearest first.
    pub levels: Vec<ReportLevel>,
    /// Disparity histogram (1 px bins from 0).
    pub histogram: Vec<u32>,
}

impl DepthReport {
    /// The report cut down to fit in `max_bytes` as an encoded message, so
    /// that it takes one radio packet: the target's distance and region
    /// stay, the histogram goes, and the nearest levels stay while they fit.
    /// `None` when not even the distance fits.
    pub fn fitted(&self, max_bytes: usize) -> Option<DepthReport> {
        let room = max_bytes.checked_sub(container::report_len(0, 0))?;
        let levels = (room / container::REPORT_LEVEL_LEN).min(self.levels.len());
        Some(DepthReport {
            levels: self.levels[..levels].to_vec(),
            histogram: Vec::new(),
            ..*self
        })
    }
}

/// A message of the stereolink protocol.
#[derive(Clone, Debug, PartialEq)]
pub enum Message {
    /// A stereo pair (boxed: it is far larger than the other messages).
    StereoFrame(Box<StereoFrame>),
    /// A depth report.
    DepthReport(DepthReport),
    /// An application-defined control message (opaque bytes).
    Control(Vec<u8>),
}
