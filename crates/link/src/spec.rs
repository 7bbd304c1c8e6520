//! Link specifications, as users write them on the command line:
//!
//! * `serial:/dev/ttyUSB0?baud=115200&api=2&dest=0x0001&mtu=100&radio=auto` — an
//!   XBee in API mode 1 or 2 (`api=0`: transparent mode or a USB cable, SLIP
//!   framed). `dest` is the peer's 16-bit `MY` (0xFFFF, the default, is the
//!   broadcast) or its 64-bit `SH`/`SL` (`dest=0x0013A20040522BAA`: more than
//!   four hex digits). `radio=auto` asks the radio its firmware and `NP` when
//!   the link opens ([`crate::radio::ask`]); `radio=802.15.4|zigbee|digimesh`
//!   names the family and asks nothing; `flow=rtscts` turns on RTS/CTS
//!   hardware flow control (set D6=1 and D7=1 on the radio);
//! * `udp:127.0.0.1:9001?peer=127.0.0.1:9000` — bind locally, send to `peer`
//!   (without `peer`, answer whoever sends first);
//! * `sim:?loss=0.1&seed=3&baud=115200&mac_retries=0&ber=0&dup=0&reorder=0&speedup=20` —
//!   the simulated XBee channel (inside one process); `radio=zigbee` models
//!   ZigBee firmware (its frames and overheads, and `mtu` 84 by default) and
//!   `radio=digimesh` DigiMesh, both at Digi's measured throughput for
//!   `hops=1`, `encrypted=0` and `role=rr|re|er` ([`crate::throughput`]);
//!   `buffer=256` is the radio's serial buffer in bytes, and `paced=2` the
//!   transmit requests the host keeps at the radio (0: as CTS allows);
//! * `fallback:PRIMARY,SECONDARY?silence_ms=2000` (the query after the last
//!   spec applies to the fallback).
//!
//! Several specs given together make a bond of them ([`open_all`],
//! [`crate::bond`]).

use std::net::SocketAddr;
use std::time::Duration;

use crate::arq::MIN_MTU;
use crate::bond::Bond;
use crate::radio::{self, Address, Firmware, RadioInfo};
use crate::sim::SimConfig;
use crate::throughput::{RadioPath, Role};
use crate::transport::{Fallback, Serial, SerialFraming, Transport, Udp};
use crate::xbee::ApiMode;

/// How a serial link speaks to an XBee in API mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ApiSpec {
    /// `api=1` or `api=2`.
    pub mode: ApiMode,
    /// `dest=`: the peer.
    pub dest: Address,
    /// `radio=`: the firmware family, or `None` (`auto`) to ask the radio.
    pub radio: Option<Firmware>,
    /// `hops=`: radio hops to the peer (ZigBee, DigiMesh; default 1).
    pub hops: u8,
    /// `encrypted=1`: the radios' network security is on.
    pub encrypted: bool,
}

/// A parsed link specification.
#[derive(Clone, Debug, PartialEq)]
pub enum LinkSpec {
    /// A serial port: an XBee in API mode, or (`api: None`) SLIP frames.
    Serial {
        /// The port's device path.
        path: String,
        /// Its baud rate.
        baud: u32,
        /// The XBee API mode and firmware, or `None` for SLIP.
        api: Option<ApiSpec>,
        /// The largest packet.
        mtu: usize,
        /// `flow=rtscts`: RTS/CTS hardware flow control (the radio's D6/D7).
        rtscts: bool,
    },
    /// A UDP socket.
    Udp {
        /// The local address.
        bind: SocketAddr,
        /// The peer's address (`None`: the first sender's).
        peer: Option<SocketAddr>,
        /// The largest datagram.
        mtu: usize,
    },
    /// The simulated channel, real time sped up by `speedup`.
    Sim {
        /// The channel model.
        config: SimConfig,
        /// How much faster than real time it runs.
        speedup: f64,
    },
    /// Primary and secondary.
    Fallback {
        /// The link used while it works.
        primary: Box<LinkSpec>,
        /// The link used when the primary falls silent.
        secondary: Box<LinkSpec>,
        /// How long a silence moves the traffic over.
        silence: Duration,
    },
}

