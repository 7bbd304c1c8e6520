//! The MQTT gateway against a real Mosquitto (Debian's `mosquitto`), each
//! test with its own broker on a free port and its own config in a temp
//! folder, built from `tools/mosquitto/` (its ACL as shipped). Stations are
//! simulated ([`SimStation`]: synthetic frames and reports over UDP on
//! 127.0.0.1), or a real `stereolink send` process for the commands; the
//! gateway is the `stereolink gateway` process.
//!
//! Without `/usr/sbin/mosquitto` the tests are skipped, except under
//! `CI=true`, where they fail and say to install it.

#![cfg(all(feature = "gateway", not(target_arch = "arm")))]

mod common;

use common::mqtt::*;
use serde_json::Value;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};
use stereolink_codec::control::{unix_us, Command as StationCommand};
use stereolink_gateway::sim::{SimConfig, SimStation};
use stereolink_link::secure::{keyfile, Keys};

const FOUR: [&str; 4] = ["cam1", "cam2", "cam3", "cam4"];

/// 4 stations x 100 reports (a frame with every 10th) through one
/// gateway: every report arrives once, by id, and the retained state is
/// right.
#[test]
fn soak_four_stations_every_report_arrives_once() {
    let Some(broker) = Broker::start() else {
        return;
    };
    let sub = Subscriber::start(
        &broker,
        "viewer",
        "soak-sub",
        &["stereolink/#", "homeassistant/#"],
        false,
    );
    let (gw, specs) = Gateway::start(&broker, &FOUR, &["--homeassistant", "homeassistant"]);
    sub.wait_for("bridge/state online", Duration::from_secs(10), |g| {
        g.iter()
            .any(|g| g.topic == "stereolink/bridge/state" && g.payload == b"online")
    });
    let sims = stations(&specs, 100, Duration::from_millis(10));
    wait_finished(&sims, Duration::from_secs(30));
    sub.wait_for("400 depth reports", Duration::from_secs(10), |g| {
        g.iter().filter(|g| g.topic.ends_with("/depth")).count() >= 400
    });
    std::thread::sleep(Duration::from_millis(1500)); // late duplicates, link stats
    let got = sub.all();
    assert_complete(&got, &FOUR, 100);
    for s in sims {
        let log = s.stop();
        let log = log.lock().unwrap();
        assert_eq!(log.reports_delivered, 100, "{:?}", log.failures);
        assert!(log.failures.is_empty(), "{:?}", log.failures);
    }
    for name in FOUR {
        let t = |rest: &str| format!("stereolink/{name}/{rest}");
        assert_eq!(sub.last(&t("availability")).as_deref(), Some("online"));
        let meta: Value = serde_json::from_str(&sub.last(&t("frame")).unwrap()).unwrap();
        assert_eq!(
            (meta["width"].as_u64(), meta["height"].as_u64()),
            (Some(128), Some(96))
        );
        for img in ["left", "view3d", "disparity"] {
            let png = got
                .iter()
                .rev()
                .find(|g| g.topic == t(&format!("frame/{img}")))
                .unwrap();
            assert!(png.payload.starts_with(b"\x89PNG"), "{img} is a PNG");
            assert!(png.retain || png.at_us > 0);
        }
        let link: Value = serde_json::from_str(&sub.last(&t("link")).unwrap()).unwrap();
        assert!(link["depth_reports"].as_u64().unwrap() >= 100, "{link}");
        // The retransmission rate: duplicates over the segments received.
        let (dups, segs) = (link["retransmissions"].as_u64(), link["segments"].as_u64());
        let rate = link["retransmission_rate"].as_f64().unwrap();
        assert!(segs.unwrap() >= 100, "{link}");
        assert_eq!(rate, dups.unwrap() as f64 / segs.unwrap() as f64, "{link}");
        let depth = got.iter().find(|g| g.topic == t("depth")).unwrap();
        let d = json(depth);
        for field in [
            "frame_id",
            "distance_m",
            "levels",
            "time_us",
            "received_us",
            "link",
        ] {
            assert!(!d[field].is_null(), "depth has {field}: {d}");
        }
    }
    // Home Assistant discovery: the distance sensor reads the depth topic.
    let sensor = sub
        .last("homeassistant/sensor/stereolink_cam1_distance/config")
        .unwrap();
    let sensor: Value = serde_json::from_str(&sensor).unwrap();
    assert_eq!(sensor["state_topic"], "stereolink/cam1/depth");
    let list: Value =
        serde_json::from_str(&sub.last("stereolink/bridge/stations").unwrap()).unwrap();
    assert_eq!(list.as_array().unwrap().len(), 4);
    let latency: Vec<f64> = got
        .iter()
        .filter(|g| g.topic.ends_with("/depth"))
        .map(|g| (g.at_us as f64 - json(g)["received_us"].as_f64().unwrap()) / 1e3)
        .collect();
    eprintln!(
        "gateway -> subscriber latency: median {:.2} ms over {} reports",
        median(latency),
        got.len()
    );
    drop(gw);
}

