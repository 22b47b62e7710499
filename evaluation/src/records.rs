//! The records of a run: what the driver heard during the scenario's ticks (ground truth,
//! applied torques, the coordinator's diagnostics and statuses, the agents' statuses), which
//! every evaluation reads.
//!
//! Every message goes into the run's [`Tally`], which measures the run as it goes in bounded
//! memory. The messages themselves are kept as a trace for the figures and for a walk's
//! evaluation: all of them up to [`TRACE_ROBOT_SAMPLES`] (robot samples: ticks times robots),
//! then every second tick, then every fourth, and so on, so that a run of any length keeps
//! between half that and that, evenly spread. A walking scenario keeps its whole trace (its
//! evaluation follows each foot tick by tick, and its plan bounds its length).

use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

use protocol::{AgentStatus, CoordinatorStatus, DriveCommand, GroundTruth, TickDiagnostics};

use crate::tally::{Tally, RECENT_TICKS};
use scenario::Plan;

/// Ticks times robots the trace holds before it thins (about 100 MB of ground truth for two
/// robots).
pub const TRACE_ROBOT_SAMPLES: usize = 1 << 16;

/// Statuses kept before a change of the stale members alone stops counting as a change (a
/// lossy link's stale members change every few ticks).
pub const STALE_STATUSES: usize = 1 << 14;

/// What a run recorded (scenario ticks only; settling is not evaluated).
#[derive(Debug, Clone)]
pub struct Records {
    /// The trace: ground truth, applied torques per robot (tick, torques in actuated-joint
    /// order; a drive command's `tau_ff`) and diagnostics of every `stride`-th tick.
    pub truth: Vec<GroundTruth>,
    pub torques: BTreeMap<String, Vec<(u64, Vec<f64>)>>,
    pub diagnostics: Vec<TickDiagnostics>,
    /// The trace keeps the ticks that are multiples of this (1 until it first thinned).
    pub stride: u64,
    /// Samples the trace holds at most.
    trace_cap: usize,
    /// Per robot, how many drive commands carried gains (`drive_gains`).
    pub with_gains: BTreeMap<String, u64>,
    pub last_status: Option<CoordinatorStatus>,
    /// The coordinator's statuses that changed what it says of the team (its mode, members,
    /// stale, silent or late robots, detail or last refusal), and the last one heard: it sends
    /// one every tick it solves, and those between are the same but for their counters. Past
    /// [`STALE_STATUSES`] kept, a change of the stale members alone is no longer kept.
    pub statuses: Vec<CoordinatorStatus>,
    /// Whether the last of `statuses` repeats the one before it (and is replaced by the next
    /// repeat).
    status_repeats: bool,
    /// The status tick at which the coordinator first reported the team let go of the object.
    pub released_at: Option<u64>,
    /// Wall time of the settling and of the scenario proper.
    pub settle_wall: Duration,
    pub run_wall: Duration,
    /// The machine's processors over the scenario proper (`None` where they cannot be read).
    pub machine: Option<crate::machine::MachineLoad>,
    /// Ticks seen (ground truth), settling included.
    pub ticks_seen: u64,
    /// The bridge's wall-clock stamp of the last settling tick's ground truth: the hand-over
    /// to the scenario is measured from it to the first scenario tick's.
    pub settle_end_stamp_ns: Option<u64>,
    /// Per robot, the most safe-mode entries its agent's statuses reported (robots whose agent
    /// was not heard are absent).
    pub agent_safe_mode: BTreeMap<String, u64>,
    /// Per robot, the longest team delay its agent's statuses reported, state ticks (with
    /// `team_delay_ticks = "auto"` the delay each agent came to).
    pub agent_delay: BTreeMap<String, u64>,
    /// The run measured so far.
    pub tally: Tally,
    /// The last ticks' robots whose torques the bridge applied in time (real time).
    recent_applied: VecDeque<(u64, Vec<String>)>,
}

impl Records {
    /// Empty records of a run of `plan`.
    pub fn new(plan: &Plan) -> Records {
        let robots = plan.robots.len().max(1);
        let walks = plan.references.walk.is_some();
        Records {
            truth: Vec::new(),
            torques: BTreeMap::new(),
            diagnostics: Vec::new(),
            stride: 1,
            trace_cap: if walks { usize::MAX } else { TRACE_ROBOT_SAMPLES / robots },
            with_gains: BTreeMap::new(),
            last_status: None,
            statuses: Vec::new(),
            status_repeats: false,
            released_at: None,
            settle_wall: Duration::ZERO,
            run_wall: Duration::ZERO,
            machine: None,
            ticks_seen: 0,
            settle_end_stamp_ns: None,
            agent_safe_mode: BTreeMap::new(),
            agent_delay: BTreeMap::new(),
            tally: Tally::new(plan),
            recent_applied: VecDeque::new(),
        }
    }

    /// Empty records of the same run.
    pub fn empty(&self) -> Records {
        Records::new(&self.tally.run.plan)
    }

