//! `stereolink gateway`: many stations, one MQTT broker.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::Context;
use stereolink_gateway::station::StationConfig;
use stereolink_gateway::{self as gateway, Broker, GatewayConfig};
use stereolink_link::secure::{keyfile, Keys};
use stereolink_pipeline::record::{OnError, Recorder};

/// Arguments of `stereolink gateway`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A station's link, once per station: NAME=SPEC, or SPEC alone (named
    /// station1, station2, ... in order). One UDP peer or radio address each.
    #[arg(long = "link", value_name = "[NAME=]SPEC", required = true)]
    pub links: Vec<String>,
    /// The broker: mqtt://[USER[:PASSWORD]@]HOST[:PORT] (port 1883), or
    /// over TLS mqtts://... (ssl:// too; port 8883).
    #[arg(long, default_value = "mqtt://127.0.0.1:1883")]
    pub mqtt: String,
    /// The CA certificates (PEM) the broker's certificate must chain to,
    /// for mqtts:// (default: the system's CAs).
    #[arg(long, value_name = "FILE")]
    pub mqtt_ca: Option<PathBuf>,
    /// The gateway's client certificate (PEM), for a broker that asks for
    /// one (mutual TLS); with --mqtt-key.
    #[arg(long, value_name = "FILE", requires = "mqtt_key")]
    pub mqtt_cert: Option<PathBuf>,
    /// The private key (PEM) of --mqtt-cert.
    #[arg(long, value_name = "FILE", requires = "mqtt_cert")]
    pub mqtt_key: Option<PathBuf>,
    /// The MQTT version: 5, or 3.1.1 for an older broker (no message
    /// expiry, no response topics: the `transaction` field correlates).
    #[arg(long, value_name = "5|3.1.1", default_value = "5")]
    pub mqtt_version: gateway::session::Version,
    /// MQTT 5: the broker drops a depth report not delivered within this
    /// many seconds (so a late subscriber never gets a stale distance);
    /// 0: never. Default 1.
    #[arg(long, value_name = "S")]
    pub depth_expiry_s: Option<u32>,
    /// A file holding the broker password (instead of putting it in --mqtt).
    #[arg(long, value_name = "FILE")]
    pub mqtt_password_file: Option<PathBuf>,
    /// The MQTT client id.
    #[arg(long, default_value = "stereolink-gateway")]
    pub client_id: String,
    /// The first level of every topic.
    #[arg(long, default_value = "stereolink")]
    pub topic_prefix: String,
    /// This gateway's private key (NAME.key from `stereolink keygen`).
    #[arg(long, value_name = "FILE", requires = "peer_keys")]
    pub key: Option<PathBuf>,
    /// A folder with each station's public key as <station>.pub; only the
    /// station holding the matching private key is accepted on its link.
    #[arg(long, value_name = "DIR", requires = "key")]
    pub peer_keys: Option<PathBuf>,
    /// A station silent this long is published offline.
    #[arg(long, default_value_t = 10.0)]
    pub offline_after_s: f64,
    /// Most messages kept while the broker is away (the oldest beyond are
    /// dropped and counted in bridge/health).
    #[arg(long, default_value_t = 10_000)]
    pub queue: usize,
    /// Largest disparity searched when a frame is rebuilt.
    #[arg(long, default_value_t = 32)]
    pub max_disp: usize,
    /// Rebuild and publish the images of at most one frame per station
    /// this often (seconds; 0: every frame). Rebuilding (decode, match,
    /// three PNGs) is most of the gateway's work.
    #[arg(long, default_value_t = 10.0)]
    pub images_every_s: f64,
    /// How often each station's link statistics go out, seconds.
    #[arg(long, default_value_t = 5.0)]
    pub stats_every_s: f64,
    /// How often bridge/health goes out, seconds.
    #[arg(long, default_value_t = 10.0)]
    pub health_every_s: f64,
    /// Announce each station to Home Assistant (MQTT discovery under this
    /// prefix, usually `homeassistant`): distance sensor, axis-stop
    /// button, levels number.
    #[arg(long, value_name = "PREFIX")]
    pub homeassistant: Option<String>,
    /// Stop after this many seconds (0: run until killed).
    #[arg(long, default_value_t = 0.0)]
    pub run_s: f64,
    /// Record every station in FILE.mcap as ROS 2 messages, under
    /// /STATION/... (docs/recording.md): its depth reports, the frames it
    /// rebuilds and its link statistics. A write that fails closes the
    /// recording; the gateway goes on.
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    #[command(flatten)]
    /// `--config FILE.toml`.
    pub config: crate::config::ConfigArg,
}

