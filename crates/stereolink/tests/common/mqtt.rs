//! The MQTT gateway's test harness: a Mosquitto of the test's own (the
//! shipped ACL, a fresh password file, a free port; with a TLS listener
//! too, its certificates made by `openssl` in the test), a subscriber in a
//! thread of its own, the `stereolink gateway` process, and the checks on
//! what the broker delivered.

use rumqttc::{Client, Event, MqttOptions, Packet, QoS};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use stereolink_codec::control::unix_us;
use stereolink_gateway::sim::{SimConfig, SimStation};

pub const MOSQUITTO: &str = "/usr/sbin/mosquitto";
pub const PASSWORDS: [(&str, &str); 3] = [
    ("gateway", "gw-secret"),
    ("operator", "op-secret"),
    ("viewer", "view-secret"),
];

pub fn free_tcp() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A test PKI made by `openssl`: a CA, the broker's certificate (for
/// 127.0.0.1 and localhost) and a client certificate, each with its key.
pub struct Pki {
    pub ca: PathBuf,
    pub server: (PathBuf, PathBuf),
    pub client: (PathBuf, PathBuf),
}

/// Runs `openssl ARGS` in `dir`; fails the test with its words if it fails.
fn openssl(dir: &Path, args: &[&str]) {
    let out = Command::new("openssl")
        .current_dir(dir)
        .args(args)
        .output()
        .expect("openssl runs (Debian's openssl; .ci/run installs it)");
    assert!(
        out.status.success(),
        "openssl {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Makes a PKI in `dir` (created): an EC P-256 CA valid 2 days, and the
/// broker's and a client's certificates it signs. With `expired_server`
/// the broker's certificate is valid for no time at all (`-days 0`: its
/// notAfter is the second it was made), so it has expired once that
/// second has passed (this waits for it).
pub fn make_pki(dir: &Path, expired_server: bool) -> Pki {
    std::fs::create_dir_all(dir).unwrap();
    let ec = [
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:prime256v1",
        "-nodes",
    ];
    let ca = ["-keyout", "ca.key", "-out", "ca.crt", "-days", "2"];
    // Each PKI's CA has a name of its own (its folder's).
    let name = dir.file_name().unwrap().to_str().unwrap();
    let subj = ["-subj", &format!("/CN=stereolink-test-ca-{name}")];
    openssl(dir, &[&["req", "-x509"][..], &ec, &ca, &subj].concat());
    let sign = |name: &str, ext: &str, days: &str| {
        std::fs::write(dir.join(format!("{name}.ext")), ext).unwrap();
        let (key, csr, crt) = (
            format!("{name}.key"),
            format!("{name}.csr"),
            format!("{name}.crt"),
        );
        let subj = format!("/CN=stereolink-test-{name}");
        openssl(
            dir,
            &[
                &["req"][..],
                &ec,
                &["-keyout", &key, "-out", &csr, "-subj", &subj],
            ]
            .concat(),
        );
        openssl(
            dir,
            &[
                "x509", "-req", "-in", &csr, "-CA", "ca.crt", "-CAkey", "ca.key",
            ]
            .into_iter()
            .chain(["-CAcreateserial", "-days", days, "-extfile"])
            .chain([format!("{name}.ext").as_str(), "-out", &crt])
            .collect::<Vec<&str>>(),
        );
        (dir.join(crt), dir.join(key))
    };
    let server = sign(
        "server",
        "subjectAltName=IP:127.0.0.1,DNS:localhost\nextendedKeyUsage=serverAuth\n",
        if expired_server { "0" } else { "2" },
    );
    let client = sign("client", "extendedKeyUsage=clientAuth\n", "2");
    // Mosquitto reads them after it dropped to its own user.
    for f in std::fs::read_dir(dir).unwrap() {
        use std::os::unix::fs::PermissionsExt;
        let f = f.unwrap().path();
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o644)).unwrap();
    }
    if expired_server {
        std::thread::sleep(Duration::from_millis(1100));
    }
    Pki {
        ca: dir.join("ca.crt"),
        server,
        client,
    }
}

/// A Mosquitto of the test's own: the shipped ACL, a fresh password file.
pub struct Broker {
    pub dir: tempfile::TempDir,
    pub conf: PathBuf,
    pub port: u16,
    /// The TLS listener's port, if it has one.
    pub tls_port: Option<u16>,
    pub child: Option<Child>,
}

