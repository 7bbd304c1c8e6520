//! The Control message (container type 3): commands for a station and the
//! station's reply, shared by the gateway that sends them and by `send`
//! and `receive` (and the board's build) that act on them.
//!
//! The Control body is versioned (its first byte), so a station that does
//! not know a later version or operation refuses it instead of guessing
//! (`docs/wire-format.md`, "Control body"):
//!
//! ```text
//!  0     1    2               6
//!  +-----+----+---------------+------------ ...
//!  | ver | op | command id    | argument
//!  +-----+----+---------------+------------ ...
//! ```
//!
//! A reply (operation 5) carries the id of the command it answers, whether
//! the station did it, and if not, why.

use crate::container::{self, Body};
use crate::{Limits, Message};

/// The version of the Control body this build writes and reads.
pub const CONTROL_VERSION: u8 = 1;

/// Operation codes of the Control body, version 1.
pub mod op {
    /// Stop the axis now (no argument).
    pub const AXIS_STOP: u8 = 1;
    /// Send a frame now (no argument).
    pub const FRAME_REQUEST: u8 = 2;
    /// Segment with this many levels (argument: one byte, 2..=16).
    pub const SET_LEVELS: u8 = 3;
    /// Segment with this method (argument: its name, UTF-8, at most 32 bytes).
    pub const SET_METHOD: u8 = 4;
    /// The station's reply to a command (argument: 0 done or 1 refused,
    /// then the reason, UTF-8, at most [`super::MAX_REASON`] bytes).
    pub const REPLY: u8 = 5;
}

/// The longest reason a reply carries, in bytes.
pub const MAX_REASON: usize = 120;

/// A command for a station.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Command {
    /// Stop the axis now.
    AxisStop,
    /// Send a frame now.
    FrameRequest,
    /// Segment with this many levels.
    SetLevels(u8),
    /// Segment with this method (`kmeans`, `meanshift`, `pso`, `dpso`, `fodpso`, `otsu`).
    SetMethod(String),
}

/// The segmentation methods a `method` command may name.
pub const METHODS: [&str; 6] = ["kmeans", "meanshift", "pso", "dpso", "fodpso", "otsu"];

/// A station's answer to command `id`: done, or refused with the reason.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Reply {
    /// The id of the command it answers.
    pub id: u32,
    /// Done, or refused with the reason.
    pub result: Result<(), String>,
}

/// A Control body, read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Control {
    /// Command `id`.
    Command {
        /// The command's id (its reply carries it back).
        id: u32,
        /// What it asks.
        command: Command,
    },
    /// A station's reply.
    Reply(Reply),
}

/// Why a message is not a Control body this build takes.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ControlError {
    /// The message failed the container's checks.
    #[error("control message rejected: {0}")]
    Container(String),
    /// The message is another type (a StereoFrame or a DepthReport).
    #[error("a {0} message, not a control message")]
    NotControl(&'static str),
    /// The body ends before its fields do.
    #[error("control body: truncated")]
    Truncated,
    /// A body version this build does not read.
    #[error("control body: version {0} is not supported (this build reads {CONTROL_VERSION})")]
    Version(u8),
    /// An operation this build does not know.
    #[error("control body: unknown operation {0}")]
    Operation(u8),
    /// The argument does not fit the operation.
    #[error("control body: operation {op}: {why}")]
    Argument {
        /// The operation code.
        op: u8,
        /// What is wrong with the argument.
        why: String,
    },
}

impl Command {
    /// A short name for logs and responses.
    pub fn name(&self) -> String {
        match self {
            Command::AxisStop => "axis stop".into(),
            Command::FrameRequest => "frame request".into(),
            Command::SetLevels(n) => format!("levels {n}"),
            Command::SetMethod(m) => format!("method {m}"),
        }
    }

