//! `send` and `receive` as separate processes over UDP and over a pair of
//! pseudo-terminals joined by an emulated radio, with the display writing
//! PNGs and the simulated axis; the received views must equal the sent
//! segmented views bit for bit, and the axis must end at the reported
//! distance. Also the demo on a small scene.

mod common;

use std::sync::atomic::Ordering;
use std::time::Duration;

use common::xbee::{Firmware, RadioLink, Timing};
use common::{
    finish, finish_with_stderr, free_port, json_text, send_args, spawn, spawn_udp_receiver,
    strings, synth,
};
use serde_json::Value;
use stereolink_image::io;

/// Where the board's disparity comes from in [`run_pair`].
#[derive(Clone, Copy, PartialEq)]
enum Board {
    /// WTA on the rebuilt pair.
    Wta,
    /// The sender's plane table (`send --algo planes`, `receive
    /// --disparity planes`): the board's map must be the sender's.
    Planes,
}

/// The distance `send --json` reported for its first frame, metres.
fn reported_m(sent: &Value) -> f64 {
    sent["frames"][0]["distance_m"].as_f64().unwrap()
}

/// Where `receive --json`'s first depth report sent the axis, mm.
fn commanded_mm(got: &Value) -> f64 {
    got["events"]
        .as_array()
        .unwrap()
        .iter()
        .find_map(|e| e["Report"]["commanded_mm"].as_f64())
        .unwrap_or_else(|| panic!("no report moved the axis: {got}"))
}

/// Runs one `receive` and one `send` of a synthetic pair; returns what the
/// sender said on stderr.
fn run_pair(rx_link: String, tx_link: String, board: Board) -> String {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let (shots, saved) = (dir.path().join("screens"), dir.path().join("saved"));
    let mut rx_args = strings(&[
        "--json",
        "receive",
        "--link",
        &rx_link,
        "--robot",
        "sim",
        "--insecure",
        "--frames",
        "1",
        "--max-disp",
        "24",
        "--timeout-s",
        "60",
    ]);
    if board == Board::Planes {
        rx_args.extend(strings(&["--disparity", "planes"]));
    }
    rx_args.extend(strings(&[
        "--display",
        &format!("png:{}", shots.display()),
        "--save",
        saved.to_str().unwrap(),
    ]));
    let rx = spawn(&rx_args);
    std::thread::sleep(Duration::from_millis(200));
    let mut tx_args = send_args(&tx_link, &scene);
    tx_args.extend(strings(&[
        "--json",
        "--save",
        saved.to_str().unwrap(),
        "--method",
        "kmeans",
        "--levels",
        "4",
    ]));
    if board == Board::Planes {
        // A coarser table than the default: more segments left implied.
        tx_args.extend(strings(&["--algo", "planes", "--plane-implied-below", "6"]));
        tx_args.extend(strings(&["--plane-slant-bits", "10"]));
    }
    let tx = spawn(&tx_args);
    let (sent, said) = finish_with_stderr(tx, "send");
    let got = finish(rx, "receive");
    for side in ["left", "right"] {
        let a = io::read_rgb(saved.join(format!("sent-{side}.png"))).unwrap();
        let b = io::read_rgb(saved.join(format!("received-{side}.png"))).unwrap();
        assert_eq!(a, b, "{side} view differs");
    }
    let pfm = |name: &str| stereolink_image::pfm::read(saved.join(name)).unwrap();
    let (sent_map, board_map) = (pfm("sent-disparity.pfm"), pfm("received-disparity.pfm"));
    if board == Board::Planes {
        // The plane table rebuilt the sender's map on the board, bit for bit.
        assert_eq!(sent_map, board_map, "the board's planes map differs");
        let valid = board_map
            .as_slice()
            .iter()
            .filter(|d| d.is_finite())
            .count();
        assert!(valid * 10 > board_map.as_slice().len() * 9, "{valid} valid");
    } else {
        assert_eq!(board_map.dims(), sent_map.dims());
    }
    assert!(shots.join("screen-00001.png").is_file());
    assert_eq!(
        io::read_rgb(shots.join("screen.png")).unwrap().dims(),
        (480, 272)
    );
    // The axis was sent to the reported distance (clamped to its 1 m
    // travel), and went there within 0.5 mm.
    let (sent, got) = (json_text(&sent), json_text(&got));
    let reported = (reported_m(&sent) * 1000.0).min(1000.0);
    let commanded = commanded_mm(&got);
    let axis = got["summary"]["axis_mm"].as_f64().unwrap();
    assert!(
        (commanded - reported).abs() <= 1e-3,
        "axis sent to {commanded} mm for {reported} mm ({sent} / {got})"
    );
    assert!(
        (axis - commanded).abs() <= 0.5,
        "axis {axis} mm for {commanded} mm ({sent} / {got})"
    );
    said
}

