//! [`TickReport`]: what one PIDC tick computed, kept for tests and reports, and the tick's
//! outputs written from it (each robot's torque slice, the tick's diagnostics); the matrices
//! a tick forms only where it reads them ([`ContactMatrices`], the controller's workspace);
//! and a tick with every matrix formed ([`MaterializedTick`]).

use std::ops::{Deref, DerefMut};

use nalgebra::{DMatrix, DVector, Vector6};
use protocol::{DynamicsTerms, TickDiagnostics, TorqueCommand};

use crate::building_blocks::grasp::GraspTerms;
use crate::building_blocks::impedance::MotionScale;
use crate::building_blocks::projection::Projections;
use crate::controller_shell::report::{
    diagnostics_into, tick_note, torque_commands_into, TickOutputs,
};
use crate::qp::{self, ContactKind};
use crate::team::Team;

/// What the last tick computed (kept for tests and reports): every field is written on every
/// tick, none holds an earlier tick's value. Its buffers are overwritten in place by the next
/// tick, so a tick allocates nothing once the team's shape is set (see
/// [`super::Pidc::compute`]); the matrices a tick forms only on some paths are the
/// workspace's ([`ContactMatrices`]).
#[derive(Debug, Clone, Default)]
pub struct TickReport {
    pub team: Team,
    pub grasp: Option<GraspTerms>,
    /// `Jdot_c v` (eq. jacobian_c).
    pub jdv_c: DVector<f64>,
    /// `J_c v`: the constraints' velocity, which a held contact keeps at zero (its norm is the
    /// diagnostics' `constraint_residual`).
    pub jc_v: DVector<f64>,
    pub proj: Projections,
    /// Motion torque `tau_M` and `tau_0 = [P S]^+ P tau_M`.
    pub tau_m: DVector<f64>,
    pub tau0: DVector<f64>,
    /// `J_x^T F_x`: the object's load on the robots (n).
    pub load: DVector<f64>,
    /// `F_x` at the object centre.
    pub f_x: Vector6<f64>,
    /// `F_c`: zero on a tick the QP's hot start by the robots' blocks answered
    /// (`qp.solver == "blocks"`, [`qp::BlockHotStart`]), which does not form it;
    /// [`super::Pidc::materialized`] forms one.
    pub f_c: DVector<f64>,
    /// `eta` of eq. relation_between_lambda_and_Fc (without the hand-load offset).
    pub eta: DVector<f64>,
    /// `lambda = rho F_c + eta`, and the real contact wrenches (hand rows + `G^+ F_x`).
    pub lambda: DVector<f64>,
    pub lambda_real: DVector<f64>,
    /// Full team torque (n) and the QP pieces.
    pub tau: DVector<f64>,
    /// The team's generalized accelerations under `tau`, the held object a rigid body on the
    /// hands (n, eq. aghili_25; `crate::pidc::stages::acceleration`): written only by ticks
    /// that keep them (`TeamController::keep_accelerations`), stale otherwise.
    pub qdd: DVector<f64>,
    pub contacts: Vec<(usize, ContactKind)>,
    pub limits: Vec<f64>,
    pub actuated: Vec<usize>,
    pub qp: qp::QpOutcome,
    /// Why the hot start by the robots' blocks did not answer this tick (`None` when it did
    /// or was not tried).
    pub blocks_declined: Option<qp::Decline>,
    pub fallback: Option<String>,
    /// `tau0` was saturated at the torque limits after the QP failed on it (it is then no
    /// longer `[P S]^+ P tau_M`; see [`super::stages::torque`]).
    pub saturated: bool,
    /// How much of their motion the object's and the torsos' tasks kept: less than whole when
    /// the QP was infeasible at the tick's motion and the motion yielded
    /// ([`super::stages::yielding`]).
    pub motion: MotionScale,
    /// Why the hands are free while the contact sets hold the object
    /// ([`crate::building_blocks::release`]); `None` while the grasp holds.
    pub release: Option<String>,
    /// The team let go on this tick: its diagnostics name the release (its tick and cause)
    /// rather than the fallback the tick took, so that a release followed by fallbacks is
    /// still on record.
    pub released_now: bool,
    pub timing: Timing,
}

