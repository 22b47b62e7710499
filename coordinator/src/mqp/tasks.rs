//! The MQP's tasks (the paper's section "Controller Comparison"): the object, every torso and
//! every swing foot, each with its reference acceleration
//! `xdd_ref = xdd_des + K_p (x_des - x) + K_d (xd_des - xd)` (eq. of `\eeacceleration_{ref}`),
//! stacked as weighted rows `w (J_x qdd + Jdot_x v - xdd_ref)` of the objective.
//!
//! Targets, errors and the object pose are the coordinator's units (the same
//! [`Targets`] rules as PIDC: a task without a reference holds the pose it had when first seen).

use nalgebra::{DMatrix, DVector, Vector3, Vector6};
use protocol::TaskReferences;

use crate::linalg::{zeros, zeros_v};
use crate::mqp::MqpConfig;
use crate::units::targets::{frame_pose, Targets};
use crate::team::Team;
use crate::units::grasp::GraspTerms;
use crate::units::impedance::{point_error, pose_error, Gains, TaskError};
use crate::ControllerError;

/// Every task of a tick stacked: `J` (k x n), `rhs = xdd_ref - Jdot v` (k) and each row's weight.
#[derive(Debug, Clone, Default)]
pub struct TaskRows {
    pub j: DMatrix<f64>,
    pub rhs: DVector<f64>,
    pub weight: DVector<f64>,
    at: usize,
}

impl TaskRows {
    fn begin(&mut self, k: usize, n: usize) {
        zeros(&mut self.j, k, n);
        zeros_v(&mut self.rhs, k);
        zeros_v(&mut self.weight, k);
        self.at = 0;
    }

    /// One task: `xdd_ref = acc_d - K_p e - K_d edot` (`e = x - x_des`).
    fn push(&mut self, j_x: &DMatrix<f64>, jdv_x: &DVector<f64>, err: &TaskError, gains: &Gains, weight: f64) {
        let d = j_x.nrows();
        self.j.rows_mut(self.at, d).copy_from(j_x);
        for i in 0..d {
            let xdd_ref = err.acc_d[i] - gains.kp[i] * err.e[i] - gains.kd[i] * err.edot[i];
            self.rhs[self.at + i] = xdd_ref - jdv_x[i];
            self.weight[self.at + i] = weight;
        }
        self.at += d;
    }
}

/// What [`task_rows`] reads.
pub struct TaskRowsInput<'a> {
    pub team: &'a Team,
    pub grasp: Option<&'a GraspTerms>,
    pub references: Option<&'a TaskReferences>,
    pub config: &'a MqpConfig,
}

/// The tick's tasks into `rows`; also returns the object's desired acceleration (zero without
/// a grasp), which the report keeps.
pub fn task_rows(inp: &TaskRowsInput, targets: &mut Targets, rows: &mut TaskRows) -> Result<Vector6<f64>, ControllerError> {
    let TaskRowsInput { team, grasp, references: refs, config: cfg } = inp;
    let frames = team.torsos.iter().chain(&team.swing_feet).chain(&team.free_hands);
    let k = grasp.map_or(0, |g| g.j_o.nrows()) + frames.map(|t| t.jacobian.nrows()).sum::<usize>();
    rows.begin(k, team.n);
    let mut object_acc_d = Vector6::zeros();
    if let Some(g) = grasp {
        let (x_d, tw_d, acc_d) = targets.object(*refs, &g.object);
        let err = pose_error(&g.object, &g.object_twist, &x_d, &tw_d, &acc_d);
        object_acc_d = err.acc_d;
        rows.push(&g.j_o, &g.jdv_o, &err, &cfg.object_gains, cfg.object_weight);
    }
    for tf in &team.torsos {
        let id = &team.robots[tf.robot].id;
        let (x, twist) = frame_pose(tf, &team.velocity);
        let (x_d, tw_d, acc_d) = targets.torso(*refs, id, &x);
        let err = pose_error(&x, &twist, &x_d, &tw_d, &acc_d);
        rows.push(&tf.jacobian, &tf.jdot_v, &err, &cfg.torso_gains, cfg.torso_weight);
    }
    for tf in &team.swing_feet {
        let id = &team.robots[tf.robot].id;
        let (p_d, v_d, a_d) = targets.swing_foot(*refs, id, &tf.name, &tf.position);
        let vel: Vector3<f64> = tf.velocity(&team.velocity).fixed_rows::<3>(0).into();
        let err = point_error(&tf.position, &vel, &p_d, &v_d, &a_d);
        rows.push(&tf.jacobian, &tf.jdot_v, &err, &cfg.swing_gains, cfg.swing_weight);
    }
    targets.keep_free_hands(team);
    targets.keep_swing_feet(team);
    for tf in &team.free_hands {
        let (x, twist) = frame_pose(tf, &team.velocity);
        let (x_d, tw_d, acc_d) = targets.free_hand(&team.robots[tf.robot].id, &x);
        let err = pose_error(&x, &twist, &x_d, &tw_d, &acc_d);
        rows.push(&tf.jacobian, &tf.jdot_v, &err, &cfg.hand_gains, cfg.hand_weight);
    }
    if rows.at != k {
        return Err(ControllerError::Dimension { what: "mqp tasks".into(), detail: format!("{} of {k} task rows filled", rows.at) });
    }
    Ok(object_acc_d)
}
