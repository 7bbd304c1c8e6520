//! The frame container: a fixed header and a typed body, all little-endian.
//! `docs/wire-format.md` gives the exact byte layout.
//!
//! ```text
//!  0      4   5   6      8          12                 20         24         28
//!  +------+---+---+------+----------+------------------+----------+----------+------ ...
//!  | SLNK |ver|typ|flags | frame id | timestamp (µs)   | body len | body CRC | body
//!  +------+---+---+------+----------+------------------+----------+----------+------ ...
//! ```

use stereolink_image::segments::components;
use stereolink_image::{Calibration, IndexedImage, LabelMap, Rgb, RgbImage};

use crate::planetable::CodedPlaneTable;
use crate::{
    labels, planetable, rgb, CodecError, DepthReport, Limits, Message, ReportLevel,
    SegmentationKind, StereoFrame, View,
};

/// The magic bytes.
pub const MAGIC: [u8; 4] = *b"SLNK";
/// The format version this build writes and reads.
pub const VERSION: u8 = 2;
/// Header length in bytes.
pub const HEADER_LEN: usize = 28;

/// Message type codes.
pub mod kind {
    /// [`crate::Message::StereoFrame`].
    pub const STEREO_FRAME: u8 = 1;
    /// [`crate::Message::DepthReport`].
    pub const DEPTH_REPORT: u8 = 2;
    /// [`crate::Message::Control`].
    pub const CONTROL: u8 = 3;
}

/// View coding codes.
mod coding {
    pub const LABELS: u8 = 0;
    pub const LABELS_CONDITIONED: u8 = 1;
    pub const RGB: u8 = 2;
}

/// Stereo shift search range of the encoder (px); any value decodes.
pub const SHIFT_SEARCH: usize = 96;

/// The decoded header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Format version.
    pub version: u8,
    /// Message type code.
    pub kind: u8,
    /// Frame id.
    pub frame_id: u32,
    /// Sender timestamp in microseconds.
    pub timestamp_us: u64,
    /// Body length in bytes.
    pub body_len: u32,
}

pub(crate) struct Writer(pub(crate) Vec<u8>);

impl Writer {
    pub(crate) fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    pub(crate) fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn f32(&mut self, v: f32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn bytes(&mut self, b: &[u8]) {
        self.0.extend_from_slice(b);
    }
}

pub(crate) struct Reader<'a> {
    pub(crate) data: &'a [u8],
    pub(crate) pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], CodecError> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.data.len())
            .ok_or(CodecError::Truncated(what))?;
        let s = &self.data[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    pub(crate) fn u8(&mut self, what: &'static str) -> Result<u8, CodecError> {
        Ok(self.take(1, what)?[0])
    }
    pub(crate) fn u16(&mut self, what: &'static str) -> Result<u16, CodecError> {
        Ok(u16::from_le_bytes(
            self.take(2, what)?.try_into().expect("2 bytes"),
        ))
    }
    pub(crate) fn u32(&mut self, what: &'static str) -> Result<u32, CodecError> {
        Ok(u32::from_le_bytes(
            self.take(4, what)?.try_into().expect("4 bytes"),
        ))
    }
    pub(crate) fn f32(&mut self, what: &'static str) -> Result<f32, CodecError> {
        Ok(f32::from_le_bytes(
            self.take(4, what)?.try_into().expect("4 bytes"),
        ))
    }
    pub(crate) fn f64(&mut self, what: &'static str) -> Result<f64, CodecError> {
        Ok(f64::from_le_bytes(
            self.take(8, what)?.try_into().expect("8 bytes"),
        ))
    }
}

pub(crate) fn check(what: &'static str, value: usize, max: usize) -> Result<(), CodecError> {
    if value > max {
        Err(CodecError::TooLarge {
            what,
            value: value as u64,
            max: max as u64,
        })
    } else {
        Ok(())
    }
}

/// Serialises a message with its header, label maps in the default
/// [`labels::Mode`] (the fast one).
///
/// # Panics
/// If the frame's views differ in size, exceed 65535 px a side, or `params`
/// exceeds 255 bytes (the encoder's own inputs, not external data).
pub fn encode(msg: &Message, frame_id: u32, timestamp_us: u64) -> Vec<u8> {
    encode_with(msg, frame_id, timestamp_us, labels::Mode::default())
}

