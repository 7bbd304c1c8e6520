//! Recordings: `--record FILE.mcap` on `send`, `receive` and `gateway`
//! (each station under its name: [`Recorder::station`]). An MCAP file
//! (profile `ros2`, schemas `ros2msg`, messages `cdr`: [`crate::rosmsg`])
//! that `ros2 bag play`, Foxglove, Lichtblick and Rerun open as it is, with
//! the topics of `stereo_image_proc` ([`topic`]): each pair's views and
//! cameras, the disparity, the baseline once on `/tf_static`, the depth
//! reports and the link's statistics. Every message's log time and
//! `header.stamp` is its pair's capture time (µs since the epoch, as the
//! sender stamps it); the statistics carry the time they were taken.
//!
//! Uncompressed chunks: the `mcap` crate's zstd and lz4 are C builds, and
//! the views the link carries are small.
//!
//! A recording that fails mid-run (a full disk) is closed as far as it
//! can be and, by [`OnError`], the run goes on without it or stops.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

use serde::Serialize;
use stereolink_codec::DepthReport;
use stereolink_image::{Calibration, DisparityMap, RgbImage};

use crate::rosmsg::{self, MsgType};

/// The topics, as `stereo_image_proc` names them, and the frames.
pub mod topic {
    /// The left view (rectified on the sender, received on the receiver).
    pub const LEFT_IMAGE: &str = "/stereo/left/image_rect_color";
    /// The right view.
    pub const RIGHT_IMAGE: &str = "/stereo/right/image_rect_color";
    /// The left camera.
    pub const LEFT_INFO: &str = "/stereo/left/camera_info";
    /// The right camera (the baseline in P's Tx).
    pub const RIGHT_INFO: &str = "/stereo/right/camera_info";
    /// The disparity map.
    pub const DISPARITY: &str = "/stereo/disparity";
    /// The baseline, once.
    pub const TF_STATIC: &str = "/tf_static";
    /// The depth reports.
    pub const DEPTH_REPORT: &str = "/stereo/depth_report";
    /// The link's statistics.
    pub const DIAGNOSTICS: &str = "/diagnostics";
    /// The left camera's optical frame (the reference).
    pub const LEFT_FRAME: &str = "stereo_left_optical";
    /// The right camera's optical frame.
    pub const RIGHT_FRAME: &str = "stereo_right_optical";
}

/// The calibration of a frame that carries none: the cameras get zeros
/// for K and P, and no baseline goes on `/tf_static`.
pub const UNCALIBRATED: Calibration = Calibration {
    focal_px: None,
    baseline_m: None,
    doffs: 0.0,
    ndisp: 0,
};

/// What a failed write does to the run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum OnError {
    /// The recording is closed and the run goes on without it.
    #[default]
    Continue,
    /// The recording is closed and the run stops with the error.
    Stop,
}

/// QoS that rosbag2 records with each topic: reliable, volatile, or
/// transient local for `/tf_static` (a late subscriber still gets it).
fn qos(transient_local: bool) -> BTreeMap<String, String> {
    let durability = if transient_local { 1 } else { 2 };
    let forever = "\n    sec: 2147483647\n    nsec: 4294967295";
    let yaml = format!(
        "- history: 1\n  depth: 1\n  reliability: 1\n  durability: {durability}\n  \
         deadline:{forever}\n  lifespan:{forever}\n  liveliness: 1\n  \
         liveliness_lease_duration:{forever}\n  avoid_ros_namespace_conventions: false\n"
    );
    BTreeMap::from([("offered_qos_profiles".to_string(), yaml)])
}

/// The schemas' ids.
struct Schemas {
    image: u16,
    info: u16,
    disparity: u16,
    report: u16,
    diagnostics: u16,
}

/// One station's topics (all of them, but for the shared `/tf_static`).
struct Station {
    left: u16,
    right: u16,
    left_info: u16,
    right_info: u16,
    disparity: u16,
    report: u16,
    diagnostics: u16,
    /// Its cameras' frames.
    frames: (String, String),
    /// Whether its baseline went on `/tf_static`.
    tf_written: bool,
}

