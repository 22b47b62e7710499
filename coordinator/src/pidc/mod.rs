//! [`Pidc`]: the team controller of the paper's §III, projected inverse dynamics control with
//! the contact-force QP, run every tick.
//!
//! `tau = [P S]^+ P tau_M + B J_c^T F_c` (eq. ua_solution with `(I - P) tau_C = J_c^T F_c`),
//! `F_c` from the QP of eq. wrench_optim2 (see [`crate::qp`]). [`Pidc::compute`] runs the
//! stages of [`stages`] in the paper's order; each writes into the [`TickReport`] (what tests
//! and reports read) or the controller's workspace, so a tick allocates nothing once the
//! team's shape is known.
//!
//! * [`config`]: [`PidcConfig`], the gains, the object, the QP's margins and settings.
//! * [`report`]: [`TickReport`] (every intermediate of the last tick) and the tick's messages.
//! * [`stages`]: the stages, one job each.

pub mod config;
pub mod report;
pub mod stages;

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use nalgebra::DVector;
use protocol::{DynamicsTerms, FootLoad, QpStatus, RobotDescription, TorqueCommand};

pub use config::PidcConfig;
pub use report::{ContactMatrices, MaterializedTick, TickReport, Timing};

use crate::building_blocks::contact_jacobian::{contact_drift, contact_jacobian, contact_velocity};
use crate::building_blocks::contacts::{contact_list, unload_feet};
use crate::building_blocks::impedance::{MotionScale, TaskStack};
use crate::building_blocks::projection::{ProjectionPath, ProjectionWorkspace};
use crate::controller_shell::{ControlLaw, Shell, ShellState, TickTeam};
use crate::linalg::zeros_v;
use crate::qp::{self, QpInput, QpWorkspace};
use crate::ControllerError;
use stages::acceleration::{commanded_accelerations, AccelerationScratch, ObjectBody};
use stages::by_robot::{decoupled, ByRobot, ByRobotScratch};
use stages::tasks::{task_torque, MotionSpaceTerms, TaskTorqueInput};
use stages::torque::{compose, fallback, motion_torque, saturate, Clamp, MotionTorqueScratch};
use stages::wrench::{
    contact_map, contact_offset, contact_wrenches, Actuation, ContactMapScratch, MapInput,
    WrenchInput,
};
use stages::yielding::{yield_motion, YieldScratch};

/// Scratch of a tick that the report does not keep: each stage's workspace and the contact
/// map's matrices.
#[derive(Default)]
struct Workspace {
    contact: ContactMatrices,
    proj: ProjectionWorkspace,
    motion: MotionSpaceTerms,
    tasks: TaskStack,
    torque: MotionTorqueScratch,
    map: ContactMapScratch,
    qp: QpWorkspace,
    blocks: qp::BlockHotStart,
    by_robot: ByRobotScratch,
    acceleration: AccelerationScratch,
    /// The object's load `F_x` with the object held still (the motion yielding).
    f_x_hold: nalgebra::Vector6<f64>,
    yielding: YieldScratch,
    /// When the tick's contact forces must be chosen ([`PidcLaw::solve_budget`] from the tick's
    /// start): past it the QP's chain and the steps before the fallback are not started.
    deadline: Option<Instant>,
}

impl Workspace {
    /// Whether the tick's budget is spent (never without one).
    fn out_of_time(&self) -> bool {
        qp::settings::passed(self.deadline)
    }
}

/// The PIDC team controller (paper §III): the shell with PIDC's law.
pub type Pidc = Shell<PidcLaw>;

/// PIDC's own law: its parameters, the last tick and its workspace.
pub struct PidcLaw {
    pub config: PidcConfig,
    report: TickReport,
    /// Whether `report` holds a completed tick.
    valid: bool,
    /// Whether a tick computes what its torque accelerates (`report.qdd`,
    /// [`crate::TeamController::keep_accelerations`]).
    accelerations: bool,
    /// How long a tick may take to choose its contact forces before the fallback answers
    /// ([`crate::TeamController::set_solve_budget`]); `None`: every step runs to its end.
    solve_budget: Option<Duration>,
    ws: Workspace,
}

