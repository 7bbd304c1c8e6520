//! Lossless coding of label maps with an adaptive context model.
//!
//! Each pixel is coded as a short sequence of binary decisions with the
//! [range coder](crate::rangecoder): "is it the same label as candidate i?"
//! over the distinct labels of a causal template of the map (W, N, NW, NE,
//! WW, NN, NEE, NWW, NNW, NNE, WWW, NEEE) and, when the map is the right view
//! of a pair, of the **stereo prediction** around P, the left view's label at
//! `x + s` (one shift `s` per block of [`BLOCK`] columns of a row, chosen by
//! the encoder and sent with the row): P, its neighbours E, W, S (the row
//! below: the whole left view is known), N and EE. A decision's context is
//! the candidate's rank and which template positions hold the candidate's
//! label, so flat areas cost a few thousandths of a bit per pixel and edges
//! that the left view already shows cost little more. A label matching no
//! candidate is sent explicitly: label by label among the others (context:
//! the W label) for palettes up to 32 colours, as a binary tree above.
//!
//! Two [`Mode`]s: *fast* gives each decision one context; *strong* mixes
//! nine ([`crate::mixer`]: the two masks at three sizes, an outer ring of
//! the template, runs, the equalities among the neighbours and three hashes
//! of labels) and, for palettes of per-channel classes, four
//! [channel models](crate::channels), with two weight sets averaged,
//! refines the result with an [`Apm`], and mixes the missed-label
//! decisions too: about 14 % smaller (FO-DPSO) and about 27 times slower
//! to decode.
//! Probabilities are [`Counter`]s, which learn fast in rare contexts.
//! `docs/wire-format.md` specifies the stream bit for bit.

use stereolink_image::{LabelMap, Rgb};

use crate::channels::{self, ChannelModel};
use crate::mixer::{squash, Apm, Mixer};
use crate::rangecoder::{Counter, Decoder, Encoder};
use crate::CodecError;

/// How hard the model works, chosen by the sender and sent as the payload's
/// first byte: decode speed against size.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Mode {
    /// One context per decision: the fast decoder (what a receiver wants).
    #[default]
    Fast = 0,
    /// Nine contexts and four channel models per decision, logistically
    /// mixed: smaller, much slower.
    Strong = 1,
}

impl Mode {
    /// The mode's name (`fast` or `strong`), as [`str::parse`] reads it.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Fast => "fast",
            Mode::Strong => "strong",
        }
    }
}

impl std::str::FromStr for Mode {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "fast" => Ok(Mode::Fast),
            "strong" => Ok(Mode::Strong),
            _ => Err(format!("unknown label coding mode {s:?} (fast or strong)")),
        }
    }
}

/// Columns per stereo-shift block.
pub const BLOCK: usize = 32;
/// Largest stereo shift searched and coded (8 bits).
pub const MAX_SHIFT: usize = 255;

