//! When the board asks the sender for a key frame: a predicted frame whose
//! reference it lacks (a restart of either end, a frame lost or refused)
//! cannot be shown, and every frame after it would be refused too until a
//! key frame comes. So the board asks at once, with a frame request (a
//! Control command the sender already obeys with a key frame), and asks
//! again every [`ASK_AGAIN_AFTER`] while none has come: a request or its
//! answer may be lost, or the sender may still be busy with the frame in
//! flight. The sender's answer (a Control reply to the request's id) is
//! taken here, not shown as a stray message.

use std::time::{Duration, Instant};

use stereolink_codec::control::{Command, Reply};

/// How long the board waits for a key frame before it asks again.
pub const ASK_AGAIN_AFTER: Duration = Duration::from_secs(1);

/// The board's frame requests: the last one and when it went.
#[derive(Debug, Default)]
pub struct KeyRequests {
    /// The id of the last request and when it was made.
    last: Option<(u32, Instant)>,
    /// Requests made.
    made: u32,
}

impl KeyRequests {
    /// The frame request to send now, if a key frame is wanted and none
    /// was asked for within [`ASK_AGAIN_AFTER`]: its whole message.
    pub fn due(&mut self, wanted: bool, now: Instant) -> Option<Vec<u8>> {
        if !wanted {
            self.last = None;
            return None;
        }
        if self
            .last
            .is_some_and(|(_, at)| now.duration_since(at) < ASK_AGAIN_AFTER)
        {
            return None;
        }
        self.made += 1;
        // Ids of their own (top bit set), so a reply is never taken for
        // another station's.
        let id = 0x8000_0000 | self.made;
        self.last = Some((id, now));
        Some(Command::FrameRequest.message(id))
    }

    /// Whether `reply` answers one of these requests.
    pub fn answers(&self, reply: &Reply) -> bool {
        reply.id & 0x8000_0000 != 0 && reply.id & 0x7fff_ffff <= self.made
    }

    /// Requests made so far.
    pub fn made(&self) -> u32 {
        self.made
    }
}

#[cfg(test)]
mod tests {
    use stereolink_codec::control::Control;
    use stereolink_codec::{container, Limits, Message};

    use super::*;

    fn command(msg: &[u8]) -> (u32, Command) {
        let (_, m) = container::decode(msg, &Limits::default()).unwrap();
        let Message::Control(body) = m else {
            panic!("not a control message")
        };
        match Control::decode(&body).unwrap() {
            Control::Command { id, command } => (id, command),
            other => panic!("not a command: {other:?}"),
        }
    }

    #[test]
    fn a_key_frame_is_asked_for_at_once_and_again_each_second_until_it_comes() {
        let t0 = Instant::now();
        let mut k = KeyRequests::default();
        assert_eq!(k.due(false, t0), None);
        let (id, c) = command(&k.due(true, t0).unwrap());
        assert_eq!(c, Command::FrameRequest);
        assert_eq!(k.due(true, t0 + Duration::from_millis(900)), None);
        let (again, _) = command(&k.due(true, t0 + ASK_AGAIN_AFTER).unwrap());
        assert_ne!(id, again);
        assert_eq!(k.made(), 2);
        // The key frame came: nothing more; a later gap asks at once.
        assert_eq!(k.due(false, t0 + Duration::from_secs(2)), None);
        assert!(k.due(true, t0 + Duration::from_millis(2100)).is_some());
    }

    #[test]
    fn only_answers_to_its_own_requests_are_taken() {
        let mut k = KeyRequests::default();
        let (id, _) = command(&k.due(true, Instant::now()).unwrap());
        let reply = |id| Reply { id, result: Ok(()) };
        assert!(k.answers(&reply(id)));
        assert!(!k.answers(&reply(id + 1)));
        assert!(!k.answers(&reply(id & 0x7fff_ffff)));
    }
}
