//! Zhang's closed-form initialisation (Z. Zhang, "A flexible new technique
//! for camera calibration", IEEE TPAMI 22(11), 2000): a homography per view
//! of a planar target, the intrinsics from the constraints each homography
//! puts on `B = K⁻ᵀK⁻¹` (Zhang's eq. 8–9, with zero skew as a third
//! constraint), and each view's pose from `K⁻¹H` (his eq. 2 and §3.1).
//!
//! The pixels are centred on the image and scaled by its larger side
//! before the homographies are fitted, so that the entries of `B` have
//! similar magnitudes. Where the closed form gives no valid camera (too
//! few or too similar views), the principal point is taken at the image
//! centre and only the focal lengths are solved, as OpenCV's
//! `initIntrinsicParams2D` does.

use nalgebra::{Matrix3, Point2, Point3, SMatrix, SymmetricEigen, Vector3};

use crate::{Camera, Distortion, Pose};

/// The homography `H` with `[u v 1]ᵀ ∝ H·[X Y 1]ᵀ`, by the normalised DLT
/// (Hartley & Zisserman, Algorithm 4.2). `None` for fewer than 4 points or
/// a degenerate configuration.
pub(crate) fn homography(object: &[Point3<f64>], image: &[Point2<f64>]) -> Option<Matrix3<f64>> {
    if object.len() < 4 || object.len() != image.len() {
        return None;
    }
    let to_2d: Vec<Point2<f64>> = object.iter().map(|p| Point2::new(p.x, p.y)).collect();
    let tn_obj = normaliser(&to_2d)?;
    let tn_img = normaliser(image)?;
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for (o, i) in to_2d.iter().zip(image) {
        let o = tn_obj * Vector3::new(o.x, o.y, 1.0);
        let i = tn_img * Vector3::new(i.x, i.y, 1.0);
        let rows = [
            [o.x, o.y, 1.0, 0.0, 0.0, 0.0, -i.x * o.x, -i.x * o.y, -i.x],
            [0.0, 0.0, 0.0, o.x, o.y, 1.0, -i.y * o.x, -i.y * o.y, -i.y],
        ];
        for r in rows {
            let r = SMatrix::<f64, 9, 1>::from_row_slice(&r);
            ata += r * r.transpose();
        }
    }
    let eig = SymmetricEigen::new(ata);
    let (smallest, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let h = eig.eigenvectors.column(smallest);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let h = tn_img.try_inverse()? * hn * tn_obj;
    let scale = h[(2, 2)];
    (scale.abs() > 1e-300).then(|| h / scale)
}

/// Hartley's similarity: centroid to the origin, mean distance √2.
fn normaliser(points: &[Point2<f64>]) -> Option<Matrix3<f64>> {
    let n = points.len() as f64;
    let c = points
        .iter()
        .fold(Vector3::zeros(), |a, p| a + Vector3::new(p.x, p.y, 0.0))
        / n;
    let mean = points
        .iter()
        .map(|p| ((p.x - c.x).powi(2) + (p.y - c.y).powi(2)).sqrt())
        .sum::<f64>()
        / n;
    if mean <= 1e-12 {
        return None;
    }
    let s = std::f64::consts::SQRT_2 / mean;
    Some(Matrix3::new(
        s,
        0.0,
        -s * c.x,
        0.0,
        s,
        -s * c.y,
        0.0,
        0.0,
        1.0,
    ))
}

/// Zhang's `v_ij` (his eq. 7) of homography `h`'s columns `i` and `j`.
fn v(h: &Matrix3<f64>, i: usize, j: usize) -> [f64; 6] {
    let (a, b) = (h.column(i), h.column(j));
    [
        a[0] * b[0],
        a[0] * b[1] + a[1] * b[0],
        a[1] * b[1],
        a[2] * b[0] + a[0] * b[2],
        a[2] * b[1] + a[1] * b[2],
        a[2] * b[2],
    ]
}

/// The intrinsics `(fx, fy, cx, cy)` in the normalised pixel frame by
/// Zhang's closed form (his Appendix B), with zero skew imposed.
fn closed_form(homographies: &[Matrix3<f64>]) -> Option<[f64; 4]> {
    let mut vtv = SMatrix::<f64, 6, 6>::zeros();
    let mut add = |row: [f64; 6]| {
        let r = SMatrix::<f64, 6, 1>::from_row_slice(&row);
        vtv += r * r.transpose();
    };
    for h in homographies {
        let v12 = v(h, 0, 1);
        let (v11, v22) = (v(h, 0, 0), v(h, 1, 1));
        add(v12);
        add(std::array::from_fn(|k| v11[k] - v22[k]));
    }
    // Zero skew: B12 = 0.
    add([0.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
    let eig = SymmetricEigen::new(vtv);
    let (smallest, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let b = eig.eigenvectors.column(smallest);
    let (b11, b12, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4], b[5]);
    let den = b11 * b22 - b12 * b12;
    let v0 = (b12 * b13 - b11 * b23) / den;
    let lambda = b33 - (b13 * b13 + v0 * (b12 * b13 - b11 * b23)) / b11;
    let alpha = (lambda / b11).sqrt();
    let beta = (lambda * b11 / den).sqrt();
    let gamma = -b12 * alpha * alpha * beta / lambda;
    let u0 = gamma * v0 / beta - b13 * alpha * alpha / lambda;
    let k = [alpha, beta, u0, v0];
    k.iter().all(|x| x.is_finite()).then_some(k)
}

/// The focal lengths with the principal point at the origin of the
/// normalised frame (the image centre).
fn focal_only(homographies: &[Matrix3<f64>]) -> Option<[f64; 4]> {
    // h1ᵀBh2 = 0 and h1ᵀBh1 = h2ᵀBh2 with B = diag(a, b, 1), linear in a, b.
    let mut ata = nalgebra::Matrix2::<f64>::zeros();
    let mut atb = nalgebra::Vector2::<f64>::zeros();
    for h in homographies {
        let rows = [
            (
                [h[(0, 0)] * h[(0, 1)], h[(1, 0)] * h[(1, 1)]],
                -h[(2, 0)] * h[(2, 1)],
            ),
            (
                [
                    h[(0, 0)].powi(2) - h[(0, 1)].powi(2),
                    h[(1, 0)].powi(2) - h[(1, 1)].powi(2),
                ],
                -(h[(2, 0)].powi(2) - h[(2, 1)].powi(2)),
            ),
        ];
        for (r, rhs) in rows {
            let r = nalgebra::Vector2::new(r[0], r[1]);
            ata += r * r.transpose();
            atb += r * rhs;
        }
    }
    let ab = ata.try_inverse()? * atb;
    (ab[0] > 0.0 && ab[1] > 0.0).then(|| [1.0 / ab[0].sqrt(), 1.0 / ab[1].sqrt(), 0.0, 0.0])
}

/// An initial camera (no distortion) and one pose per view.
pub(crate) fn initialise(
    object: &[Point3<f64>],
    views: &[Vec<Point2<f64>>],
    size: (usize, usize),
) -> Option<(Camera, Vec<Pose>)> {
    let (w, h) = (size.0 as f64, size.1 as f64);
    let scale = w.max(h);
    let (ox, oy) = ((w - 1.0) / 2.0, (h - 1.0) / 2.0);
    let homographies: Vec<Matrix3<f64>> = views
        .iter()
        .map(|v| {
            let normalised: Vec<Point2<f64>> = v
                .iter()
                .map(|p| Point2::new((p.x - ox) / scale, (p.y - oy) / scale))
                .collect();
            homography(object, &normalised)
        })
        .collect::<Option<_>>()?;
    let plausible = |k: &[f64; 4]| {
        k[0] > 0.05
            && k[1] > 0.05
            && k[0] < 50.0
            && k[1] < 50.0
            && k[2].abs() < 0.5
            && k[3].abs() < 0.5
    };
    let k = closed_form(&homographies)
        .filter(plausible)
        .or_else(|| focal_only(&homographies).filter(plausible))?;
    let camera = Camera {
        fx: k[0] * scale,
        fy: k[1] * scale,
        cx: k[2] * scale + ox,
        cy: k[3] * scale + oy,
        distortion: Distortion::default(),
        width: size.0,
        height: size.1,
    };
    let kn = Matrix3::new(k[0], 0.0, k[2], 0.0, k[1], k[3], 0.0, 0.0, 1.0);
    let kinv = kn.try_inverse()?;
    let poses = homographies
        .iter()
        .map(|h| pose_from_homography(&kinv, h))
        .collect::<Option<_>>()?;
    Some((camera, poses))
}

/// The board's pose from `K⁻¹H = λ·[r1 r2 t]` (Zhang §3.1), the rotation
/// made orthonormal by SVD and the board put in front of the camera.
pub(crate) fn pose_from_homography(kinv: &Matrix3<f64>, h: &Matrix3<f64>) -> Option<Pose> {
    let m = kinv * h;
    let (c1, c2, c3) = (
        m.column(0).into_owned(),
        m.column(1).into_owned(),
        m.column(2).into_owned(),
    );
    let mut lambda = 2.0 / (c1.norm() + c2.norm());
    if !lambda.is_finite() {
        return None;
    }
    if c3.z * lambda < 0.0 {
        lambda = -lambda;
    }
    let (r1, r2) = (c1 * lambda, c2 * lambda);
    let r = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
    let svd = r.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut rot = u * vt;
    if rot.determinant() < 0.0 {
        rot = -rot;
    }
    Some(Pose::from_matrix(&rot, c3 * lambda))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::BoardSize;

    #[test]
    fn homography_maps_the_points_it_was_fitted_to() {
        let object = BoardSize::new(9, 6).points(1.0);
        let truth = Matrix3::new(50.0, 3.0, 100.0, -2.0, 48.0, 80.0, 0.001, -0.002, 1.0);
        let image: Vec<Point2<f64>> = object
            .iter()
            .map(|p| {
                let q = truth * Vector3::new(p.x, p.y, 1.0);
                Point2::new(q.x / q.z, q.y / q.z)
            })
            .collect();
        let h = homography(&object, &image).unwrap();
        assert!((h - truth).norm() < 1e-6 * truth.norm(), "{h}");
    }

    #[test]
    fn closed_form_recovers_a_distortion_free_camera() {
        let camera = Camera {
            fx: 670.0,
            fy: 665.0,
            cx: 330.0,
            cy: 230.0,
            distortion: Distortion::default(),
            width: 640,
            height: 480,
        };
        let object = BoardSize::new(9, 6).points(0.025);
        let poses = crate::board::tests::spread_poses(0.025, 8);
        let views: Vec<Vec<Point2<f64>>> = poses
            .iter()
            .map(|pose| object.iter().map(|p| camera.project(pose, p)).collect())
            .collect();
        let (init, _) = initialise(&object, &views, (640, 480)).unwrap();
        assert!((init.fx - 670.0).abs() < 1e-3, "{init:?}");
        assert!((init.fy - 665.0).abs() < 1e-3, "{init:?}");
        assert!((init.cx - 330.0).abs() < 1e-3, "{init:?}");
        assert!((init.cy - 230.0).abs() < 1e-3, "{init:?}");
    }
}