/// The causal template of the map: W, N, NW, NE, WW, NN, NEE, NWW, NNW,
/// NNE, WWW, NEEE.
const OWN: [(isize, isize); OWN_LEN] = [
    (-1, 0),
    (0, -1),
    (-1, -1),
    (1, -1),
    (-2, 0),
    (0, -2),
    (2, -1),
    (-2, -1),
    (-1, -2),
    (1, -2),
    (-3, 0),
    (3, -1),
];
const OWN_LEN: usize = 12;
/// The template of the stereo prediction around `(x + s, y)`: P, E, W, S, N, EE.
const REF: [(isize, isize); 6] = [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1), (2, 0)];
/// Ranks told apart by the contexts (later ones share the last).
const RANKS: usize = 4;
/// Counters of the strong mode's candidate decisions (one per context).
const COUNTER_INPUTS: usize = 9;
/// Chain-rule channel models ([`crate::channels`]) mixed with the counters.
const CHANNEL_MODELS: usize = 4;
/// Mixed inputs of the strong mode's candidate decisions.
const STRONG_INPUTS: usize = COUNTER_INPUTS + CHANNEL_MODELS;
/// Context bits besides the rank of the strong mode's mixed models: W … NWW
/// of the own mask; W, N, NW, NE of it and the prediction's mask; both
/// masks; the two label hashes (which include the rank); the outer mask
/// and W … NWW; the label hash of the candidate and its masks; the runs and
/// W … NWW; the neighbours' equalities and W, N, NW, NE.
const CONTEXT_BITS: [u32; COUNTER_INPUTS] = [
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
/// The outer ring of the strong mode's template, beyond [`OWN`]: WWWW,
/// NNWW, NNEE, NNN, NWWW, NEEEE, NNWWW, NNEEE. Which of these hold a
/// candidate tells a noisy area from a clean edge.
const OUTER: [(isize, isize); OUTER_LEN] = [
    (-4, 0),
    (-2, -2),
    (2, -2),
    (0, -3),
    (-3, -1),
    (4, -1),
    (-3, -2),
    (3, -2),
];
const OUTER_LEN: usize = 8;
/// The strong mode's missed-label counters stop slowing down here: the
/// statistics of a segmented view drift across it.
const STRONG_COUNT_LIMIT: u8 = 30;
/// The limits of the strong mode's candidate counters, context by context:
/// the sparse label hashes learn fastest, the dense masks slowest (about
/// 0.2 % smaller than 30 for all; chosen on the ten 2001–2005 scenes and
/// smaller on the ten 2006–2014 ones too).
const COUNT_LIMITS: [u8; COUNTER_INPUTS] = [120, 120, 60, 10, 10, 60, 10, 60, 30];
/// Contexts of the strong mode's [`Apm`]: rank and own mask.
const APM_CONTEXTS: usize = RANKS << OWN_LEN;
/// Weight sets of the strong mode's second mixer: candidate label (up to
/// 63) and rank.
const LABEL_MIX_SETS: usize = 64 * RANKS;
/// Counters of the strong mode's missed-label decisions.
const MISSED_COUNTERS: usize = 5;
/// Mixed inputs of the strong mode's missed-label decisions.
const MISSED_INPUTS: usize = MISSED_COUNTERS + CHANNEL_MODELS;
/// The strong mode's channel models (channel order; own template
/// positions): R, G, B with W, N, NW, NE, WW, NN, NEE, NWW; B, G, R with W,
/// N, NW, NE; G, B, R with W, N, NE, WW, NN, NEE; B, R, G with W, N, WW,
/// NN, NWW, NNW.
const CHANNEL_ORDERS: [ChannelModel; CHANNEL_MODELS] = [
    ChannelModel::new([0, 1, 2], &[0, 1, 2, 3, 4, 5, 6, 7]),
    ChannelModel::new([2, 1, 0], &[0, 1, 2, 3]),
    ChannelModel::new([1, 2, 0], &[0, 1, 3, 4, 5, 6]),
    ChannelModel::new([2, 0, 1], &[0, 1, 4, 5, 7, 8]),
];
/// Bits of the label hashes.
const LABEL_HASH_BITS: u32 = 18;
/// Context bits besides the rank of the fast mode: eight bits of the own
/// mask alone, four and the prediction's six conditioned.
const FAST_BITS: u32 = 10;
/// Contexts of the fast mode.
const FAST_CONTEXTS: usize = RANKS << FAST_BITS;
/// Mixer weight sets: rank, W, N, NW, NE of the own mask, P of the prediction's.
const MIX_SETS: usize = RANKS * 32;
/// Palettes up to this size send a missed label label by label.
const SEQUENTIAL_MAX: usize = 32;

struct Model {
    /// The strong mode's counters of the candidate decisions, one table per
    /// mixed context.
    flags: [Vec<Counter>; COUNTER_INPUTS],
    /// Their mixers: weight sets by masks, and by candidate label.
    mixer: Mixer<STRONG_INPUTS>,
    label_mixer: Mixer<STRONG_INPUTS>,
    apm: Apm,
    /// The strong mode's counters of the missed-label decisions, and their mixer.
    missed: [Vec<Counter>; MISSED_COUNTERS],
    missed_mixer: Mixer<MISSED_INPUTS>,
    /// The strong mode's per-pixel contexts beyond the template: the labels
    /// of [`OUTER`], and the quantised run lengths of W's label leftwards
    /// and N's upwards (`runs`, from `row_run` and `column_runs`).
    outer: [u32; OUTER_LEN],
    runs: usize,
    /// The strong mode's channel models, and each label's channel classes
    /// (empty: no channel model, their inputs are ½).
    channels: [ChannelModel; CHANNEL_MODELS],
    classes: Vec<[u8; 3]>,
    column_runs: Vec<u32>,
    /// The fast mode's counters, one per [`fast_context`].
    fast: Box<[Counter; FAST_CONTEXTS]>,
    explicit: Vec<Counter>,
    same_shift: Counter,
    shift: Vec<Counter>,
}

impl Model {
    /// The channel models in use: none when the palette has no classes.
    fn channels(&self) -> &[ChannelModel] {
        &self.channels[..CHANNEL_MODELS * !self.classes.is_empty() as usize]
    }

    /// [`Model::channels`], to learn.
    fn channels_mut(&mut self) -> &mut [ChannelModel] {
        &mut self.channels[..CHANNEL_MODELS * !self.classes.is_empty() as usize]
    }

    fn new() -> Self {
        Model {
            flags: Default::default(),
            mixer: Mixer::new(0),
            label_mixer: Mixer::new(0),
            apm: Apm::new(0),
            missed: Default::default(),
            missed_mixer: Mixer::new(0),
            outer: [NONE; OUTER_LEN],
            runs: 0,
            channels: CHANNEL_ORDERS,
            classes: Vec::new(),
            column_runs: Vec::new(),
            fast: Box::new([Counter::default(); FAST_CONTEXTS]),
            explicit: Vec::new(),
            same_shift: Counter::default(),
            shift: Vec::new(),
        }
    }

    /// Back to the initial state for a map indexing `palette`, reusing the storage.
    fn reset(&mut self, palette: &[Rgb], strong: bool) {
        let n_labels = palette.len();
        let mut sizes = [0; COUNTER_INPUTS];
        let mut missed_sizes = [0; MISSED_COUNTERS];
        self.classes.clear();
        if strong {
            channels::classes(palette, &mut self.classes);
            let classes = &self.classes;
            if !classes.is_empty() {
                self.channels.iter_mut().for_each(|m| m.reset(classes));
            }
            sizes = CONTEXT_BITS.map(|b| RANKS << b);
            missed_sizes = MISSED_SIZES;
            self.mixer.reset(MIX_SETS);
            self.label_mixer.reset(LABEL_MIX_SETS);
            self.apm.reset(APM_CONTEXTS);
            self.missed_mixer.reset(1);
        }
        for (f, size) in self.flags.iter_mut().zip(sizes) {
            f.clear();
            f.resize(size, Counter::default());
        }
        for (f, size) in self.missed.iter_mut().zip(missed_sizes) {
            f.clear();
            f.resize(size, Counter::default());
        }
        self.fast.fill(Counter::default());
        self.explicit.clear();
        self.explicit
            .resize(explicit_size(n_labels), Counter::default());
        self.same_shift = Counter::default();
        self.shift.clear();
        self.shift.resize(256, Counter::default());
    }
}

/// The counter of the fast mode's decision for the candidate of rank `r`
/// with own mask `mo` and prediction mask `mr`: the own-mask bits are W, N,
/// NW, NE when coding conditioned (`COND`: the prediction's mask takes the
/// place), else the eight nearest (and `mr` is 0). The contexts are those
/// of `docs/wire-format.md`, packed densely, so that the few that occur
/// share cache lines.
#[inline(always)]
const fn fast_context<const COND: bool>(r: usize, mo: usize, mr: usize) -> usize {
    if COND {
        r << FAST_BITS | (mo & 15) << 6 | mr
    } else {
        r << FAST_BITS | (mo & 255)
    }
}

/// The fast mode's counter for [`fast_context`] (which is below
/// [`FAST_CONTEXTS`]: the mask only spares the bounds check).
#[inline(always)]
fn fast_counter<const COND: bool>(
    fast: &mut [Counter; FAST_CONTEXTS],
    r: usize,
    mo: usize,
    mr: usize,
) -> &mut Counter {
    &mut fast[fast_context::<COND>(r, mo, mr) & (FAST_CONTEXTS - 1)]
}

/// Bits of the binary tree of a missed label (palettes over [`SEQUENTIAL_MAX`]).
fn tree_bits(n_labels: usize) -> u32 {
    usize::BITS - (n_labels.max(1) - 1).leading_zeros()
}

fn explicit_size(n_labels: usize) -> usize {
    if n_labels <= SEQUENTIAL_MAX {
        (SEQUENTIAL_MAX + 1) * SEQUENTIAL_MAX
    } else {
        1 << tree_bits(n_labels)
    }
}

/// Stands for a template position outside the map (or no prediction).
const NONE: u32 = u32::MAX;

/// The two ends of the range coder behind one interface, so that the
/// encoder and the decoder run the same model code: the encoder codes the
/// bit it is given, the decoder ignores it and returns the decoded one.
trait BitIo {
    /// Codes a bit whose probability of being 0 is `p0` / 2^16.
    fn code(&mut self, p0: u32, bit: bool) -> bool;
    fn overrun(&self) -> bool;

    /// Codes a bit with an adaptive counter.
    #[inline(always)]
    fn bit(&mut self, c: &mut Counter, bit: bool) -> bool {
        let bit = self.code(c.p0(), bit);
        c.update(bit);
        bit
    }
}

impl BitIo for Encoder {
    #[inline(always)]
    fn code(&mut self, p0: u32, bit: bool) -> bool {
        Encoder::code(self, p0, bit);
        bit
    }
    fn overrun(&self) -> bool {
        false
    }
}

impl BitIo for Decoder<'_> {
    #[inline(always)]
    fn code(&mut self, p0: u32, _: bool) -> bool {
        Decoder::code(self, p0)
    }
    fn overrun(&self) -> bool {
        Decoder::overrun(self)
    }
}

