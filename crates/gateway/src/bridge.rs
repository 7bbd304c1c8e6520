//! The bridge's state: what each station did, the outbox to the broker,
//! and how each station event and each request becomes publishes.

use std::sync::mpsc;
use std::time::{Duration, Instant};

use rumqttc::QoS;
use serde_json::{json, Value};
use stereolink_codec::control::unix_us;

use crate::command::{self, SetError};
use crate::mqtt::{Outbox, Pub};
use crate::session::Reply;
use crate::station::{Request, Up};
use crate::GatewayConfig;

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
    /// MQTT 5 message expiry of the depth reports, seconds.
    depth_expiry_s: Option<u32>,
}

impl Bridge {
    pub(super) fn new(cfg: &GatewayConfig) -> Self {
        let mut b = Bridge {
            prefix: cfg.prefix.trim_end_matches('/').to_string(),
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
            depth_expiry_s: cfg.depth_expiry_s,
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

    /// The last will's topic: the bridge's state.
    pub(super) fn will_topic(&self) -> String {
        self.topic("bridge/state")
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
                expiry_s: None,
                correlation: None,
            },
            connected,
        );
    }

    /// Answers a request on its default topic `to` or, under MQTT 5, on
    /// the response topic it gave, with its correlation data. A response
    /// topic is taken only at or below `to` (`P/S/response/...`), so that
    /// a client who may command cannot make the gateway publish on the
    /// stations' own topics; elsewhere the answer goes to `to`, still
    /// correlated.
    fn answer(&mut self, to: String, r: &Value, reply: Option<&Reply>, connected: bool) {
        self.outbox.push(
            Pub {
                topic: response_topic(to, reply),
                payload: Self::json(r),
                qos: QoS::AtLeastOnce,
                retain: false,
                kind: "response",
                expiry_s: None,
                correlation: reply.and_then(|rp| rp.correlation.clone()),
            },
            connected,
        );
    }

    /// Answers a command on `P/S/response` (or its response topic).
    fn respond(&mut self, station: usize, r: &Value, reply: Option<&Reply>, connected: bool) {
        let to = self.station_topic(station, "response");
        self.answer(to, r, reply, connected);
    }

    fn retain(&mut self, topic: String, payload: Vec<u8>, connected: bool) {
        self.outbox.push(
            Pub {
                topic,
                payload,
                qos: QoS::AtLeastOnce,
                retain: true,
                kind: "retained",
                expiry_s: None,
                correlation: None,
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
                // A stale distance is worse than none: the broker drops it
                // for a subscriber that comes too late (MQTT 5).
                self.outbox.push(
                    Pub {
                        topic: self.station_topic(station, "depth"),
                        payload: Self::json(&payload),
                        qos: QoS::AtLeastOnce,
                        retain: false,
                        kind: "depth",
                        expiry_s: self.depth_expiry_s,
                        correlation: None,
                    },
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
                self.respond(station, &r, request.reply.as_ref(), connected);
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
                self.respond(station, &r, request.reply.as_ref(), connected);
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
        reply: Option<Reply>,
        downs: &[mpsc::Sender<Request>],
        connected: bool,
    ) {
        let Some(rest) = topic
            .strip_prefix(&self.prefix)
            .and_then(|t| t.strip_prefix('/'))
        else {
            return;
        };
        let parsed: Result<Value, SetError> =
            serde_json::from_slice(payload).map_err(|e| SetError::NotJson(e.to_string()));
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
            return self.answer(response, &r, reply.as_ref(), connected);
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
                self.respond(i, &r, reply.as_ref(), connected);
            }
            Ok(command) => {
                let req = Request {
                    command,
                    transaction,
                    reply: reply.clone(),
                    at: Instant::now(),
                };
                if downs[i].send(req).is_err() {
                    let r = json!({"status": "error", "error": "the station's link is closed"});
                    self.respond(i, &r, reply.as_ref(), connected);
                }
            }
            Err(e) => {
                let r =
                    json!({"status": "error", "error": e.to_string(), "transaction": transaction});
                self.respond(i, &r, reply.as_ref(), connected);
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

/// Where an answer goes: the request's response topic if it is `to` or
/// below it, else `to`.
fn response_topic(to: String, reply: Option<&Reply>) -> String {
    match reply {
        Some(rp) if rp.topic == to || rp.topic.starts_with(&format!("{to}/")) => rp.topic.clone(),
        _ => to,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_response_topic_is_taken_only_below_the_default() {
        let to = || "p/cam1/response".to_string();
        let reply = |t: &str| Reply {
            topic: t.into(),
            correlation: None,
        };
        for (asked, goes) in [
            ("p/cam1/response/op1", "p/cam1/response/op1"),
            ("p/cam1/response", "p/cam1/response"),
            ("p/cam1/depth", "p/cam1/response"),
            ("p/cam1/responses", "p/cam1/response"),
            ("p/bridge/state", "p/cam1/response"),
        ] {
            assert_eq!(response_topic(to(), Some(&reply(asked))), goes, "{asked}");
        }
        assert_eq!(response_topic(to(), None), "p/cam1/response");
    }
}
