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

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rumqttc::{Client, Event, MqttOptions, Packet, QoS};
use serde_json::Value;
use stereolink_codec::control::{unix_us, Command as StationCommand};
use stereolink_gateway::sim::{SimConfig, SimStation};
use stereolink_link::secure::{keyfile, Keys};

const MOSQUITTO: &str = "/usr/sbin/mosquitto";
const PASSWORDS: [(&str, &str); 3] = [
    ("gateway", "gw-secret"),
    ("operator", "op-secret"),
    ("viewer", "view-secret"),
];

fn free_udp() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn free_tcp() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A Mosquitto of the test's own: the shipped ACL, a fresh password file.
struct Broker {
    dir: tempfile::TempDir,
    conf: PathBuf,
    port: u16,
    child: Option<Child>,
}

impl Broker {
    /// Starts one, or returns None (skip) when Mosquitto is not installed
    /// outside CI.
    fn start() -> Option<Broker> {
        if !Path::new(MOSQUITTO).exists() {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "{MOSQUITTO} is missing: install Debian's mosquitto and mosquitto-clients \
                 (.ci/run does) to run the gateway tests"
            );
            eprintln!("skipped: {MOSQUITTO} is not installed (apt-get install mosquitto mosquitto-clients)");
            return None;
        }
        let dir = tempfile::tempdir().unwrap();
        // Run as root, Mosquitto drops to its own user: it must be able to
        // write its log and its persistence file here.
        let open = |p: &Path| {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(p, std::fs::Permissions::from_mode(0o777)).unwrap()
        };
        open(dir.path());
        let passwd = dir.path().join("passwd");
        std::fs::write(&passwd, "").unwrap();
        for (user, pw) in PASSWORDS {
            let ok = Command::new("mosquitto_passwd")
                .args(["-b", passwd.to_str().unwrap(), user, pw])
                .status()
                .expect("mosquitto_passwd (Debian's mosquitto) runs");
            assert!(ok.success());
        }
        let acl = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools/mosquitto/acl");
        let shipped = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools/mosquitto/mosquitto.conf"),
        )
        .unwrap();
        let port = free_tcp();
        let data = dir.path().join("data");
        std::fs::create_dir(&data).unwrap();
        open(&data);
        // The shipped config with this test's port and paths.
        let conf_text = shipped
            .lines()
            .map(|l| match l.split_whitespace().next() {
                Some("listener") => format!("listener {port} 127.0.0.1"),
                Some("password_file") => format!("password_file {}", passwd.display()),
                Some("acl_file") => format!("acl_file {}", acl.canonicalize().unwrap().display()),
                Some("persistence_location") => {
                    format!("persistence_location {}/", data.display())
                }
                _ => l.to_string(),
            })
            .collect::<Vec<_>>()
            .join("\n")
            + &format!(
                "\nlog_dest file {}\nlog_type all\n",
                dir.path().join("broker.log").display()
            );
        let conf = dir.path().join("mosquitto.conf");
        std::fs::write(&conf, conf_text).unwrap();
        let mut b = Broker {
            dir,
            conf,
            port,
            child: None,
        };
        b.run();
        Some(b)
    }

    fn run(&mut self) {
        let child = Command::new(MOSQUITTO)
            .arg("-c")
            .arg(&self.conf)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        self.child = Some(child);
        let until = Instant::now() + Duration::from_secs(5);
        while std::net::TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            assert!(
                Instant::now() < until,
                "mosquitto did not start: {}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Stops it as a service manager does (SIGTERM: it saves its state).
    fn stop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = Command::new("kill").arg(c.id().to_string()).status();
            let _ = c.wait();
        }
    }

    fn log(&self) -> String {
        std::fs::read_to_string(self.dir.path().join("broker.log")).unwrap_or_default()
    }

    fn url(&self, user: &str) -> String {
        let pw = PASSWORDS.iter().find(|p| p.0 == user).unwrap().1;
        format!("mqtt://{user}:{pw}@127.0.0.1:{}", self.port)
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// One message as a subscriber got it.
#[derive(Clone, Debug)]
struct Got {
    topic: String,
    payload: Vec<u8>,
    retain: bool,
    /// The broker's redelivery of a message it sent before (QoS 1).
    dup: bool,
    at_us: u64,
}

/// A subscriber in a thread of its own: reconnects by itself, keeps
/// everything it got.
struct Subscriber {
    got: Arc<Mutex<Vec<Got>>>,
    subscribed: Arc<AtomicBool>,
    client: Client,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Subscriber {
    /// `persistent`: a session the broker keeps across a restart.
    fn start(broker: &Broker, user: &str, id: &str, filters: &[&str], persistent: bool) -> Self {
        let pw = PASSWORDS.iter().find(|p| p.0 == user).unwrap().1;
        let mut o = MqttOptions::new(id, "127.0.0.1", broker.port);
        o.set_credentials(user, pw)
            .set_keep_alive(Duration::from_secs(5))
            .set_clean_session(!persistent)
            .set_max_packet_size(16 << 20, 1 << 16);
        let (client, mut conn) = Client::new(o, 64);
        let got = Arc::new(Mutex::new(Vec::new()));
        let (subscribed, stop) = (
            Arc::new(AtomicBool::new(false)),
            Arc::new(AtomicBool::new(false)),
        );
        let filters: Vec<String> = filters.iter().map(|s| s.to_string()).collect();
        let thread = {
            let (client, got, subscribed, stop) = (
                client.clone(),
                got.clone(),
                subscribed.clone(),
                stop.clone(),
            );
            std::thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    match conn.recv_timeout(Duration::from_millis(50)) {
                        Ok(Ok(Event::Incoming(Packet::ConnAck(_)))) => {
                            for f in &filters {
                                client.try_subscribe(f.clone(), QoS::AtLeastOnce).unwrap();
                            }
                        }
                        Ok(Ok(Event::Incoming(Packet::SubAck(_)))) => {
                            subscribed.store(true, Ordering::Relaxed)
                        }
                        Ok(Ok(Event::Incoming(Packet::Publish(p)))) => {
                            got.lock().unwrap().push(Got {
                                topic: p.topic.clone(),
                                payload: p.payload.to_vec(),
                                retain: p.retain,
                                dup: p.dup,
                                at_us: unix_us(),
                            })
                        }
                        Ok(Ok(_)) | Err(rumqttc::RecvTimeoutError::Timeout) => {}
                        Ok(Err(_)) => std::thread::sleep(Duration::from_millis(100)),
                        Err(rumqttc::RecvTimeoutError::Disconnected) => break,
                    }
                }
            })
        };
        let s = Subscriber {
            got,
            subscribed,
            client,
            stop,
            thread: Some(thread),
        };
        let until = Instant::now() + Duration::from_secs(5);
        while !s.subscribed.load(Ordering::Relaxed) {
            assert!(
                Instant::now() < until,
                "the subscriber {id} could not subscribe"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        s
    }

    fn all(&self) -> Vec<Got> {
        self.got.lock().unwrap().clone()
    }

    /// The last payload on `topic`, as text.
    fn last(&self, topic: &str) -> Option<String> {
        let got = self.got.lock().unwrap();
        got.iter()
            .rev()
            .find(|g| g.topic == topic)
            .map(|g| String::from_utf8_lossy(&g.payload).into_owned())
    }

    /// Waits until `check` holds of what arrived, or fails saying `what`.
    fn wait_for(&self, what: &str, limit: Duration, check: impl Fn(&[Got]) -> bool) {
        let until = Instant::now() + limit;
        loop {
            if check(&self.got.lock().unwrap()) {
                return;
            }
            assert!(Instant::now() < until, "timed out waiting for {what}");
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    fn publish(&self, topic: &str, payload: &str) {
        self.client
            .publish(topic, QoS::AtLeastOnce, false, payload.as_bytes().to_vec())
            .unwrap();
    }
}

impl Drop for Subscriber {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        let _ = self.client.try_disconnect();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The gateway process and its stations' gateway-side ports.
struct Gateway {
    child: Child,
    log: PathBuf,
}

impl Gateway {
    /// Starts `stereolink gateway` for stations named `names`, each on its
    /// own UDP port pair; returns it and each station's link spec.
    fn start(broker: &Broker, names: &[&str], extra: &[&str]) -> (Gateway, Vec<String>) {
        let mut args: Vec<String> = vec!["gateway".into()];
        let mut station_specs = Vec::new();
        for n in names {
            let (g, s) = (free_udp(), free_udp());
            args.push("--link".into());
            args.push(format!("{n}=udp:127.0.0.1:{g}?peer=127.0.0.1:{s}"));
            station_specs.push(format!("udp:127.0.0.1:{s}?peer=127.0.0.1:{g}"));
        }
        args.extend(["--mqtt".into(), broker.url("gateway")]);
        // Defaults for the tests, unless `extra` sets them.
        for (flag, value) in [
            ("--stats-every-s", "1"),
            ("--health-every-s", "1"),
            ("--max-disp", "16"),
        ] {
            if !extra.contains(&flag) {
                args.extend([flag.into(), value.into()]);
            }
        }
        args.extend(extra.iter().map(|s| s.to_string()));
        let log = broker.dir.path().join("gateway.log");
        let child = Command::new(env!("CARGO_BIN_EXE_stereolink"))
            .args(&args)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap();
        (Gateway { child, log }, station_specs)
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn json(g: &Got) -> Value {
    serde_json::from_slice(&g.payload).unwrap_or(Value::Null)
}

/// Frame ids of the depth reports on each station's topic (the broker's
/// own redeliveries, flagged DUP, left out).
fn depth_ids(got: &[Got]) -> BTreeMap<String, Vec<u32>> {
    let mut ids: BTreeMap<String, Vec<u32>> = BTreeMap::new();
    for g in got.iter().filter(|g| g.topic.ends_with("/depth") && !g.dup) {
        let station = g.topic.split('/').nth(1).unwrap().to_string();
        ids.entry(station)
            .or_default()
            .push(json(g)["frame_id"].as_u64().unwrap() as u32);
    }
    ids
}

/// Asserts every station's reports 1..=n arrived, each exactly once.
#[track_caller]
fn assert_complete(got: &[Got], names: &[&str], n: u32) {
    assert_complete_but(got, names, n, 0);
}

/// Asserts every station's reports 1..=n arrived, and at most `allowed`
/// of them twice (over all stations); returns how many did.
#[track_caller]
fn assert_complete_but(got: &[Got], names: &[&str], n: u32, allowed: usize) -> usize {
    let ids = depth_ids(got);
    let mut twice = 0;
    for name in names {
        let mut v = ids.get(*name).cloned().unwrap_or_default();
        v.sort_unstable();
        let missing: Vec<u32> = (1..=n).filter(|i| v.binary_search(i).is_err()).collect();
        let dups: Vec<u32> = v
            .windows(2)
            .filter(|w| w[0] == w[1])
            .map(|w| w[0])
            .collect();
        twice += dups.len();
        assert!(
            missing.is_empty() && twice <= allowed,
            "station {name}: missing {missing:?}, duplicated {dups:?} ({allowed} allowed)"
        );
    }
    twice
}

fn stations(specs: &[String], reports: u32, interval: Duration) -> Vec<SimStation> {
    specs
        .iter()
        .map(|s| SimStation::start(SimConfig::new(s.parse().unwrap(), reports, interval)).unwrap())
        .collect()
}

fn wait_finished(sims: &[SimStation], limit: Duration) {
    let until = Instant::now() + limit;
    while !sims.iter().all(SimStation::finished) {
        assert!(
            Instant::now() < until,
            "the stations did not finish in time"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Waits until the gateway said `online` (a subscriber of its own).
fn wait_bridge_online(broker: &Broker) {
    let state = Subscriber::start(
        broker,
        "viewer",
        "state",
        &["stereolink/bridge/state"],
        false,
    );
    state.wait_for("bridge/state online", Duration::from_secs(10), |g| {
        g.iter().any(|g| g.payload == b"online")
    });
}

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
        depth_ids(g)
            .values()
            .map(|v| {
                let mut v = v.clone();
                v.sort_unstable();
                v.dedup();
                v.len()
            })
            .sum::<usize>()
            >= 400
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