/// [`encode`] with the label maps coded in `mode`.
pub fn encode_with(msg: &Message, frame_id: u32, timestamp_us: u64, mode: labels::Mode) -> Vec<u8> {
    let mut body = Writer(Vec::new());
    let kind = match msg {
        Message::StereoFrame(f) => {
            encode_frame(&mut body, f, mode);
            kind::STEREO_FRAME
        }
        Message::DepthReport(r) => {
            encode_report(&mut body, r);
            kind::DEPTH_REPORT
        }
        Message::Control(c) => {
            body.bytes(c);
            kind::CONTROL
        }
    };
    let body = body.0;
    let mut out = Writer(Vec::with_capacity(HEADER_LEN + body.len()));
    out.bytes(&MAGIC);
    out.u8(VERSION);
    out.u8(kind);
    out.u16(0);
    out.u32(frame_id);
    out.0.extend_from_slice(&timestamp_us.to_le_bytes());
    out.u32(body.len() as u32);
    out.u32(crc32fast::hash(&body));
    out.bytes(&body);
    out.0
}

fn encode_frame(w: &mut Writer, f: &StereoFrame, mode: labels::Mode) {
    let (width, height) = f.left.dims();
    assert_eq!(f.right.dims(), (width, height), "views differ in size");
    w.u16(u16::try_from(width).expect("width fits 16 bits"));
    w.u16(u16::try_from(height).expect("height fits 16 bits"));
    w.u8(f.kind as u8);
    w.u8(f.levels);
    let params = f.params.as_bytes();
    w.u8(u8::try_from(params.len()).expect("params fit 255 bytes"));
    w.bytes(params);
    match &f.thresholds {
        None => w.u8(0),
        Some(t) => {
            w.u8(1);
            for ch in t {
                w.u8(ch.len() as u8);
                w.bytes(ch);
            }
        }
    }
    match &f.calibration {
        None => w.u8(0),
        Some(c) => {
            w.u8(1);
            w.f64(c.focal_px.unwrap_or(0.0));
            w.f64(c.baseline_m.unwrap_or(0.0));
            w.f64(c.doffs);
            w.u16(c.ndisp.min(u16::MAX as usize) as u16);
        }
    }
    encode_view(w, &f.left, None, mode);
    let reference = match &f.left {
        View::Indexed(l) => Some(l),
        View::Rgb(_) => None,
    };
    encode_view(w, &f.right, reference, mode);
    if let Some(t) = &f.planes {
        let ids = match &f.left {
            View::Indexed(l) => Some(components(l.labels(), t.tile as usize).0),
            View::Rgb(_) => None,
        };
        t.encode(w, ids.as_ref());
    }
}

fn encode_view(w: &mut Writer, view: &View, reference: Option<&IndexedImage>, mode: labels::Mode) {
    let (code, palette, payload): (u8, &[Rgb], Vec<u8>) = match view {
        View::Indexed(img) => match reference {
            Some(r) => (
                coding::LABELS_CONDITIONED,
                img.palette(),
                conditioned_payload(r, img, mode),
            ),
            None => (
                coding::LABELS,
                img.palette(),
                labels::encode(img.labels(), img.palette(), None, 0, mode),
            ),
        },
        View::Rgb(img) => (coding::RGB, &[], rgb::encode(img)),
    };
    w.u8(code);
    w.u32(palette.len() as u32);
    for p in palette {
        w.bytes(p);
    }
    w.u32(payload.len() as u32);
    w.bytes(&payload);
}

/// The payload of a right view coded conditioned on the left: the label
/// table, then the labels predicted through it.
pub fn conditioned_payload(
    left: &IndexedImage,
    right: &IndexedImage,
    mode: labels::Mode,
) -> Vec<u8> {
    let table = label_table(left, right);
    let predicted = prediction(left, &table);
    let mut payload: Vec<u8> = table.iter().flat_map(|t| t.to_le_bytes()).collect();
    payload.extend(labels::encode(
        right.labels(),
        right.palette(),
        Some(&predicted),
        SHIFT_SEARCH,
        mode,
    ));
    payload
}

/// The left view's labels in the right view's numbering: what the right
/// view coded conditioned on the left is predicted from (through the
/// per-block shifts of [`labels::plan_shifts`] with [`SHIFT_SEARCH`]).
pub fn right_prediction(left: &IndexedImage, right: &IndexedImage) -> LabelMap {
    prediction(left, &label_table(left, right))
}

