//! The world built from URDF: counts, mass and joint order against the robots' own models.

use sim_bridge::mujoco_plant::MujocoPlant;
use sim_bridge::plant::{empty_state, Plant};
use sim_bridge::world::{
    check_against_model, load_robots, RobotPlacement, World, WorldError, WorldSpec,
    DEFAULT_STANDING_HEIGHT,
};

#[test]
fn pair_world_builds_and_matches_the_models() {
    let spec = WorldSpec::paper_pair();
    let w = World::build(&spec, &load_robots(&spec).unwrap()).expect("world builds");
    let raw = w.model.ffi();
    // 2 robots x (7 + 18) + object 7
    assert_eq!(raw.nq, 2 * 25 + 7);
    assert_eq!(raw.nv, 2 * 24 + 6);
    assert_eq!(raw.nu, 36);
    for r in &w.robots {
        check_against_model(&w.model, r).unwrap();
        assert_eq!(r.hand_geoms.len(), 1, "{}", r.id);
        assert_eq!(r.foot_geoms.len(), 4, "{}", r.id);
    }
    let mut p = MujocoPlant::new(w).unwrap();
    let mut s = empty_state("t", "r1");
    // Each robot's state is where the spec placed it: its base position, and its yaw as the
    // quaternion (cos(yaw/2), 0, 0, sin(yaw/2)) up to sign.
    for (i, placed) in spec.robots.iter().enumerate() {
        p.state(i, &mut s);
        let offset: f64 = s
            .base_pose
            .position
            .iter()
            .zip(&placed.base_position)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(
            offset < 1e-9,
            "{}: base at {:?}, placed at {:?}",
            placed.id,
            s.base_pose.position,
            placed.base_position
        );
        let [w, x, y, z] = s.base_pose.orientation;
        let (c, sn) = ((placed.base_yaw / 2.0).cos(), (placed.base_yaw / 2.0).sin());
        let dot = (w * c + z * sn).abs();
        assert!(
            dot > 1.0 - 1e-9 && x.abs() < 1e-9 && y.abs() < 1e-9,
            "{}: orientation {:?} for yaw {}",
            placed.id,
            s.base_pose.orientation,
            placed.base_yaw
        );
        assert_eq!(s.joint_positions.len(), 18);
        assert_eq!(s.time, 0.0);
    }
    p.step();
    p.state(0, &mut s);
    assert_eq!(p.ticks(), 1);
    assert!(
        (s.time - 1.0 / spec.control_hz).abs() < 1e-12,
        "one control period simulated: {}",
        s.time
    );
}

#[test]
fn a_mass_or_joint_order_mismatch_is_detected() {
    let spec = WorldSpec::single("r1");
    let w = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    let mut r = w.robots[0].clone();
    std::sync::Arc::make_mut(&mut r.robot).model.total_mass += 0.01;
    assert!(matches!(
        check_against_model(&w.model, &r),
        Err(WorldError::MassMismatch { ref id, .. }) if id == "r1"
    ));
    let mut r = w.robots[0].clone();
    std::sync::Arc::make_mut(&mut r.robot).actuated_joints.swap(0, 1);
    assert!(matches!(
        check_against_model(&w.model, &r),
        Err(WorldError::JointOrderMismatch { .. })
    ));
}

#[test]
fn robots_are_loaded_once_per_description_and_must_match_the_spec() {
    let spec = WorldSpec::paper_pair();
    let robots = load_robots(&spec).unwrap();
    // Both robots use the default description: one load, one shared robot.
    assert_eq!(robots.len(), 2);
    assert!(std::sync::Arc::ptr_eq(&robots[0], &robots[1]));
    let w = World::build(&spec, &robots).unwrap();
    assert!(w.robots.iter().all(|r| std::sync::Arc::ptr_eq(&r.robot, &robots[0])));
    // One robot short, or one loaded from another file: refused, naming what is wrong.
    let e = World::build(&spec, &robots[..1]).err().expect("too few robots refused");
    assert!(
        matches!(&e, WorldError::Invalid(m) if m.contains("1 robots loaded for 2 placements")),
        "{e}"
    );
    let mut other = (*robots[1]).clone();
    other.path = "elsewhere.toml".into();
    let e = World::build(&spec, &[robots[0].clone(), std::sync::Arc::new(other)])
        .err()
        .expect("wrong robot refused");
    assert!(
        matches!(&e, WorldError::Invalid(m) if m.contains("r2") && m.contains("elsewhere.toml")),
        "{e}"
    );
    // A missing description is named with the robot.
    let mut spec = WorldSpec::single("r9");
    spec.robots[0].description = "/nonexistent/robot.toml".into();
    let e = load_robots(&spec).unwrap_err();
    assert!(matches!(&e, WorldError::Description { id, .. } if id == "r9"), "{e}");
}

#[test]
fn the_default_height_is_the_default_robots_standing_height() {
    let robot = robot_model::Robot::load(robot_model::default_robot_path()).unwrap();
    assert_eq!(robot.standing_q[2], DEFAULT_STANDING_HEIGHT);
    let p =
        RobotPlacement::standing("r1", robot_model::default_robot_path(), &robot, [1.0, 2.0], 0.5)
            .unwrap();
    assert_eq!(p.base_position, [1.0, 2.0, DEFAULT_STANDING_HEIGHT]);
    assert_eq!(p, RobotPlacement::default_robot("r1", 1.0, 2.0, 0.5));
}
