//! The watchdog and the safe mode.
//!
//! Without a valid command within the deadline (a number of state ticks, or a time, whichever
//! comes first) the agent enters safe mode: a locally computed joint-space posture hold with
//! damping and gravity compensation, carrying the load the last command carried,
//!
//! ```text
//! tau = clamp( Kp (q_hold - q) - Kd qdot + g_a(q) + tau_c, -tau_max, tau_max )
//! tau_c = tau_last - g_a(q_hold)
//! ```
//!
//! on the actuated joints, where `q_hold` are the joint positions when safe mode was entered,
//! `g_a(q)` the joint torques that balance gravity at the current state, the stance feet
//! carrying the floating base ([`crate::standing`]), and
//! `tau_c` what the last command applied beyond the robot's own gravity (the hand's squeeze and
//! the object's weight, the feet's share of them; zero if no command was applied): entering
//! the hold does not drop the object, and the torque does not jump. It leaves safe mode only on
//! a valid command whose tick is newer than the latest state tick at entry.
//!
//! Entering the hold from commands blends too ([`Takeover`] the other way): for
//! [`Takeover::duration`] the applied torque moves linearly from the last command to the hold,
//! `tau = (1 - a) tau_last + a tau_hold`. The hold's damping `-Kd qdot` would otherwise step in
//! at once: 0.5 N m on an arm joint of S4's circle, a hundred times the carry's own steps.
//!
//! Commands then take over without a jump ([`Takeover`], a bumpless transfer): for
//! [`Takeover::duration`] of robot time the applied torque moves linearly from the posture
//! hold of the current state to the command, `tau = (1 - a) tau_hold + a tau_cmd`. The same
//! happens after the coordinator's hold orders (a member it is admitting, or a tick it could
//! not solve): whenever the agent's own hold was the last torque applied.

use std::time::{Duration, Instant};

/// When a missing command sends the agent to safe mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandDeadline {
    /// State ticks without a valid command (0: no tick deadline).
    pub ticks: u64,
    /// Time without a valid command (`None`: no time deadline).
    pub time: Option<Duration>,
}

impl Default for CommandDeadline {
    /// 5 ticks or 25 ms (5 ticks of a 200 Hz loop).
    fn default() -> Self {
        CommandDeadline { ticks: 5, time: Some(Duration::from_millis(25)) }
    }
}

/// [`Watchdog`]'s deadline for the first command, from the first state: 2 s, long against a
/// team's start-up work (the coordinator's first solve, its first window of references, a
/// recorder's buffers: 50-70 ms measured on a loaded two-core machine), short against a
/// coordinator that never comes.
pub const FIRST_COMMAND: CommandDeadline =
    CommandDeadline { ticks: 0, time: Some(Duration::from_secs(2)) };

/// Watches for the deadline; knows the tick at which safe mode was entered.
///
/// The deadline runs from every valid command applied. Before the first, a robot is not yet
/// commanded and its team is still starting: the first command has its own deadline
/// ([`FIRST_COMMAND`] by default), from the first state. A start slower than a tick's deadline
/// is then not a fault (it used to send every robot to safe mode at tick 0, holding no load:
/// the palms let go of the object before the first command came).
#[derive(Debug, Clone)]
pub struct Watchdog {
    deadline: CommandDeadline,
    first_command: CommandDeadline,
    /// Tick and time of the first state, from which the first command's deadline runs.
    first_state: Option<(u64, Instant)>,
    /// Tick and time of the latest valid command, from which the deadline runs.
    applied: Option<(u64, Instant)>,
    in_safe_mode: Option<u64>,
}

impl Watchdog {
    pub fn new(deadline: CommandDeadline, first_command: CommandDeadline) -> Self {
        Watchdog { deadline, first_command, first_state: None, applied: None, in_safe_mode: None }
    }

    pub fn deadline(&self) -> CommandDeadline {
        self.deadline
    }

    /// A state arrived: the first one starts the first command's deadline.
    pub fn on_state(&mut self, tick: u64, now: Instant) {
        if self.first_state.is_none() {
            self.first_state = Some((tick, now));
        }
    }

    /// Whether the deadline has passed at the latest state tick `latest_tick` and time `now`:
    /// the deadline from the latest command, or the first command's from the first state
    /// (false before the first state and while in safe mode).
    pub fn expired(&self, latest_tick: u64, now: Instant) -> bool {
        let (deadline, (tick, at)) = match (self.applied, self.first_state) {
            (Some(applied), _) => (self.deadline, applied),
            (None, Some(first)) => (self.first_command, first),
            (None, None) => return false,
        };
        if self.in_safe_mode.is_some() {
            return false;
        }
        let by_ticks = deadline.ticks > 0 && latest_tick.saturating_sub(tick) >= deadline.ticks;
        let by_time = deadline.time.is_some_and(|d| now.saturating_duration_since(at) > d);
        by_ticks || by_time
    }

