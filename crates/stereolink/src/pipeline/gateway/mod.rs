//! The fleet gateway: the receiver side for any number of stations, each
//! on its own link (its own ARQ session and keys), bridged to an MQTT
//! broker in the zigbee2mqtt style. `docs/mqtt.md` lists every topic and
//! payload.
//!
//! One thread per station ([`station`]) owns its endpoint, rebuilds its
//! frames and sends its commands down; the bridge thread ([`run`]) owns
//! the broker connection ([`mqtt`]): it turns the stations' events into
//! publishes, tracks availability, and hands commands from `set` topics to
//! the stations. Commands reach a station only over its own link, sealed
//! when keys are given ([`command`]: a versioned Control message).
//!
//! [`sim`] is a simulated station (synthetic frames and reports, an axis
//! that obeys commands) for the tests and the measurements.

pub mod command;
pub mod mqtt;
pub mod sim;
pub mod station;

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use rumqttc::{Client, Event, LastWill, MqttOptions, Packet, QoS};
use serde_json::{json, Value};

use command::Command;
use mqtt::{Outbox, Pub};
use station::{Request, StationConfig, Up};

/// Where the broker is and who the gateway is there.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Broker {
    pub host: String,
    pub port: u16,
    /// User name and password, if the broker asks for them.
    pub login: Option<(String, String)>,
    pub client_id: String,
}

impl Broker {
    /// Reads `mqtt://[USER[:PASSWORD]@]HOST[:PORT]` (`tcp://` too; port
    /// 1883 by default). TLS (`mqtts://`) is not built in.
    pub fn parse(url: &str) -> Result<Broker, String> {
        let rest = url
            .strip_prefix("mqtt://")
            .or_else(|| url.strip_prefix("tcp://"))
            .ok_or_else(|| format!("broker {url:?}: use mqtt://HOST:PORT (no TLS here)"))?;
        let rest = rest.trim_end_matches('/');
        let (login, hostport) = match rest.rsplit_once('@') {
            Some((user, hp)) => {
                let (u, p) = user.split_once(':').unwrap_or((user, ""));
                (Some((u.to_string(), p.to_string())), hp)
            }
            None => (None, rest),
        };
        let (host, port) = match hostport.rsplit_once(':') {
            Some((h, p)) => (
                h,
                p.parse()
                    .map_err(|_| format!("broker {url:?}: port {p:?} is not a number"))?,
            ),
            None => (hostport, 1883),
        };
        if host.is_empty() {
            return Err(format!("broker {url:?}: no host"));
        }
        Ok(Broker {
            host: host.into(),
            port,
            login,
            client_id: "stereolink-gateway".into(),
        })
    }
}

/// Everything the gateway needs.
#[derive(Clone, Debug)]
pub struct GatewayConfig {
    pub stations: Vec<StationConfig>,
    pub broker: Broker,
    /// The first topic level (`stereolink`).
    pub prefix: String,
    /// A station silent this long is `offline`.
    pub offline_after: Duration,
    /// Most non-retained publishes kept while the broker is away.
    pub queue: usize,
    /// How often `bridge/health` goes out.
    pub health_every: Duration,
    /// Home Assistant's discovery prefix (`homeassistant`), if the
    /// stations are to be announced to it.
    pub discovery: Option<String>,
}

/// What a gateway run did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Summary {
    pub published: u64,
    pub republished: u64,
    pub dropped: BTreeMap<&'static str, u64>,
    pub reconnects: u64,
    pub commands: u64,
}

/// A station's state on the bridge side.
#[derive(Default)]
struct Seen {
    last_heard: Option<Instant>,
    online: bool,
    frames: u64,
    depth_reports: u64,
    last_frame_id: Option<u32>,
    last_distance_m: Option<f64>,
}

/// The shortest and longest wait before reconnecting to the broker.
const BACKOFF: (Duration, Duration) = (Duration::from_millis(100), Duration::from_secs(5));
/// How long the bridge waits for the broker or the stations in one round.
const ROUND: Duration = Duration::from_millis(5);
/// `bridge/stations` goes out at most this often while it changes.
const STATIONS_EVERY: Duration = Duration::from_secs(2);

