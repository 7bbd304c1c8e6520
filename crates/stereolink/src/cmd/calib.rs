//! Calibration options shared by the commands that turn disparity into
//! distance (`depth`, `send`): flags, a Middlebury `calib.txt`, a TOML file,
//! or the YAML of OpenCV's `stereoRectify` or a ROS `camera_info`.

use std::path::{Path, PathBuf};

use anyhow::Context;
use stereolink_image::Calibration;

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
    /// Read focal length, baseline and doffs from a Middlebury calib.txt.
    #[arg(long, value_name = "FILE", group = "calib_file")]
    pub calib: Option<PathBuf>,
    /// Read them from a TOML file with keys focal_px, baseline_m, doffs.
    #[arg(long, value_name = "FILE", group = "calib_file")]
    pub calib_toml: Option<PathBuf>,
    /// Read them from the YAML of OpenCV's stereoRectify (P1, P2) or a ROS
    /// camera_info of the right camera (projection_matrix).
    #[arg(long, value_name = "FILE", group = "calib_file")]
    pub calib_yaml: Option<PathBuf>,
    /// Unit of the YAML's translation: m (ROS; OpenCV calibrated in metres),
    /// cm or mm (OpenCV calibrated with a target measured in them).
    #[arg(long, default_value = "m", value_parser = ["m", "cm", "mm"], requires = "calib_yaml")]
    pub calib_units: String,
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
        let mut c = Calibration {
            focal_px: None,
            baseline_m: None,
            doffs: self.doffs,
            ndisp,
        };
        if let Some(p) = &self.calib {
            let file = Calibration::parse_middlebury(&read(p)?)
                .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
            c = Calibration { ndisp, ..file };
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
            let scale = match self.calib_units.as_str() {
                "mm" => 1e-3,
                "cm" => 1e-2,
                _ => 1.0,
            };
            let file = Calibration::parse_yaml(&read(p)?, scale)
                .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
            c = Calibration { ndisp, ..file };
        }
        c.focal_px = self.focal_px.or(c.focal_px);
        c.baseline_m = self.baseline_m.or(c.baseline_m);
        Ok(c)
    }
}
