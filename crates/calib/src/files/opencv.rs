//! OpenCV `FileStorage` YAML: the file `cv::FileStorage` writes and reads,
//! holding a stereo calibration under the names of OpenCV's samples and of
//! `stereoCalibrate`/`stereoRectify`: `M1, D1, M2, D2, R, T, E, F, R1, R2,
//! P1, P2, Q`, plus `image_width` and `image_height`.
//!
//! The reader is not a general YAML parser (OpenCV's `%YAML:1.0` directive
//! is refused by YAML 1.2 parsers anyway): it reads the top-level `key:
//! value` pairs and the `!!opencv-matrix` mappings (`rows`, `cols`, `dt`,
//! `data: [ … ]` over one or more lines) and ignores everything else, so it
//! takes files cv2 wrote, in any key order, with comments, `dt: d` or `f`,
//! and `D` as `1xN` or `Nx1`. Two files concatenated (OpenCV's
//! `stereo_calib` sample writes `intrinsics.yml` and `extrinsics.yml`) read
//! as one.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{DMatrix, Matrix3, Matrix3x4, Matrix4, Vector3};

use crate::{Camera, Distortion, Error, Rectification, Result, StereoCalibration, StereoRig};

/// Files larger than this are refused unread: a calibration is a few kB.
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// Image sides above this are refused (the maps allocate per pixel).
pub const MAX_SIDE: usize = 1 << 14;

/// OpenCV wraps a matrix's data list before a line would pass this column.
const WRAP_COLUMN: usize = 73;

/// True if `text` looks like an OpenCV stereo calibration: a `%YAML`
/// directive or a top-level `M1` matrix.
pub fn is_opencv_yaml(text: &str) -> bool {
    text.trim_start().starts_with("%YAML")
        || text.lines().any(|l| {
            l.strip_prefix("M1")
                .is_some_and(|r| r.trim_start().starts_with(':'))
        })
}

/// Formats a number as OpenCV does for `dt: d`: integral values as `1.`,
/// others in the shortest form that reads back exactly, with a two-digit
/// signed exponent where one is needed (`5.1928e+02`).
fn number(v: f64) -> String {
    if v.is_nan() {
        return ".Nan".into();
    }
    if v.is_infinite() {
        return if v > 0.0 {
            ".Inf".into()
        } else {
            "-.Inf".into()
        };
    }
    if v == v.trunc() && v.abs() < 1e15 {
        return format!("{}.", v as i64);
    }
    let plain = format!("{v}");
    if (1e-4..1e6).contains(&v.abs()) {
        return plain;
    }
    let sci = format!("{v:e}");
    let (mantissa, exp) = sci.split_once('e').expect("`{:e}` has an exponent");
    let exp: i32 = exp.parse().expect("`{:e}` has an integer exponent");
    let sign = if exp < 0 { '-' } else { '+' };
    format!("{mantissa}e{sign}{:02}", exp.abs())
}

/// Appends `key` as an `!!opencv-matrix` of doubles, row-major, its data
/// wrapped over lines as `cv::FileStorage` wraps it.
fn write_matrix(out: &mut String, key: &str, rows: usize, cols: usize, data: &[f64]) {
    debug_assert_eq!(rows * cols, data.len());
    let _ = write!(
        out,
        "{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n"
    );
    let mut line = String::from("   data: [");
    for (i, v) in data.iter().enumerate() {
        let v = number(*v);
        if i > 0 {
            line.push(',');
        }
        if i > 0 && line.len() + 1 + v.len() > WRAP_COLUMN {
            out.push_str(&line);
            out.push('\n');
            line.clear();
            line.push_str("      ");
        }
        line.push(' ');
        line.push_str(&v);
    }
    out.push_str(&line);
    out.push_str(" ]\n");
}

