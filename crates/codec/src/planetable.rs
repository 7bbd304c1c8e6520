//! The plane table section of a stereo frame: the sender's disparity map as
//! one plane `d = a·x + b·y + c` per segment (4-connected component of the
//! transmitted left label map, cut by square tiles), so the receiver can
//! rebuild a dense map from labels it already decodes, without matching.
//!
//! Compact: the distinct planes are listed once, in 16.16 fixed point, and
//! each segment's index into that list is range coded ([`IndexCoder`]):
//! segments are numbered in raster order of their first pixel, so the
//! segments just before one are mostly its neighbours, and clustered
//! neighbours share planes. A move-to-front list of the planes used last
//! turns most indices into rank 0 or 1, a fraction of a bit each; version 1
//! spent 1–2 bytes on every index, which made the table 37–54 % of a frame.
//! Rounding a, b and c to the nearest 2^-16 moves the plane's disparity at
//! pixel (x, y) by at most 2^-17 · (x + y + 1) px: under 0.007 px on a
//! 450×375 view. [`PlaneTable::disparity`] evaluates a plane in the same
//! fixed point, integers only (the ARM926 board has no FPU), so sender
//! and receiver rebuild the very same map. Layout: `docs/wire-format.md`.

use std::collections::HashMap;

use crate::container::{Reader, Writer};
use crate::rangecoder::{BitTree, Decoder, Encoder, Prob};
use crate::CodecError;

/// Section tag of a plane table.
pub const TAG: u8 = 1;
/// Version of the plane table section this build writes and reads (1 had
/// raw 1-, 2- or 4-byte indices; a frame's version 1 table is skipped).
pub const VERSION: u8 = 2;
/// Planes on the move-to-front list of [`IndexCoder`].
const RECENT: usize = 15;
/// Fraction bits of the fixed-point plane coefficients.
pub const FRACTION_BITS: u32 = 16;

/// A plane in fixed point: `a`, `b` (px of disparity per px) and `c` (px at
/// `(0, 0)`), each times 2^[`FRACTION_BITS`].
pub type FixedPlane = [i32; 3];

/// The plane table of a frame.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PlaneTable {
    /// Side of the square tiles that cut the components into segments (px,
    /// 0: no tiles).
    pub tile: u16,
    /// The disparity range every plane is clamped to (px, inclusive).
    pub range: (i16, i16),
    /// The distinct planes.
    pub planes: Vec<FixedPlane>,
    /// For each segment, in raster order of its first pixel, its plane's
    /// index in `planes`. Empty when the sender found no plane (the map is
    /// invalid everywhere).
    pub of_segment: Vec<u32>,
}

/// `v` in 16.16 fixed point, rounded to nearest and saturated (0 for NaN).
fn fixed(v: f32) -> i32 {
    (v as f64 * (1u32 << FRACTION_BITS) as f64).round() as i32
}

impl PlaneTable {
    /// Quantises one plane `[a, b, c]` per segment, listing equal
    /// quantised planes once in the order of their first segment.
    pub fn quantise(tile: u16, range: (i16, i16), per_segment: &[[f32; 3]]) -> Self {
        let mut index = HashMap::new();
        let mut planes = Vec::new();
        let of_segment = per_segment
            .iter()
            .map(|p| {
                let q = p.map(fixed);
                *index.entry(q).or_insert_with(|| {
                    planes.push(q);
                    planes.len() as u32 - 1
                })
            })
            .collect();
        PlaneTable {
            tile,
            range,
            planes,
            of_segment,
        }
    }

    /// The disparity of segment `s` at pixel `(x, y)`, clamped to the
    /// range, in 16.16 fixed point (None: no plane for `s`).
    #[inline]
    pub fn disparity(&self, s: usize, x: usize, y: usize) -> Option<i64> {
        let [a, b, c] = self.planes[*self.of_segment.get(s)? as usize].map(i64::from);
        let (lo, hi) = (
            i64::from(self.range.0) << FRACTION_BITS,
            i64::from(self.range.1) << FRACTION_BITS,
        );
        Some((a * x as i64 + b * y as i64 + c).clamp(lo, hi))
    }

    /// Checks that the table has a plane for each of the `segments` of the
    /// decoded label map (or none at all).
    pub fn check_segments(&self, segments: usize) -> Result<(), CodecError> {
        match self.of_segment.len() {
            0 => Ok(()),
            n if n == segments => Ok(()),
            n => Err(CodecError::Invalid(format!(
                "the plane table has {n} segments but the left labels have {segments}"
            ))),
        }
    }