#[test]
fn send_and_receive_over_udp() {
    let (a, b) = (free_port(), free_port());
    run_pair(
        format!("udp:127.0.0.1:{b}?peer=127.0.0.1:{a}"),
        format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"),
        Board::Wta,
    );
}

/// One report starts a long, slow move, then the link falls silent: the
/// receiver's watchdog stops the axis after `--watchdog-s`, though no
/// message arrives to wake it, and says so once.
#[test]
fn a_silent_link_trips_the_watchdog_and_stops_the_axis() {
    let (a, b) = (free_port(), free_port());
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let rx = spawn_udp_receiver(
        a,
        b,
        &[
            "--frames",
            "0",
            "--timeout-s",
            "4",
            "--watchdog-s",
            "1",
            "--max-speed",
            "20",
            "--json",
        ],
    );
    std::thread::sleep(Duration::from_millis(200));
    let link = format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}");
    let mut tx_args = send_args(&link, &scene);
    tx_args.push("--json".into());
    let sent = json_text(&finish(spawn(&tx_args), "send"));
    let (got, said) = finish_with_stderr(rx, "receive");
    let got = json_text(&got);
    let commanded = (reported_m(&sent) * 1000.0).min(1000.0);
    let axis = got["summary"]["axis_mm"].as_f64().unwrap();
    assert!(commanded > 200.0, "a long move: {commanded} mm");
    // Stopped where the watchdog found it, far short of the target (without
    // the watchdog the axis goes on to the target).
    assert!(
        axis > 0.0 && axis < 60.0,
        "axis at {axis} mm of {commanded}"
    );
    assert_eq!(said.matches("watchdog: ").count(), 1, "{said}");
}

/// `send --algo planes` and `receive --disparity planes` over UDP: the
/// frame carries the plane table and the board rebuilds the sender's map.
#[test]
fn planes_over_udp_rebuild_the_senders_map() {
    let (a, b) = (free_port(), free_port());
    run_pair(
        format!("udp:127.0.0.1:{b}?peer=127.0.0.1:{a}"),
        format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"),
        Board::Planes,
    );
}

/// Over two emulated 802.15.4 radios (TX16 to the broadcast address).
#[test]
fn send_and_receive_over_a_pty_pair() {
    let radio = RadioLink::new(Firmware::Ieee802154, None);
    run_pair(
        format!("serial:{}?baud=115200&api=2", radio.b),
        format!("serial:{}?baud=115200&api=2", radio.a),
        Board::Wta,
    );
}