fn query(q: &str) -> Vec<(&str, &str)> {
    q.split('&')
        .filter(|p| !p.is_empty())
        .map(|p| p.split_once('=').unwrap_or((p, "")))
        .collect()
}

/// A `dest=` value: 64-bit when written with more than four hex digits or
/// above 0xFFFF, 16-bit otherwise.
fn address(v: &str) -> Result<Address, String> {
    let n: u64 = num("dest", v)?;
    let long_hex = v.strip_prefix("0x").is_some_and(|h| h.len() > 4);
    Ok(match u16::try_from(n) {
        Ok(short) if !long_hex => Address::Short(short),
        _ => Address::Long(n),
    })
}

/// A link's `mtu` must hold every segment: at least an ACK.
fn check_mtu(kind: &str, mtu: usize) -> Result<(), String> {
    if mtu < MIN_MTU {
        return Err(format!(
            "{kind}: mtu={mtu} is too small: an ACK segment takes {MIN_MTU} bytes"
        ));
    }
    Ok(())
}

fn num<T: std::str::FromStr>(key: &str, v: &str) -> Result<T, String> {
    let v2 = v.trim_start_matches("0x");
    if v.starts_with("0x") {
        if let Ok(n) = u64::from_str_radix(v2, 16) {
            if let Ok(t) = n.to_string().parse() {
                return Ok(t);
            }
        }
    }
    v.parse()
        .map_err(|_| format!("{key}={v} is not a valid number"))
}

