//! The contact-force QP (eq. wrench_optim2) solved with Clarabel:
//!
//! ```text
//! min_F  F^T (J_c B^T B J_c^T + eps I) F
//! s.t.   C_k (rho F + eta)_k >= d_k     friction pyramid + unilateral (eqn. unilateral_and_friction_cone_constraint)
//!                                       and hand moments (eqn. moment_constraint), per contact k
//!        tau_min - tau_0 <= Xi F <= tau_max - tau_0     (eq. real_torque_limit, Xi = S_ns^T B J_c^T)
//! ```
//!
//! where `lambda = rho F + eta` (eq. relation_between_lambda_and_Fc) are the predicted real
//! contact wrenches ON the robots (world-aligned, at the contact frame origins; for hands the
//! offset of the object load is already in `eta`, see `controller.rs`).
//!
//! Sign conventions of the constraint rows (all in the contact's own frame):
//! * feet: `n = e_z` (world), `f_z >= f_min`, `|f_x|, |f_y| <= mu f_z` (ground pushes up).
//!   Feet and hands have their own `f_min` (a hand's is the squeeze it keeps at least).
//! * hands: `hand_contact` +z `n` is the palm's OUTWARD normal, pointing into the object; the
//!   object pushes the palm back, so the force on the robot has `n . f <= 0`. With the normal
//!   force `f_n = -n . f >= f_min`: `|t_x . f|, |t_y . f| <= mu f_n`, `|n . m| <= xi f_n`,
//!   and the tilt moments — physically correct pairing, which DEVIATES from the paper's
//!   matrix in eqn. moment_constraint (it pairs delta_x with m_x): a centre of pressure at
//!   `(p_x, p_y)` in the patch gives `m_x = p_y f_z`, `m_y = -p_x f_z`, so
//!   `|t_x . m| <= delta_y f_n` and `|t_y . m| <= delta_x f_n`.

use std::time::Instant;

use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettings, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus};
use nalgebra::{DMatrix, DVector, Vector3};
use protocol::QpStatus;

use crate::linalg::{add_product, mat, product, zeros, zeros_v};

/// What a contact's rows need.
#[derive(Debug, Clone, Copy)]
pub enum ContactKind {
    /// Point foot: friction coefficient.
    Foot { mu: f64, f_min: f64 },
    /// Flat hand: frame axes (world), friction, torsional coefficient, patch half-sizes,
    /// minimum normal force.
    Hand { tx: Vector3<f64>, ty: Vector3<f64>, n: Vector3<f64>, mu: f64, xi: f64, half: [f64; 2], f_min: f64 },
}

impl ContactKind {
    /// Rows of the contact's wrench in `lambda`: 3 for a foot, 6 for a hand.
    pub fn dim(&self) -> usize {
        match self {
            ContactKind::Foot { .. } => 3,
            ContactKind::Hand { .. } => 6,
        }
    }
}

/// Most constraint rows of one contact (a hand's 11).
pub const MAX_CONTACT_ROWS: usize = 11;

/// The rows `c . lambda_k >= lo` of one contact, `c` with [`ContactKind::dim`] entries.
#[derive(Debug, Clone, Copy)]
pub struct ContactRows {
    dim: usize,
    len: usize,
    rows: [([f64; 6], f64); MAX_CONTACT_ROWS],
}

impl ContactRows {
    fn new(dim: usize) -> Self {
        ContactRows { dim, len: 0, rows: [([0.0; 6], 0.0); MAX_CONTACT_ROWS] }
    }

    fn push(&mut self, c: [f64; 6], lo: f64) {
        self.rows[self.len] = (c, lo);
        self.len += 1;
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Each row's `c` (its first `dim` entries) and `lo`.
    pub fn iter(&self) -> impl Iterator<Item = (&[f64], f64)> + '_ {
        self.rows[..self.len].iter().map(move |(c, lo)| (&c[..self.dim], *lo))
    }
}

