//! The ROS 2 message types a recording holds ([`crate::record`]): their
//! `ros2msg` schema text, as rosbag2 stores it (the type's own definition,
//! then each type it uses after a line of 80 `=` and `MSG: pkg/Type`), and
//! their CDR encoding ([`crate::cdr`]) from stereolink's own types.
//!
//! The types: `sensor_msgs/msg/Image` and `CameraInfo`,
//! `stereo_msgs/msg/DisparityImage`, `tf2_msgs/msg/TFMessage`,
//! `diagnostic_msgs/msg/DiagnosticArray`, and the depth report as
//! `stereolink_msgs/msg/DepthReport` (a type of our own, whose definition
//! travels in the file like the others').

use stereolink_codec::DepthReport;
use stereolink_image::{Calibration, DisparityMap, RgbImage};

use crate::cdr::Cdr;

/// A message type: its name and its full `ros2msg` schema text.
pub struct MsgType {
    /// As rosbag2 names it, `pkg/msg/Type`.
    pub name: String,
    /// Its definition and the definitions it depends on.
    pub schema: String,
}

const TIME: (&str, &str) = ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n");
const HEADER: (&str, &str) = (
    "std_msgs/Header",
    "builtin_interfaces/Time stamp\nstring frame_id\n",
);
const IMAGE: (&str, &str) = (
    "sensor_msgs/Image",
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n\
     uint8 is_bigendian\nuint32 step\nuint8[] data\n",
);
const ROI: (&str, &str) = (
    "sensor_msgs/RegionOfInterest",
    "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n",
);
const CAMERA_INFO: (&str, &str) = (
    "sensor_msgs/CameraInfo",
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n\
     float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n\
     uint32 binning_y\nsensor_msgs/RegionOfInterest roi\n",
);
const DISPARITY: (&str, &str) = (
    "stereo_msgs/DisparityImage",
    "std_msgs/Header header\nsensor_msgs/Image image\nfloat32 f\nfloat32 t\n\
     sensor_msgs/RegionOfInterest valid_window\nfloat32 min_disparity\n\
     float32 max_disparity\nfloat32 delta_d\n",
);
const TF: (&str, &str) = (
    "tf2_msgs/TFMessage",
    "geometry_msgs/TransformStamped[] transforms\n",
);
const TRANSFORM_STAMPED: (&str, &str) = (
    "geometry_msgs/TransformStamped",
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n",
);
const TRANSFORM: (&str, &str) = (
    "geometry_msgs/Transform",
    "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
);
const VECTOR3: (&str, &str) = ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n");
const QUATERNION: (&str, &str) = (
    "geometry_msgs/Quaternion",
    "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
);
const DIAGNOSTIC_ARRAY: (&str, &str) = (
    "diagnostic_msgs/DiagnosticArray",
    "std_msgs/Header header\ndiagnostic_msgs/DiagnosticStatus[] status\n",
);
const DIAGNOSTIC_STATUS: (&str, &str) = (
    "diagnostic_msgs/DiagnosticStatus",
    "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\n\
     string message\nstring hardware_id\ndiagnostic_msgs/KeyValue[] values\n",
);
const KEY_VALUE: (&str, &str) = ("diagnostic_msgs/KeyValue", "string key\nstring value\n");
const DEPTH_REPORT: (&str, &str) = (
    "stereolink_msgs/DepthReport",
    "# The sender's depth estimate (stereolink's DepthReport): the target's\n\
     # distance (NaN: unknown) and region, the depth levels nearest first, and\n\
     # the disparity histogram (1 px bins from 0; empty when cut to one packet).\n\
     std_msgs/Header header\nfloat32 target_distance_m\n\
     # x, y, width, height in pixels\nuint16[4] target_region\n\
     stereolink_msgs/DepthLevel[] levels\nuint32[] histogram\n",
);
const DEPTH_LEVEL: (&str, &str) = (
    "stereolink_msgs/DepthLevel",
    "# A peak of the disparity histogram.\nfloat32 disparity\nfloat32 distance_m\n\
     # share of the valid pixels, 0..1\nfloat32 share\n",
);

/// The type named `pkg/Type` as `pkg/msg/Type`, with its schema.
fn msg_type(own: (&str, &str), deps: &[(&str, &str)]) -> MsgType {
    let mut schema = own.1.to_string();
    for (name, text) in deps {
        schema.push_str(&"=".repeat(80));
        schema.push_str(&format!("\nMSG: {name}\n{text}"));
    }
    let (pkg, ty) = own.0.split_once('/').unwrap_or(("", own.0));
    let name = format!("{pkg}/msg/{ty}");
    MsgType { name, schema }
}

