//! The strong mode's contexts: the nine counters of a candidate decision,
//! the five of a missed label, the label hashes and the channel models,
//! mixed and refined, and the strong mode's pixel step.

use super::bitio::BitIo;
use super::fast::fast_counter;
use super::model::{Model, RANKS};
use super::pixel::{code_pixel, SEQUENTIAL_MAX};
use super::template::{flat_inside, is_flat, mask, own_template, OUTER_LEN, OWN_LEN};
use crate::channels::{self, ChannelModel};
use crate::mixer::squash;
use crate::CodecError;

/// Counters of the strong mode's candidate decisions (one per context).
pub(super) const COUNTER_INPUTS: usize = 9;
/// Chain-rule channel models ([`crate::channels`]) mixed with the counters.
pub(super) const CHANNEL_MODELS: usize = 4;
/// Mixed inputs of the strong mode's candidate decisions.
pub(super) const STRONG_INPUTS: usize = COUNTER_INPUTS + CHANNEL_MODELS;
/// Context bits besides the rank of the strong mode's mixed models: W … NWW
/// of the own mask; W, N, NW, NE of it and the prediction's mask; both
/// masks; the two label hashes (which include the rank); the outer mask
/// and W … NWW; the label hash of the candidate and its masks; the runs and
/// W … NWW; the neighbours' equalities and W, N, NW, NE.
pub(super) const CONTEXT_BITS: [u32; COUNTER_INPUTS] = [
    8,
    10,
    OWN_LEN as u32 + 6,
    LABEL_HASH_BITS - 2,
    LABEL_HASH_BITS - 2,
    OUTER_LEN as u32 + 8,
    LABEL_HASH_BITS - 2,
    14,
    12,
];

/// The strong mode's missed-label counters stop slowing down here: the
/// statistics of a segmented view drift across it.
const STRONG_COUNT_LIMIT: u8 = 30;
/// The limits of the strong mode's candidate counters, context by context:
/// the sparse label hashes learn fastest, the dense masks slowest
/// (docs/tuning.md, “The strong mode's counter limits”).
const COUNT_LIMITS: [u8; COUNTER_INPUTS] = [120, 120, 60, 10, 10, 60, 10, 60, 30];
/// Contexts of the strong mode's [`Apm`](crate::mixer::Apm): rank and own mask.
pub(super) const APM_CONTEXTS: usize = RANKS << OWN_LEN;
/// Weight sets of the strong mode's second mixer: candidate label (up to
/// 63) and rank.
pub(super) const LABEL_MIX_SETS: usize = 64 * RANKS;
/// Counters of the strong mode's missed-label decisions.
pub(super) const MISSED_COUNTERS: usize = 5;
/// Mixed inputs of the strong mode's missed-label decisions.
pub(super) const MISSED_INPUTS: usize = MISSED_COUNTERS + CHANNEL_MODELS;
/// The strong mode's channel models (channel order; own template
/// positions): R, G, B with W, N, NW, NE, WW, NN, NEE, NWW; B, G, R with W,
/// N, NW, NE; G, B, R with W, N, NE, WW, NN, NEE; B, R, G with W, N, WW,
/// NN, NWW, NNW.
pub(super) const CHANNEL_ORDERS: [ChannelModel; CHANNEL_MODELS] = [
    ChannelModel::new([0, 1, 2], &[0, 1, 2, 3, 4, 5, 6, 7]),
    ChannelModel::new([2, 1, 0], &[0, 1, 2, 3]),
    ChannelModel::new([1, 2, 0], &[0, 1, 3, 4, 5, 6]),
    ChannelModel::new([2, 0, 1], &[0, 1, 4, 5, 7, 8]),
];
/// Bits of the label hashes.
const LABEL_HASH_BITS: u32 = 18;

/// Mixer weight sets: rank, W, N, NW, NE of the own mask, P of the prediction's.
pub(super) const MIX_SETS: usize = RANKS * 32;

