//! Checking a message (header, limits, CRC, structure) and parsing its
//! body without decoding the views, which stay slices of the message:
//! what a receiver does before it decides to decode a frame.

use stereolink_image::{Calibration, Rgb};

use super::bytes::check;
use super::{coding, kind, Header, Reader, HEADER_LEN, MAGIC, VERSION};
use crate::lossy::LossyCodec;
use crate::planetable::{self, CodedPlaneTable};
use crate::temporal::{self, RefId};
use crate::{CodecError, DepthReport, Limits, ReportLevel, SegmentationKind};

/// Parses and checks a header (without the body).
pub fn decode_header(bytes: &[u8]) -> Result<Header, CodecError> {
    let mut r = Reader {
        data: bytes,
        pos: 0,
    };
    if r.take(4, "header")? != MAGIC {
        return Err(CodecError::BadMagic);
    }
    let version = r.u8("header")?;
    if version != VERSION {
        return Err(CodecError::UnsupportedVersion(version));
    }
    let kind = r.u8("header")?;
    let _flags = r.u16("header")?;
    let frame_id = r.u32("header")?;
    let timestamp_us = u64::from_le_bytes(r.take(8, "header")?.try_into().expect("8 bytes"));
    let body_len = r.u32("header")?;
    Ok(Header {
        version,
        kind,
        frame_id,
        timestamp_us,
        body_len,
    })
}

/// A message checked and parsed, its views not yet decoded (they borrow
/// the message bytes).
#[derive(Debug)]
pub enum Body<'a> {
    /// A stereo pair; decode its views with [`FrameRef::decode`] or, into
    /// buffers kept from frame to frame, [`FrameDecoder`](super::FrameDecoder).
    StereoFrame(FrameRef<'a>),
    /// A depth report.
    DepthReport(DepthReport),
    /// A control message's bytes.
    Control(&'a [u8]),
}

/// Checks a message (header, limits, CRC, structure) and parses its body
/// without decoding the views: every check of [`decode`](super::decode) except those of
/// the coded views, which happen when they are decoded.
pub fn parse<'a>(bytes: &'a [u8], limits: &Limits) -> Result<(Header, Body<'a>), CodecError> {
    let header = decode_header(bytes)?;
    check("body length", header.body_len as usize, limits.max_body)?;
    let crc = u32::from_le_bytes(
        bytes
            .get(24..28)
            .ok_or(CodecError::Truncated("header"))?
            .try_into()
            .expect("4"),
    );
    let body = bytes
        .get(HEADER_LEN..)
        .ok_or(CodecError::Truncated("header"))?;
    if body.len() < header.body_len as usize {
        return Err(CodecError::Truncated("body"));
    }
    if body.len() > header.body_len as usize {
        return Err(CodecError::Invalid(format!(
            "{} bytes after the body",
            body.len() - header.body_len as usize
        )));
    }
    // Under the fuzzer the CRC is not checked, so it can explore the bodies.
    if crc32fast::hash(body) != crc && !cfg!(fuzzing) {
        return Err(CodecError::Crc);
    }
    let mut r = Reader { data: body, pos: 0 };
    let parsed = match header.kind {
        kind::STEREO_FRAME => Body::StereoFrame(parse_frame(&mut r, limits)?),
        kind::DEPTH_REPORT => Body::DepthReport(decode_report(&mut r, limits)?),
        kind::CONTROL => return Ok((header, Body::Control(body))),
        other => return Err(CodecError::UnknownType(other)),
    };
    if r.pos != body.len() {
        return Err(CodecError::Invalid("trailing bytes in the body".into()));
    }
    Ok((header, parsed))
}

/// A stereo frame parsed but not decoded: its fields, and each view's
/// palette and coded payload as slices of the message.
#[derive(Clone, Debug)]
pub struct FrameRef<'a> {
    /// View width.
    pub width: usize,
    /// View height.
    pub height: usize,
    /// Segmentation method.
    pub kind: SegmentationKind,
    /// Levels (classes) requested.
    pub levels: u8,
    /// The method's parameters.
    pub params: &'a str,
    /// Per-channel thresholds, for the thresholding methods.
    pub thresholds: Option<[&'a [u8]; 3]>,
    /// Calibration of the camera pair.
    pub calibration: Option<Calibration>,
    /// Left view.
    pub left: ViewRef<'a>,
    /// Right view.
    pub right: ViewRef<'a>,
    /// The plane table section, if the frame has one (boxed: most frames
    /// have none), its indices still coded.
    pub planes: Option<Box<CodedPlaneTable>>,
}

