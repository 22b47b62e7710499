//! [`DualActiveSet`]: the Goldfarb–Idnani dual active-set method for the assembled QP of
//! eq. wrench_optim2, hot-started from the previous tick's active set; tried before
//! [`super::DenseIpm`] (which, then Clarabel, finishes what it does not solve).
//!
//! ```text
//! min_F  1/2 F^T P F,  P = 2 (Y^T Y + eps I)     (eq. wrench_optim2, regularised)
//! s.t.   a_i F <= b_i                             (eqs. unilateral_and_friction_cone_constraint,
//!                                                  moment_constraint, real_torque_limit)
//! ```
//!
//! `P` is strictly convex (the `eps I`), so the unconstrained minimum `F = 0` is a dual
//! feasible start and every step keeps dual feasibility (Goldfarb & Idnani 1983, the method of
//! quadprog): the most violated row is added, rows whose multiplier would turn negative are
//! dropped on the way. The factors are `P = L L^T` (once per tick), `J = L^{-T} Q` and the
//! upper triangular `R` of `L^{-1} N_W = Q [R; 0]` (`N_W`: the active rows, negated), updated
//! by Givens rotations when a row enters or leaves.
//!
//! **Hot start.** The team's QP changes little from tick to tick: the previous tick's active
//! rows are put into the factors first (skipping any that became linearly dependent), the
//! equality-constrained minimum on them and its multipliers are computed, rows with a negative
//! multiplier are dropped until all are non-negative (a dual feasible start again), and the
//! method continues from there. On a tick like the last, no row enters or leaves.
//!
//! The answer is the equality-constrained minimum on the final active set, computed again
//! from the factors, and it is accepted only if every row holds to [`ACTIVE_SET_TOL`] and
//! every multiplier is non-negative; otherwise (or when it detects infeasibility, or the
//! iterations run out) the caller runs the interior-point path, which reports the status.
//!
//! [`ACTIVE_SET_TOL`]: super::settings::ACTIVE_SET_TOL

use faer::{MatMut, MatRef};
use nalgebra::{DMatrix, DVector};
use protocol::QpStatus;

use super::problem::QpProblem;
use super::settings::QpSettings;
use super::{QpOutcome, QpSolver};

use crate::linalg::{
    cholesky_in_place, dot, gemm, lower_inverse, lower_solve_in_place, shape, zeros_v,
};

/// Why [`DualActiveSet`] stopped without an answer (the caller then runs the interior-point
/// path).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ActiveSetError {
    #[error("the objective is not positive definite (Cholesky failed)")]
    NotPositiveDefinite,
    #[error("no step can satisfy row {row}: the QP looks infeasible")]
    Infeasible { row: usize },
    #[error("{0} iterations without an answer")]
    IterationLimit(u32),
    #[error("the final point misses a row or a multiplier by more than the tolerance ({0:.1e})")]
    Inaccurate(f64),
    #[error("a value is not finite")]
    NonFinite,
}

impl ActiveSetError {
    /// The status a failed attempt would have on its own.
    pub fn status(&self) -> QpStatus {
        match self {
            ActiveSetError::Infeasible { .. } => QpStatus::Infeasible,
            ActiveSetError::IterationLimit(_) => QpStatus::MaxIterations,
            _ => QpStatus::NumericalError,
        }
    }
}

/// The Goldfarb–Idnani dual active-set method (see the module's docs). Its factors, the
/// previous tick's active set and its scratch are kept between ticks; nothing is allocated
/// once the QP's shape is known.
#[derive(Default)]
pub struct DualActiveSet {
    /// The solution of the last successful solve.
    pub x: DVector<f64>,
    /// Cholesky factor of `P` (lower triangle).
    l: DMatrix<f64>,
    /// `J = L^{-T} Q` (n x n).
    j: DMatrix<f64>,
    /// `R` (upper triangular, the first `q` columns used).
    r: DMatrix<f64>,
    /// Multipliers of the active rows.
    u: DVector<f64>,
    /// Active rows, in the order of `R`'s columns.
    active: Vec<usize>,
    /// Active rows of the last solve, and its problem's shape `(n, rows)`.
    warm: Vec<usize>,
    warm_shape: (usize, usize),
    /// Slacks `b - A x` and row norms `|a_i|`.
    s: DVector<f64>,
    norms: DVector<f64>,
    /// Scratch: `d = J^T n_p`, the primal step `z`, the dual step `R^{-1} d_1`, `n_p = -a_p`.
    d: DVector<f64>,
    z: DVector<f64>,
    rv: DVector<f64>,
    np: DVector<f64>,
    /// Iterations of the last solve, and whether it was hot-started.
    pub iterations: u32,
    pub hot: bool,
}

