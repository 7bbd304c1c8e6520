//! The broker session in either protocol version behind one face: MQTT 5
//! by default (rumqttc's `v5` client: message expiry on depth reports,
//! response topic and correlation data on commands), or MQTT 3.1.1 for an
//! older broker (rumqttc's first client: no properties, the `transaction`
//! field alone correlates). The bridge sees only [`Ev`] and [`Pub`].

use std::time::Duration;

use bytes::Bytes;
use rumqttc::v5;
use rumqttc::v5::mqttbytes::v5::{Packet as Packet5, PublishProperties};
use rumqttc::{Event, Outgoing, Packet, QoS, Transport};

use crate::mqtt::Pub;
use crate::Broker;

/// The MQTT protocol version the gateway speaks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Version {
    /// MQTT 5 (the default).
    #[default]
    V5,
    /// MQTT 3.1.1.
    V311,
}

/// `5` or `3.1.1`.
impl std::fmt::Display for Version {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Version::V5 => "5",
            Version::V311 => "3.1.1",
        })
    }
}

impl std::str::FromStr for Version {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "5" | "5.0" => Ok(Version::V5),
            "3.1.1" | "3" | "4" => Ok(Version::V311),
            other => Err(format!("MQTT version {other:?}: 5 or 3.1.1")),
        }
    }
}

/// Where a request wants its answer (MQTT 5): its response topic and its
/// correlation data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Reply {
    /// The response topic the client gave.
    pub topic: String,
    /// The correlation data it gave, echoed in the answer.
    pub correlation: Option<Vec<u8>>,
}

/// One event of the session, whatever its version.
pub(crate) enum Ev {
    /// The broker took the connection.
    ConnAck,
    /// The broker acknowledged a publish.
    PubAck(u16),
    /// A message from a subscription.
    Publish {
        topic: String,
        payload: Vec<u8>,
        reply: Option<Reply>,
    },
    /// The client wrote a packet.
    Outgoing(Outgoing),
    /// Anything else (pings, SUBACKs).
    Other,
    /// The connection failed or was lost: what happened, and the TLS
    /// cause if TLS is what failed.
    Lost { error: String, tls: Option<String> },
}

/// What waiting for an event gave.
pub(crate) enum Recv {
    Ev(Ev),
    Timeout,
    Closed,
}

/// The client and its connection, of one version (boxed: they are large
/// and unlike in size).
pub(crate) enum Session {
    V311(rumqttc::Client, Box<rumqttc::Connection>),
    V5(v5::Client, Box<v5::Connection>),
}

impl Session {
    /// A session (not yet connected: [`Session::recv_timeout`] connects)
    /// with a retained `offline` last will on `will_topic`.
    pub(crate) fn new(
        broker: &Broker,
        version: Version,
        will_topic: String,
        transport: Transport,
    ) -> Session {
        let (id, host, port) = (broker.client_id.clone(), broker.host.clone(), broker.port);
        match version {
            Version::V311 => {
                let mut o = rumqttc::MqttOptions::new(id, host, port);
                o.set_keep_alive(Duration::from_secs(5))
                    .set_clean_session(true)
                    .set_max_packet_size(64 * 1024, 16 * 1024 * 1024)
                    .set_inflight(100)
                    .set_transport(transport)
                    .set_last_will(rumqttc::LastWill::new(
                        will_topic,
                        "offline",
                        QoS::AtLeastOnce,
                        true,
                    ));
                if let Some((u, p)) = &broker.login {
                    o.set_credentials(u.clone(), p.clone());
                }
                let (c, conn) = rumqttc::Client::new(o, 256);
                Session::V311(c, Box::new(conn))
            }
            Version::V5 => {
                let mut o = v5::MqttOptions::new(id, host, port);
                o.set_keep_alive(Duration::from_secs(5))
                    .set_clean_start(true)
                    .set_max_packet_size(Some(64 * 1024))
                    .set_outgoing_inflight_upper_limit(100)
                    .set_transport(transport)
                    .set_last_will(v5::mqttbytes::v5::LastWill::new(
                        will_topic,
                        "offline",
                        v5::mqttbytes::QoS::AtLeastOnce,
                        true,
                        None,
                    ));
                if let Some((u, p)) = &broker.login {
                    o.set_credentials(u.clone(), p.clone());
                }
                let (c, conn) = v5::Client::new(o, 256);
                Session::V5(c, Box::new(conn))
            }
        }
    }