impl FrameRef<'_> {
    /// The frames the views are predicted from, if any view is
    /// ([`crate::temporal`]): a key frame has none.
    pub fn references(&self) -> impl Iterator<Item = RefId> + '_ {
        [self.left, self.right]
            .into_iter()
            .filter_map(|v| v.reference())
    }

    /// The reference of a still pair: both views predicted from it, lossy,
    /// with no block changed or moved (the pair is the reference's).
    pub fn unchanged(&self) -> Option<RefId> {
        let dims = (self.width, self.height);
        let still = |v: &ViewRef| match v.coding {
            coding::PREDICTED => {
                let coded = temporal::Coded::parse(v.payload, dims).ok()?;
                (!coded.any_changed()).then_some(coded.reference)
            }
            coding::MOTION => crate::motion::still_reference(v.payload, dims),
            _ => None,
        };
        let left = still(&self.left)?;
        (still(&self.right)? == left).then_some(left)
    }
}

/// One coded view: how it is coded, its palette and its payload.
#[derive(Clone, Copy, Debug)]
pub struct ViewRef<'a> {
    pub(super) coding: u8,
    /// The palette, three bytes (R, G, B) per colour.
    pub(super) palette: &'a [u8],
    pub(super) payload: &'a [u8],
}

impl ViewRef<'_> {
    /// The lossy codec and its bitstream, for a lossy view (checked by
    /// [`parse`]).
    pub(super) fn lossy(&self) -> Option<(LossyCodec, &[u8])> {
        if self.coding != coding::LOSSY {
            return None;
        }
        let (&codec, bits) = self.payload.split_first()?;
        Some((LossyCodec::from_u8(codec)?, bits))
    }

    /// The view's lossy codec, if it is lossy.
    pub fn lossy_codec(&self) -> Option<LossyCodec> {
        self.lossy().map(|(codec, _)| codec)
    }

    /// The frame a predicted view is predicted from (checked by [`parse`]).
    pub fn reference(&self) -> Option<RefId> {
        matches!(
            self.coding,
            coding::PREDICTED | coding::LABELS_PREDICTED | coding::MOTION
        )
        .then(|| temporal::split_reference(self.payload).ok())
        .flatten()
        .map(|(id, _)| id)
    }

    /// Whether the view is predicted from the frame's left view
    /// ([`crate::stereo`]).
    pub fn is_stereo(&self) -> bool {
        self.coding == coding::STEREO
    }

    /// Whether the view is predicted by motion from an earlier frame
    /// ([`crate::motion`]).
    pub fn is_motion(&self) -> bool {
        self.coding == coding::MOTION
    }

    /// Number of palette colours (0 for an unsegmented view).
    pub fn colours(&self) -> usize {
        self.palette.len() / 3
    }

    /// The palette's colours.
    pub(super) fn palette(&self) -> impl Iterator<Item = Rgb> + '_ {
        self.palette.chunks_exact(3).map(|c| [c[0], c[1], c[2]])
    }
}