/// Codes `value` (`bits` bits, most significant first) with a tree of counters.
fn tree<I: BitIo>(io: &mut I, probs: &mut [Counter], bits: u32, value: u32) -> u32 {
    let mut node = 1usize;
    for i in (0..bits).rev() {
        let bit = io.bit(&mut probs[node], (value >> i) & 1 == 1);
        node = (node << 1) | bit as usize;
    }
    (node - (1 << bits)) as u32
}

/// The labels of the map's template around (x, y).
#[inline(always)]
fn own_template(data: &[u16], w: usize, x: usize, y: usize) -> [u32; OWN_LEN] {
    if x >= 3 && x + 3 < w && y >= 2 {
        // Inside (most pixels): direct reads, in the order of OWN.
        let (r0, r1, r2) = (y * w + x, (y - 1) * w + x, (y - 2) * w + x);
        assert!(r0 <= data.len());
        // SAFETY: the indices lie in r2 − 1 ..= r1 + 3, below r0 (x + 3 < w).
        let g = |i: usize| u32::from(unsafe { *data.get_unchecked(i) });
        [
            g(r0 - 1),
            g(r1),
            g(r1 - 1),
            g(r1 + 1),
            g(r0 - 2),
            g(r2),
            g(r1 + 2),
            g(r1 - 2),
            g(r2 - 1),
            g(r2 + 1),
            g(r0 - 3),
            g(r1 + 3),
        ]
    } else {
        // A plain loop: `array::map` is not inlined here.
        let mut t = [NONE; OWN_LEN];
        for (t, &(dx, dy)) in t.iter_mut().zip(&OWN) {
            let (xx, yy) = (x as isize + dx, y as isize + dy);
            if xx >= 0 && yy >= 0 && (xx as usize) < w {
                *t = u32::from(data[yy as usize * w + xx as usize]);
            }
        }
        t
    }
}

/// The labels of [`OUTER`] around (x, y).
#[inline(always)]
fn outer_template(data: &[u16], w: usize, x: usize, y: usize) -> [u32; OUTER_LEN] {
    if x >= 4 && x + 4 < w && y >= 3 {
        // Inside: direct reads, in the order of OUTER.
        let (r0, r1, r2, r3) = (y * w + x, (y - 1) * w + x, (y - 2) * w + x, (y - 3) * w + x);
        let g = |i: usize| u32::from(data[i]);
        return [
            g(r0 - 4),
            g(r2 - 2),
            g(r2 + 2),
            g(r3),
            g(r1 - 3),
            g(r1 + 4),
            g(r2 - 3),
            g(r2 + 3),
        ];
    }
    OUTER.map(|(dx, dy)| {
        let (xx, yy) = (x as isize + dx, y as isize + dy);
        if xx >= 0 && yy >= 0 && (xx as usize) < w {
            u32::from(data[yy as usize * w + xx as usize])
        } else {
            NONE
        }
    })
}

