//! The robots' drives execute a drive command (`protocol::DriveCommand`) at every physics step,
//! `tau = tau_ff + kp (q_des - q) + kd (qd_des - qd)`, until the next command: the MuJoCo plant
//! and the placeholder plant, each against the law written out here, in the test, at every
//! physics step. Without gains a drive command is the torque it carries, bit for bit. And the
//! team with the agents' drive gains on (`drive_gains = "inertia"`) against the torque loop.

mod common;

use protocol::{DriveCommand, Header, RobotState};
use sim_bridge::mujoco_plant::MujocoPlant;
use sim_bridge::plant::{PlaceholderPlant, Plant};
use sim_bridge::world::{load_robots, World, WorldSpec};

/// The paper's pair without the object, `substeps` physics steps (1 kHz) per control tick.
fn pair(substeps: u32) -> MujocoPlant {
    let mut spec = WorldSpec::paper_pair();
    spec.object = None;
    spec.physics_hz = 1000.0;
    spec.control_hz = 1000.0 / f64::from(substeps);
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    assert_eq!(world.substeps, substeps);
    MujocoPlant::new(world).unwrap()
}

fn empty_state() -> RobotState {
    RobotState {
        header: Header::new("t", Some("r"), 0, 0),
        base_pose: protocol::Pose { position: [0.0; 3], orientation: [1.0, 0.0, 0.0, 0.0] },
        base_twist: [0.0; 6],
        joint_positions: Vec::new(),
        joint_velocities: Vec::new(),
        time: 0.0,
        foot_forces: Vec::new(),
        object_pose: None,
    }
}

/// A PD command about each robot's start, 0.05 rad away, with a feed-forward torque.
fn commands(p: &MujocoPlant) -> Vec<DriveCommand> {
    let mut s = empty_state();
    (0..p.robots().len())
        .map(|i| {
            p.state(i, &mut s);
            let n = s.joint_positions.len();
            let mut d = DriveCommand::torque(
                "t",
                &p.robots()[i],
                0,
                (0..n).map(|j| 0.5 * (j as f64).sin()).collect(),
            );
            d.q_des = s.joint_positions.iter().map(|q| q + 0.05).collect();
            d.qd_des = vec![0.1; n];
            d.kp = (0..n).map(|j| 40.0 + 5.0 * j as f64).collect();
            d.kd = vec![2.0; n];
            d
        })
        .collect()
}

#[test]
fn the_mujoco_drives_run_the_law_at_every_physics_step() {
    // Held for a control period of ten physics steps, the command gives the motion of the law
    // written out at each of those steps (a plant with one physics step per tick, its torques
    // computed here from its own state).
    let (mut driven, mut written) = (pair(10), pair(1));
    let cmds = commands(&driven);
    let mut s = empty_state();
    let mut tau = Vec::new();
    for _ in 0..20 {
        for (i, c) in cmds.iter().enumerate() {
            driven.set_drive(i, c);
        }
        driven.step();
        for _ in 0..10 {
            for (i, c) in cmds.iter().enumerate() {
                written.state(i, &mut s);
                tau.clear();
                for j in 0..c.tau_ff.len() {
                    tau.push(
                        c.tau_ff[j]
                            + c.kp[j] * (c.q_des[j] - s.joint_positions[j])
                            + c.kd[j] * (c.qd_des[j] - s.joint_velocities[j]),
                    );
                }
                written.set_torques(i, &tau);
            }
            written.step();
        }
    }
    assert_eq!(
        driven.full_state(),
        written.full_state(),
        "the law at every physics step, bit for bit"
    );
    // The robots moved (a law that did nothing would agree too).
    let start = pair(10).full_state();
    let moved =
        driven.full_state().iter().zip(&start).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    assert!(moved > 1e-3, "moved {moved}");
    // The same torques held for the whole period (a command without gains, the old drives)
    // move the robots otherwise: the law ran inside the period.
    let mut held = pair(10);
    for _ in 0..20 {
        for (i, c) in cmds.iter().enumerate() {
            held.state(i, &mut s);
            let tau: Vec<f64> = (0..c.tau_ff.len())
                .map(|j| {
                    c.tau_ff[j]
                        + c.kp[j] * (c.q_des[j] - s.joint_positions[j])
                        + c.kd[j] * (c.qd_des[j] - s.joint_velocities[j])
                })
                .collect();
            held.set_drive(i, &DriveCommand::torque("t", "r", 0, tau));
        }
        held.step();
    }
    assert_ne!(held.full_state(), driven.full_state());
}

