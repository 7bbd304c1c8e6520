//! `stereolink calibrate` as a user runs it: on chessboard pairs rendered
//! through a known rig (always), and on the shared real set when it is
//! beside the repository; its file must then feed `rectify` and `depth`.

mod common;

use std::path::{Path, PathBuf};

use nalgebra::{Rotation3, Vector3};
use stereolink_calib::synthetic::{render_board, RenderSpec};
use stereolink_calib::{BoardSize, Camera, Distortion, Pose};
use stereolink_image::io;

/// Two webcams 6 cm apart; the right one is turned by about 1°.
fn rig() -> (Camera, Camera, Pose) {
    let left = Camera {
        fx: 660.0,
        fy: 658.0,
        cx: 318.0,
        cy: 242.0,
        distortion: Distortion {
            k1: -0.2,
            k2: 0.08,
            p1: 0.0005,
            p2: -0.0008,
            k3: 0.0,
        },
        width: 640,
        height: 480,
    };
    let right = Camera {
        fx: 664.0,
        fy: 662.5,
        cx: 325.0,
        cy: 236.0,
        ..left
    };
    let between = Pose {
        rotation: Vector3::new(0.003, -0.012, 0.002),
        translation: Vector3::new(-0.06, 0.0005, 0.001),
    };
    (left, right, between)
}

/// Writes `n` rendered pairs as left_01.png, right_01.png, ...
fn write_pairs(dir: &Path, n: usize) {
    let (left, right, between) = rig();
    let spec = RenderSpec {
        board: BoardSize::new(9, 6),
        square: 0.025,
        samples: 3,
        noise: 2.0,
        seed: 0,
    };
    let centre = Vector3::new(0.1, 0.0625, 0.0);
    for i in 0..n {
        let a = i as f64 * 2.4;
        let tilt = 0.35 + 0.25 * (i % 3) as f64;
        let r = Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(a.cos(), a.sin(), 0.0)),
            tilt,
        );
        let at = Vector3::new(
            0.03 + 0.03 * (a * 1.7).sin(),
            0.02 * (a * 2.3).cos(),
            0.55 + 0.05 * (i % 4) as f64,
        );
        let pose = Pose {
            rotation: r.scaled_axis(),
            translation: at - r * centre,
        };
        let l = render_board(
            &left,
            &pose,
            &RenderSpec {
                seed: 2 * i as u64,
                ..spec
            },
        );
        let r = render_board(
            &right,
            &pose.then(&between),
            &RenderSpec {
                seed: 2 * i as u64 + 1,
                ..spec
            },
        );
        io::write_gray(dir.join(format!("left_{:02}.png", i + 1)), &l).unwrap();
        io::write_gray(dir.join(format!("right_{:02}.png", i + 1)), &r).unwrap();
    }
}

fn calibrate(dir: &Path, square: &str, out: &Path) -> serde_json::Value {
    let left = format!("{}/left*", dir.display());
    let right = format!("{}/right*", dir.display());
    let child = common::spawn(&[
        "--json",
        "calibrate",
        "--board",
        "9x6",
        "--square",
        square,
        "--left",
        &left,
        "--right",
        &right,
        "-o",
        out.to_str().unwrap(),
    ]);
    serde_json::from_str(&common::finish(child, "calibrate")).unwrap()
}

