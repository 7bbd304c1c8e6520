use std::path::PathBuf;

use nalgebra::{Matrix3, Point2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use stereolink_image::GrayImage;

use super::*;

const BOARD: BoardSize = BoardSize::new(9, 6);

/// A rendered board: the image and the true corners in the documented order.
struct Rendered {
    image: GrayImage,
    corners: Vec<Point2<f64>>,
}

/// How a board is imaged: lighting (a gain per pixel), optical blur (the
/// standard deviation of a Gaussian PSF, px) and uniform noise (± gray
/// levels).
struct Imaging<L: Fn(usize, usize) -> f64> {
    light: L,
    psf: f64,
    noise: f64,
    seed: u64,
}

/// Even light, a mild PSF (real lenses and sensors are not sharper than
/// about 0.7 px) and ±4 levels of noise.
fn camera(seed: u64) -> Imaging<fn(usize, usize) -> f64> {
    Imaging {
        light: |_, _| 1.0,
        psf: 0.7,
        noise: 4.0,
        seed,
    }
}

/// Renders a `pattern` board with squares of side 1 and the outer square
/// (0,0) dark, mapped by `h` (board units → pixels), 8x8 supersampled, with
/// a one-square white margin on a mid-gray background, then imaged.
fn render<L: Fn(usize, usize) -> f64>(
    pattern: BoardSize,
    h: Matrix3<f64>,
    (width, height): (usize, usize),
    imaging: &Imaging<L>,
) -> Rendered {
    let inv = h.try_inverse().expect("invertible homography");
    let (sq_w, sq_h) = ((pattern.cols + 1) as f64, (pattern.rows + 1) as f64);
    let shade = |x: f64, y: f64| {
        let b = inv * Vector3::new(x, y, 1.0);
        let (u, v) = (b.x / b.z, b.y / b.z);
        if b.z <= 0.0 || u < -1.0 || v < -1.0 || u > sq_w + 1.0 || v > sq_h + 1.0 {
            120.0
        } else if u < 0.0 || v < 0.0 || u >= sq_w || v >= sq_h {
            220.0
        } else if (u.floor() as i64 + v.floor() as i64) % 2 == 0 {
            30.0
        } else {
            220.0
        }
    };
    const SS: usize = 8;
    let clean = GrayImage::from_fn(width, height, |x, y| {
        let mut sum = 0.0;
        for sy in 0..SS {
            for sx in 0..SS {
                let px = x as f64 + (sx as f64 + 0.5) / SS as f64 - 0.5;
                let py = y as f64 + (sy as f64 + 0.5) / SS as f64 - 0.5;
                sum += shade(px, py);
            }
        }
        (sum / (SS * SS) as f64 * (imaging.light)(x, y)).round() as u8
    });
    let blurred = saddle::smooth(&clean, imaging.psf);
    let mut rng = ChaCha8Rng::seed_from_u64(imaging.seed);
    let image = GrayImage::from_fn(width, height, |x, y| {
        let noise = imaging.noise * (rng.gen::<f64>() - 0.5) * 2.0;
        (blurred.pixel(x as isize, y as isize) + noise)
            .round()
            .clamp(0.0, 255.0) as u8
    });
    let corners = (0..pattern.count())
        .map(|k| {
            let b = h * Vector3::new(
                (k % pattern.cols + 1) as f64,
                (k / pattern.cols + 1) as f64,
                1.0,
            );
            Point2::new(b.x / b.z, b.y / b.z)
        })
        .collect();
    Rendered { image, corners }
}

/// A homography: board units scaled by `scale`, rotated by `angle`, shifted
/// to `(tx, ty)`, with perspective terms `(px, py)`.
fn homography(scale: f64, angle: f64, (tx, ty): (f64, f64), (px, py): (f64, f64)) -> Matrix3<f64> {
    let (s, c) = angle.sin_cos();
    Matrix3::new(
        scale * c,
        -scale * s,
        tx,
        scale * s,
        scale * c,
        ty,
        px,
        py,
        1.0,
    )
}

fn rms(a: &[Point2<f64>], b: &[Point2<f64>]) -> f64 {
    assert_eq!(a.len(), b.len());
    (a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).norm_squared())
        .sum::<f64>()
        / a.len() as f64)
        .sqrt()
}

