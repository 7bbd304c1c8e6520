//! Robust fit of a disparity plane `d = a·x + b·y + c` to a segment's
//! reliable disparities, after AdaptingBP (Klaus, Sormann, Karner, "Segment-
//! Based Stereo Matching Using Belief Propagation and a Self-Adapting
//! Dissimilarity Measure", ICPR 2006, §2.3):
//!
//! 1. the horizontal slant `a` is voted from disparity derivatives along
//!    rows, `Δd / Δx` of pairs of reliable pixels of one row, half a row's
//!    samples apart (long baselines, one vote per sample);
//! 2. the vertical slant `b` the same way along columns;
//! 3. the offset `c` from `d − a·x − b·y` of every reliable pixel.
//!
//! Each vote takes the mode of the values smoothed by a box kernel of
//! half-width `bandwidth` (the densest window of the sorted values, then
//! their mean), which is AdaptingBP's smoothed histogram without bins.
//! A least-squares refit over the pixels within `inlier` px of the voted
//! plane follows, so noise-free data gives the exact plane; a slant that
//! the samples cannot observe (no two samples in a row or column, or a
//! singular refit) is left at its vote, 0 without votes.

use stereolink_image::DisparityMap;

use super::DisparityPlane;

/// The voting and refit tolerances.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct FitParams {
    /// Half-width of the slant votes' kernel (px of disparity per px).
    pub slant_bandwidth: f32,
    /// Half-width of the offset vote's kernel (px).
    pub offset_bandwidth: f32,
    /// Largest residual of a pixel that the refit uses (px).
    pub inlier: f32,
}

impl Default for FitParams {
    fn default() -> Self {
        FitParams {
            slant_bandwidth: 0.05,
            offset_bandwidth: 0.5,
            inlier: 1.0,
        }
    }
}

/// A reliable disparity sample at pixel `(x, y)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Column.
    pub x: f32,
    /// Row.
    pub y: f32,
    /// Disparity.
    pub d: f32,
}

/// The finite disparities of `pixels` (indices into `disparity`, raster order).
pub fn samples(disparity: &DisparityMap, pixels: &[u32], out: &mut Vec<Sample>) {
    let w = disparity.width();
    out.clear();
    out.extend(pixels.iter().filter_map(|&p| {
        let d = disparity.as_slice()[p as usize];
        d.is_finite().then(|| Sample {
            x: (p as usize % w) as f32,
            y: (p as usize / w) as f32,
            d,
        })
    }));
}

/// The robust plane of `samples` (in raster order), `None` without samples.
pub fn fit_plane(samples: &[Sample], params: &FitParams) -> Option<DisparityPlane> {
    if samples.is_empty() {
        return None;
    }
    let mut votes = Vec::with_capacity(samples.len());
    // Rows: raster order keeps each row's samples together and sorted by x.
    slant_votes(samples, |s| (s.y, s.x), &mut votes);
    let a = mode(&mut votes, params.slant_bandwidth).unwrap_or(0.0);
    let mut by_column = samples.to_vec();
    by_column.sort_unstable_by(|p, q| p.x.total_cmp(&q.x).then(p.y.total_cmp(&q.y)));
    slant_votes(&by_column, |s| (s.x, s.y), &mut votes);
    let b = mode(&mut votes, params.slant_bandwidth).unwrap_or(0.0);
    votes.clear();
    votes.extend(samples.iter().map(|s| s.d - a * s.x - b * s.y));
    let c = mode(&mut votes, params.offset_bandwidth)?;
    let voted = DisparityPlane { a, b, c };
    Some(refit(samples, voted, params.inlier).unwrap_or(voted))
}

/// Derivative votes along lines: `line_of` gives a sample's line and its
/// position on it; `samples` are sorted by both. Each sample `i` of a line
/// of `n` votes with sample `i + ⌈n/2⌉`.
fn slant_votes(samples: &[Sample], line_of: impl Fn(&Sample) -> (f32, f32), out: &mut Vec<f32>) {
    out.clear();
    for line in samples.chunk_by(|p, q| line_of(p).0 == line_of(q).0) {
        let half = line.len().div_ceil(2);
        for (p, q) in line.iter().zip(&line[half..]) {
            let (dt, dd) = (line_of(q).1 - line_of(p).1, q.d - p.d);
            out.push(dd / dt);
        }
    }
}

/// The mode of `values` under a box kernel of half-width `bandwidth`: the
/// mean of the most populous window `[v, v + 2·bandwidth]` (the first of
/// equals); `None` when empty.
pub fn mode(values: &mut [f32], bandwidth: f32) -> Option<f32> {
    values.sort_unstable_by(f32::total_cmp);
    let mut best = (0, 0..0);
    let mut end = 0;
    for start in 0..values.len() {
        while end < values.len() && values[end] - values[start] <= 2.0 * bandwidth {
            end += 1;
        }
        if end - start > best.0 {
            best = (end - start, start..end);
        }
    }
    let window = &values[best.1];
    (!window.is_empty()).then(|| window.iter().sum::<f32>() / window.len() as f32)
}