/// A context from labels themselves: `values` folded from 0 by
/// `h = (h ^ v) · 0x9E3779B1` (mod 2^32), the top [`LABEL_HASH_BITS`] bits.
#[inline(always)]
fn label_hash(values: &[u32]) -> usize {
    let h = values
        .iter()
        .fold(0u32, |h, &v| (h ^ v).wrapping_mul(0x9E37_79B1));
    (h >> (32 - LABEL_HASH_BITS)) as usize
}

/// Codes the decision "label = `c`" for the `rank`-th candidate, given the
/// templates: which positions hold `c` select the contexts of the mixed models.
#[inline(always)]
pub(super) fn code_candidate<I: BitIo, const STRONG: bool, const COND: bool>(
    io: &mut I,
    model: &mut Model,
    rank: usize,
    c: u32,
    (own, rf): (&[u32; OWN_LEN], &[u32; 6]),
    (mo, mr): (usize, usize),
    bit: bool,
) -> bool {
    let r = rank.min(RANKS - 1);
    if !STRONG {
        return io.bit(fast_counter::<COND>(&mut model.fast, r, mo, mr), bit);
    }
    let ctx = [
        r << 8 | (mo & 255),
        r << 10 | (mo & 15) << 6 | mr,
        r << (OWN_LEN + 6) | mo << 6 | mr,
        label_hash(&[r as u32, c, own[0], own[1], own[2], own[3], rf[0]]),
        label_hash(&[
            (RANKS + r) as u32,
            c,
            own[0],
            own[1],
            own[4],
            own[5],
            rf[1],
            rf[3],
        ]),
        r << (OUTER_LEN + 8) | mask(&model.outer, c) << 8 | (mo & 255),
        label_hash(&[(2 * RANKS + r) as u32, c, (mo & 255 | mr << 8) as u32]),
        r << 14 | model.runs << 8 | (mo & 255),
        r << 12 | equalities(own) << 4 | (mo & 15),
    ];
    let channels = channel_p0(model.channels(), c);
    let [t0, t1, t2, t3, t4, t5, t6, t7, t8] = &mut model.flags;
    let counters = [
        &mut t0[ctx[0]],
        &mut t1[ctx[1]],
        &mut t2[ctx[2]],
        &mut t3[ctx[3]],
        &mut t4[ctx[4]],
        &mut t5[ctx[5]],
        &mut t6[ctx[6]],
        &mut t7[ctx[7]],
        &mut t8[ctx[8]],
    ];
    let p0 = inputs(counters.each_ref().map(|c| c.p0()), channels);
    let mix = model.mixer.mix(r << 5 | (mo & 15) << 1 | (mr & 1), p0);
    let by_label = model.label_mixer.mix((c as usize).min(63) << 2 | r, p0);
    let d = (mix.stretch() + by_label.stretch()) >> 1;
    let refined = model.apm.refine(d, r << OWN_LEN | mo);
    // The mixed and the refined probability of a 1, averaged, in 1/2^16.
    let p1 = ((squash(d) << 4) + refined.p1()) >> 1;
    let bit = io.code((65536 - p1 as u32).clamp(32, 65504), bit);
    model.mixer.update(&mix, bit);
    model.label_mixer.update(&by_label, bit);
    model.apm.update(&refined, bit);
    for (c, limit) in counters.into_iter().zip(COUNT_LIMITS) {
        c.update_to(bit, limit);
    }
    if !bit {
        model.channels_mut().iter_mut().for_each(|m| m.refuse(c));
    }
    bit
}

/// The channel models' `p0` of the decision "the label is `l`" (½ each
/// without classes).
#[inline(always)]
fn channel_p0(channels: &[ChannelModel], l: u32) -> [u32; CHANNEL_MODELS] {
    let mut p0 = [1 << 15; CHANNEL_MODELS];
    for (p, m) in p0.iter_mut().zip(channels) {
        *p = m.p0(l);
    }
    p0
}

/// The mixed inputs of a decision: the counters' `p0`, then the channel models'.
#[inline(always)]
fn inputs<const N: usize, const M: usize>(
    counters: [u32; N],
    channels: [u32; CHANNEL_MODELS],
) -> [u32; M] {
    let mut all = [0; M];
    all[..N].copy_from_slice(&counters);
    all[N..].copy_from_slice(&channels);
    all
}