/// Over two emulated Zigbee radios, each end addressed by the other's
/// 64-bit serial number: both ask their radio, send 0x10 requests with
/// fragments of at most the radios' NP (84 bytes), and the pair arrives bit
/// for bit; the radios were given no frame they ignore.
#[test]
fn send_and_receive_over_two_emulated_zigbee_radios() {
    let radio = RadioLink::new(Firmware::Zigbee, None);
    let (a, b) = (radio.configs[0].serial, radio.configs[1].serial);
    run_pair(
        format!("serial:{}?baud=115200&api=2&dest=0x{a:016X}", radio.b),
        format!("serial:{}?baud=115200&api=2&dest=0x{b:016X}", radio.a),
        Board::Wta,
    );
    let count = |i: usize, c: fn(&common::xbee::Counters) -> &std::sync::atomic::AtomicUsize| {
        c(&radio.counters[i]).load(std::sync::atomic::Ordering::Relaxed)
    };
    // Radio 0 serves the sender: the frame's fragments, full to NP.
    assert!(
        count(0, |c| &c.delivered) > 10,
        "{}",
        count(0, |c| &c.delivered)
    );
    assert_eq!(count(0, |c| &c.largest), 84);
    assert!(count(1, |c| &c.delivered) > 0 && count(1, |c| &c.largest) <= 84);
    assert_eq!((count(0, |c| &c.ignored), count(1, |c| &c.ignored)), (0, 0));
}

/// Over two emulated ZigBee radios with their real rates: the UART at
/// 115200 baud is faster than the air, so a sender that wrote as fast as its
/// UART takes bytes would overrun the radio's 256-byte serial buffer. Paced
/// by the transmit status, not one byte is lost and the views arrive bit for
/// bit.
#[test]
fn paced_by_transmit_status_the_zigbee_radios_buffer_never_overruns() {
    let radio = RadioLink::timed(Firmware::Zigbee, Timing::zigbee());
    let (a, b) = (radio.configs[0].serial, radio.configs[1].serial);
    run_pair(
        format!("serial:{}?baud=115200&api=2&dest=0x{a:016X}", radio.b),
        format!("serial:{}?baud=115200&api=2&dest=0x{b:016X}", radio.a),
        Board::Wta,
    );
    let overrun = |i: usize| radio.counters[i].overrun.load(Ordering::Relaxed);
    assert!(radio.counters[0].delivered.load(Ordering::Relaxed) > 10);
    assert_eq!((overrun(0), overrun(1)), (0, 0));
}

/// The sender's radio resets mid-frame, losing the requests it held without
/// a status: the link sends them again under fresh frame ids, says so, and
/// the views still arrive bit for bit.
#[test]
fn a_radio_that_resets_mid_frame_loses_nothing() {
    let radio = RadioLink::timed_with_reset(Firmware::Zigbee, Timing::zigbee(), 10);
    let (a, b) = (radio.configs[0].serial, radio.configs[1].serial);
    let said = run_pair(
        format!("serial:{}?baud=115200&api=2&dest=0x{a:016X}", radio.b),
        format!("serial:{}?baud=115200&api=2&dest=0x{b:016X}", radio.a),
        Board::Wta,
    );
    assert_eq!(radio.counters[0].resets.load(Ordering::Relaxed), 1);
    assert!(said.contains("the radio reset mid-stream"), "{said}");
    assert!(said.contains("joined network"), "{said}");
}

/// The timed emulator bites: TX requests written back to back, faster than
/// the air carries them, overrun its buffer and lose bytes.
#[test]
fn a_host_that_ignores_the_radios_pace_overruns_its_buffer() {
    use std::io::Write;
    let radio = RadioLink::timed(Firmware::Zigbee, Timing::zigbee());
    let mut port = serialport::new(&radio.a, 115_200).open().unwrap();
    let dest = radio.configs[1].serial;
    for id in 1..=12u8 {
        let request = stereolink_link::xbee::Frame::ZbTx {
            frame_id: id,
            dest64: dest,
            dest16: 0xFFFE,
            radius: 0,
            options: 0,
            data: vec![id; 84],
        };
        port.write_all(&request.encode(stereolink_link::xbee::ApiMode::Escaped))
            .unwrap();
    }
    std::thread::sleep(Duration::from_millis(400));
    assert!(radio.counters[0].overrun.load(Ordering::Relaxed) > 0);
    assert!(radio.counters[0].delivered.load(Ordering::Relaxed) < 12);
}

