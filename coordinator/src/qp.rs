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

/// What a contact's rows need.
#[derive(Debug, Clone)]
pub enum ContactKind {
    /// Point foot: friction coefficient.
    Foot { mu: f64, f_min: f64 },
    /// Flat hand: frame axes (world), friction, torsional coefficient, patch half-sizes,
    /// minimum normal force.
    Hand { tx: Vector3<f64>, ty: Vector3<f64>, n: Vector3<f64>, mu: f64, xi: f64, half: [f64; 2], f_min: f64 },
}

/// Rows `c . lambda_k >= lo` of one contact (3 or 6 columns).
pub fn contact_rows(kind: &ContactKind) -> Vec<(Vec<f64>, f64)> {
    match kind {
        ContactKind::Foot { mu, f_min } => vec![
            (vec![-1.0, 0.0, *mu], 0.0),
            (vec![1.0, 0.0, *mu], 0.0),
            (vec![0.0, -1.0, *mu], 0.0),
            (vec![0.0, 1.0, *mu], 0.0),
            (vec![0.0, 0.0, 1.0], *f_min),
        ],
        ContactKind::Hand { tx, ty, n, mu, xi, half, f_min } => {
            let row = |f: Vector3<f64>, m: Vector3<f64>| vec![f.x, f.y, f.z, m.x, m.y, m.z];
            let z = Vector3::zeros();
            vec![
                // friction pyramid on f_n = -n.f
                (row(-*mu * n - tx, z), 0.0),
                (row(-*mu * n + tx, z), 0.0),
                (row(-*mu * n - ty, z), 0.0),
                (row(-*mu * n + ty, z), 0.0),
                (row(-n, z), *f_min),
                // torsion |n.m| <= xi f_n
                (row(-*xi * n, -n), 0.0),
                (row(-*xi * n, *n), 0.0),
                // tilt: |t_x.m| <= delta_y f_n, |t_y.m| <= delta_x f_n (physical pairing)
                (row(-half[1] * n, -tx), 0.0),
                (row(-half[1] * n, *tx), 0.0),
                (row(-half[0] * n, -ty), 0.0),
                (row(-half[0] * n, *ty), 0.0),
            ]
        }
    }
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
    /// Try [`dense_ipm`] first (Clarabel if it does not converge).
    pub dense_first: bool,
}

