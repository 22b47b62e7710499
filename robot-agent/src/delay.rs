//! The team's delay ([`crate::core::AgentConfig::team_delay`]) as a number of state ticks, or
//! set from the latency the agent measures ([`TeamDelay::Auto`]).
//!
//! The team's command for the state of tick k applies at the state of tick k + d. It is on time
//! when it is there before that state: when it arrives, the latest state is at most k + d - 1.
//! With d = 0 the command answers the state it waits at, and the robot's drives take that
//! answer only for so long: where they do not wait for it (real time), a command is also late
//! when it comes more than the robot's answer window
//! ([`crate::core::AgentConfig::answer_within`]) after its own state arrived. A command that
//! comes later is answered alone ([`crate::core::AgentCore`]'s skipped commands), which is
//! safe but loses the team's answer for a tick.
//!
//! With `auto`, [`AdaptiveDelay`] counts the commands that came late in a window of [`WINDOW`]
//! commands; the [`LATE_TO_RAISE`]-th (one in forty) raises the delay by one tick, up to its
//! most (`auto:N`; `auto` is [`AUTO_MAX`]). When in [`LOWER_WINDOW`] commands at most
//! [`LATE_TO_KEEP`] would have been late a tick sooner, it lowers it by one (a start-up's
//! bursts raise it, and a delay is what the team's tracking pays for latency). The delay
//! covers the latency most commands see, not the rare long one: a command that would have
//! been late even at the most delay (a lost packet's retransmission on a lossy link takes many
//! ticks) is not counted, because no delay it may come to would have kept it, and a delay that
//! long costs the team's loop more than the commands it keeps (S4 with 5 % loss on one robot's
//! link held with 3 ticks and fell with 8, fixed or come to). A change moves every command
//! still waiting with it: a raise leaves one state without a team command (answered alone), a
//! lowering applies two at one state (the newer one wins). Without an answer window the count
//! is in state ticks and needs no clock: a lockstep run, whose simulator waits for every
//! answer, never counts a command late at d = 0 and keeps it.

use std::fmt;
use std::str::FromStr;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

/// The longest team delay, in state ticks (`crate::core::AgentConfig::team_delay`).
pub const MAX_TEAM_DELAY: u64 = protocol::MAX_TEAM_DELAY_TICKS;

/// Commands per window of late counts.
pub const WINDOW: u32 = 200;
/// The most `auto` raises the delay to, ticks (`auto:N` sets another, up to
/// [`MAX_TEAM_DELAY`]).
pub const AUTO_MAX: u64 = 4;
/// Late commands in one window that raise the delay by a tick (one in forty of [`WINDOW`]).
pub const LATE_TO_RAISE: u32 = 5;
/// Commands over which a delay a tick shorter is tried.
pub const LOWER_WINDOW: u32 = 2000;
/// At most this many of [`LOWER_WINDOW`] commands late for a delay a tick shorter lower it
/// (1 %).
pub const LATE_TO_KEEP: u32 = 20;

/// The team's delay as configured: a number of state ticks, or `auto` (from 0, changed from the
/// measured latency, up to `max`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "RawDelay", into = "RawDelay")]
pub enum TeamDelay {
    Ticks(u64),
    Auto { max: u64 },
}

impl Default for TeamDelay {
    fn default() -> Self {
        TeamDelay::Ticks(0)
    }
}

impl TeamDelay {
    /// `auto`, up to [`AUTO_MAX`].
    pub const AUTO: TeamDelay = TeamDelay::Auto { max: AUTO_MAX };

    /// The delay the agent starts with.
    pub fn initial(self) -> u64 {
        match self {
            TeamDelay::Ticks(d) => d,
            TeamDelay::Auto { .. } => 0,
        }
    }

    /// Whether the agent raises it from the latency it measures.
    pub fn adapts(self) -> bool {
        matches!(self, TeamDelay::Auto { .. })
    }

    /// The most it may come to.
    pub fn max(self) -> u64 {
        match self {
            TeamDelay::Ticks(d) => d,
            TeamDelay::Auto { max } => max,
        }
    }
}

impl FromStr for TeamDelay {
    type Err = String;

    /// A whole number of ticks from 0 to [`MAX_TEAM_DELAY`], `auto`, or `auto:N` (N from 1 to
    /// [`MAX_TEAM_DELAY`]).
    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim();
        let bad = || {
            format!(
                "team delay {s:?}: \"auto\", \"auto:N\" or a whole number of ticks from 0 to \
                 {MAX_TEAM_DELAY}"
            )
        };
        if s == "auto" {
            return Ok(TeamDelay::AUTO);
        }
        if let Some(max) = s.strip_prefix("auto:") {
            return match max.parse::<u64>() {
                Ok(max) if (1..=MAX_TEAM_DELAY).contains(&max) => Ok(TeamDelay::Auto { max }),
                _ => Err(bad()),
            };
        }
        match s.parse::<u64>() {
            Ok(d) if d <= MAX_TEAM_DELAY => Ok(TeamDelay::Ticks(d)),
            _ => Err(bad()),
        }
    }
}

