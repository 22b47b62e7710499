//! The robot's loop: the one loop that drives a robot, simulated or real, through its
//! [`RobotHardware`]. Each turn:
//!
//! 1. the robot's state, when it is due: every period of the loop's clock
//!    ([`ReadTiming::Period`]: a real robot's drives, the mock; the loop numbers the tick and
//!    stamps its time), or as the robot sends it ([`ReadTiming::Robot`]: a simulator, in lockstep
//!    or real time, whose states carry their own tick and time). `read`, then
//!    [`AgentCore::on_state`] and the terms out ([`TeamLink::send_terms`]);
//! 2. the commands that have arrived ([`AgentCore::on_command`]), the contact sets
//!    ([`AgentCore::on_contacts`]) and the coordinator's comings and goings
//!    ([`AgentCore::on_coordinator`], [`AgentCore::on_coordinator_lost`]: safe mode if it is not
//!    back within the core's grace);
//! 3. housekeeping when due ([`AgentCore::on_timer`]: the watchdog by time, status,
//!    description);
//! 4. wait until the next state is due or anything arrives ([`TeamLink::wait`]; a robot that
//!    sends its states rings the same [`super::Bell`]).
//!
//! A drive command is written ([`RobotHardware::write`]) as soon as the core gives one (a
//! team command, the posture hold of safe mode, the limp drives of a fall). A
//! [`ReadTiming::Period`] robot is also written after every read, with the latest command (as a
//! ros2_control loop writes every cycle; a command is a trajectory, so writing it again
//! changes nothing), whether or not its team's answer to the previous state has come: two
//! writes a cycle when the team answers, one when it does not. Nothing is written before the
//! first command or safe mode.
//!
//! Every wait is bounded: the loop's wait (a period, or the housekeeping period), and Zenoh
//! puts (per the link's QoS: the simulated robot's agent blocks under congestion, as lockstep
//! needs). The loop stops when `stop` is set: within a period, or for a robot that sends its
//! states at its next state or housekeeping, and at once when the bell is rung with it
//! (`agent::AgentThread::stop` does); when the hardware asks to deactivate (safe mode, then
//! [`DriverExit::Deactivated`]); and when it fails (safe mode, then [`DriverError::Hardware`]).
//! While `stall` is set (a fault injector's hook) it handles nothing and stays a member, as a
//! hung process would. Run it on a thread of its own, outside any async runtime.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use protocol::{DriveCommand, Header, Pose, RobotState, Validate};
use thiserror::Error;

use super::link::{Inbound, Presence, TeamLink, INBOX};
use super::{HardwareError, HwStatus, ReadTiming, RobotHardware};
use crate::core::{AgentCore, Outputs, Sent};
use crate::dynamics_source::DynamicsSource;
use crate::status::AgentCounters;

/// ReadTiming of the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DriverConfig {
    /// The robot's cycle (1 ms for a 1 kHz robot) for a [`ReadTiming::Period`] robot; a
    /// [`ReadTiming::Robot`] robot sets its own pace and this is not used.
    pub period: Duration,
}

