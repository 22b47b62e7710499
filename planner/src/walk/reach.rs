//! Whether a walking robot's arm can keep its hand on the object all along the walk: with the
//! torso at every pose the crawl puts it in (each step's shift, where the torso sways furthest,
//! and the last waypoint), the hand's grasp pose (fixed on the object, which moves with the
//! team in a transport) is solved by IK within the arm's joint limits, and the arm's joints
//! must hold the object's push on the hand (the start pose's static forces) within their
//! torque limits there. A walk that asks more
//! is refused before the run, naming the robot, the time and how far its torso is from its
//! start: run anyway, the grasp would be lost there.

use nalgebra::{Isometry3, Matrix6xX, Translation3, UnitQuaternion};
use robot_model::ik::{self, IkOptions};
use robot_model::{forward_kinematics, frame_jacobian, gravity, Data, Robot};

use super::{Walk, WalkError};
use crate::gait::HandLoad;

/// The arm's joint torques that hold `load` (the object's wrench on the hand) at rest at
/// configuration `q`: `tau = g(q) - J_hand^T [f; n]` (eq. js_dynamics at rest) on the actuated
/// joints that move the hand, `(joint, tau, limit)` in velocity order.
pub fn arm_torques(
    robot: &Robot,
    q: &[f64],
    load: &HandLoad,
) -> Result<Vec<(String, f64, f64)>, String> {
    let model = &robot.model;
    let frame = model.frame_id(&robot.hand_frame).map_err(|e| e.to_string())?;
    let mut data = Data::new(model);
    let g = gravity(model, &mut data, q).map_err(|e| e.to_string())?.clone();
    forward_kinematics(model, &mut data, q, &vec![0.0; model.nv]).map_err(|e| e.to_string())?;
    let mut jac = Matrix6xX::zeros(model.nv);
    frame_jacobian(model, &data, frame, &mut jac).map_err(|e| e.to_string())?;
    let w = nalgebra::Vector6::new(
        load.force.x,
        load.force.y,
        load.force.z,
        load.moment.x,
        load.moment.y,
        load.moment.z,
    );
    let support = &model.bodies[model.frames[frame].body].support;
    Ok(robot
        .actuated_indices
        .iter()
        .enumerate()
        .filter(|(_, k)| support.contains(k))
        .map(|(a, &k)| {
            (robot.actuated_joints[a].clone(), g[k] - jac.column(k).dot(&w), robot.torque_limits[a])
        })
        .collect())
}

/// The first arm joint whose torque ([`arm_torques`]) passes its limit.
fn arm_over_limit(
    robot: &Robot,
    q: &[f64],
    load: &HandLoad,
) -> Result<Option<(String, f64, f64)>, String> {
    Ok(arm_torques(robot, q, load)?.into_iter().find(|(_, tau, limit)| tau.abs() > *limit))
}

/// Check robot `i` of `walk`: `robot` standing at configuration `q` with its torso at `torso`
/// and its hand at `hand`, on the object, which starts at `object_start` and pushes the hand
/// with `load` there (the arm must hold it within its torque limits at every shifted pose).
#[allow(clippy::too_many_arguments)]
pub fn check(
    walk: &Walk,
    i: usize,
    robot: &Robot,
    q: &[f64],
    torso: &Isometry3<f64>,
    hand: &Isometry3<f64>,
    object_start: &Isometry3<f64>,
    load: Option<&HandLoad>,
) -> Result<(), WalkError> {
    let id = &walk.robots[i];
    let base = base_pose(q);
    let torso_to_base = torso.inverse() * base;
    let hand_on_object = object_start.inverse() * hand;
    let mut times: Vec<f64> =
        walk.gait.steps().iter().filter(|s| s.robot == i).map(|s| s.liftoff).collect();
    times.push(walk.gait.end_time());
    let mut q_t = q.to_vec();
    for t in times {
        let object = walk.gait.object(t).map_or(*object_start, |o| o.0);
        let target = object * hand_on_object;
        let torso_t = walk.gait.torso(i, t).0;
        let base_t = torso_t * torso_to_base;
        q_t[0..3].copy_from_slice(base_t.translation.vector.as_slice());
        let r = base_t.rotation;
        q_t[3..7].copy_from_slice(&[r.w, r.i, r.j, r.k]);
        match ik::solve_hand(
            robot,
            &q_t,
            &target.translation.vector,
            target.rotation.to_rotation_matrix().matrix(),
            &IkOptions::default(),
        ) {
            // The next pose starts from this one's arm: the walk moves it continuously.
            Ok(sol) => q_t = sol.q,
            Err(e) => {
                let offset = (torso_t.translation.vector - torso.translation.vector).xy().norm();
                return Err(WalkError::Reach {
                    robot: id.clone(),
                    time: t,
                    offset,
                    reason: e.to_string(),
                });
            }
        }
        check_arm_torque(robot, &q_t, load, &object, object_start, id, t)?;
    }
    Ok(())
}

/// The floating base's pose in configuration `q` (position, then quaternion `w, x, y, z`).
fn base_pose(q: &[f64]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(q[0], q[1], q[2]),
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[3], q[4], q[5], q[6])),
    )
}

/// At time `t`, robot `id`'s arm at configuration `q` holds the hand's `load` (moved with the
/// object from `object_start` to `object`) within its torque limits.
fn check_arm_torque(
    robot: &Robot,
    q: &[f64],
    load: Option<&HandLoad>,
    object: &Isometry3<f64>,
    object_start: &Isometry3<f64>,
    id: &str,
    t: f64,
) -> Result<(), WalkError> {
    let moved = load.map(|l| l.moved(&(object * object_start.inverse())));
    if let Some(l) = moved {
        if let Some((joint, torque, limit)) = arm_over_limit(robot, q, &l)
            .map_err(|reason| WalkError::Robot { robot: id.to_string(), reason })?
        {
            return Err(WalkError::ArmTorque {
                robot: id.to_string(),
                time: t,
                joint,
                torque,
                limit,
            });
        }
    }
    Ok(())
}