impl fmt::Display for TeamDelay {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TeamDelay::Ticks(d) => write!(f, "{d}"),
            TeamDelay::Auto { max: AUTO_MAX } => f.write_str("auto"),
            TeamDelay::Auto { max } => write!(f, "auto:{max}"),
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
            TeamDelay::Auto { .. } => RawDelay::Word(d.to_string()),
        }
    }
}

/// States whose arrival is kept (the delay's lateness at d = 0 looks at a command's own
/// state, at most [`MAX_TEAM_DELAY`] + 1 ticks back).
const ARRIVALS: usize = MAX_TEAM_DELAY as usize + 2;

/// The delay in use and, with `auto`, the count that raises it (see the module's docs).
#[derive(Debug, Clone)]
pub struct AdaptiveDelay {
    delay: u64,
    /// The least it goes to (the configured start) and the most.
    floor: u64,
    max: u64,
    adapts: bool,
    /// The robot's answer window (`None`: its drives wait for the answer).
    within: Option<Duration>,
    /// The latest state's tick, and when recent states arrived (by tick modulo [`ARRIVALS`]).
    latest: Option<u64>,
    arrivals: [(u64, Option<Instant>); ARRIVALS],
    seen: u32,
    late: u32,
    /// Commands since the delay last changed or was tried lower, and how many of them would
    /// have been late a tick sooner.
    seen_long: u32,
    late_sooner: u32,
}

impl AdaptiveDelay {
    /// The delay `cfg` for a robot whose drives take an answer within `within` of its state
    /// (`None`: they wait for it).
    pub fn new(cfg: TeamDelay, within: Option<Duration>) -> Self {
        AdaptiveDelay {
            delay: cfg.initial(),
            floor: cfg.initial(),
            max: cfg.max(),
            adapts: cfg.adapts(),
            within,
            latest: None,
            arrivals: [(0, None); ARRIVALS],
            seen: 0,
            late: 0,
            seen_long: 0,
            late_sooner: 0,
        }
    }

    /// The delay in use, state ticks.
    pub fn ticks(&self) -> u64 {
        self.delay
    }

    /// The state of `tick` arrived at `now` (an older one than the latest is ignored).
    pub fn on_state(&mut self, tick: u64, now: Instant) {
        if self.latest.is_some_and(|l| tick < l) {
            return;
        }
        self.latest = Some(tick);
        self.arrivals[(tick % ARRIVALS as u64) as usize] = (tick, Some(now));
    }

    /// Whether a command of the state of `tick` arriving at `now` came late for the delay in
    /// use (never before any state).
    pub fn late(&self, tick: u64, now: Instant) -> bool {
        self.late_for(self.delay, tick, now)
    }

    /// A command of the state of `tick` arrived at `now`: the new delay when this changes it.
    pub fn on_command(&mut self, tick: u64, now: Instant) -> Option<u64> {
        if !self.adapts || self.latest.is_none() {
            return None;
        }
        self.seen += 1;
        // Late even at the most: no delay it may come to would have kept it (module docs).
        let curable = !self.late_for(self.max, tick, now);
        if curable && self.late(tick, now) {
            self.late += 1;
        }
        self.seen_long += 1;
        if self.delay > self.floor && curable && self.late_for(self.delay - 1, tick, now) {
            self.late_sooner += 1;
        }
        let before = self.delay;
        if self.late >= LATE_TO_RAISE && self.delay < self.max {
            self.delay += 1;
        } else if self.seen_long >= LOWER_WINDOW
            && self.late_sooner <= LATE_TO_KEEP
            && self.delay > self.floor
        {
            self.delay -= 1;
        }
        if self.delay != before || self.seen >= WINDOW {
            (self.seen, self.late) = (0, 0);
        }
        if self.delay != before || self.seen_long >= LOWER_WINDOW {
            (self.seen_long, self.late_sooner) = (0, 0);
        }
        (self.delay != before).then_some(self.delay)
    }

    /// Whether a command of `tick` arriving at `now` is late for a delay of `delay` ticks: the
    /// state it applies at came before it, or (d = 0, with an answer window) its own state
    /// came longer than the window before it (module docs).
    fn late_for(&self, delay: u64, tick: u64, now: Instant) -> bool {
        let Some(latest) = self.latest else { return false };
        if latest.saturating_sub(tick) >= delay.max(1) {
            return true;
        }
        delay == 0 && self.waited(tick, now).zip(self.within).is_some_and(|(w, max)| w > max)
    }

