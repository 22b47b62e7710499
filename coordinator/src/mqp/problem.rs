//! The MQP as one QP over the whole team (the paper's section "Controller Comparison",
//! after Bouyarmane et al. 2019): decision variable `x = [qdd (n); lambda (m); tau (na)]`,
//!
//! `min 1/2 x^T P x + q^T x` with `P = 2 sum_t w_t J_t^T J_t + 2 diag(eps)`,
//! `q = -2 sum_t w_t J_t^T (xdd_ref,t - Jdot_t v)` (the weighted task accelerations plus a
//! small regularisation), subject to, in Clarabel's form `A x + s = b`:
//!
//! * zero cone (equalities):
//!   - dynamics of every robot, `(M + J_o^T M_o J_o) qdd - J_c^T lambda - S^T tau = -h - J_o^T c_o`
//!     (eq. js_dynamics with the object's load, see [`super::object`]);
//!   - contact kinematics `J_c qdd = -Jdot_c v` (eq. jacobian_c: stance feet and the grasp
//!     `J_c,ee`; the grasp rows' right side is `N Jdot_c,ee v`, its part in the range of
//!     `J_c,ee = N J_ee`, so the rank-deficient rows stay consistent);
//!   - the grasp wrench is internal, `G lambda_ee = 0` (its part along `G^T` does no work
//!     through `J_c,ee^T` and would otherwise be free in the contact rows);
//! * non-negative cone (inequalities):
//!   - friction pyramids, minimum normal forces, hands' sliding and torsion in one cone and
//!     centre of pressure
//!     ([`crate::qp::contact_rows`], eqns. unilateral_and_friction_cone_constraint and
//!     moment_constraint) on the real wrenches (hands: `lambda_ee + G^+ F_x`);
//!   - torque limits `|tau_j| <= tau_max,j` (eq. original_torque_limit);
//!   - joint acceleration and velocity limits as bounds on `qdd_j`:
//!     `max(-a_max, (-v_max - v_j)/dt) <= qdd_j <= min(a_max, (v_max - v_j)/dt)`.
//!
//! [`MqpProblem::assemble`] writes dense matrices kept between ticks, then their CSC forms
//! (Clarabel's input) into kept buffers.

use clarabel::algebra::CscMatrix;
use nalgebra::{DMatrix, DVector};

use crate::building_blocks::grasp::GraspTerms;
use crate::linalg::{zeros, zeros_v};
use crate::mqp::object::ObjectTerms;
use crate::mqp::tasks::TaskRows;
use crate::mqp::MqpConfig;
use crate::qp::{contact_rows, ContactKind};
use crate::team::Team;

/// Where each block of `x` starts.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Layout {
    /// Team velocities, contact rows (`3 nf + 6 B`), actuated joints.
    pub n: usize,
    pub m: usize,
    pub na: usize,
    /// Rows of the zero cone (equalities) and of the non-negative cone.
    pub eq: usize,
    pub ineq: usize,
}

impl Layout {
    pub fn vars(&self) -> usize {
        self.n + self.m + self.na
    }
    pub fn lambda(&self) -> usize {
        self.n
    }
    pub fn tau(&self) -> usize {
        self.n + self.m
    }
}

/// What [`MqpProblem::assemble`] reads.
pub struct ProblemInput<'a> {
    pub team: &'a Team,
    pub grasp: Option<&'a GraspTerms>,
    /// `J_c` (m x n) and `Jdot_c v` (m) with the grasp rows' right side in the range of `N`.
    pub j_c: &'a DMatrix<f64>,
    pub jdv_c: &'a DVector<f64>,
    pub object: &'a ObjectTerms,
    pub tasks: &'a TaskRows,
    pub contacts: &'a [(usize, ContactKind)],
    pub actuated: &'a [usize],
    pub limits: &'a [f64],
    pub config: &'a MqpConfig,
}

