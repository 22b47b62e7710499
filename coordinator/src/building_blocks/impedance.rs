//! Cartesian impedance in the motion space (eq. control_law, eqn. joint_space_tau_M):
//! `F = mu_c + Lambda_c a_d - K_d edot - K_p e`, `tau_M += J_x^T F`, with the operational-space
//! inertia `Lambda_c = (J_x M_c^{-1} P J_x^T)^{-1}` and non-linear term
//! `mu_c = Lambda_c J_x M_c^{-1} (P h - Pdot v) - Lambda_c Jdot_x v`.
//! Orientation errors are world-frame rotation vectors `log(R R_d^T)`.
//!
//! **Several tasks** (the object, every torso, every swing foot) are superposed in joint space,
//! `tau_M = sum_i J_i^T F_i`, with each task's own gains and reference. `Lambda_c` and `mu_c`
//! are computed once for the stacked task space `x = [x_o; x_t1; x_t2; ...]` ([`TaskStack`]):
//! the paper's eq. control_law with `J_x` the stacked Jacobian, whose wrench's blocks are the
//! tasks' `F_i`. Computing `Lambda_i` and `mu_i` per task instead compensates the non-linear
//! terms (gravity above all) of dynamically coupled tasks (the arm sits on the torso: the
//! object and torso tasks share joints) more than once or not at all; the team then settles
//! off its references by the residual over `K_p`, measured at 4.5 mm on the torsos with the
//! paper's S1 gains. With the stacked terms and tasks that span the motion space (two torsos
//! and the object: 18 = 48 - 24 foot rows - 6 grasp rows) a static team has no such error.

use nalgebra::{DMatrix, DVector, Isometry3, Vector3, Vector6};
use robot_model::spatial::rotation_error;

use crate::building_blocks::block_projection::{GramScratch, TaskSpan};
use crate::building_blocks::projection::Projections;
use crate::linalg::{mat, product, spd_factor, spd_solve_in_place, zeros, zeros_v, Pinv, RANK_TOL};
use crate::ControllerError;

/// Diagonal stiffness and damping of one task (3 or 6 entries).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Gains {
    pub kp: Vec<f64>,
    pub kd: Vec<f64>,
}

impl Gains {
    pub fn new(kp: &[f64], kd: &[f64]) -> Self {
        Gains { kp: kp.to_vec(), kd: kd.to_vec() }
    }

    /// `n` stiffness and `n` damping values, finite and non-negative; the error says which.
    pub fn check(&self, n: usize) -> Result<(), String> {
        if self.kp.len() != n || self.kd.len() != n {
            return Err(format!(
                "needs {n} stiffness and {n} damping values, has {} and {}",
                self.kp.len(),
                self.kd.len()
            ));
        }
        if self.kp.iter().chain(&self.kd).any(|x| !(x.is_finite() && *x >= 0.0)) {
            return Err("gains must be finite and non-negative".into());
        }
        Ok(())
    }
}

/// Per-tick quantities shared by every task: `M_c^{-1} P` (the projections' matrix, or
/// their operator on the block path) and `M_c^{-1} (P h - Pdot v)`.
pub struct MotionSpace<'a> {
    pub proj: &'a Projections,
    pub mcinv_bias: &'a DVector<f64>,
}

/// Task errors: `e` and `edot` (current minus desired), and the desired acceleration. A task
/// has `dim` rows (6 for a pose, 3 for a point); the rest of the entries are unused.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TaskError {
    pub dim: usize,
    pub e: Vector6<f64>,
    pub edot: Vector6<f64>,
    pub acc_d: Vector6<f64>,
}

/// 6-D pose error `[p - p_d; log(R R_d^T)]` and twist error.
pub fn pose_error(
    x: &Isometry3<f64>,
    twist: &Vector6<f64>,
    x_d: &Isometry3<f64>,
    twist_d: &[f64; 6],
    acc_d: &[f64; 6],
) -> TaskError {
    let dp: Vector3<f64> = x.translation.vector - x_d.translation.vector;
    let dr = rotation_error(&x.rotation.to_rotation_matrix(), &x_d.rotation.to_rotation_matrix());
    let e = Vector6::new(dp.x, dp.y, dp.z, dr.x, dr.y, dr.z);
    TaskError {
        dim: 6,
        e,
        edot: twist - Vector6::from_row_slice(twist_d),
        acc_d: Vector6::from_row_slice(acc_d),
    }
}

