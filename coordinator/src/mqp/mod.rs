//! [`Mqp`]: the paper's baseline, the multi-robot QP of Bouyarmane et al. 2019 (the paper's
//! section "Controller Comparison"), behind the same [`TeamController`] interface as PIDC.
//!
//! One QP over the whole team per tick: decision variables `qdd`, `lambda` and `tau` of every
//! robot; the weighted task accelerations of the object, the torsos and the swing feet
//! (`xdd_ref = xdd_des + K_p (x_des - x) + K_d (xd_des - xd)`) plus a small regularisation,
//! under the floating-base dynamics, contact kinematics (stance feet and the grasp), torque,
//! joint acceleration and velocity limits, friction (a palm's sliding and torsion in one cone)
//! and the hands' centre of pressure. Solved by Clarabel. It composes the coordinator's units: the team assembly
//! ([`crate::team`]), the grasp ([`crate::units::grasp`]), the task errors
//! ([`crate::units::impedance`]), the targets ([`crate::units::targets`]), the object's load
//! ([`crate::units::object_load`]), the torque limits ([`crate::units::limits`]), the contact
//! list ([`crate::units::contacts`]) and the QP's contact rows ([`crate::qp::rows`]).
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

use std::collections::BTreeMap;
use std::time::Instant;

use protocol::{DynamicsTerms, QpStatus, RobotDescription, TaskReferences, TickDiagnostics, TorqueCommand};

pub use config::MqpConfig;
pub use report::{MqpReport, MqpTiming};

use crate::linalg::zeros_v;
use crate::units::contact_jacobian::contact_jacobian;
use crate::units::contacts::{contact_list, unload_feet};
use crate::units::grasp::GraspTracker;
use crate::units::limits::torque_limits;
use crate::units::messages::set_note;
use crate::units::release::{GraspWatch, GraspObservation};
use crate::units::targets::Targets;
use crate::{ControllerError, TeamController};
use problem::ProblemInput;
use tasks::{task_rows, TaskRowsInput};

/// The multi-robot QP team controller.
pub struct Mqp {
    pub config: MqpConfig,
    descriptions: BTreeMap<String, RobotDescription>,
    expected: Option<Vec<String>>,
    references: Option<TaskReferences>,
    targets: Targets,
    grasp: GraspTracker,
    /// When the team lets go of the object ([`crate::units::release`]).
    watch: GraspWatch,
    report: MqpReport,
    /// The last valid solution's torque (empty before the first).
    last_tau: nalgebra::DVector<f64>,
    valid: bool,
    diagnostics: Option<TickDiagnostics>,
    /// Scratch: `N Jdot_c,ee v`.
    n_jdv: nalgebra::DVector<f64>,
}

impl Mqp {
    pub fn new(config: MqpConfig) -> Self {
        Mqp {
            config,
            descriptions: BTreeMap::new(),
            expected: None,
            references: None,
            targets: Targets::default(),
            grasp: GraspTracker::default(),
            watch: GraspWatch::default(),
            report: MqpReport::default(),
            last_tau: nalgebra::DVector::zeros(0),
            valid: false,
            diagnostics: None,
            n_jdv: nalgebra::DVector::zeros(0),
        }
    }

    /// Limits and contact parameters of a robot (from its agent's description).
    pub fn set_description(&mut self, d: &RobotDescription) {
        self.descriptions.insert(d.header.robot_id().to_string(), d.clone());
    }

    /// The robots every tick must contain (sorted ids); `None`: whoever is in the tick.
    pub fn set_expected(&mut self, robots: Option<Vec<String>>) {
        self.expected = robots;
    }

    /// Task references. Tasks without a reference hold the pose they had when first seen.
    pub fn set_references(&mut self, r: &TaskReferences) {
        match &mut self.references {
            Some(old) => old.clone_from(r),
            None => self.references = Some(r.clone()),
        }
    }

    /// The last tick, if it completed.
    pub fn last(&self) -> Option<&MqpReport> {
        self.valid.then_some(&self.report)
    }

