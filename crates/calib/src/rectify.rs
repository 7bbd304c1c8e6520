//! Bouguet's rectification, as `cv::stereoRectify` computes it (Bouguet's
//! Camera Calibration Toolbox for MATLAB, `rectify_stereo_pair.m`; Bradski
//! & Kaehler, *Learning OpenCV*, ch. 12):
//!
//! 1. each camera turns by half of `R`, in opposite senses, so that the two
//!    image planes are parallel (`r_r = rodrigues(−om/2)`, `om = rodrigues(R)`);
//! 2. one more rotation `w` takes the baseline onto the x axis (the y axis
//!    for a vertical rig): `R1 = w·r_rᵀ`, `R2 = w·r_r`;
//! 3. the common focal length is the smaller of the two `fy` (shrunk when
//!    `k1 < 0` so that barrel distortion's corners fit), the principal
//!    points centre each undistorted image, and their y (x for a vertical
//!    rig) are averaged so that rows correspond;
//! 4. `alpha` scales the focal length between `s0` (0: only valid pixels,
//!    the largest rectangle inside both undistorted images) and `s1` (1:
//!    every source pixel kept, the smallest rectangle around both).

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Point2, Rotation3, Vector3};

use crate::{Camera, Error, Rectification, Result, StereoRig};

/// An axis-aligned rectangle `(x0, y0, x1, y1)` in rectified pixels.
type Rect = [f64; 4];

/// Where distorted pixel `p` of `camera` lands after the rotation `r` and
/// the projection `k` (OpenCV's `undistortPoints` with `R` and `P`).
pub fn rectified_point(
    camera: &Camera,
    r: &Matrix3<f64>,
    k: &Matrix3<f64>,
    p: Point2<f64>,
) -> Point2<f64> {
    let n = camera.normalised(p);
    let q = k * (r * Vector3::new(n.x, n.y, 1.0));
    Point2::new(q.x / q.z, q.y / q.z)
}

/// The inner and outer rectangles of a camera's image after rectification,
/// from a 9×9 grid of its pixels (as OpenCV's `getRectangles`): the inner
/// one lies within the image's border everywhere, the outer one holds it.
fn rectangles(camera: &Camera, r: &Matrix3<f64>, k: &Matrix3<f64>) -> (Rect, Rect) {
    const N: usize = 9;
    let (w, h) = (camera.width as f64 - 1.0, camera.height as f64 - 1.0);
    let mut inner = [f64::MIN, f64::MIN, f64::MAX, f64::MAX];
    let mut outer = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
    for j in 0..N {
        for i in 0..N {
            let p = rectified_point(
                camera,
                r,
                k,
                Point2::new(i as f64 * w / (N - 1) as f64, j as f64 * h / (N - 1) as f64),
            );
            outer = [
                outer[0].min(p.x),
                outer[1].min(p.y),
                outer[2].max(p.x),
                outer[3].max(p.y),
            ];
            if i == 0 {
                inner[0] = inner[0].max(p.x);
            }
            if i == N - 1 {
                inner[2] = inner[2].min(p.x);
            }
            if j == 0 {
                inner[1] = inner[1].max(p.y);
            }
            if j == N - 1 {
                inner[3] = inner[3].min(p.y);
            }
        }
    }
    (inner, outer)
}

/// The scale of the focal length that fits rectangle `rect` about the
/// principal point `c` into a `w×h` image: the largest scale at which the
/// image still lies within `rect` (for the inner rectangle, `alpha` 0) or
/// the smallest at which `rect` lies within the image (outer, `alpha` 1).
fn fit_scale(rect: &Rect, c: Point2<f64>, w: f64, h: f64, inner: bool) -> f64 {
    let ratios = [
        c.x / (c.x - rect[0]),
        c.y / (c.y - rect[1]),
        (w - 1.0 - c.x) / (rect[2] - c.x),
        (h - 1.0 - c.y) / (rect[3] - c.y),
    ];
    if inner {
        ratios.into_iter().fold(f64::MIN, f64::max)
    } else {
        ratios.into_iter().fold(f64::MAX, f64::min)
    }
}

