//! The gateway's MQTT 5 against an outside MQTT 5 client
//! (`tools/mqtt5_probe.py`, PyPI `paho-mqtt`) through a real Mosquitto:
//! the message expiry interval on every depth report, no stale report
//! delivered to a subscriber that comes back late, and a command answered
//! on its response topic with its correlation data. The probe runs when
//! paho-mqtt is installed, and must under `STEREOLINK_REQUIRE_PAHO=1`, as
//! CI sets after installing it. 3.1.1 (`--mqtt-version 3.1.1`) is tested
//! in `gateway_tls.rs` (`over_tls_every_report_arrives_once`).

#![cfg(all(feature = "gateway", not(target_arch = "arm")))]

mod common;

use common::mqtt::*;
use serde_json::Value;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

/// Whether python3 has paho-mqtt (failing the test if it must).
fn have_paho() -> bool {
    let required = std::env::var("STEREOLINK_REQUIRE_PAHO").as_deref() == Ok("1");
    let have = Command::new("python3")
        .args(["-c", "import paho.mqtt.client"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(have || !required, "python3 cannot import paho.mqtt");
    if !have {
        eprintln!("skipped: pip install paho-mqtt");
    }
    have
}

/// Runs the probe against `broker` as the operator, away `away_s`.
fn probe(broker: &Broker, away_s: f64) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools/mqtt5_probe.py");
    let (user, pw) = PASSWORDS[1];
    let out = Command::new("python3")
        .arg(script)
        .args(["--port", &broker.port.to_string(), "--user", user])
        .args(["--password", pw, "--away-s", &away_s.to_string()])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&out.stderr);
    let got: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("the probe printed no JSON ({e}): {said}"));
    assert!(out.status.success(), "the probe timed out: {got} {said}");
    got
}

/// MQTT 5 by default: every depth report carries the expiry interval
/// (`--depth-expiry-s 1`), a subscriber away for 3 s is not handed the
/// reports that expired meanwhile (its persistent session queued them),
/// and a command with a response topic and correlation data is answered
/// there (`ok`, then the station's `done`), correlated.
#[test]
fn an_mqtt5_client_sees_the_expiry_and_gets_correlated_answers() {
    let Some(broker) = Broker::start() else {
        return;
    };
    if !have_paho() {
        return;
    }
    let (gw, specs) = Gateway::start(&broker, &["cam1"], &["--depth-expiry-s", "1"]);
    wait_bridge_online(&broker);
    let interval = Duration::from_millis(50);
    let sims = stations(&specs, 100_000, interval);
    let got = probe(&broker, 3.0);
    drop(sims);
    assert!(gw.log().contains("(MQTT 5)"), "{}", gw.log());
    let reports = |phase: &str| got[phase].as_array().unwrap().clone();
    let (before, after) = (reports("before"), reports("after"));
    assert!(!before.is_empty() && after.len() >= 10, "{got}");
    // Delivered at once, each report carries the interval.
    for r in &before {
        assert_eq!(r["expiry_s"].as_u64(), Some(1), "{r}");
    }
    // Held for the subscriber, it carries what is left of it: Mosquitto
    // counts whole seconds of its clock, and leaves the property out once
    // the second the report came in has passed.
    for r in &after {
        let expiry = r["expiry_s"].as_u64();
        assert!(matches!(expiry, Some(1) | None), "{r}");
    }
    assert!(
        after.iter().any(|r| r["expiry_s"] == 1),
        "the fresh reports carry the interval: {got}"
    );
    // Reports the broker held for the absent subscriber are at most the
    // interval old (Mosquitto counts whole seconds: under 2 s; 2.5 s with
    // the delivery under load), and the older ones never came: a gap in
    // the ids across the 3 s away.
    let max_age = after
        .iter()
        .map(|r| r["age_s"].as_f64().unwrap())
        .fold(0.0, f64::max);
    assert!(
        max_age < 2.2,
        "a stale report was delivered ({max_age:.2} s)"
    );
    let id = |r: &Value| r["frame_id"].as_u64().unwrap();
    let last_before = before.iter().map(id).max().unwrap();
    let first_after = after.iter().map(id).min().unwrap();
    eprintln!(
        "away 3 s: reports {last_before} then {first_after}; oldest delivered {max_age:.2} s old"
    );
    assert!(
        first_after > last_before + 10,
        "the reports of the absence were delivered: {last_before} then {first_after}"
    );
    // The command's answers: on the response topic, with the correlation
    // data, and the transaction field absent (none was given).
    let responses = got["responses"].as_array().unwrap();
    let statuses: Vec<&str> = responses
        .iter()
        .map(|r| r["payload"]["status"].as_str().unwrap_or("?"))
        .collect();
    assert_eq!(statuses, ["ok", "done"], "{got}");
    // An expiry asked of 3.1.1, which has none, is an error.
    let out = common::stereolink()
        .args(["gateway", "--link", "udp:127.0.0.1:1?peer=127.0.0.1:2"])
        .args(["--mqtt-version", "3.1.1", "--depth-expiry-s", "2"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("MQTT 5"), "{err}");
    for r in responses {
        assert_eq!(r["topic"], "stereolink/cam1/response/probe", "{r}");
        assert_eq!(r["correlation"], "c-42", "{r}");
        assert_eq!(r["payload"]["command"], "levels 4", "{r}");
    }
}
