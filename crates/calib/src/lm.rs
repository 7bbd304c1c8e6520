//! Levenberg–Marquardt for problems whose residuals come in blocks that
//! each depend on a few parameters, as calibration's do: a view's corners
//! depend on the intrinsics and that view's pose only.
//!
//! Written here rather than taken from the `levenberg-marquardt` crate
//! because that crate factors the dense Jacobian (QR, `O(m·n²)`: 5400
//! residuals × 174 parameters for a 25-pair stereo calibration is about
//! 160 M multiply-adds an iteration), while the normal equations built
//! block by block cost `O(m·k²)` with `k` ≈ 30 parameters a block, and the
//! `n×n` solve is small; OpenCV's `CvLevMarq` solves the normal equations
//! too. The Jacobian is taken by central differences per block.
//!
//! The damping is Marquardt's: `(JᵀJ + λ·diag(JᵀJ))·δ = −Jᵀr`, with `λ`
//! divided by 10 after a step that lowers the cost and multiplied by 10
//! after one that does not.

use nalgebra::{DMatrix, DVector};

/// A least-squares problem `min Σ rᵢ(x)²` in blocks of residuals.
pub(crate) trait BlockProblem: Sync {
    /// The number of residual blocks.
    fn blocks(&self) -> usize;
    /// The indices of the parameters block `b` depends on, into `x`.
    fn block_params(&self, b: usize) -> Vec<usize>;
    /// Block `b`'s residuals at `x`, written to `out` (cleared first).
    fn residuals(&self, b: usize, x: &[f64], out: &mut Vec<f64>);
}

/// The settings of a run.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LmOptions {
    /// At most this many iterations.
    pub max_iterations: usize,
    /// Stop when a step changes the cost by less than this fraction.
    pub tolerance: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions {
            max_iterations: 100,
            tolerance: 1e-12,
        }
    }
}

/// What a run ended with.
#[derive(Clone, Debug)]
pub(crate) struct LmResult {
    /// The parameters at the minimum found.
    pub x: Vec<f64>,
    /// The sum of squared residuals there.
    pub cost: f64,
    /// The number of residuals.
    pub residuals: usize,
    /// `JᵀJ` at the minimum (undamped), for parameter uncertainties.
    pub jtj: DMatrix<f64>,
}

impl LmResult {
    /// The standard deviation of each parameter, from `σ²·(JᵀJ)⁻¹` with
    /// `σ² = cost / (m − n)`; infinite where `JᵀJ` is singular.
    pub fn std_devs(&self) -> Vec<f64> {
        let n = self.x.len();
        let dof = self.residuals.saturating_sub(n).max(1) as f64;
        let sigma2 = self.cost / dof;
        match self.jtj.clone().try_inverse() {
            Some(inv) => (0..n)
                .map(|i| (sigma2 * inv[(i, i)]).max(0.0).sqrt())
                .collect(),
            None => vec![f64::INFINITY; n],
        }
    }
}

fn cost(problem: &impl BlockProblem, x: &[f64]) -> (f64, usize) {
    let mut r = Vec::new();
    let mut total = 0.0;
    let mut count = 0;
    for b in 0..problem.blocks() {
        problem.residuals(b, x, &mut r);
        total += r.iter().map(|v| v * v).sum::<f64>();
        count += r.len();
    }
    (total, count)
}

