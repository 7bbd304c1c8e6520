//! The CLI frame: exit codes, one-line errors, `synth` and `info`.

mod common;

use std::process::Command;

use common::stereolink;

/// Asserts that the command succeeded, showing its stderr if not.
fn assert_success(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn usage_errors_exit_2_and_failures_exit_1_with_one_line() {
    let out = stereolink().arg("no-such-command").output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let out = stereolink()
        .args(["info", "/no/such/scene"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8(out.stderr).unwrap();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("/no/such/scene"), "{err}");
}

#[test]
fn synth_writes_a_scene_that_info_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("s");
    let out = stereolink()
        .args([
            "synth",
            scene.to_str().unwrap(),
            "--seed",
            "5",
            "--width",
            "96",
            "--height",
            "64",
        ])
        .args(["--max-disp", "16"])
        .output()
        .unwrap();
    assert_success(&out);
    for f in [
        "left.png",
        "right.png",
        "gt_left.pfm",
        "mask_nonocc.png",
        "calib.txt",
    ] {
        assert!(scene.join(f).is_file(), "{f} missing");
    }
    let out = stereolink()
        .args(["--json", "info", scene.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success());
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        (info["width"].as_u64(), info["height"].as_u64()),
        (Some(96), Some(64))
    );
    assert_eq!(info["ndisp"].as_u64(), Some(16));
    let hi = info["gt_left_range"][1].as_f64().unwrap();
    assert!(hi <= 0.95 * 16.0 + 1e-6 && hi > 8.0, "{hi}");
}

#[test]
fn truncated_image_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("s");
    let status = stereolink()
        .args([
            "synth",
            scene.to_str().unwrap(),
            "--width",
            "64",
            "--height",
            "48",
            "--max-disp",
            "8",
        ])
        .status()
        .unwrap();
    assert!(status.success());
    let right = scene.join("right.png");
    let bytes = std::fs::read(&right).unwrap();
    std::fs::write(&right, &bytes[..bytes.len() / 3]).unwrap();
    let out = stereolink()
        .args(["info", scene.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("right.png"), "{err}");
}

/// `depth` takes its calibration from flags or from an OpenCV
/// `stereoRectify` YAML (here in millimetres) and gives the same distance,
/// Z = f·b / d.
#[test]
fn depth_reads_an_opencv_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let disp = dir.path().join("d.pfm");
    stereolink_image::pfm::write(&disp, &stereolink_image::DisparityMap::new(8, 6, 10.0)).unwrap();
    let yaml = dir.path().join("rectify.yml");
    std::fs::write(
        &yaml,
        "%YAML:1.0\n---\nP1: !!opencv-matrix\n   rows: 3\n   cols: 4\n   dt: d\n   \
         data: [ 700., 0., 4., 0., 0., 700., 3., 0., 0., 0., 1., 0. ]\n\
         P2: !!opencv-matrix\n   rows: 3\n   cols: 4\n   dt: d\n   \
         data: [ 700., 0., 4., -4.2e+04, 0., 700., 3., 0., 0., 0., 1., 0. ]\n",
    )
    .unwrap();
    let distance = |calib: &[&str]| {
        let out = stereolink()
            .args([
                "--json",
                "depth",
                disp.to_str().unwrap(),
                "--roi",
                "0,0,4,4",
            ])
            .args(calib)
            .output()
            .unwrap();
        assert_success(&out);
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        v["regions"][0][1].as_f64().unwrap()
    };
    let from_yaml = distance(&[
        "--calib-yaml",
        yaml.to_str().unwrap(),
        "--calib-units",
        "mm",
    ]);
    assert!((from_yaml - 4.2).abs() < 1e-9, "{from_yaml}");
    assert_eq!(
        distance(&["--focal-px", "700", "--baseline-m", "0.06"]),
        from_yaml
    );
    // The wrong unit gives a thousandfold distance, not a silent default.
    assert!((distance(&["--calib-yaml", yaml.to_str().unwrap()]) - 4200.0).abs() < 1e-6);
}

