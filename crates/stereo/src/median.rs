//! The refinement's median filter over the valid pixels of a square window.
//!
//! Sorting each window costs a few hundred nanoseconds per pixel, more than
//! the whole WTA matcher. Instead the median is taken by a selection
//! network: Batcher's odd–even merge sort for the window's pixel count,
//! pruned to the comparators the middle output depends on (113 for 5×5),
//! run on [`CHUNK`] neighbouring pixels at once so that every comparator is
//! one vector `min` and `max`. Disparities are compared as integer keys in
//! [`f32::total_cmp`] order; invalid pixels and pixels outside the image
//! become the smallest or largest key in equal numbers (see [`Keys::split_holes`]),
//! which makes the network's middle output the median of the valid pixels
//! exactly, as a sort would give it.
//!
//! LLVM's vectoriser turns the network on arrays of `[u32; 8]` into shuffles
//! through memory, so the vector set is written out twice behind the [`Keys`]
//! trait: plainly, and with AVX2 intrinsics; the tests check both.

use rayon::prelude::*;
use stereolink_image::DisparityMap;

/// Pixels filtered together by the network (one AVX2 register of `u32`).
const CHUNK: usize = 8;

/// Median over the valid pixels of a `size`×`size` window (`size` is made
/// odd by rounding down to `2·(size/2) + 1`); for an even count of valid
/// pixels the upper of the two middle values. Invalid pixels stay invalid.
/// Rows run in parallel.
///
/// # Panics
/// If `size` is larger than 15 (checked by [`crate::MatchSpec::validate`]).
pub fn median(map: &DisparityMap, size: usize) -> DisparityMap {
    median_with(map, size, stereolink_image::cpu::avx2())
}

/// [`median`] with the AVX2 kernel (`avx2`, only if the CPU has it) or the portable one.
fn median_with(map: &DisparityMap, size: usize, avx2: bool) -> DisparityMap {
    let (w, h) = map.dims();
    let r = size / 2;
    let mut out = map.clone();
    if r == 0 || w == 0 {
        return out;
    }
    let n = 2 * r + 1;
    assert!(n <= 15, "median window {size} is larger than 15");
    // The 5×5 network is unrolled with constant indices (`None`).
    let built = (n != 5).then(|| Box::new(selection_network(n * n, n * n / 2)));
    let network = built.as_deref().map(Network::pairs);
    let keys: Vec<u32> = map
        .as_slice()
        .par_iter()
        .map(|&v| if v.is_finite() { order_key(v) } else { HOLE })
        .collect();
    out.as_mut_slice()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| {
            let job = RowJob {
                keys: &keys,
                dims: (w, h),
                y,
                r,
                network,
            };
            #[cfg(target_arch = "x86_64")]
            if avx2 {
                // SAFETY: the caller saw AVX2 at run time.
                return unsafe { filter_row_avx2(&job, row) };
            }
            let _ = avx2;
            // SAFETY: the portable keys need no CPU feature.
            unsafe { filter_row::<[u32; CHUNK]>(&job, row) }
        });
    out
}

/// What filtering one row needs.
struct RowJob<'a> {
    keys: &'a [u32],
    dims: (usize, usize),
    y: usize,
    r: usize,
    /// The selection network, or `None` for the unrolled 5×5 one.
    network: Option<&'a [(u8, u8)]>,
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn filter_row_avx2(job: &RowJob, row: &mut [f32]) {
    filter_row::<std::arch::x86_64::__m256i>(job, row)
}

/// Replaces the valid pixels of `row` by their window medians.
///
/// # Safety
/// `K`'s instruction set must be available.
#[inline(always)]
unsafe fn filter_row<K: Keys>(job: &RowJob, row: &mut [f32]) {
    let n = 2 * job.r + 1;
    let mut unrolled = [K::splat(0); 25];
    let mut general = Vec::new();
    let lanes: &mut [K] = match job.network {
        None => &mut unrolled,
        Some(_) => {
            general.resize(n * n, K::splat(0));
            &mut general
        }
    };
    let middle = lanes.len() / 2;
    for x in (0..job.dims.0).step_by(CHUNK) {
        match job.network {
            Some(pairs) => {
                gather(job.keys, job.dims, (x, job.y), job.r, lanes);
                pairs.iter().for_each(|&pair| compare(lanes, pair));
            }
            None => {
                // A constant radius, so that the loads unroll too.
                gather(job.keys, job.dims, (x, job.y), 2, lanes);
                apply_5x5(lanes);
            }
        }
        let row = &mut row[x..(x + CHUNK).min(job.dims.0)];
        for (o, &key) in row.iter_mut().zip(&lanes[middle].to_array()) {
            if o.is_finite() {
                *o = from_order_key(key);
            }
        }
    }
}

