//! `stereolink radio --link SPEC`: what the local XBee radio reports, as
//! XCTU's basic read shows it: firmware family and version, hardware
//! version, API mode, largest payload, addresses, channel and PAN. The
//! values are the radio's answers to AT queries (`stereolink_link::radio`),
//! in hexadecimal as XCTU writes them.

use anyhow::Context;
use serde::Serialize;
use stereolink_link::spec;

/// Arguments of `stereolink radio`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Link: serial:/dev/ttyUSB0?baud=115200&api=2 (radio=zigbee etc. names the family).
    #[arg(long)]
    pub link: String,
}

#[derive(Serialize)]
struct Report {
    link: String,
    /// "802.15.4", "zigbee", "digimesh", or null when VR/HV is not known.
    firmware: Option<String>,
    firmware_version: String,
    hardware_version: String,
    api_mode: u8,
    max_payload: Option<u16>,
    my: Option<String>,
    sh: Option<String>,
    sl: Option<String>,
    channel: Option<String>,
    pan_id: Option<String>,
    operating_pan: Option<String>,
}

fn or_none(v: &Option<String>) -> &str {
    v.as_deref().unwrap_or("(not supported)")
}

/// Asks the radio and prints its answers.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let link = super::link_spec(&args.link)?;
    let info =
        spec::ask_radio(&link).with_context(|| format!("cannot ask the radio on {}", args.link))?;
    let report = Report {
        link: args.link.clone(),
        firmware: info.firmware.map(|f| f.to_string()),
        firmware_version: format!("{:X}", info.firmware_version),
        hardware_version: format!("{:X}", info.hardware_version),
        api_mode: info.api_mode,
        max_payload: info.max_payload,
        my: info.my.map(|v| format!("{v:X}")),
        sh: info.serial.map(|v| format!("{:X}", v >> 32)),
        sl: info.serial.map(|v| format!("{:X}", v & 0xFFFF_FFFF)),
        channel: info.channel.map(|v| format!("{v:X}")),
        pan_id: info.pan_id.map(|v| format!("{v:X}")),
        operating_pan: info.operating_pan.map(|v| format!("{v:X}")),
    };
    out.emit(&report, || {
        let r = &report;
        format!(
            "radio on {}\n  firmware     {} (VR {})\n  hardware     HV {}\n  API mode     AP {}\n  \
             max payload  NP {}\n  address      MY {}\n  serial       SH {}  SL {}\n  channel      CH {}\n  \
             PAN          ID {}  OP {}\n",
            r.link,
            r.firmware.as_deref().unwrap_or("unknown (name it with radio=)"),
            r.firmware_version,
            r.hardware_version,
            r.api_mode,
            r.max_payload.map_or("(not supported)".into(), |n| format!("{n} bytes")),
            or_none(&r.my),
            or_none(&r.sh),
            or_none(&r.sl),
            or_none(&r.channel),
            or_none(&r.pan_id),
            or_none(&r.operating_pan),
        )
    })
}
