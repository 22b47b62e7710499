//! Arm inverse kinematics on OUR robot model (`robot_agent::dynamics`), so that each hand lies
//! flat on its face of the object: damped least squares on the hand contact frame (position
//! and orientation, world frame), base fixed at its placement, legs at their configuration,
//! only the joints that move the hand frame (velocity indices after the base) change, kept
//! within their position limits.
//!
//! The face is the object face whose outward normal points most toward the robot's base. The
//! hand target: `hand_contact` at the face's point level with the face centre, palm normal
//! (`+z`) anti-parallel to the face's outward normal, hand `x` horizontal (`x = e_z x z`), as in
//! the standing pose of the default robot.

use nalgebra::{Matrix3, Matrix6, Matrix6xX, Rotation3, UnitQuaternion, Vector3, Vector6};
use protocol::conventions::quat_from_wxyz;
use robot_agent::description::Robot;
use robot_agent::dynamics::{forward_kinematics, frame_jacobian, Data};
use thiserror::Error;

use crate::world::{ObjectSpec, WorldSpec};

#[derive(Debug, Error)]
pub enum IkError {
    #[error("robot {robot}: IK did not converge: position error {position_error} m, angle error {angle_error} rad after {iterations} iterations")]
    NoConvergence { robot: String, position_error: f64, angle_error: f64, iterations: usize },
    #[error("robot {robot}: {reason}")]
    Model { robot: String, reason: String },
    #[error("the world has no object to put the hands on")]
    NoObject,
}

/// A solved arm.
#[derive(Debug, Clone)]
pub struct IkSolution {
    /// Full configuration (our convention) with the arm solved.
    pub q: Vec<f64>,
    /// Solved joints: (name, position).
    pub joints: Vec<(String, f64)>,
    pub position_error: f64,
    pub angle_error: f64,
    pub iterations: usize,
    /// The target pose of the hand contact frame (world).
    pub target_position: Vector3<f64>,
    pub target_rotation: Matrix3<f64>,
}

/// Target pose of the hand frame on the face of `object` that faces a base at `base`.
pub fn face_target(object: &ObjectSpec, base: &Vector3<f64>, hand_height: Option<f64>) -> (Vector3<f64>, Matrix3<f64>) {
    let ro = quat_from_wxyz(object.orientation);
    let po = Vector3::from(object.position);
    let to_base = ro.inverse_transform_vector(&(base - po));
    // The face (in the object's frame) most toward the base.
    let mut best = (0usize, 1.0f64, f64::MIN);
    for axis in 0..3 {
        for sign in [1.0, -1.0] {
            let d = sign * to_base[axis] / (object.size[axis] / 2.0);
            if d > best.2 {
                best = (axis, sign, d);
            }
        }
    }
    let mut n_local = Vector3::zeros();
    n_local[best.0] = best.1;
    let n = ro.transform_vector(&n_local);
    let mut p = po + n * (object.size[best.0] / 2.0);
    if let Some(h) = hand_height {
        // Slide along the face (keep on its plane) to the requested height if it is vertical.
        if n.z.abs() < 1e-9 {
            p.z = h;
        }
    }
    let z = -n;
    let mut x = Vector3::z().cross(&z);
    if x.norm() < 1e-9 {
        x = Vector3::x().cross(&z);
    }
    let x = x.normalize();
    let y = z.cross(&x);
    (p, Matrix3::from_columns(&[x, y, z]))
}