/// Least squares over the samples within `inlier` of `plane`, coordinates
/// taken about their mean for conditioning; `None` when the inliers leave
/// the plane undetermined.
pub fn refit(samples: &[Sample], plane: DisparityPlane, inlier: f32) -> Option<DisparityPlane> {
    let inliers = || {
        samples
            .iter()
            .filter(move |s| (plane.at(s.x, s.y) - s.d).abs() <= inlier)
    };
    let n = inliers().count();
    if n < 3 {
        return None;
    }
    let mean = inliers().fold([0f64; 3], |m, s| {
        [m[0] + s.x as f64, m[1] + s.y as f64, m[2] + s.d as f64]
    });
    let [mx, my, md] = mean.map(|v| v / n as f64);
    let (mut sxx, mut sxy, mut syy, mut sxd, mut syd) = (0f64, 0f64, 0f64, 0f64, 0f64);
    for s in inliers() {
        let (x, y, d) = (s.x as f64 - mx, s.y as f64 - my, s.d as f64 - md);
        sxx += x * x;
        sxy += x * y;
        syy += y * y;
        sxd += x * d;
        syd += y * d;
    }
    let det = sxx * syy - sxy * sxy;
    // Collinear pixels (one row or column) leave one slant free.
    if det <= 1e-9 * (sxx * syy).max(1.0) {
        return None;
    }
    let a = (sxd * syy - syd * sxy) / det;
    let b = (syd * sxx - sxd * sxy) / det;
    let c = md - a * mx - b * my;
    Some(DisparityPlane {
        a: a as f32,
        b: b as f32,
        c: c as f32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(plane: DisparityPlane, w: usize, h: usize) -> Vec<Sample> {
        (0..h)
            .flat_map(|y| (0..w).map(move |x| (x as f32, y as f32)))
            .map(|(x, y)| Sample {
                x,
                y,
                d: plane.at(x, y),
            })
            .collect()
    }

    #[test]
    fn noise_free_slanted_planes_are_recovered_exactly() {
        for plane in [
            DisparityPlane {
                a: 0.25,
                b: -0.125,
                c: 20.0,
            },
            DisparityPlane {
                a: -0.4,
                b: 0.3,
                c: 41.5,
            },
            DisparityPlane {
                a: 0.0,
                b: 0.0,
                c: 7.0,
            },
        ] {
            let fit = fit_plane(&grid(plane, 30, 20), &FitParams::default()).unwrap();
            assert!((fit.a - plane.a).abs() < 1e-5, "{fit:?} vs {plane:?}");
            assert!((fit.b - plane.b).abs() < 1e-5, "{fit:?} vs {plane:?}");
            assert!((fit.c - plane.c).abs() < 1e-3, "{fit:?} vs {plane:?}");
        }
    }

    #[test]
    fn outliers_do_not_move_the_plane() {
        let plane = DisparityPlane {
            a: 0.1,
            b: 0.2,
            c: 10.0,
        };
        let mut s = grid(plane, 25, 25);
        // A quarter of the pixels are gross mismatches, 3 to 9 px off.
        for (i, p) in s.iter_mut().enumerate() {
            if i % 4 == 1 {
                p.d += if i % 8 == 1 { 3.0 } else { -2.0 } * (1 + i % 3) as f32;
            }
        }
        let fit = fit_plane(&s, &FitParams::default()).unwrap();
        assert!((fit.a - plane.a).abs() < 1e-4, "{fit:?}");
        assert!((fit.b - plane.b).abs() < 1e-4, "{fit:?}");
        assert!((fit.c - plane.c).abs() < 1e-2, "{fit:?}");
    }

    #[test]
    fn one_row_or_one_pixel_leaves_the_unobservable_slant_at_zero() {
        let row: Vec<Sample> = (0..10)
            .map(|x| Sample {
                x: x as f32,
                y: 3.0,
                d: 5.0 + 0.5 * x as f32,
            })
            .collect();
        let fit = fit_plane(&row, &FitParams::default()).unwrap();
        assert_eq!((fit.a, fit.b), (0.5, 0.0));
        assert!((fit.at(4.0, 3.0) - 7.0).abs() < 1e-5);
        let one = [Sample {
            x: 2.0,
            y: 2.0,
            d: 9.0,
        }];
        let fit = fit_plane(&one, &FitParams::default()).unwrap();
        assert_eq!(
            fit,
            DisparityPlane {
                a: 0.0,
                b: 0.0,
                c: 9.0
            }
        );
        assert_eq!(fit_plane(&[], &FitParams::default()), None);
    }

    #[test]
    fn mode_takes_the_densest_window() {
        assert_eq!(mode(&mut [], 1.0), None);
        let m = mode(&mut [5.0, 1.0, 1.1, 0.9, 9.0], 0.15).unwrap();
        assert!((m - 1.0).abs() < 1e-6, "{m}");
    }
}
