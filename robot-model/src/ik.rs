//! Inverse kinematics of one frame on the robot's own model (rapier's `multibody_ik` shape:
//! options plus a `joint_can_move` predicate): damped least squares on the frame's pose
//! (position and orientation, world frame). The floating base never moves (its coordinates
//! are not 1-DoF joints); of the 1-DoF joints that support the frame, those the predicate
//! allows change, each step clamped to [`MAX_JOINT_STEP`] and the result to the joint's
//! position limits.
//!
//! [`solve_hand`] is the arm of a described robot: the hand frame, every joint that moves it.
//! Where the hand should go (a face of the object) is planning, not IK:
//! `planner::grasp` decides it.

use nalgebra::{DMatrix, Matrix3, Matrix6, Matrix6xX, Rotation3, UnitQuaternion, Vector3, Vector6};
use thiserror::Error;

use crate::algorithm::{forward_kinematics, frame_jacobian};
use crate::data::Data;
use crate::description::Robot;
use crate::error::{DynamicsError, ModelError};
use crate::model::{FrameId, Model};
use crate::spatial::SE3;

/// Largest change of one joint in one iteration, rad (or m).
pub const MAX_JOINT_STEP: f64 = 0.2;

/// Options of [`solve`] (rapier's `InverseKinematicsOption`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkOptions {
    /// Added to the diagonal of `J Jᵀ` (the λ² of damped least squares).
    pub damping: f64,
    /// Iterations before giving up.
    pub max_iters: usize,
    /// Converged when the position error (m) is below this ...
    pub epsilon_linear: f64,
    /// ... and the angle error (rad) below this.
    pub epsilon_angular: f64,
}

impl Default for IkOptions {
    fn default() -> Self {
        IkOptions { damping: 1e-4, max_iters: 500, epsilon_linear: 1e-7, epsilon_angular: 1e-7 }
    }
}

/// Why IK found no answer.
#[derive(Debug, Error)]
pub enum IkError {
    #[error(
        "IK did not converge: position error {position_error} m, angle error {angle_error} rad \
         after {iterations} iterations"
    )]
    NoConvergence { position_error: f64, angle_error: f64, iterations: usize },
    #[error("no joint that may move moves frame {frame:?}")]
    NoJoint { frame: String },
    #[error("singular damped Jacobian")]
    Singular,
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Dynamics(#[from] DynamicsError),
}

/// A solved pose.
#[derive(Debug, Clone)]
pub struct IkSolution {
    /// Full configuration (the model's convention) with the joints solved.
    pub q: Vec<f64>,
    /// Solved joints: (name, position).
    pub joints: Vec<(String, f64)>,
    pub position_error: f64,
    pub angle_error: f64,
    pub iterations: usize,
    /// The target pose of the frame (world).
    pub target_position: Vector3<f64>,
    pub target_rotation: Matrix3<f64>,
}

/// Move the joints of `model` (configuration `q0`, base included) for which `joint_can_move`
/// (given the joint's velocity index) is true, so that `frame` reaches `(p_t, r_t)` (world).
pub fn solve(
    model: &Model,
    frame: FrameId,
    q0: &[f64],
    p_t: &Vector3<f64>,
    r_t: &Matrix3<f64>,
    options: &IkOptions,
    joint_can_move: impl Fn(usize) -> bool,
) -> Result<IkSolution, IkError> {
    solve_rows(model, frame, q0, p_t, Some(r_t), options, joint_can_move)
}

/// [`solve`] on the frame's position alone (a point foot: its orientation is free), the
/// solution's target rotation the frame's as solved.
pub fn solve_position(
    model: &Model,
    frame: FrameId,
    q0: &[f64],
    p_t: &Vector3<f64>,
    options: &IkOptions,
    joint_can_move: impl Fn(usize) -> bool,
) -> Result<IkSolution, IkError> {
    solve_rows(model, frame, q0, p_t, None, options, joint_can_move)
}

/// Damped least squares on the frame's position and, with `r_t`, its orientation.
fn solve_rows(
    model: &Model,
    frame: FrameId,
    q0: &[f64],
    p_t: &Vector3<f64>,
    r_t: Option<&Matrix3<f64>>,
    options: &IkOptions,
    joint_can_move: impl Fn(usize) -> bool,
) -> Result<IkSolution, IkError> {
    let f = model
        .frames
        .get(frame)
        .ok_or(DynamicsError::FrameOutOfRange { index: frame, count: model.frames.len() })?;
    let cols = moving_columns(model, f.body, joint_can_move);
    if cols.is_empty() {
        return Err(IkError::NoJoint { frame: f.name.clone() });
    }
    // velocity index -> configuration index of 1-DoF joints
    let qoff = model.nq - model.nv;
    let mut data = Data::new(model);
    let mut q = q0.to_vec();
    let zero = vec![0.0; model.nv];
    let mut jac = Matrix6xX::zeros(model.nv);
    let lambda2 = options.damping;
    let (mut pe, mut ae) = (f64::MAX, f64::MAX);
    for it in 0..options.max_iters {
        forward_kinematics(model, &mut data, &q, &zero)?;
        let m = data.o_m_f[frame];
        let (dp, dw) = pose_error(&m, p_t, r_t);
        pe = dp.norm();
        ae = dw.norm();
        if pe < options.epsilon_linear && ae < options.epsilon_angular {
            return Ok(finish(
                model,
                q,
                &cols,
                qoff,
                pe,
                ae,
                it,
                p_t,
                &r_t.copied().unwrap_or(m.rot),
            ));
        }
        frame_jacobian(model, &data, frame, &mut jac)?;
        let e = Vector6::new(dp.x, dp.y, dp.z, dw.x, dw.y, dw.z);
        // Position alone: the rotation rows are left out (zero rows, their damping keeps the
        // system regular).
        let rows = if r_t.is_some() { 6 } else { 3 };
        let ja = moving_rows(&jac, &cols, rows);
        let y = dls_multiplier(&ja, &e, lambda2)?;
        apply_step(model, &mut q, &ja, &y, &cols, qoff);
    }
    Err(IkError::NoConvergence {
        position_error: pe,
        angle_error: ae,
        iterations: options.max_iters,
    })
}