fn prediction(left: &IndexedImage, table: &[u16]) -> LabelMap {
    left.labels().map(|l| table[l as usize])
}

/// The map from the left view's labels to the right view's, sent with the
/// right view so that any mapping decodes. The two views are segmented
/// separately, so their classes correspond but their numbering may differ;
/// this encoder maps each left label to the right label of the nearest
/// colour (on the Middlebury pairs it predicts better than the most frequent
/// co-located label at the dominant disparity, which was also measured).
fn label_table(left: &IndexedImage, right: &IndexedImage) -> Vec<u16> {
    let dist = |a: &Rgb, b: &Rgb| {
        (0..3)
            .map(|k| (a[k] as i32 - b[k] as i32).pow(2))
            .sum::<i32>()
    };
    left.palette()
        .iter()
        .map(|c| {
            (0..right.palette().len())
                .min_by_key(|&i| (dist(c, &right.palette()[i]), i))
                .unwrap_or(0) as u16
        })
        .collect()
}

fn encode_report(w: &mut Writer, r: &DepthReport) {
    w.f32(r.target_distance_m);
    for v in r.target_region {
        w.u16(v);
    }
    w.u8(r.levels.len().min(255) as u8);
    for l in r.levels.iter().take(255) {
        w.f32(l.disparity);
        w.f32(l.distance_m);
        w.f32(l.share);
    }
    w.u32(r.histogram.len() as u32);
    for &h in &r.histogram {
        w.u32(h);
    }
}

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

/// Decodes one message; the bytes must hold exactly one header and its body.
pub fn decode(bytes: &[u8], limits: &Limits) -> Result<(Header, Message), CodecError> {
    let (header, body) = parse(bytes, limits)?;
    let msg = match body {
        Body::StereoFrame(f) => Message::StereoFrame(Box::new(f.decode()?)),
        Body::DepthReport(r) => Message::DepthReport(r),
        Body::Control(c) => Message::Control(c.to_vec()),
    };
    Ok((header, msg))
}

/// A message checked and parsed, its views not yet decoded (they borrow
/// the message bytes).
#[derive(Debug)]
pub enum Body<'a> {
    /// A stereo pair; decode its views with [`FrameRef::decode`] or, into
    /// buffers kept from frame to frame, [`FrameDecoder`].
    StereoFrame(FrameRef<'a>),
    /// A depth report.
    DepthReport(DepthReport),
    /// A control message's bytes.
    Control(&'a [u8]),
}

/// Checks a message (header, limits, CRC, structure) and parses its body
/// without decoding the views: every check of [`decode`] except those of
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

/// One coded view: how it is coded, its palette and its payload.
#[derive(Clone, Copy, Debug)]
pub struct ViewRef<'a> {
    coding: u8,
    /// The palette, three bytes (R, G, B) per colour.
    palette: &'a [u8],
    payload: &'a [u8],
}

impl ViewRef<'_> {
    /// Number of palette colours (0 for an RGB view).
    pub fn colours(&self) -> usize {
        self.palette.len() / 3
    }

    /// The palette's colours.
    fn palette(&self) -> impl Iterator<Item = Rgb> + '_ {
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
    if right.coding == coding::LABELS_CONDITIONED && left.coding == coding::RGB {
        return Err(CodecError::Invalid(
            "conditioned view without an indexed left view".into(),
        ));
    }
    if left.coding == coding::LABELS_CONDITIONED {
        return Err(CodecError::Invalid(
            "the left view is coded conditioned (on nothing)".into(),
        ));
    }
    let planes = parse_sections(r, w * h)?;
    if planes.is_some() && left.coding == coding::RGB {
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
        coding::RGB => {}
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

impl FrameRef<'_> {
    /// Decodes both views into an owned [`StereoFrame`].
    pub fn decode(&self) -> Result<StereoFrame, CodecError> {
        let mut d = FrameDecoder::default();
        d.decode_labels(self)?;
        let view = |v: &ViewRef, labels: LabelMap, rgb: RgbImage| -> Result<View, CodecError> {
            Ok(match v.coding {
                coding::RGB => View::Rgb(rgb),
                _ => View::Indexed(
                    IndexedImage::new(labels, v.palette().collect())
                        .map_err(|e| CodecError::Invalid(e.to_string()))?,
                ),
            })
        };
        let planes = match &self.planes {
            Some(coded) => {
                let (ids, count) = components(&d.labels.0, coded.tile() as usize);
                Some(coded.resolve(&ids, count)?)
            }
            None => None,
        };
        Ok(StereoFrame {
            kind: self.kind,
            levels: self.levels,
            params: self.params.to_owned(),
            thresholds: self.thresholds.map(|t| t.map(<[u8]>::to_vec)),
            calibration: self.calibration,
            left: view(&self.left, d.labels.0, d.rgb.0)?,
            right: view(&self.right, d.labels.1, d.rgb.1)?,
            planes,
        })
    }
}

