//! The broker connection: a ledger of what was handed to the MQTT client,
//! so that nothing is lost when the broker goes away, a bounded queue of
//! what waits meanwhile, and the retained state to publish again on every
//! (re)connection.
//!
//! rumqttc forgets its unacknowledged publishes when it reconnects with a
//! clean session; the gateway therefore keeps each publish in its
//! [`Outbox`] until the broker acknowledged it (QoS 1) or it was written
//! (QoS 0), and on a lost connection puts the unacknowledged ones back at
//! the head of its queue. Retained topics are kept as their latest value
//! only, and are all published again after each CONNACK.

use std::collections::{BTreeMap, VecDeque};

use rumqttc::{Outgoing, QoS};

/// One publish the gateway wants made.
#[derive(Clone, Debug)]
pub struct Pub {
    /// The topic.
    pub topic: String,
    /// The payload.
    pub payload: Vec<u8>,
    /// The quality of service it goes with.
    pub qos: QoS,
    /// Whether the broker keeps it for later subscribers.
    pub retain: bool,
    /// What it is, for the drop counts (`depth`, `link`, `response`, ...).
    pub kind: &'static str,
    /// MQTT 5: the broker drops it after this many seconds undelivered.
    pub expiry_s: Option<u32>,
    /// MQTT 5: the correlation data of the request it answers.
    pub correlation: Option<Vec<u8>>,
}

/// A publish handed to the client: its packet id once written.
#[derive(Debug)]
struct Handed {
    publish: Pub,
    pkid: Option<u16>,
}

/// The gateway's side of the broker connection.
#[derive(Debug)]
pub struct Outbox {
    /// Waiting for the client (non-retained ones count against `cap`).
    queue: VecDeque<Pub>,
    /// Handed to the client, in the order it takes them.
    handed: VecDeque<Handed>,
    /// Latest payload of each retained topic.
    retained: BTreeMap<String, Pub>,
    /// Most non-retained publishes the queue holds.
    cap: usize,
    /// Most publishes handed to the client and not yet acknowledged.
    window: usize,
    /// Publishes dropped because the queue was full, by kind.
    pub dropped: BTreeMap<&'static str, u64>,
    /// Publishes acknowledged by the broker (or written, QoS 0).
    pub published: u64,
    /// Publishes handed again after a lost connection.
    pub republished: u64,
}

impl Outbox {
    /// An outbox holding at most `cap` waiting messages, `window` in flight.
    pub fn new(cap: usize, window: usize) -> Self {
        Outbox {
            queue: VecDeque::new(),
            handed: VecDeque::new(),
            retained: BTreeMap::new(),
            cap,
            window,
            dropped: BTreeMap::new(),
            published: 0,
            republished: 0,
        }
    }

    /// Queues a publish; a retained one replaces the topic's last value.
    /// When the queue is full the oldest non-retained publish is dropped
    /// and counted.
    pub fn push(&mut self, p: Pub, connected: bool) {
        if p.retain {
            self.retained.insert(p.topic.clone(), p.clone());
            if !connected {
                // It goes out with the rest of the retained state on CONNACK.
                return;
            }
        }
        self.queue.push_back(p);
        while self.waiting() > self.cap {
            let Some(i) = self.queue.iter().position(|q| !q.retain) else {
                break;
            };
            let old = self.queue.remove(i).expect("an index of the queue");
            *self.dropped.entry(old.kind).or_default() += 1;
        }
    }

    /// Non-retained publishes waiting.
    pub fn waiting(&self) -> usize {
        self.queue.iter().filter(|q| !q.retain).count()
    }

    /// Publishes handed to the client and not yet acknowledged.
    pub fn in_flight(&self) -> usize {
        self.handed.len()
    }

    /// Total drops.
    pub fn dropped_total(&self) -> u64 {
        self.dropped.values().sum()
    }

    /// The next publish to hand to the client, if the window allows; call
    /// [`Outbox::handed`] once the client took it.
    pub fn next(&self) -> Option<&Pub> {
        (self.handed.len() < self.window)
            .then(|| self.queue.front())
            .flatten()
    }

    /// The client took the front of the queue.
    pub fn handed(&mut self) {
        if let Some(publish) = self.queue.pop_front() {
            self.handed.push_back(Handed {
                publish,
                pkid: None,
            });
        }
    }

    /// The client wrote a packet: a publish gets its packet id (QoS 0 ones
    /// are done).
    pub fn on_outgoing(&mut self, out: &Outgoing) {
        let Outgoing::Publish(pkid) = out else {
            return;
        };
        let Some(i) = self.handed.iter().position(|h| h.pkid.is_none()) else {
            return;
        };
        if self.handed[i].publish.qos == QoS::AtMostOnce {
            self.handed.remove(i);
            self.published += 1;
        } else {
            self.handed[i].pkid = Some(*pkid);
        }
    }

    /// The broker acknowledged packet `pkid`.
    pub fn on_puback(&mut self, pkid: u16) {
        if let Some(i) = self.handed.iter().position(|h| h.pkid == Some(pkid)) {
            self.handed.remove(i);
            self.published += 1;
        }
    }

    /// The connection was lost: what the broker did not acknowledge goes
    /// back to the head of the queue (retained topics excepted: they all go
    /// again on the next CONNACK).
    pub fn on_disconnect(&mut self) {
        for h in self.handed.drain(..).rev() {
            if !h.publish.retain {
                self.republished += 1;
                self.queue.push_front(h.publish);
            }
        }
        self.queue.retain(|q| !q.retain);
    }

    /// A new connection: the retained state goes first, then the queue.
    pub fn on_connack(&mut self) {
        self.queue.retain(|q| !q.retain);
        // The bridge's state first: it says "online" before the rest.
        let mut all: Vec<Pub> = self.retained.values().cloned().collect();
        all.sort_by_key(|p| !p.topic.ends_with("bridge/state"));
        for p in all.into_iter().rev() {
            self.queue.push_front(p);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(topic: &str, retain: bool) -> Pub {
        Pub {
            topic: topic.into(),
            payload: b"x".to_vec(),
            qos: QoS::AtLeastOnce,
            retain,
            kind: "depth",
            expiry_s: None,
            correlation: None,
        }
    }

    #[test]
    fn a_full_queue_drops_the_oldest_and_counts_it() {
        let mut o = Outbox::new(2, 10);
        for t in ["a", "b", "c"] {
            o.push(p(t, false), true);
        }
        o.push(p("r", true), true);
        assert_eq!(o.dropped["depth"], 1);
        let topics: Vec<_> = o.queue.iter().map(|q| q.topic.as_str()).collect();
        assert_eq!(topics, ["b", "c", "r"]);
    }

    #[test]
    fn unacknowledged_publishes_go_again_after_a_lost_connection() {
        let mut o = Outbox::new(10, 10);
        o.push(p("s/bridge/state", true), true);
        for t in ["a", "b", "c"] {
            o.push(p(t, false), true);
        }
        for _ in 0..4 {
            assert!(o.next().is_some());
            o.handed();
        }
        for pkid in 1..=4 {
            o.on_outgoing(&Outgoing::Publish(pkid));
        }
        o.on_puback(2); // "a" arrived
        o.on_disconnect();
        o.push(p("d", false), false);
        o.on_connack();
        let topics: Vec<_> = o.queue.iter().map(|q| q.topic.as_str()).collect();
        assert_eq!(topics, ["s/bridge/state", "b", "c", "d"]);
        assert_eq!((o.published, o.republished), (1, 2));
    }
}