/// `(c, s, h)` with `[c s; -s c] [a; b] = [h; 0]`.
fn givens(a: f64, b: f64) -> (f64, f64, f64) {
    let h = a.hypot(b);
    if h == 0.0 {
        (1.0, 0.0, 0.0)
    } else {
        (a / h, b / h, h)
    }
}

/// Rotate columns `i`, `k` of `m` by `(c, s)`: `(m_i, m_k) <- (c m_i + s m_k, -s m_i + c m_k)`.
fn rotate_columns(m: &mut DMatrix<f64>, i: usize, k: usize, c: f64, s: f64) {
    let n = m.nrows();
    let (lo, hi) = m.as_mut_slice().split_at_mut(k * n);
    let ci = &mut lo[i * n..(i + 1) * n];
    let ck = &mut hi[..n];
    for (x, y) in ci.iter_mut().zip(ck.iter_mut()) {
        let (a, b) = (*x, *y);
        *x = c * a + s * b;
        *y = -s * a + c * b;
    }
}

impl QpSolver for DualActiveSet {
    fn name(&self) -> &'static str {
        "active-set"
    }

    /// Writes `x` only when it solved the QP; a failure's status is what the attempt alone
    /// would report (the caller goes on to the interior-point path).
    fn solve_problem(
        &mut self,
        problem: &QpProblem,
        settings: &QpSettings,
        x: &mut DVector<f64>,
    ) -> QpOutcome {
        let rows = problem.rows();
        let status = match self.solve(problem, settings) {
            Ok(()) => {
                if x.len() != self.x.len() {
                    zeros_v(x, self.x.len());
                }
                x.copy_from(&self.x);
                QpStatus::Solved
            }
            Err(e) => e.status(),
        };
        QpOutcome {
            status,
            iterations: self.iterations,
            solve_us: 0.0,
            setup_us: 0.0,
            rows,
            solver: self.name(),
        }
    }
}

impl DualActiveSet {
    /// Solve into [`DualActiveSet::x`], hot-started from the last successful solve's active
    /// rows when the problem has the same shape.
    pub fn solve(
        &mut self,
        problem: &QpProblem,
        settings: &QpSettings,
    ) -> Result<(), ActiveSetError> {
        self.iterations = 0;
        self.hot = false;
        let result = self.run(problem, settings);
        if result.is_ok() {
            self.warm.clear();
            self.warm.extend_from_slice(&self.active);
            self.warm_shape = (problem.n(), problem.rows());
        } else {
            self.warm.clear();
        }
        result
    }

    /// The active rows of the last successful solve and its problem's shape `(variables,
    /// rows)`: what the next tick's hot start begins from ([`super::BlockHotStart`] too).
    pub fn warm(&self) -> (&[usize], (usize, usize)) {
        (&self.warm, self.warm_shape)
    }

    /// Start the next hot start from `rows` of a problem of `shape` (what
    /// [`super::BlockHotStart`] found optimal on a tick this method did not solve).
    pub fn set_warm(&mut self, rows: &[usize], shape: (usize, usize)) {
        self.warm.clear();
        self.warm.extend_from_slice(rows);
        self.warm_shape = shape;
    }

