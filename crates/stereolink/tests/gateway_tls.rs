//! The MQTT gateway over TLS (`mqtts://`) against a real Mosquitto whose
//! TLS listener is the example shipped in `tools/mosquitto/mosquitto.conf`,
//! uncommented, with a CA, a broker and a client certificate that
//! `openssl` makes in each test ([`make_pki`]). The broker keeps its
//! plaintext listener too: the tests' own subscribers read there what the
//! gateway published over TLS.
//!
//! Without `/usr/sbin/mosquitto` the tests are skipped, except under
//! `CI=true`, where they fail and say to install it.

#![cfg(all(feature = "gateway", not(target_arch = "arm")))]

mod common;

use common::mqtt::*;
use serde_json::Value;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

/// The gateway's last stderr line (its error when it failed).
fn last_line(gw: &Gateway) -> String {
    gw.log().lines().last().unwrap_or_default().to_string()
}

/// Starts a gateway for `cam1` on `url`, with `more` flags, which must
/// fail on its first connection: returns its one-line error after checking
/// it exited non-zero, named the broker, and gave away no password.
fn refused(broker: &Broker, url: &str, port: u16, more: &[&str]) -> String {
    let mut args = vec!["--mqtt", url];
    args.extend(more);
    let (mut gw, _) = Gateway::start(broker, &["cam1"], &args);
    let status = gw.wait_exit(Duration::from_secs(15));
    let log = gw.log();
    let status = status.unwrap_or_else(|| panic!("the gateway kept running: {log}"));
    assert!(!status.success(), "{log}");
    let line = last_line(&gw);
    let errors: Vec<&str> = log
        .lines()
        .filter(|l| l.starts_with("stereolink:"))
        .collect();
    assert_eq!(errors, [line.as_str()], "one line says why: {log}");
    assert!(
        line.contains(&format!("://127.0.0.1:{port}")),
        "the error names the broker: {line}"
    );
    assert!(!log.contains("gw-secret"), "no password in the log: {log}");
    line
}

/// As [`refused`], on the broker's TLS port with `--mqtt-ca CA`.
fn refused_tls(broker: &Broker, ca: &Path) -> String {
    let url = broker.tls_url("gateway");
    let ca = ca.to_str().unwrap();
    refused(broker, &url, broker.tls_port.unwrap(), &["--mqtt-ca", ca])
}

/// A PKI made in `dir` (the broker's certificate `expired` or not) and a
/// broker with its TLS listener (`mutual`: client certificates required).
fn tls_broker(dir: &Path, expired: bool, mutual: bool) -> Option<(Pki, Broker)> {
    let pki = make_pki(dir, expired);
    let broker = Broker::start_tls(TlsListener {
        pki: &pki,
        require_certificate: mutual,
    })?;
    Some((pki, broker))
}

/// Over TLS the gateway relays what it relays over TCP: 2 stations x 50
/// reports, each once, and the retained state; here in MQTT 3.1.1 (the
/// other tests speak the default, 5).
#[test]
fn over_tls_every_report_arrives_once() {
    let dir = tempfile::tempdir().unwrap();
    let Some((pki, broker)) = tls_broker(dir.path(), false, false) else {
        return;
    };
    let sub = Subscriber::start(&broker, "viewer", "tls-sub", &["stereolink/#"], false);
    let url = broker.tls_url("gateway");
    let ca = pki.ca.to_str().unwrap();
    let names = ["cam1", "cam2"];
    let (gw, specs) = Gateway::start(
        &broker,
        &names,
        &["--mqtt", &url, "--mqtt-ca", ca, "--mqtt-version", "3.1.1"],
    );
    sub.wait_for(
        &format!("bridge/state online; gateway: {}", gw.log()),
        Duration::from_secs(10),
        |g| {
            g.iter()
                .any(|g| g.topic == "stereolink/bridge/state" && g.payload == b"online")
        },
    );
    let sims = stations(&specs, 50, Duration::from_millis(10));
    wait_finished(&sims, Duration::from_secs(30));
    sub.wait_for("100 depth reports", Duration::from_secs(10), |g| {
        g.iter().filter(|g| g.topic.ends_with("/depth")).count() >= 100
    });
    std::thread::sleep(Duration::from_millis(500));
    assert_complete(&sub.all(), &names, 50);
    for name in names {
        let avail = sub.last(&format!("stereolink/{name}/availability"));
        assert_eq!(avail.as_deref(), Some("online"));
    }
    let port = broker.tls_port.unwrap();
    assert!(
        gw.log()
            .contains(&format!("to mqtts://127.0.0.1:{port} (MQTT 3.1.1)")),
        "{}",
        gw.log()
    );
    for s in sims {
        s.stop();
    }
}

