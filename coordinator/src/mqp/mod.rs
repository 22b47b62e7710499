//! [`Mqp`]: the paper's baseline, the multi-robot QP of Bouyarmane et al. 2019 (the paper's
//! section "Controller Comparison"), behind the same [`TeamController`] interface as PIDC.
//!
//! One QP over the whole team per tick: decision variables `qdd`, `lambda` and `tau` of every
//! robot; the weighted task accelerations of the object, the torsos and the swing feet
//! (`xdd_ref = xdd_des + K_p (x_des - x) + K_d (xd_des - xd)`) plus a small regularisation,
//! under the floating-base dynamics, contact kinematics (stance feet and the grasp), torque,
//! joint acceleration and velocity limits, friction (a palm's sliding and torsion in one cone)
//! and the hands' centre of pressure. Solved by Clarabel. It is a law of the controller shell
//! ([`crate::controller_shell`]: [`Mqp`] is `Shell<MqpLaw>`) and composes the coordinator's
//! building blocks: the team assembly ([`crate::team`]), the grasp
//! ([`crate::building_blocks::grasp`]), the task errors ([`crate::building_blocks::impedance`]),
//! the targets ([`crate::building_blocks::targets`]), the object's load
//! ([`crate::building_blocks::object_load`]), the torque limits
//! ([`crate::building_blocks::limits`]), the contact
//! list ([`crate::building_blocks::contacts`]) and the QP's contact rows ([`crate::qp::rows`]).
//!
//! * [`config`]: [`MqpConfig`], task weights and gains, the object, margins, limits.
//! * [`tasks`]: the task rows of the objective.
//! * [`object`]: the carried object's dynamics as an affine function of `qdd`.
//! * [`problem`]: the QP (objective, equalities, inequalities), dense and CSC.
//! * [`solve`](mod@solve): Clarabel.
//! * [`report`]: [`MqpReport`], the tick's commands and diagnostics.
//!
//! **Fallback.** When Clarabel fails (infeasible, iteration limit, numerical error) every robot
//! is still commanded: the last valid solution's torque if the team's shape is unchanged,
//! else the bias torque `h` of the actuated joints (gravity compensation without contacts);
//! both clamped to the torque limits. The diagnostics carry the solver's status, and
//! [`MqpReport::fallback`] says which fallback ran and why.

pub mod config;
pub mod object;
pub mod problem;
pub mod report;
pub mod solve;
pub mod tasks;

use std::time::Instant;

use protocol::{DynamicsTerms, QpStatus, TorqueCommand};

pub use config::MqpConfig;
pub use report::{MqpReport, MqpTiming};

use crate::building_blocks::contact_jacobian::contact_jacobian;
use crate::building_blocks::contacts::{contact_list, unload_feet};
use crate::controller_shell::{ControlLaw, Shell, ShellState, TickTeam};
use crate::linalg::zeros_v;
use crate::ControllerError;
use problem::ProblemInput;
use tasks::{task_rows, TaskRowsInput};

/// The multi-robot QP team controller: the shell with the MQP's law.
pub type Mqp = Shell<MqpLaw>;

/// The MQP's own law: its parameters, the last tick and its scratch.
pub struct MqpLaw {
    pub config: MqpConfig,
    report: MqpReport,
    /// The last valid solution's torque (empty before the first).
    last_tau: nalgebra::DVector<f64>,
    valid: bool,
    /// Scratch: `N Jdot_c,ee v`.
    n_jdv: nalgebra::DVector<f64>,
}

impl Shell<MqpLaw> {
    /// The MQP controller with parameters `config`.
    pub fn new(config: MqpConfig) -> Self {
        Shell::with_law(MqpLaw {
            config,
            report: MqpReport::default(),
            last_tau: nalgebra::DVector::zeros(0),
            valid: false,
            n_jdv: nalgebra::DVector::zeros(0),
        })
    }

    /// The last tick, if it completed.
    pub fn last(&self) -> Option<&MqpReport> {
        self.law.last()
    }

    /// One tick ([`MqpLaw::compute`]).
    pub fn compute(&mut self, tick: &[DynamicsTerms]) -> Result<&MqpReport, ControllerError> {
        self.law.compute(&mut self.state, tick)
    }
}

impl MqpLaw {
    /// The last tick, if it completed.
    pub fn last(&self) -> Option<&MqpReport> {
        self.valid.then_some(&self.report)
    }

    /// One tick: assemble the team and the QP, solve it with Clarabel, the torque sent (the
    /// solution's, or the fallback's). Allocates nothing of its own once the team's shape is
    /// set, except Clarabel's setup (see [`solve`]) and a fallback's message.
    pub fn compute(
        &mut self,
        state: &mut ShellState,
        tick: &[DynamicsTerms],
    ) -> Result<&MqpReport, ControllerError> {
        self.valid = false;
        let start = Instant::now();
        let us = || start.elapsed().as_secs_f64() * 1e6;
        self.assemble(state, tick)?;
        let t_build = us();
        self.solve_qp();
        let (cfg, r) = (&self.config, &mut self.report);
        let fell_back = r.fallback.is_some();
        let team = (&r.team, r.grasp.as_ref());
        r.released_now = state.watch_release(cfg, tick, team, fell_back, &mut r.release);
        r.timing = MqpTiming { build_us: t_build, solve_us: r.outcome.solve_us, total_us: us() };
        self.valid = true;
        Ok(&self.report)
    }

