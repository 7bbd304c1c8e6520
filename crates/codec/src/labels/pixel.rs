//! One pixel's label in either mode: W first, then the other candidates of
//! the templates in a fixed order, then, if none holds it, the label
//! itself (label by label for small palettes, else as a binary tree).

use super::bitio::{tree, BitIo};
use super::model::Model;
use super::strong::{code_candidate, code_missed};
use super::template::{mask, NONE, OWN_LEN};
use crate::CodecError;

/// Palettes up to this size send a missed label label by label.
pub(super) const SEQUENTIAL_MAX: usize = 32;

/// Bits of the binary tree of a missed label (palettes over [`SEQUENTIAL_MAX`]).
fn tree_bits(n_labels: usize) -> u32 {
    usize::BITS - (n_labels.max(1) - 1).leading_zeros()
}

/// Counters of the missed-label coding for `n_labels`: one per W label
/// and label up to [`SEQUENTIAL_MAX`], else the binary tree's.
pub(super) fn explicit_size(n_labels: usize) -> usize {
    if n_labels <= SEQUENTIAL_MAX {
        (SEQUENTIAL_MAX + 1) * SEQUENTIAL_MAX
    } else {
        1 << tree_bits(n_labels)
    }
}

/// `l` as a label, if below `n_labels`.
#[inline(always)]
pub(super) fn checked(l: u32, n_labels: usize) -> Result<u16, CodecError> {
    if (l as usize) < n_labels {
        Ok(l as u16)
    } else {
        Err(CodecError::LabelOutOfRange {
            label: l,
            labels: n_labels,
        })
    }
}

/// `1 << v` for a label below 64, else 0.
#[inline(always)]
fn bit64(v: u32) -> u64 {
    1u64.checked_shl(v).unwrap_or(0)
}

/// Codes the label of one pixel: `v` for the encoder, ignored by the decoder.
#[inline(always)]
pub(super) fn code_pixel<I: BitIo, const STRONG: bool, const COND: bool>(
    io: &mut I,
    model: &mut Model,
    n_labels: usize,
    (own, flat): (&[u32; OWN_LEN], bool),
    rf: &[u32; 6],
    v: u32,
) -> Result<u16, CodecError> {
    let wv = own[0];
    // W first (most pixels end there), with its masks: all set when flat.
    if wv != NONE {
        let masks = if flat {
            ((1 << OWN_LEN) - 1, mask(rf, wv))
        } else {
            (mask(own, wv), mask(rf, wv))
        };
        if code_candidate::<I, STRONG, COND>(io, model, 0, wv, (own, rf), masks, wv == v) {
            return checked(wv, n_labels);
        }
    }
    code_after_w::<I, STRONG, COND>(io, model, n_labels, own, rf, v, Scan::after(wv))
}

/// Where [`code_after_w`] takes up the scan of a pixel's candidates: the
/// next position of its order, the rank of the next candidate, and the
/// labels below 64 coded so far, as bits.
#[derive(Clone, Copy)]
pub(super) struct Scan {
    next: usize,
    rank: usize,
    seen: u64,
}

impl Scan {
    /// The scan once W's label `wv` (NONE: no W) is coded.
    #[inline(always)]
    pub(super) fn after(wv: u32) -> Self {
        Scan {
            next: 0,
            rank: (wv != NONE) as usize,
            seen: bit64(wv),
        }
    }

    /// From position `next`, the ones before holding no other candidate.
    #[inline(always)]
    pub(super) fn from(self, next: usize) -> Self {
        Scan { next, ..self }
    }

    /// Once the candidate `c` at position `k` is coded and refused.
    #[inline(always)]
    pub(super) fn refused(self, k: usize, c: u32) -> Self {
        Scan {
            next: k + 1,
            rank: self.rank + 1,
            seen: self.seen | bit64(c),
        }
    }
}

/// The rest of [`code_pixel`] once the label is known not to be W's (or
/// there is no W): the other candidates, then the label itself.
#[inline(always)]
pub(super) fn code_after_w<I: BitIo, const STRONG: bool, const COND: bool>(
    io: &mut I,
    model: &mut Model,
    n_labels: usize,
    own: &[u32; OWN_LEN],
    rf: &[u32; 6],
    v: u32,
    scan: Scan,
) -> Result<u16, CodecError> {
    let order = [
        rf[0], own[1], own[3], own[2], own[4], own[5], own[6], own[7], rf[1], rf[2], rf[3], rf[4],
        rf[5], own[8], own[9], own[10], own[11],
    ];
    let wv = own[0];
    // The candidates coded so far are W and those of `order` before `c`
    // (NONE aside): the ones below 64 are kept as bits, larger ones are
    // looked up there (no list to fill). Each is coded as soon as it is
    // found, so a hit ends the scan of the template early.
    let Scan {
        next,
        rank: mut n,
        mut seen,
    } = scan;
    for (k, &c) in order.iter().enumerate().skip(next) {
        let new = if c < 64 {
            seen & bit64(c) == 0
        } else {
            c != NONE && c != wv && !order[..k].contains(&c)
        };
        if new {
            // The fast context reads only the eight nearest own positions.
            let mo = match STRONG {
                true => mask(own, c),
                false => mask::<8>(own[..8].try_into().expect("eight positions"), c),
            };
            let masks = (mo, mask(rf, c));
            if code_candidate::<I, STRONG, COND>(io, model, n, c, (own, rf), masks, c == v) {
                return checked(c, n_labels);
            }
            n += 1;
            seen |= bit64(c);
        }
    }
    if n_labels <= SEQUENTIAL_MAX {
        // One decision per label not already refused, in increasing order,
        // the last one implied.
        let mut free = !seen & (bit64(n_labels as u32) - 1);
        let row = wv.min(SEQUENTIAL_MAX as u32) as usize * SEQUENTIAL_MAX;
        while free != 0 {
            let l = free.trailing_zeros();
            free &= free - 1;
            let hit = |io: &mut I, model: &mut Model| match STRONG {
                true => code_missed(io, model, own, l, l == v),
                false => io.bit(&mut model.explicit[row + l as usize], l == v),
            };
            if free == 0 || hit(io, model) {
                return Ok(l as u16);
            }
        }
        Err(CodecError::Invalid("label stream: no label left".into()))
    } else {
        checked(
            tree(io, &mut model.explicit, tree_bits(n_labels), v),
            n_labels,
        )
    }
}
