//! The calibration readers that take a user's files: the OpenCV stereo
//! YAML ([`stereolink_calib::files::opencv`]) and the receiver's focal
//! length and baseline from OpenCV or ROS `camera_info` YAML
//! ([`stereolink_calib::files::depth_from_yaml`]). Any text reads to a
//! calibration or an error naming the file, never a panic.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use stereolink_calib::files::depth_from_yaml;
use stereolink_calib::files::opencv::from_opencv_yaml;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = from_opencv_yaml(text, Path::new("fuzz.yml"));
    let _ = depth_from_yaml(text, Path::new("fuzz.yml"), 1.0);
});