/// The broker restarts in the middle of the soak: the gateway reconnects,
/// nothing is lost (its queue and its own republishing), and the retained
/// state is right afterwards.
#[test]
fn broker_restart_mid_soak_loses_no_report() {
    let Some(mut broker) = Broker::start() else {
        return;
    };
    // A persistent session: the broker keeps it (and what arrives for it)
    // across its restart.
    let sub = Subscriber::start(
        &broker,
        "viewer",
        "restart-sub",
        &["stereolink/+/depth"],
        true,
    );
    let (gw, specs) = Gateway::start(&broker, &FOUR, &[]);
    wait_bridge_online(&broker);
    let sims = stations(&specs, 100, Duration::from_millis(25));
    std::thread::sleep(Duration::from_millis(800));
    broker.stop();
    std::thread::sleep(Duration::from_millis(700));
    broker.run();
    wait_finished(&sims, Duration::from_secs(30));
    sub.wait_for("400 depth reports", Duration::from_secs(15), |g| {
        distinct_reports(g) >= 400
    });
    std::thread::sleep(Duration::from_millis(500));
    // Retained state after the restart, as a new client sees it.
    let fresh = Subscriber::start(&broker, "viewer", "after", &["stereolink/#"], false);
    fresh.wait_for("the retained state", Duration::from_secs(5), |g| {
        g.iter()
            .filter(|g| g.retain && g.topic.ends_with("/availability"))
            .count()
            >= 4
            && g.iter().any(|g| g.topic.ends_with("bridge/health"))
    });
    // QoS 1 is at least once: a report whose PUBACK the restart cut off
    // is published again by the gateway, and may arrive twice; so may one
    // the broker redelivers to the subscriber (flagged DUP, left out
    // here); no other may.
    let republished = fresh.last("stereolink/bridge/health").unwrap();
    let republished = serde_json::from_str::<Value>(&republished).unwrap()["republished"]
        .as_u64()
        .unwrap() as usize;
    let twice = assert_complete_but(&sub.all(), &FOUR, 100, republished);
    eprintln!("after the restart: {republished} published again, {twice} reports arrived twice");
    assert_eq!(
        fresh.last("stereolink/bridge/state").as_deref(),
        Some("online")
    );
    for name in FOUR {
        assert_eq!(
            fresh
                .last(&format!("stereolink/{name}/availability"))
                .as_deref(),
            Some("online")
        );
    }
    fresh.wait_for(
        "a reconnect in bridge/health",
        Duration::from_secs(3),
        |g| {
            g.iter()
                .filter(|g| g.topic.ends_with("bridge/health"))
                .any(|g| json(g)["reconnects"].as_u64() >= Some(1))
        },
    );
    let health = fresh.last("stereolink/bridge/health").unwrap();
    let health: Value = serde_json::from_str(&health).unwrap();
    assert_eq!(health["dropped_total"], 0, "{health}");
    assert!(gw.log().contains("reconnected"), "{}", gw.log());
    for s in sims {
        s.stop();
    }
}

