//! Timed external wrenches: they act for their duration on the named body, and bad targets
//! are refused with an error.

use protocol::{Header, PerturbationRequest, PerturbationTarget};
use sim_bridge::mujoco_plant::MujocoPlant;
use sim_bridge::plant::{empty_state, Plant};
use sim_bridge::world::{load_robots, World, WorldSpec};

fn req(target: PerturbationTarget, fx: f64, start: f64, duration: f64) -> PerturbationRequest {
    PerturbationRequest {
        header: Header::new("t", None, 0, 0),
        target,
        wrench: [fx, 0.0, 0.0, 0.0, 0.0, 0.0],
        start: Some(start),
        duration,
    }
}

#[test]
fn a_push_on_the_object_moves_it_only_while_it_lasts() {
    let mut spec = WorldSpec::paper_pair();
    spec.robots.truncate(1);
    // The object alone on the floor, away from the robot.
    let o = spec.object.as_mut().unwrap();
    o.position = [0.5, 2.0, 0.3];
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    let mut plant = MujocoPlant::new(world).unwrap();
    // 20 N along +x on a 1 kg cube (friction 0.8 * 9.81 = 7.8 N) from 0.1 s for 0.2 s.
    plant.perturb(&req(PerturbationTarget::Object, 20.0, 0.1, 0.2)).unwrap();
    let x = |p: &MujocoPlant| p.full_state()[p.world.object.unwrap().1];
    for _ in 0..100 {
        plant.step();
    }
    let x_before = x(&plant);
    assert!((x_before - 0.5).abs() < 1e-4, "moved before the push: {x_before}");
    for _ in 0..200 {
        plant.step();
    }
    let x_after_push = x(&plant);
    assert!(x_after_push - x_before > 0.1, "the push moved it only {}", x_after_push - x_before);
    for _ in 0..500 {
        plant.step();
    }
    let x_end = x(&plant);
    for _ in 0..200 {
        plant.step();
    }
    assert!(
        (x(&plant) - x_end).abs() < 1e-4,
        "still moving after the push ended and friction stopped it"
    );
}

#[test]
fn a_push_on_a_robot_body_and_bad_targets() {
    let spec = WorldSpec::single("r1");
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    let mut plant = MujocoPlant::new(world).unwrap();
    let target = |b: &str| PerturbationTarget::RobotBody { robot: "r1".into(), body: b.into() };
    assert!(plant.perturb(&req(target("nonexistent_link"), 1.0, 0.0, 0.1)).is_err());
    assert!(plant
        .perturb(&req(
            PerturbationTarget::RobotBody { robot: "r9".into(), body: "base".into() },
            1.0,
            0.0,
            0.1
        ))
        .is_err());
    assert!(
        plant.perturb(&req(PerturbationTarget::Object, 1.0, 0.0, 0.1)).is_err(),
        "no object in this world"
    );
    // A strong sideways push on the trunk of an uncontrolled robot moves its base along y.
    let mut r = req(target("base"), 0.0, 0.0, 0.05);
    r.wrench = [0.0, 600.0, 0.0, 0.0, 0.0, 0.0];
    plant.perturb(&r).unwrap();
    for _ in 0..100 {
        plant.step();
    }
    let mut s = empty_state("t", "r1");
    plant.state(0, &mut s);
    assert!(s.base_pose.position[1] > 0.01, "base y {}", s.base_pose.position[1]);
}

#[test]
fn every_robot_measures_the_object_where_the_ground_truth_has_it_unless_told_not_to() {
    let mut spec = WorldSpec::paper_pair();
    // The object alone, pushed so that it moves and turns.
    spec.object.as_mut().unwrap().position = [0.3, 2.0, 0.3];
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    let mut plant = MujocoPlant::new(world).unwrap();
    plant.perturb(&req(PerturbationTarget::Object, 30.0, 0.0, 0.1)).unwrap();
    // At rest again (the ground truth's poses are of the last step's start, the state's of its
    // end: the same at rest).
    for _ in 0..1000 {
        plant.step();
    }
    let mut truth = sim_bridge::ground_truth::empty("t");
    assert!(plant.ground_truth("t", 1000, &mut truth));
    let body = truth.object.expect("the object's truth");
    for robot in 0..2 {
        let mut state = empty_state("t", "r1");
        plant.state(robot, &mut state);
        let seen = state.object_pose.expect("the object's pose is measured");
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9);
        assert!(close(&seen.position, &body.pose.position), "{seen:?} vs {:?}", body.pose);
        assert!(close(&seen.orientation, &body.pose.orientation), "{seen:?} vs {:?}", body.pose);
        assert!(seen.position[0] > 0.35, "the push moved it: {seen:?}");
    }
    spec.sensors.object_pose = false;
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    let plant = MujocoPlant::new(world).unwrap();
    let mut state = empty_state("t", "r1");
    plant.state(0, &mut state);
    assert!(state.object_pose.is_none(), "no object sensor");
}