/// The QP of one tick, dense and in CSC.
#[derive(Debug, Clone)]
pub struct MqpProblem {
    pub layout: Layout,
    pub p: DMatrix<f64>,
    pub q: DVector<f64>,
    pub a: DMatrix<f64>,
    pub b: DVector<f64>,
    /// Upper triangle of `P`, and `A`, in CSC.
    pub p_csc: CscMatrix<f64>,
    pub a_csc: CscMatrix<f64>,
    /// Scratch: `W J` of the tasks.
    wj: DMatrix<f64>,
}

impl Default for MqpProblem {
    fn default() -> Self {
        let empty = || CscMatrix::new(0, 0, vec![0], Vec::new(), Vec::new());
        MqpProblem {
            layout: Layout::default(),
            p: DMatrix::zeros(0, 0),
            q: DVector::zeros(0),
            a: DMatrix::zeros(0, 0),
            b: DVector::zeros(0),
            p_csc: empty(),
            a_csc: empty(),
            wj: DMatrix::zeros(0, 0),
        }
    }
}

/// Rows of the non-negative cone of a contact set.
fn contact_constraint_rows(contacts: &[(usize, ContactKind)]) -> usize {
    contacts.iter().map(|(_, k)| contact_rows(k).len()).sum()
}

impl MqpProblem {
    /// Assemble the tick's QP (see the module docs).
    pub fn assemble(&mut self, inp: &ProblemInput) {
        let (n, m, na) = (inp.team.n, inp.j_c.nrows(), inp.actuated.len());
        let grasp_rows = if inp.grasp.is_some() { 6 } else { 0 };
        let eq = n + m + grasp_rows;
        let ineq = contact_constraint_rows(inp.contacts) + 2 * na + 2 * na;
        self.layout = Layout { n, m, na, eq, ineq };
        let nx = self.layout.vars();
        zeros(&mut self.p, nx, nx);
        zeros_v(&mut self.q, nx);
        zeros(&mut self.a, eq + ineq, nx);
        zeros_v(&mut self.b, eq + ineq);
        self.objective(inp);
        self.equalities(inp);
        let mut row = eq;
        row = self.contact_constraints(inp, row);
        self.joint_limits(inp, row);
        csc_into(&self.p, true, &mut self.p_csc);
        csc_into(&self.a, false, &mut self.a_csc);
    }

    /// `P = 2 J^T W J + 2 diag(eps)`, `q = -2 J^T W rhs`.
    fn objective(&mut self, inp: &ProblemInput) {
        let t = inp.tasks;
        let Layout { n, m, na, .. } = self.layout;
        zeros(&mut self.wj, t.j.nrows(), n);
        self.wj.copy_from(&t.j);
        for i in 0..t.j.nrows() {
            self.wj.row_mut(i).scale_mut(2.0 * t.weight[i]);
        }
        let mut pqq = self.p.view_mut((0, 0), (n, n));
        pqq.gemm_tr(1.0, &t.j, &self.wj, 0.0);
        let mut qq = self.q.rows_mut(0, n);
        qq.gemv_tr(-1.0, &self.wj, &t.rhs, 0.0);
        let c = inp.config;
        for (range, eps) in [
            (0..n, c.regularisation_qdd),
            (n..n + m, c.regularisation_lambda),
            (n + m..n + m + na, c.regularisation_tau),
        ] {
            for i in range {
                self.p[(i, i)] += 2.0 * eps;
            }
        }
    }

    /// Dynamics, contact kinematics and the internal grasp wrench (the zero cone).
    fn equalities(&mut self, inp: &ProblemInput) {
        let Layout { n, m, .. } = self.layout;
        let (team, o) = (inp.team, inp.object);
        // (M + J_o^T M_o J_o) qdd - J_c^T lambda - S^T tau = -(h + J_o^T c_o)   (eq. js_dynamics)
        let mut dq = self.a.view_mut((0, 0), (n, n));
        dq.copy_from(&team.mass);
        dq += &o.mass;
        self.a.view_mut((0, n), (n, m)).tr_copy_from(inp.j_c);
        self.a.view_mut((0, n), (n, m)).neg_mut();
        for (k, &j) in inp.actuated.iter().enumerate() {
            self.a[(j, n + m + k)] = -1.0;
        }
        for i in 0..n {
            self.b[i] = -(team.bias[i] + o.bias[i]);
        }
        // J_c qdd = -Jdot_c v   (eq. jacobian_c)
        self.a.view_mut((n, 0), (m, n)).copy_from(inp.j_c);
        for i in 0..m {
            self.b[n + i] = -inp.jdv_c[i];
        }
        // G lambda_ee = 0: the grasp wrench is internal.
        if let Some(g) = inp.grasp {
            let first = n + 3 * team.feet.len();
            self.a.view_mut((n + m, first), (6, g.g.ncols())).copy_from(&g.g);
        }
    }

