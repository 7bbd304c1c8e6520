//! Helpers shared by the process-level tests: running the binary, free UDP
//! ports, ([`xbee`]) an emulated pair of XBee radios between two
//! pseudo-terminals, and ([`mqtt`]) a Mosquitto, a subscriber and the
//! gateway process.

#![allow(dead_code)] // each test binary uses its own subset

#[cfg(all(feature = "gateway", not(target_arch = "arm")))]
pub mod mqtt;
pub mod xbee;

use std::process::{Child, Command, Stdio};

/// The binary, as a command to add arguments to.
pub fn stereolink() -> Command {
    Command::new(env!("CARGO_BIN_EXE_stereolink"))
}

/// The JSON a successful run printed (its stderr in the failure message).
#[track_caller]
pub fn json(out: &std::process::Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// The JSON document `--json` printed, from captured stdout.
#[track_caller]
pub fn json_text(stdout: &str) -> serde_json::Value {
    serde_json::from_str(stdout).unwrap_or_else(|e| panic!("not JSON ({e}): {stdout}"))
}

/// Starts the binary with piped output.
pub fn spawn<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_stereolink"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Starts `receive` on UDP port `b` with its peer on port `a`, a simulated
/// axis and no keys, matching 24 disparities; `extra` adds arguments.
pub fn spawn_udp_receiver(a: u16, b: u16, extra: &[&str]) -> Child {
    let link = format!("udp:127.0.0.1:{b}?peer=127.0.0.1:{a}");
    let mut args = vec!["receive", "--link", &link, "--robot", "sim", "--insecure"];
    args.extend(["--max-disp", "24"]);
    args.extend(extra);
    spawn(&args)
}

/// Runs the binary to its end, asserts success, returns its stdout.
pub fn run_ok(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_stereolink"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// Waits for a process, asserts success, returns its stdout.
pub fn finish(child: Child, what: &str) -> String {
    finish_with_stderr(child, what).0
}

/// As [`finish`], with what the child said on stderr.
pub fn finish_with_stderr(child: Child, what: &str) -> (String, String) {
    let out = child.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    let said = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{what} failed: {text}{said}");
    (text, said)
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

/// A UDP relay on loopback between ports `a` and `b`: each datagram goes
/// on to the other side if `forward(from_a, datagram)` says `Some(true)`, is
/// dropped on `Some(false)`, and `None` stops the relay (nothing more
/// crosses it either way). Returns the relay's port, which both ends give
/// as their peer.
pub fn udp_relay(
    a: u16,
    b: u16,
    mut forward: impl FnMut(bool, &[u8]) -> Option<bool> + Send + 'static,
) -> u16 {
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = socket.local_addr().unwrap().port();
    socket
        .set_read_timeout(Some(std::time::Duration::from_millis(50)))
        .unwrap();
    std::thread::spawn(move || {
        let mut buf = [0u8; 2048];
        loop {
            let Ok((n, from)) = socket.recv_from(&mut buf) else {
                continue;
            };
            let from_a = from.port() == a;
            match forward(from_a, &buf[..n]) {
                None => return,
                Some(false) => {}
                Some(true) => {
                    let to = if from_a { b } else { a };
                    let _ = socket.send_to(&buf[..n], ("127.0.0.1", to));
                }
            }
        }
    });
    port
}

/// A UDP port free at the time of the call.
pub fn free_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// `send` of the synthetic pair in `scene` over `link`, for the synthetic
/// rig (focal length 128 px, baseline 3 cm, 23 disparities).
pub fn send_args(link: &str, scene: &std::path::Path) -> Vec<String> {
    let file = |name: &str| scene.join(name).to_str().unwrap().to_string();
    let mut args = strings(&["send", "--link", link, "--max-disp", "23"]);
    args.extend(strings(&["--focal-px", "128", "--baseline-m", "0.03"]));
    args.extend([
        "--left".into(),
        file("left.png"),
        "--right".into(),
        file("right.png"),
    ]);
    args
}
