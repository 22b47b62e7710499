//! The control loop of a real-time run, from the ground truth's [`protocol::LoopTiming`]
//! (measured where the torques are applied, so on one clock): per robot, state-to-torque
//! latency percentiles, deadline misses (ticks on which the drive held its last torques), the
//! longest run of such ticks, late arrivals and lost commands. Lockstep runs carry no loop
//! timing and get no report.

use std::collections::{BTreeMap, BTreeSet};

use protocol::GroundTruth;
use serde::Serialize;

use crate::metrics::{Percentiles, Quantiles};

/// One robot's loop over a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RobotLoop {
    /// Ticks with a measurement.
    pub ticks: u64,
    /// State-to-torque latency of the ticks whose torques came in time, µs.
    pub latency_us: Percentiles,
    /// Ticks whose torques were not there by the tick's deadline: the drive held the last
    /// torques it had (or none yet).
    pub deadline_misses: u64,
    /// Longest run of consecutive missed ticks (a robot's agent enters safe mode after
    /// `robot_agent::safe_mode::CommandDeadline::ticks` of them).
    pub longest_hold_ticks: u64,
    /// Torques that arrived after their tick's deadline.
    pub late: u64,
    /// Ticks whose torques were never applied, on time or late.
    pub lost: u64,
    /// Physics steps on which the drives had no valid command (drive gaps).
    pub drive_gaps: u64,
}

/// Ticks of one robot not yet applied are looked for this many ticks back; older ones are
/// lost.
const LOST_AFTER: u64 = 4096;

/// One robot's loop as the ticks come.
#[derive(Debug, Clone, Default)]
struct Acc {
    ticks: u64,
    latencies: Quantiles,
    misses: u64,
    streak: u64,
    longest: u64,
    late: u64,
    gaps: u64,
    /// Ticks seen whose torques were not applied yet, and ticks applied ahead of being seen.
    unapplied: BTreeSet<u64>,
    applied_ahead: BTreeSet<u64>,
    lost: u64,
}

impl Acc {
    /// The robot's timing `t` on `tick`.
    fn add(&mut self, tick: u64, t: &protocol::LoopTiming) {
        self.ticks += 1;
        self.late += u64::from(t.late);
        self.gaps += u64::from(t.gap_steps);
        if !self.applied_ahead.remove(&tick) {
            self.unapplied.insert(tick);
        }
        if let Some(k) = t.applied_tick {
            if !self.unapplied.remove(&k) && k > tick {
                self.applied_ahead.insert(k);
            }
        }
        while self.unapplied.first().is_some_and(|k| k + LOST_AFTER < tick) {
            self.unapplied.pop_first();
            self.lost += 1;
        }
        match t.latency_us {
            Some(l) => {
                self.latencies.add(l);
                self.streak = 0;
            }
            None => {
                self.misses += 1;
                self.streak += 1;
                self.longest = self.longest.max(self.streak);
            }
        }
    }

    fn to_loop(&self) -> RobotLoop {
        RobotLoop {
            ticks: self.ticks,
            latency_us: self.latencies.percentiles(),
            deadline_misses: self.misses,
            longest_hold_ticks: self.longest,
            late: self.late,
            lost: self.lost + self.unapplied.len() as u64,
            drive_gaps: self.gaps,
        }
    }
}

/// The loop timing of a run taken tick by tick, in bounded memory: the lost ticks are those
/// not applied within [`LOST_AFTER`] ticks, and the latencies' percentiles come from a
/// [`Quantiles`].
#[derive(Debug, Clone, Default)]
pub struct LoopTally {
    robots: BTreeMap<String, Acc>,
}

impl LoopTally {
    /// One tick's ground truth.
    pub fn add(&mut self, g: &GroundTruth) {
        for t in &g.loop_timing {
            match self.robots.get_mut(&t.robot) {
                Some(a) => a.add(g.header.tick, t),
                None => self.robots.entry(t.robot.clone()).or_default().add(g.header.tick, t),
            }
        }
    }