impl Shell<PidcLaw> {
    /// The PIDC controller with parameters `config`.
    pub fn new(config: PidcConfig) -> Self {
        Shell::with_law(PidcLaw {
            config,
            report: TickReport::default(),
            valid: false,
            accelerations: false,
            solve_budget: None,
            ws: Workspace::default(),
        })
    }

    /// Forget the grasp (offsets are captured again when the hands next close). This does not
    /// let go of the object: see [`crate::building_blocks::release`] for that.
    pub fn release_grasp(&mut self) {
        self.state.grasp.release();
        self.state.targets.release_object();
    }

    /// The last tick, if it completed (a tick that ended in an error leaves none).
    pub fn last(&self) -> Option<&TickReport> {
        self.law.last()
    }

    /// The contact map's matrices as the last tick left them ([`ContactMatrices`]: formed only
    /// on the ticks that read them).
    pub fn contact_matrices(&self) -> &ContactMatrices {
        &self.law.ws.contact
    }

    /// The last tick with `J_c`, `Y`, `rho` and its team-sized projection matrices formed
    /// ([`Projections::materialize`]: the block path keeps only factors on the tick), and, when
    /// the QP was answered by the robots' blocks ([`qp::BlockHotStart`]), an `F_c` with
    /// `tau = tau_0 + Y F_c` (the least-norm one, `Y^+ (tau - tau_0)`; then also
    /// `lambda = rho F_c + eta`, since `rho` and `Y` share their null space). For tests and
    /// reports; it allocates, and leaves the tick's report as it was. `None` without a
    /// completed tick, or when the SVD of `Y` fails.
    ///
    /// [`Projections::materialize`]: crate::building_blocks::projection::Projections::materialize
    pub fn materialized(&mut self) -> Option<MaterializedTick> {
        let PidcLaw { report, valid, ws, .. } = &mut self.law;
        if !*valid {
            return None;
        }
        form_j_c(report, &mut ws.contact);
        let c = &ws.contact;
        let mut tick = MaterializedTick {
            report: report.clone(),
            j_c: c.j_c.clone(),
            y: c.y.clone(),
            rho: c.rho.clone(),
        };
        let MaterializedTick { report: r, j_c, y, rho } = &mut tick;
        r.proj.materialize(&r.team);
        if r.qp.solver == qp::by_blocks::SOLVER {
            let map = MapInput {
                team: &r.team,
                proj: &r.proj,
                j_c,
                tau0: &r.tau0,
                load: &r.load,
                grasp: r.grasp.as_ref(),
                f_x: &r.f_x,
            };
            let (mut eta, mut eta_real) = (DVector::zeros(0), DVector::zeros(0));
            contact_map(&map, &mut ws.map, y, rho, &mut eta, &mut eta_real);
            let (y_pinv, _) = crate::linalg::pinv(y, crate::linalg::RANK_TOL)?;
            r.f_c = y_pinv * (&r.tau - &r.tau0);
        }
        Some(tick)
    }

    /// Run one tick ([`PidcLaw::compute`]).
    pub fn compute(&mut self, tick: &[DynamicsTerms]) -> Result<&TickReport, ControllerError> {
        self.law.compute(&mut self.state, tick)
    }
}

impl PidcLaw {
    /// The last tick, if it completed (a tick that ended in an error leaves none).
    pub fn last(&self) -> Option<&TickReport> {
        self.valid.then_some(&self.report)
    }

