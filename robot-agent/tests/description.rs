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