/// 3-D point error `p - p_d` and velocity error.
pub fn point_error(
    p: &Vector3<f64>,
    vel: &Vector3<f64>,
    p_d: &Vector3<f64>,
    v_d: &[f64; 3],
    a_d: &[f64; 3],
) -> TaskError {
    let pad = |v: Vector3<f64>| Vector6::new(v.x, v.y, v.z, 0.0, 0.0, 0.0);
    TaskError {
        dim: 3,
        e: pad(p - p_d),
        edot: pad(vel - Vector3::from_row_slice(v_d)),
        acc_d: pad(Vector3::from_row_slice(a_d)),
    }
}

/// Which tasks give way when the team's motion yields ([`TaskStack::joint_torque_yielding`],
/// [`crate::pidc::stages::yielding`]): the object's first, then the torsos'; swing feet and
/// free hands are always tracked (a foot in the air must land, a free hand must keep clear).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Yields {
    #[default]
    Never,
    Object,
    Torso,
}

/// How much of their motion the yielding tasks keep, each from 0 (held still: no acceleration
/// commanded, the task's damping bringing it to rest where it is) to 1 (tracked as
/// commanded).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionScale {
    pub object: f64,
    pub torso: f64,
    /// Held still on the contact margins' reserve (the rows with
    /// `ContactMargins::reserve`): nothing else was feasible.
    pub reserve: bool,
}

impl Default for MotionScale {
    fn default() -> Self {
        MotionScale::FULL
    }
}

impl MotionScale {
    /// Every task tracked.
    pub const FULL: MotionScale = MotionScale { object: 1.0, torso: 1.0, reserve: false };

    /// The share of the motion a task of group `g` keeps.
    pub fn of(&self, g: Yields) -> f64 {
        match g {
            Yields::Never => 1.0,
            Yields::Object => self.object,
            Yields::Torso => self.torso,
        }
    }
}

/// A task held still: its velocity error with no target velocity (the measured task velocity)
/// and its feed-forward at no acceleration (the object's weight alone).
#[derive(Debug, Clone, Copy)]
pub struct HoldStill<'a> {
    pub yields: Yields,
    pub velocity: &'a Vector6<f64>,
    pub feed_forward: Option<&'a Vector6<f64>>,
}

/// A task's Jacobian `j_x` (d x n), zero outside the team columns `cols` (first, count), and
/// its drift `Jdot_x v`.
#[derive(Debug, Clone, Copy)]
pub struct TaskJacobian<'a> {
    pub j_x: &'a DMatrix<f64>,
    pub cols: (usize, usize),
    pub jdv_x: &'a DVector<f64>,
}

/// Every task of a tick, stacked (see the module docs), in buffers kept between ticks.
///
/// [`TaskStack::begin`] sizes the stack for the tick's `k` task rows, [`TaskStack::push`]
/// copies each task in, [`TaskStack::joint_torque`] computes `tau_M = J^T F` with `F` of eq.
/// control_law for the stacked task space.
#[derive(Default)]
pub struct TaskStack {
    n: usize,
    at: usize,
    j: DMatrix<f64>,
    jdv: DVector<f64>,
    e: DVector<f64>,
    edot: DVector<f64>,
    acc_d: DVector<f64>,
    kp: DVector<f64>,
    kd: DVector<f64>,
    ff: DVector<f64>,
    /// Each row's task held still ([`HoldStill`]): the velocity error and feed-forward, and
    /// which tasks yield.
    edot_hold: DVector<f64>,
    ff_hold: DVector<f64>,
    yields: Vec<Yields>,
    // Scratch of `joint_torque`.
    j_mcinv_p: DMatrix<f64>,
    gram: GramScratch,
    lambda_inv: DMatrix<f64>,
    /// `Lambda_c` by the pseudo-inverse (dense path, or a Cholesky that failed), else the
    /// Cholesky factor of `Lambda_c^{-1}` in `chol` (`factored`).
    lambda: DMatrix<f64>,
    chol: DMatrix<f64>,
    factored: bool,
    pinv: Pinv,
    /// Each task's rows and the columns its Jacobian is non-zero on: `(row, rows, col, cols)`:
    /// this tick's first `tasks`, then the earlier tasks whose rows `j` still holds as
    /// written (see `begin`; `push` forgets them from the first task that differs).
    spans: Vec<TaskSpan>,
    tasks: usize,
    u: DVector<f64>,
    f: DVector<f64>,
}

