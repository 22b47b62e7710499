//! Faults with the whole stack and MuJoCo in the loop (the hosts-and-faults issue, fault 1): a
//! robot's agent dies mid-carry. The scenario's `[[faults]]` kills the agent's task at a tick
//! (`team_runner::faults`); its simulated robot is then unpowered (zero joint torques,
//! `sim_bridge::lockstep::AgentLoss::Unpowered`) and falls where it stands. The coordinator
//! learns of it from the agent's liveliness token and completes the tick without it. What
//! the team does is then the controller's: with two robots the remaining hand cannot hold the
//! object and the team lets go at once (`coordinator::units::release`), the remaining robot
//! standing; with three robots, two of them on opposite faces, the grasp is captured again
//! with the two remaining hands and the object stays held.
//!
//! Fault 4, the state source stops, is a message-flow test (placeholder dynamics and plant):
//! the agents, whose real-time command deadline is 25 ms, hold their posture within it.

use team_runner::driver::Records;
use team_runner::evaluate::Metrics;
use team_runner::plan::Plan;

use std::time::{Duration, Instant};

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample};
use protocol::{AgentMode, AgentStatus};
use robot_agent::safe_mode::CommandDeadline;

mod common;
use common::scenario::run_scenario_records;
use common::team::{agent_with_deadline, bridge, coordinator, session, stop};

const RELEASED: &str = "grasp released (hands free, feet only)";

/// `scenarios/{file}` with `sets` and robot `robot`'s agent killed `at` s into the scenario.
fn run_with_fault(file: &str, robot: &str, at: f64, sets: &[&str], distributed: bool, name: &str) -> (Plan, Metrics, Records) {
    let fault = format!("faults=[{{kind=\"agent-stops\",robot=\"{robot}\",at={at}}}]");
    let mut sets = sets.to_vec();
    sets.push(&fault);
    run_scenario_records(file, &sets, distributed, name)
}

/// The fault's tick, and the first tick from then on whose solution (the coordinator's
/// diagnostics: the contact wrenches it computed) no longer includes robot `robot`.
fn noticed(records: &Records, plan: &Plan, robot: &str) -> (u64, u64) {
    let fault = plan.references.clock.first_tick_at(plan.scenario.faults[0].at);
    let before = records.diagnostics.iter().filter(|d| d.header.tick < fault).any(|d| d.contacts.iter().any(|c| c.robot == robot));
    assert!(before, "{robot} was in the team's solution before the fault");
    let without = records.diagnostics.iter().find(|d| d.header.tick >= fault && !d.contacts.iter().any(|c| c.robot == robot)).map(|d| d.header.tick).expect("a solution without the robot");
    (fault, without)
}

/// Every robot but `dead` stood: torso within 5 cm and 10 deg of its reference throughout.
fn assert_standing(m: &Metrics, dead: &str) {
    for (r, t) in m.torsos.iter().filter(|(r, _)| *r != dead) {
        assert!(t.position_max_m < 0.05, "torso {r} moved {:.3} m", t.position_max_m);
        assert!(t.orientation_max_deg < 10.0, "torso {r} tilted {:.2} deg", t.orientation_max_deg);
    }
    let dead_torso = &m.torsos[dead];
    println!("{dead}'s torso (unpowered): {:.3} m, {:.1} deg", dead_torso.position_max_m, dead_torso.orientation_max_deg);
    assert!(dead_torso.position_max_m > 0.05, "the unpowered robot sagged: the fault did strike ({:.3} m)", dead_torso.position_max_m);
}

/// Two robots on S4, r2's agent killed 0.5 s into the circle.
fn two_robots(distributed: bool, name: &str) {
    let (plan, m, records) = run_with_fault("s4_object_circle.toml", "r2", 0.5, &["duration=1.5", "settle=0.5"], distributed, name);
    let (fault, without) = noticed(&records, &plan, "r2");
    println!("r2 killed at tick {fault}; the team solved without it from tick {without}; released at {:?}", records.released_at);
    assert!(without <= fault + 3, "the coordinator noticed within 3 ticks: without r2 from {without}, killed at {fault}");
    let released = m.fallback_ticks.get(RELEASED).copied().unwrap_or(0);
    assert!(released > 0, "the team let go: {:?}", m.fallback_ticks);
    let released_at = records.released_at.expect("the status said so");
    assert!(released_at <= fault + 3, "let go within 3 ticks of the fault: at {released_at}, fault {fault}");
    let status = records.last_status.as_ref().expect("status");
    assert_eq!(status.members, vec!["r1".to_string()], "the status lists the team without r2: {status:?}");
    assert_standing(&m, "r2");
}