    /// The Goldfarb–Idnani iterations on `problem`: the hot answer when the last active rows
    /// still are the optimum, else from the unconstrained minimum (or the last active rows) add
    /// the most violated row until every row holds.
    fn run(&mut self, problem: &QpProblem, settings: &QpSettings) -> Result<(), ActiveSetError> {
        let (a, b) = (&problem.a, &problem.b);
        let (rows, n) = a.shape();
        if problem.p.shape() != (n, n) || b.len() != rows {
            return Err(ActiveSetError::NonFinite);
        }
        self.size(n, rows);
        self.l.copy_from(&problem.p);
        cholesky_in_place(self.l.as_mut_slice(), n, n, 0.0)
            .ok_or(ActiveSetError::NotPositiveDefinite)?;
        let tol = settings.active_set_tol;
        let hot = self.warm_shape == (n, rows) && !self.warm.is_empty();
        if hot && self.hot_answer(a, b, tol) {
            self.hot = true;
            return Ok(());
        }
        self.cold_start(a);
        if hot {
            self.hot = true;
            self.start_from_warm(a, b);
        }
        let max_iter = settings.active_set_max_iter;
        let mut refined = false;
        loop {
            // Step 1: the most violated row (by distance, |a_i| scaled).
            let Some(p) = self.most_violated(a, b, tol)? else {
                // Every row holds: recompute the point from the factors, check it once more.
                self.equality_point(b);
                if !refined {
                    refined = true;
                    continue;
                }
                return self.verify(a, b, tol);
            };
            refined = false;
            if self.iterations >= max_iter {
                return Err(ActiveSetError::IterationLimit(self.iterations));
            }
            self.add_violated(a, b, p, max_iter)?;
        }
    }

    /// The unconstrained minimum `x = 0` with no active row, `J = L^{-T}`, and the rows' norms.
    fn cold_start(&mut self, a: &DMatrix<f64>) {
        self.x.as_mut_slice().fill(0.0);
        self.u.as_mut_slice().fill(0.0);
        self.r.as_mut_slice().fill(0.0);
        self.invert();
        // Row norms, by columns (A is column-major).
        self.norms.as_mut_slice().fill(0.0);
        for c in 0..a.ncols() {
            for (nm, v) in self.norms.iter_mut().zip(a.column(c).iter()) {
                *nm += v * v;
            }
        }
        for nm in self.norms.iter_mut() {
            *nm = nm.sqrt();
        }
    }

    /// Hot start: the previous active rows (skipping rows nearly dependent on those already
    /// in), then drop negative multipliers.
    fn start_from_warm(&mut self, a: &DMatrix<f64>, b: &DVector<f64>) {
        let (rows, n) = a.shape();
        for w in 0..self.warm.len() {
            let i = self.warm[w];
            if i >= rows || self.active.len() >= n {
                continue;
            }
            self.set_np(a, i);
            self.d.gemv_tr(1.0, &self.j, &self.np, 0.0);
            let q = self.active.len();
            let d2 = self.d.rows(q, n - q).norm();
            // Skip rows (nearly) dependent on those already in.
            if d2 > 1e-9 * self.d.norm() {
                self.add(i);
            }
        }
        self.equality_point(b);
        while let Some(k) = (0..self.active.len())
            .filter(|&k| self.u[k] < 0.0)
            .min_by(|&p, &q| self.u[p].total_cmp(&self.u[q]))
        {
            self.drop(k);
            self.equality_point(b);
        }
    }

    /// The slacks `s = b - A x` and the most violated row by distance (`|a_i|` scaled), if a
    /// row misses by more than the tolerance.
    fn most_violated(
        &mut self,
        a: &DMatrix<f64>,
        b: &DVector<f64>,
        tol: f64,
    ) -> Result<Option<usize>, ActiveSetError> {
        self.s.copy_from(b);
        self.s.gemv(-1.0, a, &self.x, 1.0);
        let mut p = None;
        let mut worst = 0.0;
        for i in 0..a.nrows() {
            let si = self.s[i];
            if !si.is_finite() {
                return Err(ActiveSetError::NonFinite);
            }
            if si < -tol * (1.0 + b[i].abs()) {
                if self.norms[i] == 0.0 {
                    return Err(ActiveSetError::Infeasible { row: i });
                }
                let v = -si / self.norms[i];
                if v > worst {
                    worst = v;
                    p = Some(i);
                }
            }
        }
        Ok(p)
    }