impl TaskStack {
    /// Start a tick with `k` task rows in total and `n` team velocities.
    pub fn begin(&mut self, k: usize, n: usize) {
        self.n = n;
        self.at = 0;
        // `j` is kept between ticks of one shape: a task on the same rows and columns as the
        // last tick's writes its columns only (the rest of its rows are zeros already), others
        // clear their rows first (`push`). `joint_torque` refuses a stack with rows unfilled.
        self.tasks = 0;
        if self.j.shape() != (k, n) {
            zeros(&mut self.j, k, n);
            self.spans.clear();
        }
        for v in [
            &mut self.jdv,
            &mut self.e,
            &mut self.edot,
            &mut self.acc_d,
            &mut self.kp,
            &mut self.kd,
            &mut self.ff,
            &mut self.edot_hold,
            &mut self.ff_hold,
        ] {
            zeros_v(v, k);
        }
        self.yields.clear();
        self.yields.resize(k, Yields::Never);
    }

    /// Add a task: Jacobian `j_x` (d x n, `d <= 6`), zero outside the columns `cols` (first,
    /// count: a torso's, a swing foot's or a free hand's are its robot's, the object's span the
    /// grasping robots'), `Jdot_x v`, its errors and gains, and an optional feed-forward wrench
    /// added to its `F` (the object's load).
    pub fn push(
        &mut self,
        j_x: &DMatrix<f64>,
        cols: (usize, usize),
        jdv_x: &DVector<f64>,
        err: &TaskError,
        gains: &Gains,
        feed_forward: Option<&Vector6<f64>>,
    ) -> Result<(), ControllerError> {
        let at = self.at;
        self.push_task(j_x, cols, jdv_x, err, gains, feed_forward)?;
        let d = j_x.nrows();
        self.edot_hold.rows_mut(at, d).copy_from(&err.edot.rows(0, d));
        if let Some(f) = feed_forward {
            self.ff_hold.rows_mut(at, d).copy_from(&f.rows(0, d));
        }
        Ok(())
    }

    /// [`TaskStack::push`] for a task that yields ([`Yields`]) when the motion does, held still
    /// as `hold` says.
    pub fn push_yielding(
        &mut self,
        task: TaskJacobian,
        err: &TaskError,
        gains: &Gains,
        feed_forward: Option<&Vector6<f64>>,
        hold: HoldStill,
    ) -> Result<(), ControllerError> {
        let TaskJacobian { j_x, cols, jdv_x } = task;
        let at = self.at;
        self.push_task(j_x, cols, jdv_x, err, gains, feed_forward)?;
        let d = j_x.nrows();
        self.edot_hold.rows_mut(at, d).copy_from(&hold.velocity.rows(0, d));
        if let Some(f) = hold.feed_forward {
            self.ff_hold.rows_mut(at, d).copy_from(&f.rows(0, d));
        }
        self.yields[at..at + d].fill(hold.yields);
        Ok(())
    }

    fn push_task(
        &mut self,
        j_x: &DMatrix<f64>,
        cols: (usize, usize),
        jdv_x: &DVector<f64>,
        err: &TaskError,
        gains: &Gains,
        feed_forward: Option<&Vector6<f64>>,
    ) -> Result<(), ControllerError> {
        let d = j_x.nrows();
        let (c0, nc) = cols;
        if d > 6
            || j_x.ncols() != self.n
            || c0 + nc > self.n
            || jdv_x.len() != d
            || err.dim != d
            || gains.kp.len() != d
            || gains.kd.len() != d
            || self.at + d > self.j.nrows()
        {
            return Err(ControllerError::Dimension {
                what: "impedance task".into(),
                detail: format!(
                    "{d}-row task with {} columns (non-zero on {c0}..{}), error {}, gains {}/{}, \
                     {} of {} rows used",
                    j_x.ncols(),
                    c0 + nc,
                    err.dim,
                    gains.kp.len(),
                    gains.kd.len(),
                    self.at,
                    self.j.nrows()
                ),
            });
        }
        let at = self.at;
        let span = (at, d, c0, nc);
        if self.spans.get(self.tasks) != Some(&span) {
            // A task unlike the last tick's here: its rows are cleared, and the later spans
            // recorded may describe rows this one overwrote, so they are forgotten (their
            // tasks clear their rows again).
            self.spans.truncate(self.tasks);
            self.j.rows_mut(at, d).fill(0.0);
            self.spans.push(span);
        }
        self.tasks += 1;
        self.j.view_mut((at, c0), (d, nc)).copy_from(&j_x.columns(c0, nc));
        self.jdv.rows_mut(at, d).copy_from(jdv_x);
        self.e.rows_mut(at, d).copy_from(&err.e.rows(0, d));
        self.edot.rows_mut(at, d).copy_from(&err.edot.rows(0, d));
        self.acc_d.rows_mut(at, d).copy_from(&err.acc_d.rows(0, d));
        self.kp.rows_mut(at, d).copy_from_slice(&gains.kp);
        self.kd.rows_mut(at, d).copy_from_slice(&gains.kd);
        if let Some(f) = feed_forward {
            self.ff.rows_mut(at, d).copy_from(&f.rows(0, d));
        }
        self.at += d;
        Ok(())
    }