impl DriverConfig {
    pub fn new(period: Duration) -> Self {
        DriverConfig { period }
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
    run_stallable(core, hardware, link, cfg, stop, &AtomicBool::new(false))
}

/// [`run`], stalled while `stall` is set: alive (a member of its team) but handling nothing,
/// as a hung process would be. A fault injector's hook (`launch::faults`); a separate process
/// is stalled with SIGSTOP instead.
pub fn run_stallable<S: DynamicsSource, H: RobotHardware, L: TeamLink>(
    core: &mut AgentCore<S>,
    hardware: &mut H,
    link: &mut L,
    cfg: &DriverConfig,
    stop: &AtomicBool,
    stall: &AtomicBool,
) -> Result<DriverReport, DriverError> {
    if hardware.joints() != core.joints() {
        return Err(DriverError::JointCount { hardware: hardware.joints(), model: core.joints() });
    }
    if hardware.timing() == ReadTiming::Period && cfg.period.is_zero() {
        return Err(DriverError::Config("the period must be positive".into()));
    }
    hardware.configure().map_err(|source| DriverError::Lifecycle { op: "configure", source })?;
    hardware.activate().map_err(|source| DriverError::Lifecycle { op: "activate", source })?;
    let mut d = Driver::new(core, hardware, link, cfg);
    let result = d.turns(stop, stall);
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
    tracing::info!(robot = %d.core.robot(), ?report, "robot loop stopped");
    Ok(report)
}

/// The loop's state.
struct Driver<'a, S: DynamicsSource, H, L> {
    core: &'a mut AgentCore<S>,
    hardware: &'a mut H,
    link: &'a mut L,
    cfg: DriverConfig,
    timing: ReadTiming,
    state: RobotState,
    out: Written,
    /// States read so far.
    tick: u64,
    overruns: u64,
    /// When the next state is due ([`ReadTiming::Period`]) and the next housekeeping.
    next_read: Instant,
    next_housekeeping: Instant,
}

/// The drive command this loop writes, and the link's failures.
struct Written {
    drive: DriveCommand,
    /// A command has been given.
    have: bool,
    /// It is to be written now.
    fresh: bool,
    link_errors: u64,
}

