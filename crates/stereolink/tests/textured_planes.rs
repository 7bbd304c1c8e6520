//! The plane matcher on heavily textured pairs, through the library call
//! `stereolink match --algo planes` makes: the left view's mean shift
//! over-segmentation, then the planes. Pixel noise gave the mean shift more
//! than 65536 regions, which stopped `match` with "invalid parameter: more
//! than 65536 segments"; now it must return a map, and a good one.

use stereolink_image::metrics::bad_pixel_rate;
use stereolink_image::{DisparityMap, Mask, RgbImage};
use stereolink_pipeline::planes::{disparity, Segments};
use stereolink_stereo::{Algorithm, MatchSpec, Matcher};

/// A fronto-parallel rectangle or ellipse at a constant disparity.
struct Object {
    inside: fn(f32, f32) -> bool,
    disparity: f32,
}

/// A pair of pixel-noise surfaces (a new colour every pixel, bilinear
/// between pixels so the right view can sample it at fractional
/// positions): a slanted background `d = 6 + 14·x/W + 4·y/H` and two
/// objects in front, with the left ground truth and its non-occluded mask.
fn textured_pair(w: usize, h: usize, seed: u64) -> (RgbImage, RgbImage, DisparityMap, Mask) {
    let objects = [
        Object {
            inside: |x, y| (150.0..330.0).contains(&x) && (90.0..260.0).contains(&y),
            disparity: 40.0,
        },
        Object {
            inside: |x, y| ((x - 95.0) / 60.0).powi(2) + ((y - 270.0) / 70.0).powi(2) <= 1.0,
            disparity: 28.0,
        },
    ];
    let (wf, hf) = (w as f32, h as f32);
    let background = |x: f32, y: f32| 6.0 + 14.0 * x / wf + 4.0 * y / hf;
    let noise = |surface: u64, x: i64, y: usize| -> [f32; 3] {
        let mut z = seed ^ surface.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        z ^= (x as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9)
            ^ (y as u64).wrapping_mul(0x94D0_49BB_1331_11EB);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        [0, 1, 2].map(|k| (z >> (8 * k)) as u8 as f32)
    };
    let texture = |surface: u64, x: f32, y: usize| -> [u8; 3] {
        let (i, f) = (x.floor() as i64, x - x.floor());
        let (a, b) = (noise(surface, i, y), noise(surface, i + 1, y));
        [0, 1, 2].map(|k| (a[k] + f * (b[k] - a[k])).round() as u8)
    };
    // The left view's surface and disparity at (x, y).
    let left_surface = |x: f32, y: f32| -> (u64, f32) {
        for (i, o) in objects.iter().enumerate() {
            if (o.inside)(x, y) {
                return (i as u64 + 1, o.disparity);
            }
        }
        (0, background(x, y))
    };
    // The right view's surface at (xr, y), the left x it shows, nearest first.
    let right_surface = |xr: f32, y: f32| -> (u64, f32) {
        for (i, o) in objects.iter().enumerate() {
            if (o.inside)(xr + o.disparity, y) {
                return (i as u64 + 1, xr + o.disparity);
            }
        }
        // x − (6 + 14·x/W + 4·y/H) = xr.
        (0, (xr + 6.0 + 4.0 * y / hf) / (1.0 - 14.0 / wf))
    };
    let left = RgbImage::from_fn(w, h, |x, y| {
        texture(left_surface(x as f32, y as f32).0, x as f32, y)
    });
    let right = RgbImage::from_fn(w, h, |x, y| {
        let (s, xl) = right_surface(x as f32, y as f32);
        texture(s, xl, y)
    });
    let gt = DisparityMap::from_fn(w, h, |x, y| left_surface(x as f32, y as f32).1);
    let nonocc = Mask::from_fn(w, h, |x, y| {
        let (s, d) = left_surface(x as f32, y as f32);
        let xr = x as f32 - d;
        xr >= 0.0 && right_surface(xr, y as f32).0 == s
    });
    (left, right, gt, nonocc)
}

/// 450x375, 48 disparities (`--max-disp 47`), as the failing pairs were:
/// these stopped with the error before the mean shift capped its regions
/// (the over-segmentation now has 65536 labels). Measured on seeds 1–3:
/// bad > 1 px non-occluded 0.18 / 0.18 / 0.15 %, 2.7–3.7 s each (release,
/// two busy cores); SGM alone gives 0.05 / 0.05 / 0.03 % on such ideal
/// texture.
#[test]
fn planes_match_heavily_textured_pairs() {
    let spec = MatchSpec::new(Algorithm::Planes, 0, 47).unwrap();
    for seed in 1..=3 {
        let (left, right, gt, nonocc) = textured_pair(450, 375, seed);
        let d = disparity(
            &mut Matcher::new(),
            (&left, &right),
            &spec,
            &Segments::OverSegmentation,
        )
        .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
        assert_eq!(d.dims(), (450, 375));
        let bad = bad_pixel_rate(&d, &gt, Some(&nonocc), 1.0).unwrap();
        eprintln!("seed {seed}: bad > 1 px non-occluded {bad:.2} %");
        assert!(bad < 1.0, "seed {seed}: {bad:.2} % bad");
    }
}
