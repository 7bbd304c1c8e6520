//! Depth from disparity, point clouds, region distances and depth levels.
//!
//! Depth follows the rectified pinhole model `Z = b·f / (d + doffs)` with the
//! focal length `f` in pixels, the baseline `b` in metres and the principal
//! point offset `doffs` (Middlebury 2014; 0 for rectified webcams).

use std::io::Write;

use stereolink_image::{Calibration, DisparityMap, Plane, RgbImage};

use crate::StereoError;

/// Depth in metres of a disparity, or `None` when it is invalid or at infinity.
pub fn depth_of(disparity: f32, focal_px: f64, baseline_m: f64, doffs: f64) -> Option<f64> {
    let denom = disparity as f64 + doffs;
    (disparity.is_finite() && denom > 0.0).then(|| baseline_m * focal_px / denom)
}

/// Focal length and baseline of a calibration, or an error naming what is missing.
pub fn metric(calib: &Calibration) -> Result<(f64, f64), StereoError> {
    match (calib.focal_px, calib.baseline_m) {
        (Some(f), Some(b)) if f > 0.0 && b > 0.0 => Ok((f, b)),
        _ => Err(StereoError::Parameter(
            "depth needs a focal length (px) and a baseline (m): give --focal-px and --baseline-m or a calib.txt".into(),
        )),
    }
}

/// Depth map in metres (`inf` where the disparity is invalid).
pub fn depth_map(
    disparity: &DisparityMap,
    calib: &Calibration,
) -> Result<DisparityMap, StereoError> {
    let (f, b) = metric(calib)?;
    Ok(disparity.map(|d| depth_of(d, f, b, calib.doffs).map_or(f32::INFINITY, |z| z as f32)))
}

/// A rectangle `x, y, w, h` in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Roi {
    /// Left column.
    pub x: usize,
    /// Top row.
    pub y: usize,
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
}

impl std::str::FromStr for Roi {
    type Err = StereoError;

    /// Parses `x,y,w,h`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let v: Vec<usize> = s
            .split(',')
            .map(|p| p.trim().parse())
            .collect::<Result<_, _>>()
            .map_err(|_| {
                StereoError::Parameter(format!("region {s:?} is not x,y,w,h in whole pixels"))
            })?;
        match v[..] {
            [x, y, w, h] if w > 0 && h > 0 => Ok(Roi { x, y, w, h }),
            _ => Err(StereoError::Parameter(format!(
                "region {s:?} is not x,y,w,h with w, h > 0"
            ))),
        }
    }
}

/// Median of the valid disparities inside `roi` (clipped to the map).
pub fn region_disparity(disparity: &DisparityMap, roi: Roi) -> Option<f32> {
    let (w, h) = disparity.dims();
    let mut values: Vec<f32> = (roi.y..(roi.y + roi.h).min(h))
        .flat_map(|y| (roi.x..(roi.x + roi.w).min(w)).map(move |x| (x, y)))
        .map(|(x, y)| disparity.get(x, y))
        .filter(|d| d.is_finite())
        .collect();
    if values.is_empty() {
        return None;
    }
    let mid = values.len() / 2;
    Some(*values.select_nth_unstable_by(mid, f32::total_cmp).1)
}

/// Distance in metres of a region: the depth of its median disparity.
pub fn region_distance(
    disparity: &DisparityMap,
    roi: Roi,
    calib: &Calibration,
) -> Result<Option<f64>, StereoError> {
    let (f, b) = metric(calib)?;
    Ok(region_disparity(disparity, roi).and_then(|d| depth_of(d, f, b, calib.doffs)))
}

/// Writes an ASCII PLY point cloud (x, y, z in metres; r, g, b) of every valid
/// pixel, with the principal point at the image centre; MeshLab opens it.
pub fn write_ply(
    out: &mut impl Write,
    disparity: &DisparityMap,
    colours: &RgbImage,
    calib: &Calibration,
) -> Result<usize, StereoError> {
    let (f, b) = metric(calib)?;
    let (w, h) = disparity.dims();
    let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
    let mut points = Vec::new();
    for y in 0..h {
        for x in 0..w {
            if let Some(z) = depth_of(disparity.get(x, y), f, b, calib.doffs) {
                let c = colours.get(x, y);
                points.push(format!(
                    "{:.5} {:.5} {:.5} {} {} {}",
                    (x as f64 - cx) * z / f,
                    -(y as f64 - cy) * z / f,
                    -z,
                    c[0],
                    c[1],
                    c[2]
                ));
            }
        }
    }
    let io =
        |e: std::io::Error| StereoError::Parameter(format!("cannot write the point cloud: {e}"));
    write!(
        out,
        "ply\nformat ascii 1.0\ncomment stereolink point cloud, metres\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        points.len()
    )
    .map_err(io)?;
    for p in &points {
        writeln!(out, "{p}").map_err(io)?;
    }
    Ok(points.len())
}