    /// Run one tick: the full team torque and every intermediate, stage by stage (§III).
    ///
    /// **Allocations.** Every matrix and vector of the tick lives in the report or in the
    /// controller's workspace and is overwritten in place: once a team's shape (robots, stance
    /// feet, grasp) has been seen, a tick allocates nothing (`tests/allocations.rs` counts).
    /// What still allocates: a change of shape (buffers are resized), capturing a new grasp,
    /// errors and fallback messages, and Clarabel when it has to finish a tick the dense
    /// interior-point method did not.
    pub fn compute(
        &mut self,
        state: &mut ShellState,
        tick: &[DynamicsTerms],
    ) -> Result<&TickReport, ControllerError> {
        self.valid = false;
        let start = Instant::now();
        self.ws.deadline = self.solve_budget.map(|b| start + b);
        let us = || start.elapsed().as_secs_f64() * 1e6;
        self.assemble(state, tick)?;
        let t_asm = us();
        self.project()?;
        let t_proj = us();
        self.motion(state)?;
        let t_imp = us();
        let PidcLaw { config: cfg, report: r, ws, .. } = self;
        let (build_us, qp_us) =
            contact_forces(r, ws, &state.descriptions, cfg, state.foot_loads())?;
        // What the torque sent accelerates, the object a rigid body on the hands (eq.
        // aghili_25): the team's delay carries each state over it (crate::team::prediction).
        if self.accelerations {
            self.commanded_accelerations();
        }
        let r = &mut self.report;
        let fell_back = r.fallback.is_some();
        // Degrade, never collapse: let go of an object the team cannot hold.
        let team = (&r.team, r.grasp.as_ref());
        r.released_now = state.watch_release(&self.config, tick, team, fell_back, &mut r.release);
        self.report.timing = Timing {
            assembly_us: t_asm,
            projections_us: t_proj - t_asm,
            impedance_us: t_imp - t_proj,
            qp_build_us: build_us,
            qp_us,
            total_us: us(),
        };
        self.valid = true;
        Ok(&self.report)
    }

    /// §III-A: M, h, v, S, J_cf, J_ee of the team, the torque limits, the grasp, the late
    /// robots' targets, `Jdot_c v` and `J_c v`.
    fn assemble(
        &mut self,
        state: &mut ShellState,
        tick: &[DynamicsTerms],
    ) -> Result<(), ControllerError> {
        let PidcLaw { config: cfg, report: r, ws, .. } = self;
        let team = TickTeam {
            team: &mut r.team,
            actuated: &mut r.actuated,
            limits: &mut r.limits,
            grasp: &mut r.grasp,
        };
        state.assemble_tick(tick, cfg, cfg.fully_actuated, team)?;
        // Jdot_c v and J_c v (eq. jacobian_c); J_c itself only where it is needed (form_j_c).
        ws.contact.j_c_formed = false;
        contact_drift(&r.team, r.grasp.as_ref(), &mut r.jdv_c);
        contact_velocity(&r.team, r.grasp.as_ref(), &mut r.jc_v);
        Ok(())
    }

    /// P, Pdot v, M_c, Mbar, [P S]^+, B (eqs. aghili_21, aghili_25, constraint_force,
    /// bmatrix): by the team's blocks, or by dense SVDs of J_c when asked or when the blocks
    /// decline; then the tasks' motion-space terms.
    fn project(&mut self) -> Result<(), ControllerError> {
        let PidcLaw { config: cfg, report: r, ws, .. } = self;
        if cfg.projections == ProjectionPath::Dense
            || !r.proj.by_blocks_into(&mut ws.proj, &r.team, r.grasp.as_ref(), &r.jdv_c)
        {
            form_j_c(r, &mut ws.contact);
            r.proj.compute_into(&mut ws.proj, &r.team, &ws.contact.j_c, &r.jdv_c)?;
        }
        ws.motion.compute_into(&r.proj, &r.team);
        Ok(())
    }

    /// tau_M of the object, torso and swing-foot impedances (eqs. control_law,
    /// joint_space_tau_M) with the object's load J_x^T F_x; tau_0 = [P S]^+ P tau_M.
    fn motion(&mut self, state: &mut ShellState) -> Result<(), ControllerError> {
        let PidcLaw { config: cfg, report: r, ws, .. } = self;
        let tasks = TaskTorqueInput {
            team: &r.team,
            grasp: r.grasp.as_ref(),
            references: state.references.as_ref(),
            config: cfg,
            motion: ws.motion.view(&r.proj),
        };
        task_torque(
            &tasks,
            &mut state.targets,
            &mut ws.tasks,
            &mut r.tau_m,
            &mut r.load,
            &mut r.f_x,
            &mut ws.f_x_hold,
        )?;
        motion_torque(&r.proj, &r.team.s_diag, &r.tau_m, &mut r.tau0, &mut ws.torque);
        Ok(())
    }

