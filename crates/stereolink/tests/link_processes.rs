//! Sender and receiver as two separate processes over UDP on loopback and
//! over a pair of pseudo-terminals with a noisy emulated radio: every
//! message must arrive byte-identical. A bond of two UDP pairs one of which
//! goes away mid-stream: the rest goes over the other; a bond of two paced
//! ZigBee radio pairs: each carries its share at its own pace. And a sender with
//! nobody to answer it: it must say what to check and fail, never hang in
//! silence.

mod common;

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use common::xbee::{Cable, Firmware, RadioLink, Timing};
use common::{finish, free_port, spawn, strings, synth, udp_relay};

/// `send` of the scene's pair with a small disparity range and k-means,
/// after `args` (the link and the options of the test).
fn send_scene(scene: &std::path::Path, args: &[&str]) -> std::process::Child {
    let mut all = strings(&["send"]);
    all.extend(strings(args));
    all.extend(strings(&[
        "--left",
        scene.join("left.png").to_str().unwrap(),
        "--right",
        scene.join("right.png").to_str().unwrap(),
        "--max-disp",
        "23",
        "--method",
        "kmeans",
    ]));
    spawn(&all)
}

fn link_test(link: &str, role: &str, count: &str, size: &str) -> std::process::Child {
    spawn(&[
        "link-test",
        "--link",
        link,
        "--role",
        role,
        "--count",
        count,
        "--size",
        size,
    ])
}

#[test]
fn udp_between_two_processes() {
    let (a, b) = (free_port(), free_port());
    let rx = link_test(
        &format!("udp:127.0.0.1:{b}?peer=127.0.0.1:{a}"),
        "receive",
        "3",
        "20000",
    );
    std::thread::sleep(Duration::from_millis(200));
    let tx = link_test(
        &format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"),
        "send",
        "3",
        "20000",
    );
    let sent = finish(tx, "sender");
    let got = finish(rx, "receiver");
    assert!(sent.contains("3/3 messages"), "{sent}");
    assert!(
        got.contains("3/3 messages") && got.contains("0 corrupted"),
        "{got}"
    );
}

/// A UDP relay between `a` and `b` on loopback that carries `budget`
/// datagrams from `a`, then goes away (the radio pair between them died):
/// nothing more crosses it either way. It stops by itself.
fn relay_that_dies(a: u16, b: u16, budget: usize) -> u16 {
    let (start, mut left) = (Instant::now(), budget);
    udp_relay(a, b, move |from_a, _| {
        if left == 0 || start.elapsed() > Duration::from_secs(60) {
            return None;
        }
        left -= usize::from(from_a);
        Some(true)
    })
}

/// `link-test` over a bond of two UDP pairs, the first through a relay
/// that dies after 300 datagrams: every message arrives intact over the
/// second, and both ends say they dropped the first.
#[test]
fn a_bond_survives_a_pair_that_goes_away_mid_stream() {
    let [a1, a2, b1, b2] = [(); 4].map(|_| free_port());
    let relay = relay_that_dies(a1, b1, 300);
    let udp = |port: u16, peer: u16| format!("udp:127.0.0.1:{port}?peer=127.0.0.1:{peer}");
    let run = |role: &str, links: [String; 2]| {
        let mut args = strings(&["--json", "link-test", "--role", role]);
        args.extend(strings(&["--count", "20", "--size", "20000"]));
        for l in links {
            args.extend(["--link".to_string(), l]);
        }
        spawn(&args)
    };
    let rx = run("receive", [udp(b1, relay), udp(b2, a2)]);
    std::thread::sleep(Duration::from_millis(200));
    let tx = run("send", [udp(a1, relay), udp(a2, b2)]);
    let json = |text: String| -> serde_json::Value { serde_json::from_str(&text).unwrap() };
    let (sent, got) = (json(finish(tx, "sender")), json(finish(rx, "receiver")));
    for (end, s, port) in [("sender", &sent, a1), ("receiver", &got, b1)] {
        assert_eq!(s["delivered"], 20, "{end}: {s}");
        assert_eq!(
            (&s["failed"], &s["corrupted"]),
            (&0.into(), &0.into()),
            "{end}: {s}"
        );
        let first = format!("udp:127.0.0.1:{port}");
        assert_eq!(s["links_dropped"], serde_json::json!([first]), "{end}: {s}");
    }
}