/// The broker restarts mid-run: the gateway reconnects over TLS (a new
/// handshake) and no report is lost.
#[test]
fn over_tls_a_broker_restart_loses_no_report() {
    let dir = tempfile::tempdir().unwrap();
    let Some((pki, mut broker)) = tls_broker(dir.path(), false, false) else {
        return;
    };
    let sub = Subscriber::start(
        &broker,
        "viewer",
        "tls-restart-sub",
        &["stereolink/+/depth"],
        true,
    );
    let url = broker.tls_url("gateway");
    let names = ["cam1", "cam2"];
    let ca = pki.ca.to_str().unwrap();
    let (gw, specs) = Gateway::start(&broker, &names, &["--mqtt", &url, "--mqtt-ca", ca]);
    wait_bridge_online(&broker);
    let sims = stations(&specs, 80, Duration::from_millis(25));
    std::thread::sleep(Duration::from_millis(700));
    broker.stop();
    std::thread::sleep(Duration::from_millis(700));
    broker.run();
    wait_finished(&sims, Duration::from_secs(30));
    sub.wait_for("160 depth reports", Duration::from_secs(15), |g| {
        distinct_reports(g) >= 160
    });
    let fresh = Subscriber::start(
        &broker,
        "viewer",
        "tls-after",
        &["stereolink/bridge/#"],
        false,
    );
    fresh.wait_for(
        "a reconnect in bridge/health",
        Duration::from_secs(5),
        |g| {
            g.iter()
                .filter(|g| g.topic.ends_with("bridge/health"))
                .any(|g| json(g)["reconnects"].as_u64() >= Some(1))
        },
    );
    let health: Value =
        serde_json::from_str(&fresh.last("stereolink/bridge/health").unwrap()).unwrap();
    let republished = health["republished"].as_u64().unwrap() as usize;
    assert_complete_but(&sub.all(), &names, 80, republished);
    assert_eq!(health["dropped_total"], 0, "{health}");
    assert_eq!(
        fresh.last("stereolink/bridge/state").as_deref(),
        Some("online")
    );
    assert!(gw.log().contains("reconnected"), "{}", gw.log());
    for s in sims {
        s.stop();
    }
}

