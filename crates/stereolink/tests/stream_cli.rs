//! `encode DIR -o OUT/` and `decode OUT/ --out DIR`: a folder of pairs
//! coded as a stream (key frames every `--key-every` pairs, predicted
//! frames between), decoded back to exactly what the encoder measured, and
//! a stream with a frame missing or cut is a clear error.

use std::path::Path;

use stereolink_image::{io, RgbImage};

mod common;

use common::{json, stereolink};

/// `view` with seeded noise of a few grey levels.
fn noisy(view: &RgbImage, seed: u32) -> RgbImage {
    let mut s = seed.wrapping_mul(2_654_435_761) | 1;
    let mut out = view.clone();
    for p in out.as_mut_slice() {
        for c in p.iter_mut() {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            *c = (i32::from(*c) + (s % 5) as i32 - 2).clamp(0, 255) as u8;
        }
    }
    out
}

/// Six noisy pairs of one synthetic 160x120 scene in `dir/seq`.
fn sequence(dir: &Path) -> std::path::PathBuf {
    let scene = dir.join("s");
    let out = stereolink()
        .args(["synth", scene.to_str().unwrap(), "--seed", "5"])
        .args(["--width", "160", "--height", "120", "--max-disp", "16"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let (l, r) = (
        io::read_rgb(scene.join("left.png")).unwrap(),
        io::read_rgb(scene.join("right.png")).unwrap(),
    );
    let seq = dir.join("seq");
    std::fs::create_dir_all(&seq).unwrap();
    for i in 1..=6u32 {
        io::write_rgb(seq.join(format!("left_{i:04}.png")), &noisy(&l, 2 * i)).unwrap();
        io::write_rgb(seq.join(format!("right_{i:04}.png")), &noisy(&r, 2 * i + 1)).unwrap();
    }
    seq
}

#[test]
fn a_stream_decodes_to_what_the_encoder_measured() {
    let dir = tempfile::tempdir().unwrap();
    let seq = sequence(dir.path());
    let frames = dir.path().join("frames");
    let e = json(
        &stereolink()
            .args(["--json", "encode"])
            .arg(&seq)
            .arg("-o")
            .arg(&frames)
            .args([
                "--view-coding",
                "webp",
                "--bytes",
                "4000",
                "--key-every",
                "4",
            ])
            .output()
            .unwrap(),
    );
    let kinds: Vec<&str> = e["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["kind"].as_str().unwrap())
        .collect();
    assert_eq!(
        kinds,
        [
            "key",
            "predicted",
            "predicted",
            "predicted",
            "key",
            "predicted"
        ]
    );
    assert_eq!(e["frames"][1]["reference"], 1);
    let key = e["key_bytes_mean"].as_f64().unwrap();
    let predicted = e["predicted_bytes_mean"].as_f64().unwrap();
    assert!(
        key <= 4000.0 && predicted * 4.0 < key,
        "{predicted} B against {key}"
    );
    let key_db = e["key_psnr_pair_db_mean"].as_f64().unwrap();
    let predicted_db = e["predicted_psnr_pair_db_mean"].as_f64().unwrap();
    assert!(
        predicted_db > key_db - 0.5,
        "{predicted_db} dB against {key_db}"
    );
    let out = dir.path().join("out");
    let d = json(
        &stereolink()
            .args(["--json", "decode"])
            .arg(&frames)
            .arg("--out")
            .arg(&out)
            .arg("--originals")
            .arg(&seq)
            .output()
            .unwrap(),
    );
    for (a, b) in e["frames"]
        .as_array()
        .unwrap()
        .iter()
        .zip(d["frames"].as_array().unwrap())
    {
        assert_eq!(a["kind"], b["kind"]);
        assert_eq!(a["bytes"], b["bytes"]);
        // The same PSNR to the last bit: the same pictures.
        assert_eq!(a["psnr_pair_db"], b["psnr_pair_db"], "{b}");
    }
    assert!(out.join("left_0006.png").exists() && out.join("right_0006.png").exists());

    // A stream whose key frame is lost: its predicted frame is an error
    // naming the missing reference.
    std::fs::remove_file(frames.join("frame_0001.slnk")).unwrap();
    let lost = stereolink()
        .arg("decode")
        .arg(&frames)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!lost.status.success());
    let why = String::from_utf8_lossy(&lost.stderr);
    assert!(
        why.contains("frame_0002.slnk") && why.contains("reference frame 1"),
        "{why}"
    );
    // A cut frame file is an error naming it.
    let cut = std::fs::read(frames.join("frame_0005.slnk")).unwrap();
    std::fs::write(frames.join("frame_0005.slnk"), &cut[..cut.len() / 2]).unwrap();
    std::fs::remove_file(frames.join("frame_0002.slnk")).unwrap();
    std::fs::remove_file(frames.join("frame_0003.slnk")).unwrap();
    std::fs::remove_file(frames.join("frame_0004.slnk")).unwrap();
    let cut = stereolink()
        .arg("decode")
        .arg(&frames)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!cut.status.success());
    let why = String::from_utf8_lossy(&cut.stderr);
    assert!(
        why.contains("frame_0005.slnk") && why.contains("truncated"),
        "{why}"
    );
}

#[test]
fn a_segmented_stream_predicts_its_label_maps() {
    let dir = tempfile::tempdir().unwrap();
    let seq = sequence(dir.path());
    let frames = dir.path().join("frames");
    let e = json(
        &stereolink()
            .args(["--json", "encode"])
            .arg(&seq)
            .arg("-o")
            .arg(&frames)
            .args(["--levels", "3"])
            .output()
            .unwrap(),
    );
    assert_eq!(
        (e["key_frames"].as_u64(), e["predicted_frames"].as_u64()),
        (Some(1), Some(5))
    );
    let key = e["key_bytes_mean"].as_f64().unwrap();
    let predicted = e["predicted_bytes_mean"].as_f64().unwrap();
    assert!(predicted * 4.0 < key, "{predicted} B against {key}");
    let d = json(
        &stereolink()
            .args(["--json", "decode"])
            .arg(&frames)
            .arg("--out")
            .arg(dir.path().join("out"))
            .arg("--originals")
            .arg(&seq)
            .output()
            .unwrap(),
    );
    for (a, b) in e["frames"]
        .as_array()
        .unwrap()
        .iter()
        .zip(d["frames"].as_array().unwrap())
    {
        assert_eq!(
            (&a["kind"], &a["psnr_pair_db"]),
            (&b["kind"], &b["psnr_pair_db"]),
            "{b}"
        );
    }
}