    /// Writes the section: tag, version, length, content.
    pub(crate) fn encode(&self, w: &mut Writer) {
        let mut c = Writer(Vec::new());
        c.u16(self.tile);
        c.u16(self.range.0 as u16);
        c.u16(self.range.1 as u16);
        c.u32(self.of_segment.len() as u32);
        c.u32(self.planes.len() as u32);
        for p in &self.planes {
            for v in p {
                c.u32(*v as u32);
            }
        }
        let mut coder = IndexCoder::default();
        let mut enc = Encoder::new();
        for &i in &self.of_segment {
            coder.encode(&mut enc, i);
        }
        c.bytes(&enc.finish());
        w.u8(TAG);
        w.u8(VERSION);
        w.u32(c.0.len() as u32);
        w.bytes(&c.0);
    }

    /// Parses a section's content (after tag, version and length) for a
    /// view of `pixels` pixels: at most one segment per pixel, at most one
    /// plane per segment, every index below the plane count and every plane
    /// used. Allocates at most 32 times the content's length up front.
    pub(crate) fn parse(content: &[u8], pixels: usize) -> Result<Self, CodecError> {
        let mut r = Reader {
            data: content,
            pos: 0,
        };
        let tile = r.u16("plane table")?;
        let range = (r.u16("plane table")? as i16, r.u16("plane table")? as i16);
        if range.0 > range.1 {
            return Err(CodecError::Invalid(format!(
                "plane table range {} > {}",
                range.0, range.1
            )));
        }
        let n = r.u32("plane table")? as usize;
        let k = r.u32("plane table")? as usize;
        if n > pixels || k > n || (k == 0) != (n == 0) {
            return Err(CodecError::Invalid(format!(
                "plane table of {n} segments and {k} planes for {pixels} pixels"
            )));
        }
        let raw = r.take(k * 12, "planes")?;
        let planes = raw
            .chunks_exact(12)
            .map(|p| {
                let v = |i: usize| i32::from_le_bytes(p[i..i + 4].try_into().expect("4 bytes"));
                [v(0), v(4), v(8)]
            })
            .collect();
        let mut coder = IndexCoder::default();
        let mut dec = Decoder::new(&content[r.pos..]);
        let mut of_segment = Vec::with_capacity(n.min(content.len() * 8));
        for _ in 0..n {
            of_segment.push(coder.decode(&mut dec, k)?);
        }
        if coder.used != k {
            return Err(CodecError::Invalid(format!(
                "plane table: {} of its {k} planes are used",
                coder.used
            )));
        }
        Ok(PlaneTable {
            tile,
            range,
            planes,
            of_segment,
        })
    }
}

/// The model that range codes the segments' plane indices, in segment
/// order. Planes are listed in the order of their first segment, so a
/// segment's plane is either one used before or exactly the next one.
///
/// Per segment: "same plane as the last segment" (a bit whose context is
/// how the last segment was coded: same, recent or other); otherwise its
/// rank 1–14 on a move-to-front list of the [`RECENT`] planes used last (a
/// 4-bit tree, 15 meaning "not on the list"); otherwise "the next new plane"
/// (a bit) or an older plane's index in ⌈log₂ used⌉ plain bits.
struct IndexCoder {
    recent: Vec<u32>,
    used: usize,
    context: usize,
    same: [Prob; 3],
    rank: BitTree,
    new: Prob,
}

impl Default for IndexCoder {
    fn default() -> Self {
        IndexCoder {
            recent: Vec::with_capacity(RECENT),
            used: 0,
            context: 0,
            same: [Prob::default(); 3],
            rank: BitTree::new(4),
            new: Prob::default(),
        }
    }
}

/// Bits of a plain index below `used`.
fn index_bits(used: usize) -> u32 {
    usize::BITS - used.saturating_sub(1).leading_zeros()
}

impl IndexCoder {
    /// Moves `plane` to the front of the list, and notes how it was coded.
    fn take(&mut self, plane: u32, context: usize) -> u32 {
        if let Some(i) = self.recent.iter().position(|&p| p == plane) {
            self.recent.remove(i);
        } else if self.recent.len() == RECENT {
            self.recent.pop();
        }
        self.recent.insert(0, plane);
        self.context = context;
        plane
    }

    fn encode(&mut self, enc: &mut Encoder, plane: u32) {
        let rank = self.recent.iter().position(|&p| p == plane);
        enc.bit(&mut self.same[self.context], rank != Some(0));
        match rank {
            Some(0) => {
                self.take(plane, 0);
            }
            Some(r) => {
                self.rank.encode(enc, r as u32 - 1);
                self.take(plane, 1);
            }
            None => {
                self.rank.encode(enc, RECENT as u32 - 1);
                let new = plane as usize == self.used;
                enc.bit(&mut self.new, !new);
                if new {
                    self.used += 1;
                } else {
                    enc.direct(plane, index_bits(self.used));
                }
                self.take(plane, 2);
            }
        }
    }

