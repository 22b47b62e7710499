//! The team's delay ([`crate::core::AgentConfig::team_delay`]) as a number of state ticks, or
//! set from the latency the agent measures ([`TeamDelay::Auto`]).
//!
//! The team's command for the state of tick k applies at the state of tick k + d. It is on time
//! when it is there before that state: when it arrives, the latest state is at most k + d - 1
//! (at most k with d = 0, where the command answers the state it waits at). A command that
//! comes later is answered alone ([`crate::core::AgentCore`]'s skipped commands), which is
//! safe but loses the team's answer for a tick. With `auto`, [`AdaptiveDelay`] counts the
//! commands that came late in a window of [`WINDOW`] commands; the [`LATE_TO_RAISE`]-th raises
//! the delay by one tick, up to [`crate::core::MAX_TEAM_DELAY`]. After [`QUIET_TO_LOWER`]
//! commands in a row none of which would have been late a tick sooner, it lowers it by one (a
//! start-up's bursts raise it, and a delay is what the team's tracking pays for latency). A
//! change moves every command still waiting with it: a raise leaves one state without a team
//! command (answered alone), a lowering applies two at one state (the newer one wins). The
//! count is in state ticks, so it needs no clock: a lockstep run, whose simulator waits for
//! every answer, never counts a command late at d = 0 and keeps it.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::core::MAX_TEAM_DELAY;

/// Commands per window of late counts.
pub const WINDOW: u32 = 200;
/// Late commands in one window that raise the delay by a tick (1.5 % of [`WINDOW`]).
pub const LATE_TO_RAISE: u32 = 3;
/// Commands in a row, none late for a delay a tick shorter, that lower it by a tick.
pub const QUIET_TO_LOWER: u32 = 2000;

/// The team's delay as configured: a number of state ticks, or `auto` (from 0, raised from the
/// measured latency).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "RawDelay", into = "RawDelay")]
pub enum TeamDelay {
    Ticks(u64),
    Auto,
}

impl Default for TeamDelay {
    fn default() -> Self {
        TeamDelay::Ticks(0)
    }
}

impl TeamDelay {
    /// The delay the agent starts with.
    pub fn initial(self) -> u64 {
        match self {
            TeamDelay::Ticks(d) => d,
            TeamDelay::Auto => 0,
        }
    }

    /// Whether the agent raises it from the latency it measures.
    pub fn adapts(self) -> bool {
        self == TeamDelay::Auto
    }
}

impl FromStr for TeamDelay {
    type Err = String;

    /// `auto` or a whole number of ticks from 0 to [`MAX_TEAM_DELAY`].
    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim();
        if s == "auto" {
            return Ok(TeamDelay::Auto);
        }
        match s.parse::<u64>() {
            Ok(d) if d <= MAX_TEAM_DELAY => Ok(TeamDelay::Ticks(d)),
            _ => Err(format!("team delay {s:?}: \"auto\" or a whole number of ticks from 0 to {MAX_TEAM_DELAY}")),
        }
    }
}

impl fmt::Display for TeamDelay {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TeamDelay::Ticks(d) => write!(f, "{d}"),
            TeamDelay::Auto => f.write_str("auto"),
        }
    }
}

/// How a delay is written in a file: a number, or the word `auto`.
#[derive(Serialize, Deserialize)]
#[serde(untagged)]
enum RawDelay {
    Ticks(u64),
    Signed(i64),
    Real(f64),
    Word(String),
}

impl TryFrom<RawDelay> for TeamDelay {
    type Error = String;

    fn try_from(raw: RawDelay) -> Result<Self, String> {
        match raw {
            RawDelay::Ticks(d) => d.to_string().parse(),
            RawDelay::Signed(d) => d.to_string().parse(),
            RawDelay::Real(d) => d.to_string().parse(),
            RawDelay::Word(w) => w.parse(),
        }
    }
}

impl From<TeamDelay> for RawDelay {
    fn from(d: TeamDelay) -> Self {
        match d {
            TeamDelay::Ticks(d) => RawDelay::Ticks(d),
            TeamDelay::Auto => RawDelay::Word("auto".into()),
        }
    }
}

/// The delay in use and, with `auto`, the count that raises it (see the module's docs).
#[derive(Debug, Clone)]
pub struct AdaptiveDelay {
    delay: u64,
    /// The least it goes to (the configured start).
    floor: u64,
    adapts: bool,
    seen: u32,
    late: u32,
    /// Commands in a row that would have been on time a tick sooner.
    quiet: u32,
}

impl AdaptiveDelay {
    pub fn new(cfg: TeamDelay) -> Self {
        AdaptiveDelay { delay: cfg.initial(), floor: cfg.initial(), adapts: cfg.adapts(), seen: 0, late: 0, quiet: 0 }
    }

    /// The delay in use, state ticks.
    pub fn ticks(&self) -> u64 {
        self.delay
    }

    /// Whether a command of the state of `tick` that arrives when the latest state is `latest`
    /// came late for the delay in use.
    pub fn late(&self, tick: u64, latest: u64) -> bool {
        late_for(self.delay, tick, latest)
    }

