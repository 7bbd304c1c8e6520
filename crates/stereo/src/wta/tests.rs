//! Tests of the WTA matcher: every kernel and loop against a naive
//! definition of eq. 12 ([`reference`]) and against each other.

use proptest::prelude::*;

use super::winner::Disparity;
use super::*;

/// Straightforward per pixel SAD and min filter (O(n²·m²) per pixel and
/// disparity), the reference the fast path is tested against.
fn reference(left: &Samples, right: &Samples, p: &WtaParams) -> DisparityMap {
    let (w, h) = left.dims();
    let (r, mr) = ((p.block / 2) as isize, (p.min_filter.max(1) / 2) as isize);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1);
    let at =
        |img: &Samples, x: isize, y: isize| img.get(clamp(x, w) as usize, clamp(y, h) as usize);
    // Eq. 12 at an image pixel and disparity index k. Border replication
    // applies to the left column first, then the right pixel is taken at
    // (clamped x) − d.
    let sad = |x: isize, y: isize, k: usize| {
        let d = (p.min_disp + k) as isize;
        let mut s = 0u32;
        for dy in -r..=r {
            for dx in -r..=r {
                let xl = clamp(x + dx, w);
                s += at(left, xl, y + dy).abs_diff(at(right, (xl - d).max(0), y + dy)) as u32;
            }
        }
        s as u16
    };
    DisparityMap::from_fn(w, h, |x, y| {
        if x < p.min_disp {
            return f32::INFINITY;
        }
        let (x, y) = (x as isize, y as isize);
        let costs: Vec<u16> = (0..p.ndisp.min(x as usize - p.min_disp + 1))
            .map(|k| {
                let around = (-mr..=mr).flat_map(|dy| (-mr..=mr).map(move |dx| (dx, dy)));
                around
                    .map(|(dx, dy)| sad(clamp(x + dx, w), clamp(y + dy, h), k))
                    .min()
                    .unwrap()
            })
            .collect();
        let k = (0..costs.len()).min_by_key(|&k| (costs[k], k)).unwrap();
        f32::winner(&costs, costs.len(), (k, costs[k]), p)
    })
}

const KERNELS: [Kernel; 3] = [Kernel::Auto, Kernel::Portable, Kernel::Swar];

/// Noise with `bits`-bit samples.
fn noise(w: usize, h: usize, seed: u64, bits: u32) -> Samples {
    let mut s = seed | 1;
    Samples::from_fn(w, h, |_, _| {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 24) as u16 & ((1 << bits) - 1)
    })
}

fn image(w: usize, h: usize, seed: u64) -> Samples {
    noise(w, h, seed, 8)
}

#[test]
fn parameters_out_of_range_are_errors() {
    let ok = WtaParams {
        min_disp: 0,
        ndisp: 8,
        block: 11,
        gray_bits: 9,
        min_filter: 5,
        uniqueness: 0,
        subpixel: false,
    };
    assert_eq!(ok.validate(), Ok(()));
    assert_eq!(
        [8, 9, 10].map(WtaParams::max_block),
        [15, 11, 7],
        "sums of the largest windows fit in u16"
    );
    for bad in [
        WtaParams { block: 13, ..ok },
        WtaParams { block: 4, ..ok },
        WtaParams { block: 0, ..ok },
        WtaParams {
            gray_bits: 11,
            ..ok
        },
        WtaParams { gray_bits: 7, ..ok },
        WtaParams {
            min_filter: 4,
            ..ok
        },
        WtaParams {
            min_filter: 17,
            ..ok
        },
        WtaParams { ndisp: 0, ..ok },
    ] {
        assert!(bad.validate().is_err(), "{bad:?}");
    }
}

#[test]
fn shifted_noise_is_recovered_exactly() {
    let right = image(80, 40, 7);
    let left = Samples::from_fn(80, 40, |x, y| right.get(x.saturating_sub(6), y));
    let p = WtaParams {
        min_disp: 0,
        ndisp: 16,
        block: 5,
        gray_bits: 8,
        min_filter: 0,
        uniqueness: 0,
        subpixel: false,
    };
    let mut out = DisparityMap::new(80, 40, 0.0);
    WtaMatcher::new().compute_into(&left, &right, &p, &mut out);
    for y in 0..40 {
        for x in 12..76 {
            assert_eq!(out.get(x, y), 6.0, "({x}, {y})");
        }
    }
}

#[test]
fn reused_matcher_gives_identical_results() {
    let (l, r) = (image(50, 70, 1), image(50, 70, 2));
    let p = WtaParams {
        min_disp: 2,
        ndisp: 9,
        block: 3,
        gray_bits: 8,
        min_filter: 3,
        uniqueness: 0,
        subpixel: true,
    };
    let mut m = WtaMatcher::new();
    let mut a = DisparityMap::new(50, 70, 0.0);
    let mut b = DisparityMap::new(50, 70, 0.0);
    m.compute_into(&l, &r, &p, &mut a);
    m.compute_into(&l, &r, &p, &mut b);
    assert_eq!(a, b);
}

