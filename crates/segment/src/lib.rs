//! Colour image segmentation: k-means, mean shift, and per-channel multilevel
//! thresholding with Otsu's criterion, solved exactly (dynamic programming)
//! or by the paper's swarms (PSO, Darwinian PSO, fractional-order DPSO).
//!
//! Every method returns one [`Segmentation`]: an indexed image (labels and
//! the colour of each label) from which the segmented image is rebuilt
//! exactly, plus the per-channel thresholds and fitness where they exist.
//!
//! # Example
//!
//! ```
//! use stereolink_image::synth::{synthesize, SynthSpec};
//! use stereolink_segment::{segment, Method};
//!
//! let scene = synthesize(&SynthSpec { width: 64, height: 48, max_disp: 8, seed: 1 }).unwrap();
//! let seg = segment(&scene.left, &Method::Otsu, 3, 7).unwrap();
//! assert!(seg.image.palette().len() <= 27);
//! assert_eq!(seg.to_rgb().dims(), (64, 48));
//! ```

// Numeric kernels index several parallel arrays by the same bin or channel.
#![allow(clippy::needless_range_loop)]

pub mod carry;
pub mod kmeans;
pub mod meanshift;
pub mod otsu;
mod regions;
pub mod swarm;

use std::fmt;
use std::str::FromStr;

use serde::Serialize;
use stereolink_image::{IndexedImage, LabelMap, Plane, Rgb, RgbImage};

/// The most labels a segmentation numbers: labels are `u16`
/// ([`LabelMap`]), and a frame's palette holds at most this many colours.
/// Mean shift merges its smallest regions into their most similar
/// neighbours to stay within it, the thresholding methods their least
/// populated classes into the nearest kept ones; k-means has at most 256.
pub const MAX_LABELS: usize = 1 << 16;

/// Errors of the segmentation methods.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SegmentError {
    /// The number of levels (classes) is outside 2..=256.
    #[error("levels must be between 2 and 256, not {0}")]
    Levels(usize),
    /// k-means asked for more clusters than there are pixels.
    #[error("k = {k} is larger than the {pixels} pixels of the image")]
    TooManyClusters {
        /// Requested clusters.
        k: usize,
        /// Pixels available.
        pixels: usize,
    },
    /// A parameter is out of range.
    #[error("invalid parameter: {0}")]
    Parameter(String),
    /// The image has no pixels.
    #[error("the image is empty")]
    Empty,
}

/// The segmentation methods.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// k-means on RGB pixels (paper eq. 5); `levels` is k.
    KMeans,
    /// Mean shift filtering and clustering in the joint spatial-range domain.
    MeanShift(meanshift::MeanShiftSpec),
    /// Exact multilevel Otsu per channel (dynamic programming).
    Otsu,
    /// Particle swarm optimisation of the per-channel thresholds.
    Pso(swarm::SwarmSpec),
    /// Darwinian PSO.
    Dpso(swarm::SwarmSpec),
    /// Fractional-order Darwinian PSO.
    Fodpso(swarm::SwarmSpec),
}

impl Method {
    /// The short name (`kmeans`, `meanshift`, `otsu`, `pso`, `dpso`, `fodpso`).
    pub fn name(&self) -> &'static str {
        match self {
            Method::KMeans => "kmeans",
            Method::MeanShift(_) => "meanshift",
            Method::Otsu => "otsu",
            Method::Pso(_) => "pso",
            Method::Dpso(_) => "dpso",
            Method::Fodpso(_) => "fodpso",
        }
    }

    /// Every method with its default parameters, in the paper's order.
    pub fn all() -> Vec<Method> {
        ["meanshift", "kmeans", "pso", "dpso", "fodpso", "otsu"]
            .iter()
            .map(|n| n.parse().expect("known"))
            .collect()
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = SegmentError;

    /// Parses a method name into the method with its default parameters.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(match s.to_ascii_lowercase().as_str() {
            "kmeans" | "k-means" => Method::KMeans,
            "meanshift" | "mean-shift" => Method::MeanShift(meanshift::MeanShiftSpec::default()),
            "otsu" | "exact" => Method::Otsu,
            "pso" => Method::Pso(swarm::SwarmSpec::pso()),
            "dpso" => Method::Dpso(swarm::SwarmSpec::dpso()),
            "fodpso" | "fo-dpso" => Method::Fodpso(swarm::SwarmSpec::fodpso()),
            other => {
                return Err(SegmentError::Parameter(format!(
                    "unknown method {other:?}; use kmeans, meanshift, otsu, pso, dpso or fodpso"
                )))
            }
        })
    }
}

