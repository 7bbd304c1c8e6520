//! Tests of the weighted median: both kernels against a pixel-by-pixel
//! definition ([`naive`]), and the parameters' and weights' ranges.

use super::*;

#[test]
fn a_disparity_edge_snaps_to_the_colour_edge() {
    // Colour edge at x = 10; the disparity edge is fattened to x = 12.
    let guide = RgbImage::from_fn(
        24,
        8,
        |x, _| if x < 10 { [200, 40, 40] } else { [20, 20, 90] },
    );
    let map = DisparityMap::from_fn(24, 8, |x, _| if x < 12 { 9.0 } else { 3.0 });
    let p = WeightedMedian {
        radius: 4,
        color_reach: 30,
        step: 1,
    };
    let out = weighted_median(&map, &guide, &p);
    for x in 0..24 {
        assert_eq!(out.get(x, 4), if x < 10 { 9.0 } else { 3.0 }, "x = {x}");
    }
}

#[test]
fn holes_take_their_neighbours_and_subpixel_values_stay() {
    let guide = RgbImage::new(9, 9, [50, 50, 50]);
    let mut map = DisparityMap::from_fn(9, 9, |x, _| if x % 2 == 0 { 4.25 } else { 3.9 });
    map.set(4, 4, f32::INFINITY);
    let out = weighted_median(&map, &guide, &WeightedMedian::DEFAULT);
    assert!(out
        .as_slice()
        .iter()
        .all(|&d| d == 4.0 || d == 4.25 || d == 3.9));
    assert_eq!(out.get(4, 4), 4.0);
    assert_eq!(out.get(2, 2), 4.25);
    let empty = DisparityMap::new(5, 5, f32::INFINITY);
    assert_eq!(
        weighted_median(
            &empty,
            &RgbImage::new(5, 5, [0; 3]),
            &WeightedMedian::DEFAULT
        ),
        empty
    );
}

/// The definition, pixel by pixel, in `u32`; if `borders`, only valid
/// pixels with an invalid 8-neighbour take the median.
fn naive(map: &DisparityMap, guide: &RgbImage, p: &WeightedMedian, borders: bool) -> DisparityMap {
    let (w, h) = map.dims();
    let finite: Vec<f32> = map
        .as_slice()
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .collect();
    let Some(lo) = finite.iter().map(|d| d.round()).reduce(f32::min) else {
        return map.clone();
    };
    let r = p.radius as isize;
    let at = |x: isize, y: isize| {
        (
            x.clamp(0, w as isize - 1) as usize,
            y.clamp(0, h as isize - 1) as usize,
        )
    };
    DisparityMap::from_fn(w, h, |x, y| {
        let next_to_hole = (-1..=1).any(|dy| {
            (-1..=1).any(|dx| {
                let (qx, qy) = at(x as isize + dx, y as isize + dy);
                !map.get(qx, qy).is_finite()
            })
        });
        if borders && !(map.get(x, y).is_finite() && next_to_hole) {
            return map.get(x, y);
        }
        let c = guide.get(x, y);
        let mut hist = vec![0u32; 70_000];
        let mut used = Vec::new();
        let n = (2 * p.radius / p.step + 1).pow(2);
        let peak = u32::from(p.color_reach).pow(2);
        let shift = (0..).find(|&s| n as u32 * (peak >> s) <= 65535).unwrap();
        for dy in (-r..=r).step_by(p.step) {
            for dx in (-r..=r).step_by(p.step) {
                let (qx, qy) = at(x as isize + dx, y as isize + dy);
                let d = map.get(qx, qy);
                if !d.is_finite() {
                    continue;
                }
                let q = guide.get(qx, qy);
                let diff: u32 = (0..3).map(|k| c[k].abs_diff(q[k]) as u32).sum();
                let wt = u32::from(p.color_reach).saturating_sub(diff).pow(2) >> shift;
                if wt == 0 {
                    continue;
                }
                let b = (d.round() - lo) as usize;
                hist[b] += wt;
                used.push(b);
            }
        }
        let own = map.get(x, y);
        let (Some(&a), Some(&b)) = (used.iter().min(), used.iter().max()) else {
            return own;
        };
        let total: u32 = hist[a..=b].iter().sum();
        let mut acc = 0;
        let median = (a..=b)
            .find(|&k| {
                acc += hist[k];
                2 * acc >= total
            })
            .unwrap_or(b);
        if own.is_finite() && (own.round() - lo) as usize == median {
            own
        } else {
            lo + median as f32
        }
    })
}

