//! The default robot's description loads and agrees with its URDF; broken descriptions say
//! what is wrong.

use robot_model::{
    default_robot_path, forward_kinematics, frame_placement, Data, DescriptionError, Robot,
};

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
    let e = load_modified(|s| s.replace("hand = \"hand_contact\"", "hand = \"no_such_frame\""))
        .unwrap_err();
    assert!(
        matches!(&e, DescriptionError::UnknownFrame { frame, .. } if frame == "no_such_frame"),
        "{e}"
    );
    let e = load_modified(|s| s.replace("arm_joint_4 = 9.0", "arm_joint_4 = -9.0")).unwrap_err();
    assert!(matches!(&e, DescriptionError::BadValue { .. }), "{e}");
    let e = load_modified(|s| s.replace("LF_HAA = 0.0\n", "")).unwrap_err();
    assert!(
        matches!(&e, DescriptionError::MissingJoints { missing, .. } if missing == &vec!["LF_HAA".to_string()]),
        "{e}"
    );
    let e = load_modified(|s| s.replace("mu = 0.8\nradius", "mu = nan\nradius")).unwrap_err();
    assert!(matches!(&e, DescriptionError::BadValue { .. }), "{e}");
    let e = load_modified(|s| {
        s.replace("urdf = \"legged_manipulator.urdf\"", "urdf = \"missing.urdf\"")
    })
    .unwrap_err();
    assert!(matches!(&e, DescriptionError::Model { .. }), "{e}");
    let e = load_modified(|s| s.replace("[robot]", "[robot]\nunknown_key = 1")).unwrap_err();
    assert!(matches!(&e, DescriptionError::Toml { .. }), "{e}");
    let e = load_modified(|s| s.replace("arm_joint_1 = 39.0", "arm_joint_1 = 390.0")).unwrap_err();
    assert!(matches!(&e, DescriptionError::Invalid { .. }), "{e}");
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
    forward_kinematics(
        &robot.model,
        &mut data,
        robot.standing_q.as_slice(),
        &vec![0.0; robot.model.nv],
    )
    .unwrap();
    let base =
        *frame_placement(&robot.model, &data, robot.model.frame_id(&robot.torso_frame).unwrap())
            .unwrap();
    let hand =
        *frame_placement(&robot.model, &data, robot.model.frame_id(&robot.hand_frame).unwrap())
            .unwrap();
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
    let e = load_modified(|s| {
        s.replace("hand_position = [0.85, 0.0, 0.05118]", "hand_position = [0.852, 0.0, 0.05118]")
    })
    .unwrap_err();
    match &e {
        DescriptionError::HandPose(m) => {
            assert_eq!(m.frame, "hand_contact");
            assert!((m.distance_mm - 2.0).abs() < 0.05, "{}", m.distance_mm);
            assert!(m.angle_deg < 0.01);
            assert!((m.actual_position[0] - 0.85).abs() < 1e-4);
        }
        other => panic!("expected HandPose, got {other}"),
    }
    let msg = e.to_string();
    assert!(
        msg.contains("hand_contact")
            && msg.contains("standing.hand_position")
            && msg.contains("mm"),
        "{msg}"
    );
    // 0.5 mm off is within tolerance.
    load_modified(|s| {
        s.replace("hand_position = [0.85, 0.0, 0.05118]", "hand_position = [0.8505, 0.0, 0.05118]")
    })
    .unwrap();
    // A rotation of 1 degree about the palm normal: beyond 0.5 deg.
    let (c, s1) = ((0.5f64.to_radians()).cos(), (0.5f64.to_radians()).sin());
    // q = q_said * (cos(a/2), 0, 0, sin(a/2)) with q_said = (0.5, 0.5, 0.5, 0.5), a = 1 deg.
    let q = [0.5 * c - 0.5 * s1, 0.5 * c + 0.5 * s1, 0.5 * c - 0.5 * s1, 0.5 * c + 0.5 * s1];
    let line = format!("hand_orientation = [{}, {}, {}, {}]", q[0], q[1], q[2], q[3]);
    let e =
        load_modified(|s| s.replace("hand_orientation = [0.5, 0.5, 0.5, 0.5]", &line)).unwrap_err();
    assert!(matches!(&e, DescriptionError::HandPose(m) if (m.angle_deg - 1.0).abs() < 0.01), "{e}");
    // Not a unit quaternion.
    let e = load_modified(|s| {
        s.replace(
            "hand_orientation = [0.5, 0.5, 0.5, 0.5]",
            "hand_orientation = [1.0, 0.5, 0.5, 0.5]",
        )
    })
    .unwrap_err();
    assert!(
        matches!(&e, DescriptionError::BadValue { what, .. } if what.contains("hand_orientation")),
        "{e}"
    );
    // Missing: the description must say where the hand is.
    let e = load_modified(|s| s.replace("hand_position = [0.85, 0.0, 0.05118]\n", "")).unwrap_err();
    assert!(
        matches!(&e, DescriptionError::Toml { reason, .. } if reason.contains("hand_position")),
        "{e}"
    );
}

