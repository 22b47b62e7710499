//! Tick and clock ownership: who numbers ticks, and what settling does to time.
//!
//! * **The state source numbers ticks.** Tick `k` is the `k`-th state the state source (the
//!   sim-bridge's lockstep or real-time loop, or a robot's hardware driver) publishes,
//!   counting from 0. Every other component takes the tick from the message it answers:
//!   `dynamics(k)` answers `state(k)`, `command(k)` answers `dynamics(k)`, `torque(k)` answers
//!   `command(k)`. Nobody else invents tick numbers.
//! * **Settling keeps counting.** A run that first settles the team under the controller for
//!   `settle_ticks` ticks continues its tick numbers into the scenario (agents refuse ticks
//!   older than the last they applied, so numbers never restart).
//! * **The scenario clock starts after settling.** Scenario time is
//!   `t(k) = (k - settle_ticks) / control_hz` from the first tick after settling; while
//!   settling there is no scenario time (references hold the start pose). The simulator's
//!   physics time restarts at 0 at the same tick, so timed pushes (on the scenario clock) and
//!   references agree.
//!
//! [`RunClock`] is that rule as a value: the scene (sim-bridge) and the reference plan
//! (runner) both read time through it.

use serde::{Deserialize, Serialize};

/// The ticks of one run: `settle_ticks` of settling, then `ticks` of scenario, at `control_hz`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RunClock {
    pub control_hz: f64,
    pub settle_ticks: u64,
    pub ticks: u64,
}

impl RunClock {
    /// Ticks of the whole run, settling included.
    pub fn total_ticks(&self) -> u64 {
        self.settle_ticks + self.ticks
    }

    /// Whether tick `k` belongs to the settling phase.
    pub fn is_settling(&self, tick: u64) -> bool {
        tick < self.settle_ticks
    }

    /// Scenario time of tick `k`'s state, s (`None` while settling).
    pub fn scenario_time(&self, tick: u64) -> Option<f64> {
        (tick >= self.settle_ticks).then(|| (tick - self.settle_ticks) as f64 / self.control_hz)
    }

    /// The first tick whose scenario time is at or after `t` (s; before 0: the first scenario
    /// tick).
    pub fn first_tick_at(&self, t: f64) -> u64 {
        self.settle_ticks + (t * self.control_hz - 1e-9).ceil().max(0.0) as u64
    }

    /// Control period, s.
    pub fn dt(&self) -> f64 {
        1.0 / self.control_hz
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scenario_time_starts_after_settling_and_ticks_keep_counting() {
        let c = RunClock { control_hz: 1000.0, settle_ticks: 500, ticks: 2000 };
        assert_eq!(c.total_ticks(), 2500);
        assert!(c.is_settling(499) && !c.is_settling(500));
        for k in [500, 501, 1234, 2499] {
            let t = c.scenario_time(k).unwrap();
            assert_eq!(c.first_tick_at(t), k, "tick {k} at its own time");
            assert_eq!(c.first_tick_at(t + 0.5e-3), k + 1, "half a period later: the next tick");
        }
        assert_eq!(c.first_tick_at(-1.0), 500);
        assert_eq!(c.scenario_time(0), None);
        assert_eq!(c.scenario_time(499), None);
        assert_eq!(c.scenario_time(500), Some(0.0));
        assert_eq!(c.scenario_time(1500), Some(1.0));
        let none = RunClock { control_hz: 2000.0, settle_ticks: 0, ticks: 10 };
        assert_eq!(none.scenario_time(0), Some(0.0));
        assert_eq!(none.scenario_time(3), Some(3.0 / 2000.0));
    }
}