    /// Whether the trace keeps `tick`.
    fn traced(&self, tick: u64) -> bool {
        tick.is_multiple_of(self.stride)
    }

    /// Keep a scenario tick's ground truth.
    pub fn keep_truth(&mut self, g: GroundTruth) {
        if !g.loop_timing.is_empty() {
            let applied = g.loop_timing.iter().filter(|t| t.latency_us.is_some());
            let robots = applied.map(|t| t.robot.clone()).collect();
            self.recent_applied.push_back((g.header.tick, robots));
            if self.recent_applied.len() as u64 > RECENT_TICKS {
                self.recent_applied.pop_front();
            }
        }
        if self.traced(g.header.tick) {
            self.truth.push(g.clone());
            if self.truth.len() > self.trace_cap {
                self.thin();
            }
        }
        self.tally.add_truth(g);
    }

    /// Keep every second tick of the trace from now on.
    fn thin(&mut self) {
        self.stride *= 2;
        let s = self.stride;
        self.truth.retain(|g| g.header.tick.is_multiple_of(s));
        self.diagnostics.retain(|d| d.header.tick.is_multiple_of(s));
        for v in self.torques.values_mut() {
            v.retain(|(t, _)| t.is_multiple_of(s));
        }
    }

    /// Keep a drive command of a scenario tick: its torque, and whether it carried gains.
    pub fn keep_drive(&mut self, cmd: &DriveCommand) {
        let robot = cmd.header.robot_id();
        if cmd.has_gains() {
            *self.with_gains.entry(robot.to_string()).or_default() += 1;
        }
        self.tally.add_drive(cmd);
        if self.traced(cmd.header.tick) {
            let v = self.torques.entry(robot.to_string()).or_default();
            v.push((cmd.header.tick, cmd.tau_ff.clone()));
        }
    }

    /// Keep a scenario tick's diagnostics.
    pub fn keep_diagnostics(&mut self, d: TickDiagnostics) {
        self.tally.add_diagnostics(&d);
        if self.traced(d.header.tick) {
            self.diagnostics.push(d);
        }
    }

    /// Keep a coordinator status; the first that reports the team let go halts the walk's
    /// references the run is measured against.
    pub fn keep_status(&mut self, status: CoordinatorStatus) {
        if status.mode == protocol::CoordinatorMode::Released && self.released_at.is_none() {
            self.released_at = Some(status.header.tick);
            self.tally.released(status.header.tick);
        }
        let with_stale = self.statuses.len() < STALE_STATUSES;
        let same = |a: &CoordinatorStatus| {
            says_the_same(a, &status) && (!with_stale || a.stale == status.stale)
        };
        match self.statuses.last_mut() {
            Some(last) if self.status_repeats && same(last) => *last = status.clone(),
            Some(last) if same(last) => {
                self.statuses.push(status.clone());
                self.status_repeats = true;
            }
            _ => {
                self.statuses.push(status.clone());
                self.status_repeats = false;
            }
        }
        self.last_status = Some(status);
    }

    /// Keep the safe-mode entries and the team delay of an agent's status.
    pub fn keep_agent_status(&mut self, st: &AgentStatus) {
        let n = self.agent_safe_mode.entry(st.header.robot_id().to_string()).or_default();
        *n = (*n).max(st.safe_mode_entries);
        let d = self.agent_delay.entry(st.header.robot_id().to_string()).or_default();
        *d = (*d).max(st.team_delay_ticks);
    }

    /// Whether robot `robot`'s command of `tick` was kept (among its last [`RECENT_TICKS`]).
    pub fn has_drive(&self, robot: &str, tick: u64) -> bool {
        let i = self.tally.run.robots.iter().position(|r| r == robot);
        i.is_some_and(|i| self.tally.torques.heard(i, tick))
    }

    /// (robot, tick) of the torques the bridge took that the records lack: from the loop
    /// timing of the last [`RECENT_TICKS`] in real time, or in lockstep the last tick of every
    /// robot that answered the tick before.
    pub fn owed_drives(&self) -> Vec<(String, u64)> {
        if self.recent_applied.is_empty() {
            let Some(tick) = self.ticks_seen.checked_sub(1) else { return Vec::new() };
            let robots = self.tally.run.robots.iter().enumerate();
            let owes = |i: usize| self.tally.torques.last_tick(i).is_some_and(|t| t + 1 == tick);
            return robots.filter(|(i, _)| owes(*i)).map(|(_, r)| (r.clone(), tick)).collect();
        }
        let applied =
            self.recent_applied.iter().flat_map(|(tick, rs)| rs.iter().map(move |r| (r, *tick)));
        applied.filter(|(r, t)| !self.has_drive(r, *t)).map(|(r, t)| (r.clone(), t)).collect()
    }
}