#[test]
fn right_map_equals_matching_the_mirrored_pair_inside() {
    let (w, h) = (90, 30);
    let right = image(w, h, 3);
    let left = Samples::from_fn(w, h, |x, y| right.get(x.saturating_sub(5 + y % 3), y));
    let p = WtaParams {
        min_disp: 1,
        ndisp: 20,
        block: 5,
        gray_bits: 8,
        min_filter: 0,
        uniqueness: 0,
        subpixel: false,
    };
    let mirrored = {
        let (fl, fr) = (crate::refine::flip(&right), crate::refine::flip(&left));
        let mut d = DisparityMap::new(w, h, 0.0);
        WtaMatcher::new().compute_into(&fl, &fr, &p, &mut d);
        crate::refine::flip(&d)
    };
    for mut matcher in KERNELS.map(WtaMatcher::with_kernel) {
        let (mut l, mut r) = (DisparityMap::new(w, h, 0.0), DisparityMap::new(w, h, 0.0));
        matcher.compute_both_into(&left, &right, &p, &mut l, &mut r);
        let mut plain = DisparityMap::new(w, h, 0.0);
        matcher.compute_into(&left, &right, &p, &mut plain);
        assert_eq!(l, plain);
        // Windows that stay inside both views on both sides agree.
        for y in 0..h {
            for x in 3..w - 3 - 21 {
                assert_eq!(r.get(x, y), mirrored.get(x, y), "({x}, {y})");
            }
            // No left pixel lies right of the last right columns' match.
            assert_eq!(r.get(w - 1, y), f32::INFINITY);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    /// The check inside the pass equals the right view's map and
    /// `refine::lr_check` at tolerances below one pixel, with every
    /// kernel, min filter and uniqueness test; on pairs with few gray
    /// levels (ties between disparities are frequent).
    #[test]
    fn the_check_in_the_pass_equals_the_lr_check(
        w in 1usize..70, h in 1usize..12, seed in any::<u64>(), shift in 0usize..9,
        min_disp in 0usize..4, ndisp in 1usize..40, half in 0usize..4,
        min_filter in prop_oneof![Just(0usize), Just(3)],
        uniqueness in prop_oneof![Just(0u32), Just(15u32)], tol in 0f32..1.0,
    ) {
        let right = levels_view(w, h, seed, 4);
        let left = Samples::from_fn(w, h, |x, y| right.get(x.saturating_sub(shift + y % 2), y));
        let p = WtaParams {
            min_disp, ndisp, block: 2 * half + 1, gray_bits: 8, min_filter,
            uniqueness, subpixel: false,
        };
        for mut matcher in KERNELS.map(WtaMatcher::with_kernel) {
            let (mut want, mut r) = (DisparityMap::new(w, h, 0.0), DisparityMap::new(w, h, 0.0));
            matcher.compute_both_into(&left, &right, &p, &mut want, &mut r);
            crate::refine::lr_check(&mut want, &r, tol);
            let mut got = DisparityMap::new(w, h, 0.0);
            matcher.compute_checked_into(&left, &right, &p, &mut got);
            prop_assert_eq!(&got, &want);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    /// The AVX2 loop of the default setting (no min filter, no right
    /// map; its own up to 96 lanes) equals the general loop of the
    /// portable kernel, with and without the check in the pass, on
    /// pairs with few gray levels (frequent ties) at every width
    /// against the lanes.
    #[test]
    fn avx2_default_loop_equals_the_general_loop(
        w in 1usize..140, h in 1usize..10, seed in any::<u64>(), shift in 0usize..40,
        min_disp in 0usize..5, ndisp in 1usize..97, half in 0usize..6,
        uniqueness in prop_oneof![Just(0u32), Just(15u32)], subpixel in any::<bool>(),
    ) {
        let right = levels_view(w, h, seed, 5);
        let left = Samples::from_fn(w, h, |x, y| right.get(x.saturating_sub(shift + y % 3), y));
        let p = WtaParams {
            min_disp, ndisp, block: 2 * half + 1, gray_bits: 8, min_filter: 0,
            uniqueness, subpixel,
        };
        let (mut fast, mut general) = (WtaMatcher::new(), WtaMatcher::portable());
        let run = |m: &mut WtaMatcher, checked: bool| {
            let mut out = DisparityMap::new(w, h, 0.0);
            if checked {
                m.compute_checked_into(&left, &right, &p, &mut out);
            } else {
                m.compute_into(&left, &right, &p, &mut out);
            }
            out.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        };
        prop_assert_eq!(run(&mut fast, false), run(&mut general, false));
        if !subpixel {
            prop_assert_eq!(run(&mut fast, true), run(&mut general, true));
        }
    }
}

/// A segmented-looking view: three gray levels in blocks, so that
/// rows repeat and the SWAR kernel's general band loop skips the
/// columns they leave alike.
fn blocks(w: usize, h: usize, seed: u64) -> Samples {
    Samples::from_fn(w, h, |x, y| {
        let v = ((x / 5) as u64 * 31 + (y / 7) as u64 * 17) ^ seed;
        [20, 130, 240][(v.wrapping_mul(0x9E37_79B9) >> 9) as usize % 3]
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    /// Every kernel equals the naive definition on blocky pairs: the
    /// SWAR kernel's board loop (no min filter) and its general loop,
    /// where the skipping of alike rows takes part (with one).
    #[test]
    fn kernels_equal_reference_on_blocks(
        w in 1usize..60, h in 1usize..40, seed in any::<u64>(), shift in 0usize..6,
        min_disp in 0usize..3, ndisp in 1usize..20, half in 0usize..5,
        min_filter in prop_oneof![Just(0usize), Just(3)],
    ) {
        let right = blocks(w, h, seed);
        let left = Samples::from_fn(w, h, |x, y| right.get(x.saturating_sub(shift), y));
        let p = WtaParams {
            min_disp, ndisp, block: 2 * half + 1, gray_bits: 8, min_filter,
            uniqueness: 0, subpixel: false,
        };
        let slow = reference(&left, &right, &p);
        for kernel in KERNELS {
            let mut levels = Levels::new(w, h, 0);
            WtaMatcher::with_kernel(kernel).compute_levels_into(&left, &right, &p, &mut levels);
            prop_assert_eq!(&levels_to_disparity(&levels), &slow, "{:?}", kernel);
        }
    }
}

/// A segmented-looking view of `levels` gray values (8 bits) in
/// blocks of random sizes.
fn levels_view(w: usize, h: usize, seed: u64, levels: u16) -> Samples {
    let (bw, bh) = (2 + seed as usize % 9, 1 + (seed >> 8) as usize % 6);
    Samples::from_fn(w, h, |x, y| {
        let v = ((x / bw) as u64 * 0x9E37_79B9) ^ ((y / bh) as u64 * 0x85EB_CA6B) ^ seed;
        let l = (v.wrapping_mul(0xC2B2_AE35) >> 13) as u16 % levels;
        l * (255 / levels.max(2)) + (seed >> 20) as u16 % 7
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]
    /// The SWAR kernel in the board's setting (no min filter, 16 or 32
    /// disparities, few gray levels: its column sums come from tables,
    /// and from the direct path when a row has more values than table
    /// slots) equals the naive definition.
    #[test]
    fn swar_board_setting_equals_reference(
        w in 33usize..110, h in 1usize..30, seed in any::<u64>(), shift in 0usize..12,
        min_disp in 0usize..3, wide in any::<bool>(), half in 0usize..8,
        levels in 1u16..12, subpixel in any::<bool>(),
    ) {
        let right = levels_view(w, h, seed, levels);
        let left = Samples::from_fn(w, h, |x, y| right.get(x.saturating_sub(shift + y % 2), y));
        let p = WtaParams {
            min_disp, ndisp: if wide { 32 } else { 16 }, block: 2 * half + 1, gray_bits: 8,
            min_filter: 0, uniqueness: 0, subpixel,
        };
        let slow = reference(&left, &right, &p);
        let mut matcher = WtaMatcher::with_kernel(Kernel::Swar);
        let mut fast = DisparityMap::new(w, h, 0.0);
        matcher.compute_into(&left, &right, &p, &mut fast);
        let bits = |m: &DisparityMap| m.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        prop_assert_eq!(bits(&fast), bits(&slow));
        if !subpixel {
            let mut levels = Levels::new(w, h, 0);
            matcher.compute_levels_into(&left, &right, &p, &mut levels);
            prop_assert_eq!(&levels_to_disparity(&levels), &slow);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    /// Both kernels (AVX2 where present, and portable) equal the naive
    /// definition, at every gray precision and min filter size.
    #[test]
    fn fast_equals_reference(
        w in 1usize..40, h in 1usize..40, seed in any::<u64>(),
        min_disp in 0usize..4, ndisp in 1usize..12, half in 0usize..8,
        gray_bits in 8u32..=10, min_filter in prop_oneof![Just(0usize), Just(1), Just(3), Just(5)],
        subpixel in any::<bool>(), uniqueness in prop_oneof![Just(0u32), Just(15u32)],
    ) {
        let (l, r) = (noise(w, h, seed, gray_bits), noise(w, h, seed ^ 0xABCD, gray_bits));
        let block = (2 * half + 1).min(WtaParams::max_block(gray_bits));
        let p = WtaParams { min_disp, ndisp, block, gray_bits, min_filter, uniqueness, subpixel };
        let slow = reference(&l, &r, &p);
        let bits = |m: &DisparityMap| m.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        for mut matcher in KERNELS.map(WtaMatcher::with_kernel) {
            let mut fast = DisparityMap::new(w, h, 0.0);
            matcher.compute_into(&l, &r, &p, &mut fast);
            prop_assert_eq!(bits(&fast), bits(&slow));
            if !subpixel {
                let mut levels = Levels::new(w, h, 0);
                matcher.compute_levels_into(&l, &r, &p, &mut levels);
                prop_assert_eq!(bits(&levels_to_disparity(&levels)), bits(&slow));
            }
        }
    }
}
