//! Where test suites find the shared Middlebury scenes: the folder
//! `STEREOLINK_DATA` names. One rule for every crate's data-backed tests, so
//! that under CI a missing folder fails them instead of letting them pass
//! without running.

use std::path::PathBuf;

/// The shared Middlebury folder (`STEREOLINK_DATA`), or `None` to skip.
/// Under CI (`CI=true`) a missing folder fails instead of passing silently,
/// unless `STEREOLINK_DATA=skip` says the skip is meant (the ARM926 board's
/// emulated run, where the data sweeps would take minutes).
pub fn dir() -> Option<PathBuf> {
    match std::env::var_os("STEREOLINK_DATA") {
        Some(dir) if dir == "skip" => None,
        Some(dir) => Some(PathBuf::from(dir)),
        None if std::env::var("CI").is_ok_and(|v| v == "true") => panic!(
            "STEREOLINK_DATA is unset under CI=true: this data-backed test would pass \
             without running; set it to the shared Middlebury folder, or to `skip`"
        ),
        None => {
            eprintln!("STEREOLINK_DATA is unset: skipping the data-backed test");
            None
        }
    }
}
