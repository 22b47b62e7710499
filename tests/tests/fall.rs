//! A robot that falls goes limp and leaves its team (`robot_agent::fall`), with the whole
//! stack and MuJoCo in the loop: three robots hold the cube (`team3_cube.toml`) and robot r3
//! is pushed over (600 N on its base for 0.4 s, sideways and away from the team: r3 stands at
//! -y facing the cube, the push is along (+x, -y) / sqrt 2; the team lets go of the cube as
//! its hand slips). Pushed along +x alone, r3 slid up to 1.8 m sideways into r2 and dragged it
//! down in most runs: whether it got that far was chaotic (a QP regularisation 20 % higher or
//! lower, or the QP's answer by the robots' blocks, 1e-6 apart in torque, decided it), and a
//! robot knocked over by a falling teammate is not what this test is about. Before the fall handling, r3 stayed in the team lying on its side: the
//! contact-force QP was infeasible on every tick from the push to the end (2856 of 4000 in a
//! 4 s run, its feet in the air) and its drives fought the floor.
//!
//! On the ground truth and the recording: r3's agent says it fell at the first state whose
//! torso tilt passes 60 degrees or whose torso height is below half its first; the coordinator solves the team without r3 within 3 ticks of
//! it, never takes it back, and its members leave r3 out; from
//! then on every tick of the two robots left is solved by the QP and they stand (torsos within
//! 2 cm and 3 deg of their holds); and every torque r3 applies after the fall is the limp law
//! written out again here, `clamp(-K_d qdot)` with the posture hold's `K_d`, from the joint
//! velocities of the state it answers.

mod common;

#[path = "../../robot-agent/tests/common/hold_law.rs"]
mod hold_law;
use hold_law::hold_kd;
use std::collections::BTreeMap;

use protocol::{AgentMode, AgentStatus, QpStatus, RobotState};

const NAME: &str = "team3_r3_falls";
const TILT_LIMIT_DEG: f64 = 60.0;
/// Fallen below this share of the first torso height.
const HEIGHT_RATIO: f64 = 0.5;

fn tilt_at_tick(g: &protocol::GroundTruth, id: &str) -> f64 {
    g.torsos.iter().find(|t| t.name == id).map_or(0.0, |t| tilt_deg(&t.pose.orientation))
}

/// Tilt of the body z axis from the vertical, deg, written out from the quaternion.
fn tilt_deg(q: &[f64; 4]) -> f64 {
    let n2: f64 = q.iter().map(|c| c * c).sum();
    (1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]) / n2).clamp(-1.0, 1.0).acos().to_degrees()
}

