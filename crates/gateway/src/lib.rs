//! The fleet gateway: the receiver side for any number of stations, each
//! on its own link (its own ARQ session and keys), bridged to an MQTT
//! broker in the zigbee2mqtt style. `docs/mqtt.md` lists every topic and
//! payload.
//!
//! One thread per station ([`station`]) owns its endpoint, rebuilds its
//! frames and sends its commands down; the bridge thread ([`run`]) owns
//! the broker connection ([`mqtt`]'s outbox): its state (`bridge`) turns
//! the stations' events into publishes, tracks availability, and hands
//! commands from `set` topics ([`command`]) to the stations; over TLS
//! (`mqtts://`) through rustls ([`tls`]), in MQTT 5 or 3.1.1 ([`session`]). Commands reach
//! a station only over its own link, sealed when keys are given, as a
//! versioned Control message ([`stereolink_codec::control`]).
//!
//! [`sim`] is a simulated station (synthetic frames and reports, an axis
//! that obeys commands) for the tests and the measurements.
//!
//! Why a crate of its own: the gateway is never in the ARM926 board's
//! build, and it alone needs an MQTT client (rumqttc); the binary's
//! `gateway` feature pulls it in off ARM only.
//!
//! It depends on the pipeline (the board's receiver, the Control message),
//! link and codec, and on image, display and robot for the frames it
//! rebuilds and the simulated station's axis.

mod bridge;
pub mod command;
pub mod mqtt;
pub mod session;
pub mod sim;
pub mod station;
pub mod tls;

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;

use rumqttc::{TlsConfiguration, Transport};

use bridge::Bridge;
use session::{Ev, Recv, Session, Version};
use station::{Request, StationConfig, Up};
use tls::TlsFiles;

/// Where the broker is and who the gateway is there.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Broker {
    /// The broker's host name or address.
    pub host: String,
    /// Its TCP port.
    pub port: u16,
    /// User name and password, if the broker asks for them.
    pub login: Option<(String, String)>,
    /// The gateway's MQTT client id.
    pub client_id: String,
    /// TLS (`mqtts://`) and its files; `None`: plain TCP.
    pub tls: Option<TlsFiles>,
}

impl Broker {
    /// Reads `mqtt://[USER[:PASSWORD]@]HOST[:PORT]` (`tcp://` too; port
    /// 1883 by default) or, over TLS, `mqtts://...` (`ssl://` too; port
    /// 8883 by default), with no TLS files yet (the system's CAs).
    pub fn parse(url: &str) -> Result<Broker, BrokerUrlError> {
        let plain = url
            .strip_prefix("mqtt://")
            .or_else(|| url.strip_prefix("tcp://"));
        let secure = url
            .strip_prefix("mqtts://")
            .or_else(|| url.strip_prefix("ssl://"));
        let (rest, tls) = match (plain, secure) {
            (Some(rest), _) => (rest, None),
            (None, Some(rest)) => (rest, Some(TlsFiles::default())),
            (None, None) => return Err(BrokerUrlError::Scheme(url.into())),
        };
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
                p.parse().map_err(|_| BrokerUrlError::Port {
                    url: url.into(),
                    port: p.into(),
                })?,
            ),
            None => (hostport, if tls.is_some() { 8883 } else { 1883 }),
        };
        if host.is_empty() {
            return Err(BrokerUrlError::NoHost(url.into()));
        }
        Ok(Broker {
            host: host.into(),
            port,
            login,
            client_id: "stereolink-gateway".into(),
            tls,
        })
    }
}

/// Why a broker URL was refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum BrokerUrlError {
    /// Neither `mqtt://` (`tcp://`) nor `mqtts://` (`ssl://`).
    #[error("broker {0:?}: use mqtt://HOST:PORT, or mqtts://HOST:PORT for TLS")]
    Scheme(String),
    /// The port is not a number.
    #[error("broker {url:?}: port {port:?} is not a number")]
    Port {
        /// The URL given.
        url: String,
        /// Its port.
        port: String,
    },
    /// No host before the port.
    #[error("broker {0:?}: no host")]
    NoHost(String),
}

/// `mqtts://HOST:PORT` or `mqtt://HOST:PORT`: the broker without its login.
impl std::fmt::Display for Broker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let scheme = if self.tls.is_some() { "mqtts" } else { "mqtt" };
        write!(f, "{scheme}://{}:{}", self.host, self.port)
    }
}

/// Everything the gateway needs.
#[derive(Clone, Debug)]
pub struct GatewayConfig {
    /// The stations, each on its own link.
    pub stations: Vec<StationConfig>,
    /// The broker to bridge them to.
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
    /// The MQTT version spoken.
    pub version: Version,
    /// MQTT 5: depth reports expire after this many seconds undelivered.
    pub depth_expiry_s: Option<u32>,
}

