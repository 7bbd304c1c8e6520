//! Calibration options shared by the commands that turn disparity into
//! distance (`depth`, `match`, `send`): flags, a Middlebury `calib.txt` or a
//! stereo calibration YAML (which also rectifies a raw pair), a TOML file,
//! or the YAML of OpenCV's `stereoRectify` or a ROS `camera_info`.

use std::path::{Path, PathBuf};

use anyhow::Context;
use stereolink_image::Calibration;
use stereolink_pipeline::sensor::Sensor;

/// Where focal length, baseline and `doffs` come from. A file gives all
/// three; `--focal-px` and `--baseline-m` override it.
#[derive(Debug, Clone, clap::Args)]
pub struct CalibArgs {
    /// Focal length in pixels.
    #[arg(long)]
    pub focal_px: Option<f64>,
    /// Baseline in metres.
    #[arg(long)]
    pub baseline_m: Option<f64>,
    /// Disparity offset between the principal points (Middlebury 2014 `doffs`).
    #[arg(long, default_value_t = 0.0)]
    pub doffs: f64,
    /// Read focal length, baseline and doffs from a Middlebury calib.txt of
    /// a rectified pair, or from a stereo calibration YAML of a raw pair
    /// (OpenCV FileStorage with M1, D1, M2, D2, R, T, R1, R2, P1, P2, Q, as
    /// `calibrate` writes; told apart by its %YAML line or M1 matrix): the
    /// pair is then rectified first and depth comes from P1 and P2.
    #[arg(long, value_name = "FILE", group = "calib_file")]
    pub calib: Option<PathBuf>,
    /// Read them from a TOML file with keys focal_px, baseline_m, doffs.
    #[arg(long, value_name = "FILE", group = "calib_file")]
    pub calib_toml: Option<PathBuf>,
    /// Read them from the YAML of OpenCV's stereoRectify (P1, P2) or a ROS
    /// camera_info of the right camera (projection_matrix).
    #[arg(long, value_name = "FILE", group = "calib_file")]
    pub calib_yaml: Option<PathBuf>,
    /// Unit of a YAML's translation (--calib-yaml, or a stereo YAML given to
    /// --calib): m (ROS; OpenCV calibrated in metres), cm or mm (OpenCV
    /// calibrated with the chessboard's square measured in them).
    #[arg(long, default_value = "m", value_parser = ["m", "cm", "mm"])]
    pub calib_units: String,
}

/// Metres per unit of `--calib-units`.
pub fn metres_per_unit(units: &str) -> f64 {
    match units {
        "mm" => 1e-3,
        "cm" => 1e-2,
        _ => 1.0,
    }
}

#[derive(serde::Deserialize)]
struct TomlCalib {
    focal_px: f64,
    baseline_m: f64,
    #[serde(default)]
    doffs: f64,
}

fn read(path: &Path) -> anyhow::Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

impl CalibArgs {
    /// The calibration, with `ndisp` for the disparity range.
    pub fn calibration(&self, ndisp: usize) -> anyhow::Result<Calibration> {
        Ok(self.sensor(ndisp)?.depth)
    }

    /// The calibration and, for a stereo calibration YAML, the maps that
    /// rectify the raw pair first; `ndisp` is the disparity range.
    pub fn sensor(&self, ndisp: usize) -> anyhow::Result<Sensor> {
        let mut c = Calibration {
            focal_px: None,
            baseline_m: None,
            doffs: self.doffs,
            ndisp,
        };
        let mut stereo = None;
        if let Some(p) = &self.calib {
            let sensor = Sensor::from_file(p, metres_per_unit(&self.calib_units), ndisp)?;
            stereo = sensor.stereo;
            c = sensor.depth;
        }
        if let Some(p) = &self.calib_toml {
            let t: TomlCalib = toml::from_str(&read(p)?).with_context(|| {
                format!("{}: expected focal_px, baseline_m, doffs", p.display())
            })?;
            c = Calibration {
                focal_px: Some(t.focal_px),
                baseline_m: Some(t.baseline_m),
                doffs: t.doffs,
                ndisp,
            };
        }
        if let Some(p) = &self.calib_yaml {
            let units = metres_per_unit(&self.calib_units);
            let file = stereolink_calib::files::depth_from_yaml(&read(p)?, p, units)?;
            c = Calibration { ndisp, ..file };
        }
        c.focal_px = self.focal_px.or(c.focal_px);
        c.baseline_m = self.baseline_m.or(c.baseline_m);
        Ok(Sensor { stereo, depth: c })
    }
}
