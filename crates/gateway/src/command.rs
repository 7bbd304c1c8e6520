//! The JSON a client publishes on `PREFIX/<station>/set`, read into the
//! [`Command`] that goes down the station's link as a Control message
//! ([`stereolink_codec::control`]).

use serde_json::Value;
use stereolink_codec::control::{Command, METHODS};

/// Why a `set` payload is not a command: said back to the client in the
/// response's `error`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SetError {
    /// The payload does not parse as JSON.
    #[error("the payload is not JSON: {0}")]
    NotJson(String),
    /// The payload is JSON but not an object.
    #[error("the payload must be a JSON object, e.g. {{\"axis\":\"stop\"}}")]
    NotObject,
    /// Not exactly one command key (the ones given, or `none`).
    #[error("give exactly one of axis, frame, levels, method (got {0})")]
    NotOne(String),
    /// `axis` other than `"stop"`.
    #[error("axis: only \"stop\" is supported")]
    Axis,
    /// `frame` other than `"request"`.
    #[error("frame: only \"request\" is supported")]
    Frame,
    /// `levels` outside 2–16.
    #[error("levels: an integer from 2 to 16")]
    Levels,
    /// `method` not a known segmentation method.
    #[error("method: one of {}", METHODS.join(", "))]
    Method,
    /// A key that is no command.
    #[error("unknown command {0:?}")]
    Unknown(String),
}

/// Reads the command of a `set` payload: exactly one of
/// `{"axis":"stop"}`, `{"frame":"request"}`, `{"levels":N}` or
/// `{"method":"NAME"}`, plus an optional `transaction` field (any JSON
/// value, echoed in the response).
pub fn from_json(v: &Value) -> Result<Command, SetError> {
    let obj = v.as_object().ok_or(SetError::NotObject)?;
    let keys: Vec<&str> = obj
        .keys()
        .map(String::as_str)
        .filter(|k| *k != "transaction")
        .collect();
    let [key] = keys[..] else {
        return Err(SetError::NotOne(if keys.is_empty() {
            "none".into()
        } else {
            keys.join(", ")
        }));
    };
    let val = &obj[key];
    match (key, val) {
        ("axis", Value::String(s)) if s == "stop" => Ok(Command::AxisStop),
        ("axis", _) => Err(SetError::Axis),
        ("frame", Value::String(s)) if s == "request" => Ok(Command::FrameRequest),
        ("frame", _) => Err(SetError::Frame),
        ("levels", v) => match v.as_u64() {
            Some(n @ 2..=16) => Ok(Command::SetLevels(n as u8)),
            _ => Err(SetError::Levels),
        },
        ("method", Value::String(m)) if METHODS.contains(&m.as_str()) => {
            Ok(Command::SetMethod(m.clone()))
        }
        ("method", _) => Err(SetError::Method),
        (other, _) => Err(SetError::Unknown(other.into())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn malformed_set_payloads_are_refused() {
        for bad in [
            json!("stop"),
            json!({}),
            json!({"axis": "go"}),
            json!({"axis": "stop", "levels": 3}),
            json!({"levels": 40}),
            json!({"method": "magic"}),
            json!({"launch": true}),
        ] {
            assert!(from_json(&bad).is_err(), "{bad}");
        }
        assert_eq!(
            from_json(&json!({"axis": "stop", "transaction": 3})),
            Ok(Command::AxisStop)
        );
        assert_eq!(
            from_json(&json!({"method": "otsu"})),
            Ok(Command::SetMethod("otsu".into()))
        );
    }
}