#[test]
fn synthetic_board_is_found_to_subpixel_accuracy() {
    let h = homography(30.0, 0.1, (120.0, 90.0), (0.0, 0.0));
    let board = render(BOARD, h, (480, 360), &camera(1));
    let found = find_chessboard(&board.image, BOARD).expect("board found");
    let err = rms(&found, &board.corners);
    assert!(err < 0.05, "RMS error {err:.4} px");
}

#[test]
fn gradient_smoothing_removes_the_bias_of_perfectly_sharp_edges() {
    // Box-filtered edges nearly along the pixel axes alias: the gradient
    // directions wobble and bias cornerSubPix (OpenCV's too).
    let h = homography(30.0, 0.1, (120.0, 90.0), (0.0, 0.0));
    let imaging = Imaging {
        psf: 0.0,
        noise: 2.0,
        ..camera(2)
    };
    let board = render(BOARD, h, (480, 360), &imaging);
    let mut opencv = ChessboardOptions::default();
    opencv.subpix.sigma = 0.0;
    let plain = rms(
        &find_chessboard_with(&board.image, BOARD, &opencv).expect("found"),
        &board.corners,
    );
    let smoothed = rms(
        &find_chessboard(&board.image, BOARD).expect("found"),
        &board.corners,
    );
    assert!(plain < 0.1, "RMS error {plain:.4} px");
    assert!(
        smoothed < 0.05 && smoothed < plain,
        "RMS error {smoothed:.4} px, {plain:.4} px without"
    );
}

#[test]
fn tilted_rotated_and_upside_down_boards_keep_the_board_order() {
    // The order follows the board (dark outer square at corner 0), whatever
    // the rotation, including 180°, and under strong perspective.
    for (i, (angle, persp)) in [
        (0.6, (0.0005, 0.0)),
        (3.0, (0.0, 0.0008)),
        (-2.0, (-0.0006, 0.0004)),
    ]
    .into_iter()
    .enumerate()
    {
        let h = homography(26.0, angle, (320.0, 240.0), persp)
            * Matrix3::new(1.0, 0.0, -5.0, 0.0, 1.0, -3.5, 0.0, 0.0, 1.0);
        let h = h / h[(2, 2)];
        let board = render(BOARD, h, (640, 480), &camera(10 + i as u64));
        let found =
            find_chessboard(&board.image, BOARD).unwrap_or_else(|e| panic!("case {i}: {e}"));
        let err = rms(&found, &board.corners);
        assert!(err < 0.05, "case {i}: RMS error {err:.4} px");
    }
}

#[test]
fn blur_noise_and_lighting_gradient() {
    let h = homography(24.0, -0.3, (150.0, 160.0), (0.0003, -0.0002));
    // Four times darker on the left; the error bound follows the noise.
    for (noise, bound) in [(4.0, 0.1), (8.0, 0.25)] {
        let imaging = Imaging {
            light: |x: usize, _y: usize| 0.25 + 0.75 * x as f64 / 560.0,
            psf: 1.5,
            noise,
            seed: 7,
        };
        let board = render(BOARD, h, (560, 420), &imaging);
        let found = find_chessboard(&board.image, BOARD).expect("board found");
        let err = rms(&found, &board.corners);
        assert!(err < bound, "noise {noise}: RMS error {err:.4} px");
    }
}

