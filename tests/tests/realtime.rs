//! The team against the wall clock (`team run --realtime`, `Scene::realtime`): the sim-bridge
//! paces physics at the control period, a robot whose torques miss a tick's deadline keeps its
//! last ones, and every tick's ground truth carries the loop as the bridge measured it
//! (`protocol::LoopTiming`), which the report turns into latency percentiles, misses, late and
//! lost commands (`evaluation::loop_timing`).
//!
//! S4 runs at its own length at the real-time defaults (`scenario::pace`: the team loop at
//! 250 Hz, drive commands with gains and a trajectory the drives follow between team ticks, the
//! delay from the latency), embedded and as processes, with no drive step left without a valid
//! command; CI runs the file again beside two busy loops. docs/results.md has the series.

mod common;

use std::collections::BTreeSet;
use std::sync::Arc;

use evaluation::evaluate::{self, Metrics};
use evaluation::loop_timing::LoopReport;
use evaluation::records::Records;
use launch::hosts::TestHosts;
use launch::launcher::RunMode;
use launch::record::{RecordOptions, ScenarioSource};
use launch::run::{self, RunOptions};
use robot_agent::delay::TeamDelay;
use robot_agent::drive_gains::DriveGainsMode;
use scenario::file::Scenario;
use scenario::plan::{self, Plan};
use scenario::Pacing;

/// The tests run one at a time: two real-time runs at once on two cores miss their deadlines.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// S4 at `hz` for `duration` s, paced by the wall clock.
fn s4_realtime(hz: f64, duration: f64) -> Plan {
    let sets = [format!("duration={duration}"), "settle=0.5".into(), format!("control_hz={hz}")];
    let s = Scenario::load(common::scenario::repo().join("scenarios/s4_object_circle.toml"), &sets)
        .expect("scenario");
    let mut plan = plan::plan(&s, &common::scenario::repo()).expect("plan");
    plan.scene.realtime = true;
    plan
}

/// `team3_cube.toml` with `sets`, paced by the wall clock.
fn team3_realtime(sets: &[&str]) -> Plan {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let s = Scenario::load(common::scenario::repo().join("scenarios/team3_cube.toml"), &sets)
        .expect("scenario");
    let mut plan = plan::plan(&s, &common::scenario::repo()).expect("plan");
    plan.scene.realtime = true;
    plan
}

/// `plan` run on this computer, embedded or as processes on loopback, reported into
/// `target/test-reports/{name}`: its records and metrics, of a run the host left its
/// processors (`None`: it never did, and the test is listed as skipped; `common::machine`).
fn run_here(plan: &Plan, distributed: bool, mode: &str, name: &str) -> Option<(Records, Metrics)> {
    common::machine::on_its_processors(&format!("realtime::{name}"), || {
        let dir = common::scenario::repo().join("target/test-reports").join(name);
        std::fs::create_dir_all(&dir).expect("report dir");
        let records = run::run(
            plan,
            &RunOptions { distributed, hosts: false, progress: false, loss: Vec::new() },
            &dir,
        )
        .expect("the run completes");
        let m = evaluated(plan, &records, mode, name);
        (records, m)
    })
}

/// `plan` run with every component on its own host of `hosts`, reported into
/// `target/test-reports/{name}`: its records, of a run the host left its processors (`None`:
/// it never did; `common::machine`).
fn run_across_hosts(plan: &Plan, hosts: Arc<TestHosts>, name: &str) -> Option<Records> {
    let run = || {
        let dir = common::scenario::repo().join("target/test-reports").join(name);
        std::fs::create_dir_all(&dir).expect("report dir");
        let mode = RunMode::Hosts { dir, hosts: hosts.clone(), certs: None };
        let rt = tokio::runtime::Runtime::new().expect("runtime");
        let records = rt
            .block_on(run::run_in(
                plan,
                &RunOptions { distributed: true, hosts: true, progress: false, loss: Vec::new() },
                &mode,
                None,
            ))
            .expect("the run completes");
        (records, ())
    };
    common::machine::on_its_processors(&format!("realtime::{name}"), run).map(|(r, ())| r)
}