    /// The next segment's plane of `planes`.
    fn decode(&mut self, dec: &mut Decoder, planes: usize) -> Result<u32, CodecError> {
        let bad = |what: &str| Err(CodecError::Invalid(format!("plane table: {what}")));
        if !dec.bit(&mut self.same[self.context]) {
            return match self.recent.first() {
                Some(&p) => Ok(self.take(p, 0)),
                None => bad("a repeated plane before any plane"),
            };
        }
        let r = self.rank.decode(dec) as usize + 1;
        if r < RECENT {
            return match self.recent.get(r) {
                Some(&p) => Ok(self.take(p, 1)),
                None => bad("a plane rank beyond the recent planes"),
            };
        }
        let plane = if !dec.bit(&mut self.new) {
            if self.used == planes {
                return bad("more planes than listed");
            }
            self.used += 1;
            self.used - 1
        } else {
            let i = dec.direct(index_bits(self.used)) as usize;
            if i >= self.used {
                return bad("an index of a plane not yet used");
            }
            i
        };
        Ok(self.take(plane as u32, 2))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn quantisation_lists_equal_planes_once_within_the_bound() {
        let p = [0.25f32, -0.125, 17.3];
        let t = PlaneTable::quantise(48, (0, 63), &[p, [0.0, 0.0, 5.0], p]);
        assert_eq!(t.planes.len(), 2);
        assert_eq!(t.of_segment, [0, 1, 0]);
        for (x, y) in [(0, 0), (100, 3), (449, 374)] {
            let exact =
                (p[0] as f64 * x as f64 + p[1] as f64 * y as f64 + p[2] as f64).clamp(0.0, 63.0);
            let got = t.disparity(2, x, y).unwrap() as f64 / 65536.0;
            let bound = (x + y + 1) as f64 / (1u32 << 17) as f64;
            assert!((got - exact).abs() <= bound, "{got} vs {exact}");
        }
        assert_eq!(t.disparity(3, 0, 0), None);
        assert_eq!(t.disparity(1, 9, 9), Some(5 << 16));
        assert!(t.check_segments(3).is_ok());
        assert!(t.check_segments(4).is_err());
    }

    fn round_trip(t: &PlaneTable, pixels: usize) -> Result<PlaneTable, CodecError> {
        let mut w = Writer(Vec::new());
        t.encode(&mut w);
        assert_eq!(&w.0[..2], &[TAG, VERSION]);
        let len = u32::from_le_bytes(w.0[2..6].try_into().unwrap()) as usize;
        assert_eq!(len, w.0.len() - 6);
        PlaneTable::parse(&w.0[6..], pixels)
    }

    #[test]
    fn index_widths_round_trip() {
        for k in [0usize, 1, 256, 257, 70_000] {
            let per: Vec<[f32; 3]> = (0..k).map(|i| [0.0, 0.0, i as f32 / 64.0]).collect();
            let t = PlaneTable::quantise(0, (-5, 300), &per);
            assert_eq!(t.planes.len(), k);
            assert_eq!(round_trip(&t, k).unwrap(), t);
            if k > 0 {
                // More segments than pixels is refused.
                assert!(round_trip(&t, k - 1).is_err());
            }
        }
    }

    /// Pins the section's bytes (the fields before the coded indices
    /// checked independently with Python's `struct`; `docs/wire-format.md`
    /// quotes them).
    #[test]
    fn golden_plane_table() {
        let t = PlaneTable::quantise(
            48,
            (0, 63),
            &[[0.25, -0.125, 17.3], [0.0, 0.0, 5.0], [0.25, -0.125, 17.3]],
        );
        assert_eq!(t.planes, [[16384, -8192, 1_133_773], [0, 0, 327_680]]);
        let mut w = Writer(Vec::new());
        t.encode(&mut w);
        let hex: String = w.0.iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(
            hex,
            "01022c000000\
             30000000\
             3f0003000000\
             02000000\
             00400000\
             00e0ffff\
             cd4c1100\
             000000000000000000000500\
             f3c2d57b0000"
        );
    }

    proptest! {
        /// Any assignment of planes to segments, runs and jumps alike,
        /// codes and decodes to itself.
        #[test]
        fn any_assignment_round_trips(choice in proptest::collection::vec(0u8..40, 0..600)) {
            let per: Vec<[f32; 3]> = choice.iter().map(|&c| [0.0, 0.0, f32::from(c)]).collect();
            let t = PlaneTable::quantise(16, (0, 63), &per);
            prop_assert_eq!(round_trip(&t, per.len()).unwrap(), t);
        }

        /// Any bytes give a table within the checks or a typed error.
        #[test]
        fn arbitrary_contents_are_tables_or_errors(
            bytes in proptest::collection::vec(any::<u8>(), 0..200),
            pixels in 0usize..100,
        ) {
            if let Ok(t) = PlaneTable::parse(&bytes, pixels) {
                prop_assert!(t.of_segment.len() <= pixels);
                prop_assert!(t.of_segment.iter().all(|&i| (i as usize) < t.planes.len()));
                prop_assert_eq!(round_trip(&t, pixels).unwrap(), t);
            }
        }
    }
}