    /// What the tick's torque accelerates (`report.qdd`), the object a rigid body on the hands.
    fn commanded_accelerations(&mut self) {
        let PidcLaw { config: cfg, report: r, ws, .. } = self;
        let body = ObjectBody { mass: cfg.object_mass, inertia: cfg.object_inertia };
        commanded_accelerations(
            &r.team,
            &r.proj,
            &r.tau,
            &ws.motion.mcinv_bias,
            r.grasp.as_ref().map(|g| (g, &body)),
            &mut r.qdd,
            &mut ws.acceleration,
        );
    }
}

/// `F_c` and `tau` of a tick from its `tau_0`: the contact map (eq.
/// relation_between_lambda_and_Fc), the QP of eq. wrench_optim2 under the friction, moment and
/// torque rows (eqs. unilateral_and_friction_cone_constraint, moment_constraint,
/// real_torque_limit) on the real wrenches, `tau = tau_0 + Y F_c` (eq. ua_solution) and the
/// wrenches for the torque sent. When the QP fails on a team that holds an object, the motion
/// yields first ([`stages::yielding`]: the tick is solved at the largest share of the object's,
/// then the torsos', motion the contacts carry). When even holding still fails and `tau_0`
/// asks more of a joint than its limit ([`saturate`]: a push, a task far from its target), the
/// QP is solved again with `tau_0` saturated, so that the contact forces are chosen for a
/// torque the joints can give; then the least-violation fallback ([`fallback`]), robot by
/// robot when no grasp couples the robots ([`stages::by_robot`]). Feet named in `loads` (the
/// references' unloading ramps) have their normal force bounded. Past the tick's budget
/// (`ws.deadline`) no step before the fallback is started and no solver down the QP's chain:
/// the fallback answers in time. Returns the build and QP times, µs.
fn contact_forces(
    r: &mut TickReport,
    ws: &mut Workspace,
    descriptions: &BTreeMap<String, RobotDescription>,
    cfg: &PidcConfig,
    loads: &[FootLoad],
) -> Result<(f64, f64), ControllerError> {
    let (mut build_us, mut qp_us) = (0.0, 0.0);
    let mut saturated = false;
    r.motion = MotionScale::FULL;
    let t_list = Instant::now();
    contact_list(&r.team, descriptions, &cfg.contact_margins(), &mut r.contacts)?;
    unload_feet(&r.team, loads, &mut r.contacts);
    build_us += t_list.elapsed().as_secs_f64() * 1e6;
    r.blocks_declined = None;
    if cfg.qp_path.tries_blocks() && hot_start(r, ws, cfg, &mut build_us, &mut qp_us) {
        return Ok((build_us, qp_us));
    }
    form_j_c(r, &mut ws.contact);
    // A team holding an object yields when the QP is infeasible: the active set's proof of
    // infeasibility is enough to start the yield (Clarabel's certificate costs milliseconds);
    // a QP nothing held still makes feasible is certified again before the steps after.
    let yields = r.grasp.is_some() && !decoupled(&r.team);
    let mut solved = dense_qp(r, ws, cfg, (true, yields), &mut build_us, &mut qp_us);
    // The motion yields before anything else gives (stages::yielding), in the tick's budget.
    if !solved && yields && !ws.out_of_time() {
        let t = Instant::now();
        solved = yield_or_restore(r, ws, descriptions, cfg, loads)?;
        qp_us += t.elapsed().as_secs_f64() * 1e6;
    }
    // No grasp couples the robots: they take the next steps one by one (below).
    if !solved && !decoupled(&r.team) && saturate(&mut r.tau0, &r.actuated, &r.limits) {
        saturated = true;
        dense_qp(r, ws, cfg, (true, false), &mut build_us, &mut qp_us);
    }
    fall_back(r, ws, cfg, saturated, &mut qp_us);
    compose_and_wrenches(r, ws)?;
    Ok((build_us, qp_us))
}