    /// The next event, waiting at most `wait`.
    pub(crate) fn recv_timeout(&mut self, wait: Duration) -> Recv {
        match self {
            Session::V311(_, conn) => match conn.recv_timeout(wait) {
                Err(rumqttc::RecvTimeoutError::Timeout) => Recv::Timeout,
                Err(rumqttc::RecvTimeoutError::Disconnected) => Recv::Closed,
                Ok(Ok(ev)) => Recv::Ev(match ev {
                    Event::Incoming(Packet::ConnAck(_)) => Ev::ConnAck,
                    Event::Incoming(Packet::PubAck(a)) => Ev::PubAck(a.pkid),
                    Event::Incoming(Packet::Publish(p)) => Ev::Publish {
                        topic: p.topic,
                        payload: p.payload.to_vec(),
                        reply: None,
                    },
                    Event::Outgoing(o) => Ev::Outgoing(o),
                    Event::Incoming(_) => Ev::Other,
                }),
                Ok(Err(e)) => Recv::Ev(Ev::Lost {
                    error: e.to_string(),
                    tls: crate::tls::failure(
                        &e,
                        match &e {
                            rumqttc::ConnectionError::Tls(t) => Some(t),
                            _ => None,
                        },
                    ),
                }),
            },
            Session::V5(_, conn) => match conn.recv_timeout(wait) {
                Err(v5::RecvTimeoutError::Timeout) => Recv::Timeout,
                Err(v5::RecvTimeoutError::Disconnected) => Recv::Closed,
                Ok(Ok(ev)) => Recv::Ev(match ev {
                    v5::Event::Incoming(Packet5::ConnAck(_)) => Ev::ConnAck,
                    v5::Event::Incoming(Packet5::PubAck(a)) => Ev::PubAck(a.pkid),
                    v5::Event::Incoming(Packet5::Publish(p)) => {
                        let props = p.properties.unwrap_or_default();
                        Ev::Publish {
                            topic: String::from_utf8_lossy(&p.topic).into_owned(),
                            payload: p.payload.to_vec(),
                            reply: props.response_topic.map(|topic| Reply {
                                topic,
                                correlation: props.correlation_data.map(|c| c.to_vec()),
                            }),
                        }
                    }
                    v5::Event::Outgoing(o) => Ev::Outgoing(o),
                    v5::Event::Incoming(_) => Ev::Other,
                }),
                Ok(Err(e)) => {
                    // The v5 client's read errors do not name their I/O
                    // error as their source: the TLS alert hides there.
                    let root: &(dyn std::error::Error + 'static) = match &e {
                        v5::ConnectionError::MqttState(v5::StateError::Deserialization(
                            v5::mqttbytes::Error::Io(io),
                        )) => io,
                        other => other,
                    };
                    let handshake = match &e {
                        v5::ConnectionError::Tls(t) => Some(t),
                        _ => None,
                    };
                    Recv::Ev(Ev::Lost {
                        error: e.to_string(),
                        tls: crate::tls::failure(root, handshake),
                    })
                }
            },
        }
    }

    /// Subscribes to `filter` at QoS 1 (false: the client is busy).
    pub(crate) fn try_subscribe(&self, filter: String) -> bool {
        match self {
            Session::V311(c, _) => c.try_subscribe(filter, QoS::AtLeastOnce).is_ok(),
            Session::V5(c, _) => c
                .try_subscribe(filter, v5::mqttbytes::QoS::AtLeastOnce)
                .is_ok(),
        }
    }

    /// Hands `p` to the client (false: its channel is full); MQTT 5 adds
    /// its expiry interval and correlation data.
    pub(crate) fn try_publish(&self, p: &Pub) -> bool {
        match self {
            Session::V311(c, _) => c
                .try_publish(p.topic.clone(), p.qos, p.retain, p.payload.clone())
                .is_ok(),
            Session::V5(c, _) => {
                let qos = match p.qos {
                    QoS::AtMostOnce => v5::mqttbytes::QoS::AtMostOnce,
                    QoS::AtLeastOnce => v5::mqttbytes::QoS::AtLeastOnce,
                    QoS::ExactlyOnce => v5::mqttbytes::QoS::ExactlyOnce,
                };
                let props = PublishProperties {
                    message_expiry_interval: p.expiry_s,
                    correlation_data: p.correlation.clone().map(Bytes::from),
                    ..Default::default()
                };
                c.try_publish_with_properties(
                    p.topic.clone(),
                    qos,
                    p.retain,
                    p.payload.clone(),
                    props,
                )
                .is_ok()
            }
        }
    }

    /// Says goodbye to the broker, and gives the client a moment to.
    pub(crate) fn disconnect(&mut self) {
        match self {
            Session::V311(c, _) => {
                let _ = c.try_disconnect();
            }
            Session::V5(c, _) => {
                let _ = c.try_disconnect();
            }
        }
        let _ = self.recv_timeout(Duration::from_millis(100));
    }
}
