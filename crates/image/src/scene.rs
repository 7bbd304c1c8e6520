//! Stereo scenes and the loaders for the layouts users have on disk.
//!
//! [`Scene::load`] recognises, in order:
//!
//! 1. the **stereolink layout** (the shared data and `stereolink synth` output):
//!    `left.png`, `right.png`, optional `gt_left.{pfm,png}`, `gt_right.{pfm,png}`,
//!    `mask_{nonocc,all,disc}.png`, `calib.txt`; the PNG ground-truth scale and
//!    `ndisp` come from `../manifest.json` when present;
//! 2. **Middlebury 2014** (`im0.png`, `im1.png`, `disp0.pfm`, `calib.txt`);
//! 3. **Middlebury 2005/2006** (`view1.png`, `view5.png`, `disp1.png`, `disp5.png`);
//!    the GT scale follows the image width (full ≈ 1390 px: 1, half: 2, third: 3);
//! 4. **Middlebury 2001/2003** (`im2.ppm`/`im6.ppm`, `disp2.pgm`/`disp6.pgm`):
//!    scale 8 for the 2001 scenes (width < 440) and 4 for 2003 quarter size;
//! 5. **Middlebury 2001 Tsukuba** (`scene1.row3.col3.ppm`, `scene1.row3.col4.ppm`,
//!    `truedisp.row3.col3.pgm`, scale 16).
//!
//! In 8-bit ground truth, value 0 means unknown; it becomes `f32::INFINITY`.
//! Where a scene has no masks but has both ground truths, the non-occluded mask
//! is derived by the left-right check of the two ground truths (as Middlebury
//! built its v2 masks): a left pixel is occluded when the right ground truth at
//! `x − d` disagrees by more than 1 px.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::{io, pfm, DisparityMap, Error, GrayImage, Mask, Result, RgbImage};

/// Camera geometry needed to turn disparity into depth: `Z = b·f / (d + doffs)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Calibration {
    /// Focal length in pixels, if known.
    pub focal_px: Option<f64>,
    /// Baseline in metres, if known.
    pub baseline_m: Option<f64>,
    /// Disparity offset between the principal points (Middlebury 2014 `doffs`).
    pub doffs: f64,
    /// Number of disparity levels to search: `0..ndisp`.
    pub ndisp: usize,
}

impl Calibration {
    /// Parses a Middlebury 2014 `calib.txt` (`cam0=[f 0 cx; ...]`, `doffs=`,
    /// `baseline=` in millimetres, `ndisp=`).
    pub fn parse_middlebury(text: &str) -> std::result::Result<Self, String> {
        let mut calib = Calibration {
            focal_px: None,
            baseline_m: None,
            doffs: 0.0,
            ndisp: 0,
        };
        for line in text.lines() {
            let Some((key, value)) = line.split_once('=') else {
                continue;
            };
            let value = value.trim();
            let num = |v: &str| {
                v.trim()
                    .parse::<f64>()
                    .map_err(|_| format!("{key}: {v:?} is not a number"))
            };
            match key.trim() {
                "cam0" => {
                    let first = value
                        .trim_start_matches('[')
                        .split_whitespace()
                        .next()
                        .unwrap_or("");
                    calib.focal_px = Some(num(first)?);
                }
                "doffs" => calib.doffs = num(value)?,
                "baseline" => calib.baseline_m = Some(num(value)? / 1000.0),
                "ndisp" => {
                    calib.ndisp = value
                        .parse()
                        .map_err(|_| format!("ndisp: {value:?} is not an integer"))?
                }
                _ => {}
            }
        }
        if calib.ndisp == 0 {
            return Err("no ndisp".into());
        }
        Ok(calib)
    }

    /// Formats as a Middlebury 2014 `calib.txt` (unknown focal length or baseline
    /// are written as 0).
    pub fn to_middlebury(&self, width: usize, height: usize) -> String {
        let f = self.focal_px.unwrap_or(0.0);
        let (cx, cy) = (width as f64 / 2.0, height as f64 / 2.0);
        format!(
            "cam0=[{f} 0 {cx}; 0 {f} {cy}; 0 0 1]\ncam1=[{f} 0 {cx1}; 0 {f} {cy}; 0 0 1]\ndoffs={}\nbaseline={}\nwidth={width}\nheight={height}\nndisp={}\n",
            self.doffs,
            self.baseline_m.unwrap_or(0.0) * 1000.0,
            self.ndisp,
            cx1 = cx + self.doffs,
        )
    }
}