/// `sensor_msgs/msg/Image`.
pub fn image_type() -> MsgType {
    msg_type(IMAGE, &[HEADER, TIME])
}

/// `sensor_msgs/msg/CameraInfo`.
pub fn camera_info_type() -> MsgType {
    msg_type(CAMERA_INFO, &[HEADER, TIME, ROI])
}

/// `stereo_msgs/msg/DisparityImage`.
pub fn disparity_type() -> MsgType {
    msg_type(DISPARITY, &[HEADER, TIME, IMAGE, ROI])
}

/// `tf2_msgs/msg/TFMessage`.
pub fn tf_type() -> MsgType {
    msg_type(
        TF,
        &[
            TRANSFORM_STAMPED,
            HEADER,
            TIME,
            TRANSFORM,
            VECTOR3,
            QUATERNION,
        ],
    )
}

/// `diagnostic_msgs/msg/DiagnosticArray`.
pub fn diagnostics_type() -> MsgType {
    msg_type(
        DIAGNOSTIC_ARRAY,
        &[HEADER, TIME, DIAGNOSTIC_STATUS, KEY_VALUE],
    )
}

/// `stereolink_msgs/msg/DepthReport`.
pub fn depth_report_type() -> MsgType {
    msg_type(DEPTH_REPORT, &[HEADER, TIME, DEPTH_LEVEL])
}

/// The fields of a `sensor_msgs/msg/Image` after its header.
fn image_body(c: &mut Cdr, (width, height): (usize, usize), encoding: &str, pixel: usize) {
    c.u32(height as u32);
    c.u32(width as u32);
    c.string(encoding);
    c.u8(0);
    c.u32((width * pixel) as u32);
}

/// A view as an `rgb8` `sensor_msgs/msg/Image`.
pub fn image(stamp_us: u64, frame_id: &str, view: &RgbImage) -> Vec<u8> {
    let data = view.as_slice().as_flattened();
    let mut c = Cdr::new(64 + data.len());
    c.header(stamp_us, frame_id);
    image_body(&mut c, view.dims(), "rgb8", 3);
    c.bytes(data);
    c.into_bytes()
}

/// A rectified camera's `sensor_msgs/msg/CameraInfo`: K from the focal
/// length with the principal point at the image's centre (the calibration
/// keeps no other), R the identity, P = K with `Tx = -f·baseline` for the
/// right camera (`right`), no distortion (`plumb_bob`, zeros).
pub fn camera_info(
    stamp_us: u64,
    frame_id: &str,
    (width, height): (usize, usize),
    calib: &Calibration,
    right: bool,
) -> Vec<u8> {
    let f = calib.focal_px.unwrap_or(0.0);
    let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let tx = if right {
        -f * calib.baseline_m.unwrap_or(0.0)
    } else {
        0.0
    };
    let mut c = Cdr::new(512);
    c.header(stamp_us, frame_id);
    c.u32(height as u32);
    c.u32(width as u32);
    c.string("plumb_bob");
    c.len(5);
    c.f64s(&[0.0; 5]);
    c.f64s(&[f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0]);
    c.f64s(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]);
    c.f64s(&[f, 0.0, cx, tx, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0]);
    c.u32(0);
    c.u32(0);
    roi(&mut c, (0, 0), (0, 0));
    c.into_bytes()
}

/// A `sensor_msgs/msg/RegionOfInterest` (all zeros: the full image).
fn roi(c: &mut Cdr, (x, y): (usize, usize), (width, height): (usize, usize)) {
    c.u32(x as u32);
    c.u32(y as u32);
    c.u32(height as u32);
    c.u32(width as u32);
    c.bool(false);
}

/// A disparity map as a `stereo_msgs/msg/DisparityImage`, in ROS's
/// conventions: `32FC1`, `doffs` added to every valid value (so that
/// Z = f·t/d), `min_disparity` = `doffs` (stereolink's disparities are
/// ≥ 0), `max_disparity` the largest valid value, invalid pixels at
/// `min_disparity - 1`, `delta_d` 1 for a map of whole pixels (0 when it
/// holds sub-pixel values).
pub fn disparity(
    stamp_us: u64,
    frame_id: &str,
    map: &DisparityMap,
    calib: &Calibration,
) -> Vec<u8> {
    let doffs = calib.doffs as f32;
    let min = doffs;
    let valid = || {
        map.as_slice()
            .iter()
            .filter(|d| d.is_finite() && **d >= 0.0)
    };
    let max = valid().fold(min, |m, &d| m.max(d + doffs));
    let whole = valid().all(|d| d.fract() == 0.0);
    let (width, height) = map.dims();
    let mut c = Cdr::new(128 + map.len() * 4);
    c.header(stamp_us, frame_id);
    c.header(stamp_us, frame_id);
    image_body(&mut c, (width, height), "32FC1", 4);
    c.bytes_with(map.len() * 4, |buf| {
        for &d in map.as_slice() {
            let v = if d.is_finite() && d >= 0.0 {
                d + doffs
            } else {
                min - 1.0
            };
            buf.extend_from_slice(&v.to_le_bytes());
        }
    });
    c.f32(calib.focal_px.unwrap_or(0.0) as f32);
    c.f32(calib.baseline_m.unwrap_or(0.0) as f32);
    roi(&mut c, (0, 0), (width, height));
    c.f32(min);
    c.f32(max);
    c.f32(if whole { 1.0 } else { 0.0 });
    c.into_bytes()
}