fn evaluated(plan: &Plan, records: &Records, mode: &str, name: &str) -> Metrics {
    let dir = common::scenario::repo().join("target/test-reports").join(name);
    std::fs::create_dir_all(&dir).expect("report dir");
    let eval = evaluate::evaluate(plan, records, mode);
    evaluate::write_report(plan, &eval, &dir).expect("report");
    evaluation::plots::write_all(plan, &eval, records, &dir).expect("figures");
    println!("{}", evaluate::summary(&eval.metrics, &dir));
    assert!(dir.join("loop_timing.png").exists(), "a real-time run draws its loop");
    eval.metrics
}

/// The bridge's bookkeeping checked against what another subscriber saw: every tick the loop
/// says came in time, the driver recorded that robot's torques of that tick too; applied ticks
/// are never ahead of their tick; a tick in time applied its own torques.
fn assert_loop_consistent(plan: &Plan, records: &Records, report: &LoopReport) {
    let ticks = plan.scene.ticks;
    for r in &plan.robots {
        let l = &report.robots[&r.id];
        assert_eq!(l.ticks, ticks, "{}: a measurement on every scenario tick", r.id);
        let recorded: BTreeSet<u64> = records
            .torques
            .get(&r.id)
            .map(|v| v.iter().map(|(t, _)| *t).collect())
            .unwrap_or_default();
        let (mut in_time, mut slow) = (0, Vec::new());
        for g in records.truth.iter() {
            for t in g.loop_timing.iter().filter(|t| t.robot == r.id) {
                assert!(
                    t.applied_tick.is_none_or(|a| a <= g.header.tick),
                    "tick {} applied {:?}",
                    g.header.tick,
                    t.applied_tick
                );
                if let Some(us) = t.latency_us {
                    in_time += 1;
                    assert_eq!(
                        t.applied_tick,
                        Some(g.header.tick),
                        "{}: tick {} came in time but applied {:?}",
                        r.id,
                        g.header.tick,
                        t.applied_tick
                    );
                    if us >= 1.5e6 / plan.scenario.control_hz {
                        slow.push((g.header.tick, us));
                    }
                    assert!(
                        recorded.contains(&g.header.tick),
                        "{}: the driver saw no torques of tick {} that the bridge applied",
                        r.id,
                        g.header.tick
                    );
                }
            }
        }
        assert_eq!(
            in_time + l.deadline_misses,
            ticks,
            "{}: every tick either in time or missed",
            r.id
        );
        // In time means taken before the tick's physics step; the latency runs to when the
        // bridge took the torques. A loaded machine can wake the bridge well after its deadline
        // (once: 17.9 ms at 250 Hz), and it then steps late too: such ticks stay rare.
        assert!(
            slow.len() as u64 <= ticks / 100,
            "{}: in time after more than 1.5 periods: {slow:?}",
            r.id
        );
    }
}

/// Embedded, 250 Hz: the team holds S4 against the wall clock, the loop is measured on every
/// tick, and it kept up (at most 5 % of the ticks missed).
#[test]
fn s4_holds_in_real_time_and_reports_its_loop() {
    let _one = serial();
    let plan = s4_realtime(250.0, 2.0);
    let Some((records, m)) = run_here(&plan, false, "embedded, real time", "realtime_s4") else {
        return;
    };
    for c in &m.checks {
        assert!(c.passed, "{} = {} not below {}", c.name, c.value, c.bound);
    }
    let report = m.loop_timing.as_ref().expect("a real-time run reports its loop");
    assert_loop_consistent(&plan, &records, report);
    for (r, l) in &report.robots {
        assert!(l.latency_us.p50 > 0.0, "{r}: latency measured");
        // Misses come in bursts when the shared machine stalls: 3 of 500 idle, 11 of 500 in a
        // fresh clone's run (one burst of 10 ticks: 40 ms during which neither robot answered).
        assert!(
            l.deadline_misses * 20 <= l.ticks,
            "{r}: {} of {} ticks missed",
            l.deadline_misses,
            l.ticks
        );
    }
    // The wall clock paced it: 2 s of scenario took about 2 s.
    assert!(
        records.run_wall.as_secs_f64() > 1.9,
        "paced by the wall clock: {:?}",
        records.run_wall
    );
    assert_handover_without_gap(&plan, &records);
}

