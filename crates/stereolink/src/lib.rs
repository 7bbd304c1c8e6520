//! The stereolink system's command line. The pipelines that join the crates
//! (segment → encode → link → decode → match → display → axis) are the
//! `stereolink-pipeline` crate, the MQTT gateway the `stereolink-gateway`
//! crate and the paper's experiments the `stereolink-report` crate.
//!
//! The binary is thin: every command is a function in [`cmd`] that a test can
//! call, and every pipeline lives in a library.

pub mod cmd;
pub mod config;
