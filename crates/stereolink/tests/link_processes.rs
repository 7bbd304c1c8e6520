//! Sender and receiver as two separate processes over UDP on loopback and
//! over a pair of pseudo-terminals with a noisy emulated radio: every
//! message must arrive byte-identical.

mod common;

use std::time::Duration;

use common::xbee::{Firmware, RadioLink};
use common::{finish, free_port, spawn};

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