#[test]
fn non_positive_limits_and_wrong_standing_length_are_named() {
    for (from, to) in [
        ("LF_KFE = 80.0", "LF_KFE = 0.0"),
        ("arm_joint_6 = 9.0", "arm_joint_6 = -1.0"),
        ("LF_HAA = 80.0", "LF_HAA = inf"),
    ] {
        let e = load_modified(|s| s.replacen(from, to, 1)).unwrap_err();
        let joint = from.split(' ').next().unwrap();
        assert!(
            matches!(&e, DescriptionError::BadValue { what, .. } if what == &format!("torque_limits.{joint}")),
            "{from} -> {to}: {e}"
        );
    }
    // Contact parameters too.
    let e = load_modified(|s| s.replace("half_size_y = 0.05", "half_size_y = 0.0")).unwrap_err();
    assert!(
        matches!(&e, DescriptionError::BadValue { what, .. } if what == "contact.hand.half_size_y"),
        "{e}"
    );
    // Standing configuration of the wrong length: a joint too few, or a joint the URDF does not have.
    let e = load_modified(|s| s.replace("arm_joint_6 = 1.570296\n", "")).unwrap_err();
    assert!(
        matches!(&e, DescriptionError::MissingJoints { what, missing, .. } if what == "standing.joints" && missing == &vec!["arm_joint_6".to_string()]),
        "{e}"
    );
    let e = load_modified(|s| {
        s.replace("arm_joint_6 = 1.570296\n", "arm_joint_6 = 1.570296\narm_joint_7 = 0.0\n")
    })
    .unwrap_err();
    assert!(
        matches!(&e, DescriptionError::UnknownJoint { joint, .. } if joint == "arm_joint_7"),
        "{e}"
    );
    // Base position of the wrong length is a format error that names the field.
    let e = load_modified(|s| {
        s.replace("base_position = [0.0, 0.0, 0.54882015]", "base_position = [0.0, 0.54882015]")
    })
    .unwrap_err();
    assert!(
        matches!(&e, DescriptionError::Toml { reason, .. } if reason.contains("base_position")),
        "{e}"
    );
    // A torque limit for a joint that is not actuated, and the messages name file and joint.
    let e =
        load_modified(|s| s.replace("[torque_limits]\n", "[torque_limits]\nLF_FOOT_fixed = 1.0\n"))
            .unwrap_err();
    assert!(
        matches!(&e, DescriptionError::UnknownJoint { joint, .. } if joint == "LF_FOOT_fixed"),
        "{e}"
    );
    assert!(e.to_string().contains("legged_manipulator.toml"), "{e}");
    // The standing configuration outside the joint limits.
    let e =
        load_modified(|s| s.replace("arm_joint_2 = 1.628906", "arm_joint_2 = 3.0")).unwrap_err();
    assert!(
        matches!(&e, DescriptionError::Invalid { what, .. } if what.contains("arm_joint_2")),
        "{e}"
    );
}

#[test]
fn frames_know_the_link_they_hang_from() {
    // What the world builder uses for the palm and foot bodies: the URDF parent link of the
    // hand and foot frames, even where that link was merged into its body.
    let robot = Robot::load(default_robot_path()).unwrap();
    let m = &robot.model;
    let id = |n: &str| m.frame_id(n).unwrap();
    assert_eq!(m.parent_link(id(&robot.hand_frame)), Some("hand"));
    assert_ne!(
        m.bodies[m.frames[id("hand")].body].name,
        "hand",
        "hand is a fixed link, merged into its body"
    );
    for foot in &robot.foot_frames {
        assert_eq!(m.parent_link(id(foot)), Some(format!("{}_SHANK", &foot[..2]).as_str()));
    }
    assert_eq!(m.parent_link(id("arm_base_link")), Some("base"));
    assert_eq!(m.parent_link(0), None, "the root hangs from nothing");
    assert_eq!(m.parent_link(m.frames.len()), None);
    // Every other frame's parent is a frame before it.
    for (i, f) in m.frames.iter().enumerate().skip(1) {
        assert!(f.parent_frame.is_some_and(|p| p < i), "{}", f.name);
    }
}

#[test]
fn a_cache_loads_each_description_once() {
    let mut cache = robot_model::RobotCache::new();
    let a = cache.load(&default_robot_path()).unwrap();
    let b = cache.load(&default_robot_path()).unwrap();
    assert!(std::sync::Arc::ptr_eq(&a, &b));
    assert_eq!(cache.len(), 1);
    let e = cache.load(std::path::Path::new("/nonexistent/robot.toml")).unwrap_err();
    assert!(matches!(&e, DescriptionError::Io { .. }), "{e}");
    assert_eq!(cache.len(), 1);
}
