//! One camera's calibration from views of a planar target: Zhang's closed
//! form, then a joint Levenberg–Marquardt over the intrinsics (fx, fy, cx,
//! cy, k1, k2, p1, p2, k3) and every view's pose, minimising the
//! reprojection error as OpenCV's `calibrateCamera` does.
//!
//! The RMS error is OpenCV's: `sqrt(Σ|eᵢ|² / N)` over the `N` corners,
//! `eᵢ` the 2-D distance between a detected corner and its reprojection.

use nalgebra::{Point2, Point3, Vector3};

use crate::lm::{minimise, BlockProblem, LmOptions};
use crate::{zhang, Camera, Distortion, Error, Pose, Result};

/// The number of intrinsic parameters: fx, fy, cx, cy, k1, k2, p1, p2, k3.
pub(crate) const INTRINSICS: usize = 9;

/// The least views a calibration accepts: Zhang's closed form needs 3
/// homographies for 5 intrinsics.
pub const MIN_VIEWS: usize = 3;

/// No view whose RMS reprojection error is below this (pixels) is an
/// outlier: that is within the noise of good subpixel corners, however
/// much better the other views fit.
pub const OUTLIER_FLOOR: f64 = 0.1;

/// A focal length whose standard deviation exceeds this share of itself is
/// reported as poorly constrained.
const FOCAL_SPREAD_WARNING: f64 = 0.01;

/// One camera's calibration.
#[derive(Clone, Debug)]
pub struct MonoCalibration {
    /// The camera.
    pub camera: Camera,
    /// Each view's board pose.
    pub poses: Vec<Pose>,
    /// The RMS reprojection error over all corners, pixels.
    pub rms: f64,
    /// Each view's RMS reprojection error, pixels.
    pub view_rms: Vec<f64>,
    /// Standard deviations of fx, fy, cx, cy, k1, k2, p1, p2, k3.
    pub std_devs: [f64; INTRINSICS],
    /// What the user should know: poorly constrained parameters.
    pub warnings: Vec<String>,
}

pub(crate) fn camera_from(p: &[f64], size: (usize, usize)) -> Camera {
    Camera {
        fx: p[0],
        fy: p[1],
        cx: p[2],
        cy: p[3],
        distortion: Distortion {
            k1: p[4],
            k2: p[5],
            p1: p[6],
            p2: p[7],
            k3: p[8],
        },
        width: size.0,
        height: size.1,
    }
}

pub(crate) fn camera_params(c: &Camera) -> [f64; INTRINSICS] {
    let d = c.distortion;
    [c.fx, c.fy, c.cx, c.cy, d.k1, d.k2, d.p1, d.p2, d.k3]
}

pub(crate) fn pose_from(p: &[f64]) -> Pose {
    Pose {
        rotation: Vector3::new(p[0], p[1], p[2]),
        translation: Vector3::new(p[3], p[4], p[5]),
    }
}

pub(crate) fn pose_params(p: &Pose) -> [f64; 6] {
    let (r, t) = (p.rotation, p.translation);
    [r.x, r.y, r.z, t.x, t.y, t.z]
}

/// Appends the residuals `projected − detected` (x then y) of one view.
pub(crate) fn push_residuals(
    camera: &Camera,
    pose: &Pose,
    object: &[Point3<f64>],
    image: &[Point2<f64>],
    out: &mut Vec<f64>,
) {
    for (o, i) in object.iter().zip(image) {
        let p = camera.project(pose, o);
        out.push(p.x - i.x);
        out.push(p.y - i.y);
    }
}

/// Each block's RMS error, `sqrt(Σ(dx² + dy²) / pairs)`, and the RMS over
/// all blocks (each block has the same number of corners: one board).
pub(crate) fn block_rms(problem: &impl BlockProblem, x: &[f64]) -> (Vec<f64>, f64) {
    let mut residuals = Vec::new();
    let each: Vec<f64> = (0..problem.blocks())
        .map(|b| {
            problem.residuals(b, x, &mut residuals);
            let pairs = (residuals.len() / 2).max(1) as f64;
            (residuals.iter().map(|r| r * r).sum::<f64>() / pairs).sqrt()
        })
        .collect();
    let all = (each.iter().map(|r| r * r).sum::<f64>() / each.len().max(1) as f64).sqrt();
    (each, all)
}

struct Mono<'a> {
    object: &'a [Point3<f64>],
    views: &'a [Vec<Point2<f64>>],
    size: (usize, usize),
}