/// The QP's outcome.
#[derive(Debug, Clone)]
pub struct QpOutcome {
    pub status: QpStatus,
    pub iterations: u32,
    pub f: DVector<f64>,
    pub solve_us: f64,
    pub setup_us: f64,
    pub rows: usize,
    /// Which solver produced the answer: "dense-ipm" or "clarabel".
    pub solver: &'static str,
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

/// The constraint matrix `A F <= b` of the QP (friction, moments, torque limits).
pub fn constraints(inp: &QpInput) -> (DMatrix<f64>, DVector<f64>) {
    let m = inp.rho.ncols();
    let mut rows_a: Vec<DVector<f64>> = Vec::new();
    let mut rows_b: Vec<f64> = Vec::new();
    for (start, kind) in inp.contacts {
        let d = match kind {
            ContactKind::Foot { .. } => 3,
            ContactKind::Hand { .. } => 6,
        };
        let rho_k = inp.rho.rows(*start, d);
        let eta_k = inp.eta.rows(*start, d);
        for (c, lo) in contact_rows(kind) {
            let c = DVector::from_vec(c);
            // c.(rho F + eta) >= lo  <=>  -(c^T rho) F <= c.eta - lo
            rows_a.push(-(rho_k.transpose() * &c));
            rows_b.push(c.dot(&eta_k) - lo);
        }
    }
    let nc = rows_a.len();
    let l = inp.actuated.len();
    let mut a = DMatrix::zeros(nc + 2 * l, m);
    let mut b = DVector::zeros(nc + 2 * l);
    for (i, (r, bi)) in rows_a.iter().zip(&rows_b).enumerate() {
        a.row_mut(i).copy_from(&r.transpose());
        b[i] = *bi;
    }
    for (k, (&j, &lim)) in inp.actuated.iter().zip(inp.limits).enumerate() {
        let xi = inp.y.row(j);
        a.row_mut(nc + 2 * k).copy_from(&xi);
        b[nc + 2 * k] = lim - inp.tau0[j];
        a.row_mut(nc + 2 * k + 1).copy_from(&(-xi));
        b[nc + 2 * k + 1] = lim + inp.tau0[j];
    }
    (a, b)
}

/// `H = Y^T Y + eps I`: the objective `F^T H F` of eq. wrench_optim2, regularised.
fn objective(inp: &QpInput) -> DMatrix<f64> {
    let mut h = inp.y.transpose() * inp.y;
    for i in 0..h.nrows() {
        h[(i, i)] += inp.regularisation;
    }
    h
}

/// Solve the QP. Never panics; a solver error is a `NumericalError` status with `F = 0`.
pub fn solve(inp: &QpInput, max_iter: u32) -> QpOutcome {
    let t0 = Instant::now();
    let m = inp.rho.ncols();
    // Clarabel minimises 1/2 x^T P x: P = 2 H.
    let h = objective(inp) * 2.0;
    let (a, b) = constraints(inp);
    let rows = a.nrows();
    if inp.dense_first && b.iter().all(|x| x.is_finite()) && h.iter().all(|x| x.is_finite()) && a.iter().all(|x| x.is_finite()) {
        if let Some((x, it, reduced)) = dense_ipm(&h, &a, &b, max_iter, DENSE_TOL) {
            let us = t0.elapsed().as_secs_f64() * 1e6;
            let status = if reduced { QpStatus::AlmostSolved } else { QpStatus::Solved };
            return QpOutcome { status, iterations: it, f: x, solve_us: us, setup_us: 0.0, rows, solver: "dense-ipm" };
        }
    }
    let p = to_csc(&h, true);
    let a_csc = to_csc(&a, false);
    let q = vec![0.0; m];
    let cones = [NonnegativeConeT(rows)];
    let settings = DefaultSettings::<f64> { verbose: false, max_iter, presolve_enable: false, ..DefaultSettings::default() };
    let setup_start = Instant::now();
    let fail = |status| QpOutcome { status, iterations: 0, f: DVector::zeros(m), solve_us: 0.0, setup_us: 0.0, rows, solver: "clarabel" };
    if !b.iter().all(|x| x.is_finite()) || !h.iter().all(|x| x.is_finite()) || !a.iter().all(|x| x.is_finite()) {
        return fail(QpStatus::NumericalError);
    }
    let Ok(mut solver) = DefaultSolver::new(&p, &q, &a_csc, b.as_slice(), &cones, settings) else {
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
    let f = DVector::from_column_slice(&sol.x);
    let f = if f.iter().all(|x| x.is_finite()) { f } else { DVector::zeros(m) };
    QpOutcome { status, iterations: sol.iterations, f, solve_us: t0.elapsed().as_secs_f64() * 1e6, setup_us, rows, solver: "clarabel" }
}

/// Relative tolerance of [`dense_ipm`] on the QP (residuals and complementarity). At 1e-8 the
/// dual residual stalled at round-off on 12 % of S1's ticks (the normal equations' condition
/// grows as complementarity vanishes) and Clarabel had to finish them; 1e-7 is a torque error
/// of about 1e-5 N m.
pub const DENSE_TOL: f64 = 1e-7;

/// Relative tolerance of a reduced-accuracy (AlmostSolved) answer of [`dense_ipm`].
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
/// second per tick). Returns `F` and the largest violation, or `None` if a solve fails.
pub fn solve_least_violation(inp: &QpInput, max_iter: u32) -> Option<(DVector<f64>, f64)> {
    let m = inp.rho.ncols();
    let (a, b) = constraints(inp);
    let h = objective(inp);
    if !(b.iter().all(|x| x.is_finite()) && a.iter().all(|x| x.is_finite()) && h.iter().all(|x| x.is_finite())) {
        return None;
    }
    let cost = |f: &DVector<f64>| f.dot(&(&h * f)) + VIOLATION_WEIGHT * (&a * f - &b).iter().map(|v| v.max(0.0).powi(2)).sum::<f64>();
    let mut f = DVector::zeros(m);
    let mut best = (cost(&f), f.clone());
    let mut active: Vec<usize> = Vec::new();
    for _ in 0..max_iter.max(30) {
        let r = &a * &f - &b;
        let now: Vec<usize> = (0..r.len()).filter(|&i| r[i] > 0.0).collect();
        if !active.is_empty() && now == active {
            break;
        }
        active = now;
        let mut k = h.clone();
        let mut rhs = DVector::zeros(m);
        for &i in &active {
            let ai = a.row(i);
            k += VIOLATION_WEIGHT * ai.transpose() * ai;
            rhs += VIOLATION_WEIGHT * b[i] * ai.transpose();
        }
        f = k.cholesky()?.solve(&rhs);
        let c = cost(&f);
        if c < best.0 {
            best = (c, f.clone());
        }
        if active.is_empty() {
            break;
        }
    }
    let f = best.1;
    let worst = (&a * &f - &b).iter().copied().fold(0.0, f64::max);
    Some((f, worst))
}

/// A dense primal-dual interior-point method (Mehrotra predictor-corrector, normal equations
/// `P + A^T (Z/S) A` by Cholesky) for `min 1/2 x^T P x  s.t.  A x <= b`: the QP is small and
/// dense, where Clarabel's sparse LDL of the (n + m)-sized KKT system is slow. Returns
/// `(x, iterations)` only when it converged to the tolerances; otherwise the caller runs
/// Clarabel (which also certifies infeasibility).
///
/// Like Clarabel, it reports reduced accuracy: when the iterations run out with every residual
/// within `REDUCED_TOL` (the dual residual can stall at round-off once complementarity has
/// vanished), it returns the iterate with `reduced = true` (status AlmostSolved).
pub fn dense_ipm(p: &DMatrix<f64>, a: &DMatrix<f64>, b: &DVector<f64>, max_iter: u32, tol: f64) -> Option<(DVector<f64>, u32, bool)> {
    let (m, n) = a.shape();
    let mut x = DVector::zeros(n);
    let mut s = DVector::from_fn(m, |i, _| b[i].max(1.0));
    let mut z = DVector::from_element(m, 1.0);
    let at = a.transpose();
    let bnorm = 1.0 + b.amax();
    let mut wa = a.clone();
    for it in 0..max_iter {
        let px = p * &x;
        let atz = &at * &z;
        let rd = &px + &atz;
        let rp = a * &x + &s - b;
        let mu = s.dot(&z) / m as f64;
        // Dual residual relative to its terms' size (as Clarabel does): `A^T z` can be large
        // (stiff contact rows), and `P x + A^T z` then stalls at round-off of that size.
        let dscale = 1.0 + px.amax().max(atz.amax());
        if rp.amax() <= tol * bnorm && rd.amax() <= tol * dscale && mu <= tol * bnorm {
            return Some((x, it, false));
        }
        if it + 1 == max_iter {
            let ok = rp.amax() <= REDUCED_TOL * bnorm && rd.amax() <= REDUCED_TOL * dscale && mu <= REDUCED_TOL * bnorm;
            return ok.then_some((x, it, true));
        }
        if std::env::var_os("COORD_IPM_DEBUG").is_some() {
            eprintln!("ipm {it}: rp {:.2e} rd {:.2e} mu {:.2e}", rp.amax(), rd.amax(), mu);
        }
        // K = P + A^T W A, W = z / s.
        for i in 0..m {
            let w = z[i] / s[i];
            for j in 0..n {
                wa[(i, j)] = a[(i, j)] * w;
            }
        }
        let mut k = p + &at * &wa;
        let reg = 1e-12 * k.diagonal().amax();
        for i in 0..n {
            k[(i, i)] += reg;
        }
        let chol = k.cholesky()?;
        let solve = |rc: &DVector<f64>| {
            // dz = S^{-1}(-rc + Z (rp + A dx)); K dx = -rd - A^T S^{-1}(-rc + Z rp)
            let t = DVector::from_fn(m, |i, _| (-rc[i] + z[i] * rp[i]) / s[i]);
            let dx = chol.solve(&(-&rd - &at * &t));
            let adx = a * &dx;
            let ds = DVector::from_fn(m, |i, _| -rp[i] - adx[i]);
            let dz = DVector::from_fn(m, |i, _| (-rc[i] - z[i] * ds[i]) / s[i]);
            (dx, ds, dz)
        };
        let step = |ds: &DVector<f64>, dz: &DVector<f64>| {
            let mut alpha: f64 = 1.0;
            for i in 0..m {
                if ds[i] < 0.0 {
                    alpha = alpha.min(-s[i] / ds[i]);
                }
                if dz[i] < 0.0 {
                    alpha = alpha.min(-z[i] / dz[i]);
                }
            }
            alpha
        };
        let rc_aff = s.component_mul(&z);
        let (_, ds_a, dz_a) = solve(&rc_aff);
        let alpha_a = step(&ds_a, &dz_a);
        let mu_aff = (&s + alpha_a * &ds_a).dot(&(&z + alpha_a * &dz_a)) / m as f64;
        let sigma = (mu_aff / mu).powi(3).clamp(0.0, 1.0);
        let rc = DVector::from_fn(m, |i, _| s[i] * z[i] + ds_a[i] * dz_a[i] - sigma * mu);
        let (dx, ds, dz) = solve(&rc);
        let alpha = (0.99 * step(&ds, &dz)).min(1.0);
        x += alpha * dx;
        s += alpha * ds;
        z += alpha * dz;
        if !(x.iter().all(|v| v.is_finite()) && s.iter().all(|v| v.is_finite() && *v > 0.0) && z.iter().all(|v| v.is_finite() && *v > 0.0)) {
            return None;
        }
    }
    None
}