/// The QP's hot start by the robots' blocks ([`solve_by_blocks`]) on the tick's `eta` and
/// `eta_real` (formed here); whether it answered. Adds its times to the build and QP times.
fn hot_start(
    r: &mut TickReport,
    ws: &mut Workspace,
    cfg: &PidcConfig,
    build_us: &mut f64,
    qp_us: &mut f64,
) -> bool {
    let t0 = Instant::now();
    let map = MapInput {
        team: &r.team,
        proj: &r.proj,
        j_c: &ws.contact.j_c,
        tau0: &r.tau0,
        load: &r.load,
        grasp: r.grasp.as_ref(),
        f_x: &r.f_x,
    };
    contact_offset(&map, &mut ws.map, &mut r.eta, &mut r.lambda_real);
    let t1 = Instant::now();
    *build_us += (t1 - t0).as_secs_f64() * 1e6;
    let solved = solve_by_blocks(r, ws, cfg);
    *qp_us += t1.elapsed().as_secs_f64() * 1e6;
    solved
}

/// After the QP's last try: robot by robot when no grasp couples the robots and it failed,
/// else the least-violation fallback when it failed ([`fallback`]); `F_c`, the fallback
/// taken and whether `tau_0` was saturated into the report. Adds its time to the QP time.
fn fall_back(
    r: &mut TickReport,
    ws: &mut Workspace,
    cfg: &PidcConfig,
    mut saturated: bool,
    qp_us: &mut f64,
) {
    let mut f_c = std::mem::replace(&mut r.f_c, DVector::zeros(0));
    let solved = matches!(r.qp.status, QpStatus::Solved | QpStatus::AlmostSolved);
    let fallback = if !solved && decoupled(&r.team) {
        let t = Instant::now();
        let by = by_robot(r, ws, cfg, &mut f_c);
        *qp_us += t.elapsed().as_secs_f64() * 1e6;
        (r.qp, saturated) = (by.outcome, by.saturated);
        by.fallback
    } else {
        fallback(
            &mut ws.qp,
            &qp_input(r, &ws.contact, cfg),
            cfg.qp_max_iter,
            r.qp.status,
            saturated,
            &mut f_c,
        )
    };
    (r.f_c, r.fallback, r.saturated) = (f_c, fallback, saturated);
}

/// `tau = tau_0 + Y F_c` and the contact wrenches for the torque sent.
fn compose_and_wrenches(r: &mut TickReport, ws: &mut Workspace) -> Result<(), ControllerError> {
    // tau = tau_0 + Y F_c (eq. ua_solution), clamped to the limits after a fallback.
    let clamp = r.fallback.is_some().then_some(Clamp { actuated: &r.actuated, limits: &r.limits });
    compose(&r.tau0, &ws.contact.y, &r.f_c, clamp, &mut r.tau)?;
    // lambda for the torque sent (eq. relation_between_lambda_and_Fc, or eq.
    // constraint_force for a clamped torque).
    let sent = if r.fallback.is_some() {
        Actuation::Torque(&r.tau)
    } else {
        Actuation::ContactForces(&r.f_c)
    };
    let wrench = WrenchInput {
        team: &r.team,
        proj: &r.proj,
        load: &r.load,
        rho: &ws.contact.rho,
        eta: &r.eta,
    };
    contact_wrenches(&wrench, sent, &mut ws.map, &mut r.lambda, &mut r.lambda_real);
    Ok(())
}

