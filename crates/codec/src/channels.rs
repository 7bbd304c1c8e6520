//! The strong label model's view of a label as colour-channel classes.
//!
//! A per-channel thresholding (FO-DPSO, PSO, Otsu at three levels) labels a
//! pixel by its class in R, G and B, and its speckle flips one channel's
//! class where that channel's value hovers near a threshold, whatever the
//! others do. A label-by-label model must learn each of the 27 combinations
//! in each neighbourhood; a channel model learns the three channels' classes
//! apart, from the neighbours' classes in the same channel, and so predicts
//! a combination it has seldom or never seen.
//!
//! When every channel of the palette takes at most three values, the class
//! of label l in channel k is the rank of its colour's value among them
//! ([`classes`]). A [`ChannelModel`] then gives each label a probability by
//! the chain rule over the channels in its order o₀, o₁, o₂:
//!
//! P(l) = Π_j P(c_{o_j}(l) | classes of the template in channel o_j,
//! which earlier channels differ from W's class),
//!
//! each factor from two adaptive counters: "the class is W's" and, if not,
//! "it is the lower of the two others". The probability that the label is
//! candidate c, given the candidates refused so far at this pixel, is
//! P(c) / (Σ_palette P − Σ_refused P): an input of the strong mode's mixers
//! for the candidate and missed-label decisions. `docs/wire-format.md`
//! specifies the integer arithmetic bit for bit.

use stereolink_image::Rgb;

use crate::rangecoder::Counter;

/// The class standing for a position outside the map.
const OUTSIDE: u8 = 3;
/// The channel counters stop slowing down here.
const COUNT_LIMIT: u8 = 60;
/// Largest palette given a channel model (the label coder's sequential limit).
const MAX_LABELS: usize = 32;

/// Each label's class per channel, or nothing when a channel of the palette
/// takes more than three values (or the palette exceeds 32 colours): the
/// rank of the label's value among the channel's distinct values.
pub fn classes(palette: &[Rgb], out: &mut Vec<[u8; 3]>) {
    out.clear();
    if palette.len() > MAX_LABELS {
        return;
    }
    let mut values = [[0u8; 3]; 3];
    let mut counts = [0usize; 3];
    for colour in palette {
        for k in 0..3 {
            let seen = &values[k][..counts[k]];
            if !seen.contains(&colour[k]) {
                if counts[k] == 3 {
                    return;
                }
                values[k][counts[k]] = colour[k];
                counts[k] += 1;
            }
        }
    }
    for k in 0..3 {
        values[k][..counts[k]].sort_unstable();
    }
    out.extend(palette.iter().map(|colour| {
        [0, 1, 2].map(|k| values[k][..counts[k]].partition_point(|&v| v < colour[k]) as u8)
    }));
}

/// The classes of a template's labels (`OUTSIDE` for a position outside
/// the map, whose label is none of the palette's).
#[inline(always)]
pub fn template_classes<const N: usize>(classes: &[[u8; 3]], template: &[u32; N]) -> [[u8; 3]; N] {
    template.map(|l| classes.get(l as usize).copied().unwrap_or([OUTSIDE; 3]))
}

/// Whether `class`, not `w_class`, is the lower of the two classes besides it.
#[inline(always)]
fn is_lower(class: u8, w_class: u8) -> bool {
    class == (w_class == 0) as u8
}

/// One chain-rule model: a channel order and the template positions (indices
/// into the label coder's template, W first) whose classes are its context.
pub struct ChannelModel {
    order: [usize; 3],
    positions: &'static [usize],
    /// Pairs of counters, "the class is W's" and "it is the lower of the
    /// two others", by [`ChannelModel::index`].
    counters: Vec<[Counter; 2]>,
    /// Per channel: the template's classes packed two bits each, and W's class.
    context: [usize; 3],
    w_class: [u8; 3],
    /// Each of the palette's `labels` labels' class triple (its index in
    /// `triples`), and how many labels have each triple: set by
    /// [`ChannelModel::reset`] for the palette.
    triple: [u8; MAX_LABELS],
    labels: usize,
    multiplicity: [u32; 27],
    /// This pixel's P of each class triple, their sum over the palette's
    /// labels, and the sum over the candidates refused so far. A label's P
    /// is its triple's, looked up when a decision needs it.
    triples: [u32; 27],
    total: u32,
    refused: u32,
}

