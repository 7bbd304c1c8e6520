//! Serialising messages: the header, a stereo frame's fields and views
//! (the right view coded conditioned on the left through a label table),
//! the plane table section, and depth reports.

use stereolink_image::segments::components;
use stereolink_image::{IndexedImage, LabelMap, Rgb};

use super::{coding, kind, Writer, HEADER_LEN, MAGIC, SHIFT_SEARCH, VERSION};
use crate::{labels, rgb, DepthReport, Message, StereoFrame, View};

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
        View::PredictedLabels(l) => Some(l.image()),
        View::Rgb(_) | View::Lossy(_) | View::Predicted(_) | View::Stereo(_) | View::Motion(_) => {
            None
        }
    };
    encode_view(w, &f.right, reference, mode);
    if let Some(t) = &f.planes {
        let ids = match &f.left {
            View::Indexed(l) => Some(components(l.labels(), t.tile as usize).0),
            View::PredictedLabels(l) => Some(components(l.image().labels(), t.tile as usize).0),
            View::Rgb(_)
            | View::Lossy(_)
            | View::Predicted(_)
            | View::Stereo(_)
            | View::Motion(_) => None,
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
        View::Lossy(v) => {
            let mut payload = Vec::with_capacity(1 + v.bytes().len());
            payload.push(v.codec() as u8);
            payload.extend_from_slice(v.bytes());
            (coding::LOSSY, &[], payload)
        }
        View::Predicted(v) => (coding::PREDICTED, &[], v.payload()),
        View::Stereo(v) => (coding::STEREO, &[], v.payload()),
        View::Motion(v) => (coding::MOTION, &[], v.payload()),
        View::PredictedLabels(v) => (
            coding::LABELS_PREDICTED,
            v.image().palette(),
            v.payload().to_vec(),
        ),
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
    predicted_payload(left, right, SHIFT_SEARCH, mode)
}

/// The payload of `view` coded predicted from `reference` (the left view,
/// or an earlier frame's same view) with shifts searched up to
/// `max_shift`: the label table, then the labels predicted through it.
pub(crate) fn predicted_payload(
    reference: &IndexedImage,
    view: &IndexedImage,
    max_shift: usize,
    mode: labels::Mode,
) -> Vec<u8> {
    let table = label_table(reference, view);
    let predicted = prediction(reference, &table);
    let mut payload: Vec<u8> = table.iter().flat_map(|t| t.to_le_bytes()).collect();
    payload.extend(labels::encode(
        view.labels(),
        view.palette(),
        Some(&predicted),
        max_shift,
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
/// colour, which predicts better than the most frequent co-located label
/// at the dominant disparity (docs/tuning.md, “The label table: nearest
/// colour”).
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

/// Bytes one depth level takes in a report's body.
pub const REPORT_LEVEL_LEN: usize = 12;

/// The encoded length of a depth report message with `levels` levels and
/// `bins` histogram bins, header included.
pub fn report_len(levels: usize, bins: usize) -> usize {
    HEADER_LEN + 4 + 8 + 1 + levels * REPORT_LEVEL_LEN + 4 + 4 * bins
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