/// Evaluation masks: `true` marks the pixels a score is computed over.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Masks {
    /// Non-occluded pixels.
    pub nonocc: Option<Mask>,
    /// All pixels with ground truth (excluding the border).
    pub all: Option<Mask>,
    /// Non-occluded pixels near depth discontinuities.
    pub disc: Option<Mask>,
}

/// A rectified stereo pair with whatever ground truth and calibration exist.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// Scene name (the folder name for loaded scenes).
    pub name: String,
    /// Left (reference) view.
    pub left: RgbImage,
    /// Right view.
    pub right: RgbImage,
    /// Ground-truth disparity of the left view (`inf` = unknown).
    pub gt_left: Option<DisparityMap>,
    /// Ground-truth disparity of the right view (`inf` = unknown).
    pub gt_right: Option<DisparityMap>,
    /// Evaluation masks for the left view.
    pub masks: Masks,
    /// Calibration and disparity search range.
    pub calib: Calibration,
}

struct Layout {
    left: PathBuf,
    right: PathBuf,
    gt_left: Option<PathBuf>,
    gt_right: Option<PathBuf>,
    gt_scale: f32,
    ndisp: Option<usize>,
    calib: Option<PathBuf>,
    masks: [Option<PathBuf>; 3],
}

fn existing(dir: &Path, names: &[&str]) -> Option<PathBuf> {
    names.iter().map(|n| dir.join(n)).find(|p| p.is_file())
}

/// The manifest entry for `dir` in `dir/../manifest.json`: `(gt_scale, ndisp)`.
fn manifest_entry(dir: &Path) -> Result<Option<(f32, usize)>> {
    let Some(parent) = dir.parent() else {
        return Ok(None);
    };
    let path = parent.join("manifest.json");
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(None);
    };
    let json: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| Error::scene(&path, format!("invalid JSON: {e}")))?;
    let name = dir.file_name().and_then(|n| n.to_str()).unwrap_or("");
    let entry = &json["scenes"][name];
    Ok(entry["gt_scale"]
        .as_f64()
        .zip(entry["ndisp"].as_u64())
        .map(|(s, n)| (s as f32, n as usize)))
}

/// The disparity levels (`0..ndisp`) a scene folder states, and the file
/// that states them: its entry in `../manifest.json`, or its `calib.txt`
/// (Middlebury's `ndisp=`); `None` when it states none (or is no scene).
pub fn stated_ndisp(dir: &Path) -> Option<(usize, PathBuf)> {
    let layout = detect(dir).ok()?;
    if let (Some(n), Some(parent)) = (layout.ndisp, dir.parent()) {
        return Some((n, parent.join("manifest.json")));
    }
    let path = layout.calib?;
    let text = std::fs::read_to_string(&path).ok()?;
    let calib = Calibration::parse_middlebury(&text).ok()?;
    Some((calib.ndisp, path))
}