#[test]
fn demo_on_a_small_synthetic_scene() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo-out");
    let scene = dir.path().join("scene");
    synth(&scene);
    let run = spawn(&strings(&[
        "--json",
        "demo",
        "--out",
        out.to_str().unwrap(),
        "--scene",
        scene.to_str().unwrap(),
        "--method",
        "otsu",
    ]));
    let text = finish(run, "demo");
    let report: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(report["received_equals_sent"], true);
    assert!(report["axis_error_mm"].as_f64().unwrap() <= 0.5, "{report}");
    let (d, t) = (
        report["distance_m"].as_f64().unwrap(),
        report["true_distance_m"].as_f64().unwrap(),
    );
    assert!((d - t).abs() / t < 0.05, "distance {d} vs ground truth {t}");
    for f in [
        "sent/left.png",
        "sent/right.png",
        "received/left.png",
        "received/right.png",
        "screen.png",
        "report.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    assert_eq!(
        io::read_rgb(out.join("sent/left.png")).unwrap(),
        io::read_rgb(out.join("received/left.png")).unwrap()
    );
}

/// `send --watch` sends the newest pair a camera wrote into a folder,
/// skipping (and counting) the older ones and one that cannot be read; a
/// pair written later is the next frame. The receiver shows both frames.
#[test]
fn send_watches_a_camera_folder_newest_first() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let camera = dir.path().join("camera");
    std::fs::create_dir(&camera).unwrap();
    let write_pair = |i: u32| {
        // The right view first: a pair is complete once its left view is there.
        for side in ["right", "left"] {
            std::fs::copy(
                scene.join(format!("{side}.png")),
                camera.join(format!("{side}_{i}.png")),
            )
            .unwrap();
        }
    };
    write_pair(1);
    write_pair(2);
    // The newest, and not images: skipped with a message.
    std::fs::write(camera.join("left_3.png"), b"not a png").unwrap();
    std::fs::write(camera.join("right_3.png"), b"nor this").unwrap();
    let shots = dir.path().join("screens");
    let (a, b) = (free_port(), free_port());
    let display = format!("png:{}", shots.display());
    let rx = spawn_udp_receiver(
        a,
        b,
        &["--frames", "2", "--timeout-s", "60", "--display", &display],
    );
    std::thread::sleep(Duration::from_millis(200));
    let tx = spawn(&strings(&[
        "--json",
        "send",
        "--link",
        &format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"),
        "--watch",
        camera.to_str().unwrap(),
        "--poll-ms",
        "50",
        "--frames",
        "2",
        "--max-disp",
        "23",
        "--method",
        "kmeans",
    ]));
    // Once the first frame is on the screen, the camera writes a new pair.
    let start = std::time::Instant::now();
    while !shots.join("screen-00001.png").is_file() {
        assert!(start.elapsed() < Duration::from_secs(60), "no first frame");
        std::thread::sleep(Duration::from_millis(20));
    }
    write_pair(4);
    let out = tx.wait_with_output().unwrap();
    let (sent, errors) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(out.status.success(), "send failed: {sent}{errors}");
    assert!(
        errors.contains("skipping") && errors.contains("left_3.png"),
        "{errors}"
    );
    let sent: serde_json::Value = serde_json::from_str(&sent).unwrap();
    let frames: Vec<_> = sent["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            (
                f["frame_id"].as_u64().unwrap(),
                f["skipped"].as_u64().unwrap(),
            )
        })
        .collect();
    // Pair 2 first (1 passed over, 3 unreadable), then pair 4.
    assert_eq!(frames, [(1, 2), (2, 0)], "{sent}");
    let status = &sent["status"];
    assert_eq!(
        (status["pairs"].as_u64(), status["skipped"].as_u64()),
        (Some(2), Some(2)),
        "{status}"
    );
    assert!(status["reports"].as_u64().unwrap() >= 1, "{status}");
    finish(rx, "receive");
    assert!(shots.join("screen-00002.png").is_file());
}

