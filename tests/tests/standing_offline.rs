//! The standing controller keeps the default robot up in MuJoCo without any transport (a
//! baseline for the Zenoh test in `lockstep_mujoco.rs`).

use sim_bridge::mujoco_plant::MujocoPlant;
use sim_bridge::plant::{empty_state, Plant};
use sim_bridge::world::{load_robots, World, WorldSpec};
use team_tests::standing_controller::{StandingController, StandingGains};

#[test]
fn default_robot_stands_5_s_offline() {
    let spec = WorldSpec::single("r1");
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    let robot = world.robots[0].robot.clone();
    let z0 = world.robots[0].initial_q[2];
    let mut plant = MujocoPlant::new(world).unwrap();
    let mut ctl = StandingController::new(robot, None, StandingGains::default()).unwrap();
    let mut s = empty_state("t", "r1");
    let mut tau = Vec::new();
    let (mut zmin, mut zmax, mut tilt_max) = (f64::MAX, f64::MIN, 0.0f64);
    for k in 0..5000 {
        plant.state(0, &mut s);
        ctl.torques(&s, &mut tau).unwrap();
        plant.set_torques(0, &tau);
        plant.step();
        let z = s.base_pose.position[2];
        zmin = zmin.min(z);
        zmax = zmax.max(z);
        let q = s.base_pose.orientation;
        // angle between base z and world z
        let cz = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]);
        tilt_max = tilt_max.max(cz.clamp(-1.0, 1.0).acos());
        if k % 1000 == 0 {
            eprintln!(
                "t={:.3} z={z:.4} tilt={:.4} deg xy=({:.4},{:.4}) tau0..3={:?}",
                plant.time(),
                cz.acos().to_degrees(),
                s.base_pose.position[0],
                s.base_pose.position[1],
                &tau[..3]
            );
        }
    }
    eprintln!(
        "z in [{zmin:.4}, {zmax:.4}] (start {z0:.4}), tilt max {:.3} deg",
        tilt_max.to_degrees()
    );
    assert!((zmin - z0).abs() < 0.03 && (zmax - z0).abs() < 0.03);
    assert!(tilt_max.to_degrees() < 2.0);
}

#[test]
fn without_torques_the_robot_collapses() {
    // The check above can fail: with zero torques the same robot sinks far below 3 cm.
    let spec = WorldSpec::single("r1");
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    let z0 = world.robots[0].initial_q[2];
    let mut plant = MujocoPlant::new(world).unwrap();
    let mut s = empty_state("t", "r1");
    plant.set_torques(0, &[0.0; 18]);
    for _ in 0..1000 {
        plant.step();
    }
    plant.state(0, &mut s);
    assert!(s.base_pose.position[2] < z0 - 0.05, "z = {}", s.base_pose.position[2]);
}