fn detect(dir: &Path) -> Result<Layout> {
    let f = |n: &str| dir.join(n);
    if let Some(left) = existing(dir, &["left.png", "left.ppm"]) {
        let right = existing(dir, &["right.png", "right.ppm"])
            .ok_or_else(|| Error::scene(dir, "has left.png but no right.png"))?;
        let manifest = manifest_entry(dir)?;
        let gt_left = existing(dir, &["gt_left.pfm", "gt_left.png"]);
        let png_gt = gt_left
            .as_ref()
            .is_some_and(|p| p.extension().is_some_and(|e| e == "png"));
        let gt_scale =
            match (manifest, png_gt) {
                (Some((s, _)), _) => s,
                (None, false) => 1.0,
                (None, true) => return Err(Error::scene(
                    dir,
                    "gt_left.png needs its scale from ../manifest.json (scene entry with gt_scale)",
                )),
            };
        return Ok(Layout {
            left,
            right,
            gt_left,
            gt_right: existing(dir, &["gt_right.pfm", "gt_right.png"]),
            gt_scale,
            ndisp: manifest.map(|m| m.1),
            calib: existing(dir, &["calib.txt"]),
            masks: [
                existing(dir, &["mask_nonocc.png"]),
                existing(dir, &["mask_all.png"]),
                existing(dir, &["mask_disc.png"]),
            ],
        });
    }
    let plain =
        |left: &str, right: &str, gl: &[&str], gr: &[&str], scale: f32, ndisp: Option<usize>| {
            Layout {
                left: f(left),
                right: f(right),
                gt_left: existing(dir, gl),
                gt_right: existing(dir, gr),
                gt_scale: scale,
                ndisp,
                calib: existing(dir, &["calib.txt"]),
                masks: [
                    existing(dir, &["mask0nocc.png", "nonocc.png"]),
                    existing(dir, &["all.png"]),
                    existing(dir, &["disc.png"]),
                ],
            }
        };
    if f("im0.png").is_file() {
        return Ok(plain(
            "im0.png",
            "im1.png",
            &["disp0.pfm", "disp0GT.pfm"],
            &["disp1.pfm"],
            1.0,
            None,
        ));
    }
    if f("view1.png").is_file() {
        let (w, _) = png_size(&f("view1.png"))?;
        let scale = if w > 1000 {
            1.0
        } else if w > 600 {
            2.0
        } else {
            3.0
        };
        return Ok(plain(
            "view1.png",
            "view5.png",
            &["disp1.png"],
            &["disp5.png"],
            scale,
            Some((240.0 / scale) as usize),
        ));
    }
    if let Some(im2) = existing(dir, &["im2.ppm", "im2.png"]) {
        let ext = im2
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("ppm")
            .to_string();
        let (w, _) = png_size(&im2)?;
        let (scale, ndisp) = if w < 440 { (8.0, 20) } else { (4.0, 60) };
        return Ok(plain(
            &format!("im2.{ext}"),
            &format!("im6.{ext}"),
            &["disp2.pgm", "disp2.png"],
            &["disp6.pgm", "disp6.png"],
            scale,
            Some(ndisp),
        ));
    }
    if f("scene1.row3.col3.ppm").is_file() {
        return Ok(plain(
            "scene1.row3.col3.ppm",
            "scene1.row3.col4.ppm",
            &["truedisp.row3.col3.pgm"],
            &[],
            16.0,
            Some(16),
        ));
    }
    Err(Error::scene(
        dir,
        "not a stereo scene: expected left.png/right.png, im0.png/im1.png, view1.png/view5.png, \
         im2.ppm/im6.ppm or scene1.row3.col3.ppm",
    ))
}

/// Image size from the header alone.
fn png_size(path: &Path) -> Result<(usize, usize)> {
    let (w, h) = image::image_dimensions(path).map_err(|e| Error::decode(path, e.to_string()))?;
    Ok((w as usize, h as usize))
}

fn read_gt(path: &Path, scale: f32) -> Result<DisparityMap> {
    if path.extension().is_some_and(|e| e == "pfm") {
        let mut d = pfm::read(path)?;
        for v in d.as_mut_slice() {
            if !v.is_finite() || *v < 0.0 {
                *v = f32::INFINITY;
            } else {
                *v /= scale;
            }
        }
        Ok(d)
    } else {
        Ok(io::read_gray(path)?.map(|v| {
            if v == 0 {
                f32::INFINITY
            } else {
                v as f32 / scale
            }
        }))
    }
}

fn read_mask(path: &Path) -> Result<Mask> {
    Ok(io::read_gray(path)?.map(|v| v == 255))
}

/// Non-occluded mask from the left-right consistency of two ground truths.
pub fn nonocc_from_ground_truth(gt_left: &DisparityMap, gt_right: &DisparityMap) -> Mask {
    let w = gt_left.width() as isize;
    crate::Plane::from_fn(gt_left.width(), gt_left.height(), |x, y| {
        let d = gt_left.get(x, y);
        if !d.is_finite() {
            return false;
        }
        let xr = (x as f32 - d).round() as isize;
        (0..w).contains(&xr) && {
            let dr = gt_right.get(xr as usize, y);
            dr.is_finite() && (dr - d).abs() <= 1.0
        }
    })
}