/// A xorshift generator seeded with `seed`.
fn xorshift(seed: u64) -> impl FnMut() -> u64 {
    let mut s = seed | 1;
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    }
}

/// Both paths (AVX2 where the CPU has it, and the portable one) give
/// the definition's map, bit for bit, with holes filled and kept.
fn as_defined(
    map: &DisparityMap,
    guide: &RgbImage,
    p: &WeightedMedian,
) -> Result<(), proptest::test_runner::TestCaseError> {
    let bits = |m: &DisparityMap| m.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    let want = bits(&naive(map, guide, p, false));
    proptest::prop_assert_eq!(bits(&weighted_median(map, guide, p)), want.clone());
    let mut portable = WeightedMedianGuide::with_avx2(guide, p, false);
    let mut out = DisparityMap::default();
    portable.filter(map, &mut out);
    proptest::prop_assert_eq!(bits(&out), want);
    let want = bits(&naive(map, guide, p, true));
    WeightedMedianGuide::new(guide, p).filter_borders(map, &mut out);
    proptest::prop_assert_eq!(bits(&out), want.clone());
    portable.filter_borders(map, &mut out);
    proptest::prop_assert_eq!(bits(&out), want);
    Ok(())
}

proptest::proptest! {
    #[test]
    /// Both kernels, as the definition computes it.
    fn equals_the_definition(
        w in 1usize..30, h in 1usize..30, seed in proptest::prelude::any::<u64>(),
        radius in 1usize..6, step in 1usize..4, reach in 1u8..=255,
    ) {
        let mut next = xorshift(seed);
        let guide = RgbImage::from_fn(w, h, |_, _| {
            let v = next();
            [v as u8 & 0xF0, (v >> 8) as u8, (v >> 16) as u8 & 0xC0]
        });
        let map = DisparityMap::from_fn(w, h, |x, y| match (x * 7 + y * 13 + seed as usize) % 11 {
            0 => f32::INFINITY,
            k => 3.0 + (k % 4) as f32 + if x > w / 2 { 0.25 } else { 0.0 },
        });
        let p = WeightedMedian { radius, color_reach: reach, step: step.min(radius) };
        as_defined(&map, &guide, &p)?;
    }

    #[test]
    /// Smooth colours and disparities (most pixels settled by the fast
    /// test on `c`, `c − 1` or `c + 1`), with steps of either and holes
    /// in runs, over ranges of more than 64 bins, the default window
    /// and large ones (961 samples, shifted weights): as defined.
    fn equals_the_definition_on_smooth_maps(
        w in 1usize..48, h in 1usize..40, seed in proptest::prelude::any::<u64>(),
        radius in 1usize..16, step in 1usize..5, reach in 1u8..=255, span in 1f32..200.0,
    ) {
        let mut next = xorshift(seed);
        let edge = (seed % 29) as usize;
        let guide = RgbImage::from_fn(w, h, |x, y| {
            let n = (next() % 9) as u8;
            if x < edge { [40 + n, 90 + (y as u8 & 15), 30] } else { [200 - n, 60, 120 + n] }
        });
        let hole = |x: usize, y: usize| (x / 3 + y * 5 + seed as usize) % 7 == 0;
        let map = DisparityMap::from_fn(w, h, |x, y| {
            if hole(x, y) {
                return f32::INFINITY;
            }
            let slant = span * (x + y) as f32 / (w + h) as f32;
            let jitter = (next() % 3) as f32 - 1.0;
            let base = if x + 2 < edge { 2.0 * span } else { 0.0 };
            base + slant.round() + jitter + if (x ^ y) & 4 == 0 { 0.5 } else { 0.0 }
        });
        let p = WeightedMedian { radius, color_reach: reach, step: step.min(radius) };
        as_defined(&map, &guide, &p)?;
    }
}

