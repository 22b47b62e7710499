//! Where the hands go at the start of a run: each robot's hand flat on the face of the object
//! that looks at it. This is planning (which face, where on it); the arm solve itself is
//! `robot_model::ik`.
//!
//! The face is the object face whose outward normal points most toward the robot's base. The
//! hand target: `hand_contact` on the face level with the face centre and, along the face,
//! in front of the base (robots spaced along a long face hold it where they stand, kept
//! [`FACE_END_MARGIN`] from its ends), palm normal
//! (`+z`) anti-parallel to the face's outward normal, hand `x` horizontal (`x = e_z x z`), as in
//! the standing pose of the default robot. Each arm is solved on the robot's own model, base
//! fixed at its placement, legs at their configuration, only the joints that move the hand
//! frame changing, within their position limits.

use std::sync::Arc;

use nalgebra::Isometry3;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use protocol::conventions::quat_from_wxyz;
use robot_model::ik::{self, IkError, IkOptions, IkSolution};
use robot_model::{Data, Robot};
use thiserror::Error;

use crate::placement::{BasePlacement, ObjectBox, FACE_END_MARGIN};

/// Why the hands could not be placed.
#[derive(Debug, Error)]
pub enum GraspPlanError {
    #[error("robot {robot}: {source}")]
    Ik { robot: String, source: IkError },
    #[error("the world has no object to put the hands on")]
    NoObject,
    #[error(
        "robot {robot}: only a floating-base robot can be placed (its base pose is part of q)"
    )]
    FixedBase { robot: String },
    #[error("{robots} robots loaded for {placements} placements")]
    RobotCount { robots: usize, placements: usize },
    #[error("robot {robot}: the hand's pose: {reason}")]
    Kinematics { robot: String, reason: String },
}

/// Target pose of the hand frame on the face of `object` that faces a base at `base`.
pub fn face_target(
    object: &ObjectBox,
    base: &Vector3<f64>,
    hand_height: Option<f64>,
) -> (Vector3<f64>, Matrix3<f64>) {
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
    // Along the face's horizontal axis: in front of the base, inside the face.
    for axis in (0..3).filter(|a| *a != best.0) {
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        let e = ro.transform_vector(&e);
        if e.z.abs() < 1e-9 {
            let room = (object.size[axis] / 2.0 - FACE_END_MARGIN).max(0.0);
            p += e * e.dot(&(base - po)).clamp(-room, room);
        }
    }
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

/// Put every robot's hand flat on its face of `object`: solves each arm on the robot's own
/// model (`robots`: loaded, in the placements' order) from its placement and writes the arm
/// joints into the placement's overrides. Returns the solutions in robot order.
pub fn place_hands(
    object: &ObjectBox,
    placements: &mut [BasePlacement],
    robots: &[Arc<Robot>],
) -> Result<Vec<IkSolution>, GraspPlanError> {
    if robots.len() != placements.len() {
        return Err(GraspPlanError::RobotCount {
            robots: robots.len(),
            placements: placements.len(),
        });
    }
    let mut out = Vec::new();
    for (r, robot) in placements.iter_mut().zip(robots) {
        if !robot.model.floating_base {
            return Err(GraspPlanError::FixedBase { robot: r.id.clone() });
        }
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
        let (p, rot) = face_target(object, &base, None);
        let sol = ik::solve_hand(robot, &q, &p, &rot, &IkOptions::default())
            .map_err(|source| GraspPlanError::Ik { robot: r.id.clone(), source })?;
        for (name, v) in &sol.joints {
            r.joint_overrides.insert(name.clone(), *v);
        }
        tracing::debug!(robot = %r.id, joints = ?sol.joints, "hand placed on the object");
        out.push(sol);
    }
    Ok(out)
}

/// Each hand's pose as planned: its frame's world pose at the solved configuration
/// (`solutions`, from [`place_hands`], robot order). With the object's pose at the grasp it
/// is the hand's grasp on the object, which the controller fits the object from whenever it
/// starts (the runner hands it over as `coordinator::building_blocks::grasp::PlannedHand`).
pub fn hand_poses(
    placements: &[BasePlacement],
    robots: &[Arc<Robot>],
    solutions: &[IkSolution],
) -> Result<Vec<Isometry3<f64>>, GraspPlanError> {
    let mut out = Vec::with_capacity(robots.len());
    for ((r, robot), sol) in placements.iter().zip(robots).zip(solutions) {
        let fail = |e: &dyn std::fmt::Display| GraspPlanError::Kinematics {
            robot: r.id.clone(),
            reason: e.to_string(),
        };
        let frame = robot.model.frame_id(&robot.hand_frame).map_err(|e| fail(&e))?;
        let mut data = Data::new(&robot.model);
        robot_model::forward_kinematics(
            &robot.model,
            &mut data,
            &sol.q,
            &vec![0.0; robot.model.nv],
        )
        .map_err(|e| fail(&e))?;
        let m = robot_model::frame_placement(&robot.model, &data, frame).map_err(|e| fail(&e))?;
        out.push(Isometry3::from_parts(m.trans.into(), UnitQuaternion::from_matrix(&m.rot)));
    }
    Ok(out)
}