/// Runs the gateway until `stop` is set; then says `offline` and leaves.
pub fn run(cfg: GatewayConfig, stop: Arc<AtomicBool>) -> anyhow::Result<Summary> {
    anyhow::ensure!(
        !cfg.stations.is_empty(),
        "the gateway needs at least one --link"
    );
    let mut names = std::collections::BTreeSet::new();
    for s in &cfg.stations {
        anyhow::ensure!(
            valid_level(&s.name) && s.name != "bridge",
            "station name {:?}: use letters, digits, - and _ (and not \"bridge\")",
            s.name
        );
        anyhow::ensure!(names.insert(&s.name), "station {:?} is named twice", s.name);
    }
    let (up_tx, up) = mpsc::channel::<Up>();
    let mut downs = Vec::new();
    let mut threads = Vec::new();
    for (i, s) in cfg.stations.iter().enumerate() {
        let (tx, rx) = mpsc::channel::<Request>();
        downs.push(tx);
        let (s, up_tx, stop) = (s.clone(), up_tx.clone(), stop.clone());
        threads.push(
            std::thread::Builder::new()
                .name(format!("station {}", s.name))
                .spawn(move || station::run(i, s, up_tx, rx, stop))?,
        );
    }
    drop(up_tx);
    let mut bridge = Bridge::new(&cfg);
    let (client, mut connection) = Client::new(bridge.options(), 256);
    let mut connected = false;
    let (mut backoff, mut next_attempt) = (BACKOFF.0, Instant::now());
    let mut last_health = Instant::now();
    let mut last_stations = Instant::now() - STATIONS_EVERY;
    let mut leaving: Option<Instant> = None;
    loop {
        if stop.load(Ordering::Relaxed) && leaving.is_none() {
            leaving = Some(Instant::now());
            bridge.leave(connected);
        }
        if let Some(t) = leaving {
            let flushed = bridge.outbox.waiting() == 0 && bridge.outbox.in_flight() == 0;
            if flushed || !connected || t.elapsed() > Duration::from_secs(2) {
                break;
            }
        }
        // The broker: events until a round passes quietly.
        if connected || Instant::now() >= next_attempt {
            let mut wait = ROUND;
            for _ in 0..256 {
                let ev = match connection.recv_timeout(wait) {
                    Ok(ev) => ev,
                    Err(rumqttc::RecvTimeoutError::Timeout) => break,
                    Err(rumqttc::RecvTimeoutError::Disconnected) => {
                        anyhow::bail!("the MQTT client stopped")
                    }
                };
                wait = Duration::ZERO;
                match ev {
                    Ok(Event::Incoming(Packet::ConnAck(ack))) => {
                        if ack.code != rumqttc::ConnectReturnCode::Success {
                            eprintln!("gateway: the broker refused the connection: {:?}", ack.code);
                            connected = false;
                            next_attempt = Instant::now() + backoff;
                            backoff = (backoff * 2).min(BACKOFF.1);
                            break;
                        }
                        if bridge.connections > 0 {
                            eprintln!("gateway: reconnected to the broker");
                        }
                        bridge.connections += 1;
                        connected = true;
                        backoff = BACKOFF.0;
                        bridge.outbox.on_connack();
                        let p = &bridge.prefix;
                        let _ = client.try_subscribe(format!("{p}/+/set"), QoS::AtLeastOnce);
                        let _ =
                            client.try_subscribe(format!("{p}/bridge/request/+"), QoS::AtLeastOnce);
                        bridge.health(connected);
                    }
                    Ok(Event::Incoming(Packet::PubAck(a))) => bridge.outbox.on_puback(a.pkid),
                    Ok(Event::Incoming(Packet::Publish(p))) => {
                        bridge.on_request(&p.topic, &p.payload, &downs, connected)
                    }
                    Ok(Event::Outgoing(o)) => bridge.outbox.on_outgoing(&o),
                    Ok(Event::Incoming(_)) => {}
                    Err(e) => {
                        if connected {
                            eprintln!("gateway: lost the broker ({e}); reconnecting");
                            bridge.reconnects += 1;
                        } else if bridge.connections == 0 && backoff == BACKOFF.0 {
                            eprintln!("gateway: cannot reach the broker ({e}); retrying");
                        }
                        connected = false;
                        bridge.outbox.on_disconnect();
                        next_attempt = Instant::now() + backoff;
                        backoff = (backoff * 2).min(BACKOFF.1);
                        break;
                    }
                }
            }
        }
        // The stations: wait here only while the broker is away.
        let wait = if connected || leaving.is_some() {
            Duration::ZERO
        } else {
            next_attempt
                .saturating_duration_since(Instant::now())
                .min(Duration::from_millis(50))
        };
        match up.recv_timeout(wait) {
            Ok(e) => bridge.on_up(e, connected),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) if leaving.is_some() => {}
            Err(RecvTimeoutError::Disconnected) => anyhow::bail!("every station thread ended"),
        }
        while let Ok(e) = up.try_recv() {
            bridge.on_up(e, connected);
        }
        bridge.check_availability(connected);
        if bridge.stations_dirty && last_stations.elapsed() >= STATIONS_EVERY {
            last_stations = Instant::now();
            bridge.publish_stations(connected);
        }
        if last_health.elapsed() >= cfg.health_every {
            last_health = Instant::now();
            bridge.health(connected);
        }
        if connected {
            while let Some(p) = bridge.outbox.next() {
                let p = p.clone();
                match client.try_publish(p.topic, p.qos, p.retain, p.payload) {
                    Ok(()) => bridge.outbox.handed(),
                    Err(_) => break, // the client's channel is full: next round
                }
            }
        }
    }
    let _ = client.try_disconnect();
    let _ = connection.recv_timeout(Duration::from_millis(100));
    for t in threads {
        let _ = t.join();
    }
    Ok(Summary {
        published: bridge.outbox.published,
        republished: bridge.outbox.republished,
        dropped: bridge.outbox.dropped.clone(),
        reconnects: bridge.reconnects,
        commands: bridge.commands,
    })
}