/// Velocity indices of the 1-DoF joints that support `body` and that the predicate lets move
/// (never the floating base).
fn moving_columns(
    model: &Model,
    body: usize,
    joint_can_move: impl Fn(usize) -> bool,
) -> Vec<usize> {
    let nb = if model.floating_base { 6 } else { 0 };
    model.bodies[body].support.iter().copied().filter(|&k| k >= nb && joint_can_move(k)).collect()
}

/// Position and orientation errors (world frame) from the frame's pose `m` to the target; no
/// orientation error without `r_t`.
fn pose_error(
    m: &SE3,
    p_t: &Vector3<f64>,
    r_t: Option<&Matrix3<f64>>,
) -> (Vector3<f64>, Vector3<f64>) {
    let dp = p_t - m.trans;
    // Through the quaternion: Rotation3::scaled_axis is NaN when rounding puts the trace
    // above 3 (see coordinator::linalg::rotation_error).
    let dw = r_t.map_or(Vector3::zeros(), |r_t| {
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
            r_t * m.rot.transpose(),
        ))
        .scaled_axis()
    });
    (dp, dw)
}

/// The Jacobian's columns `cols`, its first `rows` rows kept and the others zero (position
/// alone: the rotation rows are left out, their damping keeps the system regular).
fn moving_rows(jac: &Matrix6xX<f64>, cols: &[usize], rows: usize) -> DMatrix<f64> {
    DMatrix::from_fn(6, cols.len(), |r, c| if r < rows { jac[(r, cols[c])] } else { 0.0 })
}

/// Damped least squares, `dq = J^T (J J^T + lambda^2 I)^-1 e`: the multiplier
/// `y = (J J^T + lambda^2 I)^-1 e`.
fn dls_multiplier(
    ja: &DMatrix<f64>,
    e: &Vector6<f64>,
    lambda2: f64,
) -> Result<Vector6<f64>, IkError> {
    let jjt: Matrix6<f64> =
        Matrix6::from_fn(|r, c| (0..ja.ncols()).map(|k| ja[(r, k)] * ja[(c, k)]).sum::<f64>())
            + Matrix6::identity() * lambda2;
    let Some(inv) = jjt.try_inverse() else { return Err(IkError::Singular) };
    Ok(inv * e)
}

/// The step `dq = J^T y` on the moving joints, each clamped to [`MAX_JOINT_STEP`] and the
/// result to the joint's position limits.
fn apply_step(
    model: &Model,
    q: &mut [f64],
    ja: &DMatrix<f64>,
    y: &Vector6<f64>,
    cols: &[usize],
    qoff: usize,
) {
    for (c, &k) in cols.iter().enumerate() {
        let mut dq = (0..6).map(|r| ja[(r, c)] * y[r]).sum::<f64>();
        dq = dq.clamp(-MAX_JOINT_STEP, MAX_JOINT_STEP);
        let qi = qoff + k;
        q[qi] = (q[qi] + dq).clamp(model.lower_position_limit[qi], model.upper_position_limit[qi]);
    }
}

/// The arm of `robot`: its hand frame to `(p_t, r_t)` from `q0`, moving every joint that moves
/// the hand (base and the other limbs held).
pub fn solve_hand(
    robot: &Robot,
    q0: &[f64],
    p_t: &Vector3<f64>,
    r_t: &Matrix3<f64>,
    options: &IkOptions,
) -> Result<IkSolution, IkError> {
    let frame = robot.model.frame_id(&robot.hand_frame)?;
    solve(&robot.model, frame, q0, p_t, r_t, options, |_| true)
}

// Every argument is a field of the solution, or what its fields are read from.
#[allow(clippy::too_many_arguments)]
fn finish(
    model: &Model,
    q: Vec<f64>,
    cols: &[usize],
    qoff: usize,
    pe: f64,
    ae: f64,
    it: usize,
    p_t: &Vector3<f64>,
    r_t: &Matrix3<f64>,
) -> IkSolution {
    let nb = model.nv - model.joint_names.len();
    let joints = cols.iter().map(|&k| (model.joint_names[k - nb].clone(), q[qoff + k])).collect();
    IkSolution {
        q,
        joints,
        position_error: pe,
        angle_error: ae,
        iterations: it,
        target_position: *p_t,
        target_rotation: *r_t,
    }
}
