//! Decoding a parsed frame's views: into an owned frame, or with a
//! [`FrameDecoder`] into buffers kept from frame to frame, so that a
//! receiver allocates nothing once they have grown.

use stereolink_image::segments::components;
use stereolink_image::{IndexedImage, LabelMap, Rgb, RgbImage};

use super::{coding, FrameRef, ViewRef};
use crate::lossy::{self, LossyView};
use crate::motion::{MotionDecoder, MotionView};
use crate::stereo::{StereoDecoder, StereoView};
use crate::temporal::{self, References};
use crate::{labels, rgb, CodecError, StereoFrame, View};

impl FrameRef<'_> {
    /// Decodes both views into an owned [`StereoFrame`] (a key frame: a
    /// predicted view is [`CodecError::MissingReference`]).
    pub fn decode(&self) -> Result<StereoFrame, CodecError> {
        self.decode_with(&References::default())
    }

    /// Decodes both views into an owned [`StereoFrame`], predicted views
    /// from the frames in `refs`.
    pub fn decode_with(&self, refs: &References) -> Result<StereoFrame, CodecError> {
        let mut d = FrameDecoder::default();
        d.decode_labels(self, refs)?;
        let (w, h) = (self.width, self.height);
        let left_rgb = d.rgb.0.clone();
        let view = |v: &ViewRef, side: usize, labels: LabelMap, rgb: RgbImage| {
            if let Some((codec, bits)) = v.lossy() {
                return Ok(View::Lossy(LossyView::decoded(codec, bits.to_vec(), rgb)));
            }
            Ok(match v.coding {
                coding::RGB => View::Rgb(rgb),
                coding::STEREO => View::Stereo(StereoView::decode(v.payload, &left_rgb)?),
                coding::PREDICTED => {
                    let coded = temporal::Coded::parse(v.payload, (w, h))?;
                    View::Predicted(coded.decode(&reference(refs, coded.reference)?[side])?)
                }
                coding::MOTION => {
                    let (id, _) = temporal::split_reference(v.payload)?;
                    View::Motion(MotionView::decode(v.payload, &reference(refs, id)?[side])?)
                }
                coding::LABELS_PREDICTED => {
                    let (id, _) = temporal::split_reference(v.payload)?;
                    let image = IndexedImage::new(labels, v.palette().collect())
                        .map_err(|e| CodecError::Invalid(e.to_string()))?;
                    View::PredictedLabels(temporal::PredictedLabels::decoded(
                        id,
                        image,
                        v.payload.to_vec(),
                    ))
                }
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
            left: view(&self.left, 0, d.labels.0, d.rgb.0)?,
            right: view(&self.right, 1, d.labels.1, d.rgb.1)?,
            planes,
        })
    }
}

/// The views of reference frame `id`, or the error that names it.
fn reference(refs: &References, id: temporal::RefId) -> Result<&[RgbImage; 2], CodecError> {
    refs.get(id).ok_or(CodecError::MissingReference {
        frame_id: id.frame_id,
        timestamp_us: id.timestamp_us,
    })
}

/// Reads a label table of `from` entries (each below `n`, the view's
/// palette size) from the start of `payload` into `table`; returns the
/// rest.
fn read_table<'a>(
    payload: &'a [u8],
    from: usize,
    n: usize,
    table: &mut Vec<u16>,
) -> Result<&'a [u8], CodecError> {
    let (raw, coded) = payload
        .split_at_checked(2 * from)
        .ok_or(CodecError::Truncated("label table"))?;
    table.clear();
    table.extend(
        raw.chunks_exact(2)
            .map(|t| u16::from_le_bytes([t[0], t[1]])),
    );
    if let Some(&bad) = table.iter().find(|&&t| t as usize >= n) {
        return Err(CodecError::LabelOutOfRange {
            label: bad as u32,
            labels: n,
        });
    }
    Ok(coded)
}

