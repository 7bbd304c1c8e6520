//! `capture` and live `send` from GStreamer test sources as separate
//! processes (with the `camera` feature), and the one-line refusal of a
//! build without it.

mod common;

#[cfg(feature = "camera")]
mod live {
    use std::path::Path;
    use std::time::Duration;

    use nalgebra::{Rotation3, Vector3};
    use stereolink_calib::{stereo_rectify, Camera, Distortion, StereoCalibration, StereoRig};
    use stereolink_image::{io, RgbImage};

    use super::common::{finish, free_port, spawn, spawn_udp_receiver};

    fn test_source(pattern: &str, extra: &str) -> String {
        format!(
            "videotestsrc is-live=true pattern={pattern} {extra} ! \
             video/x-raw,width=96,height=64,framerate=30/1"
        )
    }

    fn path(p: &Path) -> &str {
        p.to_str().unwrap()
    }

    #[test]
    fn capture_writes_pairs_of_pngs() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("pairs");
        let run = spawn(&[
            "--json",
            "capture",
            "--source-left",
            &test_source("ball", ""),
            "--source-right",
            &test_source("snow", ""),
            "--out",
            path(&out),
            "--frames",
            "5",
        ]);
        let summary: serde_json::Value = serde_json::from_str(&finish(run, "capture")).unwrap();
        assert_eq!(summary["frames"], 5);
        assert!(
            summary["max_skew_ms"].as_f64().unwrap() < 1000.0 / 60.0,
            "{summary}"
        );
        for i in 1..=5 {
            let left = io::read_rgb(out.join(format!("left_{i:04}.png"))).unwrap();
            let right = io::read_rgb(out.join(format!("right_{i:04}.png"))).unwrap();
            assert_eq!((left.dims(), right.dims()), ((96, 64), (96, 64)));
            assert_ne!(left, right, "pair {i}: the patterns differ");
        }
        assert!(!out.join("left_0006.png").exists());
    }

    /// Live send of three pairs over UDP from the test patterns `patterns`
    /// with `extra` send arguments: the sender's and the receiver's views
    /// of the last pair.
    fn live_send(dir: &Path, patterns: [&str; 2], extra: &[&str]) -> (RgbImage, RgbImage) {
        let (shots, saved) = (dir.join("screens"), dir.join("saved"));
        let (a, b) = (free_port(), free_port());
        let display = format!("png:{}", shots.display());
        let rx = spawn_udp_receiver(
            a,
            b,
            &[
                "--frames",
                "3",
                "--timeout-s",
                "60",
                "--display",
                &display,
                "--save",
                path(&saved),
            ],
        );
        std::thread::sleep(Duration::from_millis(200));
        let link = format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}");
        let (left, right) = (test_source(patterns[0], ""), test_source(patterns[1], ""));
        let mut args = vec![
            "--json",
            "send",
            "--link",
            &link,
            "--source-left",
            &left,
            "--source-right",
            &right,
            "--frames",
            "3",
            "--max-disp",
            "23",
            "--method",
            "kmeans",
            "--levels",
            "4",
            "--save",
            path(&saved),
        ];
        args.extend(extra);
        let sent = finish(spawn(&args), "send");
        finish(rx, "receive");
        // Three frames, of pairs in the order taken (a pair taken while a
        // frame was in flight gave only its depth report).
        let sent: serde_json::Value = serde_json::from_str(&sent).unwrap();
        let ids: Vec<u64> = sent["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f["frame_id"].as_u64().unwrap())
            .collect();
        assert_eq!(ids.len(), 3, "{sent}");
        assert!(ids.windows(2).all(|w| w[0] < w[1]), "{sent}");
        assert!(sent["status"]["pairs"].as_u64().unwrap() >= 3, "{sent}");
        // The screen is named by frame id, which counts pairs taken: the
        // last frame's, not "3", when a pair went only as a depth report.
        let last = shots.join(format!("screen-{:05}.png", ids[2]));
        assert!(last.is_file(), "{} {sent}", last.display());
        let read = |name: &str| io::read_rgb(saved.join(name)).unwrap();
        for side in ["left", "right"] {
            let a = read(&format!("sent-{side}.png"));
            assert_eq!(a.dims(), (96, 64));
            assert_eq!(
                a,
                read(&format!("received-{side}.png")),
                "{side} view differs"
            );
        }
        (read("sent-left.png"), read("received-left.png"))
    }

    #[test]
    fn live_send_is_received_bit_for_bit() {
        live_send(
            tempfile::tempdir().unwrap().path(),
            ["ball", "ball foreground-color=0xffff8000"],
            &[],
        );
    }

    /// With `--calib stereo.yml` every live pair is rectified before it is
    /// segmented: the views sent change, and still arrive bit for bit.
    #[test]
    fn live_send_rectifies_with_a_calibration() {
        let dir = tempfile::tempdir().unwrap();
        let camera = |cx: f64| Camera {
            fx: 110.0,
            fy: 110.0,
            cx,
            cy: 31.5,
            distortion: Distortion {
                k1: -0.25,
                k2: 0.05,
                ..Distortion::default()
            },
            width: 96,
            height: 64,
        };
        let rig = StereoRig {
            left: camera(47.0),
            right: camera(48.5),
            rotation: *Rotation3::from_scaled_axis(Vector3::new(0.01, -0.02, 0.015)).matrix(),
            translation: Vector3::new(-0.06, 0.002, 0.0),
        };
        let calib = StereoCalibration {
            rig,
            rectification: stereo_rectify(&rig, 0.0).unwrap(),
        };
        let file = dir.path().join("stereo.yml");
        stereolink_calib::files::write_opencv(&file, &calib).unwrap();
        // Still patterns: the two runs see the same frames.
        let still = ["smpte", "smpte75"];
        let (raw, _) = live_send(&dir.path().join("raw"), still, &[]);
        let (rectified, _) = live_send(
            &dir.path().join("rectified"),
            still,
            &["--calib", path(&file)],
        );
        let (again, _) = live_send(&dir.path().join("again"), still, &[]);
        assert_eq!(raw, again, "the still patterns changed between runs");
        assert_ne!(raw, rectified, "the calibration changed nothing");
    }

    /// A camera whose stream ends stops the sender: non-zero exit, a message
    /// naming the camera.
    #[test]
    fn live_send_stops_when_a_camera_stops() {
        let (a, b) = (free_port(), free_port());
        let mut rx = spawn(&[
            "receive",
            "--link",
            &format!("udp:127.0.0.1:{b}?peer=127.0.0.1:{a}"),
            "--robot",
            "sim",
            "--insecure",
            "--max-disp",
            "24",
            "--timeout-s",
            "60",
        ]);
        std::thread::sleep(Duration::from_millis(200));
        let right = test_source("snow", "num-buffers=4");
        let tx = spawn(&[
            "send",
            "--link",
            &format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"),
            "--source-left",
            &test_source("ball", ""),
            "--source-right",
            &right,
            "--max-disp",
            "23",
            "--method",
            "kmeans",
        ]);
        let out = tx.wait_with_output().unwrap();
        rx.kill().unwrap();
        rx.wait().unwrap();
        let errors = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{errors}");
        let right_name = right.split_whitespace().collect::<Vec<_>>().join(" ");
        assert!(
            errors.contains(&format!(
                "right camera `{right_name}` stopped: end of stream"
            )),
            "{errors}"
        );
        // One line of error (beside the warning that the link has no keys).
        let lines = errors.lines().filter(|l| !l.starts_with("warning:"));
        assert_eq!(lines.count(), 1, "{errors}");
    }

    #[test]
    fn a_bad_description_and_an_absent_device_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("pairs");
        // `capture` with these sources fails with exit code 1; its stderr.
        let fails = |sources: [&str; 4]| {
            let mut args = vec!["capture"];
            args.extend(sources);
            args.extend(["--out", path(&out)]);
            let res = spawn(&args).wait_with_output().unwrap();
            assert_eq!(res.status.code(), Some(1));
            String::from_utf8_lossy(&res.stderr).into_owned()
        };
        let errors = fails([
            "--source-left",
            "videotestsrc ! nosuchelement",
            "--source-right",
            "videotestsrc",
        ]);
        assert!(
            errors.contains("left source `videotestsrc ! nosuchelement`"),
            "{errors}"
        );
        let errors = fails([
            "--camera-left",
            "/dev/video98",
            "--camera-right",
            "/dev/video99",
        ]);
        assert!(
            errors.contains("left camera /dev/video98: no such device"),
            "{errors}"
        );
        assert!(!out.exists(), "nothing is written when the cameras fail");
    }
}

/// Without the feature, `capture` says in one line how to get cameras.
#[cfg(not(feature = "camera"))]
#[test]
fn without_the_feature_capture_says_how_to_enable_cameras() {
    let run = common::spawn(&[
        "capture",
        "--source-left",
        "videotestsrc",
        "--source-right",
        "videotestsrc",
        "--out",
        "/nonexistent/never-written",
    ]);
    let out = run.wait_with_output().unwrap();
    let errors = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{errors}");
    assert_eq!(errors.lines().count(), 1, "{errors}");
    assert!(errors.contains("--features camera"), "{errors}");
    assert!(errors.contains("libgstreamer1.0-dev"), "{errors}");
}