/// The hand-over from the lockstep settle to the paced scenario is a tick like the others: the
/// wall time between the last settling tick's ground truth and the first scenario tick's (both
/// stamped by the bridge, one clock) is at most two periods, or the longest gap between two
/// scenario ticks if a loaded machine made one longer. A bridge that declared its links again
/// and waited for the coordinator's next status there left 10-50 ms at 250 Hz, and the agents'
/// deadlines ran out in it.
fn assert_handover_without_gap(plan: &Plan, records: &Records) {
    let ms = |a: u64, b: u64| b.saturating_sub(a) as f64 / 1e6;
    let settle_end =
        records.settle_end_stamp_ns.expect("the last settling tick's ground truth was heard");
    let first = records.truth.first().expect("scenario ticks");
    assert_eq!(first.header.tick, plan.references.clock.settle_ticks, "the first scenario tick");
    let handover = ms(settle_end, first.header.stamp_ns);
    let slowest = records
        .truth
        .windows(2)
        .map(|w| ms(w[0].header.stamp_ns, w[1].header.stamp_ns))
        .fold(0.0, f64::max);
    let period_ms = 1e3 / plan.scenario.control_hz;
    println!("hand-over {handover:.2} ms; slowest scenario tick {slowest:.2} ms; period {period_ms:.2} ms; safe-mode entries {:?}", records.agent_safe_mode);
    assert!(handover <= slowest.max(2.0 * period_ms), "the hand-over took {handover:.2} ms (period {period_ms:.2} ms, slowest tick {slowest:.2} ms)");
}

/// A real-time run with no settle: the first tick waits for every robot's torques (the team's
/// start-up work is not simulated time with the drives off), then the pacing starts. At S4's
/// own 1 kHz every robot's first tick is in time, and the robots never stood undriven: a bridge
/// that paced the first tick too stepped it with no torque (every robot missed it: the team's
/// first tick takes longer than a 1 ms period).
#[test]
fn a_real_time_run_without_a_settle_waits_for_its_first_torques() {
    let _one = serial();
    let s = Scenario::load(
        common::scenario::repo().join("scenarios/s4_object_circle.toml"),
        &["duration=1.0".into(), "settle=0".into(), "control_hz=1000".into()],
    )
    .expect("scenario");
    let mut plan = plan::plan(&s, &common::scenario::repo()).expect("plan");
    plan.scene.realtime = true;
    let Some((records, m)) = run_here(&plan, false, "embedded, real time", "realtime_no_settle")
    else {
        return;
    };
    let first = records.truth.first().expect("ticks");
    assert_eq!(first.header.tick, 0);
    for t in &first.loop_timing {
        assert!(
            t.latency_us.is_some(),
            "{}: the first tick's torques came in its window: {t:?}",
            t.robot
        );
        assert_eq!(
            t.applied_tick,
            Some(0),
            "{}: the first tick stepped with its own torques",
            t.robot
        );
    }
    assert_eq!(first.loop_timing.len(), plan.robots.len(), "every robot's loop measured");
    assert!(!m.drop.dropped, "the object is held");
    assert_eq!(records.released_at, None, "never let go");
    assert_loop_consistent(&plan, &records, m.loop_timing.as_ref().expect("loop report"));
}