/// The contact map's matrices, formed on the ticks that read them and kept between ticks (part
/// of the controller's workspace, not of the tick's result): `J_c` (eq. jacobian_c; the dense
/// projections and the team-sized QP read it, `j_c_formed` says whether this tick formed it),
/// `Y = B J_c^T` and `rho` (eq. relation_between_lambda_and_Fc; not formed on a tick the hot
/// start by the robots' blocks answered). [`super::Pidc::materialized`] forms all three.
#[derive(Debug, Clone, Default)]
pub struct ContactMatrices {
    pub j_c: DMatrix<f64>,
    pub j_c_formed: bool,
    pub y: DMatrix<f64>,
    pub rho: DMatrix<f64>,
}

/// The last tick with every matrix formed ([`super::Pidc::materialized`], for tests and
/// reports; it allocates): the tick's report (its projections materialized; on a tick answered
/// by the robots' blocks, the least-norm `F_c` with `tau = tau_0 + Y F_c`), and `J_c`, `Y`,
/// `rho` of that tick. Reads as a [`TickReport`] too.
#[derive(Debug, Clone)]
pub struct MaterializedTick {
    pub report: TickReport,
    pub j_c: DMatrix<f64>,
    pub y: DMatrix<f64>,
    pub rho: DMatrix<f64>,
}

impl Deref for MaterializedTick {
    type Target = TickReport;

    fn deref(&self) -> &TickReport {
        &self.report
    }
}

impl DerefMut for MaterializedTick {
    fn deref_mut(&mut self) -> &mut TickReport {
        &mut self.report
    }
}

/// Where the time of a tick went, µs.
#[derive(Debug, Clone, Default)]
pub struct Timing {
    pub assembly_us: f64,
    pub projections_us: f64,
    pub impedance_us: f64,
    pub qp_build_us: f64,
    pub qp_us: f64,
    pub total_us: f64,
}

impl TickReport {
    /// Each robot's torque slice (its actuated rows of `tau`) into `out`, with what it
    /// accelerates those joints by (the same rows of `qdd`) when `accelerations` says the tick
    /// computed them and they are finite, reusing the previous tick's messages (their strings
    /// and vectors) when the team is the same.
    pub fn commands_into(
        &self,
        tick: &[DynamicsTerms],
        accelerations: bool,
        out: &mut Vec<TorqueCommand>,
    ) {
        torque_commands_into(&self.team, tick, out, |r, tau, qdd| {
            tau.extend(r.actuated.iter().map(|&j| self.tau[j]));
            let finite =
                || r.actuated.iter().all(|&j| self.qdd.get(j).is_some_and(|a| a.is_finite()));
            if accelerations && finite() {
                qdd.extend(r.actuated.iter().map(|&j| self.qdd[j]));
            }
        });
    }

    /// The tick's diagnostics into `d` (its strings and vectors reused): the real contact
    /// wrenches, the QP's status and time, `|J_c v|`, the object estimate and the fit's slip, the
    /// fallback taken, how much of the motion yielded.
    pub fn diagnostics_into(&self, tick: &[DynamicsTerms], d: &mut TickDiagnostics) {
        let outputs = TickOutputs {
            team: &self.team,
            grasp: self.grasp.as_ref(),
            wrench: &self.lambda_real,
            status: self.qp.status,
            iterations: self.qp.iterations,
            solve_us: self.qp.solve_us,
            assembly_us: self.timing.assembly_us,
            total_us: self.timing.total_us,
            residual: self.jc_v.norm(),
            note: tick_note(self.fallback.as_deref(), self.release.as_deref(), self.released_now),
        };
        diagnostics_into(&outputs, tick, d);
        d.motion_yield = (self.motion != MotionScale::FULL).then_some(protocol::MotionYield {
            object: self.motion.object,
            torso: self.motion.torso,
            reserve: self.motion.reserve,
        });
    }
}
