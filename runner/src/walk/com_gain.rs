//! How far a standing robot's centre of mass moves when its torso shifts horizontally while
//! its feet (and its hand, on the object) stay where they are: the legs and the arm take up
//! the shift, so the CoM moves less than the torso (the shanks and the forearm hardly move).
//! The crawl planner shifts torsos with this gain ([`crate::gait::WalkingRobot::com_gain`]).
//!
//! The constrained motion: a base translation `e` (world) with base twist `[R^T e; 0]` (the
//! base frame, the model's convention) and joint velocities `v_j` that keep every held frame
//! still, `J_j v_j = -J_b v_b` (least squares; joints that move no held frame stay put); the
//! CoM's velocity along it by a central difference of [`robot_model::center_of_mass`].

use nalgebra::{DMatrix, DVector, Matrix2, Matrix6xX, Rotation2, Vector3};
use robot_model::{center_of_mass, forward_kinematics, frame_jacobian, Data, Robot};

/// Step of the central difference along the constrained motion, m.
const STEP: f64 = 1e-5;

/// Joint velocities (the model's velocity vector) of robot `robot` at configuration `q` (base
/// included) when its base translates at `e` (world, m/s) with `held` frames still.
pub fn held_motion(robot: &Robot, q: &[f64], e: &Vector3<f64>, held: &[&str]) -> Result<DVector<f64>, String> {
    let model = &robot.model;
    let mut data = Data::new(model);
    forward_kinematics(model, &mut data, q, &vec![0.0; model.nv]).map_err(|e| e.to_string())?;
    let mut rows: Vec<DMatrix<f64>> = Vec::new();
    let mut jac = Matrix6xX::zeros(model.nv);
    for name in held {
        let f = model.frame_id(name).map_err(|e| e.to_string())?;
        frame_jacobian(model, &data, f, &mut jac).map_err(|e| e.to_string())?;
        // A foot is a point (3 rows), the hand a rigid grasp (6 rows).
        let n = if *name == robot.hand_frame { 6 } else { 3 };
        rows.push(DMatrix::from_fn(n, model.nv, |r, c| jac[(r, c)]));
    }
    let m: usize = rows.iter().map(|r| r.nrows()).sum();
    let mut j = DMatrix::zeros(m, model.nv);
    let mut at = 0;
    for r in &rows {
        j.rows_mut(at, r.nrows()).copy_from(r);
        at += r.nrows();
    }
    let rot = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[3], q[4], q[5], q[6]));
    let mut v = DVector::zeros(model.nv);
    v.fixed_rows_mut::<3>(0).copy_from(&(rot.inverse() * e));
    let rhs = -(&j.columns(0, 6) * v.rows(0, 6));
    let vj = j.columns(6, model.nv - 6).into_owned().pseudo_inverse(1e-9).map_err(|e| e.to_string())? * rhs;
    v.rows_mut(6, model.nv - 6).copy_from(&vj);
    Ok(v)
}

/// The configuration `q` moved by `dt` along the velocity `v` with the base translating at
/// `e` (world): positions only, the base orientation held.
pub fn advance(q: &[f64], v: &DVector<f64>, e: &Vector3<f64>, dt: f64) -> Vec<f64> {
    let mut out = q.to_vec();
    for k in 0..3 {
        out[k] += dt * e[k];
    }
    for (k, vk) in v.iter().enumerate().skip(6) {
        out[k + 1] += dt * vk;
    }
    out
}

/// The CoM's horizontal displacement per metre of horizontal torso shift, in the torso's own
/// (yaw) frame, for robot `robot` standing at `q` with its feet and, when `hand_held`, its hand
/// held where they are.
pub fn com_shift_gain(robot: &Robot, q: &[f64], hand_held: bool) -> Result<Matrix2<f64>, String> {
    let mut held: Vec<&str> = robot.foot_frames.iter().map(String::as_str).collect();
    if hand_held {
        held.push(robot.hand_frame.as_str());
    }
    let com = |q: &[f64]| {
        let mut data = Data::new(&robot.model);
        forward_kinematics(&robot.model, &mut data, q, &vec![0.0; robot.model.nv]).map(|_| center_of_mass(&robot.model, &data).1).map_err(|e| e.to_string())
    };
    let mut world = Matrix2::zeros();
    for (c, e) in [Vector3::x(), Vector3::y()].iter().enumerate() {
        let v = held_motion(robot, q, e, &held)?;
        let d = (com(&advance(q, &v, e, STEP))? - com(&advance(q, &v, e, -STEP))?) / (2.0 * STEP);
        world.set_column(c, &d.xy());
    }
    let yaw = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[3], q[4], q[5], q[6])).euler_angles().2;
    let r = Rotation2::new(yaw).into_inner();
    Ok(r.transpose() * world * r)
}
