//! Cartesian impedance in the motion space (eq. control_law, eqn. joint_space_tau_M):
//! `F = mu_c + Lambda_c a_d - K_d edot - K_p e`, `tau_M += J_x^T F`, with the operational-space
//! inertia `Lambda_c = (J_x M_c^{-1} P J_x^T)^{-1}` and non-linear term
//! `mu_c = Lambda_c J_x M_c^{-1} (P h - Pdot v) - Lambda_c Jdot_x v`.
//! Orientation errors are world-frame rotation vectors `log(R R_d^T)`.

use nalgebra::{DMatrix, DVector, Isometry3, Vector3};

use crate::linalg::{pinv, rotation_error, RANK_TOL};
use crate::ControllerError;

/// Diagonal stiffness and damping of one task (3 or 6 entries).
#[derive(Debug, Clone, PartialEq)]
pub struct Gains {
    pub kp: Vec<f64>,
    pub kd: Vec<f64>,
}

impl Gains {
    pub fn new(kp: &[f64], kd: &[f64]) -> Self {
        Gains { kp: kp.to_vec(), kd: kd.to_vec() }
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