#[test]
fn rendered_pairs_calibrate_to_the_rig_and_the_file_serves_rectify_and_depth() {
    let dir = tempfile::tempdir().unwrap();
    write_pairs(dir.path(), 10);
    let out = dir.path().join("stereo.yml");
    let report = calibrate(dir.path(), "0.025", &out);
    let (left, right, between) = rig();
    assert_eq!(report["pairs_used"], 10, "{report:#}");
    for (side, truth) in [("left", left), ("right", right)] {
        let fx = report[side]["fx"].as_f64().unwrap();
        assert!((fx / truth.fx - 1.0).abs() < 3e-3, "{side} fx {fx}");
        assert!(
            report[side]["rms_px"].as_f64().unwrap() < 0.15,
            "{report:#}"
        );
    }
    let baseline = report["baseline"].as_f64().unwrap();
    assert!(
        (baseline / between.translation.norm() - 1.0).abs() < 5e-3,
        "baseline {baseline}"
    );
    for suffix in ["-left.yaml", "-right.yaml", "-preview.png"] {
        assert!(
            dir.path().join(format!("stereo{suffix}")).is_file(),
            "{suffix}"
        );
    }

    // The file rectifies a raw pair...
    let rectified = dir.path().join("rectified");
    let child = common::spawn(&[
        "rectify",
        dir.path().join("left_01.png").to_str().unwrap(),
        dir.path().join("right_01.png").to_str().unwrap(),
        "--calib",
        out.to_str().unwrap(),
        "-o",
        rectified.to_str().unwrap(),
    ]);
    common::finish(child, "rectify");
    assert_eq!(
        io::read_rgb(rectified.join("left.png")).unwrap().dims(),
        (640, 480)
    );

    // ... and the existing --calib-yaml reader takes depth from its P1/P2.
    let disp = dir.path().join("d.pfm");
    stereolink_image::pfm::write(&disp, &stereolink_image::DisparityMap::new(64, 48, 40.0))
        .unwrap();
    let child = common::spawn(&[
        "--json",
        "depth",
        disp.to_str().unwrap(),
        "--calib-yaml",
        out.to_str().unwrap(),
        "--roi",
        "10,10,8,8",
    ]);
    let depth: serde_json::Value = serde_json::from_str(&common::finish(child, "depth")).unwrap();
    let calib = stereolink_calib::files::read_opencv(&out).unwrap();
    let (p1, p2) = (calib.rectification.p1, calib.rectification.p2);
    let expected = -p2[(0, 3)] / (40.0 + p2[(0, 2)] - p1[(0, 2)]);
    let got = depth["regions"][0][1].as_f64().unwrap();
    assert!(
        (got - expected).abs() < 1e-4 * expected,
        "depth {got} m, P1/P2 give {expected} m"
    );
    assert!((got - baseline * p1[(0, 0)] / (40.0 + p2[(0, 2)] - p1[(0, 2)])).abs() < 1e-3);
}

#[test]
fn images_without_a_board_are_named() {
    let dir = tempfile::tempdir().unwrap();
    write_pairs(dir.path(), 3);
    io::write_gray(
        dir.path().join("right_02.png"),
        &stereolink_image::GrayImage::new(640, 480, 90),
    )
    .unwrap();
    let left = format!("{}/left*", dir.path().display());
    let right = format!("{}/right*", dir.path().display());
    let out = common::spawn(&[
        "calibrate",
        "--board",
        "9x6",
        "--square",
        "0.025",
        "--left",
        &left,
        "--right",
        &right,
        "-o",
        dir.path().join("s.yml").to_str().unwrap(),
    ])
    .wait_with_output()
    .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("right_02.png") && err.contains("at least 3"),
        "{err}"
    );
}

/// The shared real set: `STEREOLINK_CALIB_DATA`, or `../shared/data/calibration` beside the repository.
fn real_set() -> Option<PathBuf> {
    let dir = std::env::var_os("STEREOLINK_CALIB_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/calibration")
        });
    let set = dir.join("ximea-9x6");
    set.is_dir().then_some(set)
}

#[test]
fn the_real_set_calibrates_as_well_as_opencv() {
    let Some(set) = real_set() else {
        eprintln!("skipped: no shared calibration set (set STEREOLINK_CALIB_DATA)");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let report = calibrate(&set, "1", &dir.path().join("stereo.yml"));
    assert_eq!(report["pairs_used"], 25);
    // OpenCV 5.0 on these files (the set's MANIFEST.md): stereo RMS 0.1740 px,
    // fx 519.28 / 518.39 px, baseline 3.8345 squares.
    assert!(
        report["stereo_rms_px"].as_f64().unwrap() <= 0.174,
        "{report:#}"
    );
    for (side, fx) in [("left", 519.28), ("right", 518.39)] {
        let got = report[side]["fx"].as_f64().unwrap();
        assert!((got / fx - 1.0).abs() < 5e-3, "{side} fx {got}");
    }
    let b = report["baseline"].as_f64().unwrap();
    assert!((b / 3.8345 - 1.0).abs() < 5e-3, "baseline {b}");
    // Its "left" camera is the right one: the warning says to swap them.
    assert!(
        report["warnings"].to_string().contains("swap"),
        "{report:#}"
    );
}