/// Row-major values of a nalgebra matrix (which stores columns).
fn row_major<R: nalgebra::Dim, C: nalgebra::Dim, S>(m: &nalgebra::Matrix<f64, R, C, S>) -> Vec<f64>
where
    S: nalgebra::RawStorage<f64, R, C>,
{
    (0..m.nrows())
        .flat_map(|r| (0..m.ncols()).map(move |c| m[(r, c)]))
        .collect()
}

/// The cross-product matrix `[t]×`.
fn skew(t: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0)
}

/// The essential matrix `E = [T]×·R`, as `stereoCalibrate` returns it.
fn essential(rig: &StereoRig) -> Matrix3<f64> {
    skew(&rig.translation) * rig.rotation
}

/// The fundamental matrix `F = M2⁻ᵀ·E·M1⁻¹`, scaled so that `F[2][2] = 1`
/// as OpenCV returns it (unscaled when that entry is 0).
fn fundamental(rig: &StereoRig) -> Matrix3<f64> {
    let inv = |c: &Camera| c.matrix().try_inverse().unwrap_or_else(Matrix3::zeros);
    let f = inv(&rig.right).transpose() * essential(rig) * inv(&rig.left);
    if f[(2, 2)].abs() > f64::EPSILON * f.abs().max() {
        f / f[(2, 2)]
    } else {
        f
    }
}

/// The calibration as an OpenCV `FileStorage` YAML document.
pub fn to_opencv_yaml(calib: &StereoCalibration) -> String {
    let (rig, rect) = (&calib.rig, &calib.rectification);
    let mut out = String::from("%YAML:1.0\n---\n");
    let _ = writeln!(out, "image_width: {}", rig.left.width);
    let _ = writeln!(out, "image_height: {}", rig.left.height);
    if rect.size != (rig.left.width, rig.left.height) {
        let _ = writeln!(out, "rectified_width: {}", rect.size.0);
        let _ = writeln!(out, "rectified_height: {}", rect.size.1);
    }
    let cams = [("M1", "D1", &rig.left), ("M2", "D2", &rig.right)];
    for (m, d, cam) in cams {
        write_matrix(&mut out, m, 3, 3, &row_major(&cam.matrix()));
        write_matrix(&mut out, d, 1, 5, &cam.distortion.to_array());
    }
    write_matrix(&mut out, "R", 3, 3, &row_major(&rig.rotation));
    write_matrix(&mut out, "T", 3, 1, rig.translation.as_slice());
    write_matrix(&mut out, "E", 3, 3, &row_major(&essential(rig)));
    write_matrix(&mut out, "F", 3, 3, &row_major(&fundamental(rig)));
    write_matrix(&mut out, "R1", 3, 3, &row_major(&rect.r1));
    write_matrix(&mut out, "R2", 3, 3, &row_major(&rect.r2));
    write_matrix(&mut out, "P1", 3, 4, &row_major(&rect.p1));
    write_matrix(&mut out, "P2", 3, 4, &row_major(&rect.p2));
    write_matrix(&mut out, "Q", 4, 4, &row_major(&rect.q));
    out
}

/// Writes [`to_opencv_yaml`] to `path`.
pub fn write_opencv(path: &Path, calib: &StereoCalibration) -> Result<()> {
    std::fs::write(path, to_opencv_yaml(calib)).map_err(|source| Error::Io {
        path: path.to_owned(),
        source,
    })
}

/// Reads a calibration text file of at most [`MAX_FILE_BYTES`] (larger
/// files and files that are not UTF-8 are refused unread).
pub fn read_text(path: &Path) -> Result<String> {
    use std::io::Read;
    let io = |source| Error::Io {
        path: path.to_owned(),
        source,
    };
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .map_err(io)?
        .take(MAX_FILE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(io)?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(Error::File {
            path: path.to_owned(),
            problem: format!(
                "larger than {} kB: not a calibration file",
                MAX_FILE_BYTES >> 10
            ),
        });
    }
    String::from_utf8(bytes).map_err(|_| Error::File {
        path: path.to_owned(),
        problem: "not UTF-8 text: not a YAML calibration file".into(),
    })
}