/// S4 at its own length, loaded as `team run --realtime` loads it: the real-time defaults
/// (`scenario::pace`), paced by the wall clock.
fn s4_at_the_defaults() -> Plan {
    let repo = common::scenario::repo();
    let file = repo.join("scenarios/s4_object_circle.toml");
    let s = Scenario::load_paced(file, &[], Pacing::Realtime).expect("scenario");
    assert_eq!((s.duration, s.settle), (10.0, 1.0), "the scenario's own length");
    assert_eq!(
        (s.control_hz, s.team_hz, s.drive_gains, s.team_delay_ticks),
        (scenario::pace::TEAM_HZ, None, DriveGainsMode::Inertia, TeamDelay::AUTO),
        "the real-time defaults"
    );
    let mut plan = plan::plan(&s, &repo).expect("plan");
    plan.scene.realtime = true;
    plan
}

/// Every physics step of every robot had a valid drive command (none past its `valid_until`,
/// no drives lost).
fn assert_no_drive_gaps(m: &Metrics) {
    for (r, l) in &m.loop_timing.as_ref().expect("a real-time run reports its loop").robots {
        assert_eq!(l.drive_gaps, 0, "{r}: drive steps without a valid command");
    }
}

/// A full-length real-time run held the object from its start to its end: every check, never
/// released, the loop consistent and at most `missed` of the ticks missed, the hand-over
/// without a gap. A run's length used to decide its start: the first window of references grew with it
/// (2 750 at 250 Hz for 10 s), its decoding landed in the first tick, and past the agents' 25 ms
/// deadline they went to safe mode holding no load: the object fell in the settle.
fn assert_held_from_start_to_end(plan: &Plan, records: &Records, m: &Metrics, missed: f64) {
    for c in &m.checks {
        assert!(c.passed, "{} = {} not below {}", c.name, c.value, c.bound);
    }
    assert_eq!(records.released_at, None, "never let go");
    assert!(!m.drop.dropped, "the object is held");
    let report = m.loop_timing.as_ref().expect("a real-time run reports its loop");
    assert_loop_consistent(plan, records, report);
    for (r, l) in &report.robots {
        assert!(
            l.deadline_misses as f64 <= missed * l.ticks as f64,
            "{r}: {} of {} ticks missed",
            l.deadline_misses,
            l.ticks
        );
    }
    assert!(
        records.run_wall.as_secs_f64() > 9.5,
        "paced by the wall clock: {:?}",
        records.run_wall
    );
    assert_handover_without_gap(plan, records);
}

/// S4 embedded at its own length and the real-time defaults, recorded as `team run
/// --realtime` records it: held from start to end, every check, no drive step without a valid
/// command.
#[test]
fn s4_at_its_full_length_holds_in_real_time_at_the_defaults_recorded() {
    let _one = serial();
    let plan = s4_at_the_defaults();
    let dir = common::scenario::repo().join("target/test-reports/realtime_s4_full");
    std::fs::create_dir_all(&dir).expect("report dir");
    let path = common::scenario::repo().join("scenarios/s4_object_circle.toml");
    let rec = RecordOptions {
        path: dir.join("run.mcap"),
        scenario: ScenarioSource::read(&path, &[], Pacing::Realtime).expect("scenario file"),
        live: None,
        split: None,
    };
    let test = "realtime::s4_at_its_full_length_holds_in_real_time_at_the_defaults_recorded";
    let Some((records, summary)) = common::machine::on_its_processors(test, || {
        run::run_recorded(
            &plan,
            &RunOptions { distributed: false, hosts: false, progress: false, loss: Vec::new() },
            &dir,
            Some(&rec),
        )
        .expect("the run completes")
    }) else {
        return;
    };
    let summary = summary.expect("recorded");
    assert_eq!(
        (summary.dropped, summary.error.as_deref()),
        (0, None),
        "the recording is complete: {summary:?}"
    );
    let m = evaluated(&plan, &records, "embedded, real time", "realtime_s4_full");
    assert_held_from_start_to_end(&plan, &records, &m, 0.05);
    assert_no_drive_gaps(&m);
    // The recording reads back as the run it was: loaded at the same pace, the same plan.
    let (replayed, _, _) = launch::record::replay::evaluate_recording(
        &dir.join("run.mcap"),
        &common::scenario::repo(),
    )
    .expect("replay");
    assert_eq!(replayed.scenario.control_hz, plan.scenario.control_hz, "replayed at its pace");
}

