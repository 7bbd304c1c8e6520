//! Tests of SGM: the AVX2 kernels against the portable ones, bit for bit,
//! and the path step against its recurrence.

use super::aggregate::{cell, step};
use super::cost::cost_row;
use super::*;

/// The AVX2 cost rows equal the portable ones (Hamming distances).
#[test]
fn avx2_cost_rows_equal_portable_rows() {
    if !stereolink_image::cpu::avx2() {
        return;
    }
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s & ((1 << 62) - 1)
    };
    for (w, nd, min_disp) in [(1, 1, 0), (7, 3, 0), (40, 33, 2), (70, 64, 0), (100, 90, 5)] {
        let np = usize::next_multiple_of(nd, BLOCK);
        let l: Vec<u64> = (0..w).map(|_| next()).collect();
        let r: Vec<u64> = (0..w).map(|_| next()).collect();
        let (mut a, mut b) = (vec![0u8; w * np], vec![1u8; w * np]);
        cost_row(&l, &r, min_disp, nd, &mut a, false);
        cost_row(&l, &r, min_disp, nd, &mut b, true);
        assert_eq!(a, b, "w {w} nd {nd}");
        let x = w - 1;
        if x >= min_disp {
            assert_eq!(u32::from(a[x * np]), (l[x] ^ r[x - min_disp]).count_ones());
        }
    }
}

/// Whole SGM runs, AVX2 against portable, bit for bit, on random views
/// of awkward sizes and ranges (a few pixels, ranges past a block).
#[test]
fn avx2_and_portable_sgm_agree() {
    if !stereolink_image::cpu::avx2() {
        return;
    }
    let mut s = 0x1234_5678_9ABC_DEF1u64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    let cases = [
        (2, 1, 0, 1, 8),
        (5, 3, 1, 3, 4),
        (37, 9, 0, 35, 8),
        (70, 6, 3, 40, 8),
    ];
    for (w, h, min_disp, max_disp, paths) in cases {
        let left = GrayImage::from_fn(w, h, |_, _| (next() >> 58) as u8 * 16);
        let right = GrayImage::from_fn(w, h, |_, _| (next() >> 58) as u8 * 16);
        let mut spec = MatchSpec::new(crate::Algorithm::Sgm, min_disp, max_disp).unwrap();
        spec.sgm.paths = paths;
        let mut buffers = SgmBuffers::default();
        let a = sgm_with(&left, &right, &spec, &mut buffers, false);
        let b = sgm_with(&left, &right, &spec, &mut buffers, true);
        let bits = |m: &DisparityMap| m.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(&a.disparity),
            bits(&b.disparity),
            "{w}x{h} {min_disp}..={max_disp}"
        );
        let (ar, br) = (a.right.unwrap(), b.right.unwrap());
        assert_eq!(bits(&ar), bits(&br));
    }
}

#[test]
fn step_follows_the_recurrence() {
    // From the zero cell a path starts at its costs: L = C.
    let mut prev = [SENTINEL; cell(3)];
    let mut acc = [0; 3];
    step::<true>(&[0; cell(3)], &[5, 0, 9], &mut prev, &mut acc, 2, 6);
    assert_eq!(prev, [SENTINEL, 5, 0, 9, SENTINEL, 0]);
    assert_eq!(acc, [5, 0, 9]);
    let cost = [3, 3, 3];
    let mut cur = [0; cell(3)];
    let mut acc = [10; 3];
    step::<false>(&prev, &cost, &mut cur, &mut acc, 2, 6);
    // min_prev 0: k0 min(5, 0+2, jump 6) = 2 → 3+2; k1: 0 → 3; k2: min(9, 0+2) = 2 → 5.
    assert_eq!(cur, [0, 5, 3, 5, 0, 3]);
    assert_eq!(acc, [15, 13, 15]);
    step::<true>(&prev, &cost, &mut cur, &mut acc, 2, 6);
    assert_eq!(acc, [5, 3, 5]);
}

/// The AVX2 pixel kernel equals one portable step per path, on cells
/// that paths can reach (built by stepping from random costs).
#[cfg(target_arch = "x86_64")]
#[test]
fn avx2_pixel_steps_equal_portable_steps() {
    if !stereolink_image::cpu::avx2() {
        return;
    }
    fn steps(
        prev: &[Vec<u8>],
        cur: &mut [Vec<u8>],
        acc: &mut [u16],
        cost: &[u8],
        p1: u8,
    ) -> super::aggregate::PixelSteps<4> {
        super::aggregate::PixelSteps {
            prev: std::array::from_fn(|p| prev[p].as_ptr()),
            cur: std::array::from_fn(|p| cur[p].as_mut_ptr()),
            p2: [90, 40, 193, 30],
            p1,
            np: cost.len(),
            cost: cost.as_ptr(),
            acc: acc.as_mut_ptr(),
        }
    }
    let mut s = 0x2545_F491_4F6C_DD1Du64;
    let mut costs = |nd: usize, np: usize| -> Vec<u8> {
        let mut c: Vec<u8> = (0..nd)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s % 63) as u8
            })
            .collect();
        c.resize(np, PAD);
        c
    };
    for (nd, p1) in [
        (1usize, 3u8),
        (5, 24),
        (31, 1),
        (32, 29),
        (33, 7),
        (64, 24),
        (100, 12),
    ] {
        let np = nd.next_multiple_of(BLOCK);
        // Four reachable previous cells: a few steps from the zero cell.
        let prev: Vec<Vec<u8>> = (0..4)
            .map(|p| {
                let mut now = vec![0u8; cell(np)];
                for _ in 0..=p {
                    let mut out = vec![SENTINEL; cell(np)];
                    step::<true>(&now, &costs(nd, np), &mut out, &mut vec![0; np], p1, 90);
                    now = out;
                }
                now
            })
            .collect();
        let cost = costs(nd, np);
        for first in [false, true] {
            let (mut cur_a, mut acc_a) = (vec![vec![SENTINEL; cell(np)]; 4], vec![7u16; np]);
            let (mut cur_b, mut acc_b) = (cur_a.clone(), acc_a.clone());
            let a = steps(&prev, &mut cur_a, &mut acc_a, &cost, p1);
            let b = steps(&prev, &mut cur_b, &mut acc_b, &cost, p1);
            // SAFETY: AVX2 was detected above; whole cells and lanes.
            unsafe {
                if first {
                    a.run::<true>();
                    b.run_avx2::<true>();
                } else {
                    a.run::<false>();
                    b.run_avx2::<false>();
                }
            }
            assert_eq!((cur_a, acc_a), (cur_b, acc_b), "nd {nd}, first {first}");
        }
    }
}

#[test]
fn bad_penalties_are_rejected() {
    assert!(SgmParams {
        paths: 6,
        ..Default::default()
    }
    .validate()
    .is_err());
    assert!(SgmParams {
        p1: 10,
        p2: 5,
        ..Default::default()
    }
    .validate()
    .is_err());
}