/// The key of an invalid pixel (above every finite value's key).
const HOLE: u32 = u32::MAX;

/// Loads the windows of the pixels `x..x + CHUNK` of row `y` into `lanes`
/// (lane `l` of `lanes[k]` is element `k` of window `l`), invalid and
/// outside pixels as [`HOLE`] split by [`Keys::split_holes`].
///
/// # Safety
/// `K`'s instruction set must be available.
#[inline(always)]
unsafe fn gather<K: Keys>(
    keys: &[u32],
    (w, h): (usize, usize),
    (x, y): (usize, usize),
    r: usize,
    lanes: &mut [K],
) {
    let n = 2 * r + 1;
    let inside = y >= r && y + r < h && x >= r && x + CHUNK + r <= w;
    let mut parity = K::splat(0);
    let mut lanes = lanes.iter_mut();
    for dy in 0..n {
        let yy = (y + dy).checked_sub(r).filter(|&yy| yy < h);
        for dx in 0..n {
            let keys = if inside {
                let start = (y + dy - r) * w + x + dx - r;
                K::load(&keys[start..start + CHUNK])
            } else {
                K::load(&std::array::from_fn::<u32, CHUNK, _>(|l| {
                    let xx = (x + l + dx).checked_sub(r).filter(|&xx| xx < w);
                    match (xx, yy) {
                        (Some(xx), Some(yy)) => keys[yy * w + xx],
                        _ => HOLE,
                    }
                }))
            };
            *lanes.next().expect("n² lanes") = keys.split_holes(&mut parity);
        }
    }
}

/// Eight `u32` keys, one per window, and the operations the filter needs.
///
/// # Safety
/// Every method may use the instruction set its implementation is named
/// after: call them only when the CPU has it.
trait Keys: Copy {
    /// All lanes `v`.
    unsafe fn splat(v: u32) -> Self;
    /// `src[..CHUNK]`.
    unsafe fn load(src: &[u32]) -> Self;
    unsafe fn to_array(self) -> [u32; CHUNK];
    unsafe fn min(self, other: Self) -> Self;
    unsafe fn max(self, other: Self) -> Self;
    /// Turns every second [`HOLE`] of a lane (counted in `parity`, one bit
    /// per lane, over the calls for one window) into 0, the smallest key: a
    /// window with `m` holes then has `⌊m/2⌋` smallest and `⌈m/2⌉` largest
    /// keys, and the middle of all `n²` keys is element `⌊(n² − m)/2⌋` of the
    /// valid ones, the upper median.
    unsafe fn split_holes(self, parity: &mut Self) -> Self;
}

impl Keys for [u32; CHUNK] {
    #[inline(always)]
    unsafe fn splat(v: u32) -> Self {
        [v; CHUNK]
    }

    #[inline(always)]
    unsafe fn load(src: &[u32]) -> Self {
        src[..CHUNK].try_into().expect("CHUNK keys")
    }

    #[inline(always)]
    unsafe fn to_array(self) -> [u32; CHUNK] {
        self
    }

    #[inline(always)]
    unsafe fn min(self, other: Self) -> Self {
        std::array::from_fn(|l| self[l].min(other[l]))
    }

    #[inline(always)]
    unsafe fn max(self, other: Self) -> Self {
        std::array::from_fn(|l| self[l].max(other[l]))
    }

    #[inline(always)]
    unsafe fn split_holes(self, parity: &mut Self) -> Self {
        std::array::from_fn(|l| {
            let hole = self[l] == HOLE;
            parity[l] ^= u32::from(hole);
            if hole && parity[l] == 0 {
                0
            } else {
                self[l]
            }
        })
    }
}