/// Per-channel thresholding results (R, G, B).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ChannelThresholds {
    /// Thresholds per channel; `t` means values `<= t` fall in the lower class.
    pub thresholds: [Vec<u8>; 3],
    /// Between-class variance reached per channel.
    pub fitness: [f64; 3],
    /// The exact optimum per channel (for the swarms' comparison).
    pub optimum: [f64; 3],
}

/// A segmentation: labels, palette, and what the method knows about them.
#[derive(Clone, Debug, PartialEq)]
pub struct Segmentation {
    /// Label per pixel and colour per label.
    pub image: IndexedImage,
    /// Per-channel thresholds, for the thresholding methods.
    pub channels: Option<ChannelThresholds>,
    /// Iterations the method ran.
    pub iterations: usize,
}

impl Segmentation {
    /// The segmented image: each pixel shown in its label's colour.
    pub fn to_rgb(&self) -> RgbImage {
        self.image.to_rgb()
    }
}

/// Segments `image` into `levels` classes (per channel for the thresholding
/// methods, clusters for k-means; mean shift finds its own number and
/// ignores `levels`). Same seed, same result.
pub fn segment(
    image: &RgbImage,
    method: &Method,
    levels: usize,
    seed: u64,
) -> Result<Segmentation, SegmentError> {
    if image.is_empty() {
        return Err(SegmentError::Empty);
    }
    if !(2..=256).contains(&levels) {
        return Err(SegmentError::Levels(levels));
    }
    match method {
        Method::KMeans => kmeans::kmeans(image, levels, seed),
        Method::MeanShift(spec) => meanshift::mean_shift(image, spec),
        Method::Otsu => threshold_image(image, levels, |_, _, optimal| Ok((optimal.to_vec(), 0))),
        Method::Pso(spec) | Method::Dpso(spec) | Method::Fodpso(spec) => {
            spec.validate()?;
            threshold_image(image, levels, |h, c, _| {
                let r = swarm::optimise(h, levels, spec, seed.wrapping_add(c as u64));
                Ok((r.thresholds, r.iterations))
            })
        }
    }
}

/// Thresholds each channel with `search` (given the histogram, the channel
/// and the exact optimum, which the report needs anyway), then builds the
/// combined labels: one label per occurring (r, g, b) class triple,
/// coloured by the class means.
fn threshold_image(
    image: &RgbImage,
    levels: usize,
    mut search: impl FnMut(&[u64; 256], usize, &[u8]) -> Result<(Vec<u8>, usize), SegmentError>,
) -> Result<Segmentation, SegmentError> {
    let mut thresholds: [Vec<u8>; 3] = Default::default();
    let mut fitness = [0.0; 3];
    let mut optimum = [0.0; 3];
    let mut iterations = 0;
    let mut class_of = [[0u8; 256]; 3];
    let mut means = [[0u8; 256]; 3];
    for c in 0..3 {
        let hist = otsu::histogram(image, c);
        let optimal = otsu::optimal_thresholds(&hist, levels);
        let (t, it) = search(&hist, c, &optimal)?;
        iterations += it;
        fitness[c] = otsu::between_class_variance(&hist, &t);
        optimum[c] = otsu::between_class_variance(&hist, &optimal);
        for v in 0..256 {
            class_of[c][v] = t.iter().filter(|&&th| (v as u8) > th).count() as u8;
        }
        for (k, m) in otsu::class_means(&hist, &t).into_iter().enumerate() {
            means[c][k] = m;
        }
        thresholds[c] = t;
    }
    // Labels in order of first appearance, one per occurring class triple.
    const UNSEEN: u32 = u32::MAX;
    let key_of = |p: Rgb| {
        let cls = [0, 1, 2].map(|c| class_of[c][p[c] as usize] as usize);
        (cls[0] * levels + cls[1]) * levels + cls[2]
    };
    let mut index = vec![UNSEEN; levels * levels * levels];
    let mut keys: Vec<usize> = Vec::new();
    let labels: Plane<u32> = image.map(|p| {
        let key = key_of(p);
        if index[key] == UNSEEN {
            index[key] = keys.len() as u32;
            keys.push(key);
        }
        index[key]
    });
    let colour = |key: usize| {
        let cls = [key / (levels * levels), key / levels % levels, key % levels];
        [0, 1, 2].map(|c| means[c][cls[c]])
    };
    let (labels, palette): (LabelMap, Vec<Rgb>) = if keys.len() <= MAX_LABELS {
        (
            labels.map(|l| l as u16),
            keys.iter().map(|&k| colour(k)).collect(),
        )
    } else {
        let kept = cap_classes(&labels, &keys, &mut index, levels);
        let labels = labels.map(|l| index[keys[l as usize]] as u16);
        (labels, kept.into_iter().map(colour).collect())
    };
    let image =
        IndexedImage::new(labels, palette).map_err(|e| SegmentError::Parameter(e.to_string()))?;
    Ok(Segmentation {
        image,
        channels: Some(ChannelThresholds {
            thresholds,
            fitness,
            optimum,
        }),
        iterations,
    })
}

