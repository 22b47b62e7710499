//! [`DenseIpm`]: a dense primal-dual interior-point method for the assembled QP, tried first
//! (Clarabel finishes what it does not converge on).

use nalgebra::{DMatrix, DVector};
use protocol::QpStatus;

use super::problem::QpProblem;
use super::settings::{QpSettings, REDUCED_TOL};
use super::{QpOutcome, QpSolver};
use crate::linalg::{add_product, all_finite, mat, zeros, zeros_v};

/// A dense primal-dual interior-point method (Mehrotra predictor-corrector, normal equations
/// `P + A^T (Z/S) A` by Cholesky) for `min 1/2 x^T P x  s.t.  A x <= b`: the QP is small and
/// dense, where Clarabel's sparse LDL of the (n + m)-sized KKT system is slow. Its vectors
/// and matrices are kept between ticks.
#[derive(Default)]
pub struct DenseIpm {
    /// The solution of the last [`DenseIpm::solve`].
    pub x: DVector<f64>,
    s: DVector<f64>,
    z: DVector<f64>,
    px: DVector<f64>,
    atz: DVector<f64>,
    rd: DVector<f64>,
    rp: DVector<f64>,
    rc: DVector<f64>,
    t: DVector<f64>,
    adx: DVector<f64>,
    dx: DVector<f64>,
    ds: DVector<f64>,
    dz: DVector<f64>,
    /// `A` with one row of each `(a, -a)` pair, and its rows scaled by their weights.
    a_red: DMatrix<f64>,
    w: DVector<f64>,
    wa: DMatrix<f64>,
    k: DMatrix<f64>,
}

/// Why [`DenseIpm`] stopped without an answer, and after how many iterations.
#[derive(Debug, Clone, Copy)]
struct Stop {
    status: QpStatus,
    iterations: u32,
}

/// Largest step in (0, 1] keeping `s + alpha ds` and `z + alpha dz` non-negative.
fn max_step(s: &DVector<f64>, z: &DVector<f64>, ds: &DVector<f64>, dz: &DVector<f64>) -> f64 {
    let mut alpha: f64 = 1.0;
    for i in 0..s.len() {
        if ds[i] < 0.0 {
            alpha = alpha.min(-s[i] / ds[i]);
        }
        if dz[i] < 0.0 {
            alpha = alpha.min(-z[i] / dz[i]);
        }
    }
    alpha
}

impl QpSolver for DenseIpm {
    fn name(&self) -> &'static str {
        "dense-ipm"
    }

    /// Writes `x` only when it converged (Solved, or AlmostSolved at reduced accuracy).
    fn solve_problem(
        &mut self,
        problem: &QpProblem,
        settings: &QpSettings,
        x: &mut DVector<f64>,
    ) -> QpOutcome {
        let (p, a, b) = (&problem.p, &problem.a, &problem.b);
        let run = self.iterate(
            p,
            a,
            b,
            problem.pairs_from,
            settings.max_iter,
            settings.dense_tol,
            settings.reduced_tol,
        );
        let (status, iterations) = match run {
            Ok((it, reduced)) => {
                if x.len() != self.x.len() {
                    zeros_v(x, self.x.len());
                }
                x.copy_from(&self.x);
                (if reduced { QpStatus::AlmostSolved } else { QpStatus::Solved }, it)
            }
            Err(stop) => (stop.status, stop.iterations),
        };
        QpOutcome {
            status,
            iterations,
            solve_us: 0.0,
            setup_us: 0.0,
            rows: problem.rows(),
            solver: self.name(),
        }
    }
}

impl DenseIpm {
    /// Solve into [`DenseIpm::x`]. Returns the iterations only when it converged to the
    /// tolerances; otherwise the caller runs Clarabel (which also certifies infeasibility).
    ///
    /// Like Clarabel, it reports reduced accuracy: when the iterations run out with every
    /// residual within [`REDUCED_TOL`] (the dual residual can stall at round-off once
    /// complementarity has vanished), it returns the iterate with `reduced = true` (status
    /// AlmostSolved).
    ///
    /// Rows from `pairs_from` on come in pairs `(a, -a)` (two-sided bounds, the torque limits):
    /// their terms of `A^T W A` are `(w_+ + w_-) a a^T`, so the normal matrix is formed from
    /// one row per pair (a third fewer rows for the paper's QP).
    pub fn solve(
        &mut self,
        p: &DMatrix<f64>,
        a: &DMatrix<f64>,
        b: &DVector<f64>,
        pairs_from: usize,
        max_iter: u32,
        tol: f64,
    ) -> Option<(u32, bool)> {
        self.iterate(p, a, b, pairs_from, max_iter, tol, REDUCED_TOL).ok()
    }