    /// A command of the state of `tick` arrived when the latest state was `latest`: the new
    /// delay when this changes it.
    pub fn on_command(&mut self, tick: u64, latest: u64) -> Option<u64> {
        if !self.adapts {
            return None;
        }
        self.seen += 1;
        if self.late(tick, latest) {
            self.late += 1;
        }
        let sooner_late = self.delay > self.floor && late_for(self.delay - 1, tick, latest);
        self.quiet = if sooner_late { 0 } else { self.quiet + 1 };
        let before = self.delay;
        if self.late >= LATE_TO_RAISE && self.delay < MAX_TEAM_DELAY {
            self.delay += 1;
        } else if self.quiet >= QUIET_TO_LOWER && self.delay > self.floor {
            self.delay -= 1;
        }
        if self.delay != before || self.seen >= WINDOW {
            (self.seen, self.late) = (0, 0);
        }
        if self.delay != before {
            self.quiet = 0;
        }
        (self.delay != before).then_some(self.delay)
    }
}

/// Whether a command of `tick` arriving when the latest state is `latest` is late for a delay
/// of `delay` ticks (module docs).
fn late_for(delay: u64, tick: u64, latest: u64) -> bool {
    latest.saturating_sub(tick) >= delay.max(1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_delay_reads_as_auto_or_whole_ticks_up_to_the_most() {
        assert_eq!("auto".parse(), Ok(TeamDelay::Auto));
        assert_eq!(" 3".parse(), Ok(TeamDelay::Ticks(3)));
        assert_eq!(MAX_TEAM_DELAY.to_string().parse(), Ok(TeamDelay::Ticks(MAX_TEAM_DELAY)));
        for bad in ["", "9", "-1", "2.5", "Auto", "NaN"] {
            let e = bad.parse::<TeamDelay>().expect_err(bad);
            assert!(e.contains("auto") && e.contains("0 to 8"), "{e}");
        }
        for d in [TeamDelay::Auto, TeamDelay::Ticks(2)] {
            assert_eq!(d.to_string().parse(), Ok(d), "round trip through its text");
            let json = serde_json::to_string(&d).unwrap();
            assert_eq!(serde_json::from_str::<TeamDelay>(&json).unwrap(), d, "{json}");
        }
        assert_eq!(serde_json::from_str::<TeamDelay>("2").unwrap(), TeamDelay::Ticks(2));
        assert!(serde_json::from_str::<TeamDelay>("9").is_err() && serde_json::from_str::<TeamDelay>("\"soon\"").is_err());
    }

    /// Written out again: a command is on time when its state's tick plus the delay is still
    /// ahead of the latest state (d = 0: the command of the latest state itself).
    #[test]
    fn a_command_is_late_when_the_state_it_applies_at_came_before_it() {
        let mut a = AdaptiveDelay::new(TeamDelay::Auto);
        assert!(!a.late(10, 10) && a.late(10, 11), "d = 0");
        while a.ticks() < 3 {
            for _ in 0..LATE_TO_RAISE {
                a.on_command(0, 100);
            }
        }
        assert!(!a.late(10, 12) && a.late(10, 13) && a.late(10, 20), "d = 3");
        assert!(!a.late(10, 5), "a command ahead of its state");
    }

    #[test]
    fn auto_raises_by_one_tick_per_window_with_enough_late_commands_and_lowers_when_quiet() {
        let mut a = AdaptiveDelay::new(TeamDelay::Auto);
        assert_eq!(a.ticks(), 0);
        // Two late in a window, then the window ends: no raise, the count starts again.
        assert_eq!((a.on_command(0, 1), a.on_command(1, 2)), (None, None));
        for k in 2..WINDOW as u64 {
            assert_eq!(a.on_command(k, k), None, "on time");
        }
        assert_eq!((a.on_command(300, 301), a.on_command(301, 302)), (None, None), "a new window");
        assert_eq!(a.on_command(302, 303), Some(1), "the third late command of a window raises");
        for k in 0..(LATE_TO_RAISE as u64 * 20) {
            a.on_command(k, k + 50);
        }
        assert_eq!(a.ticks(), MAX_TEAM_DELAY, "up to the most");
        assert_eq!(a.on_command(0, 1000), None, "not beyond it");
        // Commands two ticks behind: on time for 3 ticks and more, late for 2 and less. It
        // comes down one tick per QUIET_TO_LOWER of them, to 3, and stays there.
        let mut changes = Vec::new();
        for k in 0..(QUIET_TO_LOWER as u64 * 10) {
            if let Some(d) = a.on_command(k, k + 2) {
                changes.push((k + 1, d));
            }
        }
        let q = QUIET_TO_LOWER as u64;
        assert_eq!(changes, (0..5).map(|i| ((i + 1) * q, MAX_TEAM_DELAY - 1 - i)).collect::<Vec<_>>());
        // One command late for 2 among them restarts the count.
        let mut b = AdaptiveDelay::new(TeamDelay::Auto);
        for k in 0..9 {
            b.on_command(k, k + 5);
        }
        assert_eq!(b.ticks(), 3);
        for k in 0..(q - 1) {
            assert_eq!(b.on_command(k, k + 1), None);
        }
        assert_eq!(b.on_command(0, 2), None, "late for 2, on time for 3");
        for k in 0..(q - 1) {
            assert_eq!(b.on_command(k, k + 1), None);
        }
        assert_eq!(b.on_command(0, 1), Some(2), "the QUIET_TO_LOWER-th in a row");
    }

    #[test]
    fn a_fixed_delay_stays_whatever_comes() {
        let mut a = AdaptiveDelay::new(TeamDelay::Ticks(2));
        for k in 0..1000 {
            assert_eq!(a.on_command(k, k + 7), None);
        }
        assert_eq!(a.ticks(), 2);
    }
}