/// The broker stays away while a station sends more than the queue holds:
/// the oldest reports are dropped and counted in `bridge/health`, the rest
/// arrive once the broker is back.
#[test]
fn broker_away_longer_than_the_queue_drops_the_oldest_and_counts_them() {
    let Some(mut broker) = Broker::start() else {
        return;
    };
    let sub = Subscriber::start(
        &broker,
        "viewer",
        "queue-sub",
        &["stereolink/+/depth"],
        true,
    );
    let (_gw, specs) = Gateway::start(
        &broker,
        &["cam1"],
        &["--queue", "20", "--stats-every-s", "60"],
    );
    wait_bridge_online(&broker);
    broker.stop();
    let sims = stations(&specs, 60, Duration::from_millis(5));
    wait_finished(&sims, Duration::from_secs(20));
    broker.run();
    let fresh = Subscriber::start(
        &broker,
        "viewer",
        "queue-after",
        &["stereolink/bridge/health"],
        false,
    );
    fresh.wait_for("drops in bridge/health", Duration::from_secs(10), |g| {
        g.iter()
            .any(|g| json(g)["dropped"]["depth"].as_u64() > Some(0))
    });
    let health = json(
        fresh
            .all()
            .iter()
            .rev()
            .find(|g| json(g)["dropped"]["depth"].as_u64() > Some(0))
            .unwrap(),
    );
    let dropped = health["dropped"]["depth"].as_u64().unwrap() as usize;
    sub.wait_for("the queued reports", Duration::from_secs(5), |g| {
        g.iter().filter(|g| !g.dup).count() + dropped >= 60
    });
    std::thread::sleep(Duration::from_millis(300));
    let mut ids = depth_ids(&sub.all()).remove("cam1").unwrap_or_default();
    ids.sort_unstable();
    eprintln!(
        "queue 20: {} reports arrived, {dropped} dropped and counted",
        ids.len()
    );
    assert_eq!(ids.len() + dropped, 60, "{ids:?}, {health}");
    // The oldest went: what arrived is the newest, in one run.
    assert_eq!(ids, ((60 - ids.len() as u32 + 1)..=60).collect::<Vec<_>>());
    for s in sims {
        s.stop();
    }
}

fn key_pair(dir: &Path, name: &str) -> ([u8; 32], [u8; 32]) {
    let (private, public) = keyfile::generate(&dir.join(name)).unwrap();
    (
        keyfile::read_key(&private).unwrap(),
        keyfile::read_key(&public).unwrap(),
    )
}