    /// Enter safe mode at latest state tick `tick`.
    pub fn enter(&mut self, tick: u64) {
        self.in_safe_mode = Some(tick);
    }

    /// Latest state tick when safe mode was entered, if in safe mode.
    pub fn safe_mode_since(&self) -> Option<u64> {
        self.in_safe_mode
    }

    /// May a (checked) command of `tick` be applied? In safe mode only if it is newer than the
    /// entry tick; `Err(entry tick)` otherwise.
    pub fn admits(&self, tick: u64) -> Result<(), u64> {
        match self.in_safe_mode {
            Some(entered) if tick <= entered => Err(entered),
            _ => Ok(()),
        }
    }

    /// A valid command of `tick` was applied at `now`: the deadline restarts; returns true if
    /// this left safe mode.
    pub fn on_applied(&mut self, tick: u64, now: Instant) -> bool {
        self.applied = Some((tick, now));
        self.in_safe_mode.take().is_some()
    }
}

/// Gains of the posture hold, per actuated joint.
#[derive(Debug, Clone, PartialEq)]
pub struct HoldGains {
    pub kp: Vec<f64>,
    pub kd: Vec<f64>,
}

impl HoldGains {
    /// Gains that scale with each joint's torque limit: the limit is reached at 0.5 rad of
    /// error (`Kp = limit / 0.5 rad`) and `Kd = Kp * 25 ms`. For the default robot: legs
    /// 160 Nm/rad and 4 Nm s/rad, arm joints 1-3 78 and 1.95, joints 4-6 18 and 0.45. A joint
    /// without a finite limit gets 100 Nm/rad and 2.5 Nm s/rad.
    pub fn from_torque_limits(limits: &[f64]) -> Self {
        let kp: Vec<f64> =
            limits.iter().map(|l| if l.is_finite() { l / 0.5 } else { 100.0 }).collect();
        let kd = kp.iter().map(|k| k * 0.025).collect();
        HoldGains { kp, kd }
    }
}

/// The posture-hold law with its held configuration and carried load.
#[derive(Debug, Clone)]
pub struct PostureHold {
    gains: HoldGains,
    limits: Vec<f64>,
    q_hold: Vec<f64>,
    /// `tau_c`: the last command's torque beyond gravity at `q_hold` (zeros without one).
    carried: Vec<f64>,
}

impl PostureHold {
    pub fn new(gains: HoldGains, limits: Vec<f64>) -> Self {
        let n = limits.len();
        PostureHold { gains, limits, q_hold: Vec::with_capacity(n), carried: vec![0.0; n] }
    }

    pub fn gains(&self) -> &HoldGains {
        &self.gains
    }

    /// Hold these joint positions from now on, carrying no load but the robot's own weight.
    pub fn hold(&mut self, q: &[f64]) {
        self.move_to(q);
        self.carried.iter_mut().for_each(|c| *c = 0.0);
    }

    /// Hold these joint positions from now on, carrying the same load as before.
    pub fn move_to(&mut self, q: &[f64]) {
        self.q_hold.clear();
        self.q_hold.extend_from_slice(q);
    }

    /// Hold these joint positions from now on, carrying what the last command `applied`
    /// carried beyond `gravity` (both at `q`).
    pub fn hold_carrying(&mut self, q: &[f64], applied: &[f64], gravity: &[f64]) {
        self.hold(q);
        for ((c, a), g) in self.carried.iter_mut().zip(applied).zip(gravity) {
            *c = a - g;
        }
    }

    pub fn q_hold(&self) -> &[f64] {
        &self.q_hold
    }

    /// The load carried beyond gravity, `tau_c`.
    pub fn carried(&self) -> &[f64] {
        &self.carried
    }

    /// Its damping alone, `tau = clamp(-Kd qdot, ±limit)`, into `out`: what a fallen robot
    /// applies ([`crate::fall`]), no position gain, no gravity compensation.
    pub fn damping(&self, qdot: &[f64], out: &mut Vec<f64>) {
        out.clear();
        out.extend(
            self.gains
                .kd
                .iter()
                .zip(qdot)
                .zip(&self.limits)
                .map(|((k, v), &l)| (-k * v).clamp(-l, l)),
        );
    }