#[test]
fn encode_carries_right_labels_over_unless_independent() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("s");
    let out = stereolink()
        .args(["synth", scene.to_str().unwrap(), "--seed", "3"])
        .args(["--width", "96", "--height", "64", "--max-disp", "16"])
        .output()
        .unwrap();
    assert_success(&out);
    let (l, r) = (scene.join("left.png"), scene.join("right.png"));
    let encode = |extra: &[&str]| {
        let frame = dir.path().join("f.slnk");
        let out = stereolink()
            .arg("encode")
            .args([&l, &r])
            .arg("-o")
            .arg(&frame)
            .args(["--method", "kmeans"])
            .args(extra)
            .output()
            .unwrap();
        (out, frame)
    };
    for extra in [&[][..], &["--carry-margin", "40"], &["--independent-right"]] {
        let (out, frame) = encode(extra);
        assert_success(&out);
        let out = stereolink()
            .arg("decode")
            .arg(&frame)
            .arg("--out")
            .arg(dir.path().join("d"))
            .output()
            .unwrap();
        assert_success(&out);
    }
    // A margin for a view segmented independently is a usage error.
    let (out, _) = encode(&["--carry-margin", "4", "--independent-right"]);
    assert_eq!(out.status.code(), Some(2));
    // A margin that is not a finite number ≥ 0 is refused, naming the flag.
    for bad in ["--carry-margin=-5", "--carry-margin=NaN"] {
        let (out, _) = encode(&[bad]);
        assert!(!out.status.success());
        assert!(String::from_utf8_lossy(&out.stderr).contains("--carry-margin"));
    }
    // A margin for a single image has no right view to act on.
    let out = stereolink()
        .arg("segment")
        .arg(&l)
        .arg("-o")
        .arg(dir.path().join("s.png"))
        .args(["--carry-margin", "5"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--right"));
}

#[test]
fn planes_matches_through_eval_and_match_with_any_segments() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("s");
    let out = stereolink()
        .args(["synth", scene.to_str().unwrap(), "--seed", "5"])
        .args(["--width", "160", "--height", "120", "--max-disp", "24"])
        .output()
        .unwrap();
    assert_success(&out);
    let eval = |extra: &[&str]| -> serde_json::Value {
        let out = stereolink()
            .args(["--json", "eval", "--data", scene.to_str().unwrap()])
            .args(["--algos", "sgm,planes"])
            .args(extra)
            .output()
            .unwrap();
        assert_success(&out);
        serde_json::from_slice(&out.stdout).unwrap()
    };
    let t = eval(&[]);
    let bad = |t: &serde_json::Value, i: usize| t["rows"][i]["bad1_nonocc"].as_f64().unwrap();
    assert_eq!(t["rows"][1]["algorithm"], "planes");
    // The planes over the mean shift over-segmentation beat SGM here.
    assert!(bad(&t, 1) < bad(&t, 0), "{t}");
    let t = eval(&["--segments", "kmeans"]);
    assert!(bad(&t, 1) < 10.0, "{t}");

    let pfm = dir.path().join("d.pfm");
    let run = |segments: &str| {
        stereolink()
            .args(["match", "--algo", "planes", "--max-disp", "23"])
            .arg(scene.join("left.png"))
            .arg(scene.join("right.png"))
            .args(["-o", pfm.to_str().unwrap(), "--segments", segments])
            .output()
            .unwrap()
    };
    assert_success(&run("otsu"));
    assert!(pfm.is_file());
    let out = run("foo");
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8(out.stderr).unwrap();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("foo"), "{err}");
}