/// S4 as separate processes on loopback at its own length and the real-time defaults: held
/// from start to end, every check, no drive step without a valid command.
#[test]
fn s4_at_its_full_length_holds_in_real_time_at_the_defaults_distributed() {
    let _one = serial();
    let plan = s4_at_the_defaults();
    let Some((records, m)) =
        run_here(&plan, true, "distributed, real time", "realtime_s4_full_distributed")
    else {
        return;
    };
    assert_held_from_start_to_end(&plan, &records, &m, 0.05);
    assert_no_drive_gaps(&m);
}

/// S4 with every component on its own test host (five namespaces) at its own length and the
/// real-time defaults: held from start to end, every check, no drive gap. Where test hosts
/// cannot be made, it fails, or skips with `TEAM_TESTS_SKIP_HOSTS=1` (`common::hosts`).
#[test]
fn s4_at_its_full_length_holds_in_real_time_at_the_defaults_across_hosts() {
    let _one = serial();
    let plan = s4_at_the_defaults();
    let ids: Vec<String> = plan.robots.iter().map(|r| r.id.clone()).collect();
    let test = "realtime::s4_at_its_full_length_holds_in_real_time_at_the_defaults_across_hosts";
    let Some(hosts) = common::hosts::hosts_or_skip(&ids, test) else {
        return;
    };
    let Some(records) = run_across_hosts(&plan, hosts, "realtime_s4_full_hosts") else {
        return;
    };
    let m = evaluated(&plan, &records, "hosts, real time", "realtime_s4_full_hosts");
    assert_held_from_start_to_end(&plan, &records, &m, 0.05);
    assert_no_drive_gaps(&m);
}

/// S4 embedded at its own length and its own 1 kHz, with the team's command applied two ticks
/// after its state (`team_delay_ticks = 2`): the team has two robot periods to answer, and the
/// object is held from start to end. Across processes the same run holds where the single
/// 1 kHz loop drops the object (docs/results.md).
#[test]
fn s4_at_its_full_length_holds_in_real_time_at_1khz_with_the_team_two_ticks_behind() {
    let _one = serial();
    let repo = common::scenario::repo();
    let s = Scenario::load(
        repo.join("scenarios/s4_object_circle.toml"),
        &["team_delay_ticks=2".to_string()],
    )
    .expect("scenario");
    assert_eq!((s.control_hz, s.duration), (1000.0, 10.0), "the scenario's own rate and length");
    let mut plan = plan::plan(&s, &repo).expect("plan");
    plan.scene.realtime = true;
    let Some((records, m)) =
        run_here(&plan, false, "embedded, real time", "realtime_s4_1khz_delay")
    else {
        return;
    };
    assert_eq!(m.team_delay_ticks, 2, "the report names the delay");
    // 248 and 602 of 10000 missed beside two busy loops, 7 idle.
    assert_held_from_start_to_end(&plan, &records, &m, 0.1);
}