/// How depth levels are counted.
///
/// A **depth level** is a significant mode of the disparity histogram: the
/// valid disparities are binned (`bin` px wide), the histogram is smoothed
/// with a Gaussian of `sigma` bins, and every local maximum is a candidate
/// level owning the bins of its basin (down to the valleys on either side).
/// Candidates whose basins hold less than `min_share` of the valid pixels are
/// merged into their larger neighbour, as are peaks closer than `min_separation`
/// px. The paper counts levels by eye in its Tables V and VI; this is the
/// reproducible version of that count.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct LevelSpec {
    /// Histogram bin width in pixels of disparity.
    pub bin: f32,
    /// Gaussian smoothing of the histogram, in bins.
    pub sigma: f32,
    /// Smallest share of valid pixels a level must hold (0..1).
    pub min_share: f64,
    /// Smallest distance between two level peaks, in pixels of disparity.
    pub min_separation: f32,
}

impl Default for LevelSpec {
    fn default() -> Self {
        LevelSpec {
            bin: 1.0,
            sigma: 1.5,
            min_share: 0.03,
            min_separation: 3.0,
        }
    }
}

/// One depth level.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Level {
    /// Peak disparity of the level (px).
    pub disparity: f32,
    /// Share of the valid pixels in the level's basin.
    pub share: f64,
}

/// The depth levels of a disparity map, nearest (largest disparity) first,
/// with the histogram they were read from.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DepthLevels {
    /// The levels.
    pub levels: Vec<Level>,
    /// Disparity histogram (`bin` px wide bins from 0).
    pub histogram: Vec<u32>,
}

/// Counts the depth levels of `disparity` (see [`LevelSpec`]).
pub fn depth_levels(disparity: &DisparityMap, spec: &LevelSpec) -> DepthLevels {
    let bin = spec.bin.max(1e-3);
    let valid: Vec<f32> = disparity
        .as_slice()
        .iter()
        .copied()
        .filter(|d| d.is_finite() && *d >= 0.0)
        .collect();
    let max = valid.iter().copied().fold(0.0f32, f32::max);
    let n_bins = ((max / bin) as usize + 1).min(1 << 16);
    let mut histogram = vec![0u32; n_bins];
    for d in &valid {
        histogram[((d / bin) as usize).min(n_bins - 1)] += 1;
    }
    if valid.is_empty() {
        return DepthLevels {
            levels: Vec::new(),
            histogram,
        };
    }
    // Gaussian smoothing.
    let radius = (3.0 * spec.sigma).ceil() as isize;
    let kernel: Vec<f64> = (-radius..=radius)
        .map(|i| {
            if spec.sigma > 0.0 {
                (-(i * i) as f64 / (2.0 * (spec.sigma as f64).powi(2))).exp()
            } else {
                (i == 0) as u8 as f64
            }
        })
        .collect();
    let smooth: Vec<f64> = (0..n_bins as isize)
        .map(|i| {
            (-radius..=radius)
                .filter_map(|j| {
                    let k = i + j;
                    (k >= 0 && k < n_bins as isize)
                        .then(|| histogram[k as usize] as f64 * kernel[(j + radius) as usize])
                })
                .sum()
        })
        .collect();
    // Basins: split at local minima of the smoothed histogram.
    let mut basins: Vec<(usize, usize, usize)> = Vec::new(); // (start, end exclusive, peak)
    let mut start = 0;
    for i in 1..n_bins {
        let valley = smooth[i] < smooth[i - 1] && (i + 1 == n_bins || smooth[i] <= smooth[i + 1]);
        if valley && i + 1 < n_bins {
            basins.push((start, i, 0));
            start = i;
        }
    }
    basins.push((start, n_bins, 0));
    for b in &mut basins {
        b.2 = (b.0..b.1)
            .max_by(|&a, &c| smooth[a].total_cmp(&smooth[c]))
            .unwrap_or(b.0);
    }
    let total = valid.len() as f64;
    let mass = |b: &(usize, usize, usize)| {
        histogram[b.0..b.1].iter().map(|&c| c as f64).sum::<f64>() / total
    };
    // Merge weak or crowded basins into their stronger neighbour until stable.
    loop {
        let weakest = (0..basins.len())
            .filter(|&i| {
                let close = |j: usize| {
                    (basins[i].2 as f32 - basins[j].2 as f32).abs() * bin < spec.min_separation
                };
                mass(&basins[i]) < spec.min_share
                    || (i > 0 && close(i - 1))
                    || (i + 1 < basins.len() && close(i + 1))
            })
            .min_by(|&a, &b| mass(&basins[a]).total_cmp(&mass(&basins[b])));
        let Some(i) = weakest else { break };
        if basins.len() == 1 {
            break;
        }
        let j = match (i.checked_sub(1), (i + 1 < basins.len()).then_some(i + 1)) {
            (Some(a), Some(b)) => {
                if mass(&basins[a]) >= mass(&basins[b]) {
                    a
                } else {
                    b
                }
            }
            (Some(a), None) => a,
            (None, Some(b)) => b,
            (None, None) => break,
        };
        let (lo, hi) = (i.min(j), i.max(j));
        let peak = if smooth[basins[i].2] > smooth[basins[j].2] {
            basins[i].2
        } else {
            basins[j].2
        };
        basins[lo] = (basins[lo].0, basins[hi].1, peak);
        basins.remove(hi);
    }
    let mut levels: Vec<Level> = basins
        .iter()
        .filter(|b| mass(b) >= spec.min_share)
        .map(|b| Level {
            disparity: (b.2 as f32 + 0.5) * bin,
            share: mass(b),
        })
        .collect();
    levels.sort_by(|a, b| b.disparity.total_cmp(&a.disparity));
    DepthLevels { levels, histogram }
}

