//! The sensor end of the pipelines: a calibration file read once into the
//! rectification maps (when the pair is raw) and the depth calibration of
//! the pair the matcher sees, shared by `rectify`, `match`, `send` and
//! `demo --scene`.
//!
//! A file given to `--calib` is told by its content: a stereo calibration
//! in OpenCV's YAML (a `%YAML` directive or an `M1` matrix) means a raw
//! pair, rectified first, with depth from the rectified `P1`/`P2`
//! ([`stereolink_calib::Rectification::depth_geometry`]); anything else is a
//! Middlebury `calib.txt` of an already rectified pair.

use std::path::Path;

use anyhow::Context;
use stereolink_calib::{files, StereoCalibration, StereoRectifier};
use stereolink_image::{Calibration, RgbImage};

/// What a calibration file gives a pipeline. The rectification maps are
/// built only by [`Sensor::rectifier`] (about 0.1 s for 640x480), so a
/// command that needs depth alone does not pay for them.
pub struct Sensor {
    /// The stereo calibration of a raw pair, or `None` for a pair that is
    /// already rectified.
    pub stereo: Option<StereoCalibration>,
    /// Focal length, baseline (metres) and `doffs` of the pair as matched.
    pub depth: Calibration,
}

/// `text` of file `path` as a stereo calibration YAML, if it is one (by
/// content).
fn parse_stereo_yaml(text: &str, path: &Path) -> anyhow::Result<Option<StereoCalibration>> {
    if !files::is_opencv_yaml(text) {
        return Ok(None);
    }
    let calib = files::from_opencv_yaml(text, path).map_err(|e| {
        anyhow::anyhow!("{e} (for depth alone from P1 and P2, give the file to --calib-yaml)")
    })?;
    Ok(Some(calib))
}

/// Reads `path` as a stereo calibration YAML, failing if it is something else.
pub fn read_stereo_yaml(path: &Path) -> anyhow::Result<StereoCalibration> {
    parse_stereo_yaml(&files::read_text(path)?, path)?.ok_or_else(|| {
        anyhow::anyhow!(
            "{}: not a stereo calibration YAML (expected OpenCV FileStorage with M1, D1, \
             M2, D2, R, T, R1, R2, P1, P2 and Q)",
            path.display()
        )
    })
}

/// The depth calibration of a rectified pair: `f = P1[0][0]`, `b =
/// −P2[0][3]/P2[0][0]` times `metres_per_unit` (T is in the square size's
/// units), `doffs = P2[0][2] − P1[0][2]`; `ndisp` is the search range.
pub fn depth_of_rectified(
    calib: &StereoCalibration,
    metres_per_unit: f64,
    ndisp: usize,
    path: &Path,
) -> anyhow::Result<Calibration> {
    let rect = &calib.rectification;
    let (f, b, doffs) = rect.depth_geometry();
    anyhow::ensure!(
        rect.p2[(1, 3)].abs() <= 1e-9 * rect.p2[(0, 3)].abs().max(1.0),
        "{}: P2 is of a vertical rig (P2[1][3] ≠ 0); only horizontal rigs are supported",
        path.display()
    );
    anyhow::ensure!(
        f.is_finite() && f > 0.0 && b.is_finite() && b > 0.0,
        "{}: P1/P2 give focal length {f} px and baseline {b}: both must be positive \
         (a negative baseline means the left and right cameras are swapped)",
        path.display()
    );
    Ok(Calibration {
        focal_px: Some(f),
        baseline_m: Some(b * metres_per_unit),
        doffs,
        ndisp,
    })
}

impl Sensor {
    /// The sensor of a `--calib FILE`: a stereo calibration YAML's maps and
    /// rectified depth, or a Middlebury calib.txt's depth; `ndisp` is the
    /// disparity range.
    pub fn from_file(path: &Path, metres_per_unit: f64, ndisp: usize) -> anyhow::Result<Self> {
        let text = files::read_text(path)?;
        if let Some(stereo) = parse_stereo_yaml(&text, path)? {
            return Self::from_stereo(&stereo, metres_per_unit, ndisp, path);
        }
        let file = Calibration::parse_middlebury(&text)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Ok(Sensor {
            stereo: None,
            depth: Calibration { ndisp, ..file },
        })
    }