/// `link-test` over a bond of two pairs of emulated ZigBee radios at their
/// real rates: each pair is paced by its own transmit statuses, so neither
/// radio's serial buffer overruns, both carry a share, and every message
/// arrives intact.
#[test]
fn a_bond_of_two_paced_zigbee_pairs_carries_on_both() {
    let radios = [(); 2].map(|_| RadioLink::timed(Firmware::Zigbee, Timing::zigbee()));
    let spec =
        |port: &str, dest: u64| format!("serial:{port}?baud=115200&api=2&dest=0x{dest:016X}");
    let run = |role: &str, links: Vec<String>| {
        let mut args = strings(&["--json", "link-test", "--role", role]);
        args.extend(strings(&["--count", "2", "--size", "8000"]));
        for l in links {
            args.extend(["--link".to_string(), l]);
        }
        spawn(&args)
    };
    let ends = |side: usize| -> Vec<String> {
        let to = radios.iter().map(|r| r.configs[1 - side].serial);
        let ports = radios.iter().map(|r| if side == 0 { &r.a } else { &r.b });
        ports.zip(to).map(|(p, d)| spec(p, d)).collect()
    };
    let rx = run("receive", ends(1));
    let tx = run("send", ends(0));
    let json = |text: String| -> serde_json::Value { serde_json::from_str(&text).unwrap() };
    let (sent, got) = (json(finish(tx, "sender")), json(finish(rx, "receiver")));
    assert_eq!(
        (&sent["delivered"], &got["delivered"]),
        (&2.into(), &2.into())
    );
    assert_eq!(got["corrupted"], 0, "{got}");
    for r in &radios {
        let delivered = r.counters[0].delivered.load(Ordering::Relaxed);
        assert!(delivered > 40, "a pair carried only {delivered} packets");
        let overrun = |i: usize| r.counters[i].overrun.load(Ordering::Relaxed);
        assert_eq!((overrun(0), overrun(1)), (0, 0));
    }
}

/// One delivered byte in 3001 is flipped by the emulated radios.
#[test]
fn serial_api_mode_between_two_processes_over_noisy_ptys() {
    let radio = RadioLink::new(Firmware::Ieee802154, Some(3001));
    let rx = link_test(
        &format!("serial:{}?baud=115200&api=2", radio.b),
        "receive",
        "2",
        "6000",
    );
    let tx = link_test(
        &format!("serial:{}?baud=115200&api=2", radio.a),
        "send",
        "2",
        "6000",
    );
    let sent = finish(tx, "sender");
    let got = finish(rx, "receiver");
    assert!(sent.contains("2/2 messages"), "{sent}");
    assert!(
        got.contains("2/2 messages") && got.contains("0 corrupted"),
        "{got}"
    );
}

/// `send` to a UDP port nobody listens on, with a 6 s message deadline: it
/// says once what to check, keeps trying until the deadline, then fails
/// naming the cause.
#[test]
fn send_to_nobody_says_what_to_check_and_fails_at_its_deadline() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let (a, nobody) = (free_port(), free_port());
    let start = Instant::now();
    let out = send_scene(
        &scene,
        &[
            "--link",
            &format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{nobody}"),
            "--deadline-s",
            "6",
        ],
    )
    .wait_with_output()
    .unwrap();
    let elapsed = start.elapsed();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(!out.status.success(), "{stdout}");
    assert!(!stdout.contains("sent in"), "{stdout}");
    assert_eq!(
        stderr
            .matches("is the peer running `stereolink receive`")
            .count(),
        1,
        "{stderr}"
    );
    for check in ["API mode", "baud rate", "destination", "api=0"] {
        assert!(stderr.contains(check), "no {check:?} in {stderr}");
    }
    // The pair's report and its frame both wait for the deadline; the
    // error names whichever the link gave up on first.
    assert!(
        stderr.contains("sending frame 1: no answer from the peer")
            || stderr.contains("depth report of pair 1: no answer from the peer"),
        "{stderr}"
    );
    assert!(
        elapsed >= Duration::from_secs(6),
        "gave up after {elapsed:?}"
    );
    assert!(elapsed < Duration::from_secs(60), "took {elapsed:?}");
}