#[test]
fn a_drive_command_without_gains_is_its_torque_bit_for_bit() {
    let (mut drive, mut torque) = (pair(10), pair(10));
    let n: Vec<usize> = (0..2).map(|i| drive.joints(i)).collect();
    for k in 0..50 {
        for (i, &n) in n.iter().enumerate() {
            let tau: Vec<f64> = (0..n).map(|j| 3.0 * ((k * 7 + j * 3 + i) as f64).sin()).collect();
            drive.set_drive(i, &DriveCommand::torque("t", "r", k as u64, tau.clone()));
            torque.set_torques(i, &tau);
        }
        drive.step();
        torque.step();
    }
    assert_eq!(drive.full_state(), torque.full_state());
    // A command with gains, then one without: the law stops, the torque is applied as it is.
    let cmds = commands(&drive);
    for p in [&mut drive, &mut torque] {
        for (i, c) in cmds.iter().enumerate() {
            p.set_drive(i, c);
        }
        p.step();
    }
    for _ in 0..10 {
        for (i, &n) in n.iter().enumerate() {
            drive.set_drive(i, &DriveCommand::torque("t", "r", 0, vec![0.5; n]));
            torque.set_torques(i, &vec![0.5; n]);
        }
        drive.step();
        torque.step();
    }
    assert_eq!(
        drive.full_state(),
        torque.full_state(),
        "no gains after gains: the law no longer runs"
    );
}

#[test]
fn the_placeholder_drives_run_the_law_as_written() {
    // Unit-inertia joints, semi-implicit Euler: v += dt tau(q, v); q += dt v.
    let (dt, v0) = (0.01, 0.3);
    let mut p = PlaceholderPlant::new(vec!["r1".into()], 2, v0, dt);
    let mut d = DriveCommand::torque("t", "r1", 0, vec![0.5, -0.2]);
    d.q_des = vec![1.0, -1.0];
    d.qd_des = vec![0.0, 0.1];
    d.kp = vec![4.0, 9.0];
    d.kd = vec![1.0, 0.5];
    p.set_drive(0, &d);
    let (mut q, mut v) = ([0.0, 0.0], [v0, v0]);
    for _ in 0..2000 {
        p.step();
        for j in 0..2 {
            v[j] +=
                dt * (d.tau_ff[j] + d.kp[j] * (d.q_des[j] - q[j]) + d.kd[j] * (d.qd_des[j] - v[j]));
            q[j] += dt * v[j];
        }
    }
    let mut s = empty_state();
    p.state(0, &mut s);
    for j in 0..2 {
        assert!(
            (s.joint_positions[j] - q[j]).abs() < 1e-12
                && (s.joint_velocities[j] - v[j]).abs() < 1e-12,
            "joint {j}: {:?} against {q:?} {v:?}",
            s.joint_positions
        );
    }
    // The PD pulls each joint to where the feed-forward balances it: q_des + tau_ff / kp.
    assert!((q[0] - (1.0 + 0.5 / 4.0)).abs() < 1e-3, "{q:?}");
}

/// S4 in lockstep with the agents' drive gains (`robot_agent::drive_gains`): every command
/// reaches the drives with its gains, and the team holds S4 as the torque loop does. At the
/// state a command is applied at its law is its torque; over the tick's second physics step
/// it pulls the joints back towards that state, which the object's error barely shows.
#[test]
fn s4_with_the_drive_gains_holds_as_the_torque_loop_does() {
    let sets = ["duration=2", "settle=0.5"];
    let (_, torque) =
        common::scenario::run_scenario("s4_object_circle.toml", &sets, false, "drive_s4_torque");
    let (plan, gains, records) = common::scenario::run_scenario_records(
        "s4_object_circle.toml",
        &[sets[0], sets[1], "drive_gains=\"inertia\""],
        false,
        "drive_s4_inertia",
    );
    for c in &gains.checks {
        assert!(c.passed, "with drive gains: {} = {} not below {}", c.name, c.value, c.bound);
    }
    for r in &plan.robots {
        let commands = records.torques.get(&r.id).map_or(0, Vec::len) as u64;
        assert_eq!(commands, plan.scene.ticks, "{}: a command every tick", r.id);
        assert_eq!(
            records.with_gains.get(&r.id).copied(),
            Some(commands),
            "{}: every command with its gains",
            r.id
        );
    }
    let (a, b) = (torque.object.position_rms_m, gains.object.position_rms_m);
    println!("object RMS: torque loop {:.4} mm, with drive gains {:.4} mm", a * 1e3, b * 1e3);
    assert!(b < 1e-3, "object RMS with drive gains {b} m");
    assert!(
        (a - b).abs() < DIFFERENCE_M,
        "the gains change the object's RMS by {} mm",
        (a - b) * 1e3
    );
}

/// How much the drive gains may change S4's object RMS in lockstep.
const DIFFERENCE_M: f64 = 1e-4;