    /// Step 2: move until row `p` holds (it enters the active set) or a multiplier reaches
    /// zero (its row leaves, and the step goes on).
    fn add_violated(
        &mut self,
        a: &DMatrix<f64>,
        b: &DVector<f64>,
        p: usize,
        max_iter: u32,
    ) -> Result<(), ActiveSetError> {
        let n = a.ncols();
        self.set_np(a, p);
        let mut u_p = 0.0;
        loop {
            self.iterations += 1;
            if self.iterations > max_iter {
                return Err(ActiveSetError::IterationLimit(self.iterations));
            }
            let q = self.active.len();
            self.step_direction(q, n);
            let (t1, leave) = self.partial_step(q);
            // Full step: row p holds with equality.
            let zn = self.z.dot(&self.np);
            let sp = b[p] + self.np.dot(&self.x);
            // zn = |d_2|^2: zero when n_p is in the span of the active rows.
            let t2 = if zn > 1e-18 * self.d.norm_squared() { -sp / zn } else { f64::INFINITY };
            if !t1.is_finite() && !t2.is_finite() {
                return Err(ActiveSetError::Infeasible { row: p });
            }
            if !t2.is_finite() {
                // Dual step only.
                for k in 0..q {
                    self.u[k] -= t1 * self.rv[k];
                }
                u_p += t1;
                self.drop(leave);
                continue;
            }
            let t = t1.min(t2);
            self.x.axpy(t, &self.z, 1.0);
            for k in 0..q {
                self.u[k] -= t * self.rv[k];
            }
            u_p += t;
            if t2 <= t1 {
                if q >= n {
                    return Err(ActiveSetError::Infeasible { row: p });
                }
                self.add(p);
                self.u[q] = u_p;
                return Ok(());
            }
            self.drop(leave);
        }
    }

    /// The step's primal and dual directions with `q` active rows: `d = J^T n_p`,
    /// `z = J_2 d_2`, `r = R^{-1} d_1`.
    fn step_direction(&mut self, q: usize, n: usize) {
        self.d.gemv_tr(1.0, &self.j, &self.np, 0.0);
        self.z.as_mut_slice().fill(0.0);
        for k in q..n {
            self.z.axpy(self.d[k], &self.j.column(k), 1.0);
        }
        for k in 0..q {
            self.rv[k] = self.d[k];
        }
        for k in (0..q).rev() {
            self.rv[k] /= self.r[(k, k)];
            let rk = self.rv[k];
            for i in 0..k {
                self.rv[i] -= self.r[(i, k)] * rk;
            }
        }
    }

    /// Partial step: the first multiplier to reach zero along `r`, and its place in the
    /// active set (`t = inf` when none decreases).
    fn partial_step(&self, q: usize) -> (f64, usize) {
        let mut t1 = f64::INFINITY;
        let mut leave = 0;
        for k in 0..q {
            if self.rv[k] > 0.0 {
                let t = self.u[k] / self.rv[k];
                if t < t1 {
                    t1 = t;
                    leave = k;
                }
            }
        }
        (t1, leave)
    }

    /// Size the buffers for `n` variables and `rows` rows; clears the active set and sets
    /// `x = 0`.
    fn size(&mut self, n: usize, rows: usize) {
        if self.l.shape() != (n, n) {
            self.warm.clear();
            self.warm_shape = (0, 0);
        }
        // `l` is copied from `P`; `j` and `r` are written before they are read (hot_answer
        // fills what it uses, the cold path clears `r` and `invert` writes `j`).
        shape(&mut self.l, n, n);
        shape(&mut self.j, n, n);
        shape(&mut self.r, n, n);
        for v in [&mut self.x, &mut self.u, &mut self.d, &mut self.z, &mut self.rv, &mut self.np] {
            zeros_v(v, n);
        }
        zeros_v(&mut self.s, rows);
        zeros_v(&mut self.norms, rows);
        self.active.clear();
        // Room for n rows (the most that can be active); `reserve` counts from the length.
        self.active.reserve(n);
        self.warm.reserve(n.saturating_sub(self.warm.len()));
    }

    /// `J = L^{-T}` into `j` (from `l`).
    fn invert(&mut self) {
        let n = self.l.nrows();
        lower_inverse(self.l.as_slice(), n, self.j.as_mut_slice());
        self.j.transpose_mut();
    }

