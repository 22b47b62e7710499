//! The synchronous hardware loop: at the robot's rate, one cycle per tick,
//!
//! 1. `read` the robot ([`RobotHardware::read`]); the loop numbers the tick and stamps it;
//! 2. [`AgentCore::on_state`]; publish the terms ([`TeamLink::send_terms`], non-blocking);
//! 3. take the commands that have arrived, waiting at most [`DriverConfig::command_wait`] for
//!    this tick's, each through [`AgentCore::on_command`];
//! 4. take the contact sets that have arrived ([`AgentCore::on_contacts`]);
//! 5. take the coordinator's comings and goings ([`AgentCore::on_coordinator`],
//!    [`AgentCore::on_coordinator_lost`]: safe mode if it is not back within the core's grace,
//!    as in the async agent);
//! 6. housekeeping ([`AgentCore::on_timer`]: the watchdog by time, status, description);
//! 7. `write` the torques of this cycle ([`RobotHardware::write`]): the last applied command,
//!    or the posture hold in safe mode; a cycle without new torques writes the previous ones
//!    again (nothing is written before the first command or safe mode);
//! 8. sleep until the next period.
//!
//! Every wait is bounded: the command wait, the sleep (one period), Zenoh puts (they drop
//! under congestion instead of waiting). The loop stops when `stop` is set (within a period
//! plus the command wait), when the hardware asks to deactivate (safe mode, then
//! [`DriverExit::Deactivated`]) and when it fails (safe mode, then [`DriverError::Hardware`]).
//! Run it on a thread of its own, outside any async runtime.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use protocol::{DriveCommand, Header, Pose, RobotState, Validate};
use thiserror::Error;

use super::link::{Inbound, Presence, TeamLink, INBOX};
use super::{HardwareError, HwStatus, RobotHardware};
use crate::core::{AgentCore, Outputs, Sent};
use crate::dynamics_source::DynamicsSource;
use crate::status::AgentCounters;

/// Timing of the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DriverConfig {
    /// The robot's cycle (1 ms for a 1 kHz robot).
    pub period: Duration,
    /// After publishing a tick's terms, wait at most this long for that tick's command (0:
    /// take only what has already arrived). With a fast coordinator the command of a tick is
    /// then written in the same cycle; a late one is applied in a later cycle.
    pub command_wait: Duration,
}

impl DriverConfig {
    /// Period `period`, waiting up to half of it for each tick's command.
    pub fn new(period: Duration) -> Self {
        DriverConfig { period, command_wait: period / 2 }
    }
}

/// Why the loop ended without an error.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DriverExit {
    /// The stop flag was set.
    Stopped,
    /// The hardware asked to deactivate (its `read` or `write` returned
    /// [`HwStatus::Deactivate`] in the cycle of `tick`).
    Deactivated { tick: u64 },
}

/// What the loop did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DriverReport {
    pub exit: DriverExit,
    /// Cycles run (ticks read).
    pub cycles: u64,
    /// Cycles that ended after the next one was due.
    pub overruns: u64,
    /// Messages the link could not send (logged; the loop carries on).
    pub link_errors: u64,
    pub counters: AgentCounters,
}