/// A plane of constant depth, as a disparity map: used by tests and examples.
pub fn plane_disparity(
    width: usize,
    height: usize,
    depth_m: f64,
    calib: &Calibration,
) -> DisparityMap {
    let (f, b) = (
        calib.focal_px.unwrap_or(1.0),
        calib.baseline_m.unwrap_or(1.0),
    );
    Plane::new(width, height, (b * f / depth_m - calib.doffs) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn calib() -> Calibration {
        Calibration {
            focal_px: Some(1000.0),
            baseline_m: Some(0.1),
            doffs: 0.0,
            ndisp: 64,
        }
    }

    #[test]
    fn depth_formula_and_invalid_values() {
        assert_eq!(depth_of(50.0, 1000.0, 0.1, 0.0), Some(2.0));
        assert_eq!(depth_of(40.0, 1000.0, 0.1, 10.0), Some(2.0));
        assert_eq!(depth_of(f32::INFINITY, 1000.0, 0.1, 0.0), None);
        assert_eq!(depth_of(0.0, 1000.0, 0.1, 0.0), None);
        let unknown = Calibration {
            focal_px: None,
            ..calib()
        };
        assert!(depth_map(&DisparityMap::new(1, 1, 1.0), &unknown).is_err());
    }

    #[test]
    fn regions_and_relative_distance() {
        let mut d = DisparityMap::new(20, 10, 50.0);
        for y in 0..10 {
            for x in 10..20 {
                d.set(x, y, 40.0);
            }
        }
        let distance_at = |x| {
            let roi = Roi {
                x,
                y: 0,
                w: 10,
                h: 10,
            };
            region_distance(&d, roi, &calib()).unwrap().unwrap()
        };
        let (near, far) = (distance_at(0), distance_at(10));
        assert!((near - 2.0).abs() < 1e-9 && (far - 2.5).abs() < 1e-9);
        assert!("1,2,3".parse::<Roi>().is_err() && "1,2,0,4".parse::<Roi>().is_err());
        assert_eq!(
            "1, 2,3,4".parse::<Roi>().unwrap(),
            Roi {
                x: 1,
                y: 2,
                w: 3,
                h: 4
            }
        );
    }

    #[test]
    fn ply_has_a_header_and_one_line_per_valid_pixel() {
        let mut d = DisparityMap::new(3, 2, 50.0);
        d.set(0, 0, f32::INFINITY);
        let mut buf = Vec::new();
        let n = write_ply(&mut buf, &d, &RgbImage::new(3, 2, [1, 2, 3]), &calib()).unwrap();
        let text = String::from_utf8(buf).unwrap();
        assert_eq!(n, 5);
        assert!(text.contains("element vertex 5") && text.ends_with("1 2 3\n"));
        assert_eq!(text.lines().count(), 11 + 5);
    }

    #[test]
    fn three_layers_give_three_levels() {
        let d = DisparityMap::from_fn(90, 30, |x, _| match x / 30 {
            0 => 10.0,
            1 => 25.0 + (x % 3) as f32 * 0.3,
            _ => 40.0,
        });
        let lv = depth_levels(&d, &LevelSpec::default());
        assert_eq!(lv.levels.len(), 3, "{:?}", lv.levels);
        assert!((lv.levels[0].disparity - 40.5).abs() < 1.0);
        assert!(lv.levels.iter().all(|l| (l.share - 1.0 / 3.0).abs() < 0.01));
        // A speck of 1 % is not a level.
        let mut e = d.clone();
        e.set(0, 0, 60.0);
        assert_eq!(depth_levels(&e, &LevelSpec::default()).levels.len(), 3);
        assert!(depth_levels(
            &DisparityMap::new(4, 4, f32::INFINITY),
            &LevelSpec::default()
        )
        .levels
        .is_empty());
    }
}