    /// The Control body for command `id`.
    pub fn encode(&self, id: u32) -> Vec<u8> {
        let (code, arg): (u8, &[u8]) = match self {
            Command::AxisStop => (op::AXIS_STOP, &[]),
            Command::FrameRequest => (op::FRAME_REQUEST, &[]),
            Command::SetLevels(n) => (op::SET_LEVELS, std::slice::from_ref(n)),
            Command::SetMethod(m) => (op::SET_METHOD, m.as_bytes()),
        };
        body(code, id, arg)
    }

    /// The whole container message of command `id`.
    pub fn message(&self, id: u32) -> Vec<u8> {
        container::encode(&Message::Control(self.encode(id)), 0, unix_us())
    }
}

impl Control {
    /// The Control body: what [`Control::decode`] reads back.
    pub fn encode(&self) -> Vec<u8> {
        match self {
            Control::Command { id, command } => command.encode(*id),
            Control::Reply(reply) => reply.encode(),
        }
    }
}

impl Reply {
    /// The Control body of this reply; a reason longer than
    /// [`MAX_REASON`] is cut at a character boundary.
    pub fn encode(&self) -> Vec<u8> {
        let mut arg = vec![self.result.is_err() as u8];
        if let Err(why) = &self.result {
            let mut end = why.len().min(MAX_REASON);
            while !why.is_char_boundary(end) {
                end -= 1;
            }
            arg.extend_from_slice(&why.as_bytes()[..end]);
        }
        body(op::REPLY, self.id, &arg)
    }

    /// The whole container message of this reply.
    pub fn message(&self) -> Vec<u8> {
        container::encode(&Message::Control(self.encode()), 0, unix_us())
    }
}

fn body(code: u8, id: u32, arg: &[u8]) -> Vec<u8> {
    let mut b = vec![CONTROL_VERSION, code];
    b.extend_from_slice(&id.to_le_bytes());
    b.extend_from_slice(arg);
    b
}

/// Microseconds since the Unix epoch (the container's time stamp).
pub fn unix_us() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

impl Control {
    /// Reads a Control body.
    pub fn decode(body: &[u8]) -> Result<Control, ControlError> {
        let (&[ver, code], rest) = body
            .split_first_chunk::<2>()
            .ok_or(ControlError::Truncated)?;
        if ver != CONTROL_VERSION {
            return Err(ControlError::Version(ver));
        }
        let (id, arg) = rest
            .split_first_chunk::<4>()
            .ok_or(ControlError::Truncated)?;
        let id = u32::from_le_bytes(*id);
        let bad = |why: &str| ControlError::Argument {
            op: code,
            why: why.into(),
        };
        let command = match (code, arg) {
            (op::AXIS_STOP, []) => Command::AxisStop,
            (op::FRAME_REQUEST, []) => Command::FrameRequest,
            (op::AXIS_STOP | op::FRAME_REQUEST, _) => return Err(bad("takes no argument")),
            (op::SET_LEVELS, &[n]) if (2..=16).contains(&n) => Command::SetLevels(n),
            (op::SET_LEVELS, _) => return Err(bad("levels: one byte from 2 to 16")),
            (op::SET_METHOD, m) if m.len() <= 32 => {
                let m = std::str::from_utf8(m).map_err(|_| bad("method name not UTF-8"))?;
                if !METHODS.contains(&m) {
                    return Err(bad(&format!("unknown method {m:?}")));
                }
                Command::SetMethod(m.into())
            }
            (op::SET_METHOD, _) => return Err(bad("method name longer than 32 bytes")),
            (op::REPLY, [0]) => return Ok(Control::Reply(Reply { id, result: Ok(()) })),
            (op::REPLY, [1, why @ ..]) if why.len() <= MAX_REASON => {
                let why = std::str::from_utf8(why).map_err(|_| bad("reason not UTF-8"))?;
                let result = Err(why.to_string());
                return Ok(Control::Reply(Reply { id, result }));
            }
            (op::REPLY, _) => {
                return Err(bad("status 0 alone, or status 1 and a short reason"));
            }
            (code, _) => return Err(ControlError::Operation(code)),
        };
        Ok(Control::Command { id, command })
    }