impl std::str::FromStr for LinkSpec {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let (kind, rest) = s
            .split_once(':')
            .ok_or_else(|| format!("link {s:?}: expected serial:, udp:, sim: or fallback:"))?;
        if kind == "fallback" {
            let (specs, q) = match rest.rsplit_once('?') {
                Some((a, q)) if !q.contains(':') => (a, q),
                _ => (rest, ""),
            };
            let (p, sec) = specs
                .split_once(',')
                .ok_or("fallback: needs PRIMARY,SECONDARY")?;
            let mut silence = Duration::from_millis(2000);
            for (k, v) in query(q) {
                match k {
                    "silence_ms" => silence = Duration::from_millis(num(k, v)?),
                    _ => return Err(format!("fallback: unknown option {k}")),
                }
            }
            return Ok(LinkSpec::Fallback {
                primary: Box::new(p.parse()?),
                secondary: Box::new(sec.parse()?),
                silence,
            });
        }
        let (target, q) = rest.split_once('?').unwrap_or((rest, ""));
        let q = query(q);
        match kind {
            "serial" => {
                if target.is_empty() {
                    return Err("serial: needs a device path, e.g. serial:/dev/ttyUSB0".into());
                }
                let (mut baud, mut api, mut dest, mut mtu) =
                    (115_200u32, 2u8, Address::BROADCAST, 100usize);
                let (mut radio, mut rtscts) = (None, false);
                let (mut hops, mut encrypted) = (1u8, false);
                for (k, v) in q {
                    match k {
                        "baud" => baud = num(k, v)?,
                        "api" => api = num(k, v)?,
                        "dest" => dest = address(v)?,
                        "mtu" => mtu = num(k, v)?,
                        "radio" if v == "auto" => radio = None,
                        "radio" => radio = Some(v.parse()?),
                        "hops" => hops = num(k, v)?,
                        "encrypted" => encrypted = num::<u8>(k, v)? != 0,
                        "flow" => {
                            rtscts = match v {
                                "rtscts" => true,
                                "none" => false,
                                _ => return Err(format!("flow={v}: expected rtscts or none")),
                            }
                        }
                        _ => return Err(format!("serial: unknown option {k}")),
                    }
                }
                let mode = match api {
                    0 => None,
                    1 => Some(ApiMode::Plain),
                    2 => Some(ApiMode::Escaped),
                    _ => return Err(format!("serial: api={api} must be 0, 1 or 2")),
                };
                if let Some(firmware) = radio {
                    radio::check_dest(firmware, dest)?;
                    let role = Role::RouterToRouter;
                    RadioPath {
                        firmware,
                        hops,
                        encrypted,
                        role,
                    }
                    .validate()?;
                } else if hops == 0 || hops > crate::throughput::MAX_HOPS {
                    return Err(format!(
                        "hops={hops}: expected 1 to {}",
                        crate::throughput::MAX_HOPS
                    ));
                }
                check_mtu("serial", mtu)?;
                Ok(LinkSpec::Serial {
                    path: target.into(),
                    baud,
                    api: mode.map(|mode| ApiSpec {
                        mode,
                        dest,
                        radio,
                        hops,
                        encrypted,
                    }),
                    mtu,
                    rtscts,
                })
            }
            "udp" => {
                let bind = target
                    .parse()
                    .map_err(|_| format!("udp:{target}: not an address like 127.0.0.1:9000"))?;
                let (mut peer, mut mtu) = (None, 100usize);
                for (k, v) in q {
                    match k {
                        "peer" => {
                            peer = Some(v.parse().map_err(|_| format!("peer={v}: not an address"))?)
                        }
                        "mtu" => mtu = num(k, v)?,
                        _ => return Err(format!("udp: unknown option {k}")),
                    }
                }
                check_mtu("udp", mtu)?;
                Ok(LinkSpec::Udp { bind, peer, mtu })
            }
            "sim" => {
                let (mut c, mut speedup, mut mtu) = (SimConfig::default(), 1.0, None);
                for (k, v) in q {
                    match k {
                        "radio" => c.radio = v.parse()?,
                        "loss" => c.loss = num(k, v)?,
                        "seed" => c.seed = num(k, v)?,
                        "baud" => c.baud = num(k, v)?,
                        "mtu" => mtu = Some(num(k, v)?),
                        "mac_retries" => c.mac_retries = num(k, v)?,
                        "ber" => c.bit_error = num(k, v)?,
                        "dup" => c.duplicate = num(k, v)?,
                        "reorder" => c.reorder = num(k, v)?,
                        "hops" => c.hops = num(k, v)?,
                        "encrypted" => c.encrypted = num::<u8>(k, v)? != 0,
                        "role" => c.role = v.parse()?,
                        "buffer" => c.buffer = num(k, v)?,
                        "paced" => c.paced = num(k, v)?,
                        "speedup" => speedup = num(k, v)?,
                        _ => return Err(format!("sim: unknown option {k}")),
                    }
                }
                // ZigBee's NP is 84 bytes; 802.15.4 takes 100.
                c.mtu = mtu.unwrap_or(match c.radio {
                    Firmware::Ieee802154 => 100,
                    Firmware::Zigbee | Firmware::DigiMesh => 84,
                });
                if !(0.0..=1.0).contains(&c.loss) || c.baud == 0 {
                    return Err("sim: loss must be in 0..1 and baud > 0".into());
                }
                c.path().validate().map_err(|e| format!("sim: {e}"))?;
                check_mtu("sim", c.mtu)?;
                Ok(LinkSpec::Sim { config: c, speedup })
            }
            other => Err(format!(
                "unknown link kind {other:?}: use serial:, udp:, sim: or fallback:"
            )),
        }
    }
}

fn open_port(
    path: &str,
    baud: u32,
    rtscts: bool,
) -> std::io::Result<Box<dyn serialport::SerialPort>> {
    let flow = match rtscts {
        true => serialport::FlowControl::Hardware,
        false => serialport::FlowControl::None,
    };
    serialport::new(path, baud)
        .flow_control(flow)
        .timeout(Duration::from_millis(1))
        .open()
        .map_err(|e| {
            std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!("cannot open serial port {path}: {e}"),
            )
        })
}

fn ask_on(
    port: &mut Box<dyn serialport::SerialPort>,
    path: &str,
    baud: u32,
    api: &ApiSpec,
) -> std::io::Result<RadioInfo> {
    radio::ask(port, api.mode, api.radio, radio::AT_TIMEOUT).map_err(|e| {
        let e = std::io::Error::from(e);
        std::io::Error::new(e.kind(), format!("{path} at {baud} baud: {e}"))
    })
}