    /// How long ago the state of `tick` arrived, if it is one of the states kept.
    fn waited(&self, tick: u64, now: Instant) -> Option<Duration> {
        match self.arrivals[(tick % ARRIVALS as u64) as usize] {
            (t, Some(at)) if t == tick => Some(now.saturating_duration_since(at)),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_delay_reads_as_auto_or_whole_ticks_up_to_the_most() {
        assert_eq!("auto".parse(), Ok(TeamDelay::Auto { max: AUTO_MAX }));
        assert_eq!("auto:8".parse(), Ok(TeamDelay::Auto { max: 8 }));
        assert_eq!(" 3".parse(), Ok(TeamDelay::Ticks(3)));
        assert_eq!(MAX_TEAM_DELAY.to_string().parse(), Ok(TeamDelay::Ticks(MAX_TEAM_DELAY)));
        for bad in ["", "9", "-1", "2.5", "Auto", "NaN", "auto:0", "auto:9", "auto:"] {
            let e = bad.parse::<TeamDelay>().expect_err(bad);
            assert!(e.contains("auto:N") && e.contains("0 to 8"), "{e}");
        }
        for d in [TeamDelay::AUTO, TeamDelay::Auto { max: 6 }, TeamDelay::Ticks(2)] {
            assert_eq!(d.to_string().parse(), Ok(d), "round trip through its text");
            let json = serde_json::to_string(&d).unwrap();
            assert_eq!(serde_json::from_str::<TeamDelay>(&json).unwrap(), d, "{json}");
        }
        assert_eq!(serde_json::from_str::<TeamDelay>("2").unwrap(), TeamDelay::Ticks(2));
        assert!(
            serde_json::from_str::<TeamDelay>("9").is_err()
                && serde_json::from_str::<TeamDelay>("\"soon\"").is_err()
        );
    }

    /// A command of `tick` arriving when the latest state is `latest` (no answer window).
    fn at(a: &mut AdaptiveDelay, tick: u64, latest: u64) -> Option<u64> {
        a.latest = Some(latest);
        a.on_command(tick, Instant::now())
    }

    /// Written out again: a command is on time when its state's tick plus the delay is still
    /// ahead of the latest state (d = 0: the command of the latest state itself).
    #[test]
    fn a_command_is_late_when_the_state_it_applies_at_came_before_it() {
        let mut a = AdaptiveDelay::new(TeamDelay::AUTO, None);
        let now = Instant::now();
        assert!(!a.late(10, now), "before any state");
        a.on_state(10, now);
        assert!(!a.late(10, now + Duration::from_secs(1)), "d = 0, no window: waits");
        a.on_state(11, now);
        assert!(a.late(10, now), "d = 0");
        while a.ticks() < 3 {
            for _ in 0..LATE_TO_RAISE {
                at(&mut a, 97, 100);
            }
        }
        a.latest = Some(12);
        assert!(!a.late(10, now), "d = 3");
        a.latest = Some(13);
        assert!(a.late(10, now), "d = 3");
        a.latest = Some(5);
        assert!(!a.late(10, now), "a command ahead of its state");
    }

    /// With an answer window, a command at d = 0 is late when it comes longer than the window
    /// after its own state, and the delay rises; at d = 1 the same command is on time.
    #[test]
    fn at_no_delay_a_command_past_the_answer_window_is_late() {
        let ms = Duration::from_millis;
        let mut a = AdaptiveDelay::new(TeamDelay::AUTO, Some(ms(2)));
        let t0 = Instant::now();
        a.on_state(0, t0);
        assert!(!a.late(0, t0 + ms(2)) && a.late(0, t0 + ms(3)));
        let mut changes = Vec::new();
        for k in 0..WINDOW as u64 {
            let t = t0 + ms(4 * k);
            a.on_state(k, t);
            // One command in ten 3 ms after its state, the others after 1 ms.
            let lag = if k % 10 == 9 { 3 } else { 1 };
            if let Some(d) = a.on_command(k, t + ms(lag)) {
                changes.push((k, d));
            }
        }
        assert_eq!(changes, vec![(10 * LATE_TO_RAISE as u64 - 1, 1)]);
        assert!(!a.late(WINDOW as u64 - 1, t0 + ms(4 * WINDOW as u64 + 2)), "d = 1");
        // Without a window (lockstep) the same commands are all on time at d = 0.
        let mut b = AdaptiveDelay::new(TeamDelay::AUTO, None);
        for k in 0..WINDOW as u64 {
            let t = t0 + ms(4 * k);
            b.on_state(k, t);
            assert_eq!(b.on_command(k, t + ms(if k % 10 == 9 { 3 } else { 1 })), None);
        }
    }

    #[test]
    fn auto_raises_by_a_tick_when_one_in_forty_come_late_and_lowers_when_a_tick_less_would_do() {
        let (raise, window, lower, keep) =
            (LATE_TO_RAISE as u64, WINDOW as u64, LOWER_WINDOW as u64, LATE_TO_KEEP as u64);
        let mut a = AdaptiveDelay::new(TeamDelay::Auto { max: MAX_TEAM_DELAY }, None);
        assert_eq!(a.ticks(), 0);
        // One fewer late than a raise in a window, then the window ends: the count restarts.
        for k in 0..window {
            let latest = if k < raise - 1 { k + 1 } else { k };
            assert_eq!(at(&mut a, k, latest), None, "command {k}");
        }
        for k in 0..raise - 1 {
            assert_eq!(at(&mut a, k, k + 1), None, "a new window: {k}");
        }
        assert_eq!(at(&mut a, 0, 1), Some(1), "the LATE_TO_RAISE-th late command of a window");
        for k in 0..raise * 20 {
            at(&mut a, k, k + MAX_TEAM_DELAY - 1);
        }
        assert_eq!(a.ticks(), MAX_TEAM_DELAY, "up to the most");
        assert_eq!(at(&mut a, 0, 1000), None, "not beyond it");
        let mut capped = AdaptiveDelay::new(TeamDelay::AUTO, None);
        for k in 0..raise * 20 {
            at(&mut capped, k, k + AUTO_MAX - 1);
        }
        assert_eq!(capped.ticks(), AUTO_MAX, "auto stops at its most");
        // Commands two ticks behind: on time for 3 ticks and more, late for 2 and less. It
        // comes down one tick per LOWER_WINDOW of them, to 3, and stays there.
        let mut changes = Vec::new();
        for k in 0..lower * 10 {
            if let Some(d) = at(&mut a, k, k + 2) {
                changes.push((k + 1, d));
            }
        }
        // (The window running since the last raise, which saw late commands, ends first.)
        assert_eq!(
            changes.iter().map(|c| c.1).collect::<Vec<_>>(),
            (3..MAX_TEAM_DELAY).rev().collect::<Vec<_>>()
        );
        assert!(
            changes[0].0 <= 2 * lower && changes.windows(2).all(|w| w[1].0 - w[0].0 == lower),
            "{changes:?}"
        );
        // LATE_TO_KEEP late for 2 in a LOWER_WINDOW still lower 3 to 2, one more does not.
        let mut b = AdaptiveDelay::new(TeamDelay::AUTO, None);
        for k in 0..raise * 3 {
            at(&mut b, k, k + 3);
        }
        assert_eq!(b.ticks(), 3);
        let mut changes = Vec::new();
        for k in 1..=lower {
            if let Some(d) = at(&mut b, k, k + if k <= keep { 2 } else { 1 }) {
                changes.push((k, d));
            }
        }
        assert_eq!(changes, vec![(lower, 2)], "{keep} late for 2 lower it");
        let mut c = AdaptiveDelay::new(TeamDelay::AUTO, None);
        for k in 0..raise * 3 {
            at(&mut c, k, k + 3);
        }
        for k in 0..lower {
            let latest = k + if k <= keep { 2 } else { 1 };
            assert_eq!(at(&mut c, k, latest), None, "{} late for 2 keep 3", keep + 1);
        }
    }

    /// A lossy link: one command in twenty comes 12 ticks late (a retransmission), the rest on
    /// time. No delay up to the most would have kept those: they do not raise it.
    #[test]
    fn commands_later_than_the_most_delay_do_not_raise_it() {
        let mut a = AdaptiveDelay::new(TeamDelay::AUTO, None);
        for k in 0..10 * WINDOW as u64 {
            let lag = if k % 20 == 0 { 12 } else { 0 };
            assert_eq!(at(&mut a, k, k + lag), None, "command {k}");
        }
        for k in 0..LATE_TO_RAISE as u64 {
            at(&mut a, k, k + AUTO_MAX - 1);
        }
        assert_eq!(a.ticks(), 1, "late by what the most would keep: raised");
    }

    #[test]
    fn a_fixed_delay_stays_whatever_comes() {
        let mut a = AdaptiveDelay::new(TeamDelay::Ticks(2), Some(Duration::ZERO));
        for k in 0..1000 {
            assert_eq!(at(&mut a, k, k + 7), None);
        }
        assert_eq!(a.ticks(), 2);
    }
}
