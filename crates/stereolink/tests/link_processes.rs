//! Sender and receiver as two separate processes over UDP on loopback and
//! over a pair of pseudo-terminals, through injected faults where the
//! transport allows: every message must arrive byte-identical.

use std::io::{Read, Write};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use serialport::{SerialPort, TTYPort};
use stereolink_link::xbee::{ApiMode, Frame, Parser};

fn stereolink(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_stereolink"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn finish(child: Child, what: &str) -> String {
    let out = child.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{what} failed: {text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    text
}

fn free_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

#[test]
fn udp_between_two_processes() {
    let (a, b) = (free_port(), free_port());
    let rx = stereolink(&[
        "link-test",
        "--link",
        &format!("udp:127.0.0.1:{b}?peer=127.0.0.1:{a}"),
        "--role",
        "receive",
        "--count",
        "3",
        "--size",
        "20000",
    ]);
    std::thread::sleep(Duration::from_millis(200));
    let tx = stereolink(&[
        "link-test",
        "--link",
        &format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"),
        "--role",
        "send",
        "--count",
        "3",
        "--size",
        "20000",
    ]);
    let sent = finish(tx, "sender");
    let got = finish(rx, "receiver");
    assert!(sent.contains("3/3 messages"), "{sent}");
    assert!(
        got.contains("3/3 messages") && got.contains("0 corrupted"),
        "{got}"
    );
}

/// Emulates the two radios between two pty pairs: TX16 requests written by
/// one process come out of the other pty as RX16 frames (API mode 2), and one
/// delivered byte in 3001 is flipped on the way, so the CRCs must catch it.
fn radio(
    mut from: TTYPort,
    mut to: TTYPort,
    stop: Arc<AtomicBool>,
    salt: u32,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let mut parser = Parser::new(ApiMode::Escaped);
        let mut buf = [0u8; 256];
        let mut count = 0u32;
        while !stop.load(Ordering::Relaxed) {
            let Ok(n) = from.read(&mut buf) else { continue };
            for &b in &buf[..n] {
                if let Some(Ok(Frame::Tx16 { data, .. })) = parser.push(b) {
                    let mut wire = Frame::Rx16 {
                        source: 0x0001,
                        rssi: 0x28,
                        options: 0,
                        data,
                    }
                    .encode(ApiMode::Escaped);
                    for byte in wire.iter_mut().skip(1) {
                        count = count.wrapping_add(1);
                        if count.wrapping_mul(2_654_435_761).wrapping_add(salt) % 3001 == 0 {
                            *byte ^= 0x10;
                        }
                    }
                    let _ = to.write_all(&wire);
                }
            }
        }
    })
}

#[test]
fn serial_api_mode_between_two_processes_over_noisy_ptys() {
    let (mut m1, s1) = TTYPort::pair().unwrap();
    let (mut m2, s2) = TTYPort::pair().unwrap();
    let (p1, p2) = (s1.name().unwrap(), s2.name().unwrap());
    m1.set_timeout(Duration::from_millis(5)).unwrap();
    m2.set_timeout(Duration::from_millis(5)).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let t1 = radio(
        m1.try_clone_native().unwrap(),
        m2.try_clone_native().unwrap(),
        stop.clone(),
        1,
    );
    let t2 = radio(m2, m1, stop.clone(), 2);
    let rx = stereolink(&[
        "link-test",
        "--link",
        &format!("serial:{p2}?baud=115200&api=2"),
        "--role",
        "receive",
        "--count",
        "2",
        "--size",
        "6000",
    ]);
    let tx = stereolink(&[
        "link-test",
        "--link",
        &format!("serial:{p1}?baud=115200&api=2"),
        "--role",
        "send",
        "--count",
        "2",
        "--size",
        "6000",
    ]);
    let sent = finish(tx, "sender");
    let got = finish(rx, "receiver");
    stop.store(true, Ordering::Relaxed);
    t1.join().unwrap();
    t2.join().unwrap();
    drop((s1, s2));
    assert!(sent.contains("2/2 messages"), "{sent}");
    assert!(
        got.contains("2/2 messages") && got.contains("0 corrupted"),
        "{got}"
    );
}
