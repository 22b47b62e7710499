//! Arm IK on the default robot's own model: the hand reaches a moved target, only the joints
//! that may move (and move the hand) change, and failures are typed.

use nalgebra::{Rotation3, Vector3};
use robot_model::ik::{self, IkError, IkOptions};
use robot_model::{default_robot_path, forward_kinematics, frame_placement, Data, Robot};

/// The hand pose at standing, moved by `dp` and turned by `angle` about world z.
fn moved_hand_target(
    robot: &Robot,
    dp: Vector3<f64>,
    angle: f64,
) -> (Vector3<f64>, nalgebra::Matrix3<f64>) {
    let mut data = Data::new(&robot.model);
    forward_kinematics(
        &robot.model,
        &mut data,
        robot.standing_q.as_slice(),
        &vec![0.0; robot.model.nv],
    )
    .unwrap();
    let hand =
        *frame_placement(&robot.model, &data, robot.model.frame_id(&robot.hand_frame).unwrap())
            .unwrap();
    let turn = Rotation3::from_axis_angle(&Vector3::z_axis(), angle).into_inner();
    (hand.trans + dp, turn * hand.rot)
}

#[test]
fn the_hand_reaches_a_moved_target_moving_only_the_arm() {
    let robot = Robot::load(default_robot_path()).unwrap();
    let (p, r) = moved_hand_target(&robot, Vector3::new(-0.05, 0.03, 0.04), 5f64.to_radians());
    let q0: Vec<f64> = robot.standing_q.iter().copied().collect();
    let sol = ik::solve_hand(&robot, &q0, &p, &r, &IkOptions::default()).unwrap();
    assert!(sol.iterations > 0);
    assert!(sol.position_error < 1e-7 && sol.angle_error < 1e-7, "{sol:?}");
    // The six arm joints are the solved ones; base and legs are where they were.
    let names: Vec<&str> = sol.joints.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        ["arm_joint_1", "arm_joint_2", "arm_joint_3", "arm_joint_4", "arm_joint_5", "arm_joint_6"]
    );
    let off = robot.model.nq - robot.model.joint_names.len();
    for (k, name) in robot.model.joint_names.iter().enumerate() {
        if !name.starts_with("arm") {
            assert_eq!(sol.q[off + k], q0[off + k], "{name} moved");
        }
    }
    assert_eq!(&sol.q[..7], &q0[..7]);
    // The solved configuration puts the hand there, within the joint limits.
    let mut data = Data::new(&robot.model);
    forward_kinematics(&robot.model, &mut data, &sol.q, &vec![0.0; robot.model.nv]).unwrap();
    let hand =
        frame_placement(&robot.model, &data, robot.model.frame_id(&robot.hand_frame).unwrap())
            .unwrap();
    assert!((hand.trans - p).norm() < 1e-6);
    for (i, q) in sol.q.iter().enumerate().skip(7) {
        assert!(
            *q >= robot.model.lower_position_limit[i] && *q <= robot.model.upper_position_limit[i]
        );
    }
}

#[test]
fn the_predicate_chooses_the_joints_and_failures_are_typed() {
    let robot = Robot::load(default_robot_path()).unwrap();
    let hand = robot.model.frame_id(&robot.hand_frame).unwrap();
    let q0: Vec<f64> = robot.standing_q.iter().copied().collect();
    let (p, r) = moved_hand_target(&robot, Vector3::new(0.0, 0.0, 0.02), 0.0);
    // Only the first three arm joints may move: position only can be met, the wrist stays.
    let first_three = |k: usize| {
        ["arm_joint_1", "arm_joint_2", "arm_joint_3"]
            .contains(&robot.model.joint_names[k - 6].as_str())
    };
    let e =
        ik::solve(&robot.model, hand, &q0, &p, &r, &IkOptions::default(), first_three).unwrap_err();
    assert!(matches!(e, IkError::NoConvergence { iterations: 500, .. }), "{e}");
    // No joint may move: said before iterating.
    let e =
        ik::solve(&robot.model, hand, &q0, &p, &r, &IkOptions::default(), |_| false).unwrap_err();
    assert!(matches!(&e, IkError::NoJoint { frame } if frame == "hand_contact"), "{e}");
    // One iteration is not enough; a frame out of range and a short q are errors, not panics.
    let one = IkOptions { max_iters: 1, ..IkOptions::default() };
    assert!(matches!(
        ik::solve(&robot.model, hand, &q0, &p, &r, &one, |_| true),
        Err(IkError::NoConvergence { iterations: 1, .. })
    ));
    assert!(matches!(
        ik::solve(&robot.model, 10_000, &q0, &p, &r, &IkOptions::default(), |_| true),
        Err(IkError::Dynamics(_))
    ));
    assert!(matches!(
        ik::solve(&robot.model, hand, &q0[..10], &p, &r, &IkOptions::default(), |_| true),
        Err(IkError::Dynamics(_))
    ));
}