/// Which pairs of the own template hold the same label (NONE equals NONE),
/// as bits 0..7: N NE, NE NEE, NEE NEEE, NW NWW, N NN, NE NNE, NW NNW,
/// NN NNE: the edges the row above shows, whatever the candidate.
#[inline(always)]
fn equalities(own: &[u32; OWN_LEN]) -> usize {
    const PAIRS: [(usize, usize); 8] = [
        (1, 3),
        (3, 6),
        (6, 11),
        (2, 7),
        (1, 5),
        (3, 9),
        (2, 8),
        (5, 9),
    ];
    let mut e = 0;
    for (k, &(a, b)) in PAIRS.iter().enumerate() {
        e |= ((own[a] == own[b]) as usize) << k;
    }
    e
}

/// Table sizes of the strong mode's missed-label contexts: W's and N's
/// label (32 when NONE or larger) with the label; three label hashes.
pub(super) const MISSED_SIZES: [usize; MISSED_COUNTERS] = [
    (SEQUENTIAL_MAX + 1) * SEQUENTIAL_MAX,
    (SEQUENTIAL_MAX + 1) * SEQUENTIAL_MAX,
    1 << (LABEL_HASH_BITS - 2),
    1 << (LABEL_HASH_BITS - 2),
    1 << (LABEL_HASH_BITS - 2),
];

/// Codes the strong mode's decision "the missed label is `l`" (palettes up
/// to [`SEQUENTIAL_MAX`]): five contexts of `l` and the neighbours' labels,
/// mixed with one weight set. A missed label is mostly one channel class
/// away from a neighbour's, which one depends on more than W.
#[inline(always)]
pub(super) fn code_missed<I: BitIo>(
    io: &mut I,
    model: &mut Model,
    own: &[u32; OWN_LEN],
    l: u32,
    bit: bool,
) -> bool {
    let row = |v: u32| v.min(SEQUENTIAL_MAX as u32) as usize * SEQUENTIAL_MAX;
    let ctx = [
        row(own[0]) + l as usize,
        row(own[1]) + l as usize,
        label_hash(&[l, own[0], own[1]]) >> 2,
        label_hash(&[l + 64, own[0], own[2], own[3]]) >> 2,
        label_hash(&[l + 128, own[0], own[1], own[4], own[5]]) >> 2,
    ];
    let channels = channel_p0(model.channels(), l);
    let [t0, t1, t2, t3, t4] = &mut model.missed;
    let counters = [
        &mut t0[ctx[0]],
        &mut t1[ctx[1]],
        &mut t2[ctx[2]],
        &mut t3[ctx[3]],
        &mut t4[ctx[4]],
    ];
    let p0 = inputs(counters.each_ref().map(|c| c.p0()), channels);
    let mix = model.missed_mixer.mix(0, p0);
    let bit = io.code(mix.p0(), bit);
    model.missed_mixer.update(&mix, bit);
    for c in counters {
        c.update_to(bit, STRONG_COUNT_LIMIT);
    }
    if !bit {
        model.channels_mut().iter_mut().for_each(|m| m.refuse(l));
    }
    bit
}

/// [`code_pixel`] in the strong mode: the channel models prepare the pixel
/// from its template and learn its label.
#[inline(always)]
pub(super) fn code_pixel_strong<I: BitIo, const COND: bool>(
    io: &mut I,
    model: &mut Model,
    n_labels: usize,
    (data, w, x, y): (&[u16], usize, usize, usize),
    rf: &[u32; 6],
    v: u32,
) -> Result<u16, CodecError> {
    let (own, flat) = match flat_inside(data, w, x, y) {
        Some(wv) => ([wv; OWN_LEN], true),
        None => {
            let t = own_template(data, w, x, y);
            (t, is_flat(&t))
        }
    };
    if !model.classes.is_empty() {
        let template = channels::template_classes(&model.classes, &own);
        model.channels.iter_mut().for_each(|m| m.prepare(&template));
    }
    let l = code_pixel::<I, true, COND>(io, model, n_labels, (&own, flat), rf, v)?;
    model
        .channels_mut()
        .iter_mut()
        .for_each(|m| m.learn(l as u32));
    Ok(l)
}