/// The right camera's pose in the left's, as a `tf2_msgs/msg/TFMessage`:
/// `baseline_m` along the left optical frame's x (rectified: no rotation).
pub fn baseline_tf(stamp_us: u64, parent: &str, child: &str, baseline_m: f64) -> Vec<u8> {
    let mut c = Cdr::new(128);
    c.len(1);
    c.header(stamp_us, parent);
    c.string(child);
    c.f64s(&[baseline_m, 0.0, 0.0]);
    c.f64s(&[0.0, 0.0, 0.0, 1.0]);
    c.into_bytes()
}

/// One `diagnostic_msgs/msg/DiagnosticArray` of one status `name`
/// (level OK) with `values`.
pub fn diagnostics(
    stamp_us: u64,
    name: &str,
    hardware_id: &str,
    message: &str,
    values: &[(String, String)],
) -> Vec<u8> {
    let mut c = Cdr::new(256);
    c.header(stamp_us, "");
    c.len(1);
    c.u8(0);
    c.string(name);
    c.string(message);
    c.string(hardware_id);
    c.len(values.len());
    for (k, v) in values {
        c.string(k);
        c.string(v);
    }
    c.into_bytes()
}

/// A depth report as a `stereolink_msgs/msg/DepthReport`.
pub fn depth_report(stamp_us: u64, frame_id: &str, r: &DepthReport) -> Vec<u8> {
    let mut c = Cdr::new(64 + r.levels.len() * 12 + r.histogram.len() * 4);
    c.header(stamp_us, frame_id);
    c.f32(r.target_distance_m);
    for v in r.target_region {
        c.u16(v);
    }
    c.len(r.levels.len());
    for l in &r.levels {
        c.f32(l.disparity);
        c.f32(l.distance_m);
        c.f32(l.share);
    }
    c.len(r.histogram.len());
    for &h in &r.histogram {
        c.u32(h);
    }
    c.into_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schemas_list_each_dependency_once_after_a_separator() {
        let t = disparity_type();
        assert_eq!(t.name, "stereo_msgs/msg/DisparityImage");
        assert!(t.schema.starts_with("std_msgs/Header header\n"));
        for dep in [
            "std_msgs/Header",
            "builtin_interfaces/Time",
            "sensor_msgs/Image",
        ] {
            let line = format!("{}\nMSG: {dep}\n", "=".repeat(80));
            assert_eq!(t.schema.matches(&line).count(), 1, "{dep}");
        }
    }

    /// Folding `doffs` in and marking the invalid pixels below the least
    /// disparity: bytes after the two headers and the image's fields.
    #[test]
    fn disparity_folds_doffs_and_marks_invalid_below_min() {
        let map = DisparityMap::from_vec(2, 1, vec![3.0, f32::INFINITY]).unwrap();
        let calib = Calibration {
            focal_px: Some(100.0),
            baseline_m: Some(0.1),
            doffs: 2.0,
            ndisp: 16,
        };
        let bytes = disparity(0, "l", &map, &calib);
        let tail = &bytes[bytes.len() - (4 + 4 + 17 + 3 + 12)..];
        let f32_at = |i: usize| f32::from_le_bytes(tail[i..i + 4].try_into().unwrap());
        let data: Vec<f32> = (0..2)
            .map(|i| {
                let at = bytes.len() - 48 + 4 * i;
                f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap())
            })
            .collect();
        assert_eq!(data, vec![5.0, 1.0]);
        assert_eq!((f32_at(0), f32_at(4)), (100.0, 0.1));
        // valid_window 0, 0, height 1, width 2, false; padding to 4.
        assert_eq!(
            &tail[8..25],
            &[0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 0]
        );
        assert_eq!((f32_at(28), f32_at(32), f32_at(36)), (2.0, 5.0, 1.0));
    }
}
