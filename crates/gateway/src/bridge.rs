//! The bridge's state: what each station did, the outbox to the broker,
//! and how each station event and each request becomes publishes.

use std::sync::mpsc;
use std::time::{Duration, Instant};

use rumqttc::{LastWill, MqttOptions, QoS};
use serde_json::{json, Value};
use stereolink_codec::control::unix_us;

use crate::command;
use crate::mqtt::{Outbox, Pub};
use crate::station::{Request, Up};
use crate::{Broker, GatewayConfig};

/// A station's state on the bridge side.
#[derive(Default)]
pub(super) struct Seen {
    last_heard: Option<Instant>,
    online: bool,
    frames: u64,
    depth_reports: u64,
    last_frame_id: Option<u32>,
    last_distance_m: Option<f64>,
}

/// The bridge's state: the stations as seen, the outbox, the counters.
pub(super) struct Bridge {
    pub(super) prefix: String,
    pub(super) broker: Broker,
    pub(super) names: Vec<String>,
    pub(super) links: Vec<String>,
    pub(super) secured: Vec<bool>,
    pub(super) seen: Vec<Seen>,
    pub(super) offline_after: Duration,
    pub(super) outbox: Outbox,
    pub(super) stations_dirty: bool,
    pub(super) connections: u64,
    pub(super) reconnects: u64,
    pub(super) commands: u64,
    pub(super) started_us: u64,
}

impl Bridge {
    pub(super) fn new(cfg: &GatewayConfig) -> Self {
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
            started_us: unix_us(),
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

    pub(super) fn options(&self) -> MqttOptions {
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

    pub(super) fn on_up(&mut self, e: Up, connected: bool) {
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
            Up::Acted {
                station,
                request,
                result,
            } => {
                let mut r = json!({
                    "command": request.command.name(),
                    "transaction": request.transaction,
                    "acted_ms": (request.at.elapsed().as_secs_f64() * 1e4).round() / 10.0,
                });
                match result {
                    Ok(()) => r["status"] = json!("done"),
                    Err(e) => {
                        r["status"] = json!("refused");
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
    pub(super) fn on_request(
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
        let command = parsed.and_then(|v| command::from_json(&v));
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

    pub(super) fn check_availability(&mut self, connected: bool) {
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

    pub(super) fn publish_stations(&mut self, connected: bool) {
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

    pub(super) fn health(&mut self, connected: bool) {
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
    pub(super) fn leave(&mut self, connected: bool) {
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