/// What a step of the loop asks of it: go on, or stop (the hardware asked to deactivate).
type Step = Result<Option<DriverExit>, DriverError>;

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
            fresh: false,
            link_errors: 0,
        };
        let timing = hardware.timing();
        let now = Instant::now();
        Driver {
            core,
            hardware,
            link,
            cfg: *cfg,
            timing,
            state,
            out,
            tick: 0,
            overruns: 0,
            next_read: now,
            next_housekeeping: now,
        }
    }

    fn turns(&mut self, stop: &AtomicBool, stall: &AtomicBool) -> Result<DriverExit, DriverError> {
        let start = Instant::now();
        let out = self.core.start(start);
        let status = send(self.link, &mut self.out, out);
        self.done(status);
        // What is already there first: a coordinator present is known before the first terms
        // go out (else they would be sent it again, as unanswered).
        if let Some(exit) = self.inbound()? {
            return Ok(exit);
        }
        (self.next_read, self.next_housekeeping) = (start, start);
        while !stop.load(Ordering::Acquire) {
            if stall.load(Ordering::Acquire) {
                self.stalled(stop, stall);
                continue;
            }
            if let Some(exit) = self.turn(start)? {
                return Ok(exit);
            }
        }
        Ok(DriverExit::Stopped)
    }

    /// One turn: the robot's state if due, what the team sent, housekeeping if due, the wait.
    fn turn(&mut self, start: Instant) -> Step {
        if let Some(exit) = self.states(start)? {
            return Ok(Some(exit));
        }
        if let Some(exit) = self.inbound()? {
            return Ok(Some(exit));
        }
        let now = Instant::now();
        if now >= self.next_housekeeping {
            self.next_housekeeping = now + self.core.housekeeping_period();
            let out = self.core.on_timer(now);
            let status = send(self.link, &mut self.out, out);
            self.done(status);
            if let Some(exit) = self.write_fresh()? {
                return Ok(Some(exit));
            }
        }
        let wake = match self.timing {
            ReadTiming::Period => self.next_read.min(self.next_housekeeping),
            ReadTiming::Robot => self.next_housekeeping,
        };
        self.link.wait(wake);
        Ok(None)
    }

    /// The states due: one per period ([`ReadTiming::Period`], counting the cycles that ended
    /// after the next was due), or those the robot has sent ([`ReadTiming::Robot`], at most
    /// [`INBOX`] a turn).
    fn states(&mut self, start: Instant) -> Step {
        if self.timing == ReadTiming::Robot {
            for _ in 0..INBOX {
                if !self.hardware.state_ready() {
                    break;
                }
                if let Some(exit) = self.cycle(Instant::now(), start)? {
                    return Ok(Some(exit));
                }
            }
            return Ok(None);
        }
        let now = Instant::now();
        if now < self.next_read {
            return Ok(None);
        }
        let exit = self.cycle(now, start)?;
        self.next_read += self.cfg.period;
        let end = Instant::now();
        if self.next_read < end {
            self.overruns += 1;
            self.next_read = end;
        }
        Ok(exit)
    }

    /// The stall: nothing handled until it ends (or the loop stops), the membership kept.
    fn stalled(&mut self, stop: &AtomicBool, stall: &AtomicBool) {
        tracing::warn!(robot = %self.core.robot(), "stalled: handling nothing, still a member");
        while stall.load(Ordering::Acquire) && !stop.load(Ordering::Acquire) {
            std::thread::sleep(Duration::from_millis(1));
        }
        tracing::warn!(robot = %self.core.robot(), "stall over");
        self.next_read = Instant::now();
    }

    /// One state: read it, hand it to the core, send what the core returns and write the
    /// drives.
    fn cycle(&mut self, now: Instant, start: Instant) -> Step {
        let tick = self.tick;
        let status = self.hardware.read(now, &mut self.state);
        self.tick += 1;
        match status {
            HwStatus::Ok => {}
            HwStatus::Unreadable => {
                self.core.on_undecodable_state("the robot's reading was unusable");
                return Ok(None);
            }
            HwStatus::Error | HwStatus::Deactivate => return self.halt(status, "read", tick),
        }
        if self.timing == ReadTiming::Period {
            self.state.header.tick = tick;
            self.state.header.stamp_ns = protocol::wall_clock_ns();
            self.state.time = now.duration_since(start).as_secs_f64();
        }
        match self.state.validate() {
            Ok(()) => self.on_state(now),
            Err(e) => self.core.on_undecodable_state(&e.to_string()),
        }
        // A robot on the loop's clock is written every cycle: the latest command again.
        if self.timing == ReadTiming::Period && self.out.have {
            self.out.fresh = true;
        }
        self.write_fresh()
    }

    /// A valid state to the core, its outputs out; a robot that fell leaves the team.
    fn on_state(&mut self, now: Instant) {
        let Ok(out) = self.core.on_state(&self.state, now) else { return };
        let leave = out.leave_team;
        let status = send(self.link, &mut self.out, out);
        self.done(status);
        // The robot fell: limp, and out of the team (crate::fall).
        if leave {
            if let Err(e) = self.link.leave_team() {
                tracing::warn!(robot = %self.core.robot(), "leaving the team after the fall: {e}");
            }
        }
    }

    /// Write the drive command the core just gave, if it gave one.
    fn write_fresh(&mut self) -> Step {
        if !std::mem::take(&mut self.out.fresh) {
            return Ok(None);
        }
        match self.hardware.write(&self.out.drive) {
            HwStatus::Ok | HwStatus::Unreadable => Ok(None),
            status => self.halt(status, "write", self.tick.saturating_sub(1)),
        }
    }

    /// What the team sent: commands (each drive written at once), contact sets, the
    /// coordinator's comings and goings, at most [`INBOX`] of each.
    fn inbound(&mut self) -> Step {
        for _ in 0..INBOX {
            match self.link.try_recv_command() {
                Inbound::Message(cmd) => {
                    if let Ok(out) = self.core.on_command(&cmd, Instant::now()) {
                        let status = send(self.link, &mut self.out, out);
                        self.done(status);
                    }
                    if let Some(exit) = self.write_fresh()? {
                        return Ok(Some(exit));
                    }
                }
                Inbound::Undecodable(reason) => {
                    self.core.on_undecodable_command(&reason);
                }
                Inbound::Empty => break,
            }
        }
        self.contacts();
        self.coordinator();
        self.write_fresh()
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
        w.fresh = true;
    }
    (sent, out.status)
}

fn link_error(w: &mut Written, what: &str, e: &dyn std::fmt::Display) {
    w.link_errors += 1;
    if w.link_errors.is_power_of_two() {
        tracing::warn!(times = w.link_errors, "{what} not sent: {e}");
    }
}