/// `stereolink --json bench live` of 20 copies of the synthetic pair at
/// 10 pairs/s over `link`.
fn bench_live(link: &str) -> serde_json::Value {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let seq = dir.path().join("seq");
    std::fs::create_dir(&seq).unwrap();
    for i in 1..=20 {
        for side in ["left", "right"] {
            std::fs::copy(
                scene.join(format!("{side}.png")),
                seq.join(format!("{side}_{i:04}.png")),
            )
            .unwrap();
        }
    }
    let calib = scene.join("calib.txt");
    let out = finish(
        spawn(&strings(&[
            "--json",
            "bench",
            "live",
            "--sequence",
            seq.to_str().unwrap(),
            "--rate",
            "10",
            "--link",
            link,
            "--calib",
            calib.to_str().unwrap(),
            "--max-disp",
            "23",
            "--method",
            "kmeans",
        ])),
        "bench live",
    );
    serde_json::from_str(&out).unwrap()
}

/// `bench live` plays a sequence at 10 pairs/s over the calibrated ZigBee
/// model: every pair is matched and its report reaches the board in order
/// (none refused as stale), frames go as the link allows, and both ends'
/// figures are in the JSON. The margins are wide: CI's two cores also run
/// other tests.
#[test]
fn bench_live_delivers_a_report_per_pair_while_frames_stream() {
    let r = bench_live("sim:?radio=zigbee");
    let (sender, receiver) = (&r["sender"], &r["receiver"]);
    let pairs = sender["pairs"].as_u64().unwrap();
    assert_eq!(pairs + sender["skipped"].as_u64().unwrap(), 20, "{r}");
    // Each pair taken gave a report; most reach the board, none stale.
    assert!(
        receiver["reports"].as_u64().unwrap() * 4 >= pairs * 3,
        "{r}"
    );
    assert_eq!(r["refused"], 0, "{r}");
    assert!(receiver["frames"].as_u64().unwrap() >= 1, "{r}");
    let latency = &receiver["report_latency_ms"];
    assert!(
        latency["p50"].as_f64().unwrap() <= latency["p99"].as_f64().unwrap(),
        "{r}"
    );
    assert!(latency["p99"].as_f64().unwrap() < 2000.0, "{r}");
}

/// On a link that collapsed (ZigBee over 4 hops with encryption, about
/// 5 kb/s), the reports of 10 pairs/s need more air than there is: depth
/// takes it all and no frame starts, and reports keep coming, none stale.
#[test]
fn bench_live_on_a_collapsed_link_sends_depth_alone() {
    let r = bench_live("sim:?radio=zigbee&hops=4&encrypted=1");
    let (sender, receiver) = (&r["sender"], &r["receiver"]);
    assert!(sender["report_air_share"].as_f64().unwrap() > 0.5, "{r}");
    assert_eq!(receiver["frames"], 0, "{r}");
    assert_eq!(r["refused"], 0, "{r}");
    // About 3.6 reports a second fit the air; 2 s of pairs.
    assert!(receiver["reports"].as_u64().unwrap() >= 3, "{r}");
}

/// A lossy pair sent within a byte budget over UDP: the frame fits, and
/// the board shows the very views the sender decoded from its own frame.
#[test]
fn a_lossy_pair_within_a_budget_over_udp() {
    let (a, b) = (free_port(), free_port());
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let saved = dir.path().join("saved");
    let shots = dir.path().join("screens");
    let saved_arg = saved.to_str().unwrap();
    let display = format!("png:{}", shots.display());
    let rx = spawn_udp_receiver(
        a,
        b,
        &[
            "--frames",
            "1",
            "--timeout-s",
            "60",
            "--save",
            saved_arg,
            "--display",
            &display,
        ],
    );
    std::thread::sleep(Duration::from_millis(200));
    let mut tx_args = vec!["--json".to_string()];
    tx_args.extend(send_args(
        &format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"),
        &scene,
    ));
    tx_args.extend(strings(&[
        "--view-coding",
        "jpeg",
        "--bytes",
        "6000",
        "--save",
        saved_arg,
    ]));
    let sent: serde_json::Value = serde_json::from_str(&finish(spawn(&tx_args), "send")).unwrap();
    finish(rx, "receive");
    let frame = &sent["frames"][0];
    assert_eq!(frame["view_coding"], "jpeg", "{sent}");
    let bytes = frame["frame_bytes"].as_u64().unwrap();
    assert!(bytes <= 6000 && bytes > 3000, "{bytes} B");
    for side in ["left", "right"] {
        let a = io::read_rgb(saved.join(format!("sent-{side}.png"))).unwrap();
        let b = io::read_rgb(saved.join(format!("received-{side}.png"))).unwrap();
        assert_eq!(a, b, "{side} view differs");
    }
    assert!(shots.join("screen-00001.png").is_file());
}