impl Station {
    /// Adds the topics of the station `name` (`""`: the topics as
    /// [`topic`] names them; else under `/name`, frames `name/...`).
    fn add<W: Write + Seek>(
        w: &mut mcap::Writer<W>,
        s: &Schemas,
        name: &str,
    ) -> mcap::McapResult<Station> {
        let ns = |t: &str| match name {
            "" => t.to_string(),
            _ => format!("/{name}{t}"),
        };
        let mut add = |schema, t: &str| w.add_channel(schema, &ns(t), "cdr", &qos(false));
        let frame = |f: &str| match name {
            "" => f.to_string(),
            _ => format!("{name}/{f}"),
        };
        Ok(Station {
            left: add(s.image, topic::LEFT_IMAGE)?,
            right: add(s.image, topic::RIGHT_IMAGE)?,
            left_info: add(s.info, topic::LEFT_INFO)?,
            right_info: add(s.info, topic::RIGHT_INFO)?,
            disparity: add(s.disparity, topic::DISPARITY)?,
            report: add(s.report, topic::DEPTH_REPORT)?,
            diagnostics: add(s.diagnostics, topic::DIAGNOSTICS)?,
            frames: (frame(topic::LEFT_FRAME), frame(topic::RIGHT_FRAME)),
            tf_written: false,
        })
    }
}

/// An MCAP recording being written, into a file (or, for the tests, any
/// seekable sink).
pub struct Recorder<W: Write + Seek = BufWriter<File>> {
    path: PathBuf,
    /// `None` once closed after a failure.
    writer: Option<mcap::Writer<W>>,
    schemas: Schemas,
    /// `/tf_static`'s channel, shared by the stations.
    tf: u16,
    /// The stations' topics, by name, and the one written to.
    stations: BTreeMap<String, Station>,
    current: String,
    on_error: OnError,
    sequence: u32,
}

impl<W: Write + Seek> std::fmt::Debug for Recorder<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Recorder({})", self.path.display())
    }
}

/// A recording that failed, naming its file.
#[derive(Debug, thiserror::Error)]
#[error("cannot {what} the recording {}: {source}", path.display())]
pub struct RecordError {
    path: PathBuf,
    what: &'static str,
    source: mcap::McapError,
}

impl Recorder {
    /// Creates `path` (replacing a file there) and writes its header,
    /// schemas and channels: a path that cannot be written fails here,
    /// before any work.
    pub fn create(path: &Path, on_error: OnError) -> Result<Recorder, RecordError> {
        let file = File::create(path).map_err(|e| RecordError {
            path: path.to_path_buf(),
            what: "create",
            source: e.into(),
        })?;
        Recorder::on(BufWriter::new(file), path, on_error)
    }
}