impl ChannelModel {
    /// A model of channel `order` with the classes at template `positions`.
    pub const fn new(order: [usize; 3], positions: &'static [usize]) -> Self {
        ChannelModel {
            order,
            positions,
            counters: Vec::new(),
            context: [0; 3],
            w_class: [0; 3],
            triple: [0; MAX_LABELS],
            labels: 0,
            multiplicity: [0; 27],
            triples: [0; 27],
            total: 0,
            refused: 0,
        }
    }

    /// Back to the initial state for a palette of `classes` (from
    /// [`classes`], not empty), reusing the storage.
    pub fn reset(&mut self, classes: &[[u8; 3]]) {
        let [k0, k1, k2] = self.order;
        self.labels = classes.len().min(MAX_LABELS);
        self.multiplicity = [0; 27];
        for (t, c) in self.triple.iter_mut().zip(classes) {
            *t = c[k0] * 9 + c[k1] * 3 + c[k2];
            self.multiplicity[*t as usize] += 1;
        }
        self.counters.clear();
        self.counters
            .resize(7 << (2 * self.positions.len()), Default::default());
    }

    /// The counters' index for the `j`-th channel of the order, `k`, with
    /// `differ` the earlier channels whose class is not W's (bit i: the
    /// i-th): a table per j of 2^j pairs per context, packed, so that the
    /// pairs in use are dense in the cache.
    #[inline(always)]
    fn index(&self, j: usize, k: usize, differ: usize) -> usize {
        (((1 << j) - 1) << (2 * self.positions.len())) + (self.context[k] << j | differ)
    }

    /// Sets the pixel's context from its template's classes (`template`,
    /// from [`template_classes`]) and computes each class triple's P (in
    /// 1/2^16) by the chain rule, each factor and product rounded down.
    pub fn prepare(&mut self, template: &[[u8; 3]]) {
        for (k, (context, w_class)) in self.context.iter_mut().zip(&mut self.w_class).enumerate() {
            *context = self
                .positions
                .iter()
                .fold(0, |c, &p| c << 2 | template[p][k] as usize);
            // W's class, else N's, else the middle one.
            *w_class = [template[0][k], template[1][k]]
                .into_iter()
                .find(|&c| c != OUTSIDE)
                .unwrap_or(1);
        }
        // factor[j][differ][class]: the j-th channel's factor.
        let mut factor = [[[0u32; 3]; 4]; 3];
        for (j, k) in self.order.into_iter().enumerate() {
            for (differ, f) in factor[j].iter_mut().enumerate().take(1 << j) {
                let [same, lower] = self.counters[self.index(j, k, differ)];
                let (same, lower) = ((1 << 16) - same.p0(), (1 << 16) - lower.p0());
                for (class, f) in f.iter_mut().enumerate() {
                    *f = match class as u8 {
                        c if c == self.w_class[k] => same,
                        c if is_lower(c, self.w_class[k]) => (((1 << 16) - same) * lower) >> 16,
                        _ => (((1 << 16) - same) * ((1 << 16) - lower)) >> 16,
                    };
                }
            }
        }
        // P of each class triple, in the order's channels: the products
        // of the factors, rounded down at each step.
        let mul = |p: u32, f: u32| ((p as u64 * f as u64) >> 16) as u32;
        let differs = |j: usize, c: usize| ((c as u8 != self.w_class[self.order[j]]) as usize) << j;
        let mut triples = [0u32; 27];
        for c0 in 0..3 {
            let p0 = mul(1 << 16, factor[0][0][c0]);
            for c1 in 0..3 {
                let p1 = mul(p0, factor[1][differs(0, c0)][c1]);
                let d = differs(0, c0) | differs(1, c1);
                for c2 in 0..3 {
                    triples[c0 * 9 + c1 * 3 + c2] = mul(p1, factor[2][d][c2]);
                }
            }
        }
        // The sum over the palette's labels, by triple (a fixed-size loop).
        self.triples = triples;
        self.total = triples
            .iter()
            .zip(&self.multiplicity)
            .map(|(p, m)| p * m)
            .sum();
        self.refused = 0;
    }

