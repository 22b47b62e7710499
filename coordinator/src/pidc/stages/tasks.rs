//! The motion tasks of a tick: each task's target ([`Targets`], from
//! [`crate::building_blocks::targets`]), the carried object's load (the paper's `J_x^T F_x` of eq.
//! js_dynamics, from [`crate::building_blocks::object_load`]), the motion-space terms every task
//! shares
//! ([`MotionSpaceTerms`]) and the motion torque `tau_M` (eqs. control_law,
//! joint_space_tau_M; [`task_torque`]).

use nalgebra::{DVector, Vector6};
use protocol::TaskReferences;

use crate::building_blocks::block_projection::{vmat, vmat_mut, BlockOp, OpScratch};
use crate::building_blocks::grasp::GraspTerms;
use crate::building_blocks::impedance::{
    HoldStill, MotionSpace, TaskError, TaskJacobian, TaskStack, Yields,
};
use crate::building_blocks::object_load::object_load;
use crate::building_blocks::projection::{mass_times, Projections};
pub use crate::building_blocks::targets::{frame_pose, PointTarget, PoseTarget, Targets};
use crate::controller_shell::tasks::{task_row_count, walk_tasks, TaskSink};
use crate::linalg::zeros_v;
use crate::pidc::PidcConfig;
use crate::team::{Team, TeamFrame};
use crate::ControllerError;

/// The motion-space term of the tasks' bias, `M_c^{-1} (P h - Pdot v)` (eq. control_law's
/// `mu_c`), kept between ticks; its `M_c^{-1} P` (`Lambda_c`) is the projections' own
/// ([`Projections::mcinv_p`], or their operator on the block path).
#[derive(Debug, Clone, Default)]
pub struct MotionSpaceTerms {
    pub mcinv_bias: DVector<f64>,
    /// `P h - Pdot v`, and scratch.
    p_bias: DVector<f64>,
    t: DVector<f64>,
    ops: OpScratch,
}

impl MotionSpaceTerms {
    /// From the tick's projections and the team's `M` and `h`.
    pub fn compute_into(&mut self, proj: &Projections, team: &Team) {
        let n = team.n;
        proj.p_times(&team.bias, &mut self.p_bias, &mut self.ops);
        self.p_bias -= &proj.pdot_v; // P h - Pdot v
        zeros_v(&mut self.mcinv_bias, n);
        if !proj.by_blocks {
            self.mcinv_bias.gemv(1.0, &proj.mc_inv, &self.p_bias, 0.0);
            return;
        }
        // M_c^{-1} x = x + Phi (x - M x) (eq. aghili_25, M_c^{-1} = I + Phi - Phi M).
        zeros_v(&mut self.t, n);
        self.t.copy_from(&self.p_bias);
        mass_times(team, -1.0, vmat(&self.p_bias), 1.0, vmat_mut(&mut self.t));
        proj.blocks.apply(
            BlockOp::Phi,
            vmat(&self.t),
            vmat_mut(&mut self.mcinv_bias),
            &mut self.ops,
        );
        self.mcinv_bias += &self.p_bias;
    }

    /// What the tasks read: these terms with the projections they were computed from.
    pub fn view<'a>(&'a self, proj: &'a Projections) -> MotionSpace<'a> {
        MotionSpace { proj, mcinv_bias: &self.mcinv_bias }
    }
}

/// What [`task_torque`] reads.
pub struct TaskTorqueInput<'a> {
    pub team: &'a Team,
    pub grasp: Option<&'a GraspTerms>,
    pub references: Option<&'a TaskReferences>,
    pub config: &'a PidcConfig,
    pub motion: MotionSpace<'a>,
}