/// `match` without `--max-disp` searches the range the scene folder states
/// (its calib.txt's `ndisp`), or, for images with no scene beside them,
/// the documented default; and says which.
#[test]
fn match_takes_the_scenes_range_or_says_its_default() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("s");
    let out = stereolink()
        .args(["synth", scene.to_str().unwrap(), "--width", "160"])
        .args(["--height", "120", "--max-disp", "24"])
        .output()
        .unwrap();
    assert_success(&out);
    let calib = std::fs::read_to_string(scene.join("calib.txt")).unwrap();
    let ndisp: usize = calib
        .lines()
        .find_map(|l| l.strip_prefix("ndisp="))
        .unwrap()
        .parse()
        .unwrap();
    let bare = dir.path().join("bare");
    std::fs::create_dir(&bare).unwrap();
    for (from, to) in [("left.png", "a.png"), ("right.png", "b.png")] {
        std::fs::copy(scene.join(from), bare.join(to)).unwrap();
    }
    let run = |left: std::path::PathBuf, right: std::path::PathBuf| {
        let out = stereolink()
            .args(["--json", "match"])
            .arg(left)
            .arg(right)
            .args(["-o", dir.path().join("d.pfm").to_str().unwrap()])
            .output()
            .unwrap();
        assert_success(&out);
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()
    };
    let m = run(scene.join("left.png"), scene.join("right.png"));
    assert_eq!(m["max_disp"], ndisp - 1, "{m}");
    assert!(
        m["max_disp_from"].as_str().unwrap().contains("calib.txt"),
        "{m}"
    );
    // 160 px: a sixteenth multiple of about an eighth of the width, 32 levels.
    let m = run(bare.join("a.png"), bare.join("b.png"));
    assert_eq!(m["max_disp"], 31, "{m}");
    assert!(
        m["max_disp_from"].as_str().unwrap().contains("160 px"),
        "{m}"
    );
}

/// Completions and man pages come from the same definitions as `--help`:
/// every command is in them.
#[test]
fn completions_and_man_pages_cover_every_command() {
    let out = stereolink().args(["completions", "bash"]).output().unwrap();
    assert_success(&out);
    let script = String::from_utf8(out.stdout).unwrap();
    for command in ["send", "receive", "match", "calibrate", "completions"] {
        assert!(script.contains(command), "{command} missing");
    }
    let dir = tempfile::tempdir().unwrap();
    let out = stereolink()
        .args(["--json", "man", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert_success(&out);
    let m: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let pages: Vec<&str> = m["pages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.as_str().unwrap())
        .collect();
    for page in ["stereolink.1", "stereolink-send.1", "stereolink-receive.1"] {
        assert!(pages.contains(&page), "{page} missing: {pages:?}");
        let text = std::fs::read_to_string(dir.path().join(page)).unwrap();
        assert!(text.starts_with(".ie") || text.contains(".TH"), "{page}");
    }
}

/// The systemd units in `deploy/systemd` verify (`systemd-analyze
/// verify`, with ExecStart pointed at this build): no error, no warning.
/// Without systemd-analyze the test is skipped, but not under CI=true.
#[test]
fn the_shipped_systemd_units_verify() {
    let Ok(probe) = Command::new("systemd-analyze").arg("--version").output() else {
        assert!(
            std::env::var_os("CI").is_none(),
            "systemd-analyze is needed under CI"
        );
        eprintln!("skipped: no systemd-analyze");
        return;
    };
    assert!(probe.status.success());
    let units = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../deploy/systemd");
    let dir = tempfile::tempdir().unwrap();
    let mut checked = 0;
    for entry in std::fs::read_dir(&units).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "service") {
            continue;
        }
        let unit = std::fs::read_to_string(&path).unwrap().replace(
            "/usr/local/bin/stereolink",
            env!("CARGO_BIN_EXE_stereolink"),
        );
        let copy = dir.path().join(path.file_name().unwrap());
        std::fs::write(&copy, unit).unwrap();
        let out = Command::new("systemd-analyze")
            .arg("verify")
            .arg(&copy)
            .output()
            .unwrap();
        let said = String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success() && said.trim().is_empty(),
            "{}: {said}",
            path.display()
        );
        checked += 1;
    }
    assert!(checked >= 1);
}