/// A TLS listener: its certificates, and whether every client must show
/// one the CA signed (mutual TLS).
pub struct TlsListener<'a> {
    pub pki: &'a Pki,
    pub require_certificate: bool,
}

impl Broker {
    /// Starts one, or returns None (skip) when Mosquitto is not installed
    /// outside CI.
    pub fn start() -> Option<Broker> {
        Self::start_with(None)
    }

    /// One with the shipped TLS listener example switched on, on a port of
    /// its own, besides the plaintext listener.
    pub fn start_tls(tls: TlsListener) -> Option<Broker> {
        Self::start_with(Some(tls))
    }

    fn start_with(tls: Option<TlsListener>) -> Option<Broker> {
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
        let tls_port = tls.as_ref().map(|_| free_tcp());
        let data = dir.path().join("data");
        std::fs::create_dir(&data).unwrap();
        open(&data);
        // The shipped config with this test's port and paths, and its TLS
        // example uncommented when asked for.
        let conf_text = shipped
            .lines()
            .map(|l| match (l.split_whitespace().next(), &tls, tls_port) {
                (Some("#listener"), Some(_), Some(p)) => format!("listener {p} 127.0.0.1"),
                (Some("#cafile"), Some(t), _) => format!("cafile {}", t.pki.ca.display()),
                (Some("#certfile"), Some(t), _) => {
                    format!("certfile {}", t.pki.server.0.display())
                }
                (Some("#keyfile"), Some(t), _) => format!("keyfile {}", t.pki.server.1.display()),
                (Some("#require_certificate"), Some(t), _) if t.require_certificate => {
                    "require_certificate true".into()
                }
                (Some("listener"), ..) => format!("listener {port} 127.0.0.1"),
                (Some("password_file"), ..) => format!("password_file {}", passwd.display()),
                (Some("acl_file"), ..) => {
                    format!("acl_file {}", acl.canonicalize().unwrap().display())
                }
                (Some("persistence_location"), ..) => {
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
            tls_port,
            child: None,
        };
        b.run();
        Some(b)
    }

    pub fn run(&mut self) {
        let child = Command::new(MOSQUITTO)
            .arg("-c")
            .arg(&self.conf)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        self.child = Some(child);
        let until = Instant::now() + Duration::from_secs(5);
        let up = |p: u16| std::net::TcpStream::connect(("127.0.0.1", p)).is_ok();
        while !up(self.port) || !self.tls_port.is_none_or(up) {
            assert!(
                Instant::now() < until,
                "mosquitto did not start: {}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Stops it as a service manager does (SIGTERM: it saves its state).
    pub fn stop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = Command::new("kill").arg(c.id().to_string()).status();
            let _ = c.wait();
        }
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(self.dir.path().join("broker.log")).unwrap_or_default()
    }

    pub fn url(&self, user: &str) -> String {
        let pw = PASSWORDS.iter().find(|p| p.0 == user).unwrap().1;
        format!("mqtt://{user}:{pw}@127.0.0.1:{}", self.port)
    }

    /// `mqtts://USER:PASSWORD@127.0.0.1:TLS_PORT`.
    pub fn tls_url(&self, user: &str) -> String {
        let pw = PASSWORDS.iter().find(|p| p.0 == user).unwrap().1;
        format!(
            "mqtts://{user}:{pw}@127.0.0.1:{}",
            self.tls_port.expect("a broker with a TLS listener")
        )
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
pub struct Got {
    pub topic: String,
    pub payload: Vec<u8>,
    pub retain: bool,
    /// The broker's redelivery of a message it sent before (QoS 1).
    pub dup: bool,
    pub at_us: u64,
}

/// A subscriber in a thread of its own: reconnects by itself, keeps
/// everything it got.
pub struct Subscriber {
    pub got: Arc<Mutex<Vec<Got>>>,
    pub subscribed: Arc<AtomicBool>,
    pub client: Client,
    pub stop: Arc<AtomicBool>,
    pub thread: Option<std::thread::JoinHandle<()>>,
}

impl Subscriber {
    /// `persistent`: a session the broker keeps across a restart.
    pub fn start(
        broker: &Broker,
        user: &str,
        id: &str,
        filters: &[&str],
        persistent: bool,
    ) -> Self {
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

    pub fn all(&self) -> Vec<Got> {
        self.got.lock().unwrap().clone()
    }

    /// The last payload on `topic`, as text.
    pub fn last(&self, topic: &str) -> Option<String> {
        let got = self.got.lock().unwrap();
        got.iter()
            .rev()
            .find(|g| g.topic == topic)
            .map(|g| String::from_utf8_lossy(&g.payload).into_owned())
    }

    /// Waits until `check` holds of what arrived, or fails saying `what`.
    pub fn wait_for(&self, what: &str, limit: Duration, check: impl Fn(&[Got]) -> bool) {
        let until = Instant::now() + limit;
        loop {
            if check(&self.got.lock().unwrap()) {
                return;
            }
            assert!(Instant::now() < until, "timed out waiting for {what}");
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    pub fn publish(&self, topic: &str, payload: &str) {
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
pub struct Gateway {
    pub child: Child,
    pub log: PathBuf,
}

impl Gateway {
    /// Starts `stereolink gateway` for stations named `names`, each on its
    /// own UDP port pair; returns it and each station's link spec.
    pub fn start(broker: &Broker, names: &[&str], extra: &[&str]) -> (Gateway, Vec<String>) {
        let mut args: Vec<String> = vec!["gateway".into()];
        let mut station_specs = Vec::new();
        for n in names {
            let (g, s) = (super::free_port(), super::free_port());
            args.push("--link".into());
            args.push(format!("{n}=udp:127.0.0.1:{g}?peer=127.0.0.1:{s}"));
            station_specs.push(format!("udp:127.0.0.1:{s}?peer=127.0.0.1:{g}"));
        }
        if !extra.contains(&"--mqtt") {
            args.extend(["--mqtt".into(), broker.url("gateway")]);
        }
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

    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Its exit status once it ended, or None if it still runs after `limit`.
    pub fn wait_exit(&mut self, limit: Duration) -> Option<std::process::ExitStatus> {
        let until = Instant::now() + limit;
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                return Some(status);
            }
            if Instant::now() >= until {
                return None;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub fn json(g: &Got) -> Value {
    serde_json::from_slice(&g.payload).unwrap_or(Value::Null)
}

/// Frame ids of the depth reports on each station's topic (the broker's
/// own redeliveries, flagged DUP, left out).
pub fn depth_ids(got: &[Got]) -> BTreeMap<String, Vec<u32>> {
    let mut ids: BTreeMap<String, Vec<u32>> = BTreeMap::new();
    for g in got.iter().filter(|g| g.topic.ends_with("/depth") && !g.dup) {
        let station = g.topic.split('/').nth(1).unwrap().to_string();
        ids.entry(station)
            .or_default()
            .push(json(g)["frame_id"].as_u64().unwrap() as u32);
    }
    ids
}

/// How many distinct reports arrived, over all stations.
pub fn distinct_reports(got: &[Got]) -> usize {
    depth_ids(got)
        .values()
        .map(|v| {
            let mut v = v.clone();
            v.sort_unstable();
            v.dedup();
            v.len()
        })
        .sum()
}

/// Asserts every station's reports 1..=n arrived, each exactly once.
#[track_caller]
pub fn assert_complete(got: &[Got], names: &[&str], n: u32) {
    assert_complete_but(got, names, n, 0);
}

/// Asserts every station's reports 1..=n arrived, and at most `allowed`
/// of them twice (over all stations); returns how many did.
#[track_caller]
pub fn assert_complete_but(got: &[Got], names: &[&str], n: u32, allowed: usize) -> usize {
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

pub fn stations(specs: &[String], reports: u32, interval: Duration) -> Vec<SimStation> {
    specs
        .iter()
        .map(|s| SimStation::start(SimConfig::new(s.parse().unwrap(), reports, interval)).unwrap())
        .collect()
}

pub fn wait_finished(sims: &[SimStation], limit: Duration) {
    let until = Instant::now() + limit;
    while !sims.iter().all(SimStation::finished) {
        assert!(
            Instant::now() < until,
            "the stations did not finish in time"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Waits until the gateway said `online` (a subscriber of its own).
pub fn wait_bridge_online(broker: &Broker) {
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