    /// The fast path of a hot start: the minimum on the previous active rows `W` held with
    /// equality, by the range space (`M = L^{-1} N_W`, `M^T M = L_W L_W^T`,
    /// `u = (M^T M)^{-1} (-b_W)`, `x = L^{-T} M u`), accepted if it is the optimum: every
    /// multiplier non-negative, every row held and the active ones with equality (to `tol`).
    /// No `J` is formed: on a tick whose active rows are the last's, this is the whole solve.
    fn hot_answer(&mut self, a: &DMatrix<f64>, b: &DVector<f64>, tol: f64) -> bool {
        let n = self.l.nrows();
        let q = self.warm.len();
        if q == 0 || q > n || self.warm.iter().any(|&i| i >= b.len()) {
            return false;
        }
        if !self.warm_gram(a, n, q) {
            return false;
        }
        self.warm_multipliers(b, n, q);
        let umax = (0..q).map(|k| self.u[k].abs()).fold(0.0, f64::max);
        if (0..q).any(|k| self.u[k].is_nan() || self.u[k] < -tol * (1.0 + umax)) {
            return false;
        }
        // x = L^{-T} (M u).
        let l = self.l.as_slice();
        let mw = self.j.as_slice();
        self.z.as_mut_slice().fill(0.0);
        for k in 0..q {
            let uk = self.u[k];
            for (z, m) in self.z.iter_mut().zip(&mw[k * n..(k + 1) * n]) {
                *z += uk * m;
            }
        }
        for c in (0..n).rev() {
            let lx = dot(&l[c * n + c + 1..c * n + n], &self.x.as_slice()[c + 1..n]);
            self.x[c] = (self.z[c] - lx) / l[c * n + c];
        }
        self.s.copy_from(b);
        self.s.gemv(-1.0, a, &self.x, 1.0);
        for i in 0..b.len() {
            if self.s[i].is_nan() || self.s[i] < -tol * (1.0 + b[i].abs()) {
                return false;
            }
        }
        if self.warm.iter().any(|&i| self.s[i] > tol * (1.0 + b[i].abs())) {
            return false;
        }
        self.active.clear();
        self.active.extend_from_slice(&self.warm);
        true
    }

    /// `M = L^{-1} N_W` of the warm rows into `j`'s first `q` columns (scratch here: `J` is
    /// formed only if the hot start fails), and the Cholesky factor `L_W` of the Gram matrix
    /// `M^T M` into `r`'s leading q x q block; false when that Gram matrix is singular.
    fn warm_gram(&mut self, a: &DMatrix<f64>, n: usize, q: usize) -> bool {
        // -N_W's columns into `j`, then M = L^{-1} N_W in place.
        let l = self.l.as_slice();
        let mw = self.j.as_mut_slice();
        for (k, &i) in self.warm.iter().enumerate() {
            for (c, y) in mw[k * n..(k + 1) * n].iter_mut().enumerate() {
                *y = -a[(i, c)];
            }
        }
        lower_solve_in_place(l, n, n, mw, n, q);
        // Gram matrix M^T M into `r`'s leading q x q block (one product), then its Cholesky
        // factor.
        let g = self.r.as_mut_slice();
        {
            let m_w = MatRef::from_column_major_slice_with_stride(&mw[..], n, q, n);
            gemm(
                MatMut::from_column_major_slice_with_stride_mut(&mut g[..], q, q, n),
                0.0,
                1.0,
                m_w.transpose(),
                m_w,
            );
        }
        cholesky_in_place(g, n, q, 1e-12).is_some()
    }

    /// The warm rows' multipliers `u`: `L_W L_W^T u = -b_W`, with `L_W` from
    /// [`DualActiveSet::warm_gram`].
    fn warm_multipliers(&mut self, b: &DVector<f64>, n: usize, q: usize) {
        let g = self.r.as_slice();
        for k in 0..q {
            self.u[k] = -b[self.warm[k]];
        }
        for k in 0..q {
            let uk = self.u[k] / g[k * n + k];
            self.u[k] = uk;
            for i in k + 1..q {
                self.u[i] -= uk * g[k * n + i];
            }
        }
        for k in (0..q).rev() {
            let dot: f64 = (k + 1..q).map(|i| g[k * n + i] * self.u[i]).sum();
            self.u[k] = (self.u[k] - dot) / g[k * n + k];
        }
    }

