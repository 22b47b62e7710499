//! Checks of an incoming torque command (docs/architecture.md, one tick, step 4): robot id,
//! tick (not older than the last applied, not from the future), age against a deadline, size,
//! finite numbers; then clamping to the torque limits with a report of which joints were
//! clamped.

use std::time::Duration;

use protocol::TorqueCommand;
use thiserror::Error;

/// Why a command was refused. The command is dropped; nothing of it is applied.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CommandRejection {
    #[error("command for robot {got:?} received by robot {expected:?}")]
    WrongRobot { expected: String, got: String },
    #[error("command for tick {tick} is not newer than the last applied tick {last}")]
    Stale { tick: u64, last: u64 },
    #[error("command for tick {tick} is from the future (latest state is tick {latest})")]
    FromTheFuture { tick: u64, latest: u64 },
    #[error("command has {got} torques, the robot has {expected} actuated joints")]
    WrongSize { expected: usize, got: usize },
    #[error("command torque {index} is not finite ({value})")]
    NonFinite { index: usize, value: f64 },
    #[error(
        "command for tick {tick} is {age_us} us old by its stamp, the deadline is {max_us} us"
    )]
    TooOld { tick: u64, age_us: u64, max_us: u64 },
    #[error(
        "command for tick {tick} came after the state of tick {latest}: {} ticks old, at most \
         {max_ticks}",
        latest - tick
    )]
    Behind { tick: u64, latest: u64, max_ticks: u64 },
    #[error("command arrived before any state")]
    NoState,
    #[error(
        "command for tick {tick} was made before safe mode was entered at tick {entered}; safe \
         mode is left only on a fresh tick"
    )]
    BeforeSafeMode { tick: u64, entered: u64 },
    #[error(
        "command for tick {tick} refused: the robot fell at tick {fell} and is limp (restart the \
         agent once it stands)"
    )]
    Fallen { tick: u64, fell: u64 },
    #[error("undecodable command: {0}")]
    Undecodable(String),
}

#[derive(Debug, Clone, Copy)]
struct SeenState {
    tick: u64,
    stamp_ns: u64,
}

/// Tick and age bookkeeping plus the limits: accepts or refuses commands, clamps accepted ones.
#[derive(Debug, Clone)]
pub struct CommandGate {
    robot: String,
    limits: Vec<f64>,
    max_age: Duration,
    max_age_ticks: u64,
    latest: Option<SeenState>,
    last_applied_tick: Option<u64>,
    clamped: Vec<usize>,
    delay: u64,
}

impl CommandGate {
    /// A gate for robot `robot` with one symmetric torque limit per actuated joint (use
    /// `f64::INFINITY` for none), a maximum command age in state ticks and one by the stamps.
    pub fn new(robot: &str, limits: Vec<f64>, max_age_ticks: u64, max_age: Duration) -> Self {
        let n = limits.len();
        CommandGate {
            robot: robot.to_string(),
            limits,
            max_age,
            max_age_ticks,
            latest: None,
            last_applied_tick: None,
            clamped: Vec::with_capacity(n),
            delay: 0,
        }
    }

    /// Commands apply `ticks` state ticks after the state they answer (the team's delay): a
    /// command of tick k is checked and applied as the command of tick k + `ticks`.
    pub fn with_delay(mut self, ticks: u64) -> Self {
        self.delay = ticks;
        self
    }

    /// The team's delay in use, state ticks: the newest command's (before the first, the
    /// configured one).
    pub fn delay(&self) -> u64 {
        self.delay
    }

    /// From now on, commands apply `ticks` state ticks after their state (the team's delay
    /// of the newest command, `crate::core`); commands already waiting apply by it too.
    pub fn set_delay(&mut self, ticks: u64) {
        self.delay = ticks;
    }

    /// The state tick at which a command of `tick` applies ([`CommandGate::with_delay`]).
    pub fn applies_at(&self, tick: u64) -> u64 {
        tick.saturating_add(self.delay)
    }

    /// Number of actuated joints a command must have.
    pub fn joints(&self) -> usize {
        self.limits.len()
    }

    pub fn limits(&self) -> &[f64] {
        &self.limits
    }

    /// A state arrived. Returns false for a state older than the latest (out of order).
    pub fn on_state(&mut self, tick: u64, stamp_ns: u64) -> bool {
        match self.latest {
            Some(last) if tick < last.tick => false,
            Some(last) if tick == last.tick => true,
            _ => {
                self.latest = Some(SeenState { tick, stamp_ns });
                true
            }
        }
    }

