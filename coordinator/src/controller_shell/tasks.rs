//! The walk over a tick's tasks that every law of the shell shares: the carried object (when
//! grasped), every torso, every swing foot and every free hand, in that order, each with its
//! target ([`Targets`]: a task without a reference holds the pose it had when first seen) and
//! its error ([`TaskError`]: `e = x - x_des`, `edot`, the desired acceleration). A law stacks
//! them its own way ([`TaskSink`]): PIDC as impedance tasks (eqs. control_law,
//! joint_space_tau_M), MQP as weighted acceleration rows of its objective.

use nalgebra::{Vector3, Vector6};
use protocol::TaskReferences;

use crate::building_blocks::grasp::GraspTerms;
use crate::building_blocks::impedance::{point_error, pose_error, TaskError};
use crate::building_blocks::targets::{frame_pose, Targets};
use crate::team::{Team, TeamFrame};
use crate::ControllerError;

/// What a law does with each task of a tick ([`walk_tasks`]).
pub trait TaskSink {
    /// The object's pose task (`J_o`, `Jdot_o v` are `g`'s), with its desired acceleration
    /// `acc_d` as the target gave it.
    fn object(
        &mut self,
        g: &GraspTerms,
        err: &TaskError,
        acc_d: &[f64; 6],
    ) -> Result<(), ControllerError>;
    /// A torso's pose task, with the torso's twist.
    fn torso(
        &mut self,
        tf: &TeamFrame,
        twist: &Vector6<f64>,
        err: &TaskError,
    ) -> Result<(), ControllerError>;
    /// A swing foot's position task.
    fn swing_foot(&mut self, tf: &TeamFrame, err: &TaskError) -> Result<(), ControllerError>;
    /// A free hand's pose task (it holds its pose).
    fn free_hand(&mut self, tf: &TeamFrame, err: &TaskError) -> Result<(), ControllerError>;
}

/// The rows of every task of a tick: the object's (when grasped), then every torso's, swing
/// foot's and free hand's.
pub fn task_row_count(team: &Team, grasp: Option<&GraspTerms>) -> usize {
    let frames = team.torsos.iter().chain(&team.swing_feet).chain(&team.free_hands);
    grasp.map_or(0, |g| g.j_o.nrows()) + frames.map(|t| t.jacobian.nrows()).sum::<usize>()
}

/// Every task of the tick into `sink`, in the order of [`task_row_count`]; the free hands' and
/// swing feet's kept targets are updated to the team's before the free hands' tasks.
pub fn walk_tasks(
    team: &Team,
    grasp: Option<&GraspTerms>,
    refs: Option<&TaskReferences>,
    targets: &mut Targets,
    sink: &mut impl TaskSink,
) -> Result<(), ControllerError> {
    if let Some(g) = grasp {
        let (x_d, tw_d, acc_d) = targets.object(refs, &g.object);
        let err = pose_error(&g.object, &g.object_twist, &x_d, &tw_d, &acc_d);
        sink.object(g, &err, &acc_d)?;
    }
    for tf in &team.torsos {
        let id = &team.robots[tf.robot].id;
        let (x, twist) = frame_pose(tf, &team.velocity);
        let (x_d, tw_d, acc_d) = targets.torso(refs, id, &x);
        let err = pose_error(&x, &twist, &x_d, &tw_d, &acc_d);
        sink.torso(tf, &twist, &err)?;
    }
    for tf in &team.swing_feet {
        let id = &team.robots[tf.robot].id;
        let (p_d, v_d, a_d) = targets.swing_foot(refs, id, &tf.name, &tf.position);
        let vel: Vector3<f64> = tf.velocity(&team.velocity).fixed_rows::<3>(0).into();
        let err = point_error(&tf.position, &vel, &p_d, &v_d, &a_d);
        sink.swing_foot(tf, &err)?;
    }
    targets.keep_free_hands(team);
    targets.keep_swing_feet(team);
    for tf in &team.free_hands {
        let (x, twist) = frame_pose(tf, &team.velocity);
        let (x_d, tw_d, acc_d) = targets.free_hand(&team.robots[tf.robot].id, &x);
        let err = pose_error(&x, &twist, &x_d, &tw_d, &acc_d);
        sink.free_hand(tf, &err)?;
    }
    Ok(())
}