/// A broker whose certificate another CA signed is refused at the first
/// connection, in one line naming the broker and the cause; bad TLS
/// options are refused before anything starts.
#[test]
fn a_wrong_ca_is_refused_naming_the_broker() {
    let dir = tempfile::tempdir().unwrap();
    let other = make_pki(&dir.path().join("other"), false);
    let Some((pki, broker)) = tls_broker(&dir.path().join("broker"), false, false) else {
        return;
    };
    let line = refused_tls(&broker, &other.ca);
    assert!(line.contains("not signed by a CA"), "{line}");
    assert!(line.contains("UnknownIssuer"), "{line}");
    // A CA file that is not there, and TLS files for a plaintext broker.
    let missing = dir.path().join("none.crt");
    let line = refused_tls(&broker, &missing);
    assert!(line.contains("none.crt"), "{line}");
    let plain = broker.url("gateway");
    let out = common::stereolink()
        .args(["gateway", "--link", "udp:127.0.0.1:1?peer=127.0.0.1:2"])
        .args(["--mqtt", &plain, "--mqtt-ca", pki.ca.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("mqtts://"), "{err}");
}

/// A plaintext client on the TLS port is refused; the gateway speaking TLS
/// to the plaintext port says the handshake failed, and exits.
#[test]
fn plaintext_on_the_tls_port_and_tls_on_the_plaintext_port_fail() {
    let dir = tempfile::tempdir().unwrap();
    let Some((pki, broker)) = tls_broker(dir.path(), false, false) else {
        return;
    };
    let tls_port = broker.tls_port.unwrap().to_string();
    let (user, pw) = PASSWORDS[1];
    let plain = Command::new("mosquitto_pub")
        .args(["-h", "127.0.0.1", "-p", &tls_port, "-u", user, "-P", pw])
        .args(["-q", "1", "-t", "stereolink/cam1/set", "-m", "{}"])
        .output()
        .unwrap();
    assert!(
        !plain.status.success(),
        "a plaintext client is refused on the TLS port"
    );
    // The same client over TLS is taken: the refusal was the plaintext.
    let ok = Command::new("mosquitto_pub")
        .args(["-h", "127.0.0.1", "-p", &tls_port, "-u", user, "-P", pw])
        .args(["--cafile", pki.ca.to_str().unwrap()])
        .args(["-q", "1", "-t", "stereolink/cam1/set", "-m", "{}"])
        .output()
        .unwrap();
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let pw = PASSWORDS[0].1;
    let url = format!("mqtts://gateway:{pw}@127.0.0.1:{}", broker.port);
    let ca = pki.ca.to_str().unwrap();
    let line = refused(&broker, &url, broker.port, &["--mqtt-ca", ca]);
    assert!(line.contains("TLS listener?"), "{line}");
    eprintln!("TLS on the plaintext port: {line}");
}

/// A broker that asks for client certificates takes the gateway with
/// `--mqtt-cert`/`--mqtt-key`, and refuses it without them.
#[test]
fn mutual_tls_takes_the_client_certificate_and_refuses_none() {
    let dir = tempfile::tempdir().unwrap();
    let Some((pki, broker)) = tls_broker(dir.path(), false, true) else {
        return;
    };
    let line = refused_tls(&broker, &pki.ca);
    assert!(line.contains("client certificate"), "{line}");
    let (url, ca) = (broker.tls_url("gateway"), pki.ca.to_str().unwrap());
    eprintln!("without a client certificate: {line}");
    let sub = Subscriber::start(&broker, "viewer", "mtls-sub", &["stereolink/#"], false);
    let (cert, key) = (
        pki.client.0.to_str().unwrap(),
        pki.client.1.to_str().unwrap(),
    );
    let (gw, specs) = Gateway::start(
        &broker,
        &["cam1"],
        &[
            "--mqtt",
            &url,
            "--mqtt-ca",
            ca,
            "--mqtt-cert",
            cert,
            "--mqtt-key",
            key,
        ],
    );
    let sims = stations(&specs, 20, Duration::from_millis(10));
    wait_finished(&sims, Duration::from_secs(20));
    sub.wait_for(
        &format!("20 depth reports; gateway: {}", gw.log()),
        Duration::from_secs(10),
        |g| g.iter().filter(|g| g.topic.ends_with("/depth")).count() >= 20,
    );
    assert_complete(&sub.all(), &["cam1"], 20);
    for s in sims {
        s.stop();
    }
}

/// A broker whose certificate has expired is refused, and the error says
/// it expired.
#[test]
fn an_expired_broker_certificate_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let Some((pki, broker)) = tls_broker(dir.path(), true, false) else {
        return;
    };
    let line = refused_tls(&broker, &pki.ca);
    assert!(line.contains("expired"), "{line}");
    eprintln!("expired: {line}");
}