/// `JᵀJ` and `Jᵀr` at `x`, summed block by block.
fn normal_equations(problem: &impl BlockProblem, x: &[f64]) -> (DMatrix<f64>, DVector<f64>) {
    use rayon::prelude::*;
    let n = x.len();
    let partial = (0..problem.blocks())
        .into_par_iter()
        .map(|b| {
            let params = problem.block_params(b);
            let mut r0 = Vec::new();
            problem.residuals(b, x, &mut r0);
            let m = r0.len();
            // Jacobian columns of the block's parameters, central differences.
            let mut jac = vec![0.0; m * params.len()];
            let mut xp = x.to_vec();
            let (mut rp, mut rm) = (Vec::new(), Vec::new());
            for (c, &p) in params.iter().enumerate() {
                let h = 1e-6 * x[p].abs().max(1e-2);
                xp[p] = x[p] + h;
                problem.residuals(b, &xp, &mut rp);
                xp[p] = x[p] - h;
                problem.residuals(b, &xp, &mut rm);
                xp[p] = x[p];
                for i in 0..m {
                    jac[i * params.len() + c] = (rp[i] - rm[i]) / (2.0 * h);
                }
            }
            let k = params.len();
            let mut jtj = vec![0.0; k * k];
            let mut jtr = vec![0.0; k];
            for i in 0..m {
                let row = &jac[i * k..(i + 1) * k];
                for a in 0..k {
                    jtr[a] += row[a] * r0[i];
                    for c in a..k {
                        jtj[a * k + c] += row[a] * row[c];
                    }
                }
            }
            (params, jtj, jtr)
        })
        .collect::<Vec<_>>();
    let mut jtj = DMatrix::zeros(n, n);
    let mut jtr = DVector::zeros(n);
    for (params, bj, br) in partial {
        let k = params.len();
        for a in 0..k {
            jtr[params[a]] += br[a];
            for c in a..k {
                let v = bj[a * k + c];
                jtj[(params[a], params[c])] += v;
                if a != c {
                    jtj[(params[c], params[a])] += v;
                }
            }
        }
    }
    (jtj, jtr)
}

/// Minimises the problem's cost from `x0`.
pub(crate) fn minimise(problem: &impl BlockProblem, x0: Vec<f64>, options: LmOptions) -> LmResult {
    let mut x = x0;
    let (mut current, residuals) = cost(problem, &x);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let (mut jtj, mut jtr) = normal_equations(problem, &x);
    while iterations < options.max_iterations {
        iterations += 1;
        let mut damped = jtj.clone();
        for i in 0..x.len() {
            damped[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
        }
        let step = damped.cholesky().map(|c| c.solve(&(-&jtr)));
        let Some(step) = step else {
            lambda *= 10.0;
            if lambda > 1e16 {
                break;
            }
            continue;
        };
        let trial: Vec<f64> = x.iter().zip(step.iter()).map(|(a, d)| a + d).collect();
        let (trial_cost, _) = cost(problem, &trial);
        if trial_cost.is_finite() && trial_cost < current {
            let gain = (current - trial_cost) / current.max(f64::MIN_POSITIVE);
            x = trial;
            current = trial_cost;
            lambda = (lambda / 10.0).max(1e-12);
            (jtj, jtr) = normal_equations(problem, &x);
            if gain < options.tolerance {
                break;
            }
        } else {
            lambda *= 10.0;
            if lambda > 1e16 {
                break;
            }
        }
    }
    LmResult {
        x,
        cost: current,
        residuals,
        jtj,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fits `y = a·exp(b·t) + c` in blocks of four samples sharing all three.
    struct Exponential {
        t: Vec<f64>,
        y: Vec<f64>,
    }

    impl BlockProblem for Exponential {
        fn blocks(&self) -> usize {
            self.t.len().div_ceil(4)
        }
        fn block_params(&self, _: usize) -> Vec<usize> {
            vec![0, 1, 2]
        }
        fn residuals(&self, b: usize, x: &[f64], out: &mut Vec<f64>) {
            out.clear();
            for i in b * 4..((b + 1) * 4).min(self.t.len()) {
                out.push(x[0] * (x[1] * self.t[i]).exp() + x[2] - self.y[i]);
            }
        }
    }

    #[test]
    fn recovers_an_exponential_from_a_poor_start() {
        let t: Vec<f64> = (0..30).map(|i| i as f64 * 0.1).collect();
        let y = t.iter().map(|t| 2.5 * (-1.3 * t).exp() + 0.4).collect();
        let problem = Exponential { t, y };
        let fit = minimise(&problem, vec![1.0, -0.1, 0.0], LmOptions::default());
        assert!((fit.x[0] - 2.5).abs() < 1e-6, "{:?}", fit.x);
        assert!((fit.x[1] + 1.3).abs() < 1e-6, "{:?}", fit.x);
        assert!((fit.x[2] - 0.4).abs() < 1e-6, "{:?}", fit.x);
        assert!(fit.cost < 1e-12);
    }
}