#[test]
fn an_agent_dying_mid_carry_in_a_team_of_two_makes_the_other_let_go_and_stand() {
    two_robots(false, "fault-agent-dies-2");
}

#[test]
fn an_agent_process_killed_mid_carry_is_noticed_as_fast() {
    // Separate processes: SIGKILL, no goodbye; the session's end takes the liveliness token.
    two_robots(true, "fault-agent-dies-2-distributed");
}

#[test]
fn an_agent_dying_in_a_team_of_three_leaves_the_other_two_holding() {
    // r1 and r2 on opposite faces (-x, +x), r3 on -y: r3's agent dies.
    let (plan, m, records) = run_with_fault("team3_cube.toml", "r3", 0.5, &["duration=2.5", "settle=0.5"], false, "fault-agent-dies-3");
    let (fault, without) = noticed(&records, &plan, "r3");
    println!("r3 killed at tick {fault}; the team solved without it from tick {without}");
    assert!(without <= fault + 3, "the coordinator noticed within 3 ticks: without r3 from {without}, killed at {fault}");
    assert_eq!(m.fallback_ticks.get(RELEASED), None, "the two remaining robots keep the object: {:?}", m.fallback_ticks);
    assert!(m.drop.largest_fall < 0.02, "the object stays up: it fell {:.3} m", m.drop.largest_fall);
    for r in ["r1", "r2"] {
        assert!(m.slip_m[r] < 0.005, "{r}'s palm slipped {:.4} m", m.slip_m[r]);
    }
    assert!(m.object.position_max_m < 0.02, "the object follows its reference within 2 cm: {:.4} m", m.object.position_max_m);
    assert_standing(&m, "r3");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn when_the_state_source_stops_every_agent_holds_within_its_deadline() {
    let team = "fault4";
    let s = session().await;
    let deadline = CommandDeadline::default();
    let limit = deadline.time.expect("a time deadline");
    let statuses = transport::subscribe(&s, keys::all_robots(team, RobotTopic::Status).unwrap()).await.unwrap();
    let c = coordinator(&s, team, Box::new(coordinator::JointDamping { damping: 2.0 }));
    let agents = [agent_with_deadline(&s, team, "r1", deadline), agent_with_deadline(&s, team, "r2", deadline)];
    let b = bridge(&s, team, &["r1", "r2"], 500, 500);
    let report = tokio::time::timeout(Duration::from_secs(60), b.task).await.expect("bounded").unwrap().expect("the run completes");
    assert_eq!(report.ticks, 500);
    // The state source has stopped: no more states, so no more terms and no more commands.
    let (stopped, stopped_ns) = (Instant::now(), protocol::wall_clock_ns());
    let mut held: std::collections::BTreeMap<String, Duration> = Default::default();
    while held.len() < 2 && stopped.elapsed() < Duration::from_secs(2) {
        let Ok(Ok(sample)) = tokio::time::timeout(Duration::from_millis(100), statuses.recv_async()).await else { continue };
        let Ok(st) = decode_sample::<AgentStatus>(&sample) else { continue };
        if st.mode == AgentMode::SafeMode && st.header.stamp_ns > stopped_ns {
            held.entry(st.header.robot_id().to_string()).or_insert(Duration::from_nanos(st.header.stamp_ns - stopped_ns));
        }
    }
    println!("safe mode after the state source stopped: {held:?} (deadline {limit:?})");
    assert_eq!(held.len(), 2, "both agents hold their posture: {held:?}");
    for (r, after) in &held {
        // The deadline, one housekeeping period (5 ms) and scheduling slack on a loaded machine.
        assert!(*after < limit + Duration::from_millis(75), "{r} held {after:?} after the last state");
    }
    for a in agents {
        assert!(stop(a).await.safe_mode_entries >= 1);
    }
    stop(c).await;
    s.close().await.unwrap();
}