fn parse_frame<'a>(r: &mut Reader<'a>, limits: &Limits) -> Result<FrameRef<'a>, CodecError> {
    let (w, h) = (r.u16("frame size")? as usize, r.u16("frame size")? as usize);
    check("view size (pixels)", w * h, limits.max_pixels)?;
    let kind = r.u8("segmentation kind")?;
    let kind = SegmentationKind::from_u8(kind)
        .ok_or_else(|| CodecError::Invalid(format!("segmentation kind {kind}")))?;
    let levels = r.u8("levels")?;
    let n = r.u8("params")? as usize;
    let params = std::str::from_utf8(r.take(n, "params")?)
        .map_err(|_| CodecError::Invalid("params are not UTF-8".into()))?;
    let thresholds = match r.u8("thresholds flag")? {
        0 => None,
        1 => {
            let mut t: [&[u8]; 3] = [&[]; 3];
            for ch in &mut t {
                let n = r.u8("thresholds")? as usize;
                *ch = r.take(n, "thresholds")?;
            }
            Some(t)
        }
        f => return Err(CodecError::Invalid(format!("thresholds flag {f}"))),
    };
    let calibration = match r.u8("calibration flag")? {
        0 => None,
        1 => {
            let known = |v: f64| (v.is_finite() && v > 0.0).then_some(v);
            Some(Calibration {
                focal_px: known(r.f64("calibration")?),
                baseline_m: known(r.f64("calibration")?),
                doffs: r.f64("calibration")?,
                ndisp: r.u16("calibration")? as usize,
            })
        }
        f => return Err(CodecError::Invalid(format!("calibration flag {f}"))),
    };
    let left = parse_view(r, limits)?;
    let right = parse_view(r, limits)?;
    if right.coding == coding::LABELS_CONDITIONED && !coding::indexed(left.coding) {
        return Err(CodecError::Invalid(
            "conditioned view without an indexed left view".into(),
        ));
    }
    if left.coding == coding::LABELS_CONDITIONED {
        return Err(CodecError::Invalid(
            "the left view is coded conditioned (on nothing)".into(),
        ));
    }
    if left.coding == coding::STEREO {
        return Err(CodecError::Invalid(
            "the left view is stereo-predicted (from nothing)".into(),
        ));
    }
    if right.coding == coding::STEREO && coding::indexed(left.coding) {
        return Err(CodecError::Invalid(
            "a stereo-predicted right view with a segmented left view".into(),
        ));
    }
    for view in [&left, &right] {
        if view.coding == coding::PREDICTED {
            temporal::Coded::parse(view.payload, (w, h))?;
        }
    }
    let planes = parse_sections(r, w * h)?;
    if planes.is_some() && !coding::indexed(left.coding) {
        return Err(CodecError::Invalid(
            "a plane table without a left label map".into(),
        ));
    }
    Ok(FrameRef {
        width: w,
        height: h,
        kind,
        levels,
        params,
        thresholds,
        calibration,
        left,
        right,
        planes,
    })
}

/// The sections after the right view, to the end of the body: each a tag,
/// a version, a length and that many bytes. A plane table of this version
/// is parsed (at most one); other sections are skipped.
fn parse_sections(
    r: &mut Reader,
    pixels: usize,
) -> Result<Option<Box<CodedPlaneTable>>, CodecError> {
    let mut planes = None;
    while r.pos < r.data.len() {
        let (tag, version) = (r.u8("section")?, r.u8("section")?);
        let len = r.u32("section")? as usize;
        let content = r.take(len, "section")?;
        if (tag, version) == (planetable::TAG, planetable::VERSION) {
            if planes.is_some() {
                return Err(CodecError::Invalid("two plane tables".into()));
            }
            planes = Some(Box::new(CodedPlaneTable::parse(content, pixels)?));
        }
    }
    Ok(planes)
}

fn parse_view<'a>(r: &mut Reader<'a>, limits: &Limits) -> Result<ViewRef<'a>, CodecError> {
    let code = r.u8("view coding")?;
    let n = r.u32("palette")? as usize;
    check("palette", n, limits.max_palette)?;
    let palette = r.take(n * 3, "palette")?;
    let len = r.u32("view payload")? as usize;
    let payload = r.take(len, "view payload")?;
    match code {
        coding::LABELS | coding::LABELS_CONDITIONED if n > 0 => {}
        coding::LABELS_PREDICTED if n > 0 => {
            temporal::split_reference(payload)?;
        }
        coding::MOTION if n == 0 => {
            temporal::split_reference(payload)?;
        }
        coding::RGB => {}
        coding::PREDICTED | coding::STEREO if n == 0 => {}
        coding::LOSSY if n == 0 => {
            let codec = *payload.first().ok_or(CodecError::Truncated("lossy view"))?;
            if LossyCodec::from_u8(codec).is_none() {
                return Err(CodecError::Invalid(format!("lossy codec {codec}")));
            }
        }
        other => {
            return Err(CodecError::Invalid(format!(
                "view coding {other} with a palette of {n}"
            )))
        }
    }
    Ok(ViewRef {
        coding: code,
        palette,
        payload,
    })
}

fn decode_report(r: &mut Reader, limits: &Limits) -> Result<DepthReport, CodecError> {
    let target_distance_m = r.f32("report")?;
    let mut target_region = [0u16; 4];
    for v in &mut target_region {
        *v = r.u16("report")?;
    }
    let n = r.u8("levels")? as usize;
    let mut levels = Vec::with_capacity(n);
    for _ in 0..n {
        levels.push(ReportLevel {
            disparity: r.f32("levels")?,
            distance_m: r.f32("levels")?,
            share: r.f32("levels")?,
        });
    }
    let n = r.u32("histogram")? as usize;
    check("histogram", n, limits.max_histogram)?;
    let raw = r.take(n * 4, "histogram")?;
    let histogram = raw
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect();
    Ok(DepthReport {
        target_distance_m,
        target_region,
        levels,
        histogram,
    })
}
