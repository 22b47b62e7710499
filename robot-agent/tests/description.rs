//! The default robot's description loads and agrees with its URDF; broken descriptions say
//! what is wrong.

use robot_agent::description::{default_robot_path, DescriptionError, Robot};
use robot_agent::dynamics::{forward_kinematics, frame_placement, Data};

#[test]
fn default_robot_loads_and_stands_on_its_feet() {
    let robot = Robot::load(default_robot_path()).unwrap();
    assert_eq!(robot.joints(), 18);
    assert_eq!(robot.model.nv, 24);
    assert_eq!(robot.model.nq, 25);
    assert!((45.0..65.0).contains(&robot.model.total_mass), "mass {}", robot.model.total_mass);
    let mut data = Data::new(&robot.model);
    let v = vec![0.0; robot.model.nv];
    forward_kinematics(&robot.model, &mut data, robot.standing_q.as_slice(), &v).unwrap();
    for foot in &robot.foot_frames {
        let id = robot.model.frame_id(foot).unwrap();
        let z = frame_placement(&robot.model, &data, id).unwrap().trans.z;
        assert!((z - robot.feet.radius).abs() < 1e-3, "{foot} at z = {z}");
    }
}

fn load_modified(edit: impl Fn(String) -> String) -> Result<Robot, DescriptionError> {
    let path = default_robot_path();
    let text = edit(std::fs::read_to_string(&path).unwrap());
    Robot::from_toml_str(&text, &path)
}

#[test]
fn broken_descriptions_name_the_problem() {
    let e = load_modified(|s| s.replace("hand = \"hand_contact\"", "hand = \"no_such_frame\"")).unwrap_err();
    assert!(matches!(&e, DescriptionError::UnknownFrame { frame, .. } if frame == "no_such_frame"), "{e}");
    let e = load_modified(|s| s.replace("arm_joint_4 = 9.0", "arm_joint_4 = -9.0")).unwrap_err();
    assert!(matches!(&e, DescriptionError::BadValue { .. }), "{e}");
    let e = load_modified(|s| s.replace("LF_HAA = 0.0\n", "")).unwrap_err();
    assert!(matches!(&e, DescriptionError::MissingJoints { missing, .. } if missing == &vec!["LF_HAA".to_string()]), "{e}");
    let e = load_modified(|s| s.replace("mu = 0.8\nradius", "mu = nan\nradius")).unwrap_err();
    assert!(matches!(&e, DescriptionError::BadValue { .. }), "{e}");
    let e = load_modified(|s| s.replace("urdf = \"legged_manipulator.urdf\"", "urdf = \"missing.urdf\"")).unwrap_err();
    assert!(matches!(&e, DescriptionError::Model { .. }), "{e}");
    let e = load_modified(|s| s.replace("[robot]", "[robot]\nunknown_key = 1")).unwrap_err();
    assert!(matches!(&e, DescriptionError::Toml { .. }), "{e}");
    let e = load_modified(|s| s.replace("arm_joint_1 = 39.0", "arm_joint_1 = 390.0")).unwrap_err();
    assert!(matches!(&e, DescriptionError::Invalid { .. }), "{e}");
}