/// Keeps the [`MAX_LABELS`] most populated class triples of a thresholding
/// (`labels` numbers them in order of first appearance, `keys` holds each
/// one's key `(r·levels + g)·levels + b`) and gives each other triple the
/// nearest kept one in class steps (a breadth-first search over the
/// `levels³` grid of triples from the kept ones): a class the thresholds
/// put next to another is the most similar. Returns the kept keys in order
/// of first appearance and leaves in `index` (by key) each triple's new
/// label. Only a fine thresholding of a noisy image has that many triples
/// (41 levels or more per channel); the search costs `O(levels³)`.
fn cap_classes(
    labels: &Plane<u32>,
    keys: &[usize],
    index: &mut [u32],
    levels: usize,
) -> Vec<usize> {
    let mut count = vec![0u64; keys.len()];
    for &l in labels.as_slice() {
        count[l as usize] += 1;
    }
    // The most populated first, ties to the first seen; then kept in the
    // order of first appearance.
    let mut order: Vec<u32> = (0..keys.len() as u32).collect();
    order.sort_unstable_by_key(|&l| (std::cmp::Reverse(count[l as usize]), l));
    order.truncate(MAX_LABELS);
    order.sort_unstable();
    const UNSEEN: u32 = u32::MAX;
    index.fill(UNSEEN);
    let mut frontier: Vec<usize> = order.iter().map(|&l| keys[l as usize]).collect();
    for (new, &key) in frontier.iter().enumerate() {
        index[key] = new as u32;
    }
    let kept = frontier.clone();
    let steps = [1, levels, levels * levels];
    let mut next = Vec::new();
    while !frontier.is_empty() {
        for &key in &frontier {
            for step in steps {
                let class = key / step % levels;
                let down = (class > 0).then(|| key - step);
                let up = (class + 1 < levels).then(|| key + step);
                for n in [down, up].into_iter().flatten() {
                    if index[n] == UNSEEN {
                        index[n] = index[key];
                        next.push(n);
                    }
                }
            }
        }
        std::mem::swap(&mut frontier, &mut next);
        next.clear();
    }
    kept
}