/// The rectification of `rig` with free scaling `alpha` in `[0, 1]`: 0
/// keeps only pixels valid in both views, 1 keeps every source pixel. The
/// rectified images have the cameras' size.
pub fn stereo_rectify(rig: &StereoRig, alpha: f64) -> Result<Rectification> {
    if !(0.0..=1.0).contains(&alpha) {
        return Err(Error::Invalid(format!("alpha {alpha} is outside 0..=1")));
    }
    let (left, right) = (&rig.left, &rig.right);
    if (left.width, left.height) != (right.width, right.height) {
        return Err(Error::SizeMismatch(format!(
            "the left camera is {}x{}, the right {}x{}",
            left.width, left.height, right.width, right.height
        )));
    }
    let om = Rotation3::from_matrix(&rig.rotation).scaled_axis();
    let r_r = *Rotation3::from_scaled_axis(om * -0.5).matrix();
    let t = r_r * rig.translation;
    let horizontal = t.x.abs() > t.y.abs();
    let idx = if horizontal { 0 } else { 1 };
    let c = t[idx];
    if t.norm() <= 0.0 || !t.norm().is_finite() {
        return Err(Error::Invalid(
            "the cameras are at the same place (T = 0)".into(),
        ));
    }
    let mut uu = Vector3::zeros();
    uu[idx] = if c > 0.0 { 1.0 } else { -1.0 };
    let ww = t.cross(&uu);
    let nw = ww.norm();
    let w_r = if nw > 0.0 {
        *Rotation3::from_scaled_axis(ww * ((c.abs() / t.norm()).min(1.0).acos() / nw)).matrix()
    } else {
        Matrix3::identity()
    };
    let r1 = w_r * r_r.transpose();
    let r2 = w_r * r_r;
    let t_new = r2 * rig.translation;

    // The common focal length: the smaller fy (fx for a vertical rig),
    // shrunk for barrel distortion.
    let (w, h) = (left.width as f64, left.height as f64);
    let mut f = f64::MAX;
    for cam in [left, right] {
        let mut fc = if horizontal { cam.fy } else { cam.fx };
        let k1 = cam.distortion.k1;
        if k1 < 0.0 {
            fc *= 1.0 + k1 * (w * w + h * h) / (4.0 * fc * fc);
        }
        f = f.min(fc);
    }
    // The principal points centring each undistorted image.
    let k0 = Matrix3::new(f, 0.0, 0.0, 0.0, f, 0.0, 0.0, 0.0, 1.0);
    let mut cc = [Point2::origin(); 2];
    for (k, (cam, r)) in [(left, &r1), (right, &r2)].into_iter().enumerate() {
        let corners = [
            (0.0, 0.0),
            (w - 1.0, 0.0),
            (0.0, h - 1.0),
            (w - 1.0, h - 1.0),
        ];
        let mean = corners
            .iter()
            .map(|&(x, y)| rectified_point(cam, r, &k0, Point2::new(x, y)).coords)
            .sum::<nalgebra::Vector2<f64>>()
            / 4.0;
        cc[k] = Point2::new((w - 1.0) / 2.0 - mean.x, (h - 1.0) / 2.0 - mean.y);
    }
    // Rows (columns) must correspond: one y (x) for both.
    let shared = (cc[0][1 - idx] + cc[1][1 - idx]) / 2.0;
    cc[0][1 - idx] = shared;
    cc[1][1 - idx] = shared;

    // alpha: between the valid-pixels scale s0 and the all-pixels scale s1.
    let kk = |c: Point2<f64>| Matrix3::new(f, 0.0, c.x, 0.0, f, c.y, 0.0, 0.0, 1.0);
    let (in1, out1) = rectangles(left, &r1, &kk(cc[0]));
    let (in2, out2) = rectangles(right, &r2, &kk(cc[1]));
    let s0 = fit_scale(&in1, cc[0], w, h, true).max(fit_scale(&in2, cc[1], w, h, true));
    let s1 = fit_scale(&out1, cc[0], w, h, false).min(fit_scale(&out2, cc[1], w, h, false));
    let s = s0 * (1.0 - alpha) + s1 * alpha;
    if !(s.is_finite() && s > 0.0) {
        return Err(Error::Failed(format!(
            "no valid rectified image at alpha {alpha} (scale {s})"
        )));
    }
    let f = f * s;

    let p = |c: Point2<f64>, tx: f64, ty: f64| {
        Matrix3x4::new(f, 0.0, c.x, tx, 0.0, f, c.y, ty, 0.0, 0.0, 1.0, 0.0)
    };
    let p1 = p(cc[0], 0.0, 0.0);
    let (tx, ty) = if horizontal {
        (t_new.x * f, 0.0)
    } else {
        (0.0, t_new.y * f)
    };
    let p2 = p(cc[1], tx, ty);
    let tq = t_new[idx];
    let mut q = Matrix4::zeros();
    q[(0, 0)] = 1.0;
    q[(1, 1)] = 1.0;
    q[(0, 3)] = -cc[0].x;
    q[(1, 3)] = -cc[0].y;
    q[(2, 3)] = f;
    q[(3, 2)] = -1.0 / tq;
    q[(3, 3)] = (cc[0][idx] - cc[1][idx]) / tq;
    Ok(Rectification {
        r1,
        r2,
        p1,
        p2,
        q,
        size: (left.width, left.height),
    })
}