    /// `tau = clamp(Kp (q_hold - q) - Kd qdot + g + tau_c, ±limit)` into `out`; returns how many
    /// joints were clamped. Lengths must agree (the agent checks states against its size
    /// first); missing entries are treated as zero error, zero velocity, zero gravity.
    pub fn torques(&self, q: &[f64], qdot: &[f64], gravity: &[f64], out: &mut Vec<f64>) -> usize {
        out.clear();
        let mut clamped = 0;
        for i in 0..self.limits.len() {
            let e = match (self.q_hold.get(i), q.get(i)) {
                (Some(h), Some(q)) => h - q,
                _ => 0.0,
            };
            let t = self.gains.kp[i] * e - self.gains.kd[i] * qdot.get(i).copied().unwrap_or(0.0)
                + gravity.get(i).copied().unwrap_or(0.0)
                + self.carried[i];
            let l = self.limits[i];
            let c = t.clamp(-l, l);
            clamped += (c != t) as usize;
            out.push(c);
        }
        clamped
    }
}

/// The bumpless transfer from the posture hold to the coordinator's commands (see the module
/// docs): started when a command follows a hold, it blends the two over `duration` of robot
/// time (the states' `time`, so lockstep and real time blend alike).
#[derive(Debug, Clone)]
pub struct Takeover {
    duration: f64,
    /// Robot time at which the blend started, while it lasts.
    since: Option<f64>,
}

impl Takeover {
    /// A takeover over `duration` (zero: commands apply at once).
    pub fn new(duration: std::time::Duration) -> Self {
        Takeover { duration: duration.as_secs_f64(), since: None }
    }

    pub fn duration(&self) -> f64 {
        self.duration
    }

    /// A command follows a hold at robot time `t`: the blend starts.
    pub fn start(&mut self, t: f64) {
        self.since = (self.duration > 0.0).then_some(t);
    }

    /// The blend's weight of the command at robot time `t` (1 once it is over, and the blend
    /// ends then).
    pub fn weight(&mut self, t: f64) -> f64 {
        let Some(t0) = self.since else { return 1.0 };
        let a = ((t - t0) / self.duration).clamp(0.0, 1.0);
        if a >= 1.0 {
            self.since = None;
        }
        a
    }

    /// The hold applies again: no blend until the next start.
    pub fn cancel(&mut self) {
        self.since = None;
    }

    /// Whether a blend is under way.
    pub fn active(&self) -> bool {
        self.since.is_some()
    }