/// The team's QP on the dense path at the tick's `tau_0`: the contact map (with `full`, `Y`
/// and `rho` too; they do not depend on `tau_0`), then the QP of eq. wrench_optim2; whether
/// it was solved. With `refuses`, the active set's proof of infeasibility is final
/// (`QpSettings::active_set_refuses`). Adds its times to the build and QP times.
fn dense_qp(
    r: &mut TickReport,
    ws: &mut Workspace,
    cfg: &PidcConfig,
    (full, refuses): (bool, bool),
    build_us: &mut f64,
    qp_us: &mut f64,
) -> bool {
    let t0 = Instant::now();
    let c = &mut ws.contact;
    let map = MapInput {
        team: &r.team,
        proj: &r.proj,
        j_c: &c.j_c,
        tau0: &r.tau0,
        load: &r.load,
        grasp: r.grasp.as_ref(),
        f_x: &r.f_x,
    };
    if full {
        contact_map(&map, &mut ws.map, &mut c.y, &mut c.rho, &mut r.eta, &mut r.lambda_real);
    } else {
        contact_offset(&map, &mut ws.map, &mut r.eta, &mut r.lambda_real);
    }
    let t1 = Instant::now();
    // F_c is kept out of the report while the QP reads it (no allocation: an empty vector).
    let mut f_c = std::mem::replace(&mut r.f_c, DVector::zeros(0));
    let settings = qp::QpSettings { active_set_refuses: refuses, ..qp_settings(cfg, ws.deadline) };
    r.qp = qp::solve_with(&mut ws.qp, &qp_input(r, &ws.contact, cfg), &settings, &mut f_c);
    r.f_c = f_c;
    *build_us += (t1 - t0).as_secs_f64() * 1e6;
    *qp_us += t1.elapsed().as_secs_f64() * 1e6;
    matches!(r.qp.status, QpStatus::Solved | QpStatus::AlmostSolved)
}

/// A tick whose QP failed at its full motion, solved with the motion yielding
/// ([`stages::yielding`]): the object held still and everything held still are formed from
/// the tick's tasks, and the QP is solved at the largest share it accepts, which the tick is
/// left at. `None` when even everything held still is infeasible.
fn yield_tick(r: &mut TickReport, ws: &mut Workspace, cfg: &PidcConfig) -> Option<MotionScale> {
    let y = &mut ws.yielding;
    y.full.copy_from(&r.tau_m, &r.tau0, &r.load, &r.f_x);
    for (scale, m) in [
        (MotionScale { object: 0.0, torso: 1.0, reserve: false }, &mut y.object_still),
        (MotionScale { object: 0.0, torso: 0.0, reserve: false }, &mut y.all_still),
    ] {
        ws.tasks.joint_torque_yielding(&ws.motion.view(&r.proj), scale, &mut m.tau_m);
        motion_torque(&r.proj, &r.team.s_diag, &m.tau_m, &mut m.tau0, &mut ws.torque);
        m.f_x = ws.f_x_hold;
        zeros_v(&mut m.load, r.team.n);
        if let Some(g) = &r.grasp {
            m.load.gemv_tr(1.0, &g.j_o, &m.f_x, 0.0);
        }
    }
    let (mut build_us, mut qp_us) = (0.0, 0.0);
    // A try past the tick's budget counts as refused.
    yield_motion(|scale| {
        ws.yielding.blend_into(scale, &mut r.tau_m, &mut r.tau0, &mut r.load, &mut r.f_x);
        !ws.out_of_time() && dense_qp(r, ws, cfg, (false, true), &mut build_us, &mut qp_us)
    })
}

/// A tick whose QP failed at its motion: solved with the motion yielding, or held still on
/// the margins' reserve (`r.motion` says which); else the tick's motion and rows are put back
/// and its QP solved again down the whole chain: whether that solved it.
fn yield_or_restore(
    r: &mut TickReport,
    ws: &mut Workspace,
    descriptions: &BTreeMap<String, RobotDescription>,
    cfg: &PidcConfig,
    loads: &[FootLoad],
) -> Result<bool, ControllerError> {
    if let Some(scale) =
        yield_tick(r, ws, cfg).or_else(|| hold_on_reserve(r, ws, descriptions, cfg, loads))
    {
        r.motion = scale;
        return Ok(true);
    }
    contact_list(&r.team, descriptions, &cfg.contact_margins(), &mut r.contacts)?;
    unload_feet(&r.team, loads, &mut r.contacts);
    ws.yielding.full.restore(&mut r.tau_m, &mut r.tau0, &mut r.load, &mut r.f_x);
    // The tick's own QP again, its infeasibility certified down the whole chain this time (the
    // active set's proof that started the yield rests on thresholds): the steps after see the
    // status they always saw.
    let (mut build_us, mut qp_us) = (0.0, 0.0);
    Ok(dense_qp(r, ws, cfg, (false, false), &mut build_us, &mut qp_us))
}

