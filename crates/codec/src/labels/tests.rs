//! Round trips in both modes, alone and conditioned; the fast mode's runs
//! against its per-pixel definition; garbage input; the golden streams of
//! `docs/wire-format.md`; and what the channel models and the conditioning
//! buy.

use proptest::prelude::*;

use super::pixel::code_pixel;
use super::template::{is_flat, own_template};
use super::*;

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
