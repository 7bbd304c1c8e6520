//! The plane table section of a stereo frame: the sender's disparity map as
//! one plane `d = a·x + b·y + c` per segment (4-connected component of the
//! transmitted left label map, cut by square tiles), so the receiver can
//! rebuild a dense map from labels it already decodes, without matching.
//!
//! Compact: the distinct planes are listed once, in 16.16 fixed point,
//! range coded by their bit lengths, and each segment's index into that
//! list is range coded, predicted by the planes of the segments just above
//! and left of the segment's first pixel: the plane assignment favours neighbours sharing a
//! plane, so one of those two mostly has the segment's plane
//! (docs/benchmarks.md, “Plane table”). Decoding the indices therefore
//! needs the decoded left labels' segments: a frame's table is parsed into a
//! [`CodedPlaneTable`] and resolved once the labels are decoded.
//! Version 1 spent 12 raw bytes on every plane and 1–2 on every index;
//! version 2 range coded them. Version 3 ([`TableCoding`]) codes
//! the coefficients only to the precision the map needs and leaves the
//! tiny segments' indices out: a segment of fewer than `implied_below`
//! pixels takes the plane of the segment above (else left of) its first
//! pixel, on both ends, which the plane assignment mostly gives it anyway.
use std::collections::HashMap;

use stereolink_image::Plane;

use crate::container::{Reader, Writer};
use crate::rangecoder::{BitTree, Decoder, Encoder, Prob};
use crate::CodecError;

/// Section tag of a plane table.
pub const TAG: u8 = 1;
/// Version of the plane table section this build writes and reads (1 had
/// raw planes and raw 1-, 2- or 4-byte indices, 2 coded every coefficient
/// to 1/65536 and every segment's index; a frame's older table is skipped).
pub const VERSION: u8 = 3;
/// Planes on the move-to-front list of [`IndexCoder`].
const RECENT: usize = 15;
/// Fraction bits of the fixed-point plane coefficients.
pub const FRACTION_BITS: u32 = 16;

/// A plane in fixed point: `a`, `b` (px of disparity per px) and `c` (px at
/// `(0, 0)`), each times 2^[`FRACTION_BITS`].
pub type FixedPlane = [i32; 3];

/// How a table is coded: its coefficients' precision and which segments'
/// indices are left out. The defaults trade table bytes against the
/// accuracy of the board's map from the planes (docs/tuning.md, “Plane
/// table coding”).
///
/// A plane rounded so is off by at most 2^−(slant_bits+1) · (x + y) +
/// 2^−(offset_bits+1) px at `(x, y)`: 0.12 px at the far corner of a
/// 450×375 view with the defaults.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TableCoding {
    /// Fraction bits of the slants `a` and `b` (at most 16): each is a
    /// multiple of 2^−`slant_bits` px per px.
    pub slant_bits: u8,
    /// Fraction bits of the offset `c` (at most 16).
    pub offset_bits: u8,
    /// Segments of fewer pixels take the plane of the segment above their
    /// first pixel, else of the one left of it, and their indices are not
    /// coded (0 or 1: every index is coded).
    pub implied_below: u16,
}

impl Default for TableCoding {
    fn default() -> Self {
        TableCoding {
            slant_bits: 12,
            offset_bits: 5,
            implied_below: 2,
        }
    }
}

impl TableCoding {
    /// Every coefficient to 1/65536 and every index coded (version 2's content).
    pub const EXACT: TableCoding = TableCoding {
        slant_bits: FRACTION_BITS as u8,
        offset_bits: FRACTION_BITS as u8,
        implied_below: 0,
    };

    /// The fraction bits of coefficient `i` (a, b, c).
    fn bits(&self, i: usize) -> u32 {
        u32::from(if i < 2 {
            self.slant_bits
        } else {
            self.offset_bits
        })
    }
}