    /// `np = -a_i`.
    fn set_np(&mut self, a: &DMatrix<f64>, i: usize) {
        for (k, v) in self.np.iter_mut().enumerate() {
            *v = -a[(i, k)];
        }
    }

    /// Row `i` enters: `d = J^T n_i` (in `self.d`) rotated to `(d_1, h, 0, ...)` with `J`,
    /// `R`'s new column `(d_1, h)`.
    fn add(&mut self, i: usize) {
        let n = self.j.ncols();
        let q = self.active.len();
        for k in (q + 1..n).rev() {
            if self.d[k] == 0.0 {
                continue;
            }
            let (c, s, h) = givens(self.d[k - 1], self.d[k]);
            self.d[k - 1] = h;
            self.d[k] = 0.0;
            rotate_columns(&mut self.j, k - 1, k, c, s);
        }
        for k in 0..=q {
            self.r[(k, q)] = self.d[k];
        }
        self.active.push(i);
        self.u[q] = 0.0;
    }

    /// Active row number `l` leaves: its column of `R` is removed and the Hessenberg rest
    /// rotated back to triangular, the same rotations applied to `J`.
    fn drop(&mut self, l: usize) {
        let q = self.active.len();
        for k in l..q - 1 {
            for i in 0..=k + 1 {
                self.r[(i, k)] = self.r[(i, k + 1)];
            }
            self.u[k] = self.u[k + 1];
            self.active[k] = self.active[k + 1];
        }
        for i in 0..q {
            self.r[(i, q - 1)] = 0.0;
        }
        self.active.pop();
        self.u[q - 1] = 0.0;
        for k in l..q - 1 {
            let (c, s, h) = givens(self.r[(k, k)], self.r[(k + 1, k)]);
            self.r[(k, k)] = h;
            self.r[(k + 1, k)] = 0.0;
            for col in k + 1..q - 1 {
                let (x, y) = (self.r[(k, col)], self.r[(k + 1, col)]);
                self.r[(k, col)] = c * x + s * y;
                self.r[(k + 1, col)] = -s * x + c * y;
            }
            rotate_columns(&mut self.j, k, k + 1, c, s);
        }
    }

    /// The minimum on the active rows held with equality and its multipliers:
    /// `v = R^{-T} (-b_W)`, `u = R^{-1} v`, `x = J_1 v`.
    fn equality_point(&mut self, b: &DVector<f64>) {
        let q = self.active.len();
        for k in 0..q {
            let mut acc = -b[self.active[k]];
            for i in 0..k {
                acc -= self.r[(i, k)] * self.rv[i];
            }
            self.rv[k] = acc / self.r[(k, k)];
        }
        self.x.as_mut_slice().fill(0.0);
        for k in 0..q {
            self.x.axpy(self.rv[k], &self.j.column(k), 1.0);
        }
        for k in 0..q {
            self.u[k] = self.rv[k];
        }
        for k in (0..q).rev() {
            self.u[k] /= self.r[(k, k)];
            let uk = self.u[k];
            for i in 0..k {
                self.u[i] -= self.r[(i, k)] * uk;
            }
        }
    }

    /// Every row within `tol` and every multiplier non-negative (to `tol` of the largest).
    fn verify(
        &mut self,
        a: &DMatrix<f64>,
        b: &DVector<f64>,
        tol: f64,
    ) -> Result<(), ActiveSetError> {
        self.s.copy_from(b);
        self.s.gemv(-1.0, a, &self.x, 1.0);
        let mut worst: f64 = 0.0;
        for i in 0..b.len() {
            if !self.s[i].is_finite() {
                return Err(ActiveSetError::NonFinite);
            }
            worst = worst.max(-self.s[i] / (1.0 + b[i].abs()));
        }
        let q = self.active.len();
        let umax = (0..q).map(|k| self.u[k].abs()).fold(0.0, f64::max);
        for k in 0..q {
            if !self.u[k].is_finite() {
                return Err(ActiveSetError::NonFinite);
            }
            worst = worst.max(-self.u[k] / (1.0 + umax));
        }
        if worst > tol {
            return Err(ActiveSetError::Inaccurate(worst));
        }
        Ok(())
    }
}