impl<W: Write + Seek> Recorder<W> {
    /// A recording written into `sink`, called `path` in its errors.
    pub fn on(sink: W, path: &Path, on_error: OnError) -> Result<Recorder<W>, RecordError> {
        let fail = |what, source| RecordError {
            path: path.to_path_buf(),
            what,
            source,
        };
        let mut w = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("stereolink ", env!("CARGO_PKG_VERSION")))
            .compression(None)
            .create(sink)
            .map_err(|e| fail("create", e))?;
        let added = (|| {
            let mut schema = |t: MsgType| w.add_schema(&t.name, "ros2msg", t.schema.as_bytes());
            let schemas = Schemas {
                image: schema(rosmsg::image_type())?,
                info: schema(rosmsg::camera_info_type())?,
                disparity: schema(rosmsg::disparity_type())?,
                report: schema(rosmsg::depth_report_type())?,
                diagnostics: schema(rosmsg::diagnostics_type())?,
            };
            let tf = schema(rosmsg::tf_type())?;
            let tf = w.add_channel(tf, topic::TF_STATIC, "cdr", &qos(true))?;
            Ok((schemas, tf))
        })();
        let (schemas, tf) = added.map_err(|e| fail("write", e))?;
        w.flush().map_err(|e| fail("write", e))?;
        Ok(Recorder {
            path: path.to_path_buf(),
            writer: Some(w),
            schemas,
            tf,
            stations: BTreeMap::new(),
            current: String::new(),
            on_error,
            sequence: 0,
        })
    }

    /// Records what follows as the station `name`'s: under `/name/...`
    /// (a gateway's stations; `""`, the first: the plain topics). A name
    /// becomes a ROS name's part: each character but letters, digits and
    /// `_` turns into `_`, and one starting with a digit gets a `_` first.
    pub fn station(&mut self, name: &str) -> &mut Recorder<W> {
        let mut name: String = name
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        if name.starts_with(|c: char| c.is_ascii_digit()) {
            name.insert(0, '_');
        }
        self.current = name;
        self
    }

    /// The topics of the station written to, added on its first message
    /// (a station that records nothing leaves no empty topics); `None`
    /// once the recording is closed.
    fn at(&mut self) -> Result<Option<&mut Station>, RecordError> {
        if !self.stations.contains_key(&self.current) {
            let Some(w) = self.writer.as_mut() else {
                return Ok(None);
            };
            match Station::add(w, &self.schemas, &self.current) {
                Ok(s) => self.stations.insert(self.current.clone(), s),
                Err(e) => return self.failed(e).map(|()| None),
            };
        }
        Ok(self.stations.get_mut(&self.current))
    }

    /// Writes one message, stamped `stamp_us`; a failure closes the
    /// recording and, by [`OnError`], is returned or said once on stderr.
    fn write(&mut self, channel_id: u16, stamp_us: u64, data: &[u8]) -> Result<(), RecordError> {
        let Some(w) = self.writer.as_mut() else {
            return Ok(());
        };
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: stamp_us * 1000,
            publish_time: stamp_us * 1000,
        };
        match w.write_to_known_channel(&header, data) {
            Ok(()) => Ok(()),
            Err(e) => self.failed(e),
        }
    }

    /// Closes the recording after `source` and, by [`OnError`], returns it
    /// or says it once on stderr.
    fn failed(&mut self, source: mcap::McapError) -> Result<(), RecordError> {
        // Closing writes what it can of the summary (dropping finishes).
        drop(self.writer.take());
        let e = RecordError {
            path: self.path.clone(),
            what: "write",
            source,
        };
        match self.on_error {
            OnError::Stop => Err(e),
            OnError::Continue => {
                eprintln!("{e}; the recording is closed, the run goes on");
                Ok(())
            }
        }
    }

    /// A pair's views and their cameras (and, the first time the
    /// calibration has a baseline, the baseline on `/tf_static`).
    pub fn views(
        &mut self,
        stamp_us: u64,
        (left, right): (&RgbImage, &RgbImage),
        calib: &Calibration,
    ) -> Result<(), RecordError> {
        let Some(s) = self.at()? else {
            return Ok(());
        };
        let (l, r, li, ri) = (s.left, s.right, s.left_info, s.right_info);
        let (lf, rf) = s.frames.clone();
        let tf = (!s.tf_written).then_some(calib.baseline_m).flatten();
        s.tf_written |= tf.is_some();
        self.write(l, stamp_us, &rosmsg::image(stamp_us, &lf, left))?;
        self.write(r, stamp_us, &rosmsg::image(stamp_us, &rf, right))?;
        let info = |frame, dims, right| rosmsg::camera_info(stamp_us, frame, dims, calib, right);
        self.write(li, stamp_us, &info(&lf, left.dims(), false))?;
        self.write(ri, stamp_us, &info(&rf, right.dims(), true))?;
        if let Some(b) = tf {
            let tf = rosmsg::baseline_tf(stamp_us, &lf, &rf, b);
            self.write(self.tf, stamp_us, &tf)?;
        }
        Ok(())
    }

    /// A pair's disparity map, in ROS's conventions ([`rosmsg::disparity`]).
    pub fn disparity(
        &mut self,
        stamp_us: u64,
        map: &DisparityMap,
        calib: &Calibration,
    ) -> Result<(), RecordError> {
        let Some(s) = self.at()? else {
            return Ok(());
        };
        let msg = rosmsg::disparity(stamp_us, &s.frames.0, map, calib);
        let id = s.disparity;
        self.write(id, stamp_us, &msg)
    }

    /// A pair's depth report.
    pub fn report(&mut self, stamp_us: u64, report: &DepthReport) -> Result<(), RecordError> {
        let Some(s) = self.at()? else {
            return Ok(());
        };
        let msg = rosmsg::depth_report(stamp_us, &s.frames.0, report);
        let id = s.report;
        self.write(id, stamp_us, &msg)
    }

    /// The link's statistics taken at `stamp_us`, as one diagnostic status
    /// `name`: each field of `stats` a key (nested ones as `outer.inner`).
    pub fn link(
        &mut self,
        stamp_us: u64,
        name: &str,
        stats: &impl Serialize,
    ) -> Result<(), RecordError> {
        let Some(id) = self.at()?.map(|s| s.diagnostics) else {
            return Ok(());
        };
        let mut values = Vec::new();
        if let Ok(v) = serde_json::to_value(stats) {
            flatten("", &v, &mut values);
        }
        let msg = rosmsg::diagnostics(stamp_us, name, "stereolink", "link", &values);
        self.write(id, stamp_us, &msg)
    }

    /// Writes the summary and closes the file.
    pub fn finish(mut self) -> Result<(), RecordError> {
        let Some(mut w) = self.writer.take() else {
            return Ok(());
        };
        w.finish().map_err(|source| RecordError {
            path: self.path.clone(),
            what: "finish",
            source,
        })?;
        Ok(())
    }
}

