//! Lossless coding of label maps with an adaptive context model.
//!
//! Each pixel is coded as a short sequence of binary decisions with the
//! [range coder](crate::rangecoder): "is it the same label as candidate i?"
//! for the causal neighbours W, N, NE, NW (duplicates skipped), and, when the
//! map is the right view of a pair, right after W the **stereo prediction** P: the
//! left view's label at `x + s`, with one shift `s` per block of
//! [`BLOCK`] columns of a row chosen by the encoder (the dominant disparity
//! there) and sent with the row. Each decision's context is the candidate's
//! rank and the equality pattern of the neighbours, so flat areas cost a few
//! hundredths of a bit per pixel (an implicit run mode) and edges that the
//! left view already shows cost little more. A label matching no candidate is
//! sent explicitly with a binary tree of adaptive probabilities.

use stereolink_image::LabelMap;

use crate::rangecoder::{BitTree, Decoder, Encoder, Prob};
use crate::CodecError;

/// Columns per stereo-shift block.
pub const BLOCK: usize = 32;
/// Largest stereo shift searched and coded (8 bits).
pub const MAX_SHIFT: usize = 255;

const CANDIDATES: usize = 5;
const PATTERNS: usize = 128;

struct Model {
    flags: Vec<Prob>,
    explicit: BitTree,
    same_shift: Prob,
    shift: BitTree,
}

impl Model {
    fn new(n_labels: usize) -> Self {
        let mut model = Model {
            flags: Vec::new(),
            explicit: BitTree::new(0),
            same_shift: Prob::default(),
            shift: BitTree::new(8),
        };
        model.reset(n_labels);
        model
    }

    /// Back to the initial state for `n_labels` labels, reusing the storage.
    fn reset(&mut self, n_labels: usize) {
        let bits = usize::BITS - (n_labels.max(1) - 1).leading_zeros();
        self.flags.clear();
        self.flags.resize(CANDIDATES * PATTERNS, Prob::default());
        self.explicit.reset(bits);
        self.same_shift = Prob::default();
        self.shift.reset(8);
    }
}

/// Stands for a neighbour outside the map (or no prediction).
const NONE: u32 = u32::MAX;

/// The candidates of pixel (x, y), in coding order, and the context pattern.
#[inline(always)]
fn candidates(
    map: &[u16],
    w: usize,
    x: usize,
    y: usize,
    predicted: Option<u16>,
) -> ([u16; CANDIDATES], usize, usize) {
    let p = predicted.map_or(NONE, u32::from);
    let (wv, nv, nw, ne) = if y > 0 && x > 0 && x + 1 < w {
        // Inside: direct reads (most pixels).
        let up = &map[(y - 1) * w + x - 1..(y - 1) * w + x + 2];
        let [nw, nv, ne] = [up[0], up[1], up[2]].map(u32::from);
        let wv = u32::from(map[y * w + x - 1]);
        if wv == nv && nv == nw && nv == ne {
            // Flat (most of a segmented map): what the general case below
            // gives, without its work.
            let same = (p == wv) as usize;
            let pattern = 0b1111 | ((p != NONE) as usize) << 4 | same << 5 | same << 6;
            let mut list = [wv as u16; CANDIDATES];
            let n = if p != NONE && same == 0 {
                list[1] = p as u16;
                2
            } else {
                1
            };
            return (list, n, pattern);
        }
        (wv, nv, nw, ne)
    } else {
        let at = |dx: isize, dy: isize| {
            let (xx, yy) = (x as isize + dx, y as isize + dy);
            if xx >= 0 && yy >= 0 && (xx as usize) < w {
                u32::from(map[yy as usize * w + xx as usize])
            } else {
                NONE
            }
        };
        (at(-1, 0), at(0, -1), at(-1, -1), at(1, -1))
    };
    let eq = |a: u32, b: u32| (a == b && a != NONE) as usize;
    let pattern = eq(wv, nv)
        | eq(nv, ne) << 1
        | eq(wv, nw) << 2
        | eq(nv, nw) << 3
        | ((p != NONE) as usize) << 4
        | eq(p, wv) << 5
        | eq(p, nv) << 6;
    let mut list = [0u16; CANDIDATES];
    let mut n = 0;
    for c in [wv, p, nv, ne, nw] {
        if c != NONE && !list[..n].contains(&(c as u16)) {
            list[n] = c as u16;
            n += 1;
        }
    }
    (list, n, pattern)
}