    /// Every contact's rows `c . w >= lo` as `-c . w <= -lo`, `w` the real wrench; returns the
    /// next free row.
    fn contact_constraints(&mut self, inp: &ProblemInput, mut row: usize) -> usize {
        let Layout { n, .. } = self.layout;
        let hands_first = 3 * inp.team.feet.len();
        for (offset, kind) in inp.contacts {
            let rows = contact_rows(kind);
            for (c, lo) in rows.iter() {
                self.b[row] = -lo;
                for (i, ci) in c.iter().enumerate() {
                    self.a[(row, n + offset + i)] = -ci;
                }
                if let ContactKind::Hand { .. } = kind {
                    // w = lambda_ee - (G^+ M_o J_o) qdd - G^+ c_o (see super::object).
                    let h = offset - hands_first;
                    for (i, ci) in c.iter().enumerate() {
                        for j in 0..n {
                            self.a[(row, j)] += ci * inp.object.hand_qdd[(h + i, j)];
                        }
                        self.b[row] -= ci * inp.object.hand_const[h + i];
                    }
                }
                row += 1;
            }
        }
        row
    }

    /// Torque limits and the bounds on `qdd` of actuated joints.
    fn joint_limits(&mut self, inp: &ProblemInput, mut row: usize) {
        let Layout { n, m, .. } = self.layout;
        let c = inp.config;
        for (k, &lim) in inp.limits.iter().enumerate() {
            for sign in [1.0, -1.0] {
                self.a[(row, n + m + k)] = sign;
                self.b[row] = lim;
                row += 1;
            }
        }
        for &j in inp.actuated {
            let (lo, hi) = acceleration_bounds(
                inp.team.velocity[j],
                c.joint_acceleration_limit,
                c.joint_velocity_limit,
                c.dt,
            );
            self.a[(row, j)] = 1.0;
            self.b[row] = hi;
            self.a[(row + 1, j)] = -1.0;
            self.b[row + 1] = -lo;
            row += 2;
        }
    }
}

/// `[lo, hi]` of `qdd_j`: `|qdd| <= a_max` and `|v + dt qdd| <= v_max`. A joint already faster
/// than the velocity limit may decelerate harder than `a_max` (the bounds never cross).
pub fn acceleration_bounds(v: f64, a_max: f64, v_max: f64, dt: f64) -> (f64, f64) {
    let lo = (-a_max).max((-v_max - v) / dt);
    let hi = a_max.min((v_max - v) / dt);
    if lo <= hi {
        (lo, hi)
    } else {
        (lo.min(hi), lo.max(hi))
    }
}

/// A dense matrix into CSC `out` (the upper triangle only if `triu`), reusing its buffers.
pub fn csc_into(a: &DMatrix<f64>, triu: bool, out: &mut CscMatrix<f64>) {
    let (rows, cols) = a.shape();
    out.m = rows;
    out.n = cols;
    out.colptr.clear();
    out.rowval.clear();
    out.nzval.clear();
    out.colptr.push(0);
    for j in 0..cols {
        let end = if triu { (j + 1).min(rows) } else { rows };
        for (i, &x) in a.column(j).iter().enumerate().take(end) {
            if x != 0.0 {
                out.rowval.push(i);
                out.nzval.push(x);
            }
        }
        out.colptr.push(out.rowval.len());
    }
}