/// Every component on its own test host, 5 % of robot r1's packets dropped (nftables), 125 Hz:
/// the object is still held and the loss shows in r1's loop. Where test hosts cannot be made,
/// it fails, or skips with `TEAM_TESTS_SKIP_HOSTS=1` (`common::hosts`). 125 Hz, not 250: five processes
/// on two cores put state-to-torque at 2.2 ms p50 and 4 ms p99 on this machine, and at 250 Hz
/// about half the ticks were missed and one run in two let go, with or without the reuse of
/// late terms (`7c3c421` too).
#[test]
fn s4_holds_in_real_time_across_hosts_with_five_percent_loss_on_one_link() {
    let _one = serial();
    let plan = s4_realtime(125.0, 3.0);
    let ids: Vec<String> = plan.robots.iter().map(|r| r.id.clone()).collect();
    let Some(hosts) = common::hosts::hosts_or_skip(
        &ids,
        "realtime::s4_holds_in_real_time_across_hosts_with_five_percent_loss_on_one_link",
    ) else {
        return;
    };
    hosts.set_loss("r1", 5).expect("loss rule");
    let Some(records) = run_across_hosts(&plan, hosts.clone(), "realtime_hosts_loss") else {
        return;
    };
    let m = evaluated(&plan, &records, "hosts, real time", "realtime_hosts_loss");
    // Held, not tracked to the millimetre: the drives hold their last torques through the
    // gaps, so the tracking bounds of a clean run are not asked.
    assert!(!m.drop.dropped, "the object is held");
    for (r, slip) in &m.slip_m {
        assert!(*slip < evaluate::MAX_SLIP, "palm {r} slipped {slip} m");
    }
    assert!(
        m.object.position_max_m < HELD_OBJECT_MAX_M,
        "object error up to {} m",
        m.object.position_max_m
    );
    for (r, t) in &m.torsos {
        assert!(t.position_max_m < STANDING_TORSO_MAX_M, "torso {r} moved {} m", t.position_max_m);
    }
    let report = m.loop_timing.as_ref().expect("loop report");
    assert_loop_consistent(&plan, &records, report);
    let dropped = hosts.dropped("r1").expect("counter");
    println!("r1's host dropped {dropped} packets");
    assert!(dropped > 10, "the loss rule dropped packets: {dropped}");
    assert!(report.robots["r1"].deadline_misses > 0, "the loss shows in r1's loop");
}

/// "Held" under a fault: no palm slips more than this, m (the acceptance bound is 5 mm: a run
/// whose infeasible tick Clarabel takes ~50 ms to prove holds stale torques meanwhile).
const HELD_SLIP_M: f64 = 0.01;
/// "Held" under loss: the object within this of its reference throughout, m.
const HELD_OBJECT_MAX_M: f64 = 0.05;
/// "Standing" under loss: each torso within this of its reference throughout, m.
const STANDING_TORSO_MAX_M: f64 = 0.08;

