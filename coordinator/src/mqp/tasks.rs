//! The MQP's tasks (the paper's section "Controller Comparison"): the object, every torso and
//! every swing foot, each with its reference acceleration
//! `xdd_ref = xdd_des + K_p (x_des - x) + K_d (xd_des - xd)` (eq. of `\eeacceleration_{ref}`),
//! stacked as weighted rows `w (J_x qdd + Jdot_x v - xdd_ref)` of the objective.
//!
//! Targets, errors and the order of the tasks are the shell's ([`walk_tasks`], the same
//! [`Targets`] rules as PIDC: a task without a reference holds the pose it had when first seen).

use nalgebra::{DMatrix, DVector, Vector6};
use protocol::TaskReferences;

use crate::building_blocks::grasp::GraspTerms;
use crate::building_blocks::impedance::{Gains, TaskError};
use crate::building_blocks::targets::Targets;
use crate::controller_shell::tasks::{task_row_count, walk_tasks, TaskSink};
use crate::linalg::{zeros, zeros_v};
use crate::mqp::MqpConfig;
use crate::team::{Team, TeamFrame};
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
    fn push(
        &mut self,
        j_x: &DMatrix<f64>,
        jdv_x: &DVector<f64>,
        err: &TaskError,
        gains: &Gains,
        weight: f64,
    ) {
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

/// The tick's tasks into `rows` ([`walk_tasks`]); also returns the object's desired
/// acceleration (zero without a grasp), which the report keeps.
pub fn task_rows(
    inp: &TaskRowsInput,
    targets: &mut Targets,
    rows: &mut TaskRows,
) -> Result<Vector6<f64>, ControllerError> {
    let TaskRowsInput { team, grasp, references: refs, config: cfg } = inp;
    let k = task_row_count(team, *grasp);
    rows.begin(k, team.n);
    let mut sink = RowSink { rows, cfg, object_acc_d: Vector6::zeros() };
    walk_tasks(team, *grasp, *refs, targets, &mut sink)?;
    let object_acc_d = sink.object_acc_d;
    if rows.at != k {
        return Err(ControllerError::Dimension {
            what: "mqp tasks".into(),
            detail: format!("{} of {k} task rows filled", rows.at),
        });
    }
    Ok(object_acc_d)
}

/// Each task as weighted acceleration rows, with its kind's gains and weight.
struct RowSink<'a> {
    rows: &'a mut TaskRows,
    cfg: &'a MqpConfig,
    /// The object's desired acceleration (zero without a grasp).
    object_acc_d: Vector6<f64>,
}

impl TaskSink for RowSink<'_> {
    fn object(
        &mut self,
        g: &GraspTerms,
        err: &TaskError,
        _acc_d: &[f64; 6],
    ) -> Result<(), ControllerError> {
        let cfg = self.cfg;
        self.object_acc_d = err.acc_d;
        self.rows.push(&g.j_o, &g.jdv_o, err, &cfg.object_gains, cfg.object_weight);
        Ok(())
    }

    fn torso(
        &mut self,
        tf: &TeamFrame,
        _twist: &Vector6<f64>,
        err: &TaskError,
    ) -> Result<(), ControllerError> {
        let cfg = self.cfg;
        self.rows.push(&tf.jacobian, &tf.jdot_v, err, &cfg.torso_gains, cfg.torso_weight);
        Ok(())
    }

    fn swing_foot(&mut self, tf: &TeamFrame, err: &TaskError) -> Result<(), ControllerError> {
        let cfg = self.cfg;
        self.rows.push(&tf.jacobian, &tf.jdot_v, err, &cfg.swing_gains, cfg.swing_weight);
        Ok(())
    }

    fn free_hand(&mut self, tf: &TeamFrame, err: &TaskError) -> Result<(), ControllerError> {
        let cfg = self.cfg;
        self.rows.push(&tf.jacobian, &tf.jdot_v, err, &cfg.hand_gains, cfg.hand_weight);
        Ok(())
    }
}