/// A WebP pair over UDP, stereo prediction on (the default) and off: with
/// it, the frame carries the sender's disparities and the board shows them
/// (no matching), rebuilding the right view bit for bit from the left;
/// without it, the board matches the pair.
#[test]
fn a_stereo_predicted_pair_over_udp_carries_its_disparity() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    for stereo in ["on", "off"] {
        let (a, b) = (free_port(), free_port());
        let saved = dir.path().join(format!("saved-{stereo}"));
        let saved_arg = saved.to_str().unwrap();
        let rx = spawn_udp_receiver(
            a,
            b,
            &[
                "--json",
                "--frames",
                "1",
                "--timeout-s",
                "60",
                "--save",
                saved_arg,
            ],
        );
        std::thread::sleep(Duration::from_millis(200));
        let mut tx_args = vec!["--json".to_string()];
        tx_args.extend(send_args(
            &format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"),
            &scene,
        ));
        tx_args.extend(strings(&[
            "--view-coding",
            "webp",
            "--bytes",
            "6000",
            "--stereo-prediction",
            stereo,
            "--save",
            saved_arg,
        ]));
        let sent: serde_json::Value =
            serde_json::from_str(&finish(spawn(&tx_args), "send")).unwrap();
        let received: serde_json::Value = serde_json::from_str(&finish(rx, "receive")).unwrap();
        let summary = &received["summary"];
        let frame = &sent["frames"][0];
        assert_eq!(frame["stereo_prediction"], stereo == "on", "{sent}");
        assert!(frame["frame_bytes"].as_u64().unwrap() <= 6000, "{sent}");
        let carried = u64::from(stereo == "on");
        assert_eq!(summary["carried_disparity_frames"], carried, "{summary}");
        for side in ["left", "right"] {
            let a = io::read_rgb(saved.join(format!("sent-{side}.png"))).unwrap();
            let b = io::read_rgb(saved.join(format!("received-{side}.png"))).unwrap();
            assert_eq!(a, b, "{stereo}: {side} view differs");
        }
    }
}

/// `send --temporal` over UDP: after a key frame, a pair seen again is
/// predicted from the frame the link delivered and costs a fraction of it;
/// the board rebuilds it bit for bit as the sender's closed loop did.
#[test]
fn predicted_frames_over_udp_rebuild_the_senders_reconstruction() {
    let (a, b) = (free_port(), free_port());
    predicted_frames_rebuild_the_senders_reconstruction(
        &format!("udp:127.0.0.1:{b}?peer=127.0.0.1:{a}"),
        &format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"),
    );
}

/// The same over two emulated ZigBee radios at their real rate, each end
/// addressed by the other's serial number.
#[test]
fn predicted_frames_over_emulated_zigbee_radios_rebuild_the_senders_reconstruction() {
    let radio = RadioLink::timed(Firmware::Zigbee, Timing::zigbee());
    let (a, b) = (radio.configs[0].serial, radio.configs[1].serial);
    predicted_frames_rebuild_the_senders_reconstruction(
        &format!("serial:{}?baud=115200&api=2&dest=0x{a:016X}", radio.b),
        &format!("serial:{}?baud=115200&api=2&dest=0x{b:016X}", radio.a),
    );
}