/// The label of W if (x, y) is inside and its whole template holds it (most
/// pixels: a quick test without gathering the template).
#[inline(always)]
fn flat_inside(data: &[u16], w: usize, x: usize, y: usize) -> Option<u32> {
    if x < 3 || x + 3 >= w || y < 2 {
        return None;
    }
    let (r0, r1, r2) = (y * w + x, (y - 1) * w + x, (y - 2) * w + x);
    let wv = data[r0 - 1];
    let same = |s: &[u16]| s.iter().fold(true, |a, &v| a & (v == wv));
    (same(&data[r0 - 3..r0 - 1]) & same(&data[r1 - 2..r1 + 4]) & same(&data[r2 - 1..r2 + 2]))
        .then_some(wv as u32)
}

/// Whether the whole template holds one label (W's, which exists).
#[inline(always)]
fn is_flat(t: &[u32; OWN_LEN]) -> bool {
    t[0] != NONE && t.iter().all(|&l| l == t[0])
}

/// The labels of the prediction's template around (`xs`, y).
#[inline(always)]
fn ref_template(reference: &LabelMap, xs: usize, y: usize) -> [u32; 6] {
    let (w, h) = reference.dims();
    let data = reference.as_slice();
    if xs >= 1 && xs + 2 < w && y >= 1 && y + 1 < h {
        // Inside: direct reads, in the order of REF.
        let i = y * w + xs;
        assert!(i + w < data.len());
        // SAFETY: the indices lie in i − w ..= i + w, inside the map (the
        // test above and the assertion).
        let g = |i: usize| u32::from(unsafe { *data.get_unchecked(i) });
        return [g(i), g(i + 1), g(i - 1), g(i + w), g(i - w), g(i + 2)];
    }
    let mut t = [NONE; 6];
    for (t, &(dx, dy)) in t.iter_mut().zip(&REF) {
        let (xx, yy) = (xs as isize + dx, y as isize + dy);
        if xx >= 0 && yy >= 0 && (xx as usize) < w && (yy as usize) < h {
            *t = u32::from(data[yy as usize * w + xx as usize]);
        }
    }
    t
}

/// A context from labels themselves: `values` folded from 0 by
/// `h = (h ^ v) · 0x9E3779B1` (mod 2^32), the top [`LABEL_HASH_BITS`] bits.
#[inline(always)]
fn label_hash(values: &[u32]) -> usize {
    let h = values
        .iter()
        .fold(0u32, |h, &v| (h ^ v).wrapping_mul(0x9E37_79B1));
    (h >> (32 - LABEL_HASH_BITS)) as usize
}

/// Which positions of `t` hold `c`, as bits.
#[inline(always)]
fn mask<const N: usize>(t: &[u32; N], c: u32) -> usize {
    let mut m = 0;
    for (k, &v) in t.iter().enumerate() {
        m |= ((v == c) as usize) << k;
    }
    m
}