    /// The probability of a 0 (in 1/2^16, within [32, 65504]) of the
    /// decision "the label is `l`", given the labels refused at this pixel.
    #[inline(always)]
    pub fn p0(&self, l: u32) -> u32 {
        let Some(p) = self.p(l) else {
            return 1 << 15;
        };
        let rest = self.total.saturating_sub(self.refused).max(1);
        let p = ((p as u64) << 16) / rest as u64;
        ((1u32 << 16).saturating_sub(p.min(1 << 16) as u32)).clamp(32, 65504)
    }

    /// Learns that the label is not `l`.
    #[inline(always)]
    pub fn refuse(&mut self, l: u32) {
        if let Some(p) = self.p(l) {
            self.refused += p;
        }
    }

    /// This pixel's P of label `l`, if the palette holds it.
    #[inline(always)]
    fn p(&self, l: u32) -> Option<u32> {
        let t = self.triple[..self.labels].get(l as usize)?;
        Some(self.triples[*t as usize])
    }

    /// Learns the pixel's label `l`.
    pub fn learn(&mut self, l: u32) {
        let Some(&t) = self.triple[..self.labels].get(l as usize) else {
            return;
        };
        // The label's classes in the order's channels: its triple's digits.
        let classes = [t / 9, t / 3 % 3, t % 3];
        let mut differ = 0;
        for (j, (k, class)) in self.order.into_iter().zip(classes).enumerate() {
            let i = self.index(j, k, differ);
            let [same, lower] = &mut self.counters[i];
            let is_same = class == self.w_class[k];
            same.update_to(is_same, COUNT_LIMIT);
            if !is_same {
                lower.update_to(is_lower(class, self.w_class[k]), COUNT_LIMIT);
                differ |= 1 << j;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classes_rank_each_channel() {
        let palette = [[10, 200, 5], [90, 200, 7], [10, 50, 9]];
        let mut c = Vec::new();
        classes(&palette, &mut c);
        assert_eq!(c, vec![[0, 1, 0], [1, 1, 1], [0, 0, 2]]);
        // A fourth value in a channel: no classes.
        classes(&[[0; 3], [1; 3], [2; 3], [3; 3]], &mut c);
        assert!(c.is_empty());
    }

    #[test]
    fn probabilities_sum_to_one_and_learn() {
        // All 27 combinations: the chain rule sums to about 1.
        let palette: Vec<Rgb> = (0..27u8).map(|i| [i % 3, i / 3 % 3, i / 9]).collect();
        let mut c = Vec::new();
        classes(&palette, &mut c);
        let mut m = ChannelModel::new([0, 1, 2], &[0, 1, 2, 3]);
        m.reset(&c);
        let template = template_classes(&c, &[13u32; 12]);
        m.prepare(&template);
        assert!((65536 - 64..=65536).contains(&m.total), "{}", m.total);
        let before = m.p0(13);
        for _ in 0..50 {
            m.prepare(&template);
            m.learn(13);
        }
        m.prepare(&template);
        assert!(m.p0(13) < before / 10, "{} {}", m.p0(13), before);
        // Refusing W's label leaves the others all the mass.
        m.refuse(13);
        let rest: u32 = (0..27).filter(|&l| l != 13).map(|l| 65536 - m.p0(l)).sum();
        assert!(rest.abs_diff(65536) < 27 * 64, "{rest}");
    }
}