    /// Tick of the latest state.
    pub fn latest_state_tick(&self) -> Option<u64> {
        self.latest.map(|s| s.tick)
    }

    pub fn last_applied_tick(&self) -> Option<u64> {
        self.last_applied_tick
    }

    /// Check `cmd`; on success write the (clamped) torques into `out` and return how many
    /// joints were clamped (their indices: [`CommandGate::clamped`]). The command does not
    /// become the last applied one until [`CommandGate::mark_applied`].
    ///
    /// Every tick here is the one the command applies at ([`CommandGate::applies_at`]).
    /// Age: the command's tick must be at most `max_age_ticks` behind the latest state's. The
    /// robot's ticks are its clock: in real time they pass at the robot's rate, so that this
    /// bounds the command's age in time; in lockstep no state comes while the team solves, and
    /// a command is as young as its state however long its solve took (a wall-clock age would
    /// refuse a slow first solve that the simulation waited for). When the sender stamped it
    /// (`stamp_ns > 0`), its stamp must also not be more than `max_age` older than the latest
    /// state's stamp (the state source's clock, which the team shares).
    pub fn check(
        &mut self,
        cmd: &TorqueCommand,
        out: &mut Vec<f64>,
    ) -> Result<usize, CommandRejection> {
        let (tick, latest) = self.check_order(cmd)?;
        self.check_torques(cmd)?;
        self.check_age(cmd, tick, latest)?;
        Ok(self.clamp_into(&cmd.tau, out))
    }

    /// Robot id, then the tick the command applies at: after a state, not from the future, not
    /// stale. Returns that tick and the latest state.
    fn check_order(&self, cmd: &TorqueCommand) -> Result<(u64, SeenState), CommandRejection> {
        let got = cmd.header.robot_id();
        if got != self.robot {
            return Err(CommandRejection::WrongRobot {
                expected: self.robot.clone(),
                got: got.to_string(),
            });
        }
        let latest = self.latest.ok_or(CommandRejection::NoState)?;
        let tick = self.applies_at(cmd.header.tick);
        if tick > latest.tick {
            return Err(CommandRejection::FromTheFuture { tick, latest: latest.tick });
        }
        if let Some(last) = self.last_applied_tick {
            if tick <= last {
                return Err(CommandRejection::Stale { tick, last });
            }
        }
        Ok((tick, latest))
    }

    /// One torque per actuated joint (none for a hold), every one finite.
    fn check_torques(&self, cmd: &TorqueCommand) -> Result<(), CommandRejection> {
        // A hold command carries no torques (the agent's own hold is applied).
        let expected = if cmd.hold { 0 } else { self.limits.len() };
        if cmd.tau.len() != expected {
            return Err(CommandRejection::WrongSize { expected, got: cmd.tau.len() });
        }
        if let Some(index) = cmd.tau.iter().position(|t| !t.is_finite()) {
            return Err(CommandRejection::NonFinite { index, value: cmd.tau[index] });
        }
        Ok(())
    }

    /// The age of the command applying at `tick`, in state ticks behind `latest` and, when
    /// stamped, by its stamp.
    fn check_age(
        &self,
        cmd: &TorqueCommand,
        tick: u64,
        latest: SeenState,
    ) -> Result<(), CommandRejection> {
        if latest.tick - tick > self.max_age_ticks {
            return Err(CommandRejection::Behind {
                tick,
                latest: latest.tick,
                max_ticks: self.max_age_ticks,
            });
        }
        if cmd.header.stamp_ns > 0 {
            let age_ns = latest.stamp_ns.saturating_sub(cmd.header.stamp_ns);
            if age_ns > self.max_age.as_nanos() as u64 {
                let (age_us, max_us) = (age_ns / 1000, self.max_age.as_micros() as u64);
                return Err(CommandRejection::TooOld { tick, age_us, max_us });
            }
        }
        Ok(())
    }

    /// `tau` clamped to the limits into `out`, the clamped joints' indices recorded; returns
    /// how many were clamped.
    fn clamp_into(&mut self, tau: &[f64], out: &mut Vec<f64>) -> usize {
        out.clear();
        self.clamped.clear();
        for (i, (&t, &l)) in tau.iter().zip(&self.limits).enumerate() {
            let c = t.clamp(-l, l);
            if c != t {
                self.clamped.push(i);
            }
            out.push(c);
        }
        self.clamped.len()
    }