/// Decodes frame after frame into buffers it keeps: the label maps, the
/// RGB views, the stereo prediction and the models. After the first frame
/// of a size it allocates nothing.
#[derive(Default)]
pub struct FrameDecoder {
    labels: (LabelMap, LabelMap),
    rgb: (RgbImage, RgbImage),
    predicted: LabelMap,
    /// The conditioned view's label table.
    table: Vec<u16>,
    /// Each view's palette, for the label decoder and the colours.
    palettes: [Vec<Rgb>; 2],
    /// Whether each view of the last frame is indexed, and whether `rgb`
    /// holds the indexed views' colours yet ([`expand_views`](Self::expand_views)).
    indexed: [bool; 2],
    expanded: bool,
    label_decoder: labels::LabelDecoder,
    rgb_decoder: rgb::RgbDecoder,
}

impl FrameDecoder {
    /// Decodes both views of `frame` as RGB images, then in [`views`](Self::views).
    pub fn decode_rgb(&mut self, frame: &FrameRef) -> Result<(), CodecError> {
        self.decode(frame)?;
        self.expand_views();
        Ok(())
    }

    /// Decodes both views of `frame`: indexed views into their label maps
    /// ([`indexed_views`](Self::indexed_views)), whose colours
    /// [`expand_views`](Self::expand_views) writes when asked (a receiver
    /// that works on the labels needs none), RGB views into
    /// [`views`](Self::views).
    pub fn decode(&mut self, frame: &FrameRef) -> Result<(), CodecError> {
        self.expanded = false;
        self.indexed = [frame.left, frame.right].map(|v| v.coding != coding::RGB);
        self.decode_labels(frame)
    }

    /// Writes the colours of the last frame's indexed views into
    /// [`views`](Self::views), once per frame.
    pub fn expand_views(&mut self) {
        if self.expanded {
            return;
        }
        self.expanded = true;
        let views = [
            (self.indexed[0], &self.labels.0, &mut self.rgb.0),
            (self.indexed[1], &self.labels.1, &mut self.rgb.1),
        ];
        for ((indexed, labels, rgb), palette) in views.into_iter().zip(&self.palettes) {
            if indexed {
                // One lookup per pixel (labels were checked against the
                // palette's size).
                if rgb.dims() != labels.dims() {
                    rgb.reset(labels.width(), labels.height(), [0; 3]);
                }
                let pixels = rgb.as_mut_slice().iter_mut().zip(labels.as_slice());
                pixels.for_each(|(p, &l)| *p = palette[l as usize]);
            }
        }
    }

    /// The left label map of the last frame decoded, if its left view is
    /// indexed (what a plane table's segments are the components of).
    pub fn left_labels(&self, frame: &FrameRef) -> Option<&LabelMap> {
        (frame.left.coding != coding::RGB).then_some(&self.labels.0)
    }

    /// The label maps of the last frame decoded, each with its palette,
    /// if both views are indexed: what the views' colours come from.
    pub fn indexed_views(&self) -> Option<[(&LabelMap, &[Rgb]); 2]> {
        (self.indexed == [true; 2]).then_some([
            (&self.labels.0, &self.palettes[0][..]),
            (&self.labels.1, &self.palettes[1][..]),
        ])
    }

    /// The views of the last frame [`decode_rgb`](Self::decode_rgb) decoded
    /// (or [`decode`](Self::decode) and [`expand_views`](Self::expand_views)).
    pub fn views(&self) -> (&RgbImage, &RgbImage) {
        (&self.rgb.0, &self.rgb.1)
    }