/// Opens the port of a `serial:` spec in API mode and asks its radio
/// ([`radio::ask`]; `radio=` overrides the family it derives).
pub fn ask_radio(spec: &LinkSpec) -> std::io::Result<RadioInfo> {
    match spec {
        LinkSpec::Serial {
            path,
            baud,
            api: Some(api),
            rtscts,
            ..
        } => ask_on(&mut open_port(path, *baud, *rtscts)?, path, *baud, api),
        _ => Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "only a serial: link in API mode (api=1 or 2) has a radio to ask",
        )),
    }
}

/// Opens a transport (not `sim:`, whose two ends live in one process: use
/// [`crate::sim::pair`]). A serial link in API mode with `radio=auto` asks the
/// radio first: its firmware picks the transmit request, its `NP` caps `mtu`.
pub fn open(spec: &LinkSpec) -> std::io::Result<Box<dyn Transport>> {
    let invalid = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, m);
    Ok(match spec {
        LinkSpec::Serial { path, baud, api, mtu, rtscts } => {
            let name = format!("serial:{path}");
            let Some(api) = api else {
                return Ok(Box::new(Serial::new(open_port(path, *baud, *rtscts)?, SerialFraming::Transparent, *mtu, name)));
            };
            let mut port = open_port(path, *baud, *rtscts)?;
            let (firmware, mtu) = match api.radio {
                Some(firmware) => (firmware, *mtu),
                None => {
                    let info = ask_on(&mut port, path, *baud, api)?;
                    let firmware = info.firmware.ok_or_else(|| {
                        invalid(format!(
                            "{path}: firmware VR {:04X} on hardware HV {:04X} is not one stereolink knows; name it with radio=802.15.4, radio=zigbee or radio=digimesh",
                            info.firmware_version, info.hardware_version
                        ))
                    })?;
                    let np = info.max_payload.map_or(*mtu, usize::from);
                    if np < MIN_MTU {
                        return Err(invalid(format!(
                            "{path}: the radio's NP is {np} bytes, no room for the link's segments (an ACK takes {MIN_MTU}); check its encryption and source-routing settings"
                        )));
                    }
                    (firmware, (*mtu).min(np))
                }
            };
            radio::check_dest(firmware, api.dest).map_err(invalid)?;
            let radio_path = RadioPath { firmware, hops: api.hops, encrypted: api.encrypted, role: Role::RouterToRouter };
            radio_path.validate().map_err(|e| invalid(format!("{path}: {e}")))?;
            let framing = SerialFraming::Api { mode: api.mode, firmware, dest: api.dest };
            Box::new(Serial::new(port, framing, mtu, name).on_path(radio_path))
        }
        LinkSpec::Udp { bind, peer, mtu } => Box::new(Udp::bind(*bind, *peer, *mtu)?),
        LinkSpec::Sim { .. } => {
            return Err(std::io::Error::new(
                std::io::ErrorKind::Unsupported,
                "a sim: link has both ends in one process (demo, link-test); use serial: or udp: between processes",
            ))
        }
        LinkSpec::Fallback { primary, secondary, silence } => Box::new(Fallback::new(open(primary)?, open(secondary)?, *silence)),
    })
}

