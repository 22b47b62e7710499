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
//! (runner) both read time through it, and every conversion between ticks and seconds is one
//! of its methods: lengths in seconds to ticks ([`RunClock::from_seconds`],
//! [`RunClock::ticks_in`], [`RunClock::ticks_lasting`]), ticks to scenario time
//! ([`RunClock::scenario_time`], [`RunClock::first_tick_at`]) or to time since the run's first
//! tick ([`RunClock::run_time`], [`RunClock::run_time_ns`]), and the sampling of a stream at a
//! lower rate ([`RunClock::ticks_per_sample`]).

use serde::{Deserialize, Serialize};

/// The ticks of one run: `settle_ticks` of settling, then `ticks` of scenario, at `control_hz`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RunClock {
    pub control_hz: f64,
    pub settle_ticks: u64,
    pub ticks: u64,
}

impl RunClock {
    /// The clock of a run that settles for `settle` s and then runs `duration` s of scenario
    /// at `control_hz`, each length rounded to the nearest tick ([`RunClock::ticks_in`]).
    pub fn from_seconds(control_hz: f64, settle: f64, duration: f64) -> RunClock {
        RunClock {
            control_hz,
            settle_ticks: Self::ticks_in(settle, control_hz),
            ticks: Self::ticks_in(duration, control_hz),
        }
    }

    /// The number of ticks nearest to `seconds` at `control_hz`: `round(seconds * control_hz)`
    /// (0 for a negative or NaN length).
    pub fn ticks_in(seconds: f64, control_hz: f64) -> u64 {
        (seconds * control_hz).round() as u64
    }

    /// The fewest ticks that last at least `seconds`: `ceil(seconds / dt)` (0 for a
    /// non-positive or NaN length).
    pub fn ticks_lasting(&self, seconds: f64) -> u64 {
        (seconds / self.dt()).ceil() as u64
    }

    /// Every how many ticks a stream of `rate_hz` samples takes one: `control_hz / rate_hz`
    /// rounded, at least 1 (every tick when the rate is at or above the control rate).
    pub fn ticks_per_sample(&self, rate_hz: f64) -> u64 {
        ((self.control_hz / rate_hz).round() as u64).max(1)
    }

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

    /// Time of tick `k`'s state since the run's first tick (settling included), s.
    pub fn run_time(&self, tick: u64) -> f64 {
        tick as f64 / self.control_hz
    }

    /// Time of tick `k`'s state since the run's first tick (settling included), whole ns
    /// (truncated; a recording's log time).
    pub fn run_time_ns(&self, tick: u64) -> u64 {
        (tick as f64 * 1e9 / self.control_hz) as u64
    }

    /// Length of the scenario (settling excluded), s.
    pub fn scenario_duration(&self) -> f64 {
        self.ticks as f64 / self.control_hz
    }

    /// Control period, s.
    pub fn dt(&self) -> f64 {
        1.0 / self.control_hz
    }

    /// Control period, us.
    pub fn dt_us(&self) -> f64 {
        1e6 / self.control_hz
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

    #[test]
    fn seconds_become_the_nearest_ticks() {
        let c = RunClock::from_seconds(2000.0, 1.0, 2.5);
        assert_eq!(c, RunClock { control_hz: 2000.0, settle_ticks: 2000, ticks: 5000 });
        assert_eq!(RunClock::ticks_in(0.0004, 1000.0), 0);
        assert_eq!(RunClock::ticks_in(0.0006, 1000.0), 1);
        assert_eq!(RunClock::ticks_in(0.0, 1000.0), 0);
        assert_eq!(RunClock::ticks_in(-1.0, 1000.0), 0, "a negative length: no ticks");
        // The same arithmetic as written out: round(seconds * control_hz).
        for (s, hz) in [(0.3, 125.0), (1.7, 2000.0), (2.0 / 3.0, 333.0), (1e-3, 1e3)] {
            assert_eq!(RunClock::ticks_in(s, hz), (s * hz).round() as u64, "{s} s at {hz} Hz");
        }
        assert_eq!(c.scenario_duration(), 2.5);
        assert_eq!(c.scenario_duration(), 5000.0 / 2000.0);
    }

    #[test]
    fn lengths_in_whole_ticks_and_sampling() {
        let c = RunClock { control_hz: 2000.0, settle_ticks: 0, ticks: 10 };
        assert_eq!(c.ticks_lasting(0.1), 200);
        assert_eq!(c.ticks_lasting(0.10001), 201, "a little longer: one more tick");
        assert_eq!(c.ticks_lasting(0.0), 0);
        assert_eq!(c.ticks_lasting(-1.0), 0);
        assert_eq!(c.ticks_lasting(0.1), (0.1_f64 / (1.0 / 2000.0)).ceil() as u64);
        assert_eq!(c.ticks_per_sample(25.0), 80);
        assert_eq!(c.ticks_per_sample(100.0), 20);
        assert_eq!(c.ticks_per_sample(3000.0), 1, "faster than the control rate: every tick");
        assert_eq!(RunClock { control_hz: 125.0, ..c }.ticks_per_sample(100.0), 1);
        assert_eq!(RunClock { control_hz: 1000.0, ..c }.ticks_per_sample(300.0), 3);
    }

    #[test]
    fn run_time_counts_from_the_first_tick_settling_included() {
        let c = RunClock { control_hz: 2000.0, settle_ticks: 500, ticks: 2000 };
        assert_eq!(c.run_time(0), 0.0);
        assert_eq!(c.run_time(500), 0.25);
        assert_eq!(c.run_time(2500), 1.25);
        assert_eq!(c.run_time(1500), c.run_time(500) + c.scenario_time(1500).unwrap());
        assert_eq!(c.run_time_ns(0), 0);
        assert_eq!(c.run_time_ns(1), 500_000);
        assert_eq!(c.run_time_ns(2500), 1_250_000_000);
        // Truncated, not rounded: 1/3 ms at 3 kHz.
        let odd = RunClock { control_hz: 3000.0, ..c };
        assert_eq!(odd.run_time_ns(1), 333_333);
        for k in [1, 7, 12_345, 987_654_321] {
            assert_eq!(odd.run_time_ns(k), (k as f64 * 1e9 / 3000.0) as u64, "tick {k}");
            assert_eq!(odd.run_time(k), k as f64 / 3000.0, "tick {k}");
        }
        assert_eq!(c.dt(), 0.5e-3);
        assert_eq!(c.dt_us(), 500.0);
        assert_eq!(odd.dt_us(), 1e6 / 3000.0);
    }
}