/// An agent alive but silent (fault `agent-stalls`: its task handles nothing while its
/// liveliness token holds), three robots at 125 Hz against the wall clock (the three-robot
/// tick, 1.6-1.9 ms at p50 on this machine, leaves 250 Hz no room: half the ticks were missed
/// and the team let go, fault or not). The coordinator notices at once: the tick it misses is
/// solved with the robot's latest terms and the status names it stale; its drives hold its last
/// torques, then freeze at their timeout (50 ms). A stall of 0.12 s stays under the 200 ms after
/// which the coordinator leaves a member out (`REALTIME_SILENCE`): the team rides it through,
/// the object held, and the robot is commanded again from its first fresh terms.
#[test]
fn a_stalled_agent_is_noticed_at_once_and_the_team_rides_it_through() {
    let _one = serial();
    let plan = team3_realtime(&[
        "duration=2.0",
        "settle=0.5",
        "control_hz=125",
        "drive_loss=\"freeze\"",
        "faults=[{kind=\"agent-stalls\",robot=\"r3\",at=0.5,duration=0.12}]",
    ]);
    let Some((records, m)) = run_here(&plan, false, "embedded, real time", "realtime_stall") else {
        return;
    };
    let clock = &plan.references.clock;
    let (struck, over) = (clock.first_tick_at(0.5), clock.first_tick_at(0.62));
    let r3 = "r3".to_string();
    let stale: Vec<u64> = records
        .statuses
        .iter()
        .filter(|st| st.stale.contains(&r3))
        .map(|st| st.header.tick)
        .collect();
    // A loaded machine can make r3 late for a tick before the stall too (stale at tick 119 of a
    // stall at 125): the stall is noticed by the first stale status from its tick on.
    let before: Vec<&u64> = stale.iter().filter(|t| **t < struck).collect();
    if !before.is_empty() {
        println!("r3 stale before its stall (a late tick) at {before:?}");
    }
    let first = *stale
        .iter()
        .find(|t| **t >= struck)
        .expect("a status naming r3 stale after the stall began");
    let cleared = records
        .statuses
        .iter()
        .find(|st| st.header.tick > first && !st.stale.contains(&r3))
        .map(|st| st.header.tick)
        .expect("r3 fresh again");
    println!("r3 stalled at tick {struck} for 0.12 s (to {over}): stale from {first}, fresh again from {cleared}");
    assert!(first >= struck && first <= struck + 3, "noticed within 3 ticks: {first}");
    assert!(
        cleared >= over && cleared <= over + 10,
        "fresh terms once the stall was over: {cleared}"
    );
    assert!(
        records.statuses.iter().all(|st| st.silent.is_empty()),
        "never left out: the stall is shorter than the silence"
    );
    // The others keep their loop: the bridge waits the whole period for r3's torques and steps
    // late, and the next tick still gives them three quarters of a period (MIN_WINDOW).
    // Catching up at once made r1 and r2 miss 9-12 of the stall's 15 ticks; now 0-1 (0-3 with
    // two busy loops beside the test).
    for r in ["r1", "r2"] {
        let missed = records
            .truth
            .iter()
            .filter(|g| (struck..over).contains(&g.header.tick))
            .flat_map(|g| &g.loop_timing)
            .filter(|t| t.robot == r && t.latency_us.is_none())
            .count();
        assert!(
            missed as u64 * 3 <= over - struck,
            "{r} missed {missed} of the stall's {} ticks",
            over - struck
        );
    }
    let last = records.last_status.as_ref().expect("status");
    assert!(
        last.reused_terms >= (over - struck) / 2,
        "its terms were reused while it stalled: {last:?}"
    );
    let solved_with_r3 = records
        .diagnostics
        .iter()
        .filter(|d| d.header.tick > over + 10)
        .all(|d| d.contacts.iter().any(|c| c.robot == r3 && c.wrench.len() == 6));
    assert!(solved_with_r3, "r3's hand stays in the grasp");
    assert!(!m.drop.dropped, "the object is held");
    for r in ["r1", "r2", "r3"] {
        assert!(m.slip_m[r] < HELD_SLIP_M, "palm {r} slipped {} m", m.slip_m[r]);
        assert!(
            m.torsos[r].position_max_m < 0.02,
            "torso {r} moved {} m",
            m.torsos[r].position_max_m
        );
    }
    assert!(
        m.object.position_max_m < HELD_OBJECT_MAX_M,
        "object error up to {} m",
        m.object.position_max_m
    );
}