/// Opens one transport, or with several specs a [`Bond`] of them (see
/// [`open`]; `sim:` specs bond with [`Bond::sim_pair`]).
pub fn open_all(specs: &[LinkSpec]) -> std::io::Result<Box<dyn Transport>> {
    match specs {
        [] => Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "no link given",
        )),
        [one] => open(one),
        several => {
            let members = several.iter().map(open).collect::<Result<_, _>>()?;
            Ok(Box::new(Bond::new(members)))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_kind() {
        let s: LinkSpec = "serial:/dev/ttyUSB0?baud=57600&api=1&dest=0x1234&flow=rtscts"
            .parse()
            .unwrap();
        assert_eq!(
            s,
            LinkSpec::Serial {
                path: "/dev/ttyUSB0".into(),
                baud: 57600,
                api: Some(ApiSpec {
                    mode: ApiMode::Plain,
                    dest: Address::Short(0x1234),
                    radio: None,
                    hops: 1,
                    encrypted: false,
                }),
                mtu: 100,
                rtscts: true,
            }
        );
        let z: LinkSpec = "serial:/dev/ttyUSB0?dest=0x0013A20040522BAA&radio=zigbee"
            .parse()
            .unwrap();
        assert!(matches!(
            z,
            LinkSpec::Serial {
                api: Some(ApiSpec {
                    mode: ApiMode::Escaped,
                    dest: Address::Long(0x0013_A200_4052_2BAA),
                    radio: Some(Firmware::Zigbee),
                    ..
                }),
                ..
            }
        ));
        // Leading zeros make a 64-bit address; api=0 has no API options.
        let z: LinkSpec = "serial:/x?dest=0x000000000000FFFF".parse().unwrap();
        assert!(matches!(
            z,
            LinkSpec::Serial {
                api: Some(ApiSpec {
                    dest: Address::Long(0xFFFF),
                    ..
                }),
                ..
            }
        ));
        let t: LinkSpec = "serial:/x?api=0".parse().unwrap();
        assert!(matches!(t, LinkSpec::Serial { api: None, .. }));
        let u: LinkSpec = "udp:127.0.0.1:9001?peer=127.0.0.1:9000".parse().unwrap();
        assert!(matches!(u, LinkSpec::Udp { peer: Some(_), .. }));
        let m: LinkSpec = "sim:?loss=0.1&seed=3".parse().unwrap();
        assert!(
            matches!(m, LinkSpec::Sim { config: SimConfig { loss, seed: 3, mtu: 100, .. }, .. } if loss == 0.1)
        );
        let z: LinkSpec = "sim:?radio=zigbee".parse().unwrap();
        assert!(matches!(
            z,
            LinkSpec::Sim {
                config: SimConfig {
                    radio: Firmware::Zigbee,
                    mtu: 84,
                    ..
                },
                ..
            }
        ));
        let f: LinkSpec = "fallback:udp:127.0.0.1:1,udp:127.0.0.1:2?silence_ms=500"
            .parse()
            .unwrap();
        assert!(
            matches!(f, LinkSpec::Fallback { silence, .. } if silence == Duration::from_millis(500))
        );
        for bad in [
            "",
            "tcp:1",
            "serial:",
            "udp:nope",
            "sim:?loss=2",
            "sim:?what=1",
            "serial:/x?api=7",
            "serial:/x?radio=lora",
            "serial:/x?radio=digimesh&dest=0x1234",
            "serial:/x?flow=xonxoff",
            "serial:/x?mtu=17",
            "udp:127.0.0.1:9000?mtu=10",
            "sim:?mtu=16",
            "fallback:udp:1.2.3.4:5",
        ] {
            assert!(bad.parse::<LinkSpec>().is_err(), "{bad}");
        }
    }

    #[test]
    fn absent_serial_device_is_a_clear_error() {
        let spec: LinkSpec = "serial:/dev/does-not-exist".parse().unwrap();
        let err = open(&spec).err().unwrap().to_string();
        assert!(err.contains("/dev/does-not-exist"), "{err}");
    }

    #[test]
    fn several_specs_open_as_a_bond() {
        let udp = |mtu| -> LinkSpec { format!("udp:127.0.0.1:0?mtu={mtu}").parse().unwrap() };
        let one = open_all(&[udp(90)]).unwrap();
        assert!(one.describe().starts_with("udp:"), "{}", one.describe());
        let two = open_all(&[udp(90), udp(100)]).unwrap();
        assert!(
            two.describe().starts_with("bond:udp:"),
            "{}",
            two.describe()
        );
        assert_eq!(two.mtu(), 90 - crate::bond::HEADER);
        assert!(open_all(&[]).is_err());
        let bad = open_all(&[udp(90), "serial:/dev/does-not-exist".parse().unwrap()]);
        assert!(bad
            .err()
            .unwrap()
            .to_string()
            .contains("/dev/does-not-exist"));
    }
}