/// Why the loop could not start or had to stop.
#[derive(Debug, Error)]
pub enum DriverError {
    #[error("the hardware has {hardware} joints, the robot's model {model}")]
    JointCount { hardware: usize, model: usize },
    #[error("driver configuration: {0}")]
    Config(String),
    #[error("hardware {op} failed: {source}")]
    Lifecycle { op: &'static str, source: HardwareError },
    #[error("hardware {op} failed at tick {tick}; safe mode entered and the hardware deactivated")]
    Hardware { op: &'static str, tick: u64 },
}

/// Run the loop until `stop` is set or the hardware stops it. Configures and activates the
/// hardware first, deactivates it at the end.
pub fn run<S: DynamicsSource, H: RobotHardware, L: TeamLink>(
    core: &mut AgentCore<S>,
    hardware: &mut H,
    link: &mut L,
    cfg: &DriverConfig,
    stop: &AtomicBool,
) -> Result<DriverReport, DriverError> {
    if hardware.joints() != core.joints() {
        return Err(DriverError::JointCount { hardware: hardware.joints(), model: core.joints() });
    }
    if cfg.period.is_zero() {
        return Err(DriverError::Config("the period must be positive".into()));
    }
    hardware.configure().map_err(|source| DriverError::Lifecycle { op: "configure", source })?;
    hardware.activate().map_err(|source| DriverError::Lifecycle { op: "activate", source })?;
    let mut d = Driver::new(core, hardware, link, cfg);
    let result = d.cycles(stop);
    if let Err(e) = d.hardware.deactivate() {
        tracing::warn!(robot = %d.core.robot(), "hardware deactivate failed: {e}");
    }
    d.publish_status();
    let report = DriverReport {
        exit: result?,
        cycles: d.tick,
        overruns: d.overruns,
        link_errors: d.out.link_errors,
        counters: d.core.counters().clone(),
    };
    tracing::info!(robot = %d.core.robot(), ?report, "hardware loop stopped");
    Ok(report)
}

/// The loop's state.
struct Driver<'a, S: DynamicsSource, H, L> {
    core: &'a mut AgentCore<S>,
    hardware: &'a mut H,
    link: &'a mut L,
    cfg: DriverConfig,
    state: RobotState,
    out: Written,
    /// Ticks read so far (the next tick's number).
    tick: u64,
    overruns: u64,
}

/// The drive command this loop writes, and the link's failures.
struct Written {
    drive: DriveCommand,
    have: bool,
    link_errors: u64,
}

impl<'a, S: DynamicsSource, H: RobotHardware, L: TeamLink> Driver<'a, S, H, L> {
    fn new(
        core: &'a mut AgentCore<S>,
        hardware: &'a mut H,
        link: &'a mut L,
        cfg: &DriverConfig,
    ) -> Self {
        let joints = core.joints();
        let state = RobotState {
            header: Header::new(core.team(), Some(core.robot()), 0, 0),
            base_pose: Pose::IDENTITY,
            base_twist: [0.0; 6],
            joint_positions: vec![0.0; joints],
            joint_velocities: vec![0.0; joints],
            time: 0.0,
            foot_forces: Vec::new(),
            object_pose: None,
        };
        let out = Written {
            drive: DriveCommand::torque(core.team(), core.robot(), 0, vec![0.0; joints]),
            have: false,
            link_errors: 0,
        };
        Driver { core, hardware, link, cfg: *cfg, state, out, tick: 0, overruns: 0 }
    }

    fn cycles(&mut self, stop: &AtomicBool) -> Result<DriverExit, DriverError> {
        let start = Instant::now();
        let out = self.core.start(start);
        let status = send(self.link, &mut self.out, out);
        self.done(status);
        let mut next = start;
        while !stop.load(Ordering::Acquire) {
            let now = Instant::now();
            if let Some(exit) = self.cycle(now, start)? {
                return Ok(exit);
            }
            next += self.cfg.period;
            let end = Instant::now();
            match next.checked_duration_since(end) {
                Some(left) => std::thread::sleep(left),
                None => {
                    self.overruns += 1;
                    next = end;
                }
            }
        }
        Ok(DriverExit::Stopped)
    }

    /// One tick; `Some` when the hardware asked to deactivate.
    fn cycle(&mut self, now: Instant, start: Instant) -> Result<Option<DriverExit>, DriverError> {
        let tick = self.tick;
        let status = self.hardware.read(now, &mut self.state);
        self.tick += 1;
        if status != HwStatus::Ok {
            return self.halt(status, "read", tick);
        }
        self.state.header.tick = tick;
        self.state.header.stamp_ns = protocol::wall_clock_ns();
        self.state.time = now.duration_since(start).as_secs_f64();
        match self.state.validate() {
            Ok(()) => {
                if let Ok(out) = self.core.on_state(&self.state, now) {
                    let leave = out.leave_team;
                    let status = send(self.link, &mut self.out, out);
                    self.done(status);
                    // The robot fell: limp, and out of the team (crate::fall).
                    if leave {
                        if let Err(e) = self.link.leave_team() {
                            tracing::warn!(
                                robot = %self.core.robot(),
                                "leaving the team after the fall: {e}"
                            );
                        }
                    }
                }
            }
            Err(e) => self.core.on_undecodable_state(&e.to_string()),
        }
        // A fallen robot takes no commands: nothing to wait for.
        let wait =
            if self.core.fallen().is_some() { Duration::ZERO } else { self.cfg.command_wait };
        self.commands(tick, now + wait);
        self.contacts();
        self.coordinator();
        let out = self.core.on_timer(Instant::now());
        let status = send(self.link, &mut self.out, out);
        self.done(status);
        if self.out.have {
            let status = self.hardware.write(&self.out.drive);
            if status != HwStatus::Ok {
                return self.halt(status, "write", tick);
            }
        }
        Ok(None)
    }