#[test]
fn random_poses_are_found_in_board_order() {
    // Seeded random views: any rotation, 18–34 px squares, tilt, blur and
    // noise; each must be found, in the board's order, to 0.1 px.
    let mut rng = ChaCha8Rng::seed_from_u64(2026);
    for case in 0..16 {
        let scale = rng.gen_range(18.0..34.0);
        let angle = rng.gen_range(-std::f64::consts::PI..std::f64::consts::PI);
        let persp = (rng.gen_range(-6e-4..6e-4), rng.gen_range(-6e-4..6e-4));
        let h = homography(scale, angle, (320.0, 256.0), persp)
            * Matrix3::new(1.0, 0.0, -5.0, 0.0, 1.0, -3.5, 0.0, 0.0, 1.0);
        let imaging = Imaging {
            psf: rng.gen_range(0.5..1.2),
            noise: rng.gen_range(0.0..6.0),
            ..camera(case)
        };
        let board = render(BOARD, h / h[(2, 2)], (640, 512), &imaging);
        let found = find_chessboard(&board.image, BOARD)
            .unwrap_or_else(|e| panic!("case {case} (scale {scale:.1}, angle {angle:.2}): {e}"));
        let err = rms(&found, &board.corners);
        assert!(err < 0.1, "case {case}: RMS error {err:.4} px");
    }
}

#[test]
fn cluttered_noise_is_rejected_quickly() {
    // The work is bounded by max_candidates, not by what the image holds.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let noise = GrayImage::from_fn(640, 512, |_, _| if rng.gen::<bool>() { 0 } else { 255 });
    // Blobs a few pixels wide: saddles everywhere between them.
    let blobs = saddle::smooth(&noise, 2.5);
    let blobs = GrayImage::from_fn(640, 512, |x, y| {
        ((blobs.pixel(x as isize, y as isize) - 128.0) * 8.0 + 128.0).clamp(0.0, 255.0) as u8
    });
    for (name, image) in [("noise", noise), ("blobs", blobs)] {
        let start = std::time::Instant::now();
        assert!(find_chessboard(&image, BOARD).is_err(), "{name}");
        let took = start.elapsed();
        assert!(took.as_secs_f64() < 2.0, "{name} took {took:?}");
    }
}

#[test]
fn a_transposed_request_reads_the_board_by_columns() {
    let board = render(
        BOARD,
        homography(30.0, 0.2, (150.0, 80.0), (0.0, 0.0)),
        (480, 400),
        &camera(3),
    );
    let found = find_chessboard(&board.image, BOARD.transposed()).expect("board found");
    assert_eq!(found.len(), BOARD.count());
    for p in &found {
        let nearest = board
            .corners
            .iter()
            .map(|q| (p - q).norm())
            .fold(f64::INFINITY, f64::min);
        assert!(nearest < 0.2, "corner {p} is no board corner");
    }
    // 6 per row now: the first row runs along the board's first column.
    let u = found[1] - found[0];
    let v = found[6] - found[0];
    assert!(u.x * v.y - u.y * v.x > 0.0, "clockwise reading");
}

#[test]
fn a_symmetric_board_starts_nearest_the_top_left() {
    // 8x6: cols + rows even, so the colours cannot tell a board from its
    // 180° rotation; corner 0 is then the end nearer the image's top-left.
    let pattern = BoardSize::new(8, 6);
    for (i, angle) in [0.2, 3.3].into_iter().enumerate() {
        let h = homography(28.0, angle, (320.0, 240.0), (0.0, 0.0))
            * Matrix3::new(1.0, 0.0, -4.5, 0.0, 1.0, -3.5, 0.0, 0.0, 1.0);
        let board = render(pattern, h, (640, 480), &camera(20 + i as u64));
        let found = find_chessboard(&board.image, pattern).expect("board found");
        let (first, last) = (found[0], found[pattern.count() - 1]);
        assert!(first.x + first.y < last.x + last.y, "angle {angle}");
        let (u, v) = (found[1] - first, found[8] - first);
        assert!(
            u.x * v.y - u.y * v.x > 0.0,
            "angle {angle}: clockwise reading"
        );
    }
}

#[test]
fn rgb_input_is_converted() {
    let h = homography(30.0, 0.4, (160.0, 60.0), (0.0, 0.0));
    let board = render(BOARD, h, (480, 400), &camera(30));
    let rgb = stereolink_image::color::gray_to_rgb(&board.image);
    assert_eq!(
        find_chessboard_rgb(&rgb, BOARD),
        find_chessboard(&board.image, BOARD)
    );
}

