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

use nalgebra::{DMatrix, DVector, Isometry3, Vector3};

use crate::linalg::{pinv, rotation_error, RANK_TOL};
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
            return Err(format!("needs {n} stiffness and {n} damping values, has {} and {}", self.kp.len(), self.kd.len()));
        }
        if self.kp.iter().chain(&self.kd).any(|x| !(x.is_finite() && *x >= 0.0)) {
            return Err("gains must be finite and non-negative".into());
        }
        Ok(())
    }
}

/// Per-tick quantities shared by every task: `M_c^{-1} P` and `M_c^{-1} (P h - Pdot v)`.
pub struct MotionSpace<'a> {
    pub mcinv_p: &'a DMatrix<f64>,
    pub mcinv_bias: &'a DVector<f64>,
}

/// Task errors: `e` and `edot` (current minus desired), and the desired acceleration.
pub struct TaskError {
    pub e: DVector<f64>,
    pub edot: DVector<f64>,
    pub acc_d: DVector<f64>,
}

/// 6-D pose error `[p - p_d; log(R R_d^T)]` and twist error.
pub fn pose_error(x: &Isometry3<f64>, twist: &DVector<f64>, x_d: &Isometry3<f64>, twist_d: &[f64; 6], acc_d: &[f64; 6]) -> TaskError {
    let dp: Vector3<f64> = x.translation.vector - x_d.translation.vector;
    let dr = rotation_error(&x.rotation.to_rotation_matrix(), &x_d.rotation.to_rotation_matrix());
    let e = DVector::from_iterator(6, dp.iter().chain(dr.iter()).cloned());
    let edot = DVector::from_iterator(6, (0..6).map(|i| twist[i] - twist_d[i]));
    TaskError { e, edot, acc_d: DVector::from_row_slice(acc_d) }
}

/// Task wrench `F` of eq. control_law for Jacobian `j_x` (k x n) with `Jdot_x v`.
pub fn task_wrench(
    j_x: &DMatrix<f64>,
    jdv_x: &DVector<f64>,
    ms: &MotionSpace,
    err: &TaskError,
    gains: &Gains,
) -> Result<DVector<f64>, ControllerError> {
    let k = j_x.nrows();
    if gains.kp.len() != k || gains.kd.len() != k || err.e.len() != k || err.edot.len() != k || err.acc_d.len() != k {
        return Err(ControllerError::Dimension { what: "impedance task".into(), detail: format!("{k}-D task with gains {}/{}", gains.kp.len(), gains.kd.len()) });
    }
    let lambda_inv = j_x * ms.mcinv_p * j_x.transpose();
    let (lambda, _) = pinv(&lambda_inv, RANK_TOL).ok_or_else(|| ControllerError::Singular { what: "operational-space inertia".into() })?;
    let mu = &lambda * (j_x * ms.mcinv_bias - jdv_x);
    let mut f = mu + &lambda * &err.acc_d;
    for i in 0..k {
        f[i] -= gains.kd[i] * err.edot[i] + gains.kp[i] * err.e[i];
    }
    Ok(f)
}

/// Every task of a tick, stacked (see the module docs).
#[derive(Default)]
pub struct TaskStack {
    rows: Vec<(DMatrix<f64>, DVector<f64>, TaskError, Gains, Option<DVector<f64>>)>,
}

impl TaskStack {
    pub fn with_capacity(n: usize) -> Self {
        TaskStack { rows: Vec::with_capacity(n) }
    }

    /// Add a task: Jacobian `j_x`, `Jdot_x v`, its errors and gains, and an optional
    /// feed-forward wrench added to its `F` (the object's load).
    pub fn push(&mut self, j_x: &DMatrix<f64>, jdv_x: &DVector<f64>, err: &TaskError, gains: &Gains, feed_forward: Option<DVector<f64>>) {
        self.rows.push((j_x.clone(), jdv_x.clone(), TaskError { e: err.e.clone(), edot: err.edot.clone(), acc_d: err.acc_d.clone() }, gains.clone(), feed_forward));
    }

    /// `tau_M = J^T F` (n) for the stacked tasks.
    pub fn joint_torque(&self, ms: &MotionSpace, n: usize) -> Result<DVector<f64>, ControllerError> {
        let k: usize = self.rows.iter().map(|r| r.0.nrows()).sum();
        if k == 0 {
            return Ok(DVector::zeros(n));
        }
        let mut j = DMatrix::zeros(k, n);
        let mut jdv = DVector::zeros(k);
        let mut err = TaskError { e: DVector::zeros(k), edot: DVector::zeros(k), acc_d: DVector::zeros(k) };
        let mut gains = Gains { kp: Vec::with_capacity(k), kd: Vec::with_capacity(k) };
        let mut ff = DVector::zeros(k);
        let mut at = 0;
        for (jx, jdvx, e, g, f) in &self.rows {
            let d = jx.nrows();
            if jx.ncols() != n || jdvx.len() != d || e.e.len() != d || g.kp.len() != d || g.kd.len() != d || f.as_ref().is_some_and(|f| f.len() != d) {
                return Err(ControllerError::Dimension { what: "impedance task".into(), detail: format!("{d}-row task with {} columns, gains {}/{}", jx.ncols(), g.kp.len(), g.kd.len()) });
            }
            j.rows_mut(at, d).copy_from(jx);
            jdv.rows_mut(at, d).copy_from(jdvx);
            err.e.rows_mut(at, d).copy_from(&e.e);
            err.edot.rows_mut(at, d).copy_from(&e.edot);
            err.acc_d.rows_mut(at, d).copy_from(&e.acc_d);
            gains.kp.extend(&g.kp);
            gains.kd.extend(&g.kd);
            if let Some(f) = f {
                ff.rows_mut(at, d).copy_from(f);
            }
            at += d;
        }
        let f = task_wrench(&j, &jdv, ms, &err, &gains)? + ff;
        Ok(j.transpose() * f)
    }
}
