//! Commands for a station: the JSON a client publishes on
//! `PREFIX/<station>/set`, and the Control message (container type 3) that
//! carries it over the station's link.
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

use serde_json::Value;

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
}

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

impl Command {
    /// Reads the command of a `set` payload: exactly one of
    /// `{"axis":"stop"}`, `{"frame":"request"}`, `{"levels":N}` or
    /// `{"method":"NAME"}`, plus an optional `transaction` field (any JSON
    /// value, echoed in the response).
    pub fn from_json(v: &Value) -> Result<Command, String> {
        let obj = v
            .as_object()
            .ok_or("the payload must be a JSON object, e.g. {\"axis\":\"stop\"}")?;
        let keys: Vec<&str> = obj
            .keys()
            .map(String::as_str)
            .filter(|k| *k != "transaction")
            .collect();
        let [key] = keys[..] else {
            return Err(format!(
                "give exactly one of axis, frame, levels, method (got {})",
                if keys.is_empty() {
                    "none".into()
                } else {
                    keys.join(", ")
                }
            ));
        };
        let val = &obj[key];
        match (key, val) {
            ("axis", Value::String(s)) if s == "stop" => Ok(Command::AxisStop),
            ("axis", _) => Err("axis: only \"stop\" is supported".into()),
            ("frame", Value::String(s)) if s == "request" => Ok(Command::FrameRequest),
            ("frame", _) => Err("frame: only \"request\" is supported".into()),
            ("levels", v) => match v.as_u64() {
                Some(n @ 2..=16) => Ok(Command::SetLevels(n as u8)),
                _ => Err("levels: an integer from 2 to 16".into()),
            },
            ("method", Value::String(m)) if METHODS.contains(&m.as_str()) => {
                Ok(Command::SetMethod(m.clone()))
            }
            ("method", _) => Err(format!("method: one of {}", METHODS.join(", "))),
            (other, _) => Err(format!("unknown command {other:?}")),
        }
    }

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
        let mut b = vec![CONTROL_VERSION, 0];
        b.extend_from_slice(&id.to_le_bytes());
        b[1] = match self {
            Command::AxisStop => op::AXIS_STOP,
            Command::FrameRequest => op::FRAME_REQUEST,
            Command::SetLevels(n) => {
                b.push(*n);
                op::SET_LEVELS
            }
            Command::SetMethod(m) => {
                b.extend_from_slice(m.as_bytes());
                op::SET_METHOD
            }
        };
        b
    }

    /// Reads a Control body: the command and its id.
    pub fn decode(body: &[u8]) -> Result<(Command, u32), String> {
        let (&[ver, code], rest) = body
            .split_first_chunk::<2>()
            .ok_or("control body: truncated")?;
        if ver != CONTROL_VERSION {
            return Err(format!("control body: version {ver} is not supported"));
        }
        let (id, arg) = rest
            .split_first_chunk::<4>()
            .ok_or("control body: truncated")?;
        let id = u32::from_le_bytes(*id);
        let cmd = match (code, arg) {
            (op::AXIS_STOP, []) => Command::AxisStop,
            (op::FRAME_REQUEST, []) => Command::FrameRequest,
            (op::SET_LEVELS, &[n]) if (2..=16).contains(&n) => Command::SetLevels(n),
            (op::SET_METHOD, m) if m.len() <= 32 => {
                let m = std::str::from_utf8(m).map_err(|_| "control body: method not UTF-8")?;
                if !METHODS.contains(&m) {
                    return Err(format!("control body: unknown method {m:?}"));
                }
                Command::SetMethod(m.into())
            }
            (code, _) => return Err(format!("control body: bad operation {code}")),
        };
        Ok((cmd, id))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn every_command_round_trips_through_its_control_body() {
        for c in [
            Command::AxisStop,
            Command::FrameRequest,
            Command::SetLevels(5),
            Command::SetMethod("fodpso".into()),
        ] {
            assert_eq!(Command::decode(&c.encode(77)), Ok((c, 77)));
        }
        // Pinned bytes (docs/wire-format.md).
        assert_eq!(Command::AxisStop.encode(0x0102_0304), [1, 1, 4, 3, 2, 1]);
        assert_eq!(Command::SetLevels(4).encode(1), [1, 3, 1, 0, 0, 0, 4]);
    }

    #[test]
    fn malformed_control_bodies_and_payloads_are_refused() {
        for bad in [
            &[][..],
            &[1],
            &[2, 1, 0, 0, 0, 0],
            &[1, 1, 0, 0, 0],
            &[1, 1, 0, 0, 0, 0, 9],
            &[1, 3, 0, 0, 0, 0, 99],
            &[1, 9, 0, 0, 0, 0],
            &[1, 4, 0, 0, 0, 0, b'x'],
        ] {
            assert!(Command::decode(bad).is_err(), "{bad:?}");
        }
        for bad in [
            json!("stop"),
            json!({}),
            json!({"axis": "go"}),
            json!({"axis": "stop", "levels": 3}),
            json!({"levels": 40}),
            json!({"method": "magic"}),
            json!({"launch": true}),
        ] {
            assert!(Command::from_json(&bad).is_err(), "{bad}");
        }
        assert_eq!(
            Command::from_json(&json!({"axis": "stop", "transaction": 3})),
            Ok(Command::AxisStop)
        );
    }
}
