//! `capture` and live `send` from GStreamer test sources as separate
//! processes (with the `camera` feature), and the one-line refusal of a
//! build without it.

mod common;

#[cfg(feature = "camera")]
mod live {
    use std::path::Path;
    use std::time::Duration;

    use super::common::{finish, free_port, spawn};
    use stereolink_image::io;

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

    /// Live send of three pairs over UDP: the receiver's views of the last
    /// equal the sender's segmented views bit for bit.
    #[test]
    fn live_send_is_received_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let (shots, saved) = (dir.path().join("screens"), dir.path().join("saved"));
        let (a, b) = (free_port(), free_port());
        let rx = spawn(&[
            "receive",
            "--link",
            &format!("udp:127.0.0.1:{b}?peer=127.0.0.1:{a}"),
            "--robot",
            "sim",
            "--frames",
            "3",
            "--max-disp",
            "24",
            "--timeout-s",
            "60",
            "--display",
            &format!("png:{}", shots.display()),
            "--save",
            path(&saved),
        ]);
        std::thread::sleep(Duration::from_millis(200));
        let tx = spawn(&[
            "send",
            "--link",
            &format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"),
            "--source-left",
            &test_source("ball", ""),
            "--source-right",
            &test_source("ball", "foreground-color=0xffff8000"),
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
        ]);
        let sent = finish(tx, "send");
        finish(rx, "receive");
        for i in 1..=3 {
            assert!(sent.contains(&format!("frame {i}:")), "{sent}");
        }
        assert!(!sent.contains("frame 4:"), "{sent}");
        assert_eq!(sent.matches("timing: capture wait").count(), 3, "{sent}");
        for side in ["left", "right"] {
            let a = io::read_rgb(saved.join(format!("sent-{side}.png"))).unwrap();
            let b = io::read_rgb(saved.join(format!("received-{side}.png"))).unwrap();
            assert_eq!(a.dims(), (96, 64));
            assert_eq!(a, b, "{side} view differs");
        }
        assert!(shots.join("screen-00003.png").is_file());
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
        assert_eq!(errors.lines().count(), 1, "{errors}");
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