/// `send --temporal --repeat 4` to `receive`: a key frame, then predicted
/// frames of at most a quarter of it, and the board's last pair is the
/// sender's reconstruction, bit for bit.
fn predicted_frames_rebuild_the_senders_reconstruction(rx_link: &str, tx_link: &str) {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let saved = dir.path().join("saved");
    let saved_arg = saved.to_str().unwrap();
    let rx = spawn(&[
        "receive",
        "--link",
        rx_link,
        "--robot",
        "sim",
        "--insecure",
        "--max-disp",
        "24",
        "--frames",
        "4",
        "--timeout-s",
        "60",
        "--save",
        saved_arg,
    ]);
    std::thread::sleep(Duration::from_millis(200));
    let mut tx_args = vec!["--json".to_string()];
    tx_args.extend(send_args(tx_link, &scene));
    tx_args.extend(strings(&[
        "--view-coding",
        "webp",
        "--quality",
        "60",
        "--temporal",
        "--repeat",
        "4",
        "--save",
        saved_arg,
    ]));
    let sent: serde_json::Value = serde_json::from_str(&finish(spawn(&tx_args), "send")).unwrap();
    finish(rx, "receive");
    let frames = sent["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 4, "{sent}");
    let (first, last) = (&frames[0], &frames[3]);
    assert_eq!(first["frame_kind"], "key", "{sent}");
    assert_eq!(last["frame_kind"], "predicted", "{sent}");
    let bytes = |f: &serde_json::Value| f["frame_bytes"].as_u64().unwrap();
    assert!(bytes(last) * 4 <= bytes(first), "{sent}");
    // The last pair as the sender's loop rebuilt it, and as the board did.
    for side in ["left", "right"] {
        let a = io::read_rgb(saved.join(format!("sent-{side}.png"))).unwrap();
        let b = io::read_rgb(saved.join(format!("received-{side}.png"))).unwrap();
        assert_eq!(a, b, "{side} view differs");
    }
}

/// Under systemd (`Type=notify`, `WatchdogSec=`): `receive` says it is
/// ready once its link is open, pings the watchdog while its loop turns
/// (here with nothing arriving), and says it is stopping, on the socket
/// systemd names.
#[test]
fn receive_tells_systemd_it_is_ready_and_alive() {
    use std::os::unix::net::UnixDatagram;
    let dir = tempfile::tempdir().unwrap();
    let socket = dir.path().join("notify");
    let systemd = UnixDatagram::bind(&socket).unwrap();
    systemd
        .set_read_timeout(Some(Duration::from_secs(20)))
        .unwrap();
    let (a, b) = (free_port(), free_port());
    let link = format!("udp:127.0.0.1:{b}?peer=127.0.0.1:{a}");
    // As systemd starts it: WATCHDOG_PID is the service's own pid.
    let child = std::process::Command::new("sh")
        .args(["-c", "WATCHDOG_PID=$$ exec \"$0\" \"$@\""])
        .arg(env!("CARGO_BIN_EXE_stereolink"))
        .args(["receive", "--link", &link, "--timeout-s", "2"])
        .env("NOTIFY_SOCKET", &socket)
        .env("WATCHDOG_USEC", "200000")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut said = Vec::new();
    let mut buf = [0u8; 512];
    while !said.iter().any(|s: &String| s.contains("STOPPING=1")) {
        let n = systemd.recv(&mut buf).expect("a notification from receive");
        said.push(String::from_utf8_lossy(&buf[..n]).into_owned());
    }
    finish(child, "receive");
    assert!(said[0].contains("READY=1"), "{said:?}");
    let pings = said.iter().filter(|s| s.contains("WATCHDOG=1")).count();
    // 2 s of a quiet link, a ping at most every 100 ms, the loop turning
    // every 200 ms.
    assert!(pings >= 3, "{said:?}");
}
