//! The team torque of eq. ua_solution, `tau = [P S]^+ P tau_M + B (I - P) tau_C` with
//! `(I - P) tau_C = J_c^T F_c`: the motion part `tau_0` ([`motion_torque`]), `F_c` when the
//! QP fails ([`fallback`]), and the sum `tau = tau_0 + Y F_c`, `Y = B J_c^T` ([`compose`]).
//!
//! **Fallback.** When the QP is infeasible or fails (status other than Solved/AlmostSolved)
//! while `tau_0` asks more of some joint than its limit, the QP is first solved again with
//! `tau_0` saturated ([`saturate`]; the caller does it). If it still fails, `F_c` comes from
//! the least-violation relaxation ([`qp::solve_least_violation`]: every row softened by a
//! heavily penalised slack), which keeps the squeeze and the friction rows as
//! far as they can be kept; if even that fails, `F_c = 0` (plain projected inverse dynamics
//! `tau = [P S]^+ P tau_M`). Either way the torques are clamped to the limits. The
//! diagnostics keep the QP's status; `TickReport::fallback` says what was done. (`F_c = 0`
//! drops the internal wrench, hence the squeeze: one infeasible tick lost the object.)

use nalgebra::{DMatrix, DVector};
use protocol::QpStatus;

use crate::building_blocks::block_projection::OpScratch;
use crate::building_blocks::projection::Projections;
use crate::linalg::zeros_v;
use crate::qp::{self, QpInput, QpWorkspace};
use crate::ControllerError;

/// Scratch of [`motion_torque`].
#[derive(Debug, Clone, Default)]
pub struct MotionTorqueScratch {
    /// `P tau_M`.
    p_tau_m: DVector<f64>,
    px: DVector<f64>,
    ops: OpScratch,
}

/// `tau_0 = [P S]^+ P tau_M` (n), the first term of eq. ua_solution (`s_diag`: `S`).
pub fn motion_torque(
    proj: &Projections,
    s_diag: &DVector<f64>,
    tau_m: &DVector<f64>,
    tau0: &mut DVector<f64>,
    s: &mut MotionTorqueScratch,
) {
    proj.p_times(tau_m, &mut s.p_tau_m, &mut s.ops);
    proj.ps_pinv_times(&s.p_tau_m, s_diag, tau0, &mut s.px, &mut s.ops);
}

/// Saturate `tau_0` at the torque limits; whether any entry was over.
pub fn saturate(tau0: &mut DVector<f64>, actuated: &[usize], limits: &[f64]) -> bool {
    let mut any = false;
    for (&j, &lim) in actuated.iter().zip(limits) {
        if tau0[j].abs() > lim {
            tau0[j] = tau0[j].clamp(-lim, lim);
            any = true;
        }
    }
    any
}

/// After a QP that ended with `status` (on a `tau_0` that was `saturated` first, or not):
/// `None` when it was solved on the unsaturated `tau_0`; otherwise what was done, and `F_c`
/// (into `f_c`) from the QP, the least-violation relaxation or zero when that fails too.
pub fn fallback(
    ws: &mut QpWorkspace,
    input: &QpInput,
    max_iter: u32,
    status: QpStatus,
    saturated: bool,
    f_c: &mut DVector<f64>,
) -> Option<String> {
    let motion = if saturated { "tau_0 saturated at the limits" } else { "tau_0" };
    match status {
        QpStatus::Solved | QpStatus::AlmostSolved if !saturated => None,
        QpStatus::Solved | QpStatus::AlmostSolved => {
            Some(format!("QP failed on tau_0 over the torque limits: solved with {motion}"))
        }
        s => match qp::solve_least_violation(ws, input, max_iter, f_c) {
            Some(worst) => Some(format!(
                concat!(
                    "QP {s:?}: least-violation F_c on {motion} (worst row violated by ",
                    "{worst:.3}), torques clamped to the limits"
                ),
                s = s,
                motion = motion,
                worst = worst
            )),
            None => {
                f_c.fill(0.0);
                Some(format!("QP {s:?}: F_c = 0, tau = {motion} clamped to the torque limits"))
            }
        },
    }
}

/// Torque limits to clamp to: the actuated joints' team indices and their limits.
#[derive(Debug, Clone, Copy)]
pub struct Clamp<'a> {
    pub actuated: &'a [usize],
    pub limits: &'a [f64],
}

/// `tau = tau_0 + Y F_c` (n), clamped to `clamp` when given (after a fallback, whose `F_c` does
/// not keep the torque limits). An error when a torque is not finite.
pub fn compose(
    tau0: &DVector<f64>,
    y: &DMatrix<f64>,
    f_c: &DVector<f64>,
    clamp: Option<Clamp>,
    tau: &mut DVector<f64>,
) -> Result<(), ControllerError> {
    zeros_v(tau, tau0.len());
    tau.copy_from(tau0);
    tau.gemv(1.0, y, f_c, 1.0);
    if let Some(c) = clamp {
        saturate(tau, c.actuated, c.limits);
    }
    if !tau.iter().all(|x| x.is_finite()) {
        return Err(ControllerError::NonFinite { robot: "team".into(), what: "torque".into() });
    }
    Ok(())
}