/// Reads a stereo calibration from an OpenCV YAML file.
pub fn read_opencv(path: &Path) -> Result<StereoCalibration> {
    from_opencv_yaml(&read_text(path)?, path)
}

/// A top-level entry: its value on the key's line, and the `key: value`
/// lines indented under it (a list continued over lines joined into one).
#[derive(Debug, Default)]
struct Entry<'a> {
    value: &'a str,
    children: Vec<(&'a str, String)>,
}

/// The top-level entries of a FileStorage YAML text, first occurrence of
/// each key kept.
fn entries(text: &str) -> Vec<(&str, Entry<'_>)> {
    let mut out: Vec<(&str, Entry<'_>)> = Vec::new();
    let mut open_list = false;
    for raw in text.lines() {
        let line = raw.split('#').next().unwrap_or("").trim_end();
        let content = line.trim_start();
        if content.is_empty() || content.starts_with('%') || content == "---" || content == "..." {
            continue;
        }
        let indented = content.len() < line.len();
        if open_list {
            if let Some((_, entry)) = out.last_mut() {
                if let Some((_, list)) = entry.children.last_mut() {
                    list.push(' ');
                    list.push_str(content);
                    open_list = !content.contains(']');
                    continue;
                }
            }
            open_list = false;
        }
        let Some((key, value)) = content.split_once(':') else {
            continue;
        };
        let (key, value) = (key.trim(), value.trim());
        if indented {
            if let Some((_, entry)) = out.last_mut() {
                open_list = value.starts_with('[') && !value.contains(']');
                entry.children.push((key, value.to_string()));
            }
        } else if out.iter().all(|(k, _)| *k != key) {
            out.push((
                key,
                Entry {
                    value,
                    children: Vec::new(),
                },
            ));
        } else {
            // A repeated key: its children must not join the first one's.
            out.push(("", Entry::default()));
        }
    }
    out
}

/// A matrix read from a file.
struct Mat {
    rows: usize,
    cols: usize,
    data: Vec<f64>,
}

/// A parsed document with the file's name for messages.
pub(super) struct Doc<'a> {
    entries: Vec<(&'a str, Entry<'a>)>,
    path: &'a Path,
}

impl<'a> Doc<'a> {
    /// The top-level entries of `text`; `path` names the file in errors.
    pub(super) fn parse(text: &'a str, path: &'a Path) -> Self {
        Doc {
            entries: entries(text),
            path,
        }
    }

    /// Whether the file has the entry `key`.
    pub(super) fn has(&self, key: &str) -> bool {
        self.entry(key).is_some()
    }

    /// An error about this file.
    pub(super) fn error(&self, problem: String) -> Error {
        Error::File {
            path: self.path.to_owned(),
            problem,
        }
    }