    /// `tau_M = J^T F` (n) for the stacked tasks, `F = mu_c + Lambda_c a_d - K_d edot - K_p e`
    /// (eq. control_law) plus the feed-forward.
    pub fn joint_torque(
        &mut self,
        ms: &MotionSpace,
        tau_m: &mut DVector<f64>,
    ) -> Result<(), ControllerError> {
        let k = self.j.nrows();
        zeros_v(tau_m, self.n);
        if self.at != k {
            return Err(ControllerError::Dimension {
                what: "impedance tasks".into(),
                detail: format!("{} of {k} task rows filled", self.at),
            });
        }
        if k == 0 {
            return Ok(());
        }
        self.lambda_c(ms.proj)?;
        self.torque_at(ms, MotionScale::FULL, tau_m);
        Ok(())
    }

    /// `tau_M` of the same tasks with the yielding ones keeping `scale` of their motion: a
    /// task at share `s` commands `s (a_d - K_d edot - K_p e) - (1 - s) K_d v` (with `v` its
    /// velocity, [`HoldStill`]) and its feed-forward blended likewise; `mu_c` stays whole.
    /// Linear in each share. Call after [`TaskStack::joint_torque`] of the same tick (it
    /// reuses that call's `Lambda_c`).
    pub fn joint_torque_yielding(
        &mut self,
        ms: &MotionSpace,
        scale: MotionScale,
        tau_m: &mut DVector<f64>,
    ) {
        zeros_v(tau_m, self.n);
        if self.j.nrows() > 0 && self.at == self.j.nrows() {
            self.torque_at(ms, scale, tau_m);
        }
    }

    /// `tau_M` into the zeroed `tau_m`, `Lambda_c` computed.
    fn torque_at(&mut self, ms: &MotionSpace, scale: MotionScale, tau_m: &mut DVector<f64>) {
        let k = self.j.nrows();
        // u = J M_c^{-1} (P h - Pdot v) - Jdot v + s a_d; F = Lambda u - K_d edot - K_p e + ff.
        zeros_v(&mut self.u, k);
        for i in 0..k {
            self.u[i] = scale.of(self.yields[i]) * self.acc_d[i] - self.jdv[i];
        }
        for &(r0, d, c0, nc) in &self.spans[..self.tasks] {
            self.u.rows_mut(r0, d).gemv(
                1.0,
                &self.j.view((r0, c0), (d, nc)),
                &ms.mcinv_bias.rows(c0, nc),
                1.0,
            );
        }
        zeros_v(&mut self.f, k);
        if self.factored {
            self.f.copy_from(&self.u);
            spd_solve_in_place(&self.chol, self.f.as_mut_slice());
        } else {
            self.f.gemv(1.0, &self.lambda, &self.u, 0.0);
        }
        for i in 0..k {
            let s = scale.of(self.yields[i]);
            let (edot, ff) = (
                s * self.edot[i] + (1.0 - s) * self.edot_hold[i],
                s * self.ff[i] + (1.0 - s) * self.ff_hold[i],
            );
            self.f[i] += ff - self.kd[i] * edot - s * self.kp[i] * self.e[i];
        }
        for &(r0, d, c0, nc) in &self.spans[..self.tasks] {
            tau_m.rows_mut(c0, nc).gemv_tr(
                1.0,
                &self.j.view((r0, c0), (d, nc)),
                &self.f.rows(r0, d),
                1.0,
            );
        }
    }