/// The plane table of a frame.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PlaneTable {
    /// Side of the square tiles that cut the components into segments (px,
    /// 0: no tiles).
    pub tile: u16,
    /// The disparity range every plane is clamped to (px, inclusive).
    pub range: (i16, i16),
    /// The coefficients' precision and the segments left implied.
    pub coding: TableCoding,
    /// The distinct planes.
    pub planes: Vec<FixedPlane>,
    /// For each segment, in raster order of its first pixel, its plane's
    /// index in `planes`. Empty when the sender found no plane (the map is
    /// invalid everywhere).
    pub of_segment: Vec<u32>,
}

/// `v` in 16.16 fixed point, rounded to the nearest multiple of
/// 2^−`bits` and saturated (0 for NaN).
fn fixed(v: f32, bits: u32) -> i32 {
    let steps = (v as f64 * (1u64 << bits) as f64).round();
    let limit = (i32::MAX >> (FRACTION_BITS - bits)) as f64;
    (steps.clamp(-limit - 1.0, limit) as i32) << (FRACTION_BITS - bits)
}

impl PlaneTable {
    /// Quantises one plane `[a, b, c]` per segment as `coding` says,
    /// listing equal quantised planes once in the order of their first
    /// segment. `ids` are the segments (as `PlaneTable::encode` takes
    /// them): a segment that `coding` leaves implied takes its
    /// predecessor's plane here, as the receiver will.
    pub fn quantise(
        tile: u16,
        range: (i16, i16),
        coding: TableCoding,
        ids: Option<&Plane<u32>>,
        per_segment: &[[f32; 3]],
    ) -> Self {
        let implied = ids.map(|ids| {
            let around = neighbours(ids, per_segment.len());
            implied(ids, &around, coding.implied_below)
        });
        let mut index = HashMap::new();
        let mut planes = Vec::new();
        let mut of_segment: Vec<u32> = Vec::with_capacity(per_segment.len());
        for (s, p) in per_segment.iter().enumerate() {
            let from = implied.as_ref().and_then(|i| i[s]);
            let k = match from {
                Some(t) => of_segment[t as usize],
                None => {
                    let q = [0, 1, 2].map(|i| fixed(p[i], coding.bits(i)));
                    *index.entry(q).or_insert_with(|| {
                        planes.push(q);
                        planes.len() as u32 - 1
                    })
                }
            };
            of_segment.push(k);
        }
        PlaneTable {
            tile,
            range,
            coding,
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

    /// Writes the section: tag, version, length, content. `ids` are the
    /// segments of the left labels the table belongs to
    /// ([`stereolink_image::segments::components`] in tiles of `tile`); the
    /// indices are coded without neighbours when there are none.
    pub(crate) fn encode(&self, w: &mut Writer, ids: Option<&Plane<u32>>) {
        let n = self.of_segment.len();
        let coding = self.coding;
        let mut c = Writer(Vec::new());
        c.u16(self.tile);
        c.u16(self.range.0 as u16);
        c.u16(self.range.1 as u16);
        c.u16(coding.implied_below);
        c.u8(coding.slant_bits);
        c.u8(coding.offset_bits);
        c.u32(n as u32);
        c.u32(self.planes.len() as u32);
        let mut enc = Encoder::new();
        let mut coefficients = CoefficientCoder::new(coding);
        for p in &self.planes {
            coefficients.encode(&mut enc, p);
        }
        let neighbours = ids.map(|ids| neighbours(ids, n));
        let implied = ids
            .zip(neighbours.as_deref())
            .map(|(ids, around)| implied(ids, around, coding.implied_below));
        let mut coder = IndexCoder::default();
        for (s, &i) in self.of_segment.iter().enumerate() {
            if implied.as_ref().is_some_and(|m| m[s].is_some()) {
                continue;
            }
            let seen = candidates(neighbours.as_deref(), s, &self.of_segment);
            coder.encode(&mut enc, i, seen);
        }
        c.bytes(&enc.finish());
        w.u8(TAG);
        w.u8(VERSION);
        w.u32(c.0.len() as u32);
        w.bytes(&c.0);
    }
}

/// A plane table as a frame carries it: its planes, and its segments'
/// indices still coded, since decoding them needs the segments of the
/// decoded left labels ([`CodedPlaneTable::resolve`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CodedPlaneTable {
    tile: u16,
    range: (i16, i16),
    coding: TableCoding,
    segments: usize,
    planes: usize,
    coded: Vec<u8>,
}

impl CodedPlaneTable {
    /// Parses a section's content (after tag, version and length) for a
    /// view of `pixels` pixels: at most one segment per pixel and at most
    /// one plane per segment. Allocates the content's length.
    pub fn parse(content: &[u8], pixels: usize) -> Result<Self, CodecError> {
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
        let coding = TableCoding {
            implied_below: r.u16("plane table")?,
            slant_bits: r.u8("plane table")?,
            offset_bits: r.u8("plane table")?,
        };
        if coding.slant_bits.max(coding.offset_bits) as u32 > FRACTION_BITS {
            return Err(CodecError::Invalid(format!(
                "plane table: {} and {} fraction bits (at most {FRACTION_BITS})",
                coding.slant_bits, coding.offset_bits
            )));
        }
        let n = r.u32("plane table")? as usize;
        let k = r.u32("plane table")? as usize;
        if n > pixels || k > n || (k == 0) != (n == 0) {
            return Err(CodecError::Invalid(format!(
                "plane table of {n} segments and {k} planes for {pixels} pixels"
            )));
        }
        Ok(CodedPlaneTable {
            tile,
            range,
            coding,
            segments: n,
            planes: k,
            coded: content[r.pos..].to_vec(),
        })
    }