    fn entry(&self, key: &str) -> Option<&Entry<'_>> {
        self.entries
            .iter()
            .find(|(k, _)| !k.is_empty() && *k == key)
            .map(|(_, e)| e)
    }

    /// A positive integer of at most [`MAX_SIDE`] under `key`, if present.
    fn side(&self, key: &str) -> Result<Option<usize>> {
        let Some(e) = self.entry(key) else {
            return Ok(None);
        };
        match e.value.parse::<usize>() {
            Ok(n) if (1..=MAX_SIDE).contains(&n) => Ok(Some(n)),
            _ => Err(self.error(format!(
                "{key} is {:?}, not a size from 1 to {MAX_SIDE}",
                e.value
            ))),
        }
    }

    /// The matrix `key` (described as `what` in messages).
    fn matrix(&self, key: &str, what: &str) -> Result<Mat> {
        let named = format!("{key} ({what})");
        let e = self
            .entry(key)
            .ok_or_else(|| self.error(format!("no {named}")))?;
        let child = |name: &str| {
            e.children
                .iter()
                .find(|(k, _)| *k == name)
                .map(|(_, v)| v.as_str())
                .ok_or_else(|| self.error(format!("{named} has no {name}: not an !!opencv-matrix")))
        };
        let dim = |name: &str| -> Result<usize> {
            let v = child(name)?;
            v.parse::<usize>()
                .ok()
                .filter(|n| (1..=64).contains(n))
                .ok_or_else(|| self.error(format!("{named}: {name} {v:?} is not from 1 to 64")))
        };
        let (rows, cols) = (dim("rows")?, dim("cols")?);
        let list = child("data")?;
        let inner = list
            .strip_prefix('[')
            .and_then(|l| l.strip_suffix(']'))
            .ok_or_else(|| self.error(format!("{named}: the data is not one [ … ] list")))?;
        let data = inner
            .split(',')
            .map(str::trim)
            .take(rows * cols + 1)
            .map(|v| match v.parse::<f64>() {
                Ok(x) if x.is_finite() => Ok(x),
                _ => Err(self.error(format!("{named}: {v:?} is not a finite number"))),
            })
            .collect::<Result<Vec<_>>>()?;
        if data.len() != rows * cols {
            return Err(self.error(format!(
                "{named}: {} values for a {rows}x{cols} matrix",
                if data.len() > rows * cols {
                    "more".to_string()
                } else {
                    data.len().to_string()
                }
            )));
        }
        Ok(Mat { rows, cols, data })
    }

    /// The matrix `key`, which must be `rows`×`cols`.
    pub(super) fn fixed(
        &self,
        key: &str,
        what: &str,
        rows: usize,
        cols: usize,
    ) -> Result<DMatrix<f64>> {
        let m = self.matrix(key, what)?;
        if (m.rows, m.cols) != (rows, cols) {
            return Err(self.error(format!(
                "{key} ({what}) is {}x{}, not {rows}x{cols}",
                m.rows, m.cols
            )));
        }
        Ok(DMatrix::from_row_slice(rows, cols, &m.data))
    }

    /// A vector `key` of 3 values, as `3x1` or `1x3`.
    fn vector3(&self, key: &str, what: &str) -> Result<Vector3<f64>> {
        let m = self.matrix(key, what)?;
        if m.rows.min(m.cols) != 1 || m.data.len() != 3 {
            return Err(self.error(format!("{key} ({what}) is {}x{}, not 3x1", m.rows, m.cols)));
        }
        Ok(Vector3::from_column_slice(&m.data))
    }

    /// A camera from its matrix `m` and distortion `d`.
    fn camera(&self, m: &str, d: &str, side: &str, size: (usize, usize)) -> Result<Camera> {
        let k = self.fixed(m, &format!("the {side} camera matrix"), 3, 3)?;
        let what = format!("the {side} camera's distortion");
        let dist = self.matrix(d, &what)?;
        let shape_ok = dist.rows.min(dist.cols) == 1;
        let model = Distortion::from_slice(&dist.data)
            .filter(|_| shape_ok)
            .ok_or_else(|| {
                self.error(format!(
                    "{d} ({what}) is {}x{}: expected 1x5 (k1, k2, p1, p2, k3) or 1x4",
                    dist.rows, dist.cols
                ))
            })?;
        if dist.data.iter().skip(5).any(|&v| v != 0.0) {
            return Err(self.error(format!(
                "{d} ({what}) has {} coefficients: the rational or thin-prism terms \
                 beyond k3 are not supported (calibrate with the 5-coefficient model)",
                dist.data.len()
            )));
        }
        let zeros = [(0, 1), (1, 0), (2, 0), (2, 1)];
        if !(k[(0, 0)] > 0.0 && k[(1, 1)] > 0.0)
            || zeros.iter().any(|&i| k[i] != 0.0)
            || k[(2, 2)] != 1.0
        {
            return Err(self.error(format!(
                "{m} (the {side} camera matrix) is not [fx 0 cx; 0 fy cy; 0 0 1] with positive focal lengths"
            )));
        }
        Ok(Camera {
            fx: k[(0, 0)],
            fy: k[(1, 1)],
            cx: k[(0, 2)],
            cy: k[(1, 2)],
            distortion: model,
            width: size.0,
            height: size.1,
        })
    }
}

