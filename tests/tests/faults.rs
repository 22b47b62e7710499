//! Faults with the whole stack and MuJoCo in the loop. Fault 1: a robot's agent dies mid-carry. The scenario's `[[faults]]` kills the agent's task at a tick
//! (`launch::faults`); its simulated robot is then unpowered (zero joint torques,
//! `sim_bridge::lockstep::AgentLoss::Unpowered`) and falls where it stands. The coordinator
//! learns of it from the agent's liveliness token and completes the tick without it. What
//! the team does is then the controller's: with two robots the remaining hand cannot hold the
//! object and the team lets go at once (`coordinator::building_blocks::release`), the remaining robot
//! standing; with three robots, two of them on opposite faces, the grasp is captured again
//! with the two remaining hands and the object stays held.
//!
//! Fault 4, the state source stops, is a message-flow test (placeholder dynamics and plant):
//! the agents, whose real-time command deadline is 25 ms, hold their posture within it.

use evaluation::evaluate::Metrics;
use evaluation::records::Records;
use scenario::plan::Plan;

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
fn run_with_fault(
    file: &str,
    robot: &str,
    at: f64,
    sets: &[&str],
    distributed: bool,
    name: &str,
) -> (Plan, Metrics, Records) {
    let fault = format!("faults=[{{kind=\"agent-stops\",robot=\"{robot}\",at={at}}}]");
    let mut sets = sets.to_vec();
    sets.push(&fault);
    run_scenario_records(file, &sets, distributed, name)
}

/// The fault's tick, and the first tick from then on whose solution (the coordinator's
/// diagnostics: the contact wrenches it computed) no longer includes robot `robot`.
fn noticed(records: &Records, plan: &Plan, robot: &str) -> (u64, u64) {
    let fault = plan.references.clock.first_tick_at(plan.scenario.faults[0].at);
    let before = records
        .diagnostics
        .iter()
        .filter(|d| d.header.tick < fault)
        .any(|d| d.contacts.iter().any(|c| c.robot == robot));
    assert!(before, "{robot} was in the team's solution before the fault");
    let without = records
        .diagnostics
        .iter()
        .find(|d| d.header.tick >= fault && !d.contacts.iter().any(|c| c.robot == robot))
        .map(|d| d.header.tick)
        .expect("a solution without the robot");
    (fault, without)
}

/// Every robot but `dead` stood: torso within 5 cm and 10 deg of its reference throughout.
fn assert_standing(m: &Metrics, dead: &str) {
    for (r, t) in m.torsos.iter().filter(|(r, _)| *r != dead) {
        assert!(t.position_max_m < 0.05, "torso {r} moved {:.3} m", t.position_max_m);
        assert!(t.orientation_max_deg < 10.0, "torso {r} tilted {:.2} deg", t.orientation_max_deg);
    }
    let dead_torso = &m.torsos[dead];
    println!(
        "{dead}'s torso (unpowered): {:.3} m, {:.1} deg",
        dead_torso.position_max_m, dead_torso.orientation_max_deg
    );
    assert!(
        dead_torso.position_max_m > 0.05,
        "the unpowered robot sagged: the fault did strike ({:.3} m)",
        dead_torso.position_max_m
    );
}