    /// Checks a whole container message and reads its Control body.
    pub fn from_message(msg: &[u8]) -> Result<Control, ControlError> {
        match container::parse(msg, &Limits::default()) {
            Ok((_, Body::Control(body))) => Control::decode(body),
            Ok((_, Body::StereoFrame(_))) => Err(ControlError::NotControl("StereoFrame")),
            Ok((_, Body::DepthReport(_))) => Err(ControlError::NotControl("DepthReport")),
            Err(e) => Err(ControlError::Container(e.to_string())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_command_and_reply_round_trips_through_its_control_body() {
        for c in [
            Command::AxisStop,
            Command::FrameRequest,
            Command::SetLevels(5),
            Command::SetMethod("fodpso".into()),
        ] {
            let back = Control::decode(&c.encode(77));
            assert_eq!(back, Ok(Control::Command { id: 77, command: c }));
        }
        for result in [Ok(()), Err("this station has no axis".to_string())] {
            let r = Reply { id: 9, result };
            assert_eq!(Control::decode(&r.encode()), Ok(Control::Reply(r.clone())));
            assert_eq!(Control::from_message(&r.message()), Ok(Control::Reply(r)));
        }
        // Pinned bytes (docs/wire-format.md).
        assert_eq!(Command::AxisStop.encode(0x0102_0304), [1, 1, 4, 3, 2, 1]);
        assert_eq!(Command::SetLevels(4).encode(1), [1, 3, 1, 0, 0, 0, 4]);
        let refused = Reply {
            id: 2,
            result: Err("no".into()),
        };
        assert_eq!(refused.encode(), [1, 5, 2, 0, 0, 0, 1, b'n', b'o']);
    }

    #[test]
    fn a_long_reason_is_cut_at_a_character_boundary() {
        let r = Reply {
            id: 1,
            result: Err("é".repeat(100)),
        };
        let Ok(Control::Reply(back)) = Control::decode(&r.encode()) else {
            panic!("the reply must decode");
        };
        assert_eq!(back.result, Err("é".repeat(MAX_REASON / 2)));
    }

    #[test]
    fn malformed_control_bodies_are_refused_with_the_cause() {
        for (bad, cause) in [
            (&[][..], ControlError::Truncated),
            (&[1], ControlError::Truncated),
            (&[2, 1, 0, 0, 0, 0], ControlError::Version(2)),
            (&[1, 1, 0, 0, 0], ControlError::Truncated),
            (&[1, 9, 0, 0, 0, 0], ControlError::Operation(9)),
        ] {
            assert_eq!(Control::decode(bad), Err(cause), "{bad:?}");
        }
        for bad in [
            &[1, 1, 0, 0, 0, 0, 9][..],
            &[1, 3, 0, 0, 0, 0, 99],
            &[1, 4, 0, 0, 0, 0, b'x'],
            &[1, 4, 0, 0, 0, 0, 0xff],
            &[1, 5, 0, 0, 0, 0],
            &[1, 5, 0, 0, 0, 0, 2],
            &[1, 5, 0, 0, 0, 0, 1, 0xff],
            // Done carries no reason (it would not come back in the reply).
            &[1, 5, 0, 0, 0, 0, 0, b'n', b'o'],
        ] {
            let e = Control::decode(bad).expect_err("must be refused");
            assert!(matches!(e, ControlError::Argument { .. }), "{bad:?}: {e}");
        }
        let report = container::encode(
            &Message::DepthReport(crate::DepthReport {
                target_distance_m: 1.0,
                target_region: [0; 4],
                levels: vec![],
                histogram: vec![],
            }),
            1,
            0,
        );
        assert_eq!(
            Control::from_message(&report),
            Err(ControlError::NotControl("DepthReport"))
        );
        assert!(matches!(
            Control::from_message(b"garbage"),
            Err(ControlError::Container(_))
        ));
    }
}