    /// The sensor of a stereo calibration: the calibration and its
    /// rectified depth calibration.
    pub fn from_stereo(
        calib: &StereoCalibration,
        metres_per_unit: f64,
        ndisp: usize,
        path: &Path,
    ) -> anyhow::Result<Self> {
        Ok(Sensor {
            stereo: Some(*calib),
            depth: depth_of_rectified(calib, metres_per_unit, ndisp, path)?,
        })
    }

    /// The maps that rectify a raw pair, built now, or `None` for a pair
    /// that is already rectified.
    pub fn rectifier(&self) -> anyhow::Result<Option<StereoRectifier>> {
        self.stereo
            .as_ref()
            .map(|c| StereoRectifier::new(c).context("cannot build the rectification maps"))
            .transpose()
    }

    /// Rectifies one raw pair (or passes a rectified one through); `what`
    /// names the pair in errors.
    pub fn rectify(
        &self,
        left: RgbImage,
        right: RgbImage,
        what: &str,
    ) -> anyhow::Result<(RgbImage, RgbImage)> {
        match self.rectifier()? {
            Some(r) => r
                .rectify(&left, &right)
                .with_context(|| format!("cannot rectify {what}")),
            None => Ok((left, right)),
        }
    }

    /// A warning when some depths cannot be matched: with `doffs > 0` a
    /// point beyond `f·b/doffs` has a negative disparity, below the
    /// matchers' range, which starts at 0.
    pub fn range_warning(&self) -> Option<String> {
        let c = &self.depth;
        let (f, b) = (c.focal_px?, c.baseline_m?);
        (self.stereo.is_some() && c.doffs > 0.0).then(|| {
            format!(
                "the rectified principal points differ by doffs = {:.2} px: points farther \
                 than {:.2} m have negative disparity and are not matched (rectify with \
                 CALIB_ZERO_DISPARITY to avoid this)",
                c.doffs,
                f * b / c.doffs
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;
    use stereolink_calib::synthetic::{rig_around, RectifiedGeometry};
    use stereolink_calib::{Camera, Distortion};

    fn calibration(doffs: f64, baseline: f64) -> StereoCalibration {
        let cam = Camera {
            fx: 500.0,
            fy: 500.0,
            cx: 80.0,
            cy: 60.0,
            distortion: Distortion::default(),
            width: 160,
            height: 120,
        };
        let geometry = RectifiedGeometry {
            focal: 480.0,
            cx: 80.0,
            cy: 60.0,
            doffs,
            baseline,
            size: (160, 120),
        };
        rig_around(
            cam,
            cam,
            Matrix3::identity(),
            Matrix3::identity(),
            &geometry,
        )
    }

    #[test]
    fn a_file_is_told_by_its_content() {
        let dir = tempfile::tempdir().unwrap();
        let yml = dir.path().join("stereo.yml");
        files::write_opencv(&yml, &calibration(0.0, 60.0)).unwrap();
        let s = Sensor::from_file(&yml, 1e-3, 32).unwrap();
        assert!(s.rectifier().unwrap().is_some());
        assert_eq!(s.depth.focal_px, Some(480.0));
        assert!((s.depth.baseline_m.unwrap() - 0.06).abs() < 1e-12);
        assert_eq!((s.depth.doffs, s.depth.ndisp), (0.0, 32));
        assert!(s.range_warning().is_none());
        let txt = dir.path().join("calib.txt");
        std::fs::write(
            &txt,
            "cam0=[700 0 10; 0 700 5; 0 0 1]\nbaseline=50\ndoffs=2\nndisp=40\n",
        )
        .unwrap();
        let s = Sensor::from_file(&txt, 1.0, 16).unwrap();
        assert!(s.rectifier().unwrap().is_none());
        assert_eq!(
            (s.depth.focal_px, s.depth.doffs, s.depth.ndisp),
            (Some(700.0), 2.0, 16)
        );
        assert!(read_stereo_yaml(&txt)
            .unwrap_err()
            .to_string()
            .contains("not a stereo calibration"));
    }

    #[test]
    fn doffs_and_swapped_cameras_are_explained() {
        let p = Path::new("stereo.yml");
        let s = Sensor::from_stereo(&calibration(12.0, 0.06), 1.0, 32, p).unwrap();
        // Beyond f·b/doffs = 480·0.06/12 = 2.4 m the disparity is negative.
        assert!(s.range_warning().unwrap().contains("2.40 m"));
        let err = Sensor::from_stereo(&calibration(0.0, -0.06), 1.0, 32, p)
            .err()
            .unwrap();
        assert!(err.to_string().contains("swapped"), "{err}");
    }
}