/// Two robots on S4, r2's agent killed 0.5 s into the circle.
fn two_robots(distributed: bool, name: &str) {
    let (plan, m, records) = run_with_fault(
        "s4_object_circle.toml",
        "r2",
        0.5,
        &["duration=1.5", "settle=0.5"],
        distributed,
        name,
    );
    let (fault, without) = noticed(&records, &plan, "r2");
    println!("r2 killed at tick {fault}; the team solved without it from tick {without}; released at {:?}", records.released_at);
    assert!(
        without <= fault + 3,
        "the coordinator noticed within 3 ticks: without r2 from {without}, killed at {fault}"
    );
    let released = m.fallback_ticks.get(RELEASED).copied().unwrap_or(0);
    assert!(released > 0, "the team let go: {:?}", m.fallback_ticks);
    let released_at = records.released_at.expect("the status said so");
    assert!(
        released_at <= fault + 3,
        "let go within 3 ticks of the fault: at {released_at}, fault {fault}"
    );
    let status = records.last_status.as_ref().expect("status");
    assert_eq!(
        status.members,
        vec!["r1".to_string()],
        "the status lists the team without r2: {status:?}"
    );
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
    let (plan, m, records) = run_with_fault(
        "team3_cube.toml",
        "r3",
        0.5,
        &["duration=2.5", "settle=0.5"],
        false,
        "fault-agent-dies-3",
    );
    let (fault, without) = noticed(&records, &plan, "r3");
    println!("r3 killed at tick {fault}; the team solved without it from tick {without}");
    assert!(
        without <= fault + 3,
        "the coordinator noticed within 3 ticks: without r3 from {without}, killed at {fault}"
    );
    assert_eq!(
        m.fallback_ticks.get(RELEASED),
        None,
        "the two remaining robots keep the object: {:?}",
        m.fallback_ticks
    );
    assert!(
        m.drop.largest_fall < 0.02,
        "the object stays up: it fell {:.3} m",
        m.drop.largest_fall
    );
    for r in ["r1", "r2"] {
        assert!(m.slip_m[r] < 0.005, "{r}'s palm slipped {:.4} m", m.slip_m[r]);
    }
    assert!(
        m.object.position_max_m < 0.02,
        "the object follows its reference within 2 cm: {:.4} m",
        m.object.position_max_m
    );
    assert_standing(&m, "r3");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn when_the_state_source_stops_every_agent_holds_within_its_deadline() {
    let team = "fault4";
    let s = session().await;
    let deadline = CommandDeadline::default();
    let limit = deadline.time.expect("a time deadline");
    let statuses = transport::subscribe(&s, keys::all_robots(team, RobotTopic::Status).unwrap())
        .await
        .unwrap();
    let c = coordinator(&s, team, Box::new(coordinator::JointDamping { damping: 2.0 }));
    let agents = [
        agent_with_deadline(&s, team, "r1", deadline),
        agent_with_deadline(&s, team, "r2", deadline),
    ];
    let b = bridge(&s, team, &["r1", "r2"], 500, 500);
    let report = tokio::time::timeout(Duration::from_secs(60), b.task)
        .await
        .expect("bounded")
        .unwrap()
        .expect("the run completes");
    assert_eq!(report.ticks, 500);
    // The state source has stopped: no more states, so no more terms and no more commands.
    let (stopped, stopped_ns) = (Instant::now(), protocol::wall_clock_ns());
    let mut held: std::collections::BTreeMap<String, Duration> = Default::default();
    while held.len() < 2 && stopped.elapsed() < Duration::from_secs(2) {
        let Ok(Ok(sample)) =
            tokio::time::timeout(Duration::from_millis(100), statuses.recv_async()).await
        else {
            continue;
        };
        let Ok(st) = decode_sample::<AgentStatus>(&sample) else { continue };
        if st.mode == AgentMode::SafeMode && st.header.stamp_ns > stopped_ns {
            held.entry(st.header.robot_id().to_string())
                .or_insert(Duration::from_nanos(st.header.stamp_ns - stopped_ns));
        }
    }
    println!("safe mode after the state source stopped: {held:?} (deadline {limit:?})");
    assert_eq!(held.len(), 2, "both agents hold their posture: {held:?}");
    for (r, after) in &held {
        // The deadline, one housekeeping period (5 ms) and scheduling slack on a loaded machine.
        assert!(
            *after < limit + Duration::from_millis(75),
            "{r} held {after:?} after the last state"
        );
    }
    for a in agents {
        assert!(stop(a).await.safe_mode_entries >= 1);
    }
    stop(c).await;
    s.close().await.unwrap();
}

/// "Without a jump in torque": no joint's torque steps more than this from one tick to the next
/// around a hand-over, N m (the carry itself steps 0.005 N m; an unblended takeover 0.65-1.9).
const MAX_STEP: f64 = 0.4;

/// The largest change of any joint's applied torque from one tick to the next, per robot, over
/// the ticks `from..to` (recorded torques of consecutive ticks only), with its tick.
///
/// A tick's torque is the first the robot's agent sent for it: the one the lockstep bridge
/// applies. A robot may send more for a tick it has already answered: a coordinator that comes
/// back catches up through ticks the robot held, and the agent takes its command (for the
/// state it has now) under the old tick's number, but no drive ever sees it.
fn largest_step(records: &Records, robot: &str, from: u64, to: u64) -> (f64, u64) {
    let mut by_tick: Vec<&(u64, Vec<f64>)> =
        records.torques[robot].iter().filter(|(t, _)| (from..to).contains(t)).collect();
    // Stable: of a tick's torques, the first sent stays first.
    by_tick.sort_by_key(|(t, _)| *t);
    by_tick.dedup_by_key(|(t, _)| *t);
    let mut worst = (0.0, from);
    for w in by_tick.windows(2) {
        let ((t0, a), (t1, b)) = (w[0], w[1]);
        if t1 - t0 != 1 {
            continue;
        }
        let step = a.iter().zip(b).map(|(x, y)| (y - x).abs()).fold(0.0, f64::max);
        if step > worst.0 {
            worst = (step, *t1);
        }
    }
    worst
}

/// Fault 2: the coordinator dies mid-carry and a new one starts 0.2 s later. The agents hold
/// their posture (its liveliness token gone for `COORDINATOR_GRACE`; the hold carries the load
/// the last command carried, so the object stays held), the new coordinator forms the team
/// again (it waits for every robot of the plan), fits the object from the hands with the
/// planned grasp, gets the references again from the driver, and the agents blend from their
/// hold into its torques: no torque steps larger than the carry's own.
///
/// During the outage the lockstep ticks run at the wall clock's pace, so the outage lasts, in
/// ticks, what the restart took on the machine: 0.2 s, plus the new process's start-up and the
/// agents' reconnection, which grow with the machine's load. The test judges the outage by the
/// ticks it lasted: the object may be off its moving reference by as much as the reference
/// travelled while nobody commanded it, and must be back on it once the new coordinator took
/// over.
fn coordinator_restart(distributed: bool, name: &str) {
    let fault = "faults=[{kind=\"coordinator-stops\",at=0.5,restart_after=0.2}]";
    let (plan, m, records) = run_scenario_records(
        "s4_object_circle.toml",
        &["duration=3.0", "settle=0.5", fault],
        distributed,
        name,
    );
    let clock = &plan.references.clock;
    let (struck, back) = (clock.first_tick_at(0.5), clock.first_tick_at(0.7));
    let solved: Vec<u64> = records
        .diagnostics
        .iter()
        .filter(|d| d.qp_status != protocol::QpStatus::NotRun)
        .map(|d| d.header.tick)
        .collect();
    assert!(
        solved.iter().all(|t| *t <= struck + 1 || *t >= back),
        "no tick solved while the coordinator was dead: {:?}",
        solved.iter().filter(|t| **t > struck + 1 && **t < back).collect::<Vec<_>>()
    );
    let after: Vec<(u64, protocol::QpStatus)> = records
        .diagnostics
        .iter()
        .filter(|d| d.header.tick > struck)
        .map(|d| (d.header.tick, d.qp_status))
        .take(5)
        .collect();
    let resumed = *solved.iter().find(|t| **t >= back).unwrap_or_else(|| {
        panic!("the new coordinator solves ticks; diagnostics after the fault: {after:?}")
    });
    let end = plan.total_ticks();
    let outage = ObjectOutage::measure(&plan, &records, struck, resumed);
    println!("coordinator killed at tick {struck}, started again at {back}, solving from {resumed}: an outage of {:.3} s; {outage:?}", outage.seconds);
    // The lockstep bridge gives a coordinator `DEFAULT_COORDINATOR_GRACE_TICKS` to come back;
    // a second is left after it to judge the takeover.
    assert!(resumed + clock.ticks_lasting(1.0) <= end, "the new coordinator took the team back with a second of the run left: tick {resumed} of {end}");
    for r in ["r1", "r2"] {
        let ticks: std::collections::BTreeSet<u64> =
            records.torques[r].iter().map(|(t, _)| *t).collect();
        let missing: Vec<u64> = (plan.references.clock.settle_ticks..plan.total_ticks())
            .filter(|t| !ticks.contains(t))
            .collect();
        assert!(
            missing.is_empty(),
            "{r} applied a torque every tick; none recorded for ticks {missing:?}"
        );
        let normal = largest_step(&records, r, clock.first_tick_at(0.1), struck);
        let hold = largest_step(&records, r, struck.saturating_sub(1), struck + 20);
        let takeover = largest_step(&records, r, resumed.saturating_sub(2), resumed + 200);
        println!("{r}: largest torque step per tick: carrying {:.3} N m (tick {}), entering the hold {:.3} (tick {}), taking over {:.3} (tick {})", normal.0, normal.1, hold.0, hold.1, takeover.0, takeover.1);
        // Measured: 0.005 N m per tick while carrying; entering the hold 0.007-0.013 with the
        // agents' blend from the last command (0.53-0.55 without it: the hold's damping stepping
        // in); taking over 0.010-0.030 with the blend, 0.65-1.9 without it (takeover zero).
        assert!(
            hold.0 <= MAX_STEP,
            "{r}: the hold starts where the commands left off: {hold:?} (carrying: {normal:?})"
        );
        assert!(
            takeover.0 <= MAX_STEP,
            "{r}: the new coordinator's torques blend in: {takeover:?} (carrying: {normal:?})"
        );
    }
    assert!(!m.drop.dropped, "the object stays held");
    for (r, slip) in &m.slip_m {
        assert!(*slip < 0.005, "{r}'s palm slipped {slip} m");
    }
    for (r, t) in &m.torsos {
        assert!(t.position_max_m < 0.01, "torso {r} moved {} m", t.position_max_m);
    }
    // Measured with outages of 0.20-0.37 s (two busy loops beside the run): the hold let the
    // object sag 6.3-6.4 mm; the error peaked up to 6 mm above the reference's travel (16-29
    // mm) and the sag together, catching up after the takeover, and was 1.7-1.9 mm over the
    // last second.
    assert!(
        outage.held_m < 0.01,
        "the held object stays near where the last command left it: it moved {:.4} m",
        outage.held_m
    );
    assert!(outage.worst_m < outage.travel_m + outage.held_m + 0.01, "the object is off its reference by no more than the reference travelled and the hold sagged during the outage, and 1 cm catching up: {outage:?}");
    assert!(
        outage.last_second_m < 0.005,
        "the new coordinator brought the object back onto its reference: {outage:?}"
    );
}

/// The object around a coordinator's outage from tick `struck` to tick `resumed`, m.
#[derive(Debug)]
struct ObjectOutage {
    /// Length of the outage, s.
    seconds: f64,
    /// How far the object's reference moved from where it was at `struck`.
    travel_m: f64,
    /// How far the object moved from where it was at `struck`, until `resumed`.
    held_m: f64,
    /// The largest error from its reference, from `struck` on.
    worst_m: f64,
    /// The largest error from its reference over the run's last second.
    last_second_m: f64,
}

impl ObjectOutage {
    fn measure(plan: &Plan, records: &Records, struck: u64, resumed: u64) -> ObjectOutage {
        let clock = &plan.references.clock;
        let at = |tick: u64| -> Option<(nalgebra::Vector3<f64>, nalgebra::Vector3<f64>)> {
            let g = records.truth.iter().find(|g| g.header.tick == tick)?;
            let measured = nalgebra::Vector3::from(g.object.as_ref()?.pose.position);
            let reference = nalgebra::Vector3::from(
                plan.references.object_at(clock.scenario_time(tick)).pose.position,
            );
            Some((measured, reference))
        };
        let (p0, r0) = at(struck).expect("the object's ground truth at the fault");
        let (mut out, end) = (
            ObjectOutage {
                seconds: (resumed - struck) as f64 * clock.dt(),
                travel_m: 0.0,
                held_m: 0.0,
                worst_m: 0.0,
                last_second_m: 0.0,
            },
            plan.total_ticks(),
        );
        let last_second = end.saturating_sub(clock.ticks_lasting(1.0));
        for (p, r, tick) in (struck..end).filter_map(|t| at(t).map(|(p, r)| (p, r, t))) {
            let error = (p - r).norm();
            out.worst_m = out.worst_m.max(error);
            if tick <= resumed {
                out.travel_m = out.travel_m.max((r - r0).norm());
                out.held_m = out.held_m.max((p - p0).norm());
            }
            if tick >= last_second {
                out.last_second_m = out.last_second_m.max(error);
            }
        }
        out
    }
}

#[test]
fn a_restarted_coordinator_takes_the_team_back_without_a_torque_jump() {
    coordinator_restart(false, "fault-coordinator-restart");
}

#[test]
fn a_coordinator_process_killed_and_started_again_takes_the_team_back() {
    // SIGKILL: the Zenoh hub of the run goes with it; the new process listens on the same
    // endpoint and the others reconnect.
    coordinator_restart(true, "fault-coordinator-restart-distributed");
}

/// Fault 3: an agent dies and a new one starts 0.3 s later. Its robot's drives freeze
/// meanwhile (`drive_loss = "freeze"`), so it still stands; the two robots on opposite faces
/// keep the object; the restarted agent joins the running team: the coordinator commands it from
/// its first terms, and it stands beside the team with its hand out of the grasp (taking a
/// grasp again is not built).
#[test]
fn an_agent_restarted_mid_carry_rejoins_the_team_beside_it() {
    let fault = "faults=[{kind=\"agent-stops\",robot=\"r3\",at=0.5,restart_after=0.3}]";
    let (plan, m, records) = run_scenario_records(
        "team3_cube.toml",
        &["duration=2.0", "settle=0.5", "drive_loss=\"freeze\"", fault],
        false,
        "fault-agent-restarts",
    );
    let clock = &plan.references.clock;
    let (struck, back) = (clock.first_tick_at(0.5), clock.first_tick_at(0.8));
    let feet_of = |d: &protocol::TickDiagnostics, r: &str| {
        d.contacts.iter().filter(|c| c.robot == r && c.wrench.len() == 3).count()
    };
    let hand_of = |d: &protocol::TickDiagnostics, r: &str| {
        d.contacts.iter().any(|c| c.robot == r && c.wrench.len() == 6)
    };
    let without = records
        .diagnostics
        .iter()
        .find(|d| d.header.tick >= struck && feet_of(d, "r3") == 0)
        .map(|d| d.header.tick)
        .expect("solved without r3");
    let rejoined = records
        .diagnostics
        .iter()
        .find(|d| d.header.tick > back && feet_of(d, "r3") > 0)
        .map(|d| d.header.tick)
        .expect("r3 back in the team's solution");
    println!("r3's agent killed at tick {struck}: solved without it from {without}; started again at {back}: in the team again from {rejoined}");
    assert!(without <= struck + 3, "noticed within 3 ticks");
    // The lockstep loop does not wait for a robot whose agent left: how many ticks the new
    // agent's start-up takes depends on the machine. Judged are the ticks after it rejoined.
    assert!(
        rejoined + clock.ticks_lasting(0.5) <= plan.total_ticks(),
        "rejoined with half a second of the run left to judge: tick {rejoined}"
    );
    for d in records.diagnostics.iter().filter(|d| d.header.tick >= rejoined) {
        assert!(!hand_of(d, "r3"), "tick {}: r3's hand stays out of the grasp", d.header.tick);
        assert!(
            hand_of(d, "r1") && hand_of(d, "r2"),
            "tick {}: r1 and r2 hold the object",
            d.header.tick
        );
    }
    let status = records.last_status.as_ref().expect("status");
    assert_eq!(status.members, vec!["r1", "r2", "r3"], "{status:?}");
    assert_eq!(status.late, vec!["r3"], "r3 is named as late: {status:?}");
    // Its agent commands it again: torques of the coordinator's ticks after the rejoin.
    assert!(
        records.torques["r3"].iter().any(|(t, _)| *t > rejoined),
        "r3's agent applies torques again"
    );
    assert!(
        !m.drop.dropped && m.drop.largest_fall < 0.02,
        "the object stays up: fell {:.3} m",
        m.drop.largest_fall
    );
    for r in ["r1", "r2"] {
        assert!(m.slip_m[r] < 0.005, "{r}'s palm slipped {:.4} m", m.slip_m[r]);
        assert!(
            m.torsos[r].position_max_m < 0.01,
            "torso {r} moved {:.4} m",
            m.torsos[r].position_max_m
        );
    }
    assert!(
        m.object.position_max_m < 0.02,
        "the object follows its reference within 2 cm: {:.4} m",
        m.object.position_max_m
    );
    let t3 = &m.torsos["r3"];
    println!(
        "r3's torso: max {:.4} m, {:.2} deg from its reference",
        t3.position_max_m, t3.orientation_max_deg
    );
    // Measured 2.0 mm, 0.08 deg (with a hold order before its first command: 41 mm, 0.66 deg,
    // before the hold carried the torso on the feet, `robot_agent::standing`).
    assert!(
        t3.position_max_m < 0.01 && t3.orientation_max_deg < 1.0,
        "r3 stands throughout (frozen, then commanded)"
    );
}