/// A tick on which not even everything held still is feasible within the controller's
/// margins, held still on the margins' reserve ([`ContactMargins::reserve`]): the rows are
/// built again with it and the object (then everything) held still is tried; the scale held
/// at, its `reserve` set. `None` when that fails too (the rows are left on the reserve).
///
/// [`ContactMargins::reserve`]: crate::building_blocks::contact_margins::ContactMargins::reserve
fn hold_on_reserve(
    r: &mut TickReport,
    ws: &mut Workspace,
    descriptions: &BTreeMap<String, RobotDescription>,
    cfg: &PidcConfig,
    loads: &[FootLoad],
) -> Option<MotionScale> {
    contact_list(&r.team, descriptions, &cfg.contact_margins().reserve(), &mut r.contacts).ok()?;
    unload_feet(&r.team, loads, &mut r.contacts);
    let (mut build_us, mut qp_us) = (0.0, 0.0);
    for still in [
        MotionScale { object: 0.0, torso: 1.0, reserve: true },
        MotionScale { object: 0.0, torso: 0.0, reserve: true },
    ] {
        ws.yielding.blend_into(still, &mut r.tau_m, &mut r.tau0, &mut r.load, &mut r.f_x);
        if !ws.out_of_time() && dense_qp(r, ws, cfg, (false, true), &mut build_us, &mut qp_us) {
            return Some(still);
        }
    }
    None
}

/// `J_c = [J_cf; J_c,ee]` (eq. jacobian_c) into the workspace, once per tick (with the same
/// `Jdot_c v` into the report): the dense projections, the team-sized QP and
/// [`Pidc::materialized`] read it; the block path does not.
fn form_j_c(r: &mut TickReport, c: &mut ContactMatrices) {
    if !c.j_c_formed {
        contact_jacobian(&r.team, r.grasp.as_ref(), &mut c.j_c, &mut r.jdv_c);
        c.j_c_formed = true;
    }
}

/// The QP on the last tick's active rows by the robots' blocks ([`qp::BlockHotStart`]), with
/// `eta` and `eta_real` (in `lambda_real`) of the tick: when it is the optimum,
/// `tau = tau_0 - J_c^T z`, `lambda = eta + z`, `lambda_real = eta_real + z`, and whether it
/// was. `Y`, `rho` and `F_c` are not formed (`F_c` is left zero; see [`Pidc::materialized`]).
fn solve_by_blocks(r: &mut TickReport, ws: &mut Workspace, cfg: &PidcConfig) -> bool {
    let t = Instant::now();
    let (warm, shape) = ws.qp.warm();
    let input = qp::BlockInput {
        team: &r.team,
        g: r.grasp.as_ref().map(|g| &g.g),
        contacts: &r.contacts,
        eta_real: &r.lambda_real,
        tau0: &r.tau0,
        actuated: &r.actuated,
        limits: &r.limits,
    };
    r.blocks_declined = ws
        .blocks
        .solve(&input, warm, shape, qp_settings(cfg, None).active_set_tol, qp::BLOCK_REPAIRS)
        .err();
    if r.blocks_declined.is_some() {
        return false;
    }
    // The next tick starts from the rows found optimal here (mended or not).
    ws.qp.set_warm(&ws.blocks.active, shape);
    let b = &ws.blocks;
    zeros_v(&mut r.tau, r.tau0.len());
    r.tau.copy_from(&r.tau0);
    r.tau += &b.dtau;
    zeros_v(&mut r.lambda, r.eta.len());
    r.lambda.copy_from(&r.eta);
    r.lambda += &b.z;
    r.lambda_real += &b.z;
    zeros_v(&mut r.f_c, b.z.len());
    let solve_us = t.elapsed().as_secs_f64() * 1e6;
    r.qp = qp::QpOutcome {
        status: QpStatus::Solved,
        iterations: b.repairs,
        solve_us,
        setup_us: 0.0,
        rows: b.rows,
        solver: qp::by_blocks::SOLVER,
    };
    (r.fallback, r.saturated) = (None, false);
    true
}

