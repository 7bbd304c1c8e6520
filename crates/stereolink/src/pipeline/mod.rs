//! Off the board, the MQTT gateway for many stations (`gateway`,
//! `stereolink gateway`); the pipelines themselves are the
//! `stereolink-pipeline` crate.

// The MQTT gateway never goes into the board's build (no rumqttc on ARM).
#[cfg(all(feature = "gateway", not(target_arch = "arm")))]
pub mod gateway;
