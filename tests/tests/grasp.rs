//! A force-closed grasp holds the object in MuJoCo: two robots, palms placed by IK, squeezing
//! the 1 kg cube with the test-side controller. Checks the contact parameters do what the
//! README says (rigid frictional patch contact: the cube neither slides down nor turns).

use scenario::layout::place_hands;
use sim_bridge::ground_truth::{self, GroundTruthLog};
use sim_bridge::mujoco_plant::MujocoPlant;
use sim_bridge::plant::{empty_state, Plant};
use sim_bridge::world::{load_robots, World, WorldSpec};
use team_tests::standing_controller::{HandPush, StandingController, StandingGains};

fn hold(squeeze: f64, seconds: f64) -> (f64, f64, usize, GroundTruthLog) {
    let mut spec = WorldSpec::paper_pair();
    let robots = load_robots(&spec).unwrap();
    place_hands(&mut spec, &robots).unwrap();
    let world = World::build(&spec, &robots).unwrap();
    let mut ctls: Vec<StandingController> = world
        .robots
        .iter()
        .map(|r| {
            let off = r.robot.model.nq - r.robot.joints();
            StandingController::new(
                r.robot.clone(),
                Some(r.initial_q[off..].to_vec()),
                StandingGains::default(),
            )
            .unwrap()
            .with_hand_push(HandPush { squeeze, carry: 9.81 / 2.0 })
            .unwrap()
        })
        .collect();
    let mut plant = MujocoPlant::new(world).unwrap();
    let mut s = empty_state("t", "r1");
    let mut tau = Vec::new();
    let mut gt = ground_truth::empty("t");
    let mut rec = GroundTruthLog::new(10);
    let (mut zmin, mut ang_max, mut min_contacts) = (f64::MAX, 0.0f64, usize::MAX);
    let ticks = (seconds * 1000.0) as u64;
    for k in 0..ticks {
        for (i, c) in ctls.iter_mut().enumerate() {
            plant.state(i, &mut s);
            c.torques(&s, &mut tau).unwrap();
            plant.set_torques(i, &tau);
        }
        plant.step();
        plant.ground_truth("t", k, &mut gt);
        rec.offer(&gt);
        let o = gt.object.as_ref().unwrap();
        zmin = zmin.min(o.pose.position[2]);
        ang_max = ang_max.max(2.0 * o.pose.orientation[0].abs().min(1.0).acos());
        if k > 50 {
            for id in ["r1", "r2"] {
                min_contacts =
                    min_contacts.min(gt.hand_contacts.iter().filter(|c| c.robot == id).count());
            }
        }
    }
    (0.6 - zmin, ang_max.to_degrees(), min_contacts, rec)
}

#[test]
fn squeezed_cube_is_held_and_unsqueezed_cube_falls() {
    let (drop, ang, contacts, rec) = hold(40.0, 3.0);
    let last = rec.records.last().unwrap();
    let push: Vec<f64> = ["r1", "r2"]
        .iter()
        .map(|id| last.hand_contacts.iter().filter(|c| &c.robot == id).map(|c| c.wrench[0]).sum())
        .collect();
    eprintln!("held: drop {drop:.5} m, turn {ang:.3} deg, min contacts per hand {contacts}, hand x-forces {push:?}");
    assert!(drop < 0.005, "the cube slid down {drop} m");
    assert!(ang < 1.0, "the cube turned {ang} deg");
    assert!(contacts >= 1);
    // r1 (at -x) pushes along +x, r2 along -x, each about the squeeze.
    assert!(push[0] > 20.0 && push[1] < -20.0, "{push:?}");
    let (drop, _, _, _) = hold(0.0, 1.0);
    assert!(drop > 0.1, "without a squeeze the cube should fall, dropped {drop} m");
}