    /// Side of the tiles that cut the left labels' components into segments.
    pub fn tile(&self) -> u16 {
        self.tile
    }

    /// The number of segments the table has planes for (0: none, the map
    /// is invalid everywhere).
    pub fn segments(&self) -> usize {
        self.segments
    }

    /// Decodes the segments' indices over `ids`, the segments of the decoded
    /// left labels ([`stereolink_image::segments::components`] in tiles of
    /// [`CodedPlaneTable::tile`]), `count` of them.
    ///
    /// # Errors
    /// If the table has segments but not `count` of them (it belongs to
    /// another label map), or its indices do not decode to planes it lists,
    /// each used.
    pub fn resolve(&self, ids: &Plane<u32>, count: usize) -> Result<PlaneTable, CodecError> {
        let (n, k) = (self.segments, self.planes);
        if n != 0 && n != count {
            return Err(CodecError::Invalid(format!(
                "the plane table has {n} segments but the left labels have {count}"
            )));
        }
        let mut dec = Decoder::new(&self.coded);
        let mut coefficients = CoefficientCoder::new(self.coding);
        let planes = (0..k)
            .map(|_| coefficients.decode(&mut dec))
            .collect::<Result<Vec<_>, _>>()?;
        let neighbours = neighbours(ids, n);
        let implied = implied(ids, &neighbours, self.coding.implied_below);
        let mut coder = IndexCoder::default();
        let mut of_segment: Vec<u32> = Vec::with_capacity(n);
        for (s, from) in implied.iter().enumerate() {
            let plane = match from {
                Some(t) => of_segment[*t as usize],
                None => {
                    let seen = candidates(Some(&neighbours), s, &of_segment);
                    coder.decode(&mut dec, k, seen)?
                }
            };
            of_segment.push(plane);
        }
        if coder.used != k {
            return Err(CodecError::Invalid(format!(
                "plane table: {} of its {k} planes are used",
                coder.used
            )));
        }
        Ok(PlaneTable {
            tile: self.tile,
            range: self.range,
            coding: self.coding,
            planes,
            of_segment,
        })
    }
}

/// The model that range codes the planes' coefficients: each in units of
/// its precision ([`TableCoding`]), zigzag-mapped (0, −1, 1, −2, … → 0,
/// 1, 2, 3, …), its bit length 0–32 through a 6-bit tree of its own per
/// coefficient (a, b, c), then the bits below the leading 1 as plain bits.
/// A plane's fitted slopes are small, so most take far fewer than 32 bits.
struct CoefficientCoder {
    coding: TableCoding,
    lengths: [BitTree; 3],
}

impl CoefficientCoder {
    fn new(coding: TableCoding) -> Self {
        CoefficientCoder {
            coding,
            lengths: [BitTree::new(6), BitTree::new(6), BitTree::new(6)],
        }
    }