/// Relabels so that labels are `0..n` in order of first appearance and the
/// palette holds only used colours.
pub(crate) fn compact(
    labels: Plane<u32>,
    colours: impl Fn(u32) -> Rgb,
) -> Result<IndexedImage, SegmentError> {
    // Labels are small (classes) or pixel indices (regions): a table by
    // label, in order of first appearance, instead of hashing every pixel.
    const UNSEEN: u32 = u32::MAX;
    let top = labels
        .as_slice()
        .iter()
        .copied()
        .max()
        .map_or(0, |m| m as usize + 1);
    let mut slot = vec![UNSEEN; top];
    let mut palette = Vec::new();
    let mut overflow = false;
    let out = labels.map(|l| {
        let s = &mut slot[l as usize];
        if *s == UNSEEN {
            overflow |= palette.len() >= MAX_LABELS;
            *s = palette.len() as u32;
            palette.push(colours(l));
        }
        *s as u16
    });
    if overflow {
        return Err(SegmentError::Parameter(format!(
            "more than {MAX_LABELS} segments"
        )));
    }
    IndexedImage::new(out, palette).map_err(|e| SegmentError::Parameter(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereolink_image::metrics::psnr_rgb;

    /// Three flat colour classes with mild noise.
    fn three_classes() -> RgbImage {
        RgbImage::from_fn(60, 30, |x, y| {
            let n = ((x * 7 + y * 13) % 5) as u8;
            match x / 20 {
                0 => [20 + n, 40 + n, 200 + n],
                1 => [120 + n, 20 + n, 60 + n],
                _ => [230 - n, 220 - n, 30 + n],
            }
        })
    }

    #[test]
    fn every_method_recovers_three_flat_classes() {
        let img = three_classes();
        for method in Method::all() {
            let seg = segment(&img, &method, 3, 1).unwrap();
            let rgb = seg.to_rgb();
            let psnr = psnr_rgb(&img, &rgb).unwrap().overall;
            assert!(psnr > 35.0, "{method}: {psnr:.1} dB");
            // Pixels of different columns never share a label.
            let l = seg.image.labels();
            assert_ne!(l.get(5, 5), l.get(25, 5), "{method}");
            assert_ne!(l.get(25, 5), l.get(45, 5), "{method}");
        }
    }

    #[test]
    fn bad_inputs_are_errors_or_defined() {
        let img = three_classes();
        assert_eq!(
            segment(&img, &Method::Otsu, 1, 0).unwrap_err(),
            SegmentError::Levels(1)
        );
        assert_eq!(
            segment(&img, &Method::Otsu, 300, 0).unwrap_err(),
            SegmentError::Levels(300)
        );
        assert!(segment(&RgbImage::new(0, 0, [0; 3]), &Method::KMeans, 3, 0).is_err());
        assert!(matches!(
            segment(&RgbImage::new(2, 1, [0; 3]), &Method::KMeans, 3, 0),
            Err(SegmentError::TooManyClusters { .. })
        ));
        // One colour: a single class, never NaN.
        let flat = RgbImage::new(10, 10, [9, 9, 9]);
        for method in Method::all() {
            let seg = segment(&flat, &method, 4, 3).unwrap();
            assert_eq!(seg.to_rgb(), flat, "{method}");
        }
        assert!("nope".parse::<Method>().is_err());
    }

    #[test]
    fn swarms_are_deterministic_per_seed() {
        let img = three_classes();
        for name in ["pso", "dpso", "fodpso", "kmeans"] {
            let m: Method = name.parse().unwrap();
            assert_eq!(
                segment(&img, &m, 4, 9).unwrap(),
                segment(&img, &m, 4, 9).unwrap(),
                "{name}"
            );
        }
    }

    /// 64 levels per channel on noise give more class triples than labels:
    /// the least populated join the nearest kept class, where their labels
    /// once wrapped around (a garbled image, 11.6 dB).
    #[test]
    fn fine_thresholds_on_noise_keep_the_label_cap() {
        let mut s = 5u32;
        let img = RgbImage::from_fn(400, 300, |_, _| {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            [(s >> 24) as u8, (s >> 16) as u8, (s >> 8) as u8]
        });
        let seg = segment(&img, &Method::Otsu, 64, 0).unwrap();
        let ch = seg.channels.as_ref().unwrap();
        assert_eq!(seg.image.palette().len(), MAX_LABELS);
        // A pixel's colour is its own class's, or one a class step or a
        // few away (a dropped class takes the nearest kept).
        let class = |c: usize, v: u8| ch.thresholds[c].iter().filter(|&&t| v > t).count();
        let rgb = seg.to_rgb();
        let mut steps = 0;
        for (p, q) in img.as_slice().iter().zip(rgb.as_slice()) {
            let d: usize = (0..3)
                .map(|c| class(c, p[c]).abs_diff(class(c, q[c])))
                .sum();
            assert!(d <= 3, "{p:?} shown as {q:?}");
            steps += d;
        }
        assert!(steps < img.len() / 2, "{steps} class steps");
        let psnr = psnr_rgb(&img, &rgb).unwrap().overall;
        assert!(psnr > 30.0, "{psnr:.1} dB");
        // Below the cap, the labels are as before: one per triple.
        let seg = segment(&img, &Method::Otsu, 16, 0).unwrap();
        assert_eq!(seg.image.palette().len(), 16 * 16 * 16);
    }
}