/// Rows `c . lambda_k >= lo` of one contact (3 or 6 columns).
pub fn contact_rows(kind: &ContactKind) -> ContactRows {
    let mut rows = ContactRows::new(kind.dim());
    match kind {
        ContactKind::Foot { mu, f_min } => {
            let row = |x: f64, y: f64, z: f64| [x, y, z, 0.0, 0.0, 0.0];
            rows.push(row(-1.0, 0.0, *mu), 0.0);
            rows.push(row(1.0, 0.0, *mu), 0.0);
            rows.push(row(0.0, -1.0, *mu), 0.0);
            rows.push(row(0.0, 1.0, *mu), 0.0);
            rows.push(row(0.0, 0.0, 1.0), *f_min);
        }
        ContactKind::Hand { tx, ty, n, mu, xi, half, f_min } => {
            let row = |f: Vector3<f64>, m: Vector3<f64>| [f.x, f.y, f.z, m.x, m.y, m.z];
            let z = Vector3::zeros();
            // friction pyramid on f_n = -n.f
            rows.push(row(-*mu * n - tx, z), 0.0);
            rows.push(row(-*mu * n + tx, z), 0.0);
            rows.push(row(-*mu * n - ty, z), 0.0);
            rows.push(row(-*mu * n + ty, z), 0.0);
            rows.push(row(-n, z), *f_min);
            // torsion |n.m| <= xi f_n
            rows.push(row(-*xi * n, -n), 0.0);
            rows.push(row(-*xi * n, *n), 0.0);
            // tilt: |t_x.m| <= delta_y f_n, |t_y.m| <= delta_x f_n (physical pairing)
            rows.push(row(-half[1] * n, -tx), 0.0);
            rows.push(row(-half[1] * n, *tx), 0.0);
            rows.push(row(-half[0] * n, -ty), 0.0);
            rows.push(row(-half[0] * n, *ty), 0.0);
        }
    }
    rows
}

/// The QP's data.
pub struct QpInput<'a> {
    /// `Y = B J_c^T` (n x m): `tau_C = Y F`.
    pub y: &'a DMatrix<f64>,
    pub rho: &'a DMatrix<f64>,
    /// `eta` including the object-load offset on the hand rows.
    pub eta: &'a DVector<f64>,
    /// Contacts with their first row in lambda, in lambda order.
    pub contacts: &'a [(usize, ContactKind)],
    /// Team indices of the actuated joints and their symmetric limits.
    pub actuated: &'a [usize],
    pub limits: &'a [f64],
    /// `tau_0 = [P S]^+ P tau_M`.
    pub tau0: &'a DVector<f64>,
    pub regularisation: f64,
    /// Try [`DenseIpm`] first (Clarabel if it does not converge).
    pub dense_first: bool,
}

/// The QP's outcome (the forces are written to the caller's vector).
#[derive(Debug, Clone, Copy)]
pub struct QpOutcome {
    pub status: QpStatus,
    pub iterations: u32,
    pub solve_us: f64,
    pub setup_us: f64,
    pub rows: usize,
    /// Which solver produced the answer: "dense-ipm" or "clarabel".
    pub solver: &'static str,
}

impl Default for QpOutcome {
    fn default() -> Self {
        QpOutcome { status: QpStatus::NotRun, iterations: 0, solve_us: 0.0, setup_us: 0.0, rows: 0, solver: "none" }
    }
}

/// The QP's matrices and its solvers' scratch, kept between ticks.
#[derive(Default)]
pub struct QpWorkspace {
    /// Objective `H` (m x m), `2 H`, constraints `A F <= b`.
    h: DMatrix<f64>,
    p: DMatrix<f64>,
    a: DMatrix<f64>,
    b: DVector<f64>,
    ipm: DenseIpm,
    // Scratch of the least-violation fallback.
    lv_k: DMatrix<f64>,
    lv_rhs: DVector<f64>,
    lv_r: DVector<f64>,
    lv_hf: DVector<f64>,
    lv_best: DVector<f64>,
    lv_active: Vec<bool>,
    lv_now: Vec<bool>,
}

/// Dense column-major matrix to Clarabel's CSC, keeping only the upper triangle if `triu`.
fn to_csc(a: &DMatrix<f64>, triu: bool) -> CscMatrix<f64> {
    let (m, n) = a.shape();
    let mut colptr = Vec::with_capacity(n + 1);
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    colptr.push(0);
    for j in 0..n {
        let end = if triu { (j + 1).min(m) } else { m };
        for i in 0..end {
            let x = a[(i, j)];
            if x != 0.0 {
                rowval.push(i);
                nzval.push(x);
            }
        }
        colptr.push(rowval.len());
    }
    CscMatrix::new(m, n, colptr, rowval, nzval)
}

