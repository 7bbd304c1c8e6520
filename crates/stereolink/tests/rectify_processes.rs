//! The sensor end through the binary: a raw pair rendered through a known
//! rig is rectified back by `rectify`, and `match --calib stereo.yml`
//! rectifies it itself and takes its depth from P1/P2.

mod common;

use common::run_ok;

use std::path::Path;
use std::process::Command;

use nalgebra::{Rotation3, Vector3};
use stereolink_calib::synthetic::{rig_around, unrectify, RectifiedGeometry};
use stereolink_calib::{files, Camera, Distortion, StereoCalibration};
use stereolink_image::synth::{synthesize, SynthSpec};
use stereolink_image::{io, RgbImage, Scene};

const W: usize = 320;
const H: usize = 240;
/// The rectified geometry the test imposes (not the synthetic scene's own).
const FOCAL: f64 = 300.0;
const BASELINE: f64 = 0.08;

/// A distorted, turned rig and the synthetic scene as its rectified views.
fn rig_and_scene() -> (StereoCalibration, Scene) {
    let cam = |fx: f64, k1: f64, cx: f64| Camera {
        fx,
        fy: fx + 1.0,
        cx,
        cy: 121.0,
        distortion: Distortion {
            k1,
            k2: 0.05,
            p1: 0.001,
            p2: -0.001,
            k3: 0.0,
        },
        width: W,
        height: H,
    };
    let r1 = *Rotation3::from_scaled_axis(Vector3::new(0.012, -0.03, 0.01)).matrix();
    let r2 = *Rotation3::from_scaled_axis(Vector3::new(-0.01, 0.02, -0.006)).matrix();
    let calib = rig_around(
        cam(310.0, -0.2, 161.0),
        cam(305.0, -0.15, 158.5),
        r1,
        r2,
        &RectifiedGeometry {
            focal: FOCAL,
            cx: 160.0,
            cy: 120.0,
            doffs: 0.0,
            baseline: BASELINE,
            size: (W, H),
        },
    );
    let scene = synthesize(&SynthSpec {
        width: W,
        height: H,
        max_disp: 32,
        seed: 3,
    })
    .unwrap();
    (calib, scene)
}

/// Writes the raw views the rig's cameras see of the scene, and the file.
fn write_raw(dir: &Path, calib: &StereoCalibration, scene: &Scene) {
    let (rig, rect) = (&calib.rig, &calib.rectification);
    let left = unrectify(&scene.left, &rig.left, &rect.r1, &rect.p1);
    let right = unrectify(&scene.right, &rig.right, &rect.r2, &rect.p2);
    io::write_rgb(dir.join("raw_left.png"), &left).unwrap();
    io::write_rgb(dir.join("raw_right.png"), &right).unwrap();
    files::write_opencv(&dir.join("stereo.yml"), calib).unwrap();
}

/// Mean absolute difference over the interior, `b` shifted down by `dy` rows.
fn mean_diff(a: &RgbImage, b: &RgbImage, dy: usize) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for y in 24..H - 24 {
        for x in 24..W - 24 {
            let (p, q) = (a.get(x, y), b.get(x, y - dy));
            sum += (0..3)
                .map(|c| (p[c] as f64 - q[c] as f64).abs())
                .sum::<f64>();
            n += 3;
        }
    }
    sum / n as f64
}

#[test]
fn a_raw_pair_is_rectified_back_and_matched_with_depth_from_p1_p2() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (calib, scene) = rig_and_scene();
    write_raw(d, &calib, &scene);
    let p = |f: &str| d.join(f).to_str().unwrap().to_string();
    let (raw_l, raw_r, yml, out) = (
        p("raw_left.png"),
        p("raw_right.png"),
        p("stereo.yml"),
        p("out"),
    );

    run_ok(&[
        "rectify", &raw_l, &raw_r, "--calib", &yml, "-o", &out, "--guides",
    ]);
    let out_dir = d.join("out");
    for (name, truth) in [("left.png", &scene.left), ("right.png", &scene.right)] {
        let rectified = io::read_rgb(out_dir.join(name)).unwrap();
        let raw = io::read_rgb(d.join(format!("raw_{name}"))).unwrap();
        let aligned = mean_diff(&rectified, truth, 0);
        // Rows line up: a row's shift costs far more than the two
        // resamplings, and the raw view is far from the rectified one.
        assert!(
            aligned < 0.5 * mean_diff(&rectified, truth, 1),
            "{name}: {aligned}"
        );
        assert!(
            aligned < 0.5 * mean_diff(&raw, truth, 0),
            "{name}: {aligned}"
        );
    }
    assert_eq!(
        io::read_rgb(out_dir.join("preview.png")).unwrap().dims(),
        (2 * W, H)
    );
    // The output folder is a scene with the rectified depth calibration.
    let rectified = Scene::load(&out_dir).unwrap();
    assert_eq!(rectified.calib.focal_px, Some(FOCAL));
    assert!((rectified.calib.baseline_m.unwrap() - BASELINE).abs() < 1e-9);

    let json = run_ok(&[
        "--json",
        "match",
        &raw_l,
        &raw_r,
        "--calib",
        &yml,
        "--max-disp",
        "31",
        "-o",
        &p("d.pfm"),
    ]);
    let m: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(m["rectified"], true);
    assert_eq!(m["focal_px"], FOCAL);
    let z = m["distance_m"].as_f64().expect("a distance");
    // The truth: the central region's median ground-truth disparity through
    // the imposed f and b (the scene's own calib.txt says otherwise).
    let gt = scene.gt_left.as_ref().unwrap();
    let mut ds: Vec<f32> = (H / 3..H / 3 + H / 3)
        .flat_map(|y| (W / 3..W / 3 + W / 3).map(move |x| (x, y)))
        .map(|(x, y)| gt.get(x, y))
        .collect();
    ds.sort_by(f32::total_cmp);
    let truth = FOCAL * BASELINE / ds[ds.len() / 2] as f64;
    assert!((z - truth).abs() < 0.03 * truth, "{z} m vs {truth} m");
}

#[test]
fn a_broken_calibration_file_is_named_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (calib, scene) = rig_and_scene();
    write_raw(d, &calib, &scene);
    let text = std::fs::read_to_string(d.join("stereo.yml")).unwrap();
    let cut = text.find("D2:").unwrap();
    let next = cut + text[cut..].find("R:").unwrap();
    let broken = d.join("broken.yml");
    std::fs::write(&broken, format!("{}{}", &text[..cut], &text[next..])).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_stereolink"))
        .args(["rectify", "a.png", "b.png", "-o"])
        .arg(d.join("o"))
        .arg("--calib")
        .arg(&broken)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8(out.stderr).unwrap();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains("broken.yml: no D2 (the right camera's distortion)"),
        "{err}"
    );
    // A raw pair of another size than the calibration's.
    let small = RgbImage::new(100, 80, [0; 3]);
    io::write_rgb(d.join("small.png"), &small).unwrap();
    let s = d.join("small.png");
    let out = Command::new(env!("CARGO_BIN_EXE_stereolink"))
        .arg("rectify")
        .args([&s, &s])
        .arg("--calib")
        .arg(d.join("stereo.yml"))
        .arg("-o")
        .arg(d.join("o"))
        .output()
        .unwrap();
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("100x80") && err.contains("320x240"), "{err}");
}
