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