/// Codes the decision "label = `c`" for the `rank`-th candidate, given the
/// templates: which positions hold `c` select the contexts of the mixed models.
#[inline(always)]
fn code_candidate<I: BitIo, const STRONG: bool, const COND: bool>(
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
const MISSED_SIZES: [usize; MISSED_COUNTERS] = [
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
fn code_missed<I: BitIo>(
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

/// `l` as a label, if below `n_labels`.
#[inline(always)]
fn checked(l: u32, n_labels: usize) -> Result<u16, CodecError> {
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
fn code_pixel<I: BitIo, const STRONG: bool, const COND: bool>(
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

/// [`code_pixel`] in the strong mode: the channel models prepare the pixel
/// from its template and learn its label.
#[inline(always)]
fn code_pixel_strong<I: BitIo, const COND: bool>(
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

/// Codes row `y` in the fast mode. Pixels whose own template reaches W,
/// N, NW, NE, WW, NN, NEE and NWW inside the map (and, conditioned, whose
/// prediction template lies inside the reference) have their W decisions,
/// and after a 0 the next candidate's, coded by [`w_run`], block by block,
/// and after two 0s the rest of the pixel; the others go through
/// [`code_pixel`].
#[inline(always)]
fn code_row_fast<I: BitIo, const COND: bool>(
    io: &mut I,
    model: &mut Model,
    n_labels: usize,
    (data, w, y): (&mut [u16], usize, usize),
    reference: Option<&LabelMap>,
    shifts: &[u8],
) -> Result<(), CodecError> {
    let h = data.len() / w;
    let mut x = 0;
    while x < w {
        let s = shifts[x / BLOCK] as usize;
        let rf = |x: usize| match reference {
            Some(r) if COND => ref_template(r, x + s, y),
            _ => [NONE; 6],
        };
        // The stretch from x that [`w_run`] may code: inside the own
        // template, the block and (conditioned) the prediction's template.
        let mut end = match y >= 2 && x >= 2 {
            true => w.saturating_sub(2),
            false => x,
        };
        if let (true, Some(_)) = (COND, reference) {
            let inside = y + 1 < h && x + s >= 1;
            end = match inside {
                true => end
                    .min(w.saturating_sub(2 + s))
                    .min((x / BLOCK + 1) * BLOCK),
                false => x,
            };
        }
        let i = y * w + x;
        if x < end {
            let pred = reference.filter(|_| COND).map(|r| (r.as_slice(), s));
            let fast = &mut model.fast;
            match w_run::<I, COND>(io, fast, n_labels, (data, w, y), x..end, pred)? {
                Some((miss, scan)) => {
                    let own = own_template(data, w, miss, y);
                    let v = data[y * w + miss] as u32;
                    let rf = &rf(miss);
                    data[y * w + miss] =
                        code_after_w::<I, false, COND>(io, model, n_labels, &own, rf, v, scan)?;
                    x = miss + 1;
                }
                None => x = end,
            }
        } else {
            let own = own_template(data, w, x, y);
            let v = data[i] as u32;
            data[i] = code_pixel::<I, false, COND>(
                io,
                model,
                n_labels,
                (&own, is_flat(&own)),
                &rf(x),
                v,
            )?;
            x += 1;
        }
    }
    Ok(())
}

/// The fast mode's W decisions of row `y` over `run`, read straight from
/// the map (and, conditioned, from `pred`: the reference's labels and the
/// block's shift): each "1" writes W's label. On a "0" the pixel's first
/// candidate after W (nearly always the prediction P, conditioned) is
/// coded here too, and on a "1" its label is written and the run goes on
/// with it as W; else the run ends at the pixel, returned with where the
/// scan of its candidates stands (the rest of that pixel is the caller's).
/// The context needs only W, N, NW, NE (and, coding alone, WW, NN, NEE,
/// NWW) and the prediction's mask, so the loop holds few values; after a
/// "1" W's label is the same, so the masks shift, and only the positions
/// entering on the right are read.
#[inline(always)]
fn w_run<I: BitIo, const COND: bool>(
    io: &mut I,
    fast: &mut [Counter; FAST_CONTEXTS],
    n_labels: usize,
    (data, w, y): (&mut [u16], usize, usize),
    run: std::ops::Range<usize>,
    pred: Option<(&[u16], usize)>,
) -> Result<Option<(usize, Scan)>, CodecError> {
    let (above, cur) = data.split_at_mut(y * w);
    let (cur, up, up2) = (&mut cur[..w], &above[(y - 1) * w..], &above[(y - 2) * w..]);
    // Conditioned, the prediction's rows y − 1, y and y + 1 from x + s on.
    let (refs, s) = pred.unwrap_or((&[], 0));
    let rows = match COND {
        // Three slices rather than an `array::map`, which is not inlined.
        true => [
            &refs[(y - 1) * w + s..y * w],
            &refs[y * w + s..(y + 1) * w],
            &refs[(y + 1) * w + s..(y + 2) * w],
        ],
        false => [&[][..]; 3],
    };
    // Every index below lies in x − 2 ..= x + 2 of a row (x + 2 of the
    // prediction's, which start at x + s): inside each of them.
    assert!(run.start >= 2 && run.end + 2 <= w && (!COND || run.end + 2 + s <= w));
    // SAFETY: the assertion above, for every row read.
    let g = |row: &[u16], x: usize| unsafe { *row.get_unchecked(x) };
    let [above, row, below] = rows;
    let eq = |v: u16, l: u16| (v == l) as usize;
    // The masks of label `l` at x (W's bit set when W holds `l`).
    let masks = |cur: &[u16], x: usize, l: u16| {
        let mut mo = eq(g(cur, x - 1), l)
            | eq(g(up, x), l) << 1
            | eq(g(up, x - 1), l) << 2
            | eq(g(up, x + 1), l) << 3;
        let mut mr = 0;
        if COND {
            mr = eq(g(row, x), l)
                | eq(g(row, x + 1), l) << 1
                | eq(g(row, x - 1), l) << 2
                | eq(g(below, x), l) << 3
                | eq(g(above, x), l) << 4
                | eq(g(row, x + 2), l) << 5;
        } else {
            mo |= eq(g(cur, x - 2), l) << 4
                | eq(g(up2, x), l) << 5
                | eq(g(up, x + 2), l) << 6
                | eq(g(up, x - 2), l) << 7;
        }
        (mo, mr)
    };
    // The masks one pixel right of x − 1, whose label `l` is now W's: N,
    // NW and NWW are the last NE, N and NW, NE the last NEE, WW is the
    // last W (`ww`: its bit, set in a run); the prediction's W, P, E are
    // the last P, E, EE. Only what enters on the right is read.
    let step = |(mo, mr): (usize, usize), x: usize, l: u16, ww: usize| {
        if COND {
            let mo = 1 | (mo >> 2 & 2) | (mo << 1 & 4) | eq(g(up, x + 1), l) << 3;
            let mr = (mr >> 1 & 1)
                | (mr >> 4 & 2)
                | (mr << 2 & 4)
                | eq(g(below, x), l) << 3
                | eq(g(above, x), l) << 4
                | eq(g(row, x + 2), l) << 5;
            (mo, mr)
        } else {
            let mo = 1
                | (mo >> 2 & 2)
                | (mo << 1 & 4)
                | (mo >> 3 & 8)
                | ww
                | eq(g(up2, x), l) << 5
                | eq(g(up, x + 2), l) << 6
                | (mo << 5 & 128);
            (mo, mr)
        }
    };
    let (mut x, end) = (run.start, run.end);
    // W's label, the run's: each "1" writes it, so it is the next W too.
    let mut wv = g(cur, x - 1);
    let mut m = masks(cur, x, wv);
    loop {
        if io.bit(fast_counter::<COND>(fast, 0, m.0, m.1), g(cur, x) == wv) {
            cur[x] = wv;
            x += 1;
            if x == end {
                return Ok(None);
            }
            m = step(m, x, wv, 16);
            continue;
        }
        // The first candidate after W: of [`code_after_w`]'s order, the
        // first label other than W's. Nearly always P (conditioned) or N;
        // else the positions within x ± 2 are looked at (coding alone,
        // the prediction's stand as W's label, never a candidate).
        let rf = |row: &[u16], x: usize| if COND { g(row, x) } else { wv };
        let (k, c) = match (rf(row, x), g(up, x)) {
            (p, _) if p != wv => (0, p),
            (_, n) if n != wv => (1, n),
            _ => {
                let near = [
                    g(up, x + 1),
                    g(up, x - 1),
                    g(cur, x - 2),
                    g(up2, x),
                    g(up, x + 2),
                    g(up, x - 2),
                    rf(row, x + 1),
                    rf(row, x - 1),
                    rf(below, x),
                    rf(above, x),
                    rf(row, x + 2),
                ];
                match near.iter().position(|&c| c != wv) {
                    Some(k) => (k + 2, near[k]),
                    None => return Ok(Some((x, Scan::after(wv.into()).from(near.len() + 2)))),
                }
            }
        };
        let mc = masks(cur, x, c);
        if !io.bit(fast_counter::<COND>(fast, 1, mc.0, mc.1), g(cur, x) == c) {
            return Ok(Some((x, Scan::after(wv.into()).refused(k, c.into()))));
        }
        cur[x] = checked(c.into(), n_labels)?;
        wv = c;
        x += 1;
        if x == end {
            return Ok(None);
        }
        // WW holds the last W's label, not `c`.
        m = step(mc, x, wv, 0);
    }
}

/// Where [`code_after_w`] takes up the scan of a pixel's candidates: the
/// next position of its order, the rank of the next candidate, and the
/// labels below 64 coded so far, as bits.
#[derive(Clone, Copy)]
struct Scan {
    next: usize,
    rank: usize,
    seen: u64,
}

impl Scan {
    /// The scan once W's label `wv` (NONE: no W) is coded.
    #[inline(always)]
    fn after(wv: u32) -> Self {
        Scan {
            next: 0,
            rank: (wv != NONE) as usize,
            seen: bit64(wv),
        }
    }

    /// From position `next`, the ones before holding no other candidate.
    #[inline(always)]
    fn from(self, next: usize) -> Self {
        Scan { next, ..self }
    }

    /// Once the candidate `c` at position `k` is coded and refused.
    #[inline(always)]
    fn refused(self, k: usize, c: u32) -> Self {
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
fn code_after_w<I: BitIo, const STRONG: bool, const COND: bool>(
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

/// What [`code_map`] codes: the map, its width, the palette, the reference
/// and the encoder's shifts.
type MapArgs<'a> = (
    &'a mut [u16],
    usize,
    &'a [Rgb],
    Option<&'a LabelMap>,
    &'a [u8],
);

/// Codes a whole map: `data` holds it for the encoder and receives it in
/// the decoder; `plan` holds the encoder's shifts (row-major, one per block).
fn code_map<I: BitIo, const STRONG: bool>(
    io: &mut I,
    model: &mut Model,
    args: MapArgs,
    shifts: &mut Vec<u8>,
) -> Result<(), CodecError> {
    model.reset(args.2, STRONG);
    match args.3 {
        Some(_) => code_rows::<I, STRONG, true>(io, model, args, shifts),
        None => code_rows::<I, STRONG, false>(io, model, args, shifts),
    }
}

/// [`code_map`] once the model is reset, compiled apart for a map coded
/// conditioned (`COND`, with a reference) and alone, where the prediction's
/// template is all NONE: its reads and masks then vanish.
#[inline(always)]
fn code_rows<I: BitIo, const STRONG: bool, const COND: bool>(
    io: &mut I,
    model: &mut Model,
    (data, w, palette, reference, plan): MapArgs,
    shifts: &mut Vec<u8>,
) -> Result<(), CodecError> {
    let n_labels = palette.len();
    let blocks = w.div_ceil(BLOCK);
    shifts.clear();
    shifts.resize(blocks, 0);
    let h = data.len().checked_div(w).unwrap_or(0);
    if STRONG {
        model.column_runs.clear();
        model.column_runs.resize(w, 0);
    }
    for y in 0..h {
        // How many pixels left of W hold W's label.
        let mut row_run = 0u32;
        if reference.is_some() {
            code_shifts(io, model, plan.get(y * blocks..).unwrap_or(&[]), shifts);
        }
        if !STRONG {
            code_row_fast::<I, COND>(io, model, n_labels, (data, w, y), reference, shifts)?;
        }
        for x in (0..w).filter(|_| STRONG) {
            let rf = match reference {
                Some(r) if COND => ref_template(r, x + shifts[x / BLOCK] as usize, y),
                _ => [NONE; 6],
            };
            let i = y * w + x;
            let v = data[i] as u32;
            // Bit length of a run, up to 7.
            let q = |n: u32| (u32::BITS - n.leading_zeros()).min(7) as usize;
            model.runs = q(row_run) << 3 | q(model.column_runs[x]);
            model.outer = outer_template(data, w, x, y);
            data[i] = code_pixel_strong::<I, COND>(io, model, n_labels, (data, w, x, y), &rf, v)?;
            let (l, runs) = (data[i], &mut model.column_runs[x]);
            row_run = if x > 0 && l == data[i - 1] {
                row_run + 1
            } else {
                0
            };
            *runs = if y > 0 && l == data[i - w] {
                *runs + 1
            } else {
                0
            };
        }
        if io.overrun() {
            return Err(CodecError::Truncated("label stream"));
        }
    }
    Ok(())
}

/// Codes a row's block shifts, each as the same as the block's in the row
/// above or else in 8 bits: `plan` holds the encoder's from the row's
/// first block on (the decoder's is empty).
fn code_shifts<I: BitIo>(io: &mut I, model: &mut Model, plan: &[u8], shifts: &mut [u8]) {
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

/// The stereo shifts [`encode`] sends for `map` predicted from `reference`
/// (searched up to `max_shift`): one per block of [`BLOCK`] columns per
/// row, row-major; the prediction of pixel (x, y) is the reference's label
/// at (x + s, y), s the shift of block x / [`BLOCK`] of row y.
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

/// Codes `map` (labels index `palette`, whose colours inform the strong
/// mode's [channel models](crate::channels)); with `reference`, predicts
/// from it through per-block shifts searched up to `max_shift`.
pub fn encode(
    map: &LabelMap,
    palette: &[Rgb],
    reference: Option<&LabelMap>,
    max_shift: usize,
    mode: Mode,
) -> Vec<u8> {
    let w = map.width();
    let plan = reference.map_or_else(Vec::new, |r| plan_shifts(map, r, max_shift));
    let mut enc = Encoder::new();
    let mut data = map.as_slice().to_vec();
    let (model, shifts) = (&mut Model::new(), &mut Vec::new());
    let args = (&mut data[..], w, palette, reference, &plan[..]);
    match mode {
        Mode::Fast => code_map::<_, false>(&mut enc, model, args, shifts),
        Mode::Strong => code_map::<_, true>(&mut enc, model, args, shifts),
    }
    .expect("the encoder codes its own labels");
    let mut out = vec![mode as u8];
    out.extend(enc.finish());
    out
}

/// Decodes a `w`×`h` map written by [`encode`] (with the same palette and
/// reference).
///
/// Fails if a decoded label does not index `palette` or the stream ends too early.
pub fn decode(
    bytes: &[u8],
    w: usize,
    h: usize,
    palette: &[Rgb],
    reference: Option<&LabelMap>,
) -> Result<LabelMap, CodecError> {
    let mut out = LabelMap::new(w, h, 0);
    decode_into(bytes, palette, reference, &mut out)?;
    Ok(out)
}

/// [`decode`] into a caller-provided map (its size gives `w`×`h`).
pub fn decode_into(
    bytes: &[u8],
    palette: &[Rgb],
    reference: Option<&LabelMap>,
    out: &mut LabelMap,
) -> Result<(), CodecError> {
    LabelDecoder::default().decode_into(bytes, palette, reference, out)
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
            model: Model::new(),
            shifts: Vec::new(),
        }
    }
}

impl LabelDecoder {
    /// [`decode`] into a caller-provided map (its size gives `w`×`h`).
    pub fn decode_into(
        &mut self,
        bytes: &[u8],
        palette: &[Rgb],
        reference: Option<&LabelMap>,
        out: &mut LabelMap,
    ) -> Result<(), CodecError> {
        let (w, h) = out.dims();
        if let Some(r) = reference {
            if r.dims() != (w, h) {
                return Err(CodecError::Invalid("reference view size differs".into()));
            }
        }
        let (&mode, coded) = bytes
            .split_first()
            .ok_or(CodecError::Truncated("label stream"))?;
        let mut dec = Decoder::new(coded);
        let (model, shifts) = (&mut self.model, &mut self.shifts);
        let args = (out.as_mut_slice(), w, palette, reference, &[][..]);
        match mode {
            0 => code_map::<_, false>(&mut dec, model, args, shifts),
            1 => code_map::<_, true>(&mut dec, model, args, shifts),
            m => Err(CodecError::Invalid(format!("label coding mode {m}"))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// `n` colours, each channel at one of three values while `n` ≤ 27, so
    /// that the strong mode's channel models take part (repeating beyond).
    fn palette(n: usize) -> Vec<Rgb> {
        (0..n)
            .map(|i| [i % 3, i / 3 % 3, i / 9 % 3].map(|c| c as u8 * 100))
            .collect()
    }

    fn blobs(w: usize, h: usize, n: u16, seed: u64) -> LabelMap {
        LabelMap::from_fn(w, h, |x, y| {
            let v = (x / 7 + (y / 5) * 3) as u64 ^ seed;
            (v.wrapping_mul(0x9E37_79B9) >> 7) as u16 % n
        })
    }

    /// A right view of `left`: shifted by 3, plus sparse noise of labels below `n`.
    fn noisy_right(left: &LabelMap, n: u16, noise: u64) -> LabelMap {
        let (w, h) = left.dims();
        let mut s = noise | 1;
        LabelMap::from_fn(w, h, |x, y| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            if s % 17 == 0 {
                (s >> 20) as u16 % n
            } else {
                left.get((x + 3).min(w - 1), y)
            }
        })
    }

    proptest! {
        #[test]
        fn round_trip_alone_and_conditioned(w in 1usize..70, h in 1usize..20, n in 1u16..100, seed in any::<u64>(), noise in any::<u64>(), strong in any::<bool>()) {
            let mode = if strong { Mode::Strong } else { Mode::Fast };
            let left = blobs(w, h, n, seed);
            let right = noisy_right(&left, n, noise);
            let a = encode(&left, &palette(n as usize), None, 0, mode);
            prop_assert_eq!(a[0], mode as u8);
            prop_assert_eq!(decode(&a, w, h, &palette(n as usize), None).unwrap(), left.clone());
            let b = encode(&right, &palette(n as usize), Some(&left), 16, mode);
            prop_assert_eq!(decode(&b, w, h, &palette(n as usize), Some(&left)).unwrap(), right);
        }

        /// The fast mode's W runs (and the candidate after W they code)
        /// give the stream of [`code_pixel`] over every pixel, alone and
        /// conditioned.
        #[test]
        fn fast_runs_code_the_stream_of_pixels(w in 1usize..70, h in 1usize..24, n in 1u16..100, seed in any::<u64>(), noise in any::<u64>()) {
            let (left, palette) = (blobs(w, h, n, seed), palette(n as usize));
            let right = noisy_right(&left, n, noise);
            prop_assert_eq!(
                encode(&left, &palette, None, 0, Mode::Fast),
                fast_stream_per_pixel(&left, &palette, None, &[])
            );
            prop_assert_eq!(
                encode(&right, &palette, Some(&left), 16, Mode::Fast),
                fast_stream_per_pixel(&right, &palette, Some(&left), &plan_shifts(&right, &left, 16))
            );
        }

        #[test]
        fn garbage_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..64), mode in 0u8..3, w in 1usize..30, h in 1usize..30, n in 1usize..80) {
            let mut stream = vec![mode];
            stream.extend(&bytes);
            let _ = decode(&stream, w, h, &palette(n), None);
            // A reference whose labels exceed the palette must not panic either.
            let reference = LabelMap::from_fn(w, h, |x, y| ((x * 7 + y) % (n + 3)) as u16);
            let _ = decode(&stream, w, h, &palette(n), Some(&reference));
        }
    }

    /// The fast mode's stream of `map` coded pixel by pixel through
    /// [`code_pixel`] (its definition: no W runs, every template gathered).
    fn fast_stream_per_pixel(
        map: &LabelMap,
        palette: &[Rgb],
        reference: Option<&LabelMap>,
        plan: &[u8],
    ) -> Vec<u8> {
        let (w, h) = map.dims();
        let (mut enc, model) = (Encoder::new(), &mut Model::new());
        model.reset(palette, false);
        let mut data = map.as_slice().to_vec();
        let blocks = w.div_ceil(BLOCK);
        let mut shifts = vec![0; blocks];
        for y in 0..h {
            if reference.is_some() {
                code_shifts(&mut enc, model, &plan[y * blocks..], &mut shifts);
            }
            for x in 0..w {
                let (i, own) = (y * w + x, own_template(&data, w, x, y));
                let (args, v) = ((&own, is_flat(&own)), data[i] as u32);
                let (io, n) = (&mut enc, palette.len());
                data[i] = match reference {
                    Some(r) => {
                        let rf = ref_template(r, x + shifts[x / BLOCK] as usize, y);
                        code_pixel::<_, false, true>(io, model, n, args, &rf, v)
                    }
                    None => code_pixel::<_, false, false>(io, model, n, args, &[NONE; 6], v),
                }
                .unwrap();
            }
        }
        let mut out = vec![Mode::Fast as u8];
        out.extend(enc.finish());
        out
    }

    /// Pins the label streams of `docs/wire-format.md`'s example: a 6×3 map
    /// of 3 labels alone in both modes, and a right view conditioned on it.
    #[test]
    fn golden_label_streams() {
        let rows = [[0, 0, 1, 1, 2, 2], [0, 0, 1, 1, 1, 2], [0, 1, 1, 1, 2, 2]];
        let left = LabelMap::from_fn(6, 3, |x, y| rows[y][x]);
        let right = LabelMap::from_fn(6, 3, |x, y| rows[y][(x + 1).min(5)]);
        let hex = |b: Vec<u8>| b.iter().map(|b| format!("{b:02x}")).collect::<String>();
        let palette = palette(3);
        let streams = [
            encode(&left, &palette, None, 0, Mode::Fast),
            encode(&left, &palette, None, 0, Mode::Strong),
            encode(&right, &palette, Some(&left), 4, Mode::Fast),
        ];
        for s in &streams[..2] {
            assert_eq!(decode(s, 6, 3, &palette, None).unwrap(), left);
        }
        assert_eq!(
            decode(&streams[2], 6, 3, &palette, Some(&left)).unwrap(),
            right
        );
        assert_eq!(
            streams.map(hex),
            ["00d79196c5c800", "01ddb21ec8212800", "0000db8ed295bd5d50"]
        );
    }

    /// A map of three thresholded channels, each flipping on its own near its
    /// thresholds (speckle), codes smaller in the strong mode when the
    /// palette tells the channels apart than when it does not.
    #[test]
    fn channel_models_pay_on_per_channel_speckle() {
        let (w, h) = (160, 120);
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        let mut noise = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f64 / (1u64 << 24) as f64 - 0.5
        };
        let class = |v: f64| (v > 0.33) as u16 + (v > 0.66) as u16;
        let map = LabelMap::from_fn(w, h, |x, y| {
            let (u, v) = (x as f64 / w as f64, y as f64 / h as f64);
            let r = class(u + 0.15 * noise());
            let g = class(v + 0.15 * noise());
            let b = class((u + v) / 2.0 + 0.15 * noise());
            r + 3 * g + 9 * b
        });
        let classes = palette(27);
        let grey: Vec<Rgb> = (0..27).map(|i| [i as u8 * 9; 3]).collect();
        let with = encode(&map, &classes, None, 0, Mode::Strong);
        let without = encode(&map, &grey, None, 0, Mode::Strong);
        assert_eq!(decode(&with, w, h, &classes, None).unwrap(), map);
        assert!(
            with.len() * 100 < without.len() * 97,
            "with classes {} bytes, without {}",
            with.len(),
            without.len()
        );
    }

    #[test]
    fn conditioning_on_the_left_view_pays() {
        let left = blobs(200, 100, 6, 1);
        let right = LabelMap::from_fn(200, 100, |x, y| left.get((x + 9).min(199), y));
        for mode in [Mode::Fast, Mode::Strong] {
            let alone = encode(&right, &palette(6), None, 0, mode).len();
            let cond = encode(&right, &palette(6), Some(&left), 32, mode).len();
            assert!(
                cond * 2 < alone,
                "{mode:?}: alone {alone} conditioned {cond}"
            );
        }
    }
}