/// `tau_M` (n): the superposition of the impedance tasks (eqn. joint_space_tau_M) of the
/// object (when grasped), every torso, every swing foot and every free hand
/// ([`walk_tasks`]), with the operational-space inertia and non-linear terms of eq.
/// control_law computed for the team's task space as a whole (every task's rows stacked; see
/// [`crate::building_blocks::impedance`]). Also the object's load
/// `F_x` (zero without a grasp) and `J_x^T F_x` (`load`, n). The object's and the torsos'
/// tasks are pushed with what they command held still, for when the motion yields
/// ([`crate::pidc::stages::yielding`]); the object's load held still is `F_x` at no
/// acceleration, into `f_x_hold`.
pub fn task_torque(
    inp: &TaskTorqueInput,
    targets: &mut Targets,
    stack: &mut TaskStack,
    tau_m: &mut DVector<f64>,
    load: &mut DVector<f64>,
    f_x: &mut Vector6<f64>,
    f_x_hold: &mut Vector6<f64>,
) -> Result<(), ControllerError> {
    let TaskTorqueInput { team, grasp, references: refs, config: cfg, motion } = inp;
    let n = team.n;
    stack.begin(task_row_count(team, *grasp), n);
    zeros_v(load, n);
    *f_x = Vector6::zeros();
    *f_x_hold = Vector6::zeros();
    let mut sink = ImpedanceSink { team, cfg, stack, load, f_x, f_x_hold };
    walk_tasks(team, *grasp, *refs, targets, &mut sink)?;
    stack.joint_torque(motion, tau_m)
}

/// Each task pushed as an impedance task on the stack, with its kind's gains; the object's
/// with its load.
struct ImpedanceSink<'a> {
    team: &'a Team,
    cfg: &'a PidcConfig,
    stack: &'a mut TaskStack,
    load: &'a mut DVector<f64>,
    f_x: &'a mut Vector6<f64>,
    f_x_hold: &'a mut Vector6<f64>,
}

impl TaskSink for ImpedanceSink<'_> {
    fn object(
        &mut self,
        g: &GraspTerms,
        err: &TaskError,
        acc_d: &[f64; 6],
    ) -> Result<(), ControllerError> {
        let cfg = self.cfg;
        // Object load feed-forward w_ff and the load F_x = -w_ff on the robots.
        let w_ff =
            object_load(&g.object, &g.object_twist, acc_d, cfg.object_mass, &cfg.object_inertia);
        let w_hold = object_load(
            &g.object,
            &g.object_twist,
            &[0.0; 6],
            cfg.object_mass,
            &cfg.object_inertia,
        );
        (*self.f_x, *self.f_x_hold) = (-w_ff, -w_hold);
        let hold = HoldStill {
            yields: Yields::Object,
            velocity: &g.object_twist,
            feed_forward: Some(&w_hold),
        };
        let cols = hands_columns(self.team);
        let gains = &cfg.object_gains;
        let task = TaskJacobian { j_x: &g.j_o, cols, jdv_x: &g.jdv_o };
        self.stack.push_yielding(task, err, gains, Some(&w_ff), hold)?;
        self.load.gemv_tr(1.0, &g.j_o, self.f_x, 0.0);
        Ok(())
    }

    fn torso(
        &mut self,
        tf: &TeamFrame,
        twist: &Vector6<f64>,
        err: &TaskError,
    ) -> Result<(), ControllerError> {
        let hold = HoldStill { yields: Yields::Torso, velocity: twist, feed_forward: None };
        let gains = &self.cfg.torso_gains;
        let task = TaskJacobian { j_x: &tf.jacobian, cols: tf.cols, jdv_x: &tf.jdot_v };
        self.stack.push_yielding(task, err, gains, None, hold)
    }

    fn swing_foot(&mut self, tf: &TeamFrame, err: &TaskError) -> Result<(), ControllerError> {
        let gains = &self.cfg.swing_gains;
        self.stack.push(&tf.jacobian, tf.cols, &tf.jdot_v, err, gains, None)
    }

    fn free_hand(&mut self, tf: &TeamFrame, err: &TaskError) -> Result<(), ControllerError> {
        let gains = &self.cfg.hand_gains;
        self.stack.push(&tf.jacobian, tf.cols, &tf.jdot_v, err, gains, None)
    }
}

/// The team columns the hands in grasp's robots span (first, count): the object's Jacobian
/// `J_o` is zero outside them.
fn hands_columns(team: &Team) -> (usize, usize) {
    let c0 = team.hands.iter().map(|h| h.cols.0).min().unwrap_or(0);
    let c1 = team.hands.iter().map(|h| h.cols.0 + h.cols.1).max().unwrap_or(0);
    (c0, c1.saturating_sub(c0))
}