/// How many more pixels a new shift must predict than the block's current
/// one to be worth its side information (a new shift costs about nine bits).
const SHIFT_CHANGE_GAIN: usize = 3;

/// Per-block shifts that best predict row `y` of `map` from `reference`.
///
/// Only pixels that the causal neighbours do not already give (different
/// from W or from N) count: elsewhere every shift is as good. A block keeps
/// the shift of the block above unless another predicts more than
/// [`SHIFT_CHANGE_GAIN`] more of those pixels, so the shifts change only
/// where it pays; the first row takes the best shift of each block.
fn best_shifts(
    map: &LabelMap,
    reference: &LabelMap,
    y: usize,
    max_shift: usize,
    above: &[u8],
    out: &mut Vec<u8>,
) {
    let w = map.width();
    let (row, refrow) = (map.row(y), reference.row(y));
    let up = (y > 0).then(|| map.row(y - 1));
    let surprising: Vec<usize> = (0..w)
        .filter(|&x| (x > 0 && row[x] != row[x - 1]) || up.is_some_and(|u| u[x] != row[x]))
        .collect();
    out.clear();
    for (b, x0) in (0..w).step_by(BLOCK).enumerate() {
        let x1 = (x0 + BLOCK).min(w);
        let lo = surprising.partition_point(|&x| x < x0);
        let hi = surprising.partition_point(|&x| x < x1);
        let pixels = &surprising[lo..hi];
        let hits = |s: usize| {
            pixels
                .iter()
                .filter(|&&x| x + s < w && row[x] == refrow[x + s])
                .count()
        };
        // Without a block above (the first row) every shift is sent anyway.
        let (keep, margin) = match above.get(b) {
            Some(&s) => (s as usize, SHIFT_CHANGE_GAIN),
            None => (0, 0),
        };
        let kept = hits(keep);
        // The best shift (the smallest among equals) replaces the kept one
        // only if it predicts enough more.
        let best = (0..=max_shift.min(w - 1))
            .map(|s| (hits(s), s))
            .max_by_key(|&(h, s)| (h, std::cmp::Reverse(s)))
            .filter(|&(h, _)| h > kept + margin);
        out.push(best.map_or(keep, |(_, s)| s) as u8);
    }
}

/// Codes `map` (labels below `n_labels`); with `reference`, predicts from it
/// through per-block shifts searched up to `max_shift`.
pub fn encode(
    map: &LabelMap,
    n_labels: usize,
    reference: Option<&LabelMap>,
    max_shift: usize,
) -> Vec<u8> {
    let (w, h) = map.dims();
    let mut model = Model::new(n_labels);
    let mut enc = Encoder::new();
    let data = map.as_slice();
    let mut shifts = Vec::new();
    let mut above: Vec<u8> = Vec::new();
    for y in 0..h {
        if let Some(r) = reference {
            best_shifts(map, r, y, max_shift.min(MAX_SHIFT), &above, &mut shifts);
            for (b, &s) in shifts.iter().enumerate() {
                let same = above.get(b) == Some(&s);
                enc.bit(&mut model.same_shift, same);
                if !same {
                    model.shift.encode(&mut enc, s as u32);
                }
            }
            above.clone_from(&shifts);
        }
        for x in 0..w {
            let predicted = reference.and_then(|r| {
                let xs = x + shifts[x / BLOCK] as usize;
                (xs < w).then(|| r.get(xs, y))
            });
            let (list, n, pattern) = candidates(data, w, x, y, predicted);
            let v = data[y * w + x];
            let mut found = false;
            for (i, &c) in list[..n].iter().enumerate() {
                let hit = c == v;
                enc.bit(&mut model.flags[i * PATTERNS + pattern], hit);
                if hit {
                    found = true;
                    break;
                }
            }
            if !found {
                model.explicit.encode(&mut enc, v as u32);
            }
        }
    }
    enc.finish()
}

/// Decodes a `w`×`h` map written by [`encode`] (with the same reference).
///
/// Fails if a decoded label is not below `n_labels` or the stream ends too early.
pub fn decode(
    bytes: &[u8],
    w: usize,
    h: usize,
    n_labels: usize,
    reference: Option<&LabelMap>,
) -> Result<LabelMap, CodecError> {
    let mut out = LabelMap::new(w, h, 0);
    decode_into(bytes, n_labels, reference, &mut out)?;
    Ok(out)
}

