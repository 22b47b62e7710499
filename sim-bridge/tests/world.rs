//! The world built from URDF: counts, mass and joint order against the robots' own models.

use sim_bridge::mujoco_plant::MujocoPlant;
use sim_bridge::plant::{empty_state, Plant};
use sim_bridge::world::{check_against_model, World, WorldError, WorldSpec};

#[test]
fn pair_world_builds_and_matches_the_models() {
    let w = World::build(&WorldSpec::paper_pair()).expect("world builds");
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
    p.state(0, &mut s);
    eprintln!("{:?}", s);
    p.step();
}

#[test]
fn a_mass_or_joint_order_mismatch_is_detected() {
    let w = World::build(&WorldSpec::single("r1")).unwrap();
    let mut r = w.robots[0].clone();
    r.robot.model.total_mass += 0.01;
    assert!(matches!(check_against_model(&w.model, &r), Err(WorldError::MassMismatch { ref id, .. }) if id == "r1"));
    let mut r = w.robots[0].clone();
    r.robot.actuated_joints.swap(0, 1);
    assert!(matches!(check_against_model(&w.model, &r), Err(WorldError::JointOrderMismatch { .. })));
}