    /// The report (`None` if no tick carried loop timing: a lockstep run).
    pub fn report(&self) -> Option<LoopReport> {
        if self.robots.is_empty() {
            return None;
        }
        let robots = self.robots.iter().map(|(r, a)| (r.clone(), a.to_loop())).collect();
        Some(LoopReport { robots })
    }
}

/// The loop of a real-time run, by robot.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LoopReport {
    pub robots: BTreeMap<String, RobotLoop>,
}

impl LoopReport {
    /// The report of the ticks in `truth` that carry loop timing (`None` if none does).
    pub fn from_truth(truth: &[GroundTruth]) -> Option<LoopReport> {
        let mut tally = LoopTally::default();
        truth.iter().for_each(|g| tally.add(g));
        tally.report()
    }

    /// One line per robot for the run's summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        for (r, l) in &self.robots {
            s.push_str(&format!(
                "  loop {r}: state-to-torque p50 {:.0} us, p99 {:.0} us, max {:.0} us; \
                 deadline misses {} of {} (longest hold {} ticks), late {}, lost {}; \
                 drive gaps {} steps\n",
                l.latency_us.p50,
                l.latency_us.p99,
                l.latency_us.max,
                l.deadline_misses,
                l.ticks,
                l.longest_hold_ticks,
                l.late,
                l.lost,
                l.drive_gaps
            ));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Header, LoopTiming};

    fn tick(k: u64, r1: (Option<f64>, Option<u64>, u32)) -> GroundTruth {
        let mut g = sim_bridge::ground_truth::empty("t");
        g.header = Header::new("t", None, k, 0);
        g.loop_timing = vec![
            LoopTiming {
                robot: "r1".into(),
                latency_us: r1.0,
                applied_tick: r1.1,
                late: r1.2,
                gap_steps: 0,
            },
            LoopTiming {
                robot: "r2".into(),
                latency_us: Some(100.0 + k as f64),
                applied_tick: Some(k),
                late: 0,
                gap_steps: 2,
            },
        ];
        g
    }

    #[test]
    fn misses_streaks_late_and_lost_are_counted_per_robot() {
        // r1: tick 10 on time; 11 and 12 missed (11's torques arrive late during 12, 12's never);
        // 13 on time; 14 missed with nothing newer; 15 on time.
        let truth = vec![
            tick(10, (Some(300.0), Some(10), 0)),
            tick(11, (None, Some(10), 0)),
            tick(12, (None, Some(11), 1)),
            tick(13, (Some(500.0), Some(13), 0)),
            tick(14, (None, Some(13), 0)),
            tick(15, (Some(400.0), Some(15), 0)),
        ];
        let rep = LoopReport::from_truth(&truth).expect("timing present");
        let r1 = &rep.robots["r1"];
        assert_eq!((r1.ticks, r1.deadline_misses, r1.longest_hold_ticks, r1.late), (6, 3, 2, 1));
        // Ticks 12 and 14 never applied.
        assert_eq!(r1.lost, 2);
        assert_eq!((r1.latency_us.count, r1.latency_us.p50, r1.latency_us.max), (3, 400.0, 500.0));
        let r2 = &rep.robots["r2"];
        assert_eq!((r2.deadline_misses, r2.longest_hold_ticks, r2.late, r2.lost), (0, 0, 0, 0));
        assert_eq!((r1.drive_gaps, r2.drive_gaps), (0, 12), "drive gaps summed over the ticks");
        assert_eq!(r2.latency_us.max, 115.0);
        assert!(rep.summary().contains("loop r1: state-to-torque p50 400 us"), "{}", rep.summary());
    }

    #[test]
    fn a_lockstep_run_has_no_loop_report() {
        let mut g = sim_bridge::ground_truth::empty("t");
        g.header = Header::new("t", None, 3, 0);
        assert!(LoopReport::from_truth(&[g.clone(), g]).is_none());
    }
}
