//! `stereolink radio` against emulated XBee radios on pseudo-terminals: what
//! each firmware reports, a radio that never answers, and how the emulated
//! radios treat frames of the other firmware and an absent peer.

mod common;

use std::time::{Duration, Instant};

use common::xbee::{Config, Firmware, RadioLink};
use common::{finish, spawn};
use serialport::SerialPort;
use stereolink_link::xbee::{ApiMode, Frame, Parser};

fn radio_json(path: &str) -> serde_json::Value {
    let out = finish(
        spawn(&["radio", "--json", "--link", &format!("serial:{path}?api=2")]),
        "radio",
    );
    serde_json::from_str(&out).unwrap()
}

#[test]
fn radio_prints_what_each_emulated_firmware_reports() {
    let cases = [
        (
            Firmware::Ieee802154,
            "802.15.4",
            "10EF",
            "1746",
            100,
            "1",
            "3332",
            None,
        ),
        (
            Firmware::Zigbee,
            "zigbee",
            "23A7",
            "1E46",
            84,
            "7D84",
            "2345",
            Some("2345"),
        ),
    ];
    for (firmware, family, vr, hv, np, my, pan, op) in cases {
        let link = RadioLink::single(Config::new(firmware, 0));
        let j = radio_json(&link.a);
        assert_eq!(j["firmware"], family, "{j}");
        assert_eq!(j["firmware_version"], vr);
        assert_eq!(j["hardware_version"], hv);
        assert_eq!(j["api_mode"], 2);
        assert_eq!(j["max_payload"], np);
        assert_eq!(j["my"], my);
        assert_eq!((&j["sh"], &j["sl"]), (&"13A200".into(), &"40A1B2C0".into()));
        assert_eq!(j["pan_id"], pan);
        assert_eq!(
            j["operating_pan"],
            op.map_or(serde_json::Value::Null, Into::into)
        );
        let text = finish(
            spawn(&["radio", "--link", &format!("serial:{}?api=2", link.a)]),
            "radio",
        );
        println!("{text}");
        assert!(
            text.contains(&format!("firmware     {family} (VR {vr})")),
            "{text}"
        );
        assert!(text.contains(&format!("NP {np} bytes")), "{text}");
    }
}

/// A pty with nothing answering (a radio at another baud rate, or in
/// transparent mode): a clear error naming what to check, within a second.
#[test]
fn a_radio_that_never_answers_is_a_clear_error_not_a_hang() {
    let (_master, slave) = serialport::TTYPort::pair().unwrap();
    let path = slave.name().unwrap();
    for cmd in [
        &["radio", "--link"][..],
        &["link-test", "--role", "send", "--link"],
    ] {
        let t = Instant::now();
        let mut args: Vec<String> = cmd.iter().map(|s| s.to_string()).collect();
        args.push(format!("serial:{path}?api=2&baud=9600"));
        let out = spawn(&args).wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success());
        assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
        for what in [
            path.as_str(),
            "9600 baud",
            "did not answer ATAP",
            "API mode",
            "api=0",
        ] {
            assert!(err.contains(what), "{what} missing from: {err}");
        }
    }
}

/// A radio whose NP leaves no room for a link segment (heavy encryption and
/// source routing can shrink it): the link refuses to open, naming NP.
#[test]
fn an_np_smaller_than_a_segment_header_is_a_clear_error() {
    let mut config = Config::new(Firmware::Zigbee, 0);
    config.np = 8;
    let link = RadioLink::single(config);
    let out = spawn(&[
        "link-test",
        "--role",
        "send",
        "--link",
        &format!("serial:{}?api=2", link.a),
    ])
    .wait_with_output()
    .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("NP is 8 bytes"), "{err}");
}

fn exchange(port: &mut dyn SerialPort, frame: Frame) -> Vec<Frame> {
    port.write_all(&frame.encode(ApiMode::Escaped)).unwrap();
    let (mut parser, mut got, mut buf) = (Parser::new(ApiMode::Escaped), vec![], [0u8; 64]);
    let until = Instant::now() + Duration::from_millis(300);
    while Instant::now() < until {
        if let Ok(n) = port.read(&mut buf) {
            got.extend(buf[..n].iter().filter_map(|&b| parser.push(b)).flatten());
        }
    }
    got
}

/// A Zigbee radio ignores an 802.15.4 TX16 (no answer, nothing sent) and
/// answers a 0x10 to an absent peer with 0x8B "address not found"; an
/// 802.15.4 radio ignores a 0x10 and answers TX16 with 0x89 "no ACK".
#[test]
fn emulated_radios_take_only_their_firmwares_frames() {
    let tx16 = Frame::Tx16 {
        frame_id: 9,
        dest: 0x1234,
        options: 0,
        data: b"x".to_vec(),
    };
    let zbtx = Frame::ZbTx {
        frame_id: 9,
        dest64: 0x0013_A200_4052_2BAA,
        dest16: 0xFFFE,
        radius: 0,
        options: 0,
        data: b"x".to_vec(),
    };
    for (firmware, foreign, own, status) in [
        (
            Firmware::Zigbee,
            tx16.clone(),
            zbtx.clone(),
            Frame::ZbTxStatus {
                frame_id: 9,
                dest16: 0xFFFE,
                retries: 0,
                delivery: 0x24,
                discovery: 0,
            },
        ),
        (
            Firmware::Ieee802154,
            zbtx,
            tx16,
            Frame::TxStatus {
                frame_id: 9,
                status: 1,
            },
        ),
    ] {
        let link = RadioLink::single(Config::new(firmware, 0));
        let mut port = serialport::new(&link.a, 115_200)
            .timeout(Duration::from_millis(5))
            .open()
            .unwrap();
        assert_eq!(exchange(&mut *port, foreign), vec![], "{firmware:?}");
        assert_eq!(
            link.counters[0]
                .ignored
                .load(std::sync::atomic::Ordering::Relaxed),
            1
        );
        assert_eq!(exchange(&mut *port, own), vec![status]);
    }
}