#[test]
fn a_rebuilt_guide_filters_as_a_new_one() {
    let view = |w: usize, h: usize, seed: u64| {
        let mut next = xorshift(seed);
        RgbImage::from_fn(w, h, |_, _| {
            let v = next();
            [v as u8, (v >> 8) as u8 & 0xE0, (v >> 16) as u8]
        })
    };
    let map = DisparityMap::from_fn(37, 21, |x, y| match (x * 5 + y * 3) % 13 {
        0 => f32::INFINITY,
        k => (k % 5) as f32 + if y > 10 { 0.5 } else { 0.0 },
    });
    let guide = view(37, 21, 9);
    let p = WeightedMedian::DEFAULT;
    let (mut fresh, mut reused) = (DisparityMap::default(), DisparityMap::default());
    WeightedMedianGuide::new(&guide, &p).filter(&map, &mut fresh);
    // Built first for another size and other parameters, and used.
    let other = WeightedMedian {
        radius: 3,
        color_reach: 9,
        step: 1,
    };
    let mut g = WeightedMedianGuide::new(&view(50, 40, 2), &other);
    g.filter(&DisparityMap::new(50, 40, 3.0), &mut reused);
    g.rebuild(&guide, &p);
    g.filter(&map, &mut reused);
    assert_eq!(reused, fresh);
    assert_eq!(fresh, naive(&map, &guide, &p, false));
    // Built for a wider window, then set to this one: the same too.
    let mut wide = WeightedMedianGuide::new(&guide, &p.before_fill());
    wide.set_window(&p);
    wide.filter(&map, &mut reused);
    assert_eq!(reused, fresh);
    wide.filter_borders(&map, &mut reused);
    assert_eq!(reused, naive(&map, &guide, &p, true));
}

#[test]
fn a_window_of_weights_fits_sixteen_bits() {
    for (reach, n) in [(150, 25), (255, 961), (255, 1), (1, 961), (40, 9)] {
        let s = weight_shift(reach, n);
        let peak = weight([0; 3], [0; 3], reach, s);
        assert_eq!(u32::from(peak), u32::from(reach).pow(2) >> s);
        assert!(n * usize::from(peak) <= 65535 && peak >= 1, "{reach} {n}");
        // The smallest such shift.
        assert!(s == 0 || n as u32 * (u32::from(reach).pow(2) >> (s - 1)) > 65535);
    }
    // Saturating colour differences: beyond the reach, no weight.
    assert_eq!(weight([255; 3], [0; 3], 255, 0), 0);
    assert_eq!(weight([10, 0, 0], [0, 0, 0], 12, 0), 4);
}

#[test]
fn bad_parameters_are_errors() {
    let ok = WeightedMedian::DEFAULT;
    assert_eq!(ok.validate(), Ok(()));
    for bad in [
        WeightedMedian { radius: 0, ..ok },
        WeightedMedian { radius: 16, ..ok },
        WeightedMedian {
            color_reach: 0,
            ..ok
        },
        WeightedMedian { step: 0, ..ok },
        WeightedMedian { step: 11, ..ok },
    ] {
        assert!(bad.validate().is_err(), "{bad:?}");
    }
}

#[test]
fn the_pass_before_a_fill_takes_nine_samples_of_a_wider_window() {
    let before = WeightedMedian::DEFAULT.before_fill();
    assert_eq!(
        before,
        WeightedMedian {
            radius: 9,
            step: 9,
            ..WeightedMedian::DEFAULT
        }
    );
    // Valid for every valid radius (at most 15 wide each way).
    for radius in 1..=15 {
        let p = WeightedMedian {
            radius,
            step: 1,
            ..WeightedMedian::DEFAULT
        };
        let b = p.before_fill();
        assert_eq!(b.validate(), Ok(()), "{b:?}");
        assert_eq!(b.radius, (3 * radius / 2).clamp(1, 15));
    }
    // The window's centre, corners and edge midpoints.
    let g = WeightedMedianGuide::new(&RgbImage::new(40, 40, [9; 3]), &before);
    assert_eq!(g.offsets.len(), 9);
}