/// The constraint matrix `A F <= b` of the QP (friction, moments, torque limits), into `a`
/// and `b`.
pub fn constraints_into(inp: &QpInput, a: &mut DMatrix<f64>, b: &mut DVector<f64>) {
    let m = inp.rho.ncols();
    let nc: usize = inp.contacts.iter().map(|(_, k)| contact_rows(k).len()).sum();
    let l = inp.actuated.len();
    zeros(a, nc + 2 * l, m);
    zeros_v(b, nc + 2 * l);
    let mut i = 0;
    for (start, kind) in inp.contacts {
        for (c, lo) in contact_rows(kind).iter() {
            // c.(rho F + eta) >= lo  <=>  -(c^T rho) F <= c.eta - lo
            let mut ce = 0.0;
            for (r, cr) in c.iter().enumerate() {
                if *cr != 0.0 {
                    for j in 0..m {
                        a[(i, j)] -= cr * inp.rho[(start + r, j)];
                    }
                    ce += cr * inp.eta[start + r];
                }
            }
            b[i] = ce - lo;
            i += 1;
        }
    }
    for (k, (&j, &lim)) in inp.actuated.iter().zip(inp.limits).enumerate() {
        let xi = inp.y.row(j);
        a.row_mut(nc + 2 * k).copy_from(&xi);
        b[nc + 2 * k] = lim - inp.tau0[j];
        for j in 0..m {
            a[(nc + 2 * k + 1, j)] = -xi[j];
        }
        b[nc + 2 * k + 1] = lim + inp.tau0[j];
    }
}

/// `H = Y^T Y + eps I`: the objective `F^T H F` of eq. wrench_optim2, regularised.
fn objective_into(inp: &QpInput, h: &mut DMatrix<f64>) {
    product(h, mat(inp.y).transpose(), mat(inp.y));
    for i in 0..h.nrows() {
        h[(i, i)] += inp.regularisation;
    }
}

fn all_finite<'a>(xs: impl IntoIterator<Item = &'a f64>) -> bool {
    xs.into_iter().all(|x| x.is_finite())
}

/// Solve the QP into `f` (length m). Never panics; a solver error is a `NumericalError`
/// status with `F = 0`.
///
/// The dense interior-point method runs in `ws` and allocates nothing once the team's shape
/// is set; Clarabel, when it has to finish a tick, builds its problem anew (it allocates).
pub fn solve(ws: &mut QpWorkspace, inp: &QpInput, max_iter: u32, f: &mut DVector<f64>) -> QpOutcome {
    let t0 = Instant::now();
    let m = inp.rho.ncols();
    zeros_v(f, m);
    objective_into(inp, &mut ws.h);
    // Both solvers minimise 1/2 x^T P x: P = 2 H.
    zeros(&mut ws.p, m, m);
    ws.p.copy_from(&ws.h);
    ws.p *= 2.0;
    constraints_into(inp, &mut ws.a, &mut ws.b);
    let rows = ws.a.nrows();
    let finite = all_finite(ws.b.iter()) && all_finite(ws.p.iter()) && all_finite(ws.a.iter());
    if inp.dense_first && finite {
        let pairs_from = rows - 2 * inp.actuated.len();
        if let Some((it, reduced)) = ws.ipm.solve(&ws.p, &ws.a, &ws.b, pairs_from, max_iter, DENSE_TOL) {
            f.copy_from(&ws.ipm.x);
            let us = t0.elapsed().as_secs_f64() * 1e6;
            let status = if reduced { QpStatus::AlmostSolved } else { QpStatus::Solved };
            return QpOutcome { status, iterations: it, solve_us: us, setup_us: 0.0, rows, solver: "dense-ipm" };
        }
    }
    let fail = |status| QpOutcome { status, iterations: 0, solve_us: 0.0, setup_us: 0.0, rows, solver: "clarabel" };
    if !finite {
        return fail(QpStatus::NumericalError);
    }
    let p = to_csc(&ws.p, true);
    let a_csc = to_csc(&ws.a, false);
    let q = vec![0.0; m];
    let cones = [NonnegativeConeT(rows)];
    let settings = DefaultSettings::<f64> { verbose: false, max_iter, presolve_enable: false, ..DefaultSettings::default() };
    let setup_start = Instant::now();
    let Ok(mut solver) = DefaultSolver::new(&p, &q, &a_csc, ws.b.as_slice(), &cones, settings) else {
        return fail(QpStatus::NumericalError);
    };
    let setup_us = setup_start.elapsed().as_secs_f64() * 1e6;
    solver.solve();
    let sol = &solver.solution;
    let status = match sol.status {
        SolverStatus::Solved => QpStatus::Solved,
        SolverStatus::AlmostSolved => QpStatus::AlmostSolved,
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible | SolverStatus::DualInfeasible | SolverStatus::AlmostDualInfeasible => QpStatus::Infeasible,
        SolverStatus::MaxIterations | SolverStatus::MaxTime => QpStatus::MaxIterations,
        _ => QpStatus::NumericalError,
    };
    if sol.x.len() == m && all_finite(sol.x.iter()) {
        f.copy_from_slice(&sol.x);
    }
    QpOutcome { status, iterations: sol.iterations, solve_us: t0.elapsed().as_secs_f64() * 1e6, setup_us, rows, solver: "clarabel" }
}