#[test]
fn terms_of_the_standing_robot_are_consistent_with_the_model() {
    use robot_agent::terms::{empty_terms, ContactSet, TermsBuilder};
    let robot = Robot::load(default_robot_path()).unwrap();
    let mut b = TermsBuilder::new(&robot).unwrap();
    let q = robot.standing_q.as_slice();
    let state = protocol::RobotState {
        header: protocol::Header::new("t", Some("r1"), 3, 0),
        base_pose: protocol::Pose { position: [q[0], q[1], q[2]], orientation: [q[3], q[4], q[5], q[6]] },
        base_twist: [0.1, 0.0, 0.0, 0.0, 0.0, 0.2],
        joint_positions: q[7..].to_vec(),
        joint_velocities: vec![0.05; 18],
        time: 0.0,
    };
    b.load_state(&robot, &state).unwrap();
    let mut contacts = ContactSet::all_stance(&robot);
    contacts.stance[1] = false;
    let mut terms = empty_terms("t", "r1");
    b.compute(&robot, &contacts, &mut terms).unwrap();
    protocol::Validate::validate(&terms).unwrap();
    assert_eq!(terms.nv(), 24);
    assert_eq!(terms.frames.len(), 6); // 3 stance feet, 1 swing foot, hand, torso
    assert_eq!(terms.frames_with(protocol::FrameRole::SwingFoot).count(), 1);
    // The torso frame is the base: its linear Jacobian columns of the base twist are the base
    // rotation (the base linear velocity is in the base frame).
    let torso = terms.frames.iter().find(|f| f.role == protocol::FrameRole::Torso).unwrap();
    assert!((torso.jacobian.get(2, 2).unwrap() - 1.0).abs() < 1e-12);
    // Mass matrix symmetric, first diagonal entry is the total mass.
    let m = terms.mass_matrix.to_dmatrix();
    assert!((m[(0, 0)] - robot.model.total_mass).abs() < 1e-9);
    assert!((m.clone() - m.transpose()).amax() < 1e-12);
    // Recomputing into the same message keeps its shape (no growth).
    b.compute(&robot, &contacts, &mut terms).unwrap();
    assert_eq!(terms.frames.len(), 6);
}

#[test]
fn the_hand_frame_is_where_the_description_says() {
    use nalgebra::{Quaternion, UnitQuaternion, Vector3};
    let robot = Robot::load(default_robot_path()).unwrap();
    // What the description says (and the models README documents).
    assert_eq!(robot.standing_hand_position, [0.85, 0.0, 0.05118]);
    assert_eq!(robot.standing_hand_orientation, [0.5, 0.5, 0.5, 0.5]);
    // Independent of the load check: forward kinematics at standing, hand relative to the base.
    let mut data = Data::new(&robot.model);
    forward_kinematics(&robot.model, &mut data, robot.standing_q.as_slice(), &vec![0.0; robot.model.nv]).unwrap();
    let base = *frame_placement(&robot.model, &data, robot.model.frame_id(&robot.torso_frame).unwrap()).unwrap();
    let hand = *frame_placement(&robot.model, &data, robot.model.frame_id(&robot.hand_frame).unwrap()).unwrap();
    let p = base.rot.transpose() * (hand.trans - base.trans);
    assert!((p - Vector3::from(robot.standing_hand_position)).norm() < 1e-3, "hand at {p:?}");
    // The palm normal (hand z) points along the base's +x, the hand's x along the base's +y.
    let r = base.rot.transpose() * hand.rot;
    assert!((r.column(2) - Vector3::x()).norm() < 1e-3, "palm normal {:?}", r.column(2));
    assert!((r.column(0) - Vector3::y()).norm() < 1e-3);
    let said = UnitQuaternion::from_quaternion(Quaternion::new(0.5, 0.5, 0.5, 0.5));
    assert!((said.to_rotation_matrix().into_inner() - r).amax() < 1e-3);
}