impl BlockProblem for Mono<'_> {
    fn blocks(&self) -> usize {
        self.views.len()
    }
    fn block_params(&self, b: usize) -> Vec<usize> {
        let pose = INTRINSICS + 6 * b;
        (0..INTRINSICS).chain(pose..pose + 6).collect()
    }
    fn residuals(&self, b: usize, x: &[f64], out: &mut Vec<f64>) {
        out.clear();
        let camera = camera_from(x, self.size);
        let pose = pose_from(&x[INTRINSICS + 6 * b..]);
        push_residuals(&camera, &pose, self.object, &self.views[b], out);
    }
}

/// Checks the views' shapes: enough of them, each with one corner per
/// object point.
pub(crate) fn check_views(object: &[Point3<f64>], views: &[Vec<Point2<f64>>]) -> Result<()> {
    if views.len() < MIN_VIEWS {
        return Err(Error::TooFewViews {
            found: views.len(),
            needed: MIN_VIEWS,
            hint: "take more views of the board, tilted in different directions".into(),
        });
    }
    if let Some((i, v)) = views
        .iter()
        .enumerate()
        .find(|(_, v)| v.len() != object.len())
    {
        return Err(Error::SizeMismatch(format!(
            "view {} has {} corners, the board has {}",
            i + 1,
            v.len(),
            object.len()
        )));
    }
    Ok(())
}

/// Calibrates one camera from views of the planar target `object` (each
/// view lists the detected corners in the order of `object`), for images
/// of `size` (width, height).
pub fn calibrate_camera(
    object: &[Point3<f64>],
    views: &[Vec<Point2<f64>>],
    size: (usize, usize),
) -> Result<MonoCalibration> {
    check_views(object, views)?;
    let (init, poses) = zhang::initialise(object, views, size).ok_or_else(|| {
        Error::Failed(
            "no initial camera fits the views (are they all parallel to the image plane?)".into(),
        )
    })?;
    let mut x0: Vec<f64> = camera_params(&init).to_vec();
    x0.extend(poses.iter().flat_map(pose_params));
    let problem = Mono {
        object,
        views,
        size,
    };
    let fit = minimise(&problem, x0, LmOptions::default());
    let camera = camera_from(&fit.x, size);
    let poses: Vec<Pose> = (0..views.len())
        .map(|i| pose_from(&fit.x[INTRINSICS + 6 * i..]))
        .collect();
    let (view_rms, all) = block_rms(&problem, &fit.x);
    let sd = fit.std_devs();
    let std_devs: [f64; INTRINSICS] = std::array::from_fn(|i| sd[i]);
    let warnings = focal_warnings(&camera, &std_devs);
    if !camera.fx.is_finite() || camera.fx <= 0.0 || camera.fy <= 0.0 {
        return Err(Error::Failed(format!(
            "the focal length diverged ({:.1}, {:.1})",
            camera.fx, camera.fy
        )));
    }
    Ok(MonoCalibration {
        camera,
        poses,
        rms: all,
        view_rms,
        std_devs,
        warnings,
    })
}

/// A warning when a focal length is poorly constrained, which happens when
/// the boards are all nearly parallel to the image plane (Zhang §5: the
/// homographies of parallel planes give dependent constraints).
pub(crate) fn focal_warnings(camera: &Camera, std_devs: &[f64; INTRINSICS]) -> Vec<String> {
    let spread = (std_devs[0] / camera.fx).max(std_devs[1] / camera.fy);
    if spread.is_finite() && spread <= FOCAL_SPREAD_WARNING {
        return Vec::new();
    }
    vec![format!(
        "the focal length is poorly constrained (standard deviation {:.1} % of it): \
         the views are nearly parallel to the image plane; tilt the board by 20-45° in several directions",
        100.0 * spread.min(99.9)
    )]
}