/// The failed QP of a team without a grasp, robot by robot ([`stages::by_robot`]): every
/// robot's block, then `tau_0` saturated on the robots whose block failed and their blocks
/// again on the rebuilt contact map (it depends on `tau_0`), then the fallback on those that
/// still fail.
fn by_robot(
    r: &mut TickReport,
    ws: &mut Workspace,
    cfg: &PidcConfig,
    f_c: &mut DVector<f64>,
) -> ByRobot {
    let settings = qp_settings(cfg, ws.deadline);
    ws.by_robot.solve(&r.team, &qp_input(r, &ws.contact, cfg), &settings, false, f_c);
    if ws.by_robot.saturate_failed(&r.team, &mut r.tau0, &r.actuated, &r.limits) {
        let c = &mut ws.contact;
        let map = MapInput {
            team: &r.team,
            proj: &r.proj,
            j_c: &c.j_c,
            tau0: &r.tau0,
            load: &r.load,
            grasp: r.grasp.as_ref(),
            f_x: &r.f_x,
        };
        contact_map(&map, &mut ws.map, &mut c.y, &mut c.rho, &mut r.eta, &mut r.lambda_real);
        ws.by_robot.solve(&r.team, &qp_input(r, &ws.contact, cfg), &settings, true, f_c);
    }
    ws.by_robot.finish(&r.team, &qp_input(r, &ws.contact, cfg), &settings, f_c)
}

/// The QP's settings from the configuration (its iteration limit and path) with the tick's
/// deadline.
fn qp_settings(cfg: &PidcConfig, deadline: Option<Instant>) -> qp::QpSettings {
    qp::QpSettings { deadline, ..qp::QpSettings::new(cfg.qp_max_iter, cfg.qp_path) }
}

/// The QP's data from the tick's report and contact map (`lambda_real` holds `eta_real` until
/// the QP is solved).
fn qp_input<'a>(r: &'a TickReport, c: &'a ContactMatrices, cfg: &PidcConfig) -> QpInput<'a> {
    QpInput {
        y: &c.y,
        rho: &c.rho,
        eta: &r.lambda_real,
        contacts: &r.contacts,
        actuated: &r.actuated,
        limits: &r.limits,
        tau0: &r.tau0,
        regularisation: cfg.regularisation,
    }
}

impl ControlLaw for PidcLaw {
    fn law_name(&self) -> &'static str {
        "pidc (projected inverse dynamics + contact-force QP)"
    }

    fn control(
        &mut self,
        state: &mut ShellState,
        tick: &[DynamicsTerms],
        out: &mut Vec<TorqueCommand>,
    ) -> Result<(), ControllerError> {
        self.compute(state, tick)?;
        // Each robot's torque slice and the tick's diagnostics, reusing the previous tick's
        // messages (their strings and vectors) when the team is the same.
        self.report.commands_into(tick, self.accelerations, out);
        self.report.diagnostics_into(tick, state.diagnostics_mut());
        Ok(())
    }

    fn fell_back(&self) -> bool {
        self.last().is_some_and(|l| l.fallback.is_some())
    }

    fn model_accelerations(&mut self, keep: bool) -> bool {
        self.accelerations = keep;
        true
    }

    fn solve_budget(&mut self, budget: Option<Duration>) -> bool {
        self.solve_budget = budget;
        true
    }

    fn accelerations_of(&self, robot: &str) -> Option<&[f64]> {
        let b = self
            .report
            .team
            .robots
            .iter()
            .find(|b| b.id == robot)
            .filter(|_| self.valid && self.accelerations)?;
        self.report.qdd.as_slice().get(b.offset..b.offset + b.nv)
    }
}