/// Both ends in API mode joined by a plain cable, with no radio between (a
/// common wiring mistake): the sender says that no transmit status comes
/// back and what to check, the receiver says once that it hears transmit
/// requests meant for a radio; neither hangs.
#[test]
fn api_mode_over_a_direct_cable_says_what_is_wrong_on_both_ends() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let cable = Cable::new();
    let link = |path: &str| format!("serial:{path}?api=2&radio=802.15.4&dest=0x0002");
    let rx = spawn(&["receive", "--link", &link(&cable.b), "--timeout-s", "8"]);
    let start = Instant::now();
    let tx = send_scene(&scene, &["--link", &link(&cable.a), "--deadline-s", "6"])
        .wait_with_output()
        .unwrap();
    assert!(
        start.elapsed() < Duration::from_secs(20),
        "{:?}",
        start.elapsed()
    );
    let sent = String::from_utf8_lossy(&tx.stderr);
    assert!(!tx.status.success());
    assert!(sent.contains("no transmit status"), "{sent}");
    assert!(sent.contains("api=0"), "{sent}");
    let got = rx.wait_with_output().unwrap();
    let heard = String::from_utf8_lossy(&got.stderr);
    assert_eq!(
        heard.matches("heard XBee transmit requests").count(),
        1,
        "{heard}"
    );
    assert!(heard.contains("wired directly"), "{heard}");
}

/// The paper's two links: frames on one UDP pair, depth reports on another.
/// Both arrive; and with nobody on the report link, the reports (only
/// they) fail there.
#[test]
fn reports_take_their_own_link_with_report_link() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let ports: Vec<u16> = (0..4).map(|_| free_port()).collect();
    let link = |me: u16, peer: u16| format!("udp:127.0.0.1:{me}?peer=127.0.0.1:{peer}");
    let send = |report_link: String| {
        let primary = link(ports[0], ports[1]);
        send_scene(
            &scene,
            &[
                "--link",
                &primary,
                "--report-link",
                &report_link,
                "--repeat",
                "2",
                "--deadline-s",
                "3",
            ],
        )
    };
    let rx = spawn(&[
        "receive",
        "--link",
        &link(ports[1], ports[0]),
        "--report-link",
        &link(ports[3], ports[2]),
        "--frames",
        "2",
        "--timeout-s",
        "20",
    ]);
    std::thread::sleep(Duration::from_millis(200));
    let sent = finish(send(link(ports[2], ports[3])), "sender");
    let got = finish(rx, "receiver");
    for line in ["frame 1:", "frame 2:", "report 1:", "report 2:"] {
        assert!(got.contains(line), "{line} missing: {got}");
    }
    // Each frame's report was acknowledged, or overtaken by the next
    // pair's before its acknowledgement came (the receiver had both).
    assert_eq!(
        sent.matches("depth report delivered").count()
            + sent.matches("depth report overtaken").count(),
        2,
        "{sent}"
    );
    // Nobody on the report link: the frames still go to a receiver of
    // the frames' link alone, and the reports fail on their own link.
    let mut frames_only = spawn(&[
        "receive",
        "--link",
        &link(ports[1], ports[0]),
        "--timeout-s",
        "20",
    ]);
    std::thread::sleep(Duration::from_millis(200));
    let nobody = free_port();
    let out = send(link(ports[2], nobody)).wait_with_output().unwrap();
    frames_only.kill().unwrap();
    frames_only.wait().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("depth report of pair") && err.contains("no answer from the peer"),
        "{err}"
    );
}