/// "stop" from an operator reaches the station over its sealed link and
/// stops its axis within 200 ms, answered with the transaction; the same
/// command from a viewer (and from an anonymous client) is refused by the
/// broker and never reaches the station.
#[test]
fn commands_from_an_operator_stop_the_axis_and_others_are_refused() {
    let Some(broker) = Broker::start() else {
        return;
    };
    let keys = broker.dir.path().join("keys");
    std::fs::create_dir(&keys).unwrap();
    let (gw_private, gw_public) = key_pair(&keys, "gateway");
    let (cam_private, _) = key_pair(&keys, "cam1");
    let _ = gw_private;
    let (gw, specs) = Gateway::start(
        &broker,
        &["cam1"],
        &[
            "--key",
            keys.join("gateway.key").to_str().unwrap(),
            "--peer-keys",
            keys.to_str().unwrap(),
        ],
    );
    let mut cfg = SimConfig::new(
        specs[0].parse().unwrap(),
        10_000,
        Duration::from_millis(100),
    );
    cfg.keys = Some(Keys::new(cam_private, gw_public));
    cfg.frame_every = 0;
    let sim = SimStation::start(cfg).unwrap();
    let op = Subscriber::start(&broker, "operator", "op", &["stereolink/cam1/#"], false);
    op.wait_for("cam1 online", Duration::from_secs(10), |g| {
        g.iter()
            .any(|g| g.topic.ends_with("cam1/availability") && g.payload == b"online")
    });
    // An unauthorised client first: the viewer may read, not command.
    let viewer = Subscriber::start(
        &broker,
        "viewer",
        "viewer",
        &["stereolink/cam1/response"],
        false,
    );
    viewer.publish(
        "stereolink/cam1/set",
        r#"{"axis":"stop","transaction":"v1"}"#,
    );
    let anonymous = Command::new("mosquitto_pub")
        .args(["-h", "127.0.0.1", "-p", &broker.port.to_string(), "-q", "1"])
        .args([
            "-t",
            "stereolink/cam1/set",
            "-m",
            r#"{"axis":"stop","transaction":"a1"}"#,
        ])
        .output()
        .unwrap();
    assert!(
        !anonymous.status.success(),
        "an anonymous client is refused at CONNECT"
    );
    std::thread::sleep(Duration::from_millis(1000));
    assert!(
        sim.log.lock().unwrap().commands.is_empty(),
        "no refused command reached the station"
    );
    assert!(
        !op.all().iter().any(|g| g.topic.ends_with("/response")),
        "no response to a refused command"
    );
    assert!(
        broker.log().contains("Denied PUBLISH from viewer"),
        "{}",
        broker.log()
    );
    // A malformed command is answered with an error.
    op.publish("stereolink/cam1/set", r#"{"axis":"go","transaction":7}"#);
    op.wait_for("the error response", Duration::from_secs(5), |g| {
        g.iter()
            .any(|g| g.topic.ends_with("/response") && json(g)["transaction"] == 7)
    });
    let r = op
        .all()
        .into_iter()
        .find(|g| g.topic.ends_with("/response"))
        .unwrap();
    assert_eq!(json(&r)["status"], "error");
    // The operator's stop.
    assert!(sim.log.lock().unwrap().failures.is_empty());
    let sent = Instant::now();
    op.publish(
        "stereolink/cam1/set",
        r#"{"axis":"stop","transaction":"t1"}"#,
    );
    op.wait_for("the stop response", Duration::from_secs(5), |g| {
        g.iter()
            .any(|g| g.topic.ends_with("/response") && json(g)["transaction"] == "t1")
    });
    let answered = sent.elapsed();
    let response = op
        .all()
        .into_iter()
        .find(|g| g.topic.ends_with("/response") && json(g)["transaction"] == "t1")
        .unwrap();
    assert_eq!(json(&response)["status"], "ok", "{}", json(&response));
    // Then the station's own word: it did it.
    let acted = |g: &Got| json(g)["transaction"] == "t1" && json(g)["status"] == "done";
    op.wait_for(
        &format!(
            "the station's reply; gateway: {}, station: {:?}",
            gw.log(),
            sim.log.lock().unwrap().failures
        ),
        Duration::from_secs(5),
        |g| g.iter().any(|g| g.topic.ends_with("/response") && acted(g)),
    );
    std::thread::sleep(Duration::from_millis(300));
    let log = sim.stop();
    let log = log.lock().unwrap();
    let [(StationCommand::AxisStop, at)] = log.commands[..] else {
        panic!("the station took {:?}", log.commands);
    };
    let took = at.duration_since(sent);
    eprintln!("stop: executed {took:?} after the publish, answered after {answered:?}");
    assert!(took < Duration::from_millis(200), "stop took {took:?}");
    let p = &log.stopped_at_mm;
    let spread =
        p.iter().copied().fold(f64::MIN, f64::max) - p.iter().copied().fold(f64::MAX, f64::min);
    assert!(spread < 1.0, "the axis kept moving after the stop: {p:?}");
    drop(gw);
}

/// A real `send` process as the station, sealed to the gateway: an
/// operator's levels, method and frame request reach it over MQTT and its
/// link, each answered `ok` (delivered) then `done` (its reply); the frame
/// it sends on request is segmented with the new settings (the frame
/// metadata says so); a stop, which a sender cannot honour, is answered
/// `refused` with why.
#[test]
fn a_real_sender_obeys_levels_method_and_frame_request_and_refuses_a_stop() {
    let Some(broker) = Broker::start() else {
        return;
    };
    let dir = broker.dir.path();
    let keys = dir.join("keys");
    std::fs::create_dir(&keys).unwrap();
    key_pair(&keys, "gateway");
    key_pair(&keys, "cam1");
    let key = |name: &str, ext: &str| keys.join(format!("{name}.{ext}"));
    let (gw, specs) = Gateway::start(
        &broker,
        &["cam1"],
        &[
            "--key",
            key("gateway", "key").to_str().unwrap(),
            "--peer-keys",
            keys.to_str().unwrap(),
            "--images-every-s",
            "0",
        ],
    );
    // One synthetic pair in a camera folder.
    let (scene, watch) = (dir.join("scene"), dir.join("watch"));
    let synth = Command::new(env!("CARGO_BIN_EXE_stereolink"))
        .args(["synth", scene.to_str().unwrap(), "--width", "160"])
        .args(["--height", "120", "--max-disp", "16", "--seed", "3"])
        .stdout(Stdio::null())
        .status()
        .unwrap();
    assert!(synth.success());
    std::fs::create_dir(&watch).unwrap();
    for view in ["left", "right"] {
        let to = watch.join(format!("{view}-1.png"));
        std::fs::copy(scene.join(format!("{view}.png")), to).unwrap();
    }
    let op = Subscriber::start(&broker, "operator", "op", &["stereolink/cam1/#"], false);
    let mut send = Command::new(env!("CARGO_BIN_EXE_stereolink"))
        .args([
            "send",
            "--link",
            &specs[0],
            "--watch",
            watch.to_str().unwrap(),
        ])
        .args(["--poll-ms", "50", "--frames", "2", "--max-disp", "16"])
        .args(["--method", "kmeans", "--levels", "3"])
        .args(["--key", key("cam1", "key").to_str().unwrap()])
        .args(["--peer-key", key("gateway", "pub").to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join("send.log")).unwrap())
        .spawn()
        .unwrap();
    let frame = |g: &Got, id: u64| g.topic == "stereolink/cam1/frame" && json(g)["frame_id"] == id;
    op.wait_for("frame 1", Duration::from_secs(30), |g| {
        g.iter().any(|g| frame(g, 1))
    });
    for set in [
        r#"{"levels":5,"transaction":"l"}"#,
        r#"{"method":"otsu","transaction":"m"}"#,
        r#"{"axis":"stop","transaction":"s"}"#,
        r#"{"frame":"request","transaction":"f"}"#,
    ] {
        op.publish("stereolink/cam1/set", set);
    }
    let answer = |g: &Got, t: &str, status: &str| {
        g.topic == "stereolink/cam1/response"
            && json(g)["transaction"] == t
            && json(g)["status"] == status
    };
    let answers = [
        ("l", "done"),
        ("m", "done"),
        ("s", "refused"),
        ("f", "done"),
    ];
    op.wait_for(
        &format!("the replies and frame 2; gateway: {}", gw.log()),
        Duration::from_secs(30),
        |g| {
            g.iter().any(|g| frame(g, 2))
                && answers.iter().all(|(t, s)| {
                    g.iter().any(|g| answer(g, t, "ok")) && g.iter().any(|g| answer(g, t, s))
                })
        },
    );
    let got = op.all();
    let meta = json(got.iter().find(|g| frame(g, 2)).unwrap());
    assert_eq!(
        (meta["levels"].as_u64(), meta["segmentation"].as_str()),
        (Some(5), Some("otsu")),
        "{meta}"
    );
    let first = json(got.iter().find(|g| frame(g, 1)).unwrap());
    assert_eq!(
        (first["levels"].as_u64(), first["segmentation"].as_str()),
        (Some(3), Some("kmeans")),
        "{first}"
    );
    let stop = json(got.iter().find(|g| answer(g, "s", "refused")).unwrap());
    assert!(
        stop["error"].as_str().unwrap().contains("no axis"),
        "{stop}"
    );
    // Each command: delivered first, then the station's word.
    for (t, s) in answers {
        let at = |status: &str| got.iter().position(|g| answer(g, t, status)).unwrap();
        assert!(at("ok") < at(s), "{t}: the reply came before the delivery");
    }
    let until = Instant::now() + Duration::from_secs(30);
    while send.try_wait().unwrap().is_none() {
        assert!(Instant::now() < until, "send did not end");
        std::thread::sleep(Duration::from_millis(50));
    }
    let said = std::fs::read_to_string(dir.join("send.log")).unwrap();
    assert!(send.wait().unwrap().success(), "{said}");
    assert!(said.contains("command 3 (axis stop): refused"), "{said}");
    drop(gw);
}

/// A killed station turns `offline` within its timeout while the other
/// stays `online`, and comes back `online` when it restarts; a killed gateway turns `bridge/state` `offline` (its
/// last will).
#[test]
fn killed_station_goes_offline_then_resumes_and_killed_gateway_leaves_its_will() {
    let Some(broker) = Broker::start() else {
        return;
    };
    let (mut gw, specs) = Gateway::start(&broker, &["cam1", "cam2"], &["--offline-after-s", "1.5"]);
    let sub = Subscriber::start(&broker, "viewer", "avail", &["stereolink/#"], false);
    let sims = stations(&specs, 10_000, Duration::from_millis(100));
    sub.wait_for("both online", Duration::from_secs(10), |g| {
        ["cam1", "cam2"].iter().all(|n| {
            g.iter().any(|g| {
                g.topic == format!("stereolink/{n}/availability") && g.payload == b"online"
            })
        })
    });
    let mut sims = sims.into_iter();
    let (cam1, cam2) = (sims.next().unwrap(), sims.next().unwrap());
    cam1.kill();
    let (killed, killed_us) = (Instant::now(), unix_us());
    sub.wait_for("cam1 offline", Duration::from_secs(4), |g| {
        g.iter().any(|g| {
            g.topic == "stereolink/cam1/availability"
                && g.payload == b"offline"
                && g.at_us > killed_us
        })
    });
    let took = killed.elapsed();
    eprintln!("cam1 offline {took:?} after it was killed (timeout 1.5 s)");
    assert!(took < Duration::from_millis(2500), "{took:?}");
    assert_eq!(
        sub.last("stereolink/cam2/availability").as_deref(),
        Some("online")
    );
    // cam1 restarts (a new process: a new link session) and resumes.
    let back_us = unix_us();
    let mut cfg = SimConfig::new(specs[0].parse().unwrap(), 5, Duration::from_millis(20));
    cfg.first_id = 1000;
    let cam1 = SimStation::start(cfg).unwrap();
    sub.wait_for(
        "cam1 back online with its new reports",
        Duration::from_secs(5),
        |g| {
            let after = |g: &&Got| g.at_us > back_us;
            let online = g
                .iter()
                .filter(after)
                .any(|g| g.topic == "stereolink/cam1/availability" && g.payload == b"online");
            let reports = g
                .iter()
                .filter(after)
                .filter(|g| g.topic == "stereolink/cam1/depth");
            online && reports.count() == 5
        },
    );
    assert!(cam1.stop().lock().unwrap().failures.is_empty());
    // Stopped while the gateway still answers (else its last report
    // would wait for the ARQ deadline).
    cam2.stop();
    let gw_killed_us = unix_us();
    gw.child.kill().unwrap();
    sub.wait_for("bridge/state offline", Duration::from_secs(10), |g| {
        g.iter().any(|g| {
            g.topic == "stereolink/bridge/state"
                && g.payload == b"offline"
                && g.at_us > gw_killed_us
        })
    });
}

/// CPU time (user + system) of process `pid`, seconds.
fn cpu_s(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .unwrap()
        .1
        .split_whitespace()
        .collect();
    // utime and stime are fields 14 and 15 (1-based), in clock ticks (100 Hz).
    let ticks: f64 = fields[11].parse::<f64>().unwrap() + fields[12].parse::<f64>().unwrap();
    ticks / 100.0
}

/// A measurement, not a test (run by hand, `--ignored`): 16 stations, each
/// paced at 115200 baud (10.56 kB of messages a second, the UART bound),
/// a frame and its depth report back to back, through one gateway with its
/// default settings (or those of STEREOLINK_GATEWAY_ARGS). Prints the gateway's CPU share of one core and the
/// latency from a report's reassembly to the subscriber. The frame is
/// Cones (450x375, k-means 3 levels, 14 kB) when STEREOLINK_DATA is set,
/// else a synthetic 480x272 scene.
#[test]
#[ignore]
fn measure_sixteen_paced_stations() {
    let Some(broker) = Broker::start() else {
        return;
    };
    let names: Vec<String> = (1..=16).map(|i| format!("cam{i}")).collect();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    let sub = Subscriber::start(&broker, "viewer", "measure", &["stereolink/+/depth"], false);
    // More gateway options from the environment, e.g. "--images-every-s 0".
    let extra = std::env::var("STEREOLINK_GATEWAY_ARGS").unwrap_or_default();
    let extra: Vec<&str> = extra.split_whitespace().collect();
    let (gw, specs) = Gateway::start(&broker, &names, &extra);
    let frame = std::env::var("STEREOLINK_DATA").ok().map(|d| {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("cones.slf");
        let cones = Path::new(&d).join("cones");
        let ok = Command::new(env!("CARGO_BIN_EXE_stereolink"))
            .arg("encode")
            .args([cones.join("left.png"), cones.join("right.png")])
            .arg("-o")
            .arg(&out)
            .args(["--method", "kmeans", "--levels", "3"])
            .stdout(Stdio::null())
            .status()
            .unwrap();
        assert!(ok.success());
        Arc::new(std::fs::read(out).unwrap())
    });
    let sims: Vec<SimStation> = specs
        .iter()
        .map(|s| {
            let mut c = SimConfig::new(s.parse().unwrap(), 100_000, Duration::ZERO);
            c.frame_every = 1;
            c.bytes_per_s = 115_200.0 * 0.733 / 8.0; // 84.5 kb/s
            c.frame = frame.clone();
            c.scene.width = 480;
            c.scene.height = 272;
            c.scene.max_disp = 32;
            SimStation::start(c).unwrap()
        })
        .collect();
    std::thread::sleep(Duration::from_secs(5));
    let (cpu0, t0, n0) = (cpu_s(gw.child.id()), Instant::now(), sub.all().len());
    std::thread::sleep(Duration::from_secs(30));
    let (cpu1, secs) = (cpu_s(gw.child.id()), t0.elapsed().as_secs_f64());
    let got = sub.all();
    let reports: Vec<&Got> = got[n0..].iter().collect();
    let after = |f: &str| -> Vec<f64> {
        reports
            .iter()
            .map(|g| (g.at_us as f64 - json(g)[f].as_f64().unwrap()) / 1e3)
            .collect()
    };
    eprintln!(
        "16 stations, {:.1} reports/s: gateway CPU {:.1} % of one core; latency median {:.2} ms \
         from reassembly, {:.2} ms from the station's stamp",
        reports.len() as f64 / secs,
        (cpu1 - cpu0) / secs * 100.0,
        median(after("received_us")),
        median(after("time_us")),
    );
    drop(sims);
}

/// Under systemd (`Type=notify`, `WatchdogSec=`): the gateway says it is
/// ready once the broker has answered, pings the watchdog while its loop
/// turns, and says it is stopping.
#[test]
fn gateway_tells_systemd_it_is_ready_once_the_broker_answers() {
    use std::os::unix::net::UnixDatagram;
    let Some(broker) = Broker::start() else {
        return;
    };
    let socket = broker.dir.path().join("notify");
    let systemd = UnixDatagram::bind(&socket).unwrap();
    systemd
        .set_read_timeout(Some(Duration::from_secs(20)))
        .unwrap();
    let (g, s) = (common::free_port(), common::free_port());
    let link = format!("cam1=udp:127.0.0.1:{g}?peer=127.0.0.1:{s}");
    // As systemd starts it: WATCHDOG_PID is the service's own pid.
    let child = Command::new("sh")
        .args(["-c", "WATCHDOG_PID=$$ exec \"$0\" \"$@\""])
        .arg(env!("CARGO_BIN_EXE_stereolink"))
        .args(["gateway", "--link", &link, "--mqtt", &broker.url("gateway")])
        .args(["--max-disp", "16", "--run-s", "2"])
        .env("NOTIFY_SOCKET", &socket)
        .env("WATCHDOG_USEC", "200000")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut said = Vec::new();
    let mut buf = [0u8; 512];
    while !said.iter().any(|s: &String| s.contains("STOPPING=1")) {
        let n = systemd
            .recv(&mut buf)
            .expect("a notification from the gateway");
        said.push(String::from_utf8_lossy(&buf[..n]).into_owned());
    }
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        said[0].contains("READY=1") && said[0].contains("bridging to"),
        "{said:?}"
    );
    let pings = said.iter().filter(|s| s.contains("WATCHDOG=1")).count();
    // 2 s of running, a ping at most every 100 ms.
    assert!(pings >= 5, "{said:?}");
}