/// Whether `s` can be a topic level (and a file name for its key).
fn valid_level(s: &str) -> bool {
    !s.is_empty()
        && s.len() <= 64
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

/// The bridge's state: the stations as seen, the outbox, the counters.
struct Bridge {
    prefix: String,
    broker: Broker,
    names: Vec<String>,
    links: Vec<String>,
    secured: Vec<bool>,
    seen: Vec<Seen>,
    offline_after: Duration,
    outbox: Outbox,
    stations_dirty: bool,
    connections: u64,
    reconnects: u64,
    commands: u64,
    started_us: u64,
}

impl Bridge {
    fn new(cfg: &GatewayConfig) -> Self {
        let mut b = Bridge {
            prefix: cfg.prefix.trim_end_matches('/').to_string(),
            broker: cfg.broker.clone(),
            names: cfg.stations.iter().map(|s| s.name.clone()).collect(),
            links: cfg.stations.iter().map(|s| s.link_text.clone()).collect(),
            secured: cfg.stations.iter().map(|s| s.keys.is_some()).collect(),
            seen: cfg.stations.iter().map(|_| Seen::default()).collect(),
            offline_after: cfg.offline_after,
            outbox: Outbox::new(cfg.queue, 100),
            stations_dirty: true,
            connections: 0,
            reconnects: 0,
            commands: 0,
            started_us: station::unix_us(),
        };
        // The retained state the first CONNACK publishes.
        b.retain(b.topic("bridge/state"), b"online".to_vec(), false);
        for i in 0..b.names.len() {
            b.retain(
                b.station_topic(i, "availability"),
                b"offline".to_vec(),
                false,
            );
            if let Some(d) = &cfg.discovery {
                for (topic, config) in b.discovery(d, i) {
                    b.retain(topic, Self::json(&config), false);
                }
            }
        }
        b
    }

    /// Home Assistant MQTT discovery for station `i`: its distance as a
    /// sensor, "stop the axis" as a button, its levels as a number.
    fn discovery(&self, prefix: &str, i: usize) -> Vec<(String, Value)> {
        let name = &self.names[i];
        let id = format!("{}_{name}", self.prefix.replace('/', "_"));
        let common = json!({
            "availability": [
                {"topic": self.topic("bridge/state")},
                {"topic": self.station_topic(i, "availability")},
            ],
            "availability_mode": "all",
            "device": {"identifiers": [id], "name": format!("stereolink {name}"), "manufacturer": "stereolink"},
        });
        let entity = |kind: &str, what: &str, extra: Value| {
            let mut c = common.clone();
            c["unique_id"] = json!(format!("{id}_{what}"));
            c["name"] = json!(what.replace('_', " "));
            for (k, v) in extra.as_object().expect("an object") {
                c[k] = v.clone();
            }
            (format!("{prefix}/{kind}/{id}_{what}/config"), c)
        };
        let set = self.station_topic(i, "set");
        vec![
            entity(
                "sensor",
                "distance",
                json!({
                    "state_topic": self.station_topic(i, "depth"),
                    "value_template": "{{ value_json.distance_m }}",
                    "unit_of_measurement": "m",
                    "device_class": "distance",
                }),
            ),
            entity(
                "button",
                "axis_stop",
                json!({
                    "command_topic": set,
                    "payload_press": "{\"axis\":\"stop\"}",
                }),
            ),
            entity(
                "number",
                "levels",
                json!({
                    "command_topic": set,
                    "command_template": "{\"levels\": {{ value | int }}}",
                    "min": 2, "max": 16, "step": 1,
                }),
            ),
        ]
    }

    fn options(&self) -> MqttOptions {
        let mut o = MqttOptions::new(
            self.broker.client_id.clone(),
            self.broker.host.clone(),
            self.broker.port,
        );
        o.set_keep_alive(Duration::from_secs(5))
            .set_clean_session(true)
            .set_max_packet_size(64 * 1024, 16 * 1024 * 1024)
            .set_inflight(100)
            .set_last_will(LastWill::new(
                self.topic("bridge/state"),
                "offline",
                QoS::AtLeastOnce,
                true,
            ));
        if let Some((u, p)) = &self.broker.login {
            o.set_credentials(u.clone(), p.clone());
        }
        o
    }

    fn topic(&self, rest: &str) -> String {
        format!("{}/{rest}", self.prefix)
    }

    fn station_topic(&self, i: usize, rest: &str) -> String {
        format!("{}/{}/{rest}", self.prefix, self.names[i])
    }

    fn push(&mut self, topic: String, payload: Vec<u8>, kind: &'static str, connected: bool) {
        self.outbox.push(
            Pub {
                topic,
                payload,
                qos: QoS::AtLeastOnce,
                retain: false,
                kind,
            },
            connected,
        );
    }

    /// Answers a command on `P/S/response`.
    fn respond(&mut self, station: usize, r: &Value, connected: bool) {
        let topic = self.station_topic(station, "response");
        self.push(topic, Self::json(r), "response", connected);
    }

    fn retain(&mut self, topic: String, payload: Vec<u8>, connected: bool) {
        self.outbox.push(
            Pub {
                topic,
                payload,
                qos: QoS::AtLeastOnce,
                retain: true,
                kind: "retained",
            },
            connected,
        );
    }

    fn json(v: &Value) -> Vec<u8> {
        serde_json::to_vec(v).expect("JSON values serialise")
    }

    fn on_up(&mut self, e: Up, connected: bool) {
        match e {
            Up::Heard(i) => {
                let s = &mut self.seen[i];
                s.last_heard = Some(Instant::now());
                if !s.online {
                    s.online = true;
                    self.stations_dirty = true;
                    eprintln!("gateway: station {} online", self.names[i]);
                    self.retain(
                        self.station_topic(i, "availability"),
                        b"online".to_vec(),
                        connected,
                    );
                }
            }
            Up::Depth {
                station,
                frame_id,
                payload,
            } => {
                let s = &mut self.seen[station];
                s.depth_reports += 1;
                s.last_frame_id = Some(frame_id);
                s.last_distance_m = payload["distance_m"].as_f64();
                self.stations_dirty = true;
                self.push(
                    self.station_topic(station, "depth"),
                    Self::json(&payload),
                    "depth",
                    connected,
                );
            }
            Up::Frame {
                station,
                meta,
                images,
            } => {
                self.seen[station].frames += 1;
                self.stations_dirty = true;
                if let Some(img) = images {
                    for (sub, png) in [
                        ("left", img.left),
                        ("view3d", img.view3d),
                        ("disparity", img.disparity),
                    ] {
                        self.retain(
                            self.station_topic(station, &format!("frame/{sub}")),
                            png,
                            connected,
                        );
                    }
                }
                self.retain(
                    self.station_topic(station, "frame"),
                    Self::json(&meta),
                    connected,
                );
            }
            Up::Link { station, payload } => self.push(
                self.station_topic(station, "link"),
                Self::json(&payload),
                "link",
                connected,
            ),
            Up::Done {
                station,
                request,
                result,
            } => {
                let mut r = json!({
                    "command": request.command.name(),
                    "transaction": request.transaction,
                });
                match result {
                    Ok(t) => {
                        r["status"] = json!("ok");
                        r["delivered_ms"] = json!((t.as_secs_f64() * 1e4).round() / 10.0);
                    }
                    Err(e) => {
                        r["status"] = json!("error");
                        r["error"] = json!(e);
                    }
                }
                self.respond(station, &r, connected);
            }
            Up::Notice { station, text } => {
                eprintln!("gateway: station {}: {text}", self.names[station])
            }
        }
    }

    /// A message on `PREFIX/<station>/set` or `PREFIX/bridge/request/<what>`.
    fn on_request(
        &mut self,
        topic: &str,
        payload: &[u8],
        downs: &[mpsc::Sender<Request>],
        connected: bool,
    ) {
        let Some(rest) = topic
            .strip_prefix(&self.prefix)
            .and_then(|t| t.strip_prefix('/'))
        else {
            return;
        };
        let parsed: Result<Value, String> =
            serde_json::from_slice(payload).map_err(|e| format!("the payload is not JSON: {e}"));
        let transaction = parsed
            .as_ref()
            .ok()
            .and_then(|v| v.get("transaction"))
            .cloned();
        if let Some(what) = rest.strip_prefix("bridge/request/") {
            let response = self.topic(&format!("bridge/response/{what}"));
            let r = match what {
                "health" => {
                    self.health(connected);
                    json!({"status": "ok", "transaction": transaction})
                }
                "stations" => {
                    self.publish_stations(connected);
                    json!({"status": "ok", "transaction": transaction})
                }
                other => {
                    json!({"status": "error", "error": format!("unknown request {other:?}"), "transaction": transaction})
                }
            };
            return self.push(response, Self::json(&r), "response", connected);
        }
        let Some(name) = rest.strip_suffix("/set") else {
            return;
        };
        let Some(i) = self.names.iter().position(|n| n == name) else {
            return; // not ours: no response topic to answer on
        };
        let command = parsed.and_then(|v| Command::from_json(&v));
        self.commands += 1;
        match command {
            // A command waits for no station that cannot take it now.
            Ok(_) if !self.seen[i].online => {
                let r = json!({"status": "error", "error": "the station is offline", "transaction": transaction});
                self.respond(i, &r, connected);
            }
            Ok(command) => {
                let req = Request {
                    command,
                    transaction,
                    at: Instant::now(),
                };
                if downs[i].send(req).is_err() {
                    let r = json!({"status": "error", "error": "the station's link is closed"});
                    self.respond(i, &r, connected);
                }
            }
            Err(e) => {
                let r = json!({"status": "error", "error": e, "transaction": transaction});
                self.respond(i, &r, connected);
            }
        }
    }

    fn check_availability(&mut self, connected: bool) {
        for i in 0..self.seen.len() {
            let s = &mut self.seen[i];
            if s.online
                && s.last_heard
                    .is_some_and(|t| t.elapsed() >= self.offline_after)
            {
                s.online = false;
                self.stations_dirty = true;
                eprintln!(
                    "gateway: station {} offline (silent for {:.0} s)",
                    self.names[i],
                    self.offline_after.as_secs_f64()
                );
                self.retain(
                    self.station_topic(i, "availability"),
                    b"offline".to_vec(),
                    connected,
                );
            }
        }
    }

    fn publish_stations(&mut self, connected: bool) {
        self.stations_dirty = false;
        let list: Vec<Value> = (0..self.names.len())
            .map(|i| {
                let s = &self.seen[i];
                json!({
                    "name": self.names[i],
                    "link": self.links[i],
                    "secured": self.secured[i],
                    "availability": if s.online { "online" } else { "offline" },
                    "frames": s.frames,
                    "depth_reports": s.depth_reports,
                    "last_frame_id": s.last_frame_id,
                    "last_distance_m": s.last_distance_m,
                    "silent_s": s.last_heard.map(|t| (t.elapsed().as_secs_f64() * 10.0).round() / 10.0),
                })
            })
            .collect();
        self.retain(
            self.topic("bridge/stations"),
            Self::json(&json!(list)),
            connected,
        );
    }

    fn health(&mut self, connected: bool) {
        let o = &self.outbox;
        let v = json!({
            "connected": connected,
            "started_us": self.started_us,
            "connections": self.connections,
            "reconnects": self.reconnects,
            "queued": o.waiting(),
            "in_flight": o.in_flight(),
            "published": o.published,
            "republished": o.republished,
            "dropped": o.dropped,
            "dropped_total": o.dropped_total(),
            "commands": self.commands,
        });
        self.retain(self.topic("bridge/health"), Self::json(&v), connected);
    }

    /// A clean exit: the stations and the bridge go `offline`.
    fn leave(&mut self, connected: bool) {
        for i in 0..self.names.len() {
            self.retain(
                self.station_topic(i, "availability"),
                b"offline".to_vec(),
                connected,
            );
        }
        self.health(connected);
        self.retain(self.topic("bridge/state"), b"offline".to_vec(), connected);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn broker_urls_parse() {
        let b = Broker::parse("mqtt://gw:s3cret@127.0.0.1:18830").unwrap();
        assert_eq!((b.host.as_str(), b.port), ("127.0.0.1", 18830));
        assert_eq!(b.login, Some(("gw".into(), "s3cret".into())));
        assert_eq!(Broker::parse("tcp://broker").unwrap().port, 1883);
        assert!(Broker::parse("mqtts://broker").is_err());
        assert!(Broker::parse("mqtt://:1883").is_err());
    }
}