/// A JSON value's leaves as `(key, value)`, objects' keys joined by `.`.
fn flatten(prefix: &str, v: &serde_json::Value, out: &mut Vec<(String, String)>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, v) in m {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten(&key, v, out);
            }
        }
        serde_json::Value::String(s) => out.push((prefix.to_string(), s.clone())),
        other => out.push((prefix.to_string(), other.to_string())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recording_reads_back_with_its_topics_and_stamps() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.mcap");
        let calib = Calibration {
            focal_px: Some(500.0),
            baseline_m: Some(0.12),
            doffs: 0.0,
            ndisp: 16,
        };
        let view = RgbImage::new(8, 4, [1, 2, 3]);
        let map = DisparityMap::new(8, 4, 2.0);
        let report = DepthReport {
            target_distance_m: 1.5,
            target_region: [1, 2, 3, 4],
            levels: Vec::new(),
            histogram: vec![1, 2],
        };
        let mut r = Recorder::create(&path, OnError::Stop).unwrap();
        for stamp in [1_000_000, 2_000_000] {
            r.views(stamp, (&view, &view), &calib).unwrap();
            r.disparity(stamp, &map, &calib).unwrap();
            r.report(stamp, &report).unwrap();
        }
        r.link(
            2_500_000,
            "send",
            &serde_json::json!({"a": 1, "b": {"c": "x"}}),
        )
        .unwrap();
        r.finish().unwrap();

        let bytes = std::fs::read(&path).unwrap();
        let mut seen: BTreeMap<String, Vec<u64>> = BTreeMap::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            assert_eq!(m.channel.message_encoding, "cdr");
            assert_eq!(m.channel.schema.as_ref().unwrap().encoding, "ros2msg");
            seen.entry(m.channel.topic.clone())
                .or_default()
                .push(m.log_time);
        }
        let twice = vec![1_000_000_000, 2_000_000_000];
        for t in [
            topic::LEFT_IMAGE,
            topic::RIGHT_IMAGE,
            topic::LEFT_INFO,
            topic::RIGHT_INFO,
            topic::DISPARITY,
            topic::DEPTH_REPORT,
        ] {
            assert_eq!(seen[t], twice, "{t}");
        }
        assert_eq!(seen[topic::TF_STATIC], vec![1_000_000_000]);
        assert_eq!(seen[topic::DIAGNOSTICS], vec![2_500_000_000]);
    }

    /// A gateway's stations each get their topics under their name, and
    /// their baselines (frames `name/...`) share `/tf_static`.
    #[test]
    fn stations_record_under_their_names() {
        let mut r = Recorder::on(
            std::io::Cursor::new(Vec::new()),
            Path::new("m"),
            OnError::Stop,
        )
        .unwrap();
        let calib = Calibration {
            focal_px: Some(100.0),
            baseline_m: Some(0.1),
            doffs: 0.0,
            ndisp: 8,
        };
        let view = RgbImage::new(4, 2, [0; 3]);
        for name in ["north", "south-2", "north"] {
            r.station(name).views(1, (&view, &view), &calib).unwrap();
        }
        let mut w = r.writer.take().unwrap();
        w.finish().unwrap();
        let bytes = w.into_inner().into_inner();
        let mut seen: BTreeMap<String, usize> = BTreeMap::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            *seen.entry(m.unwrap().channel.topic.clone()).or_default() += 1;
        }
        assert_eq!(seen["/north/stereo/left/image_rect_color"], 2);
        assert_eq!(seen["/south_2/stereo/right/camera_info"], 1);
        assert_eq!(seen[topic::TF_STATIC], 2);
        assert!(!seen.contains_key(topic::LEFT_IMAGE));
    }

    /// A sink that takes `room` bytes, then fails as a full disk does.
    struct Full {
        file: std::io::Cursor<Vec<u8>>,
        room: u64,
    }

    impl Write for Full {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            if self.file.position() + buf.len() as u64 > self.room {
                return Err(std::io::ErrorKind::StorageFull.into());
            }
            self.file.write(buf)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Seek for Full {
        fn seek(&mut self, to: std::io::SeekFrom) -> std::io::Result<u64> {
            self.file.seek(to)
        }
    }

    /// Records 40 pairs of 100x100 views into a sink with room for 200 kB.
    fn fill_a_full_disk(on_error: OnError) -> (Recorder<Full>, Result<(), RecordError>) {
        let sink = Full {
            file: Default::default(),
            room: 200_000,
        };
        let mut r = Recorder::on(sink, Path::new("full.mcap"), on_error).unwrap();
        let view = RgbImage::new(100, 100, [0; 3]);
        let result = (1..=40).try_for_each(|i| r.views(i * 1000, (&view, &view), &UNCALIBRATED));
        (r, result)
    }

    #[test]
    fn a_full_disk_closes_the_recording_and_the_run_goes_on() {
        let (r, result) = fill_a_full_disk(OnError::Continue);
        assert!(result.is_ok());
        assert!(r.writer.is_none(), "the recording is closed");
        // Closed already: finishing it again has nothing to do.
        r.finish().unwrap();
    }

    #[test]
    fn a_full_disk_stops_the_run_with_stop_naming_the_file() {
        let (r, result) = fill_a_full_disk(OnError::Stop);
        let e = result.unwrap_err().to_string();
        assert!(e.starts_with("cannot write the recording full.mcap"), "{e}");
        assert!(r.writer.is_none());
    }

    #[test]
    fn an_unwritable_path_fails_at_once_naming_it() {
        let e = Recorder::create(Path::new("/nonexistent-dir/r.mcap"), OnError::Stop)
            .err()
            .unwrap();
        assert!(e.to_string().contains("/nonexistent-dir/r.mcap"), "{e}");
    }

    #[test]
    fn nested_statistics_flatten_to_dotted_keys() {
        let mut out = Vec::new();
        flatten("", &serde_json::json!({"a": {"b": 2}, "s": "x"}), &mut out);
        assert_eq!(
            out,
            vec![("a.b".into(), "2".into()), ("s".into(), "x".into())]
        );
    }
}
