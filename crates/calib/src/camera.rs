//! The camera model: a pinhole with Brown–Conrady distortion, the model of
//! OpenCV's 5-coefficient default and of the MATLAB toolbox's `kc`, in the
//! same coefficient order `(k1, k2, p1, p2, k3)`.
//!
//! A point `X` in the camera's frame projects to normalised coordinates
//! `x = X/Z, y = Y/Z`; with `r² = x² + y²` the distortion is
//!
//! ```text
//! x' = x·(1 + k1·r² + k2·r⁴ + k3·r⁶) + 2·p1·x·y + p2·(r² + 2·x²)
//! y' = y·(1 + k1·r² + k2·r⁴ + k3·r⁶) + p1·(r² + 2·y²) + 2·p2·x·y
//! ```
//!
//! and the pixel is `u = fx·x' + cx, v = fy·y' + cy` (no skew). Pixel
//! centres are at integer coordinates, as in OpenCV.

use nalgebra::{Matrix3, Point2, Point3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

/// Brown–Conrady distortion coefficients in OpenCV's order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Distortion {
    /// Radial, r².
    pub k1: f64,
    /// Radial, r⁴.
    pub k2: f64,
    /// Tangential, first.
    pub p1: f64,
    /// Tangential, second.
    pub p2: f64,
    /// Radial, r⁶.
    pub k3: f64,
}

impl Distortion {
    /// The coefficients as OpenCV's `D` vector `[k1, k2, p1, p2, k3]`.
    pub fn to_array(self) -> [f64; 5] {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// Coefficients from OpenCV's `D` vector; a shorter vector (4 values)
    /// leaves `k3` at 0.
    pub fn from_slice(d: &[f64]) -> Option<Self> {
        match d {
            [k1, k2, p1, p2] => Some(Distortion {
                k1: *k1,
                k2: *k2,
                p1: *p1,
                p2: *p2,
                k3: 0.0,
            }),
            [k1, k2, p1, p2, k3, ..] => Some(Distortion {
                k1: *k1,
                k2: *k2,
                p1: *p1,
                p2: *p2,
                k3: *k3,
            }),
            _ => None,
        }
    }

    /// Distorts normalised coordinates (the equations of the module doc).
    pub fn apply(&self, p: Point2<f64>) -> Point2<f64> {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xy2 = 2.0 * x * y;
        Point2::new(
            x * radial + self.p1 * xy2 + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + self.p2 * xy2,
        )
    }

    /// Inverts [`Distortion::apply`] by Newton's method on the 2×2 system
    /// (OpenCV's `undistortPoints` uses a fixed-point iteration, which
    /// converges more slowly and not at all for strong distortion).
    pub fn remove(&self, distorted: Point2<f64>) -> Point2<f64> {
        let mut p = distorted;
        for _ in 0..20 {
            let (x, y) = (p.x, p.y);
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
            // d(radial)/d(r²)
            let dradial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
            let f = self.apply(p) - distorted;
            let j00 = radial + 2.0 * x * x * dradial + 2.0 * self.p1 * y + 6.0 * self.p2 * x;
            // The Jacobian is symmetric: ∂x'/∂y = ∂y'/∂x.
            let j01 = 2.0 * x * y * dradial + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
            let j10 = j01;
            let j11 = radial + 2.0 * y * y * dradial + 6.0 * self.p1 * y + 2.0 * self.p2 * x;
            let det = j00 * j11 - j01 * j10;
            if det.abs() < 1e-12 {
                break;
            }
            let dx = (j11 * f.x - j01 * f.y) / det;
            let dy = (j00 * f.y - j10 * f.x) / det;
            p.x -= dx;
            p.y -= dy;
            if dx.abs() + dy.abs() < 1e-14 {
                break;
            }
        }
        p
    }
}

/// One camera's intrinsics: focal lengths and principal point in pixels,
/// distortion, and the image size they were calibrated at.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Lens distortion.
    pub distortion: Distortion,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
}

impl Camera {
    /// The 3×3 camera matrix `K` (OpenCV's `M` / `camera_matrix`).
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// The pixel of undistorted normalised coordinates.
    pub fn pixel(&self, normalised: Point2<f64>) -> Point2<f64> {
        let d = self.distortion.apply(normalised);
        Point2::new(self.fx * d.x + self.cx, self.fy * d.y + self.cy)
    }

    /// The undistorted normalised coordinates of a pixel.
    pub fn normalised(&self, pixel: Point2<f64>) -> Point2<f64> {
        let d = Point2::new((pixel.x - self.cx) / self.fx, (pixel.y - self.cy) / self.fy);
        self.distortion.remove(d)
    }

    /// The pixel where `point`, in the frame that `pose` maps to the
    /// camera's, projects.
    pub fn project(&self, pose: &Pose, point: &Point3<f64>) -> Point2<f64> {
        let p = pose.transform(point);
        self.pixel(Point2::new(p.x / p.z, p.y / p.z))
    }
}

/// A rigid transform from a world (board) frame to a camera's frame:
/// `X_cam = R·X + t`, with `R` as a Rodrigues rotation vector (OpenCV's
/// `rvec`, `tvec`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Rotation vector: axis times angle in radians.
    pub rotation: Vector3<f64>,
    /// Translation, in the board's units.
    pub translation: Vector3<f64>,
}

impl Pose {
    /// A pose from a rotation matrix and translation.
    pub fn from_matrix(r: &Matrix3<f64>, t: Vector3<f64>) -> Self {
        let rot = Rotation3::from_matrix(r);
        Pose {
            rotation: rot.scaled_axis(),
            translation: t,
        }
    }

    /// The rotation matrix.
    pub fn matrix(&self) -> Matrix3<f64> {
        *Rotation3::from_scaled_axis(self.rotation).matrix()
    }

    /// `R·X + t`.
    pub fn transform(&self, point: &Point3<f64>) -> Point3<f64> {
        Point3::from(Rotation3::from_scaled_axis(self.rotation) * point.coords + self.translation)
    }

    /// The pose that applies `self` then `then`.
    pub fn then(&self, then: &Pose) -> Pose {
        let r = then.matrix() * self.matrix();
        Pose::from_matrix(&r, then.matrix() * self.translation + then.translation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mono::tests::c310;

    #[test]
    fn removing_distortion_inverts_it_over_the_image() {
        let cam = c310();
        for v in (0..480).step_by(40) {
            for u in (0..640).step_by(40) {
                let px = Point2::new(u as f64, v as f64);
                let back = cam.pixel(cam.normalised(px));
                assert!((back - px).norm() < 1e-9, "{px} -> {back}");
            }
        }
    }

    #[test]
    fn distortion_round_trips_through_opencv_order() {
        let d = c310().distortion;
        assert_eq!(Distortion::from_slice(&d.to_array()), Some(d));
        assert_eq!(
            Distortion::from_slice(&[0.1, 0.2, 0.0, 0.0]).unwrap().k3,
            0.0
        );
        assert_eq!(Distortion::from_slice(&[0.1]), None);
    }

    #[test]
    fn pose_composition_matches_applying_both() {
        let a = Pose {
            rotation: Vector3::new(0.1, -0.2, 0.3),
            translation: Vector3::new(1.0, 2.0, 3.0),
        };
        let b = Pose {
            rotation: Vector3::new(-0.05, 0.4, 0.0),
            translation: Vector3::new(-0.5, 0.0, 0.2),
        };
        let p = Point3::new(0.3, -0.7, 2.0);
        let direct = b.transform(&a.transform(&p));
        assert!((a.then(&b).transform(&p) - direct).norm() < 1e-12);
    }
}
