//! `send --record` and `receive --record` over UDP, and `gateway --record`:
//! the recordings hold each topic with its ROS 2 type, the views at the
//! pair's size, and the same capture time stamps on both sides (the
//! sender's); the gateway's under the station's name. An outside
//! reader (tools/check_mcap.py: PyPI `mcap` + `mcap-ros2-support`) checks
//! them too when it is installed, and must be under
//! `STEREOLINK_REQUIRE_MCAP_CHECK=1`, as CI sets after installing it.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use common::{finish, free_port, send_args, spawn, spawn_udp_receiver, strings, synth};

/// The log times of each topic's messages, and each topic's schema name.
fn topics(path: &Path) -> BTreeMap<String, (String, Vec<u64>)> {
    let bytes = std::fs::read(path).unwrap();
    let mut out: BTreeMap<String, (String, Vec<u64>)> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema = m.channel.schema.as_ref().unwrap();
        assert_eq!(
            (
                schema.encoding.as_str(),
                m.channel.message_encoding.as_str()
            ),
            ("ros2msg", "cdr")
        );
        let e = out.entry(m.channel.topic.clone()).or_default();
        e.0 = schema.name.clone();
        e.1.push(m.log_time);
        if schema.name == "sensor_msgs/msg/Image" {
            // After the header (stamp, frame id `stereo_*_optical`):
            // height and width, u32 little endian.
            let id_len = u32::from_le_bytes(m.data[12..16].try_into().unwrap()) as usize;
            let at = (16 + id_len).next_multiple_of(4);
            let u32_at = |i: usize| u32::from_le_bytes(m.data[i..i + 4].try_into().unwrap());
            assert_eq!(
                (u32_at(at + 4), u32_at(at)),
                (160, 120),
                "{}",
                m.channel.topic
            );
        }
    }
    out
}

/// Runs the outside reader on `path` (with `args`), if it is installed.
fn outside_check(path: &Path, args: &[&str]) {
    let required = std::env::var("STEREOLINK_REQUIRE_MCAP_CHECK").as_deref() == Ok("1");
    let have = Command::new("python3")
        .args(["-c", "import mcap_ros2.decoder"])
        .status()
        .is_ok_and(|s| s.success());
    if !have {
        assert!(!required, "python3 cannot import mcap_ros2");
        eprintln!("skipped the outside reader: pip install mcap mcap-ros2-support");
        return;
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools/check_mcap.py");
    let out = Command::new("python3")
        .arg(script)
        .arg(path)
        .args(["--size", "160x120", "--frames", "2"])
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}: {}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["messages"]["/tf_static"], 1);
    assert!(
        (v["baseline_m"].as_f64().unwrap() - 0.03).abs() < 1e-9,
        "{v}"
    );
}