/// Solve the arm of `robot` (configuration `q0`, base included) so that its hand frame reaches
/// `(p_t, r_t)`.
pub fn solve(robot: &Robot, id: &str, q0: &[f64], p_t: &Vector3<f64>, r_t: &Matrix3<f64>) -> Result<IkSolution, IkError> {
    let model = &robot.model;
    let err = |reason: String| IkError::Model { robot: id.to_string(), reason };
    let frame = model.frame_id(&robot.hand_frame).map_err(|e| err(e.to_string()))?;
    let nb = if model.floating_base { 6 } else { 0 };
    let cols: Vec<usize> = model.bodies[model.frames[frame].body].support.iter().copied().filter(|&k| k >= nb).collect();
    if cols.is_empty() {
        return Err(err("no joint moves the hand frame".into()));
    }
    // velocity index -> configuration index of 1-DoF joints
    let qoff = model.nq - model.nv;
    let mut data = Data::new(model);
    let mut q = q0.to_vec();
    let zero = vec![0.0; model.nv];
    let mut jac = Matrix6xX::zeros(model.nv);
    let lambda2 = 1e-4;
    let (mut pe, mut ae) = (f64::MAX, f64::MAX);
    for it in 0..500 {
        forward_kinematics(model, &mut data, &q, &zero).map_err(|e| err(e.to_string()))?;
        let m = data.o_m_f[frame];
        let dp = p_t - m.trans;
        let r_err = Rotation3::from_matrix_unchecked(r_t * m.rot.transpose());
        let dw = r_err.scaled_axis();
        pe = dp.norm();
        ae = dw.norm();
        if pe < 1e-7 && ae < 1e-7 {
            return Ok(finish(robot, q, &cols, qoff, pe, ae, it, p_t, r_t));
        }
        frame_jacobian(model, &data, frame, &mut jac).map_err(|e| err(e.to_string()))?;
        let e = Vector6::new(dp.x, dp.y, dp.z, dw.x, dw.y, dw.z);
        let ja = nalgebra::DMatrix::from_fn(6, cols.len(), |r, c| jac[(r, cols[c])]);
        let jjt: Matrix6<f64> = Matrix6::from_fn(|r, c| (0..cols.len()).map(|k| ja[(r, k)] * ja[(c, k)]).sum::<f64>()) + Matrix6::identity() * lambda2;
        let Some(inv) = jjt.try_inverse() else { return Err(err("singular damped Jacobian".into())) };
        let y = inv * e;
        for (c, &k) in cols.iter().enumerate() {
            let mut dq = (0..6).map(|r| ja[(r, c)] * y[r]).sum::<f64>();
            dq = dq.clamp(-0.2, 0.2);
            let qi = qoff + k;
            q[qi] = (q[qi] + dq).clamp(model.lower_position_limit[qi], model.upper_position_limit[qi]);
        }
    }
    Err(IkError::NoConvergence { robot: id.to_string(), position_error: pe, angle_error: ae, iterations: 500 })
}

#[allow(clippy::too_many_arguments)]
fn finish(robot: &Robot, q: Vec<f64>, cols: &[usize], qoff: usize, pe: f64, ae: f64, it: usize, p_t: &Vector3<f64>, r_t: &Matrix3<f64>) -> IkSolution {
    let nb = robot.model.nv - robot.model.joint_names.len();
    let joints = cols.iter().map(|&k| (robot.model.joint_names[k - nb].clone(), q[qoff + k])).collect();
    IkSolution { q, joints, position_error: pe, angle_error: ae, iterations: it, target_position: *p_t, target_rotation: *r_t }
}

/// Put every robot's hand flat on its face of the object: solves each arm on the robot's own
/// model from its placement and writes the arm joints into the placement's overrides.
/// Returns the solutions in robot order.
pub fn place_hands(spec: &mut WorldSpec) -> Result<Vec<IkSolution>, IkError> {
    let object = spec.object.ok_or(IkError::NoObject)?;
    let mut out = Vec::new();
    for r in &mut spec.robots {
        let robot = Robot::load(&r.description).map_err(|e| IkError::Model { robot: r.id.clone(), reason: e.to_string() })?;
        let mut q: Vec<f64> = robot.standing_q.iter().copied().collect();
        let off = robot.model.nq - robot.model.joint_names.len();
        for (j, v) in &r.joint_overrides {
            if let Some(k) = robot.model.joint_names.iter().position(|n| n == j) {
                q[off + k] = *v;
            }
        }
        q[0..3].copy_from_slice(&r.base_position);
        let yaw = UnitQuaternion::from_euler_angles(0.0, 0.0, r.base_yaw);
        q[3..7].copy_from_slice(&[yaw.w, yaw.i, yaw.j, yaw.k]);
        let base = Vector3::from(r.base_position);
        let (p, rot) = face_target(&object, &base, None);
        let sol = solve(&robot, &r.id, &q, &p, &rot)?;
        for (name, v) in &sol.joints {
            r.joint_overrides.insert(name.clone(), *v);
        }
        out.push(sol);
    }
    Ok(out)
}
