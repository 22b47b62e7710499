//! The motion tasks of a tick: each task's target ([`Targets`], from
//! [`crate::units::targets`]), the carried object's load (the paper's `J_x^T F_x` of eq.
//! js_dynamics, from [`crate::units::object_load`]), the motion-space terms every task shares
//! ([`MotionSpaceTerms`]) and the motion torque `tau_M` (eqs. control_law,
//! joint_space_tau_M; [`task_torque`]).

use nalgebra::{DVector, Vector3, Vector6};
use protocol::TaskReferences;

use crate::linalg::zeros_v;
use crate::pidc::PidcConfig;
use crate::team::Team;
use crate::units::grasp::GraspTerms;
use crate::units::block_projection::{vmat, vmat_mut, BlockOp, OpScratch};
use crate::units::impedance::{point_error, pose_error, HoldStill, MotionSpace, TaskStack, Yields};
use crate::units::object_load::object_load;
use crate::units::projection::{mass_times, Projections};
pub use crate::units::targets::{frame_pose, PointTarget, PoseTarget, Targets};
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
        proj.blocks.apply(BlockOp::Phi, vmat(&self.t), vmat_mut(&mut self.mcinv_bias), &mut self.ops);
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
/// object (when grasped), every torso, every swing foot and every free hand, with the operational-space
/// inertia and non-linear terms of eq. control_law computed for the team's task space as a
/// whole (every task's rows stacked; see [`crate::units::impedance`]). Also the object's load
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
    let frames = team.torsos.iter().chain(&team.swing_feet).chain(&team.free_hands);
    let k_rows = grasp.map_or(0, |g| g.j_o.nrows()) + frames.map(|t| t.jacobian.nrows()).sum::<usize>();
    stack.begin(k_rows, n);
    zeros_v(load, n);
    *f_x = Vector6::zeros();
    *f_x_hold = Vector6::zeros();
    if let Some(g) = grasp {
        let (x_d, tw_d, acc_d) = targets.object(*refs, &g.object);
        let err = pose_error(&g.object, &g.object_twist, &x_d, &tw_d, &acc_d);
        // Object load feed-forward w_ff and the load F_x = -w_ff on the robots.
        let w_ff = object_load(&g.object, &g.object_twist, &acc_d, cfg.object_mass, &cfg.object_inertia);
        let w_hold = object_load(&g.object, &g.object_twist, &[0.0; 6], cfg.object_mass, &cfg.object_inertia);
        (*f_x, *f_x_hold) = (-w_ff, -w_hold);
        let hold = HoldStill { yields: Yields::Object, velocity: &g.object_twist, feed_forward: Some(&w_hold) };
        stack.push_yielding(&g.j_o, hands_columns(team), &g.jdv_o, &err, &cfg.object_gains, Some(&w_ff), hold)?;
        load.gemv_tr(1.0, &g.j_o, f_x, 0.0);
    }
    for tf in &team.torsos {
        let id = &team.robots[tf.robot].id;
        let (x, twist) = frame_pose(tf, &team.velocity);
        let (x_d, tw_d, acc_d) = targets.torso(*refs, id, &x);
        let err = pose_error(&x, &twist, &x_d, &tw_d, &acc_d);
        let hold = HoldStill { yields: Yields::Torso, velocity: &twist, feed_forward: None };
        stack.push_yielding(&tf.jacobian, tf.cols, &tf.jdot_v, &err, &cfg.torso_gains, None, hold)?;
    }
    for tf in &team.swing_feet {
        let id = &team.robots[tf.robot].id;
        let (p_d, v_d, a_d) = targets.swing_foot(*refs, id, &tf.name, &tf.position);
        let vel: Vector3<f64> = tf.velocity(&team.velocity).fixed_rows::<3>(0).into();
        let err = point_error(&tf.position, &vel, &p_d, &v_d, &a_d);
        stack.push(&tf.jacobian, tf.cols, &tf.jdot_v, &err, &cfg.swing_gains, None)?;
    }
    targets.keep_free_hands(team);
    targets.keep_swing_feet(team);
    for tf in &team.free_hands {
        let (x, twist) = frame_pose(tf, &team.velocity);
        let (x_d, tw_d, acc_d) = targets.free_hand(&team.robots[tf.robot].id, &x);
        let err = pose_error(&x, &twist, &x_d, &tw_d, &acc_d);
        stack.push(&tf.jacobian, tf.cols, &tf.jdot_v, &err, &cfg.hand_gains, None)?;
    }
    stack.joint_torque(motion, tau_m)
}

/// The team columns the hands in grasp's robots span (first, count): the object's Jacobian
/// `J_o` is zero outside them.
fn hands_columns(team: &Team) -> (usize, usize) {
    let c0 = team.hands.iter().map(|h| h.cols.0).min().unwrap_or(0);
    let c1 = team.hands.iter().map(|h| h.cols.0 + h.cols.1).max().unwrap_or(0);
    (c0, c1.saturating_sub(c0))
}
