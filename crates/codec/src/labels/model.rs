//! The adaptive state of the label coder: every counter table, mixer and
//! channel model of both modes, sized and reset per map, so that one
//! model (and its storage) serves map after map.

use stereolink_image::Rgb;

use super::fast::FAST_CONTEXTS;
use super::pixel::explicit_size;
use super::strong::{
    APM_CONTEXTS, CHANNEL_MODELS, CHANNEL_ORDERS, CONTEXT_BITS, COUNTER_INPUTS, LABEL_MIX_SETS,
    MISSED_COUNTERS, MISSED_INPUTS, MISSED_SIZES, MIX_SETS, STRONG_INPUTS,
};
use super::template::{NONE, OUTER_LEN};
use crate::channels::{self, ChannelModel};
use crate::mixer::{Apm, Mixer};
use crate::rangecoder::Counter;

/// Ranks told apart by the contexts (later ones share the last).
pub(super) const RANKS: usize = 4;

/// Everything the label coder learns: the counters, mixers and channel
/// models of both modes, and the strong mode's per-pixel contexts.
pub(super) struct Model {
    /// The strong mode's counters of the candidate decisions, one table per
    /// mixed context.
    pub(super) flags: [Vec<Counter>; COUNTER_INPUTS],
    /// Their mixers: weight sets by masks, and by candidate label.
    pub(super) mixer: Mixer<STRONG_INPUTS>,
    pub(super) label_mixer: Mixer<STRONG_INPUTS>,
    pub(super) apm: Apm,
    /// The strong mode's counters of the missed-label decisions, and their mixer.
    pub(super) missed: [Vec<Counter>; MISSED_COUNTERS],
    pub(super) missed_mixer: Mixer<MISSED_INPUTS>,
    /// The strong mode's per-pixel contexts beyond the template: the labels
    /// of `OUTER`, and the quantised run lengths
    /// of W's label leftwards and N's upwards (`runs`, from `row_run` and
    /// `column_runs`).
    pub(super) outer: [u32; OUTER_LEN],
    pub(super) runs: usize,
    /// The strong mode's channel models, and each label's channel classes
    /// (empty: no channel model, their inputs are ½).
    pub(super) channels: [ChannelModel; CHANNEL_MODELS],
    pub(super) classes: Vec<[u8; 3]>,
    pub(super) column_runs: Vec<u32>,
    /// The fast mode's counters, one per `fast_context`.
    pub(super) fast: Box<[Counter; FAST_CONTEXTS]>,
    pub(super) explicit: Vec<Counter>,
    pub(super) same_shift: Counter,
    pub(super) shift: Vec<Counter>,
}

impl Model {
    /// The channel models in use: none when the palette has no classes.
    pub(super) fn channels(&self) -> &[ChannelModel] {
        &self.channels[..CHANNEL_MODELS * !self.classes.is_empty() as usize]
    }

    /// [`Model::channels`], to learn.
    pub(super) fn channels_mut(&mut self) -> &mut [ChannelModel] {
        &mut self.channels[..CHANNEL_MODELS * !self.classes.is_empty() as usize]
    }

    pub(super) fn new() -> Self {
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
    pub(super) fn reset(&mut self, palette: &[Rgb], strong: bool) {
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