/// Bridges the stations to the broker until killed (or `--run-s`).
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let secs = |s: f64, what: &str| {
        anyhow::ensure!(
            s.is_finite() && s >= 0.0,
            "--{what} must be a number of seconds"
        );
        Ok(Duration::from_secs_f64(s))
    };
    let mut broker = Broker::parse(&args.mqtt)?;
    broker.client_id = args.client_id.clone();
    let client = args.mqtt_cert.clone().zip(args.mqtt_key.clone());
    match &mut broker.tls {
        Some(tls) => {
            tls.ca = args.mqtt_ca.clone();
            tls.client = client;
        }
        None => anyhow::ensure!(
            args.mqtt_ca.is_none() && client.is_none(),
            "--mqtt-ca, --mqtt-cert and --mqtt-key are for TLS: give the broker as mqtts://HOST:PORT"
        ),
    }
    if let Some(f) = &args.mqtt_password_file {
        let pw = std::fs::read_to_string(f)
            .with_context(|| format!("cannot read the broker password from {}", f.display()))?;
        let user = broker.login.map(|l| l.0).unwrap_or_default();
        broker.login = Some((user, pw.trim_end().to_string()));
    }
    let depth_expiry_s = match (args.mqtt_version, args.depth_expiry_s) {
        (gateway::session::Version::V311, Some(_)) => {
            anyhow::bail!("--depth-expiry-s needs MQTT 5 (--mqtt-version 5)")
        }
        (gateway::session::Version::V311, None) | (_, Some(0)) => None,
        (_, s) => Some(s.unwrap_or(1)),
    };
    let private = match &args.key {
        Some(k) => Some(keyfile::read_key(k).context("cannot load the gateway's key")?),
        None => {
            eprintln!(
                "warning: no --key/--peer-keys: the links are not authenticated; anyone in \
                 radio range can send reports, and commands go out unsealed"
            );
            None
        }
    };
    let recorder = match &args.record {
        Some(path) => Some(Arc::new(Mutex::new(Recorder::create(
            path,
            OnError::Continue,
        )?))),
        None => None,
    };
    let mut stations = Vec::new();
    for (i, text) in args.links.iter().enumerate() {
        let (name, spec) = match text.split_once('=') {
            // A spec's own query has '=' after '?': a name has none before.
            Some((n, s)) if !n.contains(['?', ':', '/']) => (n.to_string(), s),
            _ => (format!("station{}", i + 1), text.as_str()),
        };
        let keys = match (private, &args.peer_keys) {
            (Some(private), Some(dir)) => {
                let path = dir.join(format!("{name}.pub"));
                let peer = keyfile::read_key(&path)
                    .with_context(|| format!("station {name}: cannot load its public key"))?;
                Some(Keys::new(private, peer))
            }
            _ => None,
        };
        stations.push(StationConfig {
            link: super::link_spec(spec).with_context(|| format!("station {name}"))?,
            link_text: spec.to_string(),
            name,
            keys,
            max_disp: args.max_disp,
            stats_every: secs(args.stats_every_s, "stats-every-s")?,
            images_every: secs(args.images_every_s, "images-every-s")?,
            recorder: recorder.clone(),
        });
    }
    let cfg = GatewayConfig {
        stations,
        broker,
        prefix: args.topic_prefix.clone(),
        offline_after: secs(args.offline_after_s, "offline-after-s")?,
        queue: args.queue,
        health_every: secs(args.health_every_s, "health-every-s")?,
        discovery: args.homeassistant.clone(),
        version: args.mqtt_version,
        depth_expiry_s,
    };
    eprintln!(
        "gateway: {} station(s) to {} (MQTT {}) under {}/",
        cfg.stations.len(),
        cfg.broker,
        cfg.version,
        cfg.prefix
    );
    let stop = Arc::new(AtomicBool::new(false));
    if args.run_s > 0.0 {
        let (stop, t) = (stop.clone(), secs(args.run_s, "run-s")?);
        std::thread::spawn(move || {
            std::thread::sleep(t);
            stop.store(true, Ordering::Relaxed);
        });
    }
    // systemd (deploy/systemd/stereolink-gateway.service): ready once the
    // broker first answers, alive while the bridge's loop turns.
    let mut service = super::service::Service::new();
    let mut ready = false;
    let broker_name = cfg.broker.to_string();
    let summary = gateway::run(cfg, stop, |connected| {
        if connected && !ready {
            ready = true;
            service.ready(&format!("bridging to {broker_name}"));
        }
        if ready {
            service.alive();
        }
    });
    service.stopping();
    // The stations' threads have ended: the recording is this one's alone.
    if let Some(r) = recorder.and_then(Arc::into_inner) {
        r.into_inner().unwrap_or_else(|e| e.into_inner()).finish()?;
    }
    let summary = summary?;
    out.emit(&summary, || {
        format!(
            "gateway: {} published, {} published again after a reconnect, {} dropped, {} reconnects, {} commands\n",
            summary.published,
            summary.republished,
            summary.dropped.values().sum::<u64>(),
            summary.reconnects,
            summary.commands
        )
    })
}