/// Parses an OpenCV YAML stereo calibration; `path` names the file in
/// errors ("stereo.yml: no D2 (the right camera's distortion)").
pub fn from_opencv_yaml(text: &str, path: &Path) -> Result<StereoCalibration> {
    let doc = Doc::parse(text, path);
    let width = doc.side("image_width")?;
    let height = doc.side("image_height")?;
    let (Some(width), Some(height)) = (width, height) else {
        return Err(doc.error(
            "no image_width and image_height (the calibrated image size; OpenCV's \
             stereo_calib sample does not write them: add `image_width: W` and \
             `image_height: H` lines)"
                .into(),
        ));
    };
    let size = (width, height);
    let rect_size = (
        doc.side("rectified_width")?.unwrap_or(width),
        doc.side("rectified_height")?.unwrap_or(height),
    );
    let left = doc.camera("M1", "D1", "left", size)?;
    let right = doc.camera("M2", "D2", "right", size)?;
    let r = doc.fixed("R", "the rotation from the left camera to the right", 3, 3)?;
    let t = doc.vector3("T", "the translation from the left camera to the right")?;
    let r1 = doc.fixed("R1", "the left rectifying rotation", 3, 3)?;
    let r2 = doc.fixed("R2", "the right rectifying rotation", 3, 3)?;
    let p1 = doc.fixed("P1", "the left rectified projection", 3, 4)?;
    let p2 = doc.fixed("P2", "the right rectified projection", 3, 4)?;
    let q = doc.fixed("Q", "the disparity-to-depth matrix", 4, 4)?;
    let m3 = |m: DMatrix<f64>| Matrix3::from_iterator(m.iter().copied());
    let m34 = |m: DMatrix<f64>| Matrix3x4::from_iterator(m.iter().copied());
    Ok(StereoCalibration {
        rig: StereoRig {
            left,
            right,
            rotation: m3(r),
            translation: t,
        },
        rectification: Rectification {
            r1: m3(r1),
            r2: m3(r2),
            p1: m34(p1),
            p2: m34(p2),
            q: Matrix4::from_iterator(q.iter().copied()),
            size: rect_size,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::files::tests::calibration;
    use proptest::prelude::*;

    fn parse(text: &str) -> Result<StereoCalibration> {
        from_opencv_yaml(text, Path::new("stereo.yml"))
    }

    fn message(text: &str) -> String {
        parse(text).unwrap_err().to_string()
    }

    #[test]
    fn numbers_read_back_exactly_in_opencv_style() {
        assert_eq!(number(1.0), "1.");
        assert_eq!(number(-0.0), "0.");
        assert_eq!(number(519.28), "519.28");
        assert_eq!(number(1.0e-5), "1e-05");
        assert_eq!(number(-4.2e7 + 0.5), "-4.19999995e+07");
        for v in [0.1, -0.3, 1.0 / 3.0, 6.02e23, -1.5e-300, 123456.789] {
            assert_eq!(number(v).parse::<f64>().unwrap(), v, "{}", number(v));
        }
    }

    #[test]
    fn data_lists_wrap_as_opencv_wraps_them() {
        let mut out = String::new();
        let data: Vec<f64> = (0..16)
            .map(|i| -0.123456789012345 * (i + 1) as f64)
            .collect();
        write_matrix(&mut out, "Q", 4, 4, &data);
        let lines: Vec<_> = out.lines().collect();
        assert!(lines.len() > 5, "{out}");
        assert!(lines.iter().all(|l| l.len() <= WRAP_COLUMN), "{out}");
        assert!(
            lines[5..].iter().all(|l| l.starts_with("       -")),
            "{out}"
        );
        assert!(out.ends_with(" ]\n"));
    }

    #[test]
    fn our_file_reads_back_equal() {
        let c = calibration();
        let text = to_opencv_yaml(&c);
        assert!(text.starts_with("%YAML:1.0\n---\nimage_width: 640\n"));
        assert!(is_opencv_yaml(&text));
        assert_eq!(parse(&text).unwrap(), c);
    }

    #[test]
    fn the_depth_reader_takes_our_file() {
        // `--calib-yaml stereo.yml` (depth only, no rectification).
        let c = calibration();
        let path = Path::new("stereo.yml");
        let depth = super::super::depth_from_yaml(&to_opencv_yaml(&c), path, 1.0).unwrap();
        let (f, b, doffs) = c.rectification.depth_geometry();
        assert_eq!(depth.focal_px, Some(f));
        assert!((depth.baseline_m.unwrap() - b).abs() < 1e-12);
        assert_eq!(depth.doffs, doffs);
        assert_ne!(doffs, 0.0, "the test rig has a doffs to carry");
    }

    #[test]
    fn essential_and_fundamental_satisfy_the_epipolar_constraint() {
        let rig = calibration().rig;
        let x_l = Vector3::new(0.3, -0.2, 2.5);
        let x_r = rig.rotation * x_l + rig.translation;
        let (n_l, n_r) = (x_l / x_l.z, x_r / x_r.z);
        assert!((n_r.transpose() * essential(&rig) * n_l)[0].abs() < 1e-12);
        let (p_l, p_r) = (rig.left.matrix() * n_l, rig.right.matrix() * n_r);
        let e = (p_r.transpose() * fundamental(&rig) * p_l)[0];
        assert!(e.abs() < 1e-9, "{e}");
        assert!((fundamental(&rig)[(2, 2)] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn a_rectified_size_that_differs_is_kept() {
        let mut c = calibration();
        c.rectification.size = (800, 600);
        let text = to_opencv_yaml(&c);
        assert!(text.contains("rectified_width: 800"));
        assert_eq!(parse(&text).unwrap(), c);
    }

    #[test]
    fn missing_and_malformed_matrices_are_named() {
        let text = to_opencv_yaml(&calibration());
        let without = |key: &str| {
            let start = text.find(&format!("\n{key}: ")).unwrap() + 1;
            let end = start + text[start..].find("]\n").unwrap() + 2;
            format!("{}{}", &text[..start], &text[end..])
        };
        assert_eq!(
            message(&without("D2")),
            "stereo.yml: no D2 (the right camera's distortion)"
        );
        assert!(message(&without("P1")).contains("no P1 (the left rectified projection)"));
        assert!(message(&without("Q")).contains("no Q"));
        assert!(message(&text.replace("image_height: 480\n", "")).contains("image_height"));
        assert!(message(&text.replace("image_width: 640", "image_width: -3")).contains("-3"));
        let p2 = text.find("P2:").unwrap();
        let bad = format!(
            "{}{}",
            &text[..p2],
            text[p2..].replacen("cols: 4", "cols: 3", 1)
        );
        assert!(message(&bad).contains("P2 (the right rectified projection): more values"));
        let bad = format!("{}{}", &text[..p2], text[p2..].replacen("0.,", "zero,", 1));
        assert!(message(&bad).contains("\"zero\" is not a finite number"));
        let bad = format!("{}{}", &text[..p2], text[p2..].replacen("0.,", ".Inf,", 1));
        assert!(message(&bad).contains("\".Inf\""));
        let joined = text.replacen("]\n", "\n", 1);
        assert!(message(&joined).contains("M1 (the left camera matrix): \"1. D1:"));
        let open = text.trim_end().trim_end_matches(']');
        assert!(message(open)
            .contains("Q (the disparity-to-depth matrix): the data is not one [ … ] list"));
        let bad = text.replacen("   rows: 1\n   cols: 5", "   rows: 5\n   cols: 1", 1);
        assert!(parse(&bad).is_ok(), "a 5x1 D is fine");
        let bad = text.replacen("   rows: 1\n   cols: 5", "   rows: 2\n   cols: 3", 1);
        assert!(parse(&bad).is_err());
        assert!(message("a: 1").contains("no image_width"));
    }

    #[test]
    fn eight_coefficients_read_when_the_extra_ones_are_zero() {
        let text = to_opencv_yaml(&calibration());
        let d1 = text.find("D1:").unwrap();
        let end = d1 + text[d1..].find(" ]").unwrap();
        let eight = format!(
            "{}{}, 0., 0., 0.{}",
            &text[..d1],
            text[d1..end].replacen("cols: 5", "cols: 8", 1),
            &text[end..]
        );
        assert_eq!(parse(&eight).unwrap(), calibration());
        let rational = eight.replacen("0., 0., 0. ]", "0.1, 0., 0. ]", 1);
        assert!(message(&rational).contains("beyond k3"));
    }

    #[test]
    fn concatenated_intrinsics_and_extrinsics_read_as_one() {
        let text = to_opencv_yaml(&calibration());
        let r = text.find("\nR: ").unwrap() + 1;
        let both = format!("{}%YAML:1.0\n---\n# extrinsics\n{}", &text[..r], &text[r..]);
        assert_eq!(parse(&both).unwrap(), calibration());
    }

    /// Written by cv2.FileStorage (OpenCV 5.0): `python3
    /// crates/calib/tests/data/make_opencv_fixture.py` regenerates it. Its
    /// D1 is 1x5 doubles, D2 a 5x1 `dt: f`, the keys out of our order, with
    /// comments, and without the E and F we write.
    const CV2_FIXTURE: &str = include_str!("../../tests/data/opencv_stereo.yml");

    #[test]
    fn reads_the_file_cv2_wrote() {
        let c = parse(CV2_FIXTURE).unwrap();
        // The generator's exact inputs.
        assert_eq!((c.rig.left.fx, c.rig.left.cy), (670.5, 238.25));
        assert_eq!(c.rig.left.distortion.k1, -0.3);
        assert!((c.rig.right.distortion.k1 + 0.28).abs() < 1e-8);
        assert_eq!(c.rig.translation, Vector3::new(-0.06, 0.0005, 0.001));
        assert_eq!((c.rig.left.width, c.rig.left.height), (640, 480));
        // stereoRectify's outputs: orthonormal rotations, a horizontal rig.
        let r1 = c.rectification.r1;
        assert!((r1 * r1.transpose() - Matrix3::identity()).norm() < 1e-9);
        let (p1, p2) = (c.rectification.p1, c.rectification.p2);
        assert_eq!(p1[(0, 0)], p2[(0, 0)]);
        assert!(p2[(0, 3)] < 0.0 && p2[(1, 3)] == 0.0);
        assert!((-p2[(0, 3)] / p2[(0, 0)] - c.rig.baseline()).abs() < 1e-9);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..2000)) {
            let _ = parse(&String::from_utf8_lossy(&bytes));
        }

        #[test]
        fn mutated_files_never_panic(
            edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..20),
            cut in any::<prop::sample::Index>(),
        ) {
            let mut bytes = to_opencv_yaml(&calibration()).into_bytes();
            for (at, b) in edits {
                let i = at.index(bytes.len());
                bytes[i] = b;
            }
            bytes.truncate(cut.index(bytes.len() + 1));
            let _ = parse(&String::from_utf8_lossy(&bytes));
        }

        #[test]
        fn huge_dimensions_are_refused_unallocated(rows in 65usize..usize::MAX) {
            let text = CV2_FIXTURE.replacen("rows: 3", &format!("rows: {rows}"), 1);
            prop_assert!(parse(&text).is_err());
        }
    }
}
