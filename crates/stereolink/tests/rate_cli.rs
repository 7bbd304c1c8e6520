//! `encode --view-coding` and `--bytes` through the CLI: lossy pairs
//! round-trip through `decode` above a PSNR floor, a budget is met with the
//! whole frame, and a budget below the smallest frame is an error naming
//! that frame's size (the one `--json` reports for the lowest setting).

use std::path::{Path, PathBuf};
use std::process::Output;

mod common;

use common::{json, stereolink};

/// A 160x120 synthetic pair in `dir`.
fn pair(dir: &Path) -> (PathBuf, PathBuf) {
    let scene = dir.join("s");
    let out = stereolink()
        .args(["synth", scene.to_str().unwrap(), "--seed", "5"])
        .args(["--width", "160", "--height", "120", "--max-disp", "16"])
        .output()
        .unwrap();
    assert!(out.status.success());
    (scene.join("left.png"), scene.join("right.png"))
}

fn encode(dir: &Path, (l, r): &(PathBuf, PathBuf), args: &[&str]) -> Output {
    stereolink()
        .arg("--json")
        .arg("encode")
        .args([l, r])
        .arg("-o")
        .arg(dir.join("f.slnk"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn lossy_pairs_decode_to_what_encode_measured_above_a_floor() {
    let dir = tempfile::tempdir().unwrap();
    let pair = pair(dir.path());
    for coding in ["jpeg", "webp"] {
        let e = json(&encode(
            dir.path(),
            &pair,
            &["--view-coding", coding, "--quality", "90"],
        ));
        assert_eq!(e["view_coding"], coding);
        assert_eq!(e["quality"], 90);
        let frame = dir.path().join("f.slnk");
        assert_eq!(e["bytes"], std::fs::metadata(&frame).unwrap().len());
        let d = json(
            &stereolink()
                .args(["--json", "decode"])
                .arg(&frame)
                .arg("--out")
                .arg(dir.path().join("d"))
                .arg("--left")
                .arg(&pair.0)
                .arg("--right")
                .arg(&pair.1)
                .output()
                .unwrap(),
        );
        assert_eq!(d["view_coding"], coding);
        assert_eq!(d["psnr_pair_db"], e["psnr_pair_db"]);
        // The synthetic views are textured; a pair with its planes or
        // views mixed up gives far below this.
        let psnr = e["psnr_pair_db"].as_f64().unwrap();
        assert!(psnr > 27.0, "{coding} q90: {psnr} dB");
    }
}

#[test]
fn budgets_are_met_and_one_below_the_smallest_frame_names_it() {
    let dir = tempfile::tempdir().unwrap();
    let pair = pair(dir.path());
    let codings: [(&str, &[&str], &str); 3] = [
        ("jpeg", &["--quality", "1"], "quality"),
        ("webp", &["--quality", "0"], "quality"),
        ("segmented", &["--levels", "2"], "levels"),
    ];
    for (coding, lowest, setting) in codings {
        let with = |extra: &[&str]| {
            let mut args = vec!["--view-coding", coding, "--method", "kmeans"];
            args.extend_from_slice(extra);
            encode(dir.path(), &pair, &args)
        };
        let smallest = json(&with(lowest))["bytes"].as_u64().unwrap();
        let mut last = (0, f64::MIN);
        for budget in [smallest, smallest + 1500, smallest + 6000] {
            let b = budget.to_string();
            let e = json(&with(&["--bytes", &b, "--levels", "12"]));
            let (bytes, psnr) = (
                e["bytes"].as_u64().unwrap(),
                e["psnr_pair_db"].as_f64().unwrap(),
            );
            assert!(
                bytes <= budget,
                "{coding}: {bytes} B in a budget of {budget}"
            );
            assert!(e[setting].is_u64(), "{coding}: {e}");
            assert!(
                bytes >= last.0 && psnr >= last.1,
                "{coding} at {budget} B: {e}"
            );
            last = (bytes, psnr);
        }
        assert!(
            last.1 > json(&with(lowest))["psnr_pair_db"].as_f64().unwrap(),
            "{coding}"
        );
        let below = (smallest - 1).to_string();
        let out = with(&["--bytes", &below, "--levels", "12"]);
        assert_eq!(out.status.code(), Some(1), "{coding}");
        assert!(out.stdout.is_empty());
        let err = String::from_utf8(out.stderr).unwrap();
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(
            err.contains(&format!("smallest frame this coding makes, {smallest} B")),
            "{coding}: {err}"
        );
    }
}