#[test]
fn a_wrong_standing_hand_pose_is_named_with_both_poses() {
    // 2 mm off in x: beyond the 1 mm tolerance.
    let e = load_modified(|s| s.replace("hand_position = [0.85, 0.0, 0.05118]", "hand_position = [0.852, 0.0, 0.05118]")).unwrap_err();
    match &e {
        DescriptionError::HandPose { frame, distance_mm, angle_deg, actual_position, .. } => {
            assert_eq!(frame, "hand_contact");
            assert!((distance_mm - 2.0).abs() < 0.05, "{distance_mm}");
            assert!(*angle_deg < 0.01);
            assert!((actual_position[0] - 0.85).abs() < 1e-4);
        }
        other => panic!("expected HandPose, got {other}"),
    }
    let msg = e.to_string();
    assert!(msg.contains("hand_contact") && msg.contains("standing.hand_position") && msg.contains("mm"), "{msg}");
    // 0.5 mm off is within tolerance.
    load_modified(|s| s.replace("hand_position = [0.85, 0.0, 0.05118]", "hand_position = [0.8505, 0.0, 0.05118]")).unwrap();
    // A rotation of 1 degree about the palm normal: beyond 0.5 deg.
    let (c, s1) = ((0.5f64.to_radians()).cos(), (0.5f64.to_radians()).sin());
    // q = q_said * (cos(a/2), 0, 0, sin(a/2)) with q_said = (0.5, 0.5, 0.5, 0.5), a = 1 deg.
    let q = [0.5 * c - 0.5 * s1, 0.5 * c + 0.5 * s1, 0.5 * c - 0.5 * s1, 0.5 * c + 0.5 * s1];
    let line = format!("hand_orientation = [{}, {}, {}, {}]", q[0], q[1], q[2], q[3]);
    let e = load_modified(|s| s.replace("hand_orientation = [0.5, 0.5, 0.5, 0.5]", &line)).unwrap_err();
    assert!(matches!(&e, DescriptionError::HandPose { angle_deg, .. } if (angle_deg - 1.0).abs() < 0.01), "{e}");
    // Not a unit quaternion.
    let e = load_modified(|s| s.replace("hand_orientation = [0.5, 0.5, 0.5, 0.5]", "hand_orientation = [1.0, 0.5, 0.5, 0.5]")).unwrap_err();
    assert!(matches!(&e, DescriptionError::BadValue { what, .. } if what.contains("hand_orientation")), "{e}");
    // Missing: the description must say where the hand is.
    let e = load_modified(|s| s.replace("hand_position = [0.85, 0.0, 0.05118]\n", "")).unwrap_err();
    assert!(matches!(&e, DescriptionError::Toml { reason, .. } if reason.contains("hand_position")), "{e}");
}

#[test]
fn non_positive_limits_and_wrong_standing_length_are_named() {
    for (from, to) in [("LF_KFE = 80.0", "LF_KFE = 0.0"), ("arm_joint_6 = 9.0", "arm_joint_6 = -1.0"), ("LF_HAA = 80.0", "LF_HAA = inf")] {
        let e = load_modified(|s| s.replacen(from, to, 1)).unwrap_err();
        let joint = from.split(' ').next().unwrap();
        assert!(
            matches!(&e, DescriptionError::BadValue { what, .. } if what == &format!("torque_limits.{joint}")),
            "{from} -> {to}: {e}"
        );
    }
    // Contact parameters too.
    let e = load_modified(|s| s.replace("half_size_y = 0.05", "half_size_y = 0.0")).unwrap_err();
    assert!(matches!(&e, DescriptionError::BadValue { what, .. } if what == "contact.hand.half_size_y"), "{e}");
    // Standing configuration of the wrong length: a joint too few, or a joint the URDF does not have.
    let e = load_modified(|s| s.replace("arm_joint_6 = 1.570296\n", "")).unwrap_err();
    assert!(matches!(&e, DescriptionError::MissingJoints { what, missing, .. } if what == "standing.joints" && missing == &vec!["arm_joint_6".to_string()]), "{e}");
    let e = load_modified(|s| s.replace("arm_joint_6 = 1.570296\n", "arm_joint_6 = 1.570296\narm_joint_7 = 0.0\n")).unwrap_err();
    assert!(matches!(&e, DescriptionError::UnknownJoint { joint, .. } if joint == "arm_joint_7"), "{e}");
    // Base position of the wrong length is a format error that names the field.
    let e = load_modified(|s| s.replace("base_position = [0.0, 0.0, 0.54882015]", "base_position = [0.0, 0.54882015]")).unwrap_err();
    assert!(matches!(&e, DescriptionError::Toml { reason, .. } if reason.contains("base_position")), "{e}");
    // A torque limit for a joint that is not actuated, and the messages name file and joint.
    let e = load_modified(|s| s.replace("[torque_limits]\n", "[torque_limits]\nLF_FOOT_fixed = 1.0\n")).unwrap_err();
    assert!(matches!(&e, DescriptionError::UnknownJoint { joint, .. } if joint == "LF_FOOT_fixed"), "{e}");
    assert!(e.to_string().contains("legged_manipulator.toml"), "{e}");
    // The standing configuration outside the joint limits.
    let e = load_modified(|s| s.replace("arm_joint_2 = 1.628906", "arm_joint_2 = 3.0")).unwrap_err();
    assert!(matches!(&e, DescriptionError::Invalid { what, .. } if what.contains("arm_joint_2")), "{e}");
}