/// Real time, separate processes: r3's agent killed (SIGKILL, so its token vanishes with no word
/// from it, as when a link drops). The coordinator first waits for the token to come back
/// (`DEPARTURE_GRACE`, 100 ms), reusing r3's terms; once they are `DEPARTURE_TICKS` (3) old,
/// r3 has left: noticed within 3 ticks of the kill, not at the end of the grace. r1 and r2
/// keep the object.
#[test]
fn an_agent_killed_in_real_time_is_noticed_within_three_ticks_and_the_others_hold() {
    use coordinator::team::membership::DEPARTURE_TICKS;
    let _one = serial();
    let plan = team3_realtime(&[
        "duration=1.5",
        "settle=0.5",
        "control_hz=125",
        "drive_loss=\"freeze\"",
        "faults=[{kind=\"agent-stops\",robot=\"r3\",at=0.5}]",
    ]);
    let Some((records, m)) = run_here(&plan, true, "distributed, real time", "realtime_kill")
    else {
        return;
    };
    let struck = plan.references.clock.first_tick_at(0.5);
    let r3 = "r3".to_string();
    let out = records
        .statuses
        .iter()
        .filter(|st| st.header.tick + 1 >= struck)
        .find(|st| !st.members.contains(&r3))
        .map(|st| st.header.tick)
        .expect("a status without r3");
    println!("r3's agent killed at tick {struck}: no member from the status of tick {out}");
    assert!(
        out <= struck + DEPARTURE_TICKS,
        "noticed within {DEPARTURE_TICKS} ticks: at {out}, killed at {struck}"
    );
    assert!(
        records
            .statuses
            .iter()
            .filter(|st| st.header.tick > out)
            .all(|st| !st.members.contains(&r3)),
        "r3 stays out"
    );
    assert_eq!(records.released_at, None, "r1 and r2 keep the object");
    assert!(!m.drop.dropped, "the object is held");
    for r in ["r1", "r2"] {
        assert!(m.slip_m[r] < HELD_SLIP_M, "palm {r} slipped {} m", m.slip_m[r]);
    }
    assert!(
        m.object.position_max_m < HELD_OBJECT_MAX_M,
        "object error up to {} m",
        m.object.position_max_m
    );
}

/// S4 with its 1 kg cube pushed down by 300 N for 0.6 s from 0.5 s into the circle (more than
/// the grasp's friction carries, as in `degrade.rs` in lockstep), against the wall clock at the
/// real-time defaults: the team lets go, the report names the release's tick and cause, and 5 s
/// after the push every robot stands (torsos within 5 cm and 10 deg of their holds), its drives
/// never without a valid command. The ticks the QP cannot solve answer within the
/// coordinator's solve budget (`realtime_solve_budget`): solved to their end (the yield,
/// Clarabel's certificate, the QP again on saturated torques) they took 7-18 ms of a 4 ms
/// period, the robots went without commands while the hands slid, and both stood in only 1-9
/// runs of 10.
#[test]
fn a_push_the_team_cannot_hold_in_real_time_is_let_go_and_every_robot_stands() {
    let _one = serial();
    pushed_off_in_real_time(false, "embedded, real time", "realtime_push_release");
}

/// The same push with every component its own process: the team lets go and every robot
/// stands. Each robot's drives follow the accelerations its last command's torques give
/// (`protocol::TorqueCommand::qdd`); while they carried the acceleration measured between the
/// last two states instead, that acceleration fed back on itself through the drives' gains
/// past the late commands, the robots' own blocks turned infeasible after the release, and
/// both stood in only 6 runs of 11.
#[test]
fn a_push_the_team_cannot_hold_is_let_go_across_processes_and_every_robot_stands() {
    let _one = serial();
    let name = "realtime_push_release_distributed";
    pushed_off_in_real_time(true, "distributed, real time", name);
}

/// S4 pushed beyond its grasp (`common::push`), running on 5 s after the push, at the
/// real-time defaults against the wall clock, embedded or as processes: released and named,
/// both robots standing, no drive gap.
fn pushed_off_in_real_time(distributed: bool, mode: &str, name: &str) {
    let (file, text) = common::push::s4_pushed_off();
    let sets: Vec<String> = ["duration=6.1", "settle=0.3"].map(String::from).to_vec();
    let s = Scenario::from_str_paced(&text, &file, &sets, Pacing::Realtime).expect("scenario");
    let mut plan = plan::plan(&s, &common::scenario::repo()).expect("plan");
    plan.scene.realtime = true;
    let Some((_, m)) = run_here(&plan, distributed, mode, name) else {
        return;
    };
    common::push::assert_release_named(&m);
    common::push::assert_team_standing(&m, 2);
    assert_no_drive_gaps(&m);
}