#[test]
fn send_and_receive_record_the_same_stamped_topics() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let (tx_rec, rx_rec) = (dir.path().join("tx.mcap"), dir.path().join("rx.mcap"));
    let (a, b) = (free_port(), free_port());
    let before_us = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_micros() as u64;
    let rx = spawn_udp_receiver(
        a,
        b,
        &[
            "--frames",
            "2",
            "--timeout-s",
            "60",
            "--record",
            rx_rec.to_str().unwrap(),
        ],
    );
    std::thread::sleep(Duration::from_millis(200));
    let mut args = send_args(&format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"), &scene);
    args.extend(strings(&[
        "--repeat",
        "2",
        "--record",
        tx_rec.to_str().unwrap(),
    ]));
    finish(spawn(&args), "send");
    finish(rx, "receive");
    let after_us = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_micros() as u64;

    let (tx, rx) = (topics(&tx_rec), topics(&rx_rec));
    let types = [
        ("/stereo/left/image_rect_color", "sensor_msgs/msg/Image"),
        ("/stereo/right/image_rect_color", "sensor_msgs/msg/Image"),
        ("/stereo/left/camera_info", "sensor_msgs/msg/CameraInfo"),
        ("/stereo/right/camera_info", "sensor_msgs/msg/CameraInfo"),
        ("/stereo/disparity", "stereo_msgs/msg/DisparityImage"),
        ("/stereo/depth_report", "stereolink_msgs/msg/DepthReport"),
    ];
    let frames = &tx["/stereo/left/image_rect_color"].1;
    assert_eq!(frames.len(), 2);
    for stamp in frames {
        assert!(
            (before_us * 1000..=after_us * 1000).contains(stamp),
            "{stamp}"
        );
    }
    for (topic, ty) in types {
        for (side, got) in [("send", &tx), ("receive", &rx)] {
            let (name, stamps) = &got[topic];
            assert_eq!(name, ty, "{side} {topic}");
            // Each frame's messages carry its pair's capture time, on both
            // sides (the receiver's are the sender's time stamps).
            assert_eq!(stamps, frames, "{side} {topic}");
        }
    }
    for got in [&tx, &rx] {
        assert_eq!(got["/tf_static"].0, "tf2_msgs/msg/TFMessage");
        assert_eq!(got["/tf_static"].1, frames[..1]);
    }
    outside_check(&tx_rec, &[]);
    outside_check(&rx_rec, &[]);
}

/// The pair sent twice to a gateway's station `north-1` (no broker: the
/// stations work on): the gateway's recording holds the station's topics
/// under `/north_1`, stamped as the sender's.
#[test]
fn the_gateway_records_each_station_under_its_name() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let (tx_rec, gw_rec) = (dir.path().join("tx.mcap"), dir.path().join("gw.mcap"));
    let (a, b) = (free_port(), free_port());
    let station = format!("north-1=udp:127.0.0.1:{b}?peer=127.0.0.1:{a}");
    let mut args = strings(&[
        "gateway",
        "--link",
        &station,
        "--mqtt",
        "mqtt://127.0.0.1:1",
    ]);
    args.extend(strings(&[
        "--run-s",
        "3",
        "--images-every-s",
        "0",
        "--stats-every-s",
        "1",
    ]));
    args.extend(strings(&[
        "--max-disp",
        "24",
        "--record",
        gw_rec.to_str().unwrap(),
    ]));
    let gw = spawn(&args);
    std::thread::sleep(Duration::from_millis(200));
    let mut args = send_args(&format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"), &scene);
    args.extend(strings(&[
        "--repeat",
        "2",
        "--record",
        tx_rec.to_str().unwrap(),
    ]));
    finish(spawn(&args), "send");
    finish(gw, "gateway");

    let (tx, gw) = (topics(&tx_rec), topics(&gw_rec));
    let frames = &tx["/stereo/left/image_rect_color"].1;
    for topic in [
        "/stereo/left/image_rect_color",
        "/stereo/right/camera_info",
        "/stereo/disparity",
        "/stereo/depth_report",
    ] {
        let (name, stamps) = &gw[&format!("/north_1{topic}")];
        assert_eq!((name, stamps), (&tx[topic].0, frames), "{topic}");
    }
    assert_eq!(
        gw["/north_1/diagnostics"].0,
        "diagnostic_msgs/msg/DiagnosticArray"
    );
    assert!(!gw.contains_key("/stereo/depth_report"), "{:?}", gw.keys());
    outside_check(&gw_rec, &["--station", "north_1"]);
}

#[test]
fn an_unwritable_recording_fails_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("no-such-dir").join("r.mcap");
    let port = free_port();
    let link = format!("udp:127.0.0.1:{port}?peer=127.0.0.1:{}", free_port());
    let out = Command::new(env!("CARGO_BIN_EXE_stereolink"))
        .args([
            "receive",
            "--link",
            &link,
            "--insecure",
            "--timeout-s",
            "30",
        ])
        .args(["--record", bad.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(said.contains(bad.to_str().unwrap()), "{said}");
}