    /// Codes `plane`, whose coefficients are multiples of their precision
    /// ([`PlaneTable::quantise`] makes them so).
    fn encode(&mut self, enc: &mut Encoder, plane: &FixedPlane) {
        for (i, (tree, &v)) in self.lengths.iter_mut().zip(plane).enumerate() {
            let v = v >> (FRACTION_BITS - self.coding.bits(i));
            let u = ((v << 1) ^ (v >> 31)) as u32;
            let n = u32::BITS - u.leading_zeros();
            tree.encode(enc, n);
            if n > 1 {
                enc.direct(u, n - 1);
            }
        }
    }

    fn decode(&mut self, dec: &mut Decoder) -> Result<FixedPlane, CodecError> {
        let mut plane = [0; 3];
        for (i, (tree, v)) in self.lengths.iter_mut().zip(&mut plane).enumerate() {
            let n = tree.decode(dec);
            let u = match n {
                0 => 0,
                1..=32 => 1u32.checked_shl(n - 1).unwrap_or(0) | dec.direct(n - 1),
                _ => {
                    return Err(CodecError::Invalid(format!(
                        "plane table: a coefficient of {n} bits"
                    )))
                }
            };
            let steps = ((u >> 1) as i32) ^ -((u & 1) as i32);
            *v = steps
                .checked_mul(1 << (FRACTION_BITS - self.coding.bits(i)))
                .ok_or_else(|| {
                    CodecError::Invalid("plane table: a coefficient beyond 32 bits".into())
                })?;
        }
        Ok(plane)
    }
}

/// For each segment of `ids` with its `neighbours` ([`neighbours`]), the
/// earlier segment whose plane it takes uncoded: a segment of fewer than
/// `below` pixels takes the one above its first pixel, else the one left of
/// it; `None` (coded) for larger segments and for those with neither.
fn implied(ids: &Plane<u32>, neighbours: &[[Option<u32>; 2]], below: u16) -> Vec<Option<u32>> {
    let n = neighbours.len();
    if below <= 1 {
        return vec![None; n];
    }
    let mut size = vec![0u16; n];
    for &s in ids.as_slice() {
        if let Some(c) = size.get_mut(s as usize) {
            *c = c.saturating_add(1);
        }
    }
    neighbours
        .iter()
        .zip(size)
        .map(|(&[up, left], size)| if size < below { up.or(left) } else { None })
        .collect()
}

/// For each of the first `n` segments of `ids`, the segments above and
/// left of its first pixel (`None` at the border, or where the map does
/// not number its segments in raster order).
fn neighbours(ids: &Plane<u32>, n: usize) -> Vec<[Option<u32>; 2]> {
    let (w, _) = ids.dims();
    let id = ids.as_slice();
    let mut out = vec![[None; 2]; n];
    let mut next = 0usize;
    for (p, &s) in id.iter().enumerate() {
        if s as usize != next || next >= n {
            continue;
        }
        let earlier = |q: usize| (id[q] < s).then_some(id[q]);
        out[next] = [
            (p >= w).then(|| earlier(p - w)).flatten(),
            (p % w > 0).then(|| earlier(p - 1)).flatten(),
        ];
        next += 1;
    }
    out
}

/// The distinct planes of segment `s`'s upper and left neighbours, from the
/// indices of the segments before it.
fn candidates(neighbours: Option<&[[Option<u32>; 2]]>, s: usize, of: &[u32]) -> [Option<u32>; 2] {
    let [up, left] = neighbours.and_then(|n| n.get(s)).map_or([None; 2], |ns| {
        ns.map(|t| t.and_then(|t| of.get(t as usize).copied()))
    });
    match (up, left) {
        (Some(u), Some(l)) if u == l => [Some(u), None],
        (None, l) => [l, None],
        pair => [pair.0, pair.1],
    }
}

/// The model that range codes the segments' plane indices, in segment
/// order. Planes are listed in the order of their first segment, so a
/// segment's plane is either one used before or exactly the next one.
///
/// Per segment, with its neighbours' distinct planes A and B
/// ([`candidates`]): "it is A" (a bit whose context is how many candidates
/// there are and whether the last segment was a candidate), then "it is B";
/// otherwise "same plane as the last segment", its rank 1–14 on a
/// move-to-front list of the [`RECENT`] planes used last (a 4-bit tree, 15
/// meaning "not on the list"), then "the next new plane" or an older
/// plane's index in ⌈log₂ used⌉ plain bits.
struct IndexCoder {
    recent: Vec<u32>,
    used: usize,
    /// The last segment's plane was one of its candidates.
    hit: bool,
    first: [[Prob; 2]; 2],
    second: [Prob; 2],
    same: Prob,
    rank: BitTree,
    new: Prob,
}

impl Default for IndexCoder {
    fn default() -> Self {
        IndexCoder {
            recent: Vec::with_capacity(RECENT),
            used: 0,
            hit: false,
            first: [[Prob::default(); 2]; 2],
            second: [Prob::default(); 2],
            same: Prob::default(),
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
    /// Moves `plane` to the front of the list, and notes whether it was a
    /// candidate.
    fn take(&mut self, plane: u32, hit: bool) -> u32 {
        if let Some(i) = self.recent.iter().position(|&p| p == plane) {
            self.recent.remove(i);
        } else if self.recent.len() == RECENT {
            self.recent.pop();
        }
        self.recent.insert(0, plane);
        self.hit = hit;
        plane
    }

    fn encode(&mut self, enc: &mut Encoder, plane: u32, seen: [Option<u32>; 2]) {
        let h = self.hit as usize;
        if let Some(a) = seen[0] {
            let two = seen[1].is_some() as usize;
            enc.bit(&mut self.first[two][h], a != plane);
            if a == plane {
                self.take(plane, true);
                return;
            }
        }
        if let Some(b) = seen[1] {
            enc.bit(&mut self.second[h], b != plane);
            if b == plane {
                self.take(plane, true);
                return;
            }
        }
        let rank = self.recent.iter().position(|&p| p == plane);
        enc.bit(&mut self.same, rank != Some(0));
        match rank {
            Some(0) => {}
            Some(r) => self.rank.encode(enc, r as u32 - 1),
            None => {
                self.rank.encode(enc, RECENT as u32 - 1);
                let new = plane as usize == self.used;
                enc.bit(&mut self.new, !new);
                if new {
                    self.used += 1;
                } else {
                    enc.direct(plane, index_bits(self.used));
                }
            }
        }
        self.take(plane, false);
    }

    /// The next segment's plane of `planes`.
    fn decode(
        &mut self,
        dec: &mut Decoder,
        planes: usize,
        seen: [Option<u32>; 2],
    ) -> Result<u32, CodecError> {
        let bad = |what: &str| Err(CodecError::Invalid(format!("plane table: {what}")));
        let h = self.hit as usize;
        if let Some(a) = seen[0] {
            if !dec.bit(&mut self.first[seen[1].is_some() as usize][h]) {
                return Ok(self.take(a, true));
            }
        }
        if let Some(b) = seen[1] {
            if !dec.bit(&mut self.second[h]) {
                return Ok(self.take(b, true));
            }
        }
        if !dec.bit(&mut self.same) {
            return match self.recent.first() {
                Some(&p) => Ok(self.take(p, false)),
                None => bad("a repeated plane before any plane"),
            };
        }
        let r = self.rank.decode(dec) as usize + 1;
        if r < RECENT {
            return match self.recent.get(r) {
                Some(&p) => Ok(self.take(p, false)),
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
        Ok(self.take(plane as u32, false))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn quantisation_lists_equal_planes_once_within_the_bound() {
        let p = [0.25f32, -0.125, 17.3];
        let exact = TableCoding::EXACT;
        let t = PlaneTable::quantise(48, (0, 63), exact, None, &[p, [0.0, 0.0, 5.0], p]);
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

    #[test]
    fn coarse_coefficients_stay_within_their_precision() {
        let p = [0.0123f32, -0.0456, 37.789];
        let coding = TableCoding::default();
        let t = PlaneTable::quantise(0, (-100, 100), coding, None, &[p]);
        let (sb, ob) = (coding.slant_bits as i32, coding.offset_bits as i32);
        for (x, y) in [(0, 0), (100, 3), (449, 374), (2000, 1500)] {
            let exact = p[0] as f64 * x as f64 + p[1] as f64 * y as f64 + p[2] as f64;
            let got = t.disparity(0, x, y).unwrap() as f64 / 65536.0;
            let bound = 2f64.powi(-sb - 1) * (x + y) as f64 + 2f64.powi(-ob - 1);
            assert!(
                (got - exact).abs() <= bound + 1e-9,
                "{got} vs {exact} at {x},{y}"
            );
        }
        // Each coefficient is a multiple of its step, and saturates.
        let [a, b, c] = t.planes[0];
        assert_eq!(
            (
                a % (1 << (16 - sb)),
                b % (1 << (16 - sb)),
                c % (1 << (16 - ob))
            ),
            (0, 0, 0)
        );
        let huge = PlaneTable::quantise(0, (0, 1), coding, None, &[[1e9, -1e9, f32::NAN]]);
        let top = i32::MAX >> (16 - sb) << (16 - sb);
        assert_eq!(huge.planes[0], [top, i32::MIN, 0]);
    }

    #[test]
    fn tiny_segments_take_the_plane_above_or_left_uncoded() {
        // Segment 0 is the top row (4 px); 1 is one pixel under its left
        // end, 2 the rest of row 1 (3 px), 3 a column of 2 px at x = 0 of
        // rows 2–3 and 4 the rest (6 px).
        let ids = Plane::from_fn(4, 4, |x, y| match (x, y) {
            (_, 0) => 0,
            (0, 1) => 1,
            (_, 1) => 2,
            (0, _) => 3,
            _ => 4,
        });
        let per: Vec<[f32; 3]> = (0..5).map(|s| [0.0, 0.0, s as f32]).collect();
        let coding = TableCoding {
            implied_below: 4,
            ..TableCoding::EXACT
        };
        let t = PlaneTable::quantise(0, (0, 9), coding, Some(&ids), &per);
        // 1 (1 px) takes 0's plane, from above; 2 (3 px) takes 0's from
        // above; 3 (2 px) takes 1's, which is 0's; 4 (6 px) keeps its own.
        assert_eq!(t.of_segment, [0, 0, 0, 0, 1]);
        assert_eq!(t.planes, [[0, 0, 0], [0, 0, 4 << 16]]);
        assert_eq!(round_trip(&t, &ids, 5, 16).unwrap(), t);
        // The implied indices cost nothing: the table is as long with any
        // plane the tiny segments were given.
        let mut other = per.clone();
        other[2] = [0.0, 0.0, 7.0];
        let u = PlaneTable::quantise(0, (0, 9), coding, Some(&ids), &other);
        assert_eq!(u, t);
    }

    /// Segments in a row, one pixel each: every segment's left neighbour
    /// is the one before it.
    fn row(n: usize) -> Plane<u32> {
        Plane::from_fn(n, 1, |x, _| x as u32)
    }

    /// Writes `t` for the segments `ids` (`count` of them), parses it for a
    /// view of `pixels` pixels and resolves it over the same segments.
    fn round_trip(
        t: &PlaneTable,
        ids: &Plane<u32>,
        count: usize,
        pixels: usize,
    ) -> Result<PlaneTable, CodecError> {
        let mut w = Writer(Vec::new());
        t.encode(&mut w, Some(ids));
        assert_eq!(&w.0[..2], &[TAG, VERSION]);
        let len = u32::from_le_bytes(w.0[2..6].try_into().unwrap()) as usize;
        assert_eq!(len, w.0.len() - 6);
        CodedPlaneTable::parse(&w.0[6..], pixels)?.resolve(ids, count)
    }

    #[test]
    fn many_planes_round_trip_and_counts_are_checked() {
        for k in [0usize, 1, 256, 257, 70_000] {
            let per: Vec<[f32; 3]> = (0..k).map(|i| [0.0, 0.0, i as f32 / 64.0]).collect();
            let t = PlaneTable::quantise(0, (-5, 300), TableCoding::EXACT, None, &per);
            assert_eq!(t.planes.len(), k);
            assert_eq!(round_trip(&t, &row(k), k, k).unwrap(), t);
            if k > 0 {
                // More segments than pixels, or than the labels have, is refused.
                assert!(round_trip(&t, &row(k), k, k - 1).is_err());
                assert!(round_trip(&t, &row(k), k + 1, k).is_err());
            }
        }
    }

    /// Pins the section's bytes (the fields before the coded planes and
    /// indices checked independently with Python's `struct`;
    /// `docs/wire-format.md` quotes them).
    #[test]
    fn golden_plane_table() {
        let coding = TableCoding {
            implied_below: 0,
            ..TableCoding::default()
        };
        let t = PlaneTable::quantise(
            48,
            (0, 63),
            coding,
            Some(&row(3)),
            &[[0.25, -0.125, 17.3], [0.0, 0.0, 5.0], [0.25, -0.125, 17.3]],
        );
        assert_eq!(t.planes, [[16384, -8192, 1_134_592], [0, 0, 327_680]]);
        let mut w = Writer(Vec::new());
        t.encode(&mut w, Some(&row(3)));
        let hex: String = w.0.iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(
            hex,
            "010321000000\
             30000000\
             3f0000000c05\
             03000000\
             02000000\
             300011ff2c5400028d0db6331fe500"
        );
    }

    proptest! {
        /// Any assignment of planes to the segments of any label map, runs
        /// and jumps alike, codes and decodes to itself.
        #[test]
        fn any_assignment_round_trips(
            labels in proptest::collection::vec(0u16..3, 1..300),
            width in 1usize..20,
            tile in 0usize..6,
            choice in proptest::collection::vec(0u8..40, 300),
            implied_below in 0u16..5,
            slant_bits in 0u8..=16,
            offset_bits in 0u8..=16,
        ) {
            let height = labels.len().div_ceil(width);
            let map = stereolink_image::LabelMap::from_fn(width, height, |x, y| {
                labels[(y * width + x) % labels.len()]
            });
            let (ids, count) = stereolink_image::segments::components(&map, tile);
            let per: Vec<[f32; 3]> = (0..count)
                .map(|s| [0.01 * f32::from(choice[(s + 1) % 300]), -0.02, f32::from(choice[s % 300]) / 3.0])
                .collect();
            let coding = TableCoding { slant_bits, offset_bits, implied_below };
            let t = PlaneTable::quantise(tile as u16, (0, 63), coding, Some(&ids), &per);
            prop_assert_eq!(round_trip(&t, &ids, count, width * height).unwrap(), t);
        }

        /// Any bytes give a table within the checks or a typed error.
        #[test]
        fn arbitrary_contents_are_tables_or_errors(
            bytes in proptest::collection::vec(any::<u8>(), 0..200),
            pixels in 0usize..100,
        ) {
            let Ok(coded) = CodedPlaneTable::parse(&bytes, pixels) else {
                return Ok(());
            };
            let n = coded.segments();
            prop_assert!(n <= pixels);
            if let Ok(t) = coded.resolve(&row(n), n) {
                prop_assert!(t.of_segment.iter().all(|&i| (i as usize) < t.planes.len()));
                prop_assert_eq!(round_trip(&t, &row(n), n, pixels).unwrap(), t);
            }
        }
    }
}