    /// The commands that arrive until `until` or until the command of `tick` is applied (at
    /// most [`INBOX`] of them).
    fn commands(&mut self, tick: u64, until: Instant) {
        for _ in 0..INBOX {
            if self.core.last_applied_tick() == Some(tick) {
                return;
            }
            match self.link.recv_command(until) {
                Inbound::Message(cmd) => {
                    if let Ok(out) = self.core.on_command(&cmd, Instant::now()) {
                        let status = send(self.link, &mut self.out, out);
                        self.done(status);
                    }
                }
                Inbound::Undecodable(reason) => {
                    self.core.on_undecodable_command(&reason);
                }
                Inbound::Empty => return,
            }
        }
    }

    /// The contact sets that have arrived (at most [`INBOX`]).
    fn contacts(&mut self) {
        for _ in 0..INBOX {
            match self.link.try_recv_contacts() {
                Inbound::Message(msg) => {
                    let _ = self.core.on_contacts(&msg);
                }
                Inbound::Undecodable(reason) => {
                    self.core.on_undecodable_contacts(&reason);
                }
                Inbound::Empty => return,
            }
        }
    }

    /// The coordinator's comings and goings that have arrived (at most [`INBOX`]): one that came
    /// gets the description (and the latest terms while they are unanswered), one that went
    /// starts the core's grace.
    fn coordinator(&mut self) {
        for _ in 0..INBOX {
            let now = Instant::now();
            let out = match self.link.try_recv_coordinator() {
                Some(Presence::Came) => self.core.on_coordinator(now),
                Some(Presence::Went) => self.core.on_coordinator_lost(now),
                None => return,
            };
            let status = send(self.link, &mut self.out, out);
            self.done(status);
        }
    }

    /// The hardware failed or asked to deactivate: safe mode (announced; the hold is not
    /// written to a hardware that refuses torques), then stop.
    fn halt(
        &mut self,
        status: HwStatus,
        op: &'static str,
        tick: u64,
    ) -> Result<Option<DriverExit>, DriverError> {
        let why = if status == HwStatus::Deactivate {
            "the hardware asked to deactivate"
        } else {
            "hardware failure"
        };
        tracing::warn!(robot = %self.core.robot(), tick, op, ?status, "{why}");
        let out = self.core.enter_safe_mode(why, Instant::now());
        let status_due = send(self.link, &mut self.out, out);
        self.done(status_due);
        match status {
            HwStatus::Deactivate => Ok(Some(DriverExit::Deactivated { tick })),
            _ => Err(DriverError::Hardware { op, tick }),
        }
    }

    /// Report what was sent to the core, then publish the status if it asked for it.
    fn done(&mut self, (sent, status): (Sent, bool)) {
        self.core.sent(&sent);
        if status {
            self.publish_status();
        }
    }

    fn publish_status(&mut self) {
        let status = self.core.status();
        status.header.stamp_ns = protocol::wall_clock_ns();
        if let Err(e) = self.link.send_status(status) {
            link_error(&mut self.out, "status", &e);
        }
    }
}

/// Stamp and send what the core returned; keep its torques for the write. Returns what was
/// sent and whether the status is due.
fn send<L: TeamLink>(link: &mut L, w: &mut Written, out: Outputs<'_>) -> (Sent, bool) {
    let mut sent = Sent::default();
    if let Some(terms) = out.terms {
        terms.header.stamp_ns = protocol::wall_clock_ns();
        match link.send_terms(terms) {
            Ok(()) => sent.terms_at = Some(Instant::now()),
            Err(e) => link_error(w, "dynamics terms", &e),
        }
    }
    if let Some(d) = out.description {
        d.header.stamp_ns = protocol::wall_clock_ns();
        match link.send_description(d) {
            Ok(()) => sent.description = true,
            Err(e) => link_error(w, "description", &e),
        }
    }
    if let Some(d) = out.drive {
        d.header.stamp_ns = protocol::wall_clock_ns();
        w.drive.clone_from(d);
        w.have = true;
    }
    (sent, out.status)
}

fn link_error(w: &mut Written, what: &str, e: &dyn std::fmt::Display) {
    w.link_errors += 1;
    if w.link_errors.is_power_of_two() {
        tracing::warn!(times = w.link_errors, "{what} not sent: {e}");
    }
}