    /// `Lambda_c = (J M_c^{-1} P J^T)^+` (eq. control_law): into `lambda`, or factored. Dense
    /// path: the projections' `M_c^{-1} P` and an SVD (the oracle). Block path:
    /// `J M_c^{-1} P J^T` by the robots' blocks and the grasp's coupling
    /// ([`crate::building_blocks::block_projection::BlockFactors::task_gram`]), and the Cholesky
    /// factor of
    /// the result when its pivots pass [`crate::linalg::SPD_TOL`] (the pseudo-inverse is then the
    /// inverse, applied by two triangular solves), the SVD otherwise.
    fn lambda_c(&mut self, proj: &Projections) -> Result<(), ControllerError> {
        let singular = || ControllerError::Singular { what: "operational-space inertia".into() };
        self.factored = false;
        if !proj.by_blocks {
            product(&mut self.j_mcinv_p, mat(&self.j), mat(&proj.mcinv_p));
            product(&mut self.lambda_inv, mat(&self.j_mcinv_p), mat(&self.j).transpose());
            self.pinv
                .compute(mat(&self.lambda_inv), RANK_TOL, &mut self.lambda)
                .ok_or_else(singular)?;
            return Ok(());
        }
        proj.blocks.task_gram(
            mat(&self.j),
            &self.spans[..self.tasks],
            &mut self.lambda_inv,
            &mut self.gram,
        );
        if spd_factor(mat(&self.lambda_inv), &mut self.chol).is_some() {
            self.factored = true;
            return Ok(());
        }
        self.pinv
            .compute(mat(&self.lambda_inv), RANK_TOL, &mut self.lambda)
            .ok_or_else(singular)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `d`-row task on columns `cols` of 10 (entries `seed + i + j / 10`, zero elsewhere).
    fn task(d: usize, cols: (usize, usize), seed: f64) -> DMatrix<f64> {
        DMatrix::from_fn(d, 10, |i, j| {
            if (cols.0..cols.0 + cols.1).contains(&j) {
                seed + i as f64 + j as f64 / 10.0
            } else {
                0.0
            }
        })
    }

    fn push_all(stack: &mut TaskStack, tasks: &[(usize, (usize, usize), f64)]) {
        let k = tasks.iter().map(|t| t.0).sum();
        stack.begin(k, 10);
        for &(d, cols, seed) in tasks {
            let err = TaskError {
                dim: d,
                e: Vector6::zeros(),
                edot: Vector6::zeros(),
                acc_d: Vector6::zeros(),
            };
            let gains = Gains::new(&vec![1.0; d], &vec![1.0; d]);
            stack
                .push(&task(d, cols, seed), cols, &DVector::zeros(d), &err, &gains, None)
                .expect("task");
        }
    }

    #[test]
    fn a_reused_stack_holds_exactly_its_tasks_rows() {
        // The same shape (18 x 10) three times; the middle tick's third task covers the rows
        // of the first tick's third and fourth. The third tick (the first again) must not
        // keep anything of the second's.
        let first = [(6, (0, 5), 1.0), (6, (5, 5), 2.0), (3, (0, 5), 3.0), (3, (5, 5), 4.0)];
        let middle = [(6, (0, 5), 1.0), (6, (5, 5), 2.0), (6, (0, 5), 5.0)];
        let mut stack = TaskStack::default();
        for tick in [&first[..], &middle[..], &first[..]] {
            push_all(&mut stack, tick);
            let mut fresh = TaskStack::default();
            push_all(&mut fresh, tick);
            assert_eq!(stack.j, fresh.j);
        }
        // A task with more than six rows is refused (the stack's products assume six at most).
        stack.begin(7, 10);
        let err = TaskError {
            dim: 7,
            e: Vector6::zeros(),
            edot: Vector6::zeros(),
            acc_d: Vector6::zeros(),
        };
        assert!(stack
            .push(
                &DMatrix::zeros(7, 10),
                (0, 10),
                &DVector::zeros(7),
                &err,
                &Gains::new(&[1.0; 7], &[1.0; 7]),
                None
            )
            .is_err());
    }
}