    /// Indices of the joints clamped by the last successful [`CommandGate::check`].
    pub fn clamped(&self) -> &[usize] {
        &self.clamped
    }

    /// The checked command of `tick` was handed to the torque sink.
    pub fn mark_applied(&mut self, tick: u64) {
        self.last_applied_tick = Some(tick);
    }
}

/// Clamp `tau` in place to `±limits`; returns how many entries changed.
pub fn clamp_to_limits(tau: &mut [f64], limits: &[f64]) -> usize {
    let mut n = 0;
    for (t, &l) in tau.iter_mut().zip(limits) {
        let c = t.clamp(-l, l);
        n += (c != *t) as usize;
        *t = c;
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::Header;

    fn cmd(robot: &str, tick: u64, tau: Vec<f64>) -> TorqueCommand {
        TorqueCommand {
            header: Header::new("t", Some(robot), tick, 0),
            tau,
            hold: false,
            delay_ticks: 0,
            qdd: Vec::new(),
        }
    }

    #[test]
    fn gate_checks_robot_tick_size_finiteness_age_and_clamps() {
        let mut g = CommandGate::new("r1", vec![10.0, 10.0, 2.0], 3, Duration::from_millis(25));
        let mut out = Vec::new();
        assert_eq!(g.check(&cmd("r1", 0, vec![0.0; 3]), &mut out), Err(CommandRejection::NoState));
        assert!(g.on_state(5, 1_000_000_000));
        assert!(matches!(
            g.check(&cmd("r2", 5, vec![0.0; 3]), &mut out),
            Err(CommandRejection::WrongRobot { .. })
        ));
        assert!(matches!(
            g.check(&cmd("r1", 6, vec![0.0; 3]), &mut out),
            Err(CommandRejection::FromTheFuture { .. })
        ));
        assert!(matches!(
            g.check(&cmd("r1", 5, vec![0.0; 4]), &mut out),
            Err(CommandRejection::WrongSize { .. })
        ));
        assert!(matches!(
            g.check(&cmd("r1", 5, vec![0.0, f64::NAN, 0.0]), &mut out),
            Err(CommandRejection::NonFinite { index: 1, .. })
        ));
        // Stamped 30 ms before the latest state: too old by the shared clock.
        let mut stamped = cmd("r1", 5, vec![0.0; 3]);
        stamped.header.stamp_ns = 1_000_000_000 - 30_000_000;
        assert_eq!(
            g.check(&stamped, &mut out),
            Err(CommandRejection::TooOld { tick: 5, age_us: 30_000, max_us: 25_000 })
        );
        assert_eq!(g.check(&cmd("r1", 5, vec![12.0, -3.0, -2.5]), &mut out), Ok(2));
        assert_eq!(out, vec![10.0, -3.0, -2.0]);
        assert_eq!(g.clamped(), &[0, 2]);
        g.mark_applied(5);
        assert!(matches!(
            g.check(&cmd("r1", 5, vec![0.0; 3]), &mut out),
            Err(CommandRejection::Stale { .. })
        ));
        assert!(g.on_state(6, 1_005_000_000));
        assert!(!g.on_state(4, 0), "out-of-order state accepted");
        assert_eq!(g.check(&cmd("r1", 6, vec![1.0; 3]), &mut out), Ok(0));
        assert!(g.clamped().is_empty());
    }

    /// Age in ticks: 3 ticks behind the latest state is the limit, 4 is refused, however long
    /// (in time) the command took.
    #[test]
    fn a_command_is_as_old_as_the_states_that_came_after_it() {
        let mut g = CommandGate::new("r1", vec![10.0; 3], 3, Duration::from_millis(25));
        let mut out = Vec::new();
        assert!(g.on_state(14, 0));
        assert_eq!(
            g.check(&cmd("r1", 10, vec![0.0; 3]), &mut out),
            Err(CommandRejection::Behind { tick: 10, latest: 14, max_ticks: 3 })
        );
        assert_eq!(g.check(&cmd("r1", 11, vec![0.0; 3]), &mut out), Ok(0));
        let msg = CommandRejection::Behind { tick: 10, latest: 14, max_ticks: 3 }.to_string();
        assert!(msg.contains("4 ticks old, at most 3"), "{msg}");
    }
}