/// Relative tolerance of [`DenseIpm`] on the QP (residuals and complementarity). At 1e-8 the
/// dual residual stalled at round-off on 12 % of S1's ticks (the normal equations' condition
/// grows as complementarity vanishes) and Clarabel had to finish them; 1e-7 is a torque error
/// of about 1e-5 N m.
pub const DENSE_TOL: f64 = 1e-7;

/// Relative tolerance of a reduced-accuracy (AlmostSolved) answer of [`DenseIpm`].
pub const REDUCED_TOL: f64 = 1e-5;

/// Price of a violated row in [`solve_least_violation`] (per N^2 of violation, against the
/// torque objective in (N m)^2).
pub const VIOLATION_WEIGHT: f64 = 1e6;

/// The fallback when the QP is infeasible: every row `A F <= b` may be violated at a price,
/// `min F^T H F + w sum_i max(0, a_i F - b_i)^2`. Always solvable; it keeps what can be kept
/// (above all the hands' squeeze) instead of dropping every contact force. Solved by the
/// active-set Newton method of this piecewise quadratic: with the violated rows `V`,
/// `(H + w A_V^T A_V) F = w A_V^T b_V`, until `V` repeats (a few 36 x 36 solves; a first
/// version put a slack per row into the interior-point method, 170 variables, and took a
/// second per tick). Writes `F` into `f` and returns the largest violation, or `None` if a
/// solve fails. It builds `H`, `A` and `b` into `ws` itself (as [`solve`] does), so it does
/// not depend on what ran before; on this rare path that is cheap next to its solves.
pub fn solve_least_violation(ws: &mut QpWorkspace, inp: &QpInput, max_iter: u32, f: &mut DVector<f64>) -> Option<f64> {
    let m = inp.rho.ncols();
    objective_into(inp, &mut ws.h);
    constraints_into(inp, &mut ws.a, &mut ws.b);
    let QpWorkspace { h, a, b, lv_k, lv_rhs, lv_r, lv_hf, lv_best, lv_active, lv_now, .. } = ws;
    if !(all_finite(b.iter()) && all_finite(a.iter()) && all_finite(h.iter())) {
        return None;
    }
    let rows = a.nrows();
    // Cost of F; leaves the residual A F - b in `r`.
    let cost = |f: &DVector<f64>, r: &mut DVector<f64>, hf: &mut DVector<f64>| {
        r.copy_from(b);
        r.gemv(1.0, a, f, -1.0);
        hf.gemv(1.0, h, f, 0.0);
        f.dot(hf) + VIOLATION_WEIGHT * r.iter().map(|v| v.max(0.0).powi(2)).sum::<f64>()
    };
    zeros_v(f, m);
    zeros_v(lv_r, rows);
    zeros_v(lv_hf, m);
    zeros_v(lv_rhs, m);
    zeros_v(lv_best, m);
    let mut best = cost(f, lv_r, lv_hf);
    lv_active.clear();
    lv_active.resize(rows, false);
    let mut first = true;
    for _ in 0..max_iter.max(30) {
        lv_now.clear();
        lv_now.extend(lv_r.iter().map(|r| *r > 0.0));
        let any = lv_now.iter().any(|x| *x);
        if !first && lv_now == lv_active {
            break;
        }
        first = false;
        std::mem::swap(lv_active, lv_now);
        zeros(lv_k, m, m);
        lv_k.copy_from(h);
        lv_rhs.fill(0.0);
        for i in (0..rows).filter(|&i| lv_active[i]) {
            let ai = a.row(i);
            lv_k.ger(VIOLATION_WEIGHT, &ai.transpose(), &ai.transpose(), 1.0);
            lv_rhs.axpy(VIOLATION_WEIGHT * b[i], &ai.transpose(), 1.0);
        }
        let k = std::mem::replace(lv_k, DMatrix::zeros(0, 0));
        let chol = k.cholesky()?;
        f.copy_from(lv_rhs);
        chol.solve_mut(f);
        *lv_k = chol.unpack_dirty();
        let c = cost(f, lv_r, lv_hf);
        if c < best {
            best = c;
            lv_best.copy_from(f);
        }
        if !any {
            break;
        }
    }
    f.copy_from(lv_best);
    cost(f, lv_r, lv_hf);
    Some(lv_r.iter().copied().fold(0.0, f64::max))
}

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