/// The views whose RMS error stands out: above twice the median, above the
/// median plus 3 robust standard deviations (1.4826 × the median absolute
/// deviation), and above [`OUTLIER_FLOOR`]. A bad detection or a moved
/// board shows this way.
pub fn outlier_views(view_rms: &[f64]) -> Vec<usize> {
    if view_rms.len() < MIN_VIEWS {
        return Vec::new();
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let m = median(&mut view_rms.to_vec());
    let mad = median(&mut view_rms.iter().map(|r| (r - m).abs()).collect());
    let limit = (2.0 * m).max(m + 3.0 * 1.4826 * mad).max(OUTLIER_FLOOR);
    (0..view_rms.len())
        .filter(|&i| view_rms[i] > limit)
        .collect()
}

#[cfg(test)]
pub(crate) mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::board::tests::spread_poses;
    use crate::BoardSize;

    pub(crate) fn c310() -> Camera {
        Camera {
            fx: 672.0,
            fy: 669.5,
            cx: 318.4,
            cy: 243.1,
            distortion: Distortion {
                k1: -0.21,
                k2: 0.09,
                p1: 0.0008,
                p2: -0.0011,
                k3: -0.01,
            },
            width: 640,
            height: 480,
        }
    }

    /// Projects the board through `camera` at `poses`, with Gaussian noise
    /// of `sigma` pixels on each coordinate.
    pub(crate) fn views(
        camera: &Camera,
        poses: &[Pose],
        sigma: f64,
        seed: u64,
    ) -> Vec<Vec<Point2<f64>>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut gauss = move || {
            // Box–Muller.
            let (u, v): (f64, f64) = (rng.gen_range(1e-12..1.0), rng.gen());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        };
        let object = BoardSize::new(9, 6).points(0.025);
        poses
            .iter()
            .map(|pose| {
                object
                    .iter()
                    .map(|p| {
                        let q = camera.project(pose, p);
                        Point2::new(q.x + sigma * gauss(), q.y + sigma * gauss())
                    })
                    .collect()
            })
            .collect()
    }

    /// Corner noise of 0.2 px RMS: 0.2/√2 px per coordinate.
    pub(crate) const CORNER_SIGMA: f64 = 0.2 / std::f64::consts::SQRT_2;

    #[test]
    fn recovers_a_distorted_camera_from_noisy_corners() {
        // 25 views as in the shared set; ten noise draws. The errors are
        // RMS over the draws: at this noise and view count the standard
        // deviations are about 0.03 % of f and 0.4 px of the principal
        // point, so a single draw strays up to 3σ.
        let truth = c310();
        let poses = spread_poses(0.025, 25);
        let (mut f_sq, mut pp_sq) = (0.0, 0.0);
        let draws = 10;
        for seed in 0..draws {
            let views = views(&truth, &poses, CORNER_SIGMA, seed);
            let fit =
                calibrate_camera(&BoardSize::new(9, 6).points(0.025), &views, (640, 480)).unwrap();
            let c = fit.camera;
            f_sq += ((c.fx / truth.fx - 1.0).powi(2) + (c.fy / truth.fy - 1.0).powi(2)) / 2.0;
            pp_sq += ((c.cx - truth.cx).powi(2) + (c.cy - truth.cy).powi(2)) / 2.0;
            assert!((fit.rms - 0.2).abs() < 0.02, "rms {}", fit.rms);
            assert!(fit.warnings.is_empty(), "{:?}", fit.warnings);
        }
        let f_rms = (f_sq / draws as f64).sqrt();
        let pp_rms = (pp_sq / draws as f64).sqrt();
        assert!(
            f_rms < 1e-3,
            "focal length RMS error {:.3} %",
            100.0 * f_rms
        );
        assert!(pp_rms < 0.5, "principal point RMS error {pp_rms} px");
    }

    #[test]
    fn a_displaced_view_is_named_an_outlier() {
        let truth = c310();
        let poses = spread_poses(0.025, 12);
        let mut views = views(&truth, &poses, 0.1, 5);
        // View 7's corners shifted one row: a wrong detection.
        views[7].rotate_left(9);
        let fit =
            calibrate_camera(&BoardSize::new(9, 6).points(0.025), &views, (640, 480)).unwrap();
        assert_eq!(outlier_views(&fit.view_rms), vec![7], "{:?}", fit.view_rms);
    }

    #[test]
    fn boards_parallel_to_the_image_plane_are_refused_or_warned() {
        let truth = c310();
        let poses: Vec<Pose> = (0..6)
            .map(|i| Pose {
                rotation: Vector3::new(0.0, 0.0, 0.3 * i as f64),
                translation: Vector3::new(-0.1 + 0.01 * i as f64, -0.06, 0.5 + 0.05 * i as f64),
            })
            .collect();
        let views = views(&truth, &poses, 0.2, 3);
        match calibrate_camera(&BoardSize::new(9, 6).points(0.025), &views, (640, 480)) {
            Ok(fit) => assert!(!fit.warnings.is_empty(), "{:?}", fit.camera),
            Err(Error::Failed(_)) => {}
            Err(e) => panic!("{e}"),
        }
    }

    #[test]
    fn too_few_views_say_how_many_are_needed() {
        let views = views(&c310(), &spread_poses(0.025, 2), 0.0, 1);
        let err =
            calibrate_camera(&BoardSize::new(9, 6).points(0.025), &views, (640, 480)).unwrap_err();
        assert!(err.to_string().contains("at least 3"), "{err}");
    }
}
