//! [`MqpReport`]: everything one MQP tick computed (for tests and reports), and the tick's
//! outputs written from it: each robot's torque slice and the tick's diagnostics.

use nalgebra::{DMatrix, DVector};
use protocol::{DynamicsTerms, TickDiagnostics, TorqueCommand};

use crate::building_blocks::grasp::GraspTerms;
use crate::controller_shell::report::{
    diagnostics_into, tick_note, torque_commands_into, TickOutputs,
};
use crate::linalg::zeros_v;
use crate::mqp::object::ObjectTerms;
use crate::mqp::problem::MqpProblem;
use crate::mqp::solve::SolveOutcome;
use crate::mqp::tasks::TaskRows;
use crate::qp::ContactKind;
use crate::team::Team;

/// Where the time of a tick went, µs.
#[derive(Debug, Clone, Copy, Default)]
pub struct MqpTiming {
    /// Team, grasp, object, tasks and the QP's matrices.
    pub build_us: f64,
    /// Clarabel (setup and solve).
    pub solve_us: f64,
    pub total_us: f64,
}

/// The last tick (overwritten in place by the next).
#[derive(Debug, Clone, Default)]
pub struct MqpReport {
    pub team: Team,
    pub grasp: Option<GraspTerms>,
    /// `J_c` and the right side `Jdot_c v` used (grasp rows projected by `N`).
    pub j_c: DMatrix<f64>,
    pub jdv_c: DVector<f64>,
    pub object: ObjectTerms,
    pub tasks: TaskRows,
    pub contacts: Vec<(usize, ContactKind)>,
    pub actuated: Vec<usize>,
    pub limits: Vec<f64>,
    pub problem: MqpProblem,
    /// The QP's solution `[qdd; lambda; tau]` (the last valid one after a failure).
    pub x: DVector<f64>,
    /// The real contact wrenches of the solution (feet: `lambda`; hands: `lambda_ee + G^+ F_x`).
    pub wrench: DVector<f64>,
    /// The torque sent, per actuated joint (the solution's `tau`, or the fallback's).
    pub tau: DVector<f64>,
    pub outcome: SolveOutcome,
    /// Why the torque came from the fallback, if it did.
    pub fallback: Option<String>,
    /// Why the hands are free while the contact sets hold the object
    /// ([`crate::building_blocks::release`]); `None` while the grasp holds.
    pub release: Option<String>,
    /// The team let go on this tick: its diagnostics name the release (its tick and cause)
    /// rather than the fallback the tick took, so that a release followed by fallbacks is
    /// still on record.
    pub released_now: bool,
    pub timing: MqpTiming,
}

impl MqpReport {
    /// The solution's blocks.
    pub fn qdd(&self) -> nalgebra::DVectorView<'_, f64> {
        self.x.rows(0, self.problem.layout.n)
    }
    pub fn lambda(&self) -> nalgebra::DVectorView<'_, f64> {
        self.x.rows(self.problem.layout.lambda(), self.problem.layout.m)
    }
    pub fn tau_solution(&self) -> nalgebra::DVectorView<'_, f64> {
        self.x.rows(self.problem.layout.tau(), self.problem.layout.na)
    }

    /// The real contact wrenches of the solution into `wrench` (see the field's docs).
    pub(crate) fn real_wrenches(&mut self) {
        let l = self.problem.layout;
        zeros_v(&mut self.wrench, l.m);
        self.wrench.copy_from(&self.x.rows(l.lambda(), l.m));
        let first = 3 * self.team.feet.len();
        let hands = self.object.hand_qdd.nrows();
        if hands > 0 {
            let mut w = self.wrench.rows_mut(first, hands);
            w.gemv(-1.0, &self.object.hand_qdd, &self.x.rows(0, l.n), 1.0);
            w -= &self.object.hand_const;
        }
    }

    /// Each robot's torque slice into `out` (messages reused when the team is the same).
    pub fn commands_into(&self, tick: &[DynamicsTerms], out: &mut Vec<TorqueCommand>) {
        let mut k = 0;
        torque_commands_into(&self.team, tick, out, |r, tau, _| {
            tau.extend(self.tau.rows(k, r.actuated.len()).iter());
            k += r.actuated.len();
        });
    }

    /// The tick's diagnostics into `d`: real contact wrenches, the QP's status and time,
    /// `|J_c v|`, the object estimate.
    pub fn diagnostics_into(&self, tick: &[DynamicsTerms], d: &mut TickDiagnostics) {
        let v = &self.team.velocity;
        let residual = (0..self.j_c.nrows())
            .map(|i| (0..v.len()).map(|j| self.j_c[(i, j)] * v[j]).sum::<f64>().powi(2))
            .sum::<f64>()
            .sqrt();
        let outputs = TickOutputs {
            team: &self.team,
            grasp: self.grasp.as_ref(),
            wrench: &self.wrench,
            status: self.outcome.status,
            iterations: self.outcome.iterations,
            solve_us: self.timing.solve_us,
            assembly_us: self.timing.build_us,
            total_us: self.timing.total_us,
            residual,
            note: tick_note(self.fallback.as_deref(), self.release.as_deref(), self.released_now),
        };
        diagnostics_into(&outputs, tick, d);
    }
}