#[cfg(target_arch = "x86_64")]
impl Keys for std::arch::x86_64::__m256i {
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn splat(v: u32) -> Self {
        std::arch::x86_64::_mm256_set1_epi32(v as i32)
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn load(src: &[u32]) -> Self {
        assert!(src.len() >= CHUNK);
        std::arch::x86_64::_mm256_loadu_si256(src.as_ptr().cast())
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn to_array(self) -> [u32; CHUNK] {
        std::mem::transmute(self)
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn min(self, other: Self) -> Self {
        std::arch::x86_64::_mm256_min_epu32(self, other)
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn max(self, other: Self) -> Self {
        std::arch::x86_64::_mm256_max_epu32(self, other)
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn split_holes(self, parity: &mut Self) -> Self {
        use std::arch::x86_64::*;
        let hole = _mm256_cmpeq_epi32(self, _mm256_set1_epi32(-1));
        *parity = _mm256_xor_si256(*parity, hole);
        // Clear the holes whose parity is now even.
        _mm256_andnot_si256(_mm256_andnot_si256(*parity, hole), self)
    }
}

/// A `u32` whose unsigned order is [`f32::total_cmp`]'s order of `v`.
fn order_key(v: f32) -> u32 {
    let bits = v.to_bits();
    if bits >> 31 == 1 {
        !bits
    } else {
        bits | 1 << 31
    }
}

/// The inverse of [`order_key`].
fn from_order_key(key: u32) -> f32 {
    f32::from_bits(if key >> 31 == 1 {
        key & !(1 << 31)
    } else {
        !key
    })
}

/// Room for the comparators of any window up to 15×15 (Batcher's sort of
/// 256 inputs has 3839).
const MAX_COMPARATORS: usize = 4096;

/// A comparator network: pairs `(i, j)`, `i < j`, each putting the smaller
/// of elements `i` and `j` at `i`.
pub(crate) struct Network {
    pairs: [(u8, u8); MAX_COMPARATORS],
    len: usize,
}

impl Network {
    fn pairs(&self) -> &[(u8, u8)] {
        &self.pairs[..self.len]
    }
}

/// The selection network of the 5×5 median, built at compile time.
const MEDIAN_5X5: Network = selection_network(25, 12);

/// The comparators of [`MEDIAN_5X5`], each a [`compare`], written out one
/// by one with constant indices, so that the 25 rows stay in vector
/// registers instead of being loaded and stored through memory on every
/// comparator (docs/benchmarks.md, “Median filter”).
///
/// # Safety
/// `K`'s instruction set must be available.
#[inline(always)]
unsafe fn apply_5x5<K: Keys>(lanes: &mut [K]) {
    const _: () = assert!(MEDIAN_5X5.len == 113);
    let lanes: &mut [K; 25] = lanes.try_into().expect("25 rows");
    seq_macro::seq!(K in 0..113 {
        compare(lanes, MEDIAN_5X5.pairs[K]);
    });
}

/// The comparators of Batcher's odd–even merge sort of `n ≤ 256` values
/// that output `out` of the sorted order depends on.
///
/// The sort is built for the next power of two; the missing inputs act as
/// `+∞` at the top indices, where every comparator touching them is a no-op,
/// so those comparators are dropped. Walking backwards from `out` then keeps
/// only comparators that feed it. (A `const fn`, hence the plain loops.)
const fn selection_network(n: usize, out: usize) -> Network {
    assert!(n <= 256 && out < n);
    let size = n.next_power_of_two();
    let mut sort = [(0u8, 0u8); MAX_COMPARATORS];
    let mut len = 0;
    let mut p = 1;
    while p < size {
        let mut k = p;
        while k >= 1 {
            let mut j = k % p;
            while j + k < size {
                let mut i = 0;
                while i < k && i + j + k < size {
                    let (a, b) = (i + j, i + j + k);
                    if a / (2 * p) == b / (2 * p) && b < n {
                        sort[len] = (a as u8, b as u8);
                        len += 1;
                    }
                    i += 1;
                }
                j += 2 * k;
            }
            k /= 2;
        }
        p *= 2;
    }
    let mut needed = [false; 256];
    needed[out] = true;
    let mut net = Network {
        pairs: [(0, 0); MAX_COMPARATORS],
        len: 0,
    };
    // Backwards, keeping what feeds a needed output; then reversed in place.
    while len > 0 {
        len -= 1;
        let (a, b) = sort[len];
        if needed[a as usize] || needed[b as usize] {
            needed[a as usize] = true;
            needed[b as usize] = true;
            net.pairs[net.len] = (a, b);
            net.len += 1;
        }
    }
    let mut i = 0;
    while i < net.len / 2 {
        let t = net.pairs[i];
        net.pairs[i] = net.pairs[net.len - 1 - i];
        net.pairs[net.len - 1 - i] = t;
        i += 1;
    }
    net
}

/// One comparator on every lane: the smaller keys to row `i`, the larger to `j`.
///
/// # Safety
/// `K`'s instruction set must be available.
#[inline(always)]
unsafe fn compare<K: Keys>(lanes: &mut [K], (i, j): (u8, u8)) {
    let (i, j) = (i as usize, j as usize);
    let (a, b) = (lanes[i], lanes[j]);
    lanes[i] = a.min(b);
    lanes[j] = a.max(b);
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The median of the valid pixels of the window of radius `r` at `(x, y)`,
    /// clipped to the image, by selection; `window` is scratch.
    fn median_at(map: &DisparityMap, x: usize, y: usize, r: usize, window: &mut Vec<f32>) -> f32 {
        let (w, h) = map.dims();
        window.clear();
        for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
            let src = &map.row(yy)[x.saturating_sub(r)..(x + r + 1).min(w)];
            window.extend(src.iter().filter(|v| v.is_finite()));
        }
        let mid = window.len() / 2;
        *window.select_nth_unstable_by(mid, f32::total_cmp).1
    }

    /// By the 0/1 principle a comparator network selects output `out`
    /// correctly iff it does so for every input of zeros and ones.
    #[test]
    fn every_output_of_the_pruned_networks_is_right() {
        for n in [1, 2, 3, 9, 10, 13] {
            for out in 0..n {
                let net = selection_network(n, out);
                let net = net.pairs();
                for bits in 0u32..1 << n {
                    let mut lanes: Vec<[u32; CHUNK]> =
                        (0..n).map(|k| [bits >> k & 1; CHUNK]).collect();
                    for &pair in net {
                        // SAFETY: portable keys.
                        unsafe { compare(&mut lanes, pair) };
                    }
                    let zeros = n - bits.count_ones() as usize;
                    assert_eq!(lanes[out][0], u32::from(out >= zeros), "n {n} out {out}");
                }
            }
        }
        assert_eq!(MEDIAN_5X5.pairs().len(), 113);
    }

    #[test]
    fn order_keys_follow_total_cmp() {
        let vals = [
            -3.5f32,
            -0.0,
            0.0,
            1e-30,
            2.25,
            7.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ];
        for &a in &vals {
            assert_eq!(from_order_key(order_key(a)).to_bits(), a.to_bits());
            for &b in &vals {
                assert_eq!(order_key(a).cmp(&order_key(b)), a.total_cmp(&b));
            }
        }
    }

    #[test]
    fn median_removes_a_spike_and_keeps_holes() {
        let mut m = DisparityMap::new(5, 5, 3.0);
        m.set(2, 2, 40.0);
        m.set(0, 0, f32::INFINITY);
        let f = median(&m, 3);
        assert_eq!(f.get(2, 2), 3.0);
        assert_eq!(f.get(0, 0), f32::INFINITY);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]
        /// The network, holes and borders included, equals per-pixel selection,
        /// and the portable kernel the detected one.
        #[test]
        fn network_equals_selection(
            w in 1usize..40, h in 1usize..20, size in 1usize..8,
            seed in any::<u64>(), holes in 0u32..60,
        ) {
            let mut s = seed | 1;
            let mut next = || { s ^= s << 13; s ^= s >> 7; s ^= s << 17; s };
            let map = DisparityMap::from_fn(w, h, |_, _| {
                let v = next();
                // A few holes, and subpixel values with frequent ties.
                if (v % 100) < holes as u64 { f32::INFINITY } else { (v >> 40) as f32 % 16.0 * 0.25 }
            });
            let portable = median_with(&map, size, false);
            let fast = median(&map, size);
            prop_assert_eq!(portable.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                fast.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>());
            let r = size / 2;
            let mut window = Vec::new();
            for y in 0..h {
                for x in 0..w {
                    let want = if map.get(x, y).is_finite() && r > 0 {
                        median_at(&map, x, y, r, &mut window)
                    } else {
                        map.get(x, y)
                    };
                    prop_assert_eq!(fast.get(x, y).to_bits(), want.to_bits(), "({}, {})", x, y);
                }
            }
        }
    }
}