    /// [`DenseIpm::solve`] with the reduced-accuracy tolerance given; says why it stopped
    /// without an answer.
    // The terms of the assembled QP and the settings it is solved with, one argument each as in
    // `DenseIpm::solve` (the `QpSolver` path reads them from `QpProblem` and `QpSettings`).
    #[allow(clippy::too_many_arguments)]
    fn iterate(
        &mut self,
        p: &DMatrix<f64>,
        a: &DMatrix<f64>,
        b: &DVector<f64>,
        pairs_from: usize,
        max_iter: u32,
        tol: f64,
        reduced_tol: f64,
    ) -> Result<(u32, bool), Stop> {
        let m = a.nrows();
        let pairs_from = pairs_from.min(m);
        let pairs = (m - pairs_from) / 2;
        if pairs_from + 2 * pairs != m {
            return Err(Stop { status: QpStatus::NumericalError, iterations: 0 });
        }
        let reduced = pairs_from + pairs;
        self.start(a, b, pairs_from, pairs);
        let bnorm = 1.0 + b.amax();
        for it in 0..max_iter {
            let (rp_n, rd_n, mu, dscale) = self.residuals(p, a, b);
            if rp_n <= tol * bnorm && rd_n <= tol * dscale && mu <= tol * bnorm {
                return Ok((it, false));
            }
            if it + 1 == max_iter {
                let ok = rp_n <= reduced_tol * bnorm
                    && rd_n <= reduced_tol * dscale
                    && mu <= reduced_tol * bnorm;
                return if ok {
                    Ok((it, true))
                } else {
                    Err(Stop { status: QpStatus::MaxIterations, iterations: max_iter })
                };
            }
            if !self.newton_step(p, a, pairs_from, reduced, mu) {
                return Err(Stop { status: QpStatus::NumericalError, iterations: it + 1 });
            }
        }
        Err(Stop { status: QpStatus::MaxIterations, iterations: max_iter })
    }

    /// The residuals at the iterate: primal `A x + s - b` into `rp` and dual `P x + A^T z` into
    /// `rd` (with `P x`, `A^T z`); returns their largest entries, the duality measure
    /// `mu = s^T z / m` and the dual residual's scale.
    fn residuals(
        &mut self,
        p: &DMatrix<f64>,
        a: &DMatrix<f64>,
        b: &DVector<f64>,
    ) -> (f64, f64, f64, f64) {
        let m = a.nrows();
        self.px.gemv(1.0, p, &self.x, 0.0);
        self.atz.gemv_tr(1.0, a, &self.z, 0.0);
        self.rd.copy_from(&self.px);
        self.rd += &self.atz;
        self.rp.copy_from(&self.s);
        self.rp -= b;
        self.rp.gemv(1.0, a, &self.x, 1.0);
        let mu = self.s.dot(&self.z) / m as f64;
        // Dual residual relative to its terms' size (as Clarabel does): `A^T z` can be large
        // (stiff contact rows), and `P x + A^T z` then stalls at round-off of that size.
        let dscale = 1.0 + self.px.amax().max(self.atz.amax());
        (self.rp.amax(), self.rd.amax(), mu, dscale)
    }

    /// One Mehrotra predictor-corrector step from the iterate with duality measure `mu`, kept
    /// strictly inside the cone; false on a numerical failure (the normal matrix not positive
    /// definite, or an iterate not finite).
    fn newton_step(
        &mut self,
        p: &DMatrix<f64>,
        a: &DMatrix<f64>,
        pairs_from: usize,
        reduced: usize,
        mu: f64,
    ) -> bool {
        let m = a.nrows();
        self.normal_matrix(p, pairs_from, reduced);
        let k = std::mem::replace(&mut self.k, DMatrix::zeros(0, 0));
        let Some(chol) = k.cholesky() else {
            return false;
        };
        // Predictor: rc = S z.
        self.rc.copy_from(&self.s);
        self.rc.component_mul_assign(&self.z);
        self.direction(&chol, a);
        let alpha_a = max_step(&self.s, &self.z, &self.ds, &self.dz);
        let mut sz = 0.0;
        for i in 0..m {
            sz += (self.s[i] + alpha_a * self.ds[i]) * (self.z[i] + alpha_a * self.dz[i]);
        }
        let sigma = (sz / m as f64 / mu).powi(3).clamp(0.0, 1.0);
        // Corrector: rc = S z + dS_a dz_a - sigma mu.
        for i in 0..m {
            self.rc[i] = self.s[i] * self.z[i] + self.ds[i] * self.dz[i] - sigma * mu;
        }
        self.direction(&chol, a);
        self.k = chol.unpack_dirty();
        let alpha = (0.99 * max_step(&self.s, &self.z, &self.ds, &self.dz)).min(1.0);
        self.x.axpy(alpha, &self.dx, 1.0);
        self.s.axpy(alpha, &self.ds, 1.0);
        self.z.axpy(alpha, &self.dz, 1.0);
        all_finite(self.x.as_slice())
            && self.s.iter().all(|v| v.is_finite() && *v > 0.0)
            && self.z.iter().all(|v| v.is_finite() && *v > 0.0)
    }

