//! The stereo prediction's per-block shifts: how the encoder chooses them
//! for each row, and how a row's shifts are coded.

use stereolink_image::LabelMap;

use super::bitio::{tree, BitIo};
use super::model::Model;

/// Columns per stereo-shift block.
pub const BLOCK: usize = 32;
/// Largest stereo shift searched and coded (8 bits).
pub const MAX_SHIFT: usize = 255;

/// Codes a row's block shifts, each as the same as the block's in the row
/// above or else in 8 bits: `plan` holds the encoder's from the row's
/// first block on (the decoder's is empty).
pub(super) fn code_shifts<I: BitIo>(io: &mut I, model: &mut Model, plan: &[u8], shifts: &mut [u8]) {
    for (b, s) in shifts.iter_mut().enumerate() {
        let want = plan.get(b).copied().unwrap_or(0);
        if !io.bit(&mut model.same_shift, want == *s) {
            *s = tree(io, &mut model.shift, 8, want as u32) as u8;
        }
    }
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
        // The first row has no block above: every shift is sent anyway.
        let (keep, margin) = match y {
            0 => (0, 0),
            _ => (above[b] as usize, SHIFT_CHANGE_GAIN),
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

/// The stereo shifts [`encode`](super::encode) sends for `map` predicted
/// from `reference` (searched up to `max_shift`): one per block of
/// [`BLOCK`] columns per row, row-major; the prediction of pixel (x, y) is
/// the reference's label at (x + s, y), s the shift of block x / [`BLOCK`]
/// of row y.
pub fn plan_shifts(map: &LabelMap, reference: &LabelMap, max_shift: usize) -> Vec<u8> {
    let (w, h) = map.dims();
    let mut plan = Vec::with_capacity(h * w.div_ceil(BLOCK));
    let mut above = vec![0; w.div_ceil(BLOCK)];
    let mut row = Vec::new();
    for y in 0..h {
        best_shifts(
            map,
            reference,
            y,
            max_shift.min(MAX_SHIFT),
            &above,
            &mut row,
        );
        plan.extend_from_slice(&row);
        std::mem::swap(&mut above, &mut row);
    }
    plan
}