    /// `cmd = (1 - a) hold + a cmd` in place, `a` = [`Takeover::weight`] at `t`; returns `a`.
    pub fn blend(&mut self, t: f64, hold: &[f64], cmd: &mut [f64]) -> f64 {
        let a = self.weight(t);
        if a < 1.0 {
            for (c, h) in cmd.iter_mut().zip(hold) {
                *c = (1.0 - a) * h + a * *c;
            }
        }
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deadline_by_ticks_or_time_and_leaving_only_on_a_fresh_tick() {
        let t0 = Instant::now();
        let deadline = CommandDeadline { ticks: 5, time: Some(Duration::from_millis(25)) };
        let mut w = Watchdog::new(deadline, deadline);
        assert!(!w.expired(100, t0 + Duration::from_secs(1)), "expired before any state");
        w.on_state(10, t0);
        assert!(!w.expired(14, t0 + Duration::from_millis(20)));
        assert!(w.expired(15, t0), "5 ticks without a command");
        assert!(w.expired(11, t0 + Duration::from_millis(26)), "25 ms without a command");
        assert!(!w.on_applied(12, t0 + Duration::from_millis(10)));
        assert!(!w.expired(16, t0 + Duration::from_millis(30)));
        w.enter(17);
        assert!(!w.expired(30, t0 + Duration::from_secs(1)), "already in safe mode");
        assert_eq!(w.admits(17), Err(17));
        assert_eq!(w.admits(18), Ok(()));
        assert!(w.on_applied(18, t0 + Duration::from_millis(40)));
        assert_eq!(w.safe_mode_since(), None);
        let none = CommandDeadline { ticks: 0, time: None };
        let no_time = Watchdog::new(none, none);
        assert!(!no_time.expired(u64::MAX, t0 + Duration::from_secs(100)));
    }

    /// The first command has its own deadline from the first state; once a command came, the
    /// tick's deadline runs from it.
    #[test]
    fn the_first_command_has_its_own_deadline() {
        let t0 = Instant::now();
        let deadline = CommandDeadline { ticks: 5, time: Some(Duration::from_millis(25)) };
        let mut w = Watchdog::new(deadline, FIRST_COMMAND);
        w.on_state(0, t0);
        assert!(!w.expired(0, t0 + Duration::from_millis(70)), "a slow first solve is not a miss");
        assert!(
            !w.expired(40, t0 + Duration::from_millis(1999)),
            "ticks do not count before the first command"
        );
        assert!(w.expired(0, t0 + Duration::from_millis(2001)), "no first command in 2 s");
        assert!(!w.on_applied(1, t0 + Duration::from_millis(70)));
        assert!(!w.expired(5, t0 + Duration::from_millis(90)));
        assert!(w.expired(6, t0 + Duration::from_millis(90)), "5 ticks after the first command");
        assert!(w.expired(1, t0 + Duration::from_millis(96)), "25 ms after the first command");
    }

    #[test]
    fn the_damping_alone_opposes_the_velocity_within_the_limits() {
        let gains = HoldGains { kp: vec![100.0; 3], kd: vec![2.0, 10.0, 1.0] };
        let hold = PostureHold::new(gains, vec![40.0, 20.0, 5.0]);
        let mut out = Vec::new();
        hold.damping(&[0.5, -3.0, 0.0], &mut out);
        assert_eq!(out, vec![-1.0, 20.0, 0.0]);
    }

    #[test]
    fn takeover_blends_linearly_in_robot_time_and_ends() {
        let mut t = Takeover::new(Duration::from_millis(100));
        let hold = [10.0, -4.0];
        let mut cmd = [20.0, 4.0];
        assert_eq!(t.blend(5.0, &hold, &mut cmd), 1.0, "no blend before a start");
        assert_eq!(cmd, [20.0, 4.0]);
        t.start(5.0);
        let mut at = |time: f64| {
            let mut c = [20.0, 4.0];
            let a = t.blend(time, &hold, &mut c);
            (a, c)
        };
        let (a, c) = at(5.0);
        assert_eq!((a, c), (0.0, hold), "starts at the hold");
        let (a, c) = at(5.025);
        assert!((a - 0.25).abs() < 1e-12);
        assert!((c[0] - 12.5).abs() < 1e-9 && (c[1] + 2.0).abs() < 1e-9, "{c:?}");
        let (a, c) = at(5.1 + 1e-9);
        assert_eq!((a, c), (1.0, [20.0, 4.0]), "ends at the command");
        assert!(!t.active());
        let mut none = Takeover::new(Duration::ZERO);
        none.start(1.0);
        assert!(!none.active(), "a zero duration never blends");
    }

    #[test]
    fn the_hold_carries_the_last_commands_load_beyond_gravity() {
        let mut h = PostureHold::new(
            HoldGains { kp: vec![100.0, 10.0], kd: vec![2.0, 1.0] },
            vec![80.0, 9.0],
        );
        // The last command applied [20, -3] at q where gravity was [3, 8.5]: it carried [17, -11.5].
        h.hold_carrying(&[0.5, -0.2], &[20.0, -3.0], &[3.0, 8.5]);
        assert_eq!(h.carried(), [17.0, -11.5]);
        let mut out = Vec::new();
        h.torques(&[0.5, -0.2], &[0.0, 0.0], &[3.0, 8.5], &mut out);
        assert_eq!(out, vec![20.0, -3.0], "at the held posture: the last command itself");
        h.torques(&[0.4, -0.2], &[0.0, 0.0], &[4.0, 8.0], &mut out);
        assert!(
            (out[0] - (10.0 + 4.0 + 17.0)).abs() < 1e-12 && (out[1] - (8.0 - 11.5)).abs() < 1e-12,
            "{out:?}"
        );
        h.hold(&[0.5, -0.2]);
        assert_eq!(h.carried(), [0.0, 0.0], "a plain hold carries nothing");
    }

    #[test]
    fn hold_law_is_pd_plus_gravity_clamped() {
        let mut h = PostureHold::new(
            HoldGains { kp: vec![100.0, 10.0], kd: vec![2.0, 1.0] },
            vec![80.0, 9.0],
        );
        h.hold(&[0.5, -0.2]);
        let mut out = Vec::new();
        assert_eq!(h.torques(&[0.4, -0.2], &[1.0, 0.0], &[3.0, 8.5], &mut out), 0);
        assert!((out[0] - (10.0 - 2.0 + 3.0)).abs() < 1e-12);
        assert!((out[1] - 8.5).abs() < 1e-12);
        assert_eq!(h.torques(&[0.4, -0.3], &[0.0, 0.0], &[3.0, 8.5], &mut out), 1);
        assert_eq!(out[1], 9.0);
    }
}