    /// One tick: assemble the team and the QP, solve it with Clarabel, the torque sent (the
    /// solution's, or the fallback's). Allocates nothing of its own once the team's shape is
    /// set, except Clarabel's setup (see [`solve`]) and a fallback's message.
    pub fn compute(&mut self, tick: &[DynamicsTerms]) -> Result<&MqpReport, ControllerError> {
        self.valid = false;
        let start = Instant::now();
        let us = || start.elapsed().as_secs_f64() * 1e6;
        let Mqp { config: cfg, descriptions, expected, references, targets, grasp, watch, report: r, last_tau, n_jdv, .. } = self;
        // Degrade, never collapse: once the team has let go of the object, every hand is free.
        watch.rearm(tick.iter().any(|t| t.hand_in_grasp));
        r.team.hands_released = watch.released().is_some();
        // §III-A: the team; torque limits (eq. original_torque_limit); the grasp (eqs.
        // graspmatrix, jacobian_cee, obj_jacobian); J_c (eq. jacobian_c).
        r.team.assemble_into(tick, expected.as_deref(), false)?;
        torque_limits(&r.team, descriptions, false, &mut r.actuated, &mut r.limits)?;
        grasp.update(&r.team, cfg.object_pose_at_grasp, &cfg.planned_grasp, &mut r.grasp)?;
        // Late robots' free hands keep clear of the object the others hold.
        targets.keep_clear(&r.team, r.grasp.as_ref().map(|g| &g.object.translation.vector), cfg.release.retreat);
        contact_jacobian(&r.team, r.grasp.as_ref(), &mut r.j_c, &mut r.jdv_c);
        if let Some(g) = &r.grasp {
            // The grasp rows' right side in the range of N (see problem's docs).
            let first = 3 * r.team.feet.len();
            zeros_v(n_jdv, g.n.nrows());
            n_jdv.gemv(1.0, &g.n, &r.jdv_c.rows(first, g.n.nrows()), 0.0);
            r.jdv_c.rows_mut(first, g.n.nrows()).copy_from(n_jdv);
        }
        r.object.compute_into(r.grasp.as_ref(), r.team.n, cfg.object_mass, &cfg.object_inertia);
        let tasks = TaskRowsInput { team: &r.team, grasp: r.grasp.as_ref(), references: references.as_ref(), config: cfg };
        task_rows(&tasks, targets, &mut r.tasks)?;
        contact_list(&r.team, descriptions, &cfg.contact_margins(), &mut r.contacts)?;
        unload_feet(&r.team, references.as_ref().map_or(&[][..], |refs| &refs.foot_loads[..]), &mut r.contacts);
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
        let t_build = us();
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
        // Degrade, never collapse: let go of an object the team cannot hold.
        let outcome = GraspObservation::of(tick[0].header.tick, &r.team, r.grasp.as_ref(), r.fallback.is_some());
        set_note(&mut r.release, watch.after_tick(&cfg.release, outcome, &r.team, r.grasp.as_ref(), targets, grasp));
        r.timing = MqpTiming { build_us: t_build, solve_us: r.outcome.solve_us, total_us: us() };
        self.valid = true;
        Ok(&self.report)
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

impl TeamController for Mqp {
    fn name(&self) -> &'static str {
        "mqp (multi-robot QP, Bouyarmane et al. 2019; Clarabel)"
    }

    fn solve(&mut self, tick: &[DynamicsTerms], out: &mut Vec<TorqueCommand>) -> Result<(), ControllerError> {
        self.compute(tick)?;
        self.report.commands_into(tick, out);
        let d = self.diagnostics.get_or_insert_with(|| TickDiagnostics::empty("", 0));
        self.report.diagnostics_into(tick, d);
        Ok(())
    }

    fn diagnostics(&self) -> Option<&TickDiagnostics> {
        self.diagnostics.as_ref()
    }

    fn used_fallback(&self) -> bool {
        self.last().is_some_and(|l| l.fallback.is_some())
    }

    fn released_at(&self) -> Option<u64> {
        self.watch.released().map(|r| r.tick)
    }

    fn set_description(&mut self, d: &RobotDescription) {
        Mqp::set_description(self, d);
    }

    fn check_terms(&self, terms: &protocol::DynamicsTerms) -> Result<(), ControllerError> {
        crate::team::terms_fit(terms, self.descriptions.get(terms.header.robot_id()))
    }

    fn set_references(&mut self, r: &TaskReferences) {
        Mqp::set_references(self, r);
    }

    fn set_late(&mut self, robots: &[String]) {
        self.targets.set_late(robots);
    }

    fn set_members(&mut self, members: &[String]) {
        self.set_expected(Some(members.to_vec()));
    }

    fn not_ready(&self, members: &[String]) -> Option<String> {
        let missing: Vec<&String> = members.iter().filter(|m| !self.descriptions.contains_key(*m)).collect();
        (!missing.is_empty()).then(|| format!("waiting for the descriptions of {missing:?}"))
    }

    fn ready(&self, robot: &str) -> bool {
        self.descriptions.contains_key(robot)
    }
}
