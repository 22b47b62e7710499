//! [`MqpReport`]: everything one MQP tick computed (for tests and reports), and the tick's
//! outputs written from it: each robot's torque slice and the tick's diagnostics.

use nalgebra::{DMatrix, DVector};
use protocol::{ContactWrench, DynamicsTerms, Header, TickDiagnostics, TorqueCommand};

use crate::linalg::{quat_wxyz, zeros_v};
use crate::mqp::object::ObjectTerms;
use crate::mqp::problem::MqpProblem;
use crate::mqp::solve::SolveOutcome;
use crate::mqp::tasks::TaskRows;
use crate::qp::ContactKind;
use crate::team::Team;
use crate::units::grasp::GraspTerms;
use crate::units::messages::{set_header, set_string};

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
    /// ([`crate::units::release`]); `None` while the grasp holds.
    pub release: Option<String>,
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
        out.truncate(self.team.robots.len());
        let mut k = 0;
        for (i, (r, t)) in self.team.robots.iter().zip(tick).enumerate() {
            if i == out.len() {
                out.push(TorqueCommand { header: Header::new(&t.header.team, Some(&r.id), 0, 0), tau: Vec::new(), hold: false, delay_ticks: 0 });
            }
            let cmd = &mut out[i];
            // The message may be last tick's hold order (the service reuses the buffer).
            cmd.hold = false;
            set_header(&mut cmd.header, &t.header.team, Some(&r.id), t.header.tick, 0);
            cmd.tau.clear();
            cmd.tau.extend(self.tau.rows(k, r.actuated.len()).iter());
            k += r.actuated.len();
        }
    }

    /// The tick's diagnostics into `d`: real contact wrenches, the QP's status and time,
    /// `|J_c v|`, the object estimate.
    pub fn diagnostics_into(&self, tick: &[DynamicsTerms], d: &mut TickDiagnostics) {
        let (team_id, tick_no) = tick.first().map_or(("", 0), |t| (t.header.team.as_str(), t.header.tick));
        set_header(&mut d.header, team_id, None, tick_no, protocol::wall_clock_ns());
        let frames = self.team.feet.iter().map(|f| (f, 3)).chain(self.team.hands.iter().map(|h| (h, 6)));
        d.contacts.truncate(self.team.feet.len() + self.team.hands.len());
        let mut row = 0;
        for (k, (f, dim)) in frames.enumerate() {
            if k == d.contacts.len() {
                d.contacts.push(ContactWrench { robot: String::new(), frame: String::new(), wrench: Vec::new() });
            }
            let c = &mut d.contacts[k];
            set_string(&mut c.robot, &self.team.robots[f.robot].id);
            set_string(&mut c.frame, &f.name);
            c.wrench.clear();
            if self.wrench.len() >= row + dim {
                c.wrench.extend(self.wrench.rows(row, dim).iter());
            } else {
                c.wrench.extend(std::iter::repeat_n(0.0, dim));
            }
            row += dim;
        }
        let v = &self.team.velocity;
        let residual = (0..self.j_c.nrows()).map(|i| (0..v.len()).map(|j| self.j_c[(i, j)] * v[j]).sum::<f64>().powi(2)).sum::<f64>().sqrt();
        d.qp_status = self.outcome.status;
        d.qp_iterations = self.outcome.iterations;
        d.qp_solve_us = self.timing.solve_us;
        d.assembly_us = self.timing.build_us;
        d.total_us = self.timing.total_us;
        d.constraint_residual = if residual.is_finite() { residual } else { f64::MAX };
        d.object_estimate = self.grasp.as_ref().map(|g| protocol::Pose { position: g.object.translation.vector.into(), orientation: quat_wxyz(&g.object.rotation.to_rotation_matrix()) });
        d.grasp_slip = self.grasp.as_ref().map_or(0.0, |g| g.fit_residual);
        d.fallback.clone_from(if self.fallback.is_some() { &self.fallback } else { &self.release });
    }
}