/// The label maps and palettes of segmented reference frame `id`, or the
/// error that names it.
fn label_reference(
    refs: &References,
    id: temporal::RefId,
) -> Result<[(&LabelMap, &[Rgb]); 2], CodecError> {
    refs.get_labels(id).ok_or(CodecError::MissingReference {
        frame_id: id.frame_id,
        timestamp_us: id.timestamp_us,
    })
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
    /// A predicted view's changed blocks and their decoded mosaic.
    changed: Vec<bool>,
    mosaic: RgbImage,
    /// The stereo-predicted right view's decoder, and whether the last
    /// frame's right view was one.
    stereo: StereoDecoder,
    stereo_right: bool,
    /// The motion-predicted views' decoder.
    motion: MotionDecoder,
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
        self.decode_with(frame, &References::default())
    }

    /// [`decode`](Self::decode), predicted views from the frames in
    /// `refs` (a reference not held is [`CodecError::MissingReference`]).
    pub fn decode_with(&mut self, frame: &FrameRef, refs: &References) -> Result<(), CodecError> {
        self.expanded = false;
        self.indexed = [frame.left, frame.right].map(|v| coding::indexed(v.coding));
        self.decode_labels(frame, refs)
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
        coding::indexed(frame.left.coding).then_some(&self.labels.0)
    }

    /// The label maps of the last frame decoded, each with its palette,
    /// if both views are indexed: what the views' colours come from.
    pub fn indexed_views(&self) -> Option<[(&LabelMap, &[Rgb]); 2]> {
        (self.indexed == [true; 2]).then_some([
            (&self.labels.0, &self.palettes[0][..]),
            (&self.labels.1, &self.palettes[1][..]),
        ])
    }

    /// The cell disparities the last frame carried for its right view
    /// (raster order, [`crate::stereo::CELL`]-px cells), if it was
    /// stereo-predicted ([`crate::stereo`]): the sender's disparity.
    pub fn stereo_disparities(&self) -> Option<&[u16]> {
        self.stereo_right.then(|| self.stereo.disparities())
    }

    /// The views of the last frame [`decode_rgb`](Self::decode_rgb) decoded
    /// (or [`decode`](Self::decode) and [`expand_views`](Self::expand_views)).
    pub fn views(&self) -> (&RgbImage, &RgbImage) {
        (&self.rgb.0, &self.rgb.1)
    }

    /// Decodes each view: indexed views into the label maps, RGB and lossy
    /// views into the RGB images.
    fn decode_labels(&mut self, frame: &FrameRef, refs: &References) -> Result<(), CodecError> {
        let (w, h) = (frame.width, frame.height);
        self.stereo_right = false;
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
                coding::LOSSY => {
                    let (codec, bits) = view.lossy().ok_or(CodecError::Truncated("lossy view"))?;
                    lossy::decode_into(codec, bits, (w, h), rgb)?;
                }
                coding::STEREO => {
                    // Checked by `parse`: the right view, after an RGB left.
                    self.stereo
                        .decode_into(view.payload, &self.rgb.0, &mut self.rgb.1)?;
                    self.stereo_right = true;
                }
                coding::PREDICTED => {
                    let coded = temporal::Coded::parse(view.payload, (w, h))?;
                    let reference = &reference(refs, coded.reference)?[i];
                    coded.changed_into(&mut self.changed);
                    coded.decode_into(reference, &self.changed, &mut self.mosaic, rgb)?;
                }
                coding::MOTION => {
                    let (id, _) = temporal::split_reference(view.payload)?;
                    let reference = &reference(refs, id)?[i];
                    temporal::same_size(reference, (w, h))?;
                    self.motion.decode_into(view.payload, reference, rgb)?;
                }
                coding::LABELS_PREDICTED => {
                    // The reference, a label table (one u16 per reference
                    // label, each below this view's palette size), then
                    // the labels predicted through it from the reference.
                    let (id, rest) = temporal::split_reference(view.payload)?;
                    let (from, colours) = label_reference(refs, id)?[i];
                    if from.dims() != (w, h) {
                        return Err(CodecError::Invalid(format!(
                            "a {w}x{h} view predicted from a {}x{} one",
                            from.width(),
                            from.height()
                        )));
                    }
                    let coded = read_table(rest, colours.len(), n, &mut self.table)?;
                    let table = &self.table;
                    from.map_into(&mut self.predicted, |l| table[l as usize]);
                    if labels.dims() != (w, h) {
                        labels.reset(w, h, 0);
                    }
                    self.label_decoder.decode_into(
                        coded,
                        palette,
                        Some(&self.predicted),
                        labels,
                    )?;
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
                    let coded = read_table(view.payload, frame.left.colours(), n, &mut self.table)?;
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