#[test]
fn wrong_sizes_are_reported() {
    let board = render(
        BOARD,
        homography(28.0, 0.0, (100.0, 80.0), (0.0, 0.0)),
        (440, 340),
        &camera(4),
    );
    assert_eq!(
        find_chessboard(&board.image, BoardSize::new(8, 6)),
        Err(NotFound::WrongSize {
            found: BOARD,
            expected: BoardSize::new(8, 6)
        })
    );
    assert_eq!(
        find_chessboard(&board.image, BoardSize::new(10, 7)),
        Err(NotFound::Partial {
            found: BOARD,
            expected: BoardSize::new(10, 7)
        })
    );
    assert_eq!(
        find_chessboard(&board.image, BoardSize::new(2, 6)),
        Err(NotFound::BoardTooSmall(BoardSize::new(2, 6)))
    );
}

#[test]
fn degenerate_images_are_refused_without_panic() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let noise = GrayImage::from_fn(200, 150, |_, _| rng.gen());
    for (name, img) in [
        ("empty", GrayImage::new(0, 0, 0)),
        ("1x1", GrayImage::new(1, 1, 255)),
        ("black", GrayImage::new(320, 240, 0)),
        ("white", GrayImage::new(320, 240, 255)),
        ("noise", noise),
    ] {
        assert!(find_chessboard(&img, BOARD).is_err(), "{name}");
    }
    assert!(matches!(
        find_chessboard(&GrayImage::new(1, 1, 0), BOARD),
        Err(NotFound::ImageTooSmall {
            width: 1,
            height: 1
        })
    ));
}

#[test]
fn board_size_parses() {
    assert_eq!("9x6".parse::<BoardSize>(), Ok(BoardSize::new(9, 6)));
    assert!("9by6".parse::<BoardSize>().is_err());
    assert_eq!(BoardSize::new(9, 6).to_string(), "9x6");
}

fn calib_data() -> Option<PathBuf> {
    let dir = std::env::var_os("STEREOLINK_CALIB_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../../shared/data/calibration"
            ))
        });
    let dir = dir.join("ximea-9x6");
    if dir.is_dir() {
        Some(dir)
    } else {
        println!(
            "skipped: no calibration data at {} (set STEREOLINK_CALIB_DATA)",
            dir.display()
        );
        None
    }
}

#[test]
fn real_stereo_set_is_found_in_both_views_in_the_same_order() {
    let Some(dir) = calib_data() else { return };
    for n in 1..=25 {
        let read = |side: &str| {
            let path = dir.join(format!("{side}{n:02}.jpg"));
            let img = stereolink_image::io::read_gray(&path).expect("readable image");
            find_chessboard(&img, BOARD).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        };
        let (left, right) = (read("left"), read("right"));
        // The cameras are side by side and the board far: corner k moves by
        // about the same vector between the views. A reading rotated by 180°
        // in one view would move corners by up to the board's size.
        let shifts: Vec<_> = left.iter().zip(&right).map(|(l, r)| r - l).collect();
        let mean = shifts.iter().sum::<nalgebra::Vector2<f64>>() / shifts.len() as f64;
        let spread = shifts.iter().map(|s| (s - mean).norm()).fold(0.0, f64::max);
        assert!(
            spread < 20.0,
            "pair {n}: corner shifts spread by {spread:.1} px"
        );
    }
}

mod proptests {
    use proptest::prelude::*;

    use super::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        #[test]
        fn random_small_images_never_panic(
            (w, h, pixels) in (0usize..48, 0usize..48)
                .prop_flat_map(|(w, h)| (Just(w), Just(h), proptest::collection::vec(any::<u8>(), w * h)))
        ) {
            let img = GrayImage::from_vec(w, h, pixels).expect("sized");
            if let Ok(corners) = find_chessboard(&img, BoardSize::new(3, 3)) {
                prop_assert_eq!(corners.len(), 9);
            }
        }
    }
}