/// [`decode`] into a caller-provided map (its size gives `w`×`h`).
pub fn decode_into(
    bytes: &[u8],
    n_labels: usize,
    reference: Option<&LabelMap>,
    out: &mut LabelMap,
) -> Result<(), CodecError> {
    LabelDecoder::default().decode_into(bytes, n_labels, reference, out)
}

/// Decodes map after map with one model and buffers, so that a receiver
/// decoding frame after frame allocates nothing once they have grown.
pub struct LabelDecoder {
    model: Model,
    shifts: Vec<u8>,
}

impl Default for LabelDecoder {
    fn default() -> Self {
        LabelDecoder {
            model: Model::new(1),
            shifts: Vec::new(),
        }
    }
}

impl LabelDecoder {
    /// [`decode`] into a caller-provided map (its size gives `w`×`h`).
    pub fn decode_into(
        &mut self,
        bytes: &[u8],
        n_labels: usize,
        reference: Option<&LabelMap>,
        out: &mut LabelMap,
    ) -> Result<(), CodecError> {
        let (w, h) = out.dims();
        if let Some(r) = reference {
            if r.dims() != (w, h) {
                return Err(CodecError::Invalid("reference view size differs".into()));
            }
        }
        let model = &mut self.model;
        model.reset(n_labels);
        let mut dec = Decoder::new(bytes);
        let shifts = &mut self.shifts;
        shifts.clear();
        shifts.resize(w.div_ceil(BLOCK), 0);
        let data = out.as_mut_slice();
        for y in 0..h {
            if reference.is_some() {
                for s in shifts.iter_mut() {
                    if !dec.bit(&mut model.same_shift) {
                        *s = model.shift.decode(&mut dec) as u8;
                    }
                }
            }
            for x in 0..w {
                let predicted = reference.and_then(|r| {
                    let xs = x + shifts[x / BLOCK] as usize;
                    (xs < w).then(|| r.get(xs, y))
                });
                let (list, n, pattern) = candidates(data, w, x, y, predicted);
                let mut value = None;
                for (i, &c) in list[..n].iter().enumerate() {
                    if dec.bit(&mut model.flags[i * PATTERNS + pattern]) {
                        value = Some(c);
                        break;
                    }
                }
                let v = match value {
                    Some(v) => v,
                    None => {
                        let v = model.explicit.decode(&mut dec);
                        if v as usize >= n_labels {
                            return Err(CodecError::LabelOutOfRange {
                                label: v,
                                labels: n_labels,
                            });
                        }
                        v as u16
                    }
                };
                data[y * w + x] = v;
            }
            if dec.overrun() {
                return Err(CodecError::Truncated("label stream"));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn blobs(w: usize, h: usize, n: u16, seed: u64) -> LabelMap {
        LabelMap::from_fn(w, h, |x, y| {
            let v = (x / 7 + (y / 5) * 3) as u64 ^ seed;
            (v.wrapping_mul(0x9E37_79B9) >> 7) as u16 % n
        })
    }

    proptest! {
        #[test]
        fn round_trip_alone_and_conditioned(w in 1usize..70, h in 1usize..20, n in 1u16..40, seed in any::<u64>(), noise in any::<u64>()) {
            let left = blobs(w, h, n, seed);
            // The right view: the left shifted by 3, plus sparse noise.
            let mut s = noise | 1;
            let right = LabelMap::from_fn(w, h, |x, y| {
                s ^= s << 13; s ^= s >> 7; s ^= s << 17;
                if s % 17 == 0 { (s >> 20) as u16 % n } else { left.get((x + 3).min(w - 1), y) }
            });
            let a = encode(&left, n as usize, None, 0);
            prop_assert_eq!(decode(&a, w, h, n as usize, None).unwrap(), left.clone());
            let b = encode(&right, n as usize, Some(&left), 16);
            prop_assert_eq!(decode(&b, w, h, n as usize, Some(&left)).unwrap(), right);
        }

        #[test]
        fn garbage_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..64), w in 1usize..30, h in 1usize..30) {
            let _ = decode(&bytes, w, h, 5, None);
        }
    }

    #[test]
    fn conditioning_on_the_left_view_pays() {
        let left = blobs(200, 100, 6, 1);
        let right = LabelMap::from_fn(200, 100, |x, y| left.get((x + 9).min(199), y));
        let alone = encode(&right, 6, None, 0).len();
        let cond = encode(&right, 6, Some(&left), 32).len();
        assert!(cond * 2 < alone, "alone {alone} conditioned {cond}");
    }
}