impl Rectification {
    /// The left (`right == false`) or right camera's rectifying rotation
    /// and rectified camera matrix (`P`'s first three columns).
    pub fn view(&self, right: bool) -> (Matrix3<f64>, Matrix3<f64>) {
        let (r, p) = if right {
            (self.r2, self.p2)
        } else {
            (self.r1, self.p1)
        };
        (r, p.fixed_view::<3, 3>(0, 0).into_owned())
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Point3;

    use super::*;
    use crate::stereo::tests::rig;
    use crate::Pose;

    /// A 3-D point seen by both cameras, in rectified pixels of each view.
    fn rectified_pair(
        rig: &StereoRig,
        rect: &Rectification,
        x: Point3<f64>,
    ) -> (Point2<f64>, Point2<f64>) {
        let identity = Pose {
            rotation: Vector3::zeros(),
            translation: Vector3::zeros(),
        };
        let between = Pose::from_matrix(&rig.rotation, rig.translation);
        let (l, r) = (
            rig.left.project(&identity, &x),
            rig.right.project(&between, &x),
        );
        let (r1, k1) = rect.view(false);
        let (r2, k2) = rect.view(true);
        (
            rectified_point(&rig.left, &r1, &k1, l),
            rectified_point(&rig.right, &r2, &k2, r),
        )
    }

    #[test]
    fn rectified_rows_correspond_and_disparity_gives_depth() {
        let rig = rig();
        for alpha in [0.0, 0.5, 1.0] {
            let rect = stereo_rectify(&rig, alpha).unwrap();
            let f = rect.p1[(0, 0)];
            let baseline = -rect.p2[(0, 3)] / f;
            assert!((baseline - rig.baseline()).abs() < 1e-9, "{baseline}");
            for (x, y, z) in [(0.1, -0.05, 0.8), (-0.2, 0.1, 1.5), (0.0, 0.0, 3.0)] {
                let (l, r) = rectified_pair(&rig, &rect, Point3::new(x, y, z));
                assert!(
                    (l.y - r.y).abs() < 1e-6,
                    "alpha {alpha}: rows {} vs {}",
                    l.y,
                    r.y
                );
                // Z along the rectified left camera's axis, from disparity.
                let depth = (rect.r1 * Vector3::new(x, y, z)).z;
                let d = l.x - r.x;
                let doffs = rect.p2[(0, 2)] - rect.p1[(0, 2)];
                let z = f * baseline / (d + doffs);
                assert!(
                    (z - depth).abs() < 1e-6 * depth,
                    "alpha {alpha}: {z} vs {depth}"
                );
                // Q gives the same point.
                let h = rect.q * nalgebra::Vector4::new(l.x, l.y, d, 1.0);
                assert!((h.z / h.w - depth).abs() < 1e-6 * depth);
            }
        }
    }

    #[test]
    fn alpha_zero_keeps_only_valid_pixels_and_one_keeps_all() {
        let rig = rig();
        let (w, h) = (rig.left.width as f64, rig.left.height as f64);
        for (alpha, inside) in [(0.0, true), (1.0, false)] {
            let rect = stereo_rectify(&rig, alpha).unwrap();
            for (cam, right) in [(&rig.left, false), (&rig.right, true)] {
                let (r, k) = rect.view(right);
                let (inner, outer) = rectangles(cam, &r, &k);
                let tol = 1e-6;
                if inside {
                    // Every rectified pixel comes from inside the source image.
                    assert!(inner[0] <= tol && inner[1] <= tol, "{inner:?}");
                    assert!(
                        inner[2] >= w - 1.0 - tol && inner[3] >= h - 1.0 - tol,
                        "{inner:?}"
                    );
                } else {
                    // Every source pixel lands inside the rectified image.
                    assert!(outer[0] >= -tol && outer[1] >= -tol, "{outer:?}");
                    assert!(
                        outer[2] <= w - 1.0 + tol && outer[3] <= h - 1.0 + tol,
                        "{outer:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn bad_alpha_and_coincident_cameras_are_refused() {
        let mut rig = rig();
        assert!(stereo_rectify(&rig, 1.5).is_err());
        rig.translation = Vector3::zeros();
        assert!(stereo_rectify(&rig, 0.0).is_err());
    }
}