    /// The tick's team, grasp, contact Jacobian, object, tasks and contacts, and the QP's
    /// matrices.
    fn assemble(
        &mut self,
        state: &mut ShellState,
        tick: &[DynamicsTerms],
    ) -> Result<(), ControllerError> {
        let MqpLaw { config: cfg, report: r, n_jdv, .. } = self;
        // §III-A: the team, its torque limits and the grasp; J_c (eq. jacobian_c).
        let team = TickTeam {
            team: &mut r.team,
            actuated: &mut r.actuated,
            limits: &mut r.limits,
            grasp: &mut r.grasp,
        };
        state.assemble_tick(tick, cfg, false, team)?;
        let ShellState { descriptions, references, targets, .. } = state;
        contact_jacobian(&r.team, r.grasp.as_ref(), &mut r.j_c, &mut r.jdv_c);
        grasp_drift_in_range(r, n_jdv);
        r.object.compute_into(r.grasp.as_ref(), r.team.n, cfg.object_mass, &cfg.object_inertia);
        let tasks = TaskRowsInput {
            team: &r.team,
            grasp: r.grasp.as_ref(),
            references: references.as_ref(),
            config: cfg,
        };
        task_rows(&tasks, targets, &mut r.tasks)?;
        contact_list(&r.team, descriptions, &cfg.contact_margins(), &mut r.contacts)?;
        unload_feet(
            &r.team,
            references.as_ref().map_or(&[][..], |refs| &refs.foot_loads[..]),
            &mut r.contacts,
        );
        let input = ProblemInput {
            team: &r.team,
            grasp: r.grasp.as_ref(),
            j_c: &r.j_c,
            jdv_c: &r.jdv_c,
            object: &r.object,
            tasks: &r.tasks,
            contacts: &r.contacts,
            actuated: &r.actuated,
            limits: &r.limits,
            config: cfg,
        };
        r.problem.assemble(&input);
        Ok(())
    }

    /// The QP solved by Clarabel, and the torque sent: the solution's, or the fallback's.
    fn solve_qp(&mut self) {
        let MqpLaw { config: cfg, report: r, last_tau, .. } = self;
        r.outcome = solve::solve(&r.problem, cfg.max_iter, &mut r.x);
        let na = r.actuated.len();
        zeros_v(&mut r.tau, na);
        r.fallback = None;
        if matches!(r.outcome.status, QpStatus::Solved | QpStatus::AlmostSolved) {
            let first = r.problem.layout.tau();
            r.tau.copy_from(&r.x.rows(first, na));
            zeros_v(last_tau, na);
            last_tau.copy_from(&r.tau);
            r.real_wrenches();
        } else {
            r.fallback = Some(fallback_torque(r, last_tau));
        }
    }
}

/// The grasp rows' right side `Jdot_c,ee v` in the range of `N` (see [`problem`]'s docs),
/// through the scratch `n_jdv`.
fn grasp_drift_in_range(r: &mut MqpReport, n_jdv: &mut nalgebra::DVector<f64>) {
    if let Some(g) = &r.grasp {
        let first = 3 * r.team.feet.len();
        zeros_v(n_jdv, g.n.nrows());
        n_jdv.gemv(1.0, &g.n, &r.jdv_c.rows(first, g.n.nrows()), 0.0);
        r.jdv_c.rows_mut(first, g.n.nrows()).copy_from(n_jdv);
    }
}

/// The fallback torque into `r.tau` (clamped to the limits); returns why it ran.
fn fallback_torque(r: &mut MqpReport, last_tau: &nalgebra::DVector<f64>) -> String {
    let na = r.actuated.len();
    let why = format!("clarabel: {:?}", r.outcome.status);
    let what = if last_tau.len() == na && na > 0 {
        r.tau.copy_from(last_tau);
        "holding the last valid solution's torque"
    } else {
        for (k, &j) in r.actuated.iter().enumerate() {
            r.tau[k] = r.team.bias[j];
        }
        "bias compensation (no valid solution of this team's shape yet)"
    };
    for (t, lim) in r.tau.iter_mut().zip(&r.limits) {
        *t = t.clamp(-lim, *lim);
    }
    if r.x.len() != r.problem.layout.vars() {
        zeros_v(&mut r.x, r.problem.layout.vars());
    }
    zeros_v(&mut r.wrench, r.problem.layout.m);
    format!("{why}; {what}")
}

impl ControlLaw for MqpLaw {
    fn law_name(&self) -> &'static str {
        "mqp (multi-robot QP, Bouyarmane et al. 2019; Clarabel)"
    }

    fn control(
        &mut self,
        state: &mut ShellState,
        tick: &[DynamicsTerms],
        out: &mut Vec<TorqueCommand>,
    ) -> Result<(), ControllerError> {
        self.compute(state, tick)?;
        self.report.commands_into(tick, out);
        self.report.diagnostics_into(tick, state.diagnostics_mut());
        Ok(())
    }

    fn fell_back(&self) -> bool {
        self.last().is_some_and(|l| l.fallback.is_some())
    }
}
