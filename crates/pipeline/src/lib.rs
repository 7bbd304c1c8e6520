//! The pipelines that join the stereolink crates, as library functions the
//! CLI and the tests call: the sender ([`sender`]: segment, encode, match,
//! depth report; [`coding`]: segmented or lossy views, fitted to a budget) and the board's receiver ([`receiver`]: decode, rebuild,
//! match, render, drive the axis), the whole system in one process
//! ([`demo`]), the pairs arriving in a camera folder ([`watch`]), and the
//! calibration of a raw pair ([`sensor`]: rectification maps and depth from
//! `P1`/`P2`), the sender's link in its own thread ([`uplink`]: reports
//! ahead of frames) and its pair loop on that link ([`live`]: files, a
//! camera folder or two cameras), and the segments of the plane matcher ([`planes`]) and
//! its plane table over the radio ([`planetable`]), and recordings in MCAP
//! with ROS 2 messages ([`record`], [`rosmsg`], [`cdr`]). The sender and the board
//! obey the commands that come over the link (the Control message,
//! `stereolink_codec::control`) and reply to them.
//!
//! Why a crate of its own: the binary only parses arguments and prints, and
//! the receiver here is on the ARM926 board's build path, so this crate
//! builds for the board (no gateway, no MQTT: that is `stereolink-gateway`).
//!
//! It depends on the crates it joins: image, segment, stereo, codec, link
//! (with `std`), display, robot, calib and capture; nothing above it.

pub mod board_links;
pub mod cdr;
pub mod coding;
pub mod demo;
pub mod key_request;
pub mod live;
pub mod live_bench;
pub mod pairs;
pub mod planes;
pub mod planetable;
pub mod rates;
pub mod receiver;
pub mod record;
pub mod rosmsg;
pub mod sender;
pub mod sensor;
pub mod stream;
pub mod uplink;
pub mod watch;
