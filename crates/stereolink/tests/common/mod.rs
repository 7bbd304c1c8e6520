//! Helpers shared by the process-level tests: running the binary, free UDP
//! ports, and an emulated pair of XBee radios between two pseudo-terminals.

#![allow(dead_code)] // each test binary uses its own subset

use std::io::{Read, Write};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use serialport::TTYPort;
use stereolink_link::xbee::{ApiMode, Frame, Parser};

/// Starts the binary with piped output.
pub fn spawn<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_stereolink"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Waits for a process, asserts success, returns its stdout.
pub fn finish(child: Child, what: &str) -> String {
    let out = child.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{what} failed: {text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    text
}

/// Owned copies of `v`, for argument lists.
pub fn strings(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

/// Writes a small synthetic scene (160x120, disparities up to 24) into `dir`.
pub fn synth(dir: &std::path::Path) {
    let status = Command::new(env!("CARGO_BIN_EXE_stereolink"))
        .args([
            "synth",
            dir.to_str().unwrap(),
            "--width",
            "160",
            "--height",
            "120",
        ])
        .args(["--max-disp", "24", "--seed", "3"])
        .stdout(Stdio::null())
        .status()
        .unwrap();
    assert!(status.success());
}

/// A UDP port free at the time of the call.
pub fn free_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// Emulates the radios between two pty masters: TX16 requests written on
/// one side come out of the other as RX16 frames (API mode 2). With
/// `corrupt_one_in = Some(n)`, about one delivered byte in n is flipped, so
/// the link's CRCs must catch it.
pub fn radio(
    mut from: TTYPort,
    mut to: TTYPort,
    stop: Arc<AtomicBool>,
    corrupt_one_in: Option<u32>,
    salt: u32,
) -> JoinHandle<()> {
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
                    if let Some(every) = corrupt_one_in {
                        for byte in wire.iter_mut().skip(1) {
                            count = count.wrapping_add(1);
                            if count.wrapping_mul(2_654_435_761).wrapping_add(salt) % every == 0 {
                                *byte ^= 0x10;
                            }
                        }
                    }
                    let _ = to.write_all(&wire);
                }
            }
        }
    })
}

/// Two pty pairs joined by [`radio`] threads: the slave device paths, and a
/// guard that stops the radios when dropped.
pub struct RadioLink {
    /// Device path of the first side.
    pub a: String,
    /// Device path of the second side.
    pub b: String,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    _slaves: (TTYPort, TTYPort),
}

impl RadioLink {
    /// Builds the pair; `corrupt_one_in` as in [`radio`].
    pub fn new(corrupt_one_in: Option<u32>) -> Self {
        use serialport::SerialPort;
        let (mut m1, s1) = TTYPort::pair().unwrap();
        let (mut m2, s2) = TTYPort::pair().unwrap();
        m1.set_timeout(std::time::Duration::from_millis(5)).unwrap();
        m2.set_timeout(std::time::Duration::from_millis(5)).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let t1 = radio(
            m1.try_clone_native().unwrap(),
            m2.try_clone_native().unwrap(),
            stop.clone(),
            corrupt_one_in,
            1,
        );
        let t2 = radio(m2, m1, stop.clone(), corrupt_one_in, 2);
        RadioLink {
            a: s1.name().unwrap(),
            b: s2.name().unwrap(),
            stop,
            threads: vec![t1, t2],
            _slaves: (s1, s2),
        }
    }
}

impl Drop for RadioLink {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}