#[test]
fn a_robot_pushed_over_goes_limp_and_the_rest_of_the_team_stands() {
    let sets = ["duration=3.0", "settle=0.5", "perturbations=[{on=\"r3\",body=\"base\",start=1.0,duration=0.4,wrench=[424.26,-424.26,0.0,0.0,0.0,0.0]}]"];
    let (plan, metrics, records) =
        common::scenario::run_scenario_recorded("team3_cube.toml", &sets, NAME);

    // r3's agent status and the states it judged, from the recording.
    let bytes =
        std::fs::read(common::scenario::report_dir(NAME).join("run.mcap")).expect("the recording");
    let (status_key, state_key) = ("team/team/robot/r3/status", "team/team/robot/r3/state");
    let (mut fallen_status, mut states): (Option<AgentStatus>, BTreeMap<u64, RobotState>) =
        (None, BTreeMap::new());
    for msg in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
        let msg = msg.expect("a readable message");
        if msg.channel.topic == status_key && fallen_status.is_none() {
            let s: AgentStatus = serde_json::from_slice(&msg.data).expect("status decodes");
            if s.mode == AgentMode::Fallen {
                fallen_status = Some(s);
            }
        } else if msg.channel.topic == state_key {
            let s: RobotState = serde_json::from_slice(&msg.data).expect("state decodes");
            states.insert(s.header.tick, s);
        }
    }
    // The agent's two signs (`robot_agent::fall`) written out again on the states it received:
    // the first whose torso tilts past the limit or has sunk below half the height of its
    // first state (tick 0, before the settling the ground truth leaves out).
    let h0 = states.values().next().expect("r3's states").base_pose.position[2];
    let fallen = |s: &RobotState| {
        s.base_pose.position[2] < HEIGHT_RATIO * h0
            || tilt_deg(&s.base_pose.orientation) > TILT_LIMIT_DEG
    };
    let fell =
        states.values().find(|s| fallen(s)).map(|s| s.header.tick).expect("r3 is pushed over");
    // The ground truth agrees within a tick (a state is the world at its tick's start).
    let height_of = |g: &protocol::GroundTruth| {
        g.torsos.iter().find(|t| t.name == "r3").map_or(f64::NAN, |t| t.pose.position[2])
    };
    let truth_fell = records
        .truth
        .iter()
        .find(|g| height_of(g) < HEIGHT_RATIO * h0 || tilt_at_tick(g, "r3") > TILT_LIMIT_DEG)
        .map(|g| g.header.tick)
        .expect("r3 falls in the ground truth");
    assert!(
        truth_fell.abs_diff(fell) <= 1,
        "r3's states fall at tick {fell}, the ground truth at {truth_fell}"
    );
    let tilt_at = |id: &str| -> Vec<(u64, f64)> {
        records
            .truth
            .iter()
            .map(|g| {
                (
                    g.header.tick,
                    g.torsos
                        .iter()
                        .find(|t| t.name == id)
                        .map_or(0.0, |t| tilt_deg(&t.pose.orientation)),
                )
            })
            .collect()
    };
    for id in ["r1", "r2"] {
        let worst = tilt_at(id).into_iter().map(|(_, t)| t).fold(0.0, f64::max);
        assert!(worst < 3.0, "{id} tilts {worst:.2} deg");
    }
    let status = fallen_status.expect("r3's agent reports that it fell");
    println!("r3 tilted past {TILT_LIMIT_DEG} deg or sank below half its height at tick {fell}; its agent reported Fallen with the state of tick {}", status.header.tick);
    assert_eq!(status.header.tick, fell, "the agent falls at the state that passed the limit");

    // The coordinator solves without r3 within 3 ticks (its tick diagnostics name no contact of
    // r3's), and its members leave r3 out from then on.
    let left = records
        .diagnostics
        .iter()
        .filter(|d| d.header.tick >= fell)
        .find(|d| d.contacts.iter().all(|c| c.robot != "r3"))
        .map(|d| d.header.tick)
        .expect("r3 leaves the team");
    println!("the coordinator solves without r3 from tick {left}");
    assert!(left <= fell + 3, "r3 fell at tick {fell}, the team was solved without it from {left}");
    // The coordinator's status says so at once (it goes out on a change of the team; otherwise
    // about once a second). Which of the agent's two signs comes first is a race: its membership
    // withdrawn (liveliness), or its terms missing past the reuse deadline (r3 is then silent
    // until the withdrawal arrives). Either way, from the first status that leaves r3 out of
    // the team, no status takes it back, and by the last r3 is no member at all.
    let in_team = |s: &&protocol::CoordinatorStatus| {
        s.members.iter().any(|m| m == "r3") && !s.silent.iter().any(|m| m == "r3")
    };
    // (Before the fall r3 may have been silent for a tick on a loaded machine: the search
    // starts at the statuses of the fall's tick.)
    let out = records
        .statuses
        .iter()
        .position(|s| s.header.tick + 1 >= fell && !in_team(&s))
        .expect("a status leaves r3 out of the team");
    let said = records.statuses[out].header.tick;
    assert!(
        said + 1 >= fell && said <= fell + 3,
        "r3 fell at tick {fell}; the status that leaves it out is of tick {said}"
    );
    let back = records.statuses[out..].iter().find(in_team);
    assert!(back.is_none(), "r3 is back in the team at tick {:?}", back.map(|s| s.header.tick));
    let last = records.statuses.last().expect("statuses");
    assert!(
        !last.members.iter().any(|m| m == "r3"),
        "r3 withdrew its membership: still a member at tick {}",
        last.header.tick
    );

    // The two robots left: every tick solved, no contact of r3's.
    let after: Vec<_> = records.diagnostics.iter().filter(|d| d.header.tick > left + 1).collect();
    assert!(after.len() > 500, "ticks after the fall: {}", after.len());
    for d in &after {
        assert!(
            matches!(d.qp_status, QpStatus::Solved | QpStatus::AlmostSolved),
            "tick {}: {:?} ({:?})",
            d.header.tick,
            d.qp_status,
            d.fallback
        );
        assert!(
            d.contacts.iter().all(|c| c.robot != "r3"),
            "tick {}: r3 still in the QP",
            d.header.tick
        );
    }
    for id in ["r1", "r2"] {
        let t = &metrics.torsos[id];
        assert!(
            t.position_max_m < 0.02 && t.orientation_max_deg < 3.0,
            "{id}: {:.4} m, {:.2} deg",
            t.position_max_m,
            t.orientation_max_deg
        );
    }

    // r3's torques after the fall: the limp law, from the state each answers.
    let limits =
        &plan.robots.iter().find(|r| r.id == "r3").expect("r3 planned").robot.torque_limits;
    let kd: Vec<f64> = limits.iter().map(|l| hold_kd(*l)).collect();
    let applied: Vec<&(u64, Vec<f64>)> =
        records.torques["r3"].iter().filter(|(k, _)| *k >= fell).collect();
    assert!(applied.len() > 500, "r3's torques after the fall: {}", applied.len());
    let mut moving = 0;
    for (tick, tau) in applied {
        let v = &states
            .get(tick)
            .unwrap_or_else(|| panic!("r3's state of tick {tick} recorded"))
            .joint_velocities;
        for j in 0..tau.len() {
            let want = (-kd[j] * v[j]).clamp(-limits[j], limits[j]);
            assert!(
                (tau[j] - want).abs() <= 1e-9 * (1.0 + want.abs()),
                "tick {tick} joint {j}: applied {} vs -K_d qdot {want}",
                tau[j]
            );
        }
        moving += usize::from(v.iter().any(|x| x.abs() > 0.05));
    }
    assert!(moving > 10, "r3 moved while limp on {moving} ticks: the damping was exercised");
}