/// Whether two statuses say the same of the team: mode, members, silent and late robots,
/// detail and last refusal (not their counters, nor which terms were stale on their tick).
fn says_the_same(a: &CoordinatorStatus, b: &CoordinatorStatus) -> bool {
    a.mode == b.mode
        && a.members == b.members
        && a.silent == b.silent
        && a.late == b.late
        && a.detail == b.detail
        && a.last_refusal == b.last_refusal
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Header, LoopTiming};
    use std::path::Path;

    fn s4() -> Plan {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("root").to_path_buf();
        let sets = ["duration=1.0".to_string(), "settle=0.0".to_string()];
        let path = root.join("scenarios/s4_object_circle.toml");
        let s = scenario::file::Scenario::load(path, &sets).expect("S4");
        scenario::plan::plan(&s, &root).expect("plan")
    }

    fn truth(tick: u64, timing: &[(&str, bool)]) -> GroundTruth {
        let mut g = sim_bridge::ground_truth::empty("t");
        g.header = Header::new("t", None, tick, 0);
        g.loop_timing = timing
            .iter()
            .map(|(r, in_time)| LoopTiming {
                robot: r.to_string(),
                latency_us: in_time.then_some(900.0),
                applied_tick: Some(tick),
                late: 0,
                gap_steps: 0,
            })
            .collect();
        g
    }

    fn drive(robot: &str, tick: u64) -> DriveCommand {
        DriveCommand::torque("t", robot, tick, vec![0.0; 3])
    }

    /// A robot that missed the last tick still owes the tick before, which the bridge took.
    #[test]
    fn real_time_owes_every_applied_tick_not_only_the_last() {
        let mut rec = Records::new(&s4());
        rec.keep_truth(truth(10, &[("r1", true), ("r2", true)]));
        rec.keep_truth(truth(11, &[("r1", false), ("r2", true)]));
        for (r, t) in [("r1", 9), ("r2", 10), ("r2", 11)] {
            rec.keep_drive(&drive(r, t));
        }
        assert_eq!(rec.owed_drives(), vec![("r1".to_string(), 10)]);
        rec.keep_drive(&drive("r1", 10));
        assert!(rec.owed_drives().is_empty());
    }

    /// In lockstep the last tick is owed by every robot that answered the tick before.
    #[test]
    fn lockstep_owes_the_last_tick_of_who_answered_the_one_before() {
        let mut rec = Records::new(&s4());
        rec.keep_truth(truth(10, &[]));
        rec.keep_truth(truth(11, &[]));
        rec.ticks_seen = 12;
        for (r, t) in [("r1", 10), ("r2", 10), ("r2", 11)] {
            rec.keep_drive(&drive(r, t));
        }
        assert_eq!(rec.owed_drives(), vec![("r1".to_string(), 11)]);
    }

    /// Statuses that say nothing new replace each other: the changes and the last are kept.
    #[test]
    fn only_changed_statuses_and_the_last_are_kept() {
        let mut rec = Records::new(&s4());
        let status = |tick: u64, members: &[&str]| CoordinatorStatus {
            header: Header::new("t", None, tick, 0),
            mode: protocol::CoordinatorMode::Running,
            members: members.iter().map(|m| m.to_string()).collect(),
            ticks: tick,
            commands_sent: 0,
            deadline_misses: 0,
            fallbacks: 0,
            detail: String::new(),
            stale: vec![],
            silent: vec![],
            late: vec![],
            reused_terms: 0,
            refused: 0,
            last_refusal: None,
        };
        for k in 0..100 {
            rec.keep_status(status(k, if (40..60).contains(&k) { &["r1"] } else { &["r1", "r2"] }));
        }
        let mut stale = status(100, &["r1", "r2"]);
        stale.stale = vec!["r2".into()];
        rec.keep_status(stale);
        for k in 101..=103 {
            rec.keep_status(status(k, &["r1", "r2"]));
        }
        let ticks: Vec<u64> = rec.statuses.iter().map(|s| s.header.tick).collect();
        assert_eq!(ticks, vec![0, 39, 40, 59, 60, 99, 100, 101, 103]);
        assert_eq!(rec.last_status.map(|s| s.header.tick), Some(103));
    }

    /// Past its cap the trace keeps every second tick, then every fourth, of every channel.
    #[test]
    fn the_trace_thins_evenly_past_its_cap() {
        let plan = s4();
        let mut rec = Records::new(&plan);
        let cap = TRACE_ROBOT_SAMPLES / plan.robots.len();
        let ticks = 3 * cap as u64;
        for k in 0..ticks {
            rec.keep_truth(truth(k, &[]));
            rec.keep_drive(&drive("r1", k));
        }
        assert_eq!(rec.stride, 4);
        assert!(rec.truth.len() <= cap && rec.truth.len() as u64 == ticks / 4);
        assert!(rec.truth.iter().all(|g| g.header.tick % 4 == 0));
        assert_eq!(rec.torques["r1"].len(), rec.truth.len());
        assert!(rec.has_drive("r1", ticks - 1) && !rec.has_drive("r1", 0), "recent ticks only");
    }
}