/// What a gateway run did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Summary {
    /// Publishes acknowledged by the broker (or written, QoS 0).
    pub published: u64,
    /// Publishes handed again after a lost connection.
    pub republished: u64,
    /// Publishes dropped because the queue was full, by kind.
    pub dropped: BTreeMap<&'static str, u64>,
    /// Reconnections to the broker.
    pub reconnects: u64,
    /// Commands taken from `set` topics.
    pub commands: u64,
}

/// The shortest and longest wait before reconnecting to the broker.
const BACKOFF: (Duration, Duration) = (Duration::from_millis(100), Duration::from_secs(5));
/// How long the bridge waits for the broker or the stations in one round.
const ROUND: Duration = Duration::from_millis(5);
/// `bridge/stations` goes out at most this often while it changes.
const STATIONS_EVERY: Duration = Duration::from_secs(2);

/// Runs the gateway until `stop` is set; then says `offline` and leaves.
/// `on_turn` is called on each turn of its loop (every few milliseconds)
/// with whether the broker is connected: what a service manager's
/// readiness and watchdog hang on.
pub fn run(
    cfg: GatewayConfig,
    stop: Arc<AtomicBool>,
    mut on_turn: impl FnMut(bool),
) -> anyhow::Result<Summary> {
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
    // Bad TLS files are an error before any station starts.
    let transport = match &cfg.broker.tls {
        Some(files) => Transport::tls_with_config(TlsConfiguration::Rustls(
            tls::client_config(files).with_context(|| format!("broker {}", cfg.broker))?,
        )),
        None => Transport::tcp(),
    };
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
    let mut session = Session::new(&cfg.broker, cfg.version, bridge.will_topic(), transport);
    let mut connected = false;
    let (mut backoff, mut next_attempt) = (BACKOFF.0, Instant::now());
    let mut last_health = Instant::now();
    let mut last_stations = Instant::now() - STATIONS_EVERY;
    let mut leaving: Option<Instant> = None;
    loop {
        on_turn(connected);
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
                let ev = match session.recv_timeout(wait) {
                    Recv::Ev(ev) => ev,
                    Recv::Timeout => break,
                    Recv::Closed => anyhow::bail!("the MQTT client stopped"),
                };
                wait = Duration::ZERO;
                match ev {
                    // Both clients report a refused CONNACK as an error.
                    Ev::ConnAck => {
                        if bridge.connections > 0 {
                            eprintln!("gateway: reconnected to the broker");
                        }
                        bridge.connections += 1;
                        connected = true;
                        backoff = BACKOFF.0;
                        bridge.outbox.on_connack();
                        let p = &bridge.prefix;
                        session.try_subscribe(format!("{p}/+/set"));
                        session.try_subscribe(format!("{p}/bridge/request/+"));
                        bridge.health(connected);
                    }
                    Ev::PubAck(pkid) => bridge.outbox.on_puback(pkid),
                    Ev::Publish {
                        topic,
                        payload,
                        reply,
                    } => bridge.on_request(&topic, &payload, reply, &downs, connected),
                    Ev::Outgoing(o) => bridge.outbox.on_outgoing(&o),
                    Ev::Other => {}
                    Ev::Lost { error, tls } => {
                        // TLS that fails before the first connection is
                        // a setting to fix, not a broker to wait for.
                        if let (0, Some(cause)) = (bridge.connections, tls) {
                            stop.store(true, Ordering::Relaxed);
                            for t in threads {
                                let _ = t.join();
                            }
                            anyhow::bail!(
                                "cannot connect to the broker {} over TLS: {cause}",
                                cfg.broker
                            );
                        }
                        if connected {
                            eprintln!("gateway: lost the broker ({error}); reconnecting");
                            bridge.reconnects += 1;
                        } else if bridge.connections == 0 && backoff == BACKOFF.0 {
                            eprintln!("gateway: cannot reach the broker ({error}); retrying");
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
                if !session.try_publish(p) {
                    break; // the client's channel is full: next round
                }
                bridge.outbox.handed();
            }
        }
    }
    session.disconnect();
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn broker_urls_parse() {
        let b = Broker::parse("mqtt://gw:s3cret@127.0.0.1:18830").unwrap();
        assert_eq!((b.host.as_str(), b.port), ("127.0.0.1", 18830));
        assert_eq!(b.login, Some(("gw".into(), "s3cret".into())));
        assert_eq!(Broker::parse("tcp://broker").unwrap().port, 1883);
        let b = Broker::parse("mqtts://broker").unwrap();
        assert_eq!((b.port, b.tls.is_some()), (8883, true));
        let b = Broker::parse("ssl://gw:pw@10.0.0.2:18883").unwrap();
        assert_eq!((b.port, b.tls.is_some()), (18883, true));
        assert_eq!(b.to_string(), "mqtts://10.0.0.2:18883");
        assert!(Broker::parse("tcp://broker").unwrap().tls.is_none());
        assert!(Broker::parse("http://broker").is_err());
        assert!(Broker::parse("mqtt://:1883").is_err());
    }
}