/// Pixels whose ground truth differs by more than `jump` px from a neighbour
/// within `radius`, restricted to `nonocc` (the v2 "disc" mask's definition).
pub fn discontinuity_mask(gt: &DisparityMap, nonocc: &Mask, jump: f32, radius: usize) -> Mask {
    let (w, h) = gt.dims();
    let edge = crate::Plane::from_fn(w, h, |x, y| {
        let d = gt.get(x, y);
        [(1isize, 0isize), (0, 1)].iter().any(|&(dx, dy)| {
            let (nx, ny) = (x as isize + dx, y as isize + dy);
            nx < w as isize && ny < h as isize && {
                let n = gt.get(nx as usize, ny as usize);
                d.is_finite() && n.is_finite() && (d - n).abs() > jump
            }
        })
    });
    let r = radius as isize;
    crate::Plane::from_fn(w, h, |x, y| {
        nonocc.get(x, y)
            && (-r..=r).any(|dy| {
                (-r..=r).any(|dx| {
                    let (nx, ny) = (x as isize + dx, y as isize + dy);
                    nx >= 0
                        && ny >= 0
                        && nx < w as isize
                        && ny < h as isize
                        && edge.get(nx as usize, ny as usize)
                })
            })
    })
}

impl Scene {
    /// Loads a scene folder in any of the layouts listed in the module docs.
    pub fn load(dir: impl AsRef<Path>) -> Result<Scene> {
        let dir = dir.as_ref();
        if !dir.is_dir() {
            return Err(Error::scene(dir, "no such folder"));
        }
        let layout = detect(dir)?;
        let left = io::read_rgb(&layout.left)?;
        let right = io::read_rgb(&layout.right)?;
        left.check_same_size(&right, &layout.right.display().to_string())?;
        let gt_left = layout
            .gt_left
            .as_deref()
            .map(|p| read_gt(p, layout.gt_scale))
            .transpose()?;
        let gt_right = layout
            .gt_right
            .as_deref()
            .map(|p| read_gt(p, layout.gt_scale))
            .transpose()?;
        for (gt, path) in [(&gt_left, &layout.gt_left), (&gt_right, &layout.gt_right)] {
            if let (Some(gt), Some(path)) = (gt, path) {
                left.check_same_size(gt, &path.display().to_string())?;
            }
        }
        let mut masks = Masks::default();
        for (slot, path) in [&mut masks.nonocc, &mut masks.all, &mut masks.disc]
            .into_iter()
            .zip(&layout.masks)
        {
            if let Some(path) = path {
                let m = read_mask(path)?;
                left.check_same_size(&m, &path.display().to_string())?;
                *slot = Some(m);
            }
        }
        if masks.nonocc.is_none() {
            if let (Some(l), Some(r)) = (&gt_left, &gt_right) {
                masks.nonocc = Some(nonocc_from_ground_truth(l, r));
            }
        }
        if masks.disc.is_none() {
            if let (Some(gt), Some(nonocc)) = (&gt_left, &masks.nonocc) {
                masks.disc = Some(discontinuity_mask(gt, nonocc, 2.0, 2));
            }
        }
        let mut calib = match &layout.calib {
            Some(p) => {
                let text = std::fs::read_to_string(p).map_err(|e| Error::io(p, e))?;
                Calibration::parse_middlebury(&text).map_err(|e| Error::scene(p, e))?
            }
            None => Calibration {
                focal_px: None,
                baseline_m: None,
                doffs: 0.0,
                ndisp: 0,
            },
        };
        if let Some(n) = layout.ndisp {
            calib.ndisp = n;
        }
        if calib.ndisp == 0 {
            // Cover the ground truth, or a quarter of the width without it.
            let gt_max = gt_left
                .as_ref()
                .and_then(crate::colormap::finite_range)
                .map(|r| r.1);
            calib.ndisp = gt_max
                .map_or(left.width() / 4, |m| m.ceil() as usize + 1)
                .max(1);
        }
        let name = dir
            .canonicalize()
            .ok()
            .and_then(|d| d.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_else(|| "scene".into());
        Ok(Scene {
            name,
            left,
            right,
            gt_left,
            gt_right,
            masks,
            calib,
        })
    }

    /// Writes the scene in the stereolink layout: `left.png`, `right.png`,
    /// `gt_left.pfm`, `gt_right.pfm`, `mask_*.png` (where present) and `calib.txt`.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        io::write_rgb(dir.join("left.png"), &self.left)?;
        io::write_rgb(dir.join("right.png"), &self.right)?;
        if let Some(gt) = &self.gt_left {
            pfm::write(dir.join("gt_left.pfm"), gt)?;
        }
        if let Some(gt) = &self.gt_right {
            pfm::write(dir.join("gt_right.pfm"), gt)?;
        }
        for (name, mask) in [
            ("nonocc", &self.masks.nonocc),
            ("all", &self.masks.all),
            ("disc", &self.masks.disc),
        ] {
            if let Some(m) = mask {
                let gray: GrayImage = m.map(|b| if b { 255 } else { 0 });
                io::write_gray(dir.join(format!("mask_{name}.png")), &gray)?;
            }
        }
        let calib = self
            .calib
            .to_middlebury(self.left.width(), self.left.height());
        let path = dir.join("calib.txt");
        std::fs::write(&path, calib).map_err(|e| Error::io(&path, e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_middlebury_2014_calib() {
        let text = "cam0=[1038.018 0 322.037; 0 1038.018 243.393; 0 0 1]\n\
                    cam1=[1038.018 0 375.308; 0 1038.018 243.393; 0 0 1]\n\
                    doffs=53.271\nbaseline=176.252\nwidth=718\nheight=496\nndisp=73\n";
        let c = Calibration::parse_middlebury(text).unwrap();
        assert_eq!(c.focal_px, Some(1038.018));
        assert!((c.baseline_m.unwrap() - 0.176252).abs() < 1e-12);
        assert_eq!((c.doffs, c.ndisp), (53.271, 73));
        let again = Calibration::parse_middlebury(&c.to_middlebury(718, 496)).unwrap();
        assert_eq!(again, c);
        assert!(Calibration::parse_middlebury("doffs=x\nndisp=3").is_err());
    }

    #[test]
    fn missing_and_inconsistent_folders_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let err = Scene::load(dir.path()).unwrap_err().to_string();
        assert!(err.contains("not a stereo scene"), "{err}");
        assert!(Scene::load(dir.path().join("nope")).is_err());
        let img = RgbImage::new(4, 3, [1, 2, 3]);
        io::write_rgb(dir.path().join("left.png"), &img).unwrap();
        assert!(Scene::load(dir.path())
            .unwrap_err()
            .to_string()
            .contains("right.png"));
        io::write_rgb(dir.path().join("right.png"), &RgbImage::new(5, 3, [0; 3])).unwrap();
        let err = Scene::load(dir.path()).unwrap_err().to_string();
        assert!(err.contains("5x3") && err.contains("right.png"), "{err}");
        io::write_rgb(dir.path().join("right.png"), &img).unwrap();
        pfm::write(
            dir.path().join("gt_left.pfm"),
            &DisparityMap::new(2, 2, 1.0),
        )
        .unwrap();
        assert!(matches!(
            Scene::load(dir.path()),
            Err(Error::SizeMismatch { .. })
        ));
    }

    #[test]
    fn original_2001_tsukuba_layout() {
        let dir = tempfile::tempdir().unwrap();
        let img = RgbImage::new(6, 4, [9, 9, 9]);
        io::write_rgb(dir.path().join("scene1.row3.col3.ppm"), &img).unwrap();
        io::write_rgb(dir.path().join("scene1.row3.col4.ppm"), &img).unwrap();
        let gt = GrayImage::from_fn(6, 4, |x, _| (x * 16) as u8);
        io::write_gray(dir.path().join("truedisp.row3.col3.pgm"), &gt).unwrap();
        let s = Scene::load(dir.path()).unwrap();
        let g = s.gt_left.unwrap();
        assert_eq!(g.get(0, 0), f32::INFINITY);
        assert_eq!(g.get(5, 0), 5.0);
        assert_eq!(s.calib.ndisp, 16);
    }
}