impl DenseIpm {
    /// Solve into [`DenseIpm::x`]. Returns the iterations only when it converged to the
    /// tolerances; otherwise the caller runs Clarabel (which also certifies infeasibility).
    ///
    /// Like Clarabel, it reports reduced accuracy: when the iterations run out with every
    /// residual within `REDUCED_TOL` (the dual residual can stall at round-off once
    /// complementarity has vanished), it returns the iterate with `reduced = true` (status
    /// AlmostSolved).
    ///
    /// Rows from `pairs_from` on come in pairs `(a, -a)` (two-sided bounds, the torque limits):
    /// their terms of `A^T W A` are `(w_+ + w_-) a a^T`, so the normal matrix is formed from
    /// one row per pair (a third fewer rows for the paper's QP).
    pub fn solve(&mut self, p: &DMatrix<f64>, a: &DMatrix<f64>, b: &DVector<f64>, pairs_from: usize, max_iter: u32, tol: f64) -> Option<(u32, bool)> {
        let (m, n) = a.shape();
        let pairs_from = pairs_from.min(m);
        let pairs = (m - pairs_from) / 2;
        if pairs_from + 2 * pairs != m {
            return None;
        }
        let reduced = pairs_from + pairs;
        for v in [&mut self.x, &mut self.px, &mut self.atz, &mut self.rd, &mut self.dx] {
            zeros_v(v, n);
        }
        for v in [&mut self.s, &mut self.z, &mut self.rp, &mut self.rc, &mut self.t, &mut self.adx, &mut self.ds, &mut self.dz] {
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
        let bnorm = 1.0 + b.amax();
        for it in 0..max_iter {
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
            let (rp_n, rd_n) = (self.rp.amax(), self.rd.amax());
            if rp_n <= tol * bnorm && rd_n <= tol * dscale && mu <= tol * bnorm {
                return Some((it, false));
            }
            if it + 1 == max_iter {
                let ok = rp_n <= REDUCED_TOL * bnorm && rd_n <= REDUCED_TOL * dscale && mu <= REDUCED_TOL * bnorm;
                return ok.then_some((it, true));
            }
            // K = P + A^T W A, W = z / s, with each pair's weights summed on its one row.
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
            let k = std::mem::replace(&mut self.k, DMatrix::zeros(0, 0));
            let chol = k.cholesky()?;
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
            if !(all_finite(self.x.iter()) && self.s.iter().all(|v| v.is_finite() && *v > 0.0) && self.z.iter().all(|v| v.is_finite() && *v > 0.0)) {
                return None;
            }
        }
        None
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
