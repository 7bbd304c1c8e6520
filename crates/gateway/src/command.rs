//! The JSON a client publishes on `PREFIX/<station>/set`, read into the
//! [`Command`] that goes down the station's link as a Control message
//! ([`stereolink_codec::control`]).

use serde_json::Value;
use stereolink_codec::control::{Command, METHODS};

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