    /// Decodes each view: indexed views into the label maps, RGB views into
    /// the RGB images.
    fn decode_labels(&mut self, frame: &FrameRef) -> Result<(), CodecError> {
        let (w, h) = (frame.width, frame.height);
        for (i, view) in [frame.left, frame.right].iter().enumerate() {
            let (labels, rgb) = if i == 0 {
                (&mut self.labels.0, &mut self.rgb.0)
            } else {
                (&mut self.labels.1, &mut self.rgb.1)
            };
            let n = view.colours();
            let palette = &mut self.palettes[i];
            palette.clear();
            palette.extend(view.palette());
            match view.coding {
                coding::RGB => {
                    rgb.reset(w, h, [0; 3]);
                    self.rgb_decoder.decode_into(view.payload, rgb)?;
                }
                coding::LABELS => {
                    // The decoder writes every label: a map of the size is
                    // not cleared first.
                    if labels.dims() != (w, h) {
                        labels.reset(w, h, 0);
                    }
                    self.label_decoder
                        .decode_into(view.payload, palette, None, labels)?;
                }
                _ => {
                    // Conditioned: the label table (one u16 per left label,
                    // each below this view's palette size), then the labels
                    // predicted through it from the left view.
                    let (table, coded) = view
                        .payload
                        .split_at_checked(2 * frame.left.colours())
                        .ok_or(CodecError::Truncated("label table"))?;
                    self.table.clear();
                    self.table.extend(
                        table
                            .chunks_exact(2)
                            .map(|t| u16::from_le_bytes([t[0], t[1]])),
                    );
                    if let Some(&bad) = self.table.iter().find(|&&t| t as usize >= n) {
                        return Err(CodecError::LabelOutOfRange {
                            label: bad as u32,
                            labels: n,
                        });
                    }
                    // The left labels index the table: the left view decoded
                    // below its palette size, the table's length.
                    let table = &self.table;
                    self.labels
                        .0
                        .map_into(&mut self.predicted, |l| table[l as usize]);
                    let right = &mut self.labels.1;
                    if right.dims() != (w, h) {
                        right.reset(w, h, 0);
                    }
                    self.label_decoder
                        .decode_into(coded, palette, Some(&self.predicted), right)?;
                }
            }
        }
        Ok(())
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use stereolink_image::{LabelMap, RgbImage};

    fn frame(w: usize, h: usize) -> StereoFrame {
        let palette = vec![[10, 20, 30], [200, 100, 0], [0, 255, 0]];
        let left = IndexedImage::new(
            LabelMap::from_fn(w, h, |x, y| ((x / 3 + y / 2) % 3) as u16),
            palette.clone(),
        )
        .unwrap();
        let right = IndexedImage::new(
            LabelMap::from_fn(w, h, |x, y| (((x + 3) / 3 + y / 2) % 3) as u16),
            palette,
        )
        .unwrap();
        StereoFrame {
            kind: SegmentationKind::Fodpso,
            levels: 3,
            params: "alpha=0.6".into(),
            thresholds: Some([vec![80, 160], vec![90], vec![]]),
            calibration: Some(Calibration {
                focal_px: Some(700.0),
                baseline_m: Some(0.12),
                doffs: 0.0,
                ndisp: 64,
            }),
            left: View::Indexed(left),
            right: View::Indexed(right),
            planes: None,
        }
    }

    #[test]
    fn frames_reports_and_control_round_trip() {
        for (w, h) in [(1, 1), (7, 3), (33, 17)] {
            let m = Message::StereoFrame(Box::new(frame(w, h)));
            let bytes = encode(&m, 42, 123_456);
            let (hd, back) = decode(&bytes, &Limits::default()).unwrap();
            assert_eq!(
                (hd.frame_id, hd.timestamp_us, hd.kind),
                (42, 123_456, kind::STEREO_FRAME)
            );
            assert_eq!(back, m);
        }
        let rgb = StereoFrame {
            left: View::Rgb(RgbImage::from_fn(5, 4, |x, y| [x as u8, y as u8, 9])),
            right: View::Rgb(RgbImage::new(5, 4, [1, 2, 3])),
            thresholds: None,
            calibration: None,
            kind: SegmentationKind::None,
            ..frame(5, 4)
        };
        let m = Message::StereoFrame(Box::new(rgb));
        assert_eq!(decode(&encode(&m, 1, 2), &Limits::default()).unwrap().1, m);
        let c = Message::Control(vec![1, 2, 3]);
        assert_eq!(decode(&encode(&c, 1, 2), &Limits::default()).unwrap().1, c);
    }

    /// The largest palette the default limits accept, 65536 colours (labels
    /// are u16), comes back whole.
    #[test]
    fn largest_palette_round_trips() {
        let palette: Vec<Rgb> = (0..1u32 << 16)
            .map(|i| [i as u8, (i >> 8) as u8, 7])
            .collect();
        let left =
            IndexedImage::new(LabelMap::from_fn(2, 1, |x, _| x as u16 * 65535), palette).unwrap();
        let m = Message::StereoFrame(Box::new(StereoFrame {
            left: View::Indexed(left),
            right: View::Rgb(RgbImage::new(2, 1, [1, 2, 3])),
            ..frame(2, 1)
        }));
        assert_eq!(decode(&encode(&m, 1, 2), &Limits::default()).unwrap().1, m);
    }

    #[test]
    fn corrupt_and_foreign_bytes_are_typed_errors() {
        let bytes = encode(&Message::StereoFrame(Box::new(frame(20, 10))), 1, 1);
        let l = Limits::default();
        let mut bad = bytes.clone();
        bad[HEADER_LEN + 5] ^= 0x10;
        assert_eq!(decode(&bad, &l).unwrap_err(), CodecError::Crc);
        let mut v1 = bytes.clone();
        v1[4] = 1;
        assert_eq!(
            decode(&v1, &l).unwrap_err(),
            CodecError::UnsupportedVersion(1)
        );
        assert_eq!(decode(b"PNG....", &l).unwrap_err(), CodecError::BadMagic);
        assert!(matches!(
            decode(&bytes[..bytes.len() - 1], &l),
            Err(CodecError::Truncated(_))
        ));
        // A left view coded conditioned (the left view's coding byte is the
        // body's tenth without params, thresholds and calibration), even
        // after a frame that left labels behind in a reused decoder.
        let plain = StereoFrame {
            params: String::new(),
            thresholds: None,
            calibration: None,
            ..frame(20, 10)
        };
        let good = encode(&Message::StereoFrame(Box::new(plain)), 1, 1);
        let mut cond = good.clone();
        assert_eq!(cond[HEADER_LEN + 9], coding::LABELS);
        cond[HEADER_LEN + 9] = coding::LABELS_CONDITIONED;
        let crc = crc32fast::hash(&cond[HEADER_LEN..]);
        cond[24..28].copy_from_slice(&crc.to_le_bytes());
        assert!(matches!(decode(&cond, &l), Err(CodecError::Invalid(_))));
        let mut reused = FrameDecoder::default();
        for (bytes, ok) in [(&good, true), (&cond, false)] {
            let result = parse(bytes, &l).and_then(|(_, body)| match body {
                Body::StereoFrame(f) => reused.decode_rgb(&f),
                _ => unreachable!("a stereo frame"),
            });
            assert_eq!(result.is_ok(), ok);
        }
        let tight = Limits { max_body: 10, ..l };
        assert!(matches!(
            decode(&bytes, &tight),
            Err(CodecError::TooLarge { .. })
        ));
        let tiny = Limits {
            max_pixels: 100,
            ..l
        };
        assert!(matches!(
            decode(&bytes, &tiny),
            Err(CodecError::TooLarge { .. })
        ));
    }

    /// [`frame`] with a plane table: five planes over the segments of its
    /// left labels.
    fn with_planes(w: usize, h: usize) -> StereoFrame {
        let f = frame(w, h);
        let View::Indexed(left) = &f.left else {
            unreachable!("an indexed left view")
        };
        let (ids, count) = components(left.labels(), 0);
        let per: Vec<[f32; 3]> = (0..count).map(|s| [0.5, -0.25, (s % 5) as f32]).collect();
        let coding = crate::planetable::TableCoding::default();
        StereoFrame {
            planes: Some(crate::planetable::PlaneTable::quantise(
                0,
                (0, 15),
                coding,
                Some(&ids),
                &per,
            )),
            ..f
        }
    }

    #[test]
    fn plane_tables_round_trip_and_unknown_sections_are_skipped() {
        let l = Limits::default();
        let m = Message::StereoFrame(Box::new(with_planes(21, 9)));
        let bytes = encode(&m, 3, 4);
        assert_eq!(decode(&bytes, &l).unwrap().1, m);
        // Without the table, the frame is the plain frame's bytes: the
        // section is appended, so a decoder before sections sees trailing
        // bytes and refuses the frame.
        let plain = encode(&Message::StereoFrame(Box::new(frame(21, 9))), 3, 4);
        assert_eq!(&bytes[HEADER_LEN..plain.len()], &plain[HEADER_LEN..]);
        let mut body = bytes[HEADER_LEN..].to_vec();
        // An unknown section (tag 9) and plane tables of versions 1 (the
        // old raw indices) and 2 (every index coded) are skipped.
        body.extend([9, 1, 2, 0, 0, 0, 0xAA, 0xBB]);
        body.extend([1, 1, 0, 0, 0, 0, 1, 2, 0, 0, 0, 0]);
        let reframe = |body: &[u8]| {
            let mut out = bytes[..HEADER_LEN].to_vec();
            out[20..24].copy_from_slice(&(body.len() as u32).to_le_bytes());
            out[24..28].copy_from_slice(&crc32fast::hash(body).to_le_bytes());
            out.extend_from_slice(body);
            out
        };
        assert_eq!(decode(&reframe(&body), &l).unwrap().1, m);
        // A second table, a truncated section and a table on an RGB left
        // view are errors.
        let section = &bytes[plain.len()..];
        let mut two = body.clone();
        two.extend_from_slice(section);
        assert!(matches!(
            decode(&reframe(&two), &l),
            Err(CodecError::Invalid(_))
        ));
        assert!(matches!(
            decode(&reframe(&body[..body.len() - 1]), &l),
            Err(CodecError::Truncated(_))
        ));
        let rgb = StereoFrame {
            left: View::Rgb(RgbImage::new(21, 9, [1, 2, 3])),
            ..with_planes(21, 9)
        };
        let rgb = encode(&Message::StereoFrame(Box::new(rgb)), 1, 1);
        assert!(matches!(decode(&rgb, &l), Err(CodecError::Invalid(_))));
    }

    /// Pins the wire format: a depth report's exact bytes (checked independently
    /// with Python's `struct` and `zlib.crc32`).
    #[test]
    fn golden_depth_report() {
        let r = DepthReport {
            target_distance_m: 0.5,
            target_region: [1, 2, 3, 4],
            levels: vec![ReportLevel {
                disparity: 2.0,
                distance_m: 1.0,
                share: 0.5,
            }],
            histogram: vec![7],
        };
        let bytes = encode(&Message::DepthReport(r), 0x0102_0304, 5);
        let hex: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(
            hex,
            "534c4e4b02020000040302010500000000000000210000006237a12c\
             0000003f01000200030004000100000040\
             0000803f0000003f0100000007000000"
        );
    }

    proptest! {
        /// Corrupted bodies with a correct CRC reach every body parser and
        /// the view decoders: a typed error or a message, never a panic;
        /// the owning decode and the reusing decoder (with the plane table
        /// resolved against its labels, as the board does) agree.
        #[test]
        fn corrupt_bodies_are_errors_or_messages(
            flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8),
            cut in any::<usize>(),
        ) {
            let f = with_planes(21, 9);
            let mut bytes = encode(&Message::StereoFrame(Box::new(f)), 1, 2);
            for (at, x) in flips {
                let i = HEADER_LEN + at % (bytes.len() - HEADER_LEN);
                bytes[i] ^= x | 1;
            }
            bytes.truncate(HEADER_LEN + cut % (bytes.len() - HEADER_LEN + 1));
            let body_len = (bytes.len() - HEADER_LEN) as u32;
            bytes[20..24].copy_from_slice(&body_len.to_le_bytes());
            let crc = crc32fast::hash(&bytes[HEADER_LEN..]);
            bytes[24..28].copy_from_slice(&crc.to_le_bytes());
            let owned = decode(&bytes, &Limits::default());
            if let Ok((_, Body::StereoFrame(f))) = parse(&bytes, &Limits::default()) {
                let mut decoder = FrameDecoder::default();
                let reused = decoder.decode_rgb(&f).and_then(|()| {
                    if let (Some(t), Some(labels)) = (&f.planes, decoder.left_labels(&f)) {
                        let (ids, count) = components(labels, t.tile() as usize);
                        t.resolve(&ids, count)?;
                    }
                    Ok(decoder.views())
                });
                match (&owned, reused) {
                    (Ok((_, Message::StereoFrame(m))), Ok((l, r))) => {
                        prop_assert_eq!(&m.left.to_rgb(), l);
                        prop_assert_eq!(&m.right.to_rgb(), r);
                    }
                    (Err(_), Err(_)) => {}
                    (a, b) => prop_assert!(false, "owned {:?} but reused {:?}", a.is_ok(), b.is_ok()),
                }
            }
        }
    }
}
