//! The agent's view of its robot: the per-tick dynamics terms of the standing default robot
//! are consistent with the model, the published description says what the model says, and
//! the model's gravity is the protocol's.

use robot_agent::dynamics_source::robot_description;
use robot_model::{default_robot_path, Robot};

#[test]
fn terms_of_the_standing_robot_are_consistent_with_the_model() {
    use robot_agent::terms::{empty_terms, ActiveContacts, TermsBuilder};
    let robot = Robot::load(default_robot_path()).unwrap();
    let mut b = TermsBuilder::new(&robot).unwrap();
    let q = robot.standing_q.as_slice();
    let state = protocol::RobotState {
        header: protocol::Header::new("t", Some("r1"), 3, 0),
        base_pose: protocol::Pose {
            position: [q[0], q[1], q[2]],
            orientation: [q[3], q[4], q[5], q[6]],
        },
        base_twist: [0.1, 0.0, 0.0, 0.0, 0.0, 0.2],
        joint_positions: q[7..].to_vec(),
        joint_velocities: vec![0.05; 18],
        time: 0.0,
        foot_forces: Vec::new(),
        object_pose: None,
    };
    b.load_state(&robot, &state).unwrap();
    let mut contacts = ActiveContacts::all_stance(&robot);
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
fn the_published_description_is_the_models() {
    let robot = Robot::load(default_robot_path()).unwrap();
    let d = robot_description(&robot, "t", "r1");
    protocol::Validate::validate(&d).unwrap();
    assert_eq!(d.header.robot_id(), "r1");
    assert_eq!(d.joint_names, robot.actuated_joints);
    assert_eq!(d.torque_limits, robot.torque_limits);
    assert_eq!(
        (d.nq as usize, d.nv as usize, d.floating_base),
        (robot.model.nq, robot.model.nv, robot.model.floating_base)
    );
    assert_eq!(
        (d.foot_frames.clone(), d.hand_frame.clone(), d.torso_frame.clone()),
        (robot.foot_frames.clone(), robot.hand_frame.clone(), robot.torso_frame.clone())
    );
    assert_eq!(
        (d.foot_mu, d.hand_mu, d.hand_xi, d.hand_half_size),
        (
            robot.feet.mu,
            robot.hand.mu,
            robot.hand.xi,
            [robot.hand.half_size_x, robot.hand.half_size_y]
        )
    );
    assert_eq!(d.total_mass, robot.model.total_mass);
}

#[test]
fn the_models_gravity_is_the_protocols() {
    assert_eq!(robot_model::GRAVITY, [0.0, 0.0, -protocol::conventions::GRAVITY]);
    let robot = Robot::load(default_robot_path()).unwrap();
    assert_eq!(robot.model.gravity.as_slice(), &robot_model::GRAVITY);
}