    /// Sizes the iterates and scratch, copies `A`'s rows with one row per pair into `a_red`,
    /// and sets the starting point `x = 0`, `s = max(b, 1)`, `z = 1`.
    fn start(&mut self, a: &DMatrix<f64>, b: &DVector<f64>, pairs_from: usize, pairs: usize) {
        let (m, n) = a.shape();
        let reduced = pairs_from + pairs;
        for v in [&mut self.x, &mut self.px, &mut self.atz, &mut self.rd, &mut self.dx] {
            zeros_v(v, n);
        }
        for v in [
            &mut self.s,
            &mut self.z,
            &mut self.rp,
            &mut self.rc,
            &mut self.t,
            &mut self.adx,
            &mut self.ds,
            &mut self.dz,
        ] {
            zeros_v(v, m);
        }
        zeros(&mut self.a_red, reduced, n);
        zeros_v(&mut self.w, reduced);
        zeros(&mut self.wa, reduced, n);
        zeros(&mut self.k, n, n);
        for j in 0..n {
            for i in 0..pairs_from {
                self.a_red[(i, j)] = a[(i, j)];
            }
            for k in 0..pairs {
                self.a_red[(pairs_from + k, j)] = a[(pairs_from + 2 * k, j)];
            }
        }
        for i in 0..m {
            self.s[i] = b[i].max(1.0);
        }
        self.z.fill(1.0);
    }

    /// `K = P + A^T W A` (slightly regularised), `W = z / s`, with each pair's weights summed
    /// on its one row, into `self.k`.
    fn normal_matrix(&mut self, p: &DMatrix<f64>, pairs_from: usize, reduced: usize) {
        let n = p.ncols();
        for i in 0..reduced {
            self.w[i] = if i < pairs_from {
                self.z[i] / self.s[i]
            } else {
                let r = pairs_from + 2 * (i - pairs_from);
                self.z[r] / self.s[r] + self.z[r + 1] / self.s[r + 1]
            };
        }
        for j in 0..n {
            for i in 0..reduced {
                self.wa[(i, j)] = self.a_red[(i, j)] * self.w[i];
            }
        }
        self.k.copy_from(p);
        add_product(&mut self.k, 1.0, mat(&self.a_red).transpose(), mat(&self.wa));
        let reg = 1e-12 * (0..n).map(|i| self.k[(i, i)].abs()).fold(0.0, f64::max);
        for i in 0..n {
            self.k[(i, i)] += reg;
        }
    }

    /// Newton direction for the complementarity residual in `rc`:
    /// `dz = S^{-1}(-rc + Z (rp + A dx))`, `K dx = -rd - A^T S^{-1}(-rc + Z rp)`.
    fn direction(&mut self, chol: &nalgebra::Cholesky<f64, nalgebra::Dyn>, a: &DMatrix<f64>) {
        let m = self.s.len();
        for i in 0..m {
            self.t[i] = (-self.rc[i] + self.z[i] * self.rp[i]) / self.s[i];
        }
        self.dx.copy_from(&self.rd);
        self.dx.gemv_tr(-1.0, a, &self.t, -1.0);
        chol.solve_mut(&mut self.dx);
        self.adx.gemv(1.0, a, &self.dx, 0.0);
        for i in 0..m {
            self.ds[i] = -self.rp[i] - self.adx[i];
            self.dz[i] = (-self.rc[i] - self.z[i] * self.ds[i]) / self.s[i];
        }
    }
}
