//! The agent's logic without I/O: [`AgentCore`].
//!
//! The core owns the robot's dynamics source, the command gate, the watchdog and posture hold,
//! the contact set and the status. Each input is a method call with the time it arrived
//! (`now`; the core never reads a clock):
//!
//! - [`AgentCore::start`], once, after the caller can send: the description, the status.
//! - [`AgentCore::on_state`], a measured state: terms to publish; hold torques in safe mode;
//!   limp torques once fallen ([`crate::fall`]).
//! - [`AgentCore::on_command`], a torque command: checked, clamped torques to apply.
//! - [`AgentCore::on_contacts`], a contact set: nothing (scheduled for its tick, see
//!   [`crate::contact_switch`]).
//! - [`AgentCore::on_timer`], housekeeping, a few times per deadline: hold torques on entering
//!   safe mode, status, description.
//! - [`AgentCore::on_coordinator`], the coordinator appeared (liveliness): the description; the
//!   latest terms again.
//! - [`AgentCore::on_coordinator_lost`], the coordinator's token went (liveliness): nothing;
//!   safe mode follows from [`AgentCore::on_timer`] if it is not back within
//!   [`AgentConfig::coordinator_grace`].
//!
//! Each returns [`Outputs`]: references into the core's preallocated buffers that the caller
//! stamps (`header.stamp_ns`) and sends or applies, in the field order, then reports back with
//! [`AgentCore::sent`] (for the latencies and counters) and, if `status` is set, publishes
//! [`AgentCore::status`]. The robot's loop ([`crate::hardware::driver`], for a simulated robot
//! and a real one alike) is the caller; tests drive the core tick by tick.

use std::time::{Duration, Instant};

use protocol::{
    AgentMode, AgentStatus, DriveCommand, DynamicsTerms, Header, RobotDescription, RobotState,
    TorqueCommand,
};
use thiserror::Error;

use crate::contact_switch::{ContactSwitch, SwitchConfig};
use crate::delay::{AdaptiveDelay, TeamDelay};
use crate::drive_gains::{self, DriveGains, DriveGainsMode};
use crate::dynamics_source::DynamicsSource;
use crate::early_commands::{EarlyCommands, KeepOutcome};
use crate::fall::{Fall, FallDetector, FallLimits};
use crate::gate::{CommandGate, CommandRejection};
use crate::safe_mode::{
    CommandDeadline, HoldGains, PostureHold, Takeover, Watchdog, FIRST_COMMAND,
};
use crate::status::{AgentCounters, StatusBoard};
use crate::terms::{empty_terms, ActiveContacts};

/// Identity and timing of an agent. The robot itself (size, limits, frames) comes from its
/// [`DynamicsSource`].
#[derive(Debug, Clone)]
pub struct AgentConfig {
    pub team: String,
    pub robot: String,
    /// Without a valid command for this long (ticks or time) the agent enters safe mode.
    pub deadline: CommandDeadline,
    /// The first command's deadline, from the first state (see [`Watchdog`]); default
    /// [`FIRST_COMMAND`].
    pub first_command: CommandDeadline,
    /// A command more state ticks behind the latest state than this is refused (see
    /// [`CommandGate::check`]); default the deadline's ticks.
    pub max_command_age_ticks: u64,
    /// A stamped command older than this by the team's clock is refused.
    pub max_command_age: Duration,
    /// Gains of the posture hold; default [`HoldGains::from_torque_limits`].
    pub hold_gains: Option<HoldGains>,
    /// Status is published this often, and on every mode change.
    pub status_period: Duration,
    /// The robot description is published at start and this often.
    pub description_period: Duration,
    /// How contact sets are switched (touchdown force, feet kept down).
    pub contacts: SwitchConfig,
    /// Robot time over which commands take over from the posture hold (bumpless transfer,
    /// [`Takeover`]) when they follow it: after safe mode, or after the coordinator's hold orders;
    /// and over which the hold takes over from the last command when it follows commands.
    pub takeover: Duration,
    /// When the robot counts as fallen ([`crate::fall`]).
    pub fall: FallLimits,
    /// How long the coordinator's liveliness token may be gone before the agent holds its
    /// posture (unless the command deadline comes first); default [`COORDINATOR_GRACE`].
    pub coordinator_grace: Duration,
    /// The gains sent with each command ([`crate::drive_gains`]); default none (the torque).
    pub drive_gains: DriveGainsMode,
    /// The team answers every this many state ticks (its rate is the robot's divided by it;
    /// default 1). Between, the agent answers each state alone with the last command's torque
    /// and, with drive gains, the reference at that state. The tick deadline and the
    /// maximum command age in ticks count team ticks (this many state ticks each).
    pub team_every: u64,
    /// The team's delay in state ticks (default 0, at most [`MAX_TEAM_DELAY`]), or `auto`:
    /// from 0, changed from the latency the agent measures ([`crate::delay`]). The command for
    /// the state of tick k applies at the state of tick k + the delay, so that the team has
    /// that many robot periods to answer. The states before the first command can apply are
    /// answered with gravity compensation and the hold's damping; between team commands, and
    /// for a state whose command the team skipped, the agent answers alone as with
    /// [`AgentConfig::team_every`].
    pub team_delay: TeamDelay,
    /// How long after a state the robot's drives take its answer (default `None`: they wait
    /// for it, as the lockstep simulator does). With `auto`, a command at delay 0 that comes
    /// later than this after its state counts as late ([`crate::delay`]).
    pub answer_within: Option<Duration>,
}

pub use crate::delay::MAX_TEAM_DELAY;

impl AgentConfig {
    /// Defaults: deadline 5 ticks or 25 ms, the first command within 2 s, maximum command age
    /// 5 ticks (25 ms by a stamp), status every 100 ms, description every second, takeover from
    /// the hold over 100 ms.
    pub fn new(team: &str, robot: &str) -> Self {
        let deadline = CommandDeadline::default();
        AgentConfig {
            team: team.to_string(),
            robot: robot.to_string(),
            max_command_age: deadline.time.unwrap_or(Duration::from_millis(25)),
            max_command_age_ticks: deadline.ticks,
            first_command: FIRST_COMMAND,
            deadline,
            hold_gains: None,
            status_period: Duration::from_millis(100),
            description_period: Duration::from_secs(1),
            contacts: SwitchConfig::default(),
            takeover: DEFAULT_TAKEOVER,
            fall: FallLimits::default(),
            coordinator_grace: COORDINATOR_GRACE,
            drive_gains: DriveGainsMode::None,
            team_every: 1,
            team_delay: TeamDelay::default(),
            answer_within: None,
        }
    }

    /// Set the time deadline and the maximum command age together (the `--command-deadline-ms`
    /// flag).
    pub fn with_deadline_time(mut self, d: Duration) -> Self {
        self.deadline.time = Some(d);
        self.max_command_age = d;
        self
    }

    /// Set the tick deadline and the maximum command age in ticks together (the
    /// `--command-deadline-ticks` flag; 0: neither).
    pub fn with_deadline_ticks(mut self, ticks: u64) -> Self {
        self.deadline.ticks = ticks;
        self.max_command_age_ticks = if ticks == 0 { u64::MAX } else { ticks };
        self
    }

    /// How often the caller should call [`AgentCore::on_timer`]: a fifth of the time deadline,
    /// between 1 and 20 ms (20 ms without a time deadline).
    pub fn housekeeping_period(&self) -> Duration {
        self.deadline
            .time
            .map_or(Duration::from_millis(20), |d| d / 5)
            .clamp(Duration::from_millis(1), Duration::from_millis(20))
    }
}

/// [`AgentConfig::takeover`] by default: 100 ms, a tenth of the robot's slowest task
/// impedance period, long against a torque step, short against a fall.
pub const DEFAULT_TAKEOVER: Duration = Duration::from_millis(100);

/// [`AgentConfig::coordinator_grace`] by default: 100 ms, as the coordinator's own
/// `DEPARTURE_GRACE` for a robot's token. A link to the coordinator that drops and comes back
/// withdraws and declares its token again within a few milliseconds (Zenoh's first reconnect
/// attempt is at 50 ms); the robot rides through it on its commands instead of entering the
/// hold and blending back. A coordinator that is really gone sends no commands either: in real
/// time the command deadline (25 ms by default) puts the agent in safe mode first; in lockstep,
/// where that deadline is 20 s and the simulation waits for the robots, the grace does.
pub const COORDINATOR_GRACE: Duration = Duration::from_millis(100);

/// How far ahead of the latest state a command may be and still wait for its state: in real
/// time the coordinator answers a tick with a late member's latest terms, and that member's
/// command can overtake the state of its tick on the way (or the agent is still busy with the
/// previous one). Further ahead (beyond the team's delay, [`AgentConfig::team_delay`]), it is
/// refused as from the future.
pub const EARLY_TICKS: u64 = 4;

/// A configuration the core cannot run with.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CoreError {
    #[error("agent configuration: {0}")]
    Config(String),
}

/// Why a state was dropped. It is counted (`states_rejected`) and logged by the core.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum StateRejection {
    #[error("dropped state: {0}")]
    Undecodable(String),
    #[error("dropped state of another robot ({got:?})")]
    OtherRobot { got: String },
    #[error(
        "dropped state of tick {tick} with {got} joint positions or velocities, the robot has \
         {expected} joints"
    )]
    WrongSize { tick: u64, expected: usize, got: usize },
    #[error("dropped out-of-order state of tick {tick} (latest {latest:?})")]
    OutOfOrder { tick: u64, latest: Option<u64> },
    #[error(
        "dropped state of tick {tick} with {got} foot forces, the robot has {expected} feet \
         (or none measured)"
    )]
    WrongFootForces { tick: u64, expected: usize, got: usize },
}

/// Why a contact set was refused. It is counted (`contacts_rejected`) and logged by the core;
/// the contact set stays as it was.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ContactRejection {
    #[error("undecodable contact set: {0}")]
    Undecodable(String),
    #[error("contact set for robot {got:?} received by robot {robot:?}")]
    OtherRobot { robot: String, got: String },
    #[error("unknown foot frame(s) {unknown:?}; this robot's feet are {feet:?}")]
    UnknownFeet { unknown: Vec<String>, feet: Vec<String> },
    #[error("contact set of tick {tick} refused: {capacity} sets are already scheduled")]
    ScheduleFull { tick: u64, capacity: usize },
}

/// What the caller sends or applies after a core call, in this order: publish `terms` on the
/// robot's `dynamics` key, `description` on its `description` key, apply `torques` (a checked
/// command or the posture hold; the caller stamps each before sending), then publish
/// [`AgentCore::status`] if `status` is set, and withdraw the robot's team membership if
/// `leave_team` is set. The status comes last and is fetched then because it carries the
/// latency of the terms the caller has just published.
#[derive(Debug, Default)]
pub struct Outputs<'a> {
    pub terms: Option<&'a mut DynamicsTerms>,
    pub description: Option<&'a mut RobotDescription>,
    /// The drive command to apply: `tau_ff` the checked torques or the hold's; a command
    /// carries the drive gains and its reference when [`AgentConfig::drive_gains`] has them.
    pub drive: Option<&'a mut DriveCommand>,
    /// Publish the status: the mode changed, or its period is due.
    pub status: bool,
    /// The robot fell at this state ([`crate::fall`]): leave the team (once).
    pub leave_team: bool,
}

/// What the caller did with [`Outputs`], reported back with [`AgentCore::sent`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Sent {
    /// When the terms had been published (for the state-to-dynamics latency).
    pub terms_at: Option<Instant>,
    /// The description was published.
    pub description: bool,
}

/// Which torques a call yields (and which the agent applied last).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Apply {
    Nothing,
    /// The command just checked (in `torques`).
    Command,
    /// The posture hold at the latest state.
    Hold,
    /// No command can apply yet ([`AgentConfig::team_delay`]): gravity compensation with
    /// damping at the latest state, which the first command follows without a blend.
    Start,
    /// Between team ticks, or for a state whose team command was skipped
    /// ([`AgentCore::skipped`]): the last command's torque with the reference at the latest
    /// state ([`AgentConfig::team_every`]).
    Servo,
    /// Joint damping only: the robot fell ([`crate::fall`]).
    Limp,
}

/// The agent's decisions, without I/O. See the module documentation for the calls.
pub struct AgentCore<S: DynamicsSource> {
    team: String,
    robot: String,
    source: S,
    joints: usize,
    feet: Vec<String>,
    gate: CommandGate,
    watchdog: Watchdog,
    hold: PostureHold,
    fall: FallDetector,
    /// Commands following the hold blend in from it.
    takeover: Takeover,
    /// The hold following commands blends in from the last of them (`entry_from`).
    entry: Takeover,
    entry_from: Vec<f64>,
    /// What the agent applied last: a command or its own hold (a servo tick leaves it at the
    /// command).
    last_applied: Apply,
    /// The hold torques as they apply now ([`AgentCore::hold_now`]).
    hold_tau: Vec<f64>,
    /// The last command's torque as applied (after clamping and blending), for the load the
    /// hold carries ([`PostureHold::hold_carrying`]).
    last_command: Vec<f64>,
    /// Robot time of the latest accepted state, s.
    state_time: f64,
    /// What drive commands' references are carried from ([`drive_gains::Reference`]).
    reference: drive_gains::Reference,
    /// How long a drive command stays valid after the state it answers: the command deadline
    /// ([`AgentCore::valid_until`]).
    validity: CommandDeadline,
    /// Every how many state ticks the team answers (a team tick); the states between are
    /// answered by the agent alone ([`Apply::Servo`]).
    team_every: u64,
    /// The team's delay this robot asks for ([`AgentConfig::team_delay`]), sent with its terms.
    delay: AdaptiveDelay,
    /// The tick of the newest command that came (the delay follows no older one).
    newest_command: Option<u64>,
    contacts: ContactSwitch,
    terms: DynamicsTerms,
    drive: DriveCommand,
    /// Commands that came before the state they apply at (see [`EARLY_TICKS`] and
    /// [`AgentConfig::team_delay`]); each is checked when that state arrives, from `due`.
    early: EarlyCommands,
    due: TorqueCommand,
    /// The state tick the agent last answered alone ([`Apply::Servo`]).
    servo_tick: Option<u64>,
    description: Option<RobotDescription>,
    q: Vec<f64>,
    qdot: Vec<f64>,
    gravity: Vec<f64>,
    counters: AgentCounters,
    board: StatusBoard,
    /// Arrival of the latest accepted state, for the state-to-dynamics latency.
    state_at: Option<Instant>,
    /// Tick and publication time of the latest terms, for the dynamics-to-command latency.
    last_dynamics: Option<(u64, Instant)>,
    status_period: Duration,
    description_period: Duration,
    last_status: Option<Instant>,
    last_description: Option<Instant>,
    /// When the coordinator's token went, while it is gone ([`AgentCore::on_coordinator_lost`]).
    coordinator_lost: Option<Instant>,
    /// Stamp and hold flag of the command applied last (its tick is the gate's): to tell a
    /// copy of it.
    applied: (u64, bool),
    coordinator_grace: Duration,
    /// How often [`AgentCore::on_timer`] is due ([`AgentConfig::housekeeping_period`]).
    housekeeping: Duration,
    drive_gains: DriveGainsMode,
    /// The gains sent with commands, once made from the first terms ([`DriveGainsMode::Inertia`]).
    gains: Option<DriveGains>,
}

/// Room for early commands: for the longest delay the team may come to (another robot may ask
/// for more).
const EARLY_ROOM: u64 = EARLY_TICKS + MAX_TEAM_DELAY + 1;

/// The posture-hold gains (`cfg.hold_gains`, or from the torque limits), checked against the
/// number of joints as the torque limits are.
fn checked_hold_gains(
    cfg: &AgentConfig,
    joints: usize,
    limits: &[f64],
) -> Result<HoldGains, CoreError> {
    if limits.len() != joints {
        return Err(CoreError::Config(format!(
            "{} torque limits for {joints} joints",
            limits.len()
        )));
    }
    let gains = cfg.hold_gains.clone().unwrap_or_else(|| HoldGains::from_torque_limits(limits));
    if gains.kp.len() != joints || gains.kd.len() != joints {
        return Err(CoreError::Config(format!(
            "posture-hold gains have {} kp and {} kd for {joints} joints",
            gains.kp.len(),
            gains.kd.len()
        )));
    }
    Ok(gains)
}

/// Checks the team's rate and the team's delay.
fn check_timing(cfg: &AgentConfig) -> Result<(), CoreError> {
    if cfg.team_every == 0 {
        return Err(CoreError::Config("the team must answer every 1 or more ticks, not 0".into()));
    }
    if cfg.team_delay.max() > MAX_TEAM_DELAY {
        return Err(CoreError::Config(format!(
            "a team delay of {} ticks: at most {MAX_TEAM_DELAY}",
            cfg.team_delay
        )));
    }
    Ok(())
}

/// The command gate of `cfg.robot`, at the team's initial delay.
fn command_gate(cfg: &AgentConfig, limits: Vec<f64>) -> CommandGate {
    // Tick deadlines count the team's ticks: a command comes every `team_every` states.
    CommandGate::new(
        &cfg.robot,
        limits,
        cfg.max_command_age_ticks.saturating_mul(cfg.team_every),
        cfg.max_command_age,
    )
    .with_delay(cfg.team_delay.initial())
}

/// The watchdog, its tick deadline counted in state ticks (`team_every` per team tick).
fn watchdog(cfg: &AgentConfig) -> Watchdog {
    Watchdog::new(
        CommandDeadline {
            ticks: cfg.deadline.ticks.saturating_mul(cfg.team_every),
            ..cfg.deadline
        },
        cfg.first_command,
    )
}

/// The contact switch, every one of the `feet` in stance and the hand in its grasp.
fn contact_switch(cfg: &AgentConfig, feet: usize) -> ContactSwitch {
    ContactSwitch::new(
        cfg.contacts.clone(),
        ActiveContacts { stance: vec![true; feet], hand_in_grasp: true },
    )
}

/// An empty torque command of `robot`, with room for `joints` torques and accelerations.
fn empty_command(team: &str, robot: &str, joints: usize) -> TorqueCommand {
    TorqueCommand {
        header: Header::new(team, Some(robot), 0, 0),
        tau: Vec::with_capacity(joints),
        hold: false,
        delay_ticks: 0,
        qdd: Vec::with_capacity(joints),
    }
}

impl<S: DynamicsSource> AgentCore<S> {
    /// A core for `cfg.robot` over `source`. Every per-tick buffer is allocated here.
    pub fn new(cfg: &AgentConfig, source: S) -> Result<Self, CoreError> {
        let joints = source.joints();
        let limits = source.torque_limits();
        let gains = checked_hold_gains(cfg, joints, &limits)?;
        check_timing(cfg)?;
        Ok(Self::assemble(cfg, source, joints, limits, gains))
    }

    /// The core before any input, its buffers sized for `joints` (a checked configuration).
    fn assemble(
        cfg: &AgentConfig,
        source: S,
        joints: usize,
        limits: Vec<f64>,
        gains: HoldGains,
    ) -> Self {
        let (team, robot) = (cfg.team.as_str(), cfg.robot.as_str());
        let feet: Vec<String> = source.foot_frames().to_vec();
        AgentCore {
            team: team.to_string(),
            robot: robot.to_string(),
            description: source.description(team, robot),
            joints,
            gate: command_gate(cfg, limits.clone()),
            watchdog: watchdog(cfg),
            fall: FallDetector::new(cfg.fall),
            hold: PostureHold::new(gains, limits),
            takeover: Takeover::new(cfg.takeover),
            entry: Takeover::new(cfg.takeover),
            entry_from: Vec::with_capacity(joints),
            last_applied: Apply::Nothing,
            hold_tau: Vec::with_capacity(joints),
            last_command: Vec::with_capacity(joints),
            state_time: 0.0,
            reference: drive_gains::Reference::new(joints),
            validity: cfg.deadline,
            team_every: cfg.team_every,
            delay: AdaptiveDelay::new(cfg.team_delay, cfg.answer_within),
            newest_command: None,
            contacts: contact_switch(cfg, feet.len()),
            feet,
            terms: empty_terms(team, robot),
            drive: DriveCommand::torque(team, robot, 0, Vec::with_capacity(joints)),
            early: EarlyCommands::new(team, robot, joints, EARLY_ROOM as usize),
            due: empty_command(team, robot, joints),
            servo_tick: None,
            q: vec![0.0; joints],
            qdot: vec![0.0; joints],
            gravity: vec![0.0; joints],
            counters: AgentCounters::default(),
            board: StatusBoard::new(team, robot).with_team_delay(cfg.team_delay.initial()),
            state_at: None,
            last_dynamics: None,
            status_period: cfg.status_period,
            description_period: cfg.description_period,
            last_status: None,
            last_description: None,
            coordinator_lost: None,
            applied: (0, false),
            coordinator_grace: cfg.coordinator_grace,
            housekeeping: cfg.housekeeping_period(),
            drive_gains: cfg.drive_gains,
            gains: None,
            source,
        }
    }

    /// The agent has joined its team: publish the description (if the source has one) and the
    /// first status.
    pub fn start(&mut self, now: Instant) -> Outputs<'_> {
        self.last_description = Some(now);
        self.last_status = Some(now);
        Outputs { description: self.description.as_mut(), status: true, ..Outputs::default() }
    }

    /// A measured state arrived at `now`: checks (robot id, size, order), the terms for the
    /// current contact set, the watchdog by ticks, and the posture hold while in safe mode.
    pub fn on_state(
        &mut self,
        state: &RobotState,
        now: Instant,
    ) -> Result<Outputs<'_>, StateRejection> {
        let mode_before = self.board.status.mode;
        let tick = state.header.tick;
        // The same state again (the lockstep bridge republishes while it waits for some robot's
        // torques): its terms go again only while it is unanswered, as in `on_coordinator`.
        let same_tick = self.gate.latest_state_tick() == Some(tick);
        let repeat = same_tick && !self.unanswered();
        if let Err(r) = self.admit_state(state) {
            self.counters.states_rejected += 1;
            tracing::warn!(robot = %self.robot, "{r}");
            return Err(r);
        }
        self.counters.states += 1;
        self.state_at = Some(now);
        self.delay.on_state(tick, now);
        self.state_time = state.time;
        self.watchdog.on_state(tick, now);
        self.q.copy_from_slice(&state.joint_positions);
        self.qdot.copy_from_slice(&state.joint_velocities);
        let team_tick = tick.is_multiple_of(self.team_every);
        if !same_tick {
            self.reference.on_state(state.time, &self.q, &self.qdot);
        }
        let fell = self.observe_fall(tick, state);
        if self.fall.fallen().is_some() {
            // No terms: the robot is out of the team.
            let out = self.outputs(now, mode_before, false, Apply::Limp, false);
            return Ok(Outputs { leave_team: fell, ..out });
        }
        self.switch_contacts(tick, &state.foot_forces);
        // Terms on team ticks only: the states between are the agent's own (`Apply::Servo`).
        let terms = team_tick && self.compute_terms(state);
        if let Some(apply) = self.early_command_due(tick, now) {
            return Ok(self.outputs(now, mode_before, terms, apply, false));
        }
        if self.watchdog.expired(tick, now) {
            self.enter_safe_mode_at(tick, "no valid command in time");
        }
        let apply = self.own_answer(tick);
        Ok(self.outputs(now, mode_before, terms && !repeat, apply, false))
    }

    /// Whether the robot fell at the state of `tick` (a floating base only): then it goes limp
    /// and its waiting commands are dropped.
    fn observe_fall(&mut self, tick: u64, state: &RobotState) -> bool {
        let fell = self
            .source
            .floating_base()
            .then(|| self.fall.observe(tick, &state.base_pose))
            .flatten();
        if let Some(f) = fell {
            self.board.status.mode = AgentMode::Fallen;
            self.early.clear();
            tracing::error!(
                robot = %self.robot,
                tick,
                tilt_deg = f.tilt.to_degrees(),
                height_m = f.height,
                "the robot fell: limp (joint damping only), commands refused, leaving the team"
            );
        }
        fell.is_some()
    }

    /// What the agent applies alone at the state of `tick` when no command is due: the hold in
    /// safe mode, the start torques before a command can apply, the last command's torque
    /// between team commands (or for a skipped one), else nothing.
    fn own_answer(&self, tick: u64) -> Apply {
        if self.watchdog.safe_mode_since().is_some() {
            Apply::Hold
        } else if tick < self.gate.delay() {
            Apply::Start
        } else if (!self.command_tick(tick) || self.skipped())
            && self.last_applied == Apply::Command
        {
            Apply::Servo
        } else {
            Apply::Nothing
        }
    }

    /// Whether a team command applies at the state of `tick`: the state of a team tick,
    /// [`AgentConfig::team_delay`] ticks later.
    fn command_tick(&self, tick: u64) -> bool {
        tick.checked_sub(self.gate.delay()).is_some_and(|k| k.is_multiple_of(self.team_every))
    }

    /// Whether the team's command for the latest state will not come (with a team delay): a
    /// newer one waits already, so the coordinator solved past it (real time catches up), and
    /// the agent answers the state alone instead of waiting out its deadline. Lockstep solves
    /// every tick and never gets here.
    fn skipped(&self) -> bool {
        let Some(tick) = self.gate.latest_state_tick() else { return false };
        let newer = self.early.newest_tick().is_some_and(|t| self.gate.applies_at(t) > tick);
        let answered_alone = self.servo_tick == Some(tick);
        self.gate.delay() > 0
            && self.command_tick(tick)
            && self.last_applied == Apply::Command
            && self.unanswered()
            && !answered_alone
            && newer
    }

    /// The terms (and the gravity the hold carries) at `state` for the current contact set;
    /// whether there are terms.
    fn compute_terms(&mut self, state: &RobotState) -> bool {
        let tick = state.header.tick;
        let terms = match self.source.compute(state, self.contacts.active(), &mut self.terms) {
            Ok(()) => {
                self.terms.header.tick = tick;
                self.terms.state_tick = tick;
                self.terms.team_delay_ticks = self.delay.ticks();
                self.terms.object_pose = state.object_pose;
                self.counters.dynamics += 1;
                self.make_gains(tick);
                true
            }
            Err(e) => {
                tracing::warn!(robot = %self.robot, tick, "no dynamics for this tick: {e}");
                false
            }
        };
        self.source.actuated_gravity(&mut self.gravity);
        terms
    }

    /// Whether the latest state still waits for its answer: no command applied for it, and not
    /// in safe mode (whose hold answers every state).
    fn unanswered(&self) -> bool {
        self.watchdog.safe_mode_since().is_none()
            && self.gate.last_applied_tick() != self.gate.latest_state_tick()
    }

    fn admit_state(&mut self, state: &RobotState) -> Result<(), StateRejection> {
        let tick = state.header.tick;
        if state.header.robot_id() != self.robot {
            return Err(StateRejection::OtherRobot { got: state.header.robot_id().to_string() });
        }
        for got in [state.joint_positions.len(), state.joint_velocities.len()] {
            if got != self.joints {
                return Err(StateRejection::WrongSize { tick, expected: self.joints, got });
            }
        }
        let (feet, got) = (self.feet.len(), state.foot_forces.len());
        if got != 0 && got != feet {
            return Err(StateRejection::WrongFootForces { tick, expected: feet, got });
        }
        if !self.gate.on_state(tick, state.header.stamp_ns) {
            return Err(StateRejection::OutOfOrder { tick, latest: self.gate.latest_state_tick() });
        }
        Ok(())
    }

    /// Something arrived where states come from that is not a state.
    pub fn on_undecodable_state(&mut self, reason: &str) {
        self.counters.states_rejected += 1;
        tracing::warn!(robot = %self.robot, "{}", StateRejection::Undecodable(reason.to_string()));
    }

    /// A torque command arrived at `now`: the gate's checks and clamping, then the watchdog
    /// (in safe mode only a command of a tick newer than the entry is admitted).
    ///
    /// A command up to [`EARLY_TICKS`] ahead of the latest state waits for the state of its
    /// tick (nothing is applied now): the coordinator answered its tick with this robot's
    /// latest terms before this robot had that tick's state.
    pub fn on_command(
        &mut self,
        cmd: &TorqueCommand,
        now: Instant,
    ) -> Result<Outputs<'_>, CommandRejection> {
        let mode_before = self.board.status.mode;
        if let Some(f) = self.fall.fallen() {
            let r = CommandRejection::Fallen { tick: cmd.header.tick, fell: f.tick };
            return Err(self.reject(r));
        }
        if cmd.header.robot_id() == self.robot {
            self.measure_delay(cmd.header.tick, now);
            self.follow_delay(cmd);
        }
        match self.admit_command(cmd, now) {
            Ok(Some(apply)) => Ok(self.outputs(now, mode_before, false, apply, false)),
            // KeepOutcome for a later state: the latest state's own command may be skipped.
            Ok(None) if self.skipped() => {
                Ok(self.outputs(now, mode_before, false, Apply::Servo, false))
            }
            Ok(None) => Ok(Outputs::default()),
            Err(r) => {
                // The very command applied last, again: the coordinator sent it again for
                // terms of the tick that crossed it (the lockstep bridge republishes states
                // while it waits). Refused and counted, but not worth a warning.
                let copy = matches!(r, CommandRejection::Stale { tick, last } if tick == last)
                    && self.applied == (cmd.header.stamp_ns, cmd.hold);
                Err(self.refuse(r, copy))
            }
        }
    }

    /// With `auto` ([`crate::delay`]): a command of `tick` arrived now; the delay this robot
    /// asks the team for, from the next terms on.
    fn measure_delay(&mut self, tick: u64, now: Instant) {
        let Some(latest) = self.gate.latest_state_tick() else { return };
        if let Some(d) = self.delay.on_command(tick, now) {
            tracing::info!(
                robot = %self.robot,
                tick,
                latest,
                delay = d,
                "asking the team for a delay of {d} ticks: commands came after the states they \
                 apply at (or after the answer window), or none would have for a while"
            );
        }
    }

    /// The team's delay is the newest command's: it applies to every command from now on, the
    /// waiting ones too (a longer one leaves a state without a team command, answered alone; a
    /// shorter one has two apply at one state, the newer winning).
    fn follow_delay(&mut self, cmd: &TorqueCommand) {
        let tick = cmd.header.tick;
        if self.newest_command.is_some_and(|n| tick < n) || cmd.delay_ticks > MAX_TEAM_DELAY {
            return;
        }
        self.newest_command = Some(tick);
        if cmd.delay_ticks != self.gate.delay() {
            tracing::info!(
                robot = %self.robot,
                tick,
                from = self.gate.delay(),
                to = cmd.delay_ticks,
                "the team's delay changed"
            );
            self.gate.set_delay(cmd.delay_ticks);
            self.board.status.team_delay_ticks = cmd.delay_ticks;
        }
    }

    /// The newest early command that applies at the state of `tick` (or an older one): checked
    /// now. Older due ones are superseded by it.
    fn early_command_due(&mut self, tick: u64, now: Instant) -> Option<Apply> {
        let gate = &self.gate;
        self.early.take_due(|t| gate.applies_at(t) <= tick, &mut self.due)?;
        // Taken out and put back: the gate reads it while the core changes (no allocation).
        let empty = TorqueCommand {
            header: Header { version: 0, team: String::new(), robot: None, tick: 0, stamp_ns: 0 },
            tau: Vec::new(),
            hold: false,
            delay_ticks: 0,
            qdd: Vec::new(),
        };
        let due = std::mem::replace(&mut self.due, empty);
        let admitted = self.admit_command(&due, now);
        self.due = due;
        match admitted {
            Ok(apply) => apply,
            Err(r) => {
                self.reject(r);
                None
            }
        }
    }

    /// Keep `cmd` until the state it applies at arrives; a command of the wrong size is
    /// refused now (the buffers never grow).
    fn keep_early(&mut self, cmd: &TorqueCommand) -> Result<(), CommandRejection> {
        let expected = if cmd.hold { 0 } else { self.joints };
        if cmd.tau.len() != expected {
            return Err(CommandRejection::WrongSize { expected, got: cmd.tau.len() });
        }
        if self.early.keep(cmd) == KeepOutcome::Dropped {
            tracing::debug!(
                robot = %self.robot,
                tick = cmd.header.tick,
                "an early command older than every waiting one: dropped"
            );
        }
        self.counters.early += 1;
        Ok(())
    }

    /// The gate's checks and the bookkeeping of an applied command; `None`: kept as early.
    fn admit_command(
        &mut self,
        cmd: &TorqueCommand,
        now: Instant,
    ) -> Result<Option<Apply>, CommandRejection> {
        let clamped = match self.gate.check(cmd, &mut self.drive.tau_ff) {
            Ok(n) => n,
            Err(CommandRejection::FromTheFuture { tick, latest })
                if tick <= latest + EARLY_TICKS + self.gate.delay() =>
            {
                self.keep_early(cmd)?;
                return Ok(None);
            }
            Err(r) => return Err(r),
        };
        let tick = self.gate.applies_at(cmd.header.tick);
        if let Err(entered) = self.watchdog.admits(tick) {
            return Err(CommandRejection::BeforeSafeMode { tick, entered });
        }
        self.drive.header.tick = tick;
        self.reference.on_command(&cmd.qdd);
        self.gate.mark_applied(tick);
        self.applied = (cmd.header.stamp_ns, cmd.hold);
        self.counters.applied += 1;
        if clamped > 0 {
            self.counters.clamped += 1;
            let (robot, joints, times) = (&self.robot, self.gate.clamped(), self.counters.clamped);
            if times.is_power_of_two() {
                tracing::warn!(
                    %robot,
                    tick,
                    ?joints,
                    times,
                    "command clamped to the torque limits"
                );
            } else {
                tracing::debug!(%robot, tick, ?joints, "command clamped to the torque limits");
            }
        }
        if let Some((t, at)) = self.last_dynamics {
            if t == cmd.header.tick {
                self.board.status.command_latency_us =
                    now.saturating_duration_since(at).as_secs_f64() * 1e6;
            }
        }
        if self.watchdog.on_applied(tick, now) {
            tracing::info!(
                robot = %self.robot,
                tick,
                "left safe mode: the coordinator commands again"
            );
        }
        self.board.status.mode = AgentMode::Commanded;
        // A hold order: this tick's torque is the agent's own posture hold.
        Ok(Some(if cmd.hold { Apply::Hold } else { Apply::Command }))
    }

    /// Something arrived on the command key that is not a command.
    pub fn on_undecodable_command(&mut self, reason: &str) -> CommandRejection {
        self.reject(CommandRejection::Undecodable(reason.to_string()))
    }

    fn reject(&mut self, r: CommandRejection) -> CommandRejection {
        self.refuse(r, false)
    }

    /// Count and log a refused command (`copy`: a copy of the one applied last, logged at
    /// debug only).
    fn refuse(&mut self, r: CommandRejection, copy: bool) -> CommandRejection {
        self.counters.rejected += 1;
        if copy {
            tracing::debug!(
                robot = %self.robot,
                "rejected command: {r} (a copy of the command applied)"
            );
        } else {
            tracing::warn!(robot = %self.robot, "rejected command: {r}");
        }
        self.board.status.last_rejection = Some(r.to_string());
        r
    }

    /// A contact set arrived: checked against this robot's id and feet, scheduled from its tick
    /// on (a past tick: from the next state on).
    pub fn on_contacts(&mut self, msg: &protocol::ContactSet) -> Result<(), ContactRejection> {
        let tick = msg.header.tick;
        let scheduled = self.contact_set(msg).and_then(|set| {
            tracing::debug!(
                robot = %self.robot,
                tick,
                stance = ?set.stance,
                hand_in_grasp = set.hand_in_grasp,
                "contact set scheduled"
            );
            self.contacts
                .schedule(tick, set)
                .map_err(|f| ContactRejection::ScheduleFull { tick: f.tick, capacity: f.capacity })
        });
        match scheduled {
            Ok(()) => {
                self.counters.contacts_applied += 1;
                Ok(())
            }
            Err(r) => Err(self.reject_contacts(r)),
        }
    }

    /// The contact sets due at the state of `tick`: lift-offs and force-confirmed touchdowns
    /// (see [`crate::contact_switch`]).
    fn switch_contacts(&mut self, tick: u64, foot_forces: &[f64]) {
        let ev = self.contacts.on_state(tick, foot_forces);
        self.counters.liftoffs += u64::from(ev.liftoffs);
        self.counters.touchdowns += u64::from(ev.touchdowns);
        if ev.deferred > 0 {
            self.counters.liftoffs_deferred += 1;
            if self.counters.liftoffs_deferred.is_power_of_two() {
                tracing::warn!(
                    robot = %self.robot,
                    tick,
                    "lift-off deferred: the foot is still loaded, or too few feet would stay on \
                     the ground"
                );
            }
        }
        if ev.changed() {
            tracing::info!(
                robot = %self.robot,
                tick,
                stance = ?self.contacts.active().stance,
                "contact set changed"
            );
        }
    }

    /// Something arrived on the contacts key that is not a contact set.
    pub fn on_undecodable_contacts(&mut self, reason: &str) -> ContactRejection {
        self.reject_contacts(ContactRejection::Undecodable(reason.to_string()))
    }

    fn reject_contacts(&mut self, r: ContactRejection) -> ContactRejection {
        self.counters.contacts_rejected += 1;
        tracing::warn!(robot = %self.robot, "rejected contact set: {r}");
        r
    }

    /// The contact set `msg` asks for, checked against this robot's id and feet.
    fn contact_set(&self, msg: &protocol::ContactSet) -> Result<ActiveContacts, ContactRejection> {
        if msg.header.robot_id() != self.robot {
            return Err(ContactRejection::OtherRobot {
                robot: self.robot.clone(),
                got: msg.header.robot_id().to_string(),
            });
        }
        let unknown: Vec<String> =
            msg.stance_feet.iter().filter(|f| !self.feet.contains(f)).cloned().collect();
        if !unknown.is_empty() {
            return Err(ContactRejection::UnknownFeet { unknown, feet: self.feet.clone() });
        }
        let stance = self.feet.iter().map(|f| msg.stance_feet.contains(f)).collect();
        Ok(ActiveContacts { stance, hand_in_grasp: msg.hand_in_grasp })
    }

    /// Housekeeping at `now`: the watchdog by time (entering safe mode yields the hold torques
    /// of the latest state), the periodic status and description.
    pub fn on_timer(&mut self, now: Instant) -> Outputs<'_> {
        let mode_before = self.board.status.mode;
        let mut apply = Apply::Nothing;
        if let Some(tick) = self.gate.latest_state_tick().filter(|_| self.fall.fallen().is_none()) {
            if self.watchdog.expired(tick, now) {
                self.enter_safe_mode_at(tick, "no valid command in time");
                apply = Apply::Hold;
            }
        }
        if self
            .coordinator_lost
            .take_if(|t| now.duration_since(*t) >= self.coordinator_grace)
            .is_some()
        {
            apply = match self.enter_hold("the coordinator left") {
                Apply::Nothing => apply,
                hold => hold,
            };
        }
        let status_due =
            self.last_status.is_none_or(|t| now.duration_since(t) >= self.status_period);
        if status_due {
            self.last_status = Some(now);
        }
        let description_due =
            self.last_description.is_none_or(|t| now.duration_since(t) >= self.description_period);
        if description_due {
            self.last_description = Some(now);
        }
        let mut out = self.outputs(now, mode_before, false, apply, description_due);
        out.status |= status_due;
        out
    }

    /// The coordinator appeared (it started, came back after a restart, or its link did): it
    /// needs this robot's description before it can command it, so it goes out now rather than
    /// at its next period.
    pub fn on_coordinator(&mut self, now: Instant) -> Outputs<'_> {
        tracing::info!(robot = %self.robot, "the coordinator is present");
        self.last_description = Some(now);
        self.coordinator_lost = None;
        // The latest terms go again while their state is unanswered: a link that dropped may
        // have lost them, and the tick waits for them (a coordinator that solved it already
        // sends its command again: it may be the command that was lost). Once the state is
        // answered (its command applied, or the hold in safe mode) nobody waits for them, and
        // a restarted coordinator would solve a tick the robots have passed.
        let again = self.unanswered()
            && self.fall.fallen().is_none()
            && self.counters.dynamics > 0
            && self.gate.latest_state_tick() == Some(self.terms.header.tick);
        Outputs {
            terms: again.then_some(&mut self.terms),
            description: self.description.as_mut(),
            ..Outputs::default()
        }
    }

    /// The coordinator's liveliness token went at `now`. Nothing changes yet: if it is not back
    /// ([`AgentCore::on_coordinator`]) within [`AgentConfig::coordinator_grace`], the next
    /// [`AgentCore::on_timer`] enters safe mode; with a zero grace this call does at once.
    pub fn on_coordinator_lost(&mut self, now: Instant) -> Outputs<'_> {
        if self.coordinator_grace.is_zero() {
            return self.enter_safe_mode("the coordinator left", now);
        }
        self.coordinator_lost.get_or_insert(now);
        tracing::warn!(
            robot = %self.robot,
            grace = ?self.coordinator_grace,
            "the coordinator's token went; holding posture unless it is back within the grace"
        );
        Outputs::default()
    }

    /// Enter safe mode now, for a reason outside the core (the hardware asked to deactivate or
    /// failed). Yields the hold torques of the latest state, if there is one; nothing if
    /// already in safe mode.
    pub fn enter_safe_mode(&mut self, why: &str, now: Instant) -> Outputs<'_> {
        let mode_before = self.board.status.mode;
        let apply = self.enter_hold(why);
        self.outputs(now, mode_before, false, apply, false)
    }

    /// Safe mode for `why`, unless already in it or fallen: the hold at the latest state
    /// ([`Apply::Hold`]), or, before any state, announced only ([`Apply::Nothing`]).
    fn enter_hold(&mut self, why: &str) -> Apply {
        if self.watchdog.safe_mode_since().is_some() || self.fall.fallen().is_some() {
            return Apply::Nothing;
        }
        match self.gate.latest_state_tick() {
            Some(tick) => {
                self.enter_safe_mode_at(tick, why);
                Apply::Hold
            }
            None => {
                // No state to hold: announce it; commands need a state anyway.
                self.watchdog.enter(0);
                self.counters.safe_mode_entries += 1;
                self.board.status.mode = AgentMode::SafeMode;
                tracing::warn!(robot = %self.robot, "entering safe mode before any state: {why}");
                Apply::Nothing
            }
        }
    }

    fn enter_safe_mode_at(&mut self, tick: u64, why: &str) {
        self.watchdog.enter(tick);
        self.latch_hold();
        self.counters.safe_mode_entries += 1;
        self.board.status.mode = AgentMode::SafeMode;
        tracing::warn!(robot = %self.robot, tick, "entering safe mode (posture hold): {why}");
    }

    /// The outputs of a call: the terms if computed, the torques to apply (the checked command,
    /// or the hold torques of the latest state), the description if due, the status if the mode
    /// changed.
    fn outputs(
        &mut self,
        now: Instant,
        mode_before: AgentMode,
        terms: bool,
        apply: Apply,
        description: bool,
    ) -> Outputs<'_> {
        let drive = self.fill_drive(apply);
        if drive {
            self.drive.valid_until = self.valid_until();
        }
        let status = self.board.status.mode != mode_before;
        if status {
            self.last_status = Some(now);
        }
        Outputs {
            terms: if terms { Some(&mut self.terms) } else { None },
            description: if description { self.description.as_mut() } else { None },
            drive: if drive { Some(&mut self.drive) } else { None },
            status,
            leave_team: false,
        }
    }

    /// The end of a drive command's validity: the latest state's time plus the command
    /// deadline (the shorter of its time and its ticks at the measured period), after which
    /// the agent would hold its posture. The drives count a step past it as a drive gap.
    fn valid_until(&self) -> Option<f64> {
        let by_time = self.validity.time.map(|d| d.as_secs_f64());
        let period = self.reference.period();
        let ticks = self.validity.ticks.saturating_mul(self.team_every);
        let by_ticks = (ticks > 0 && period > 0.0).then_some(ticks as f64 * period);
        let horizon = match (by_time, by_ticks) {
            (Some(a), Some(b)) => a.min(b),
            (a, b) => a.or(b)?,
        };
        Some(self.state_time + horizon)
    }

    /// Fill the drive command with the torques `apply` yields; whether there are any (none
    /// before the first state).
    fn fill_drive(&mut self, apply: Apply) -> bool {
        match apply {
            Apply::Nothing => false,
            Apply::Command => {
                self.take_over();
                self.last_applied = Apply::Command;
                self.last_command.clone_from(&self.drive.tau_ff);
                self.drive_targets();
                true
            }
            Apply::Servo => self.servo_drive(),
            Apply::Hold => self.enter_hold_drive(),
            Apply::Start => self.start_drive(),
            Apply::Limp => self.limp_drive(),
        }
    }

    /// Between team commands: the last command's torque with the reference at the latest state.
    fn servo_drive(&mut self) -> bool {
        let Some(tick) = self.gate.latest_state_tick() else { return false };
        self.servo_tick = Some(tick);
        self.drive.tau_ff.clone_from(&self.last_command);
        self.drive_targets();
        self.drive.header.tick = tick;
        true
    }

    /// The posture hold at the latest state, blending in from the last command if commands
    /// came before it.
    fn enter_hold_drive(&mut self) -> bool {
        let Some(tick) = self.gate.latest_state_tick() else { return false };
        if self.last_applied != Apply::Hold {
            // A hold order after commands holds the posture of now.
            self.latch_hold();
        }
        if self.last_applied == Apply::Command {
            // Entering the hold without a jump: from the last command applied.
            self.entry_from.clone_from(&self.last_command);
            self.entry.start(self.state_time);
        }
        self.takeover.cancel();
        self.hold_drive(tick);
        self.last_applied = Apply::Hold;
        true
    }

    /// Before a command can apply: gravity compensation with damping at the latest state.
    fn start_drive(&mut self) -> bool {
        let Some(tick) = self.gate.latest_state_tick() else { return false };
        self.hold.hold(&self.q);
        self.hold_drive(tick);
        true
    }

    /// The fallen robot: joint damping only.
    fn limp_drive(&mut self) -> bool {
        let Some(tick) = self.gate.latest_state_tick() else { return false };
        self.hold.damping(&self.qdot, &mut self.drive.tau_ff);
        self.torque_only();
        self.drive.header.tick = tick;
        self.last_applied = Apply::Limp;
        true
    }

    /// The drive gains from the first terms ([`DriveGainsMode::Inertia`]): each actuated
    /// joint's inertia is the mass matrix's diagonal at the state of `tick`.
    fn make_gains(&mut self, tick: u64) {
        if self.drive_gains != DriveGainsMode::Inertia || self.gains.is_some() {
            return;
        }
        let m = &self.terms.mass_matrix;
        let offset = m.rows().saturating_sub(self.joints);
        let inertia: Vec<f64> =
            (0..self.joints).map(|j| m.get(offset + j, offset + j).unwrap_or(f64::NAN)).collect();
        match DriveGains::from_inertia(&inertia, self.gate.limits()) {
            Ok(g) => {
                tracing::info!(
                    robot = %self.robot,
                    tick,
                    kp = ?g.kp,
                    kd = ?g.kd,
                    "drive gains from the joints' inertia"
                );
                self.gains = Some(g);
            }
            Err(e) => {
                tracing::error!(
                    robot = %self.robot,
                    tick,
                    "no drive gains, the drives get torques only: {e}"
                );
                self.drive_gains = DriveGainsMode::None;
            }
        }
    }

    /// The drive command's gains and reference ([`drive_gains::Reference`]); none without
    /// gains.
    fn drive_targets(&mut self) {
        let Some(g) = &self.gains else {
            return self.torque_only();
        };
        self.reference.fill_trajectory(&mut self.drive);
        self.drive.kp.clone_from(&g.kp);
        self.drive.kd.clone_from(&g.kd);
    }

    /// The drive command of `tick` is the hold's torques at the latest state, without gains.
    fn hold_drive(&mut self, tick: u64) {
        self.hold_now();
        self.drive.tau_ff.clone_from(&self.hold_tau);
        self.torque_only();
        self.drive.header.tick = tick;
        self.counters.hold_torques += 1;
    }

    /// The drive command is its torque: no gains, no reference (the hold and the limp robot,
    /// which the agent answers at every state).
    fn torque_only(&mut self) {
        self.drive.q_des.clear();
        self.drive.qd_des.clear();
        self.drive.qdd_des.clear();
        self.drive.ref_time = None;
        self.drive.kp.clear();
        self.drive.kd.clear();
    }

    /// The gains sent with commands, once made.
    pub fn drive_gains(&self) -> Option<&DriveGains> {
        self.gains.as_ref()
    }

    /// Hold the posture of now, carrying the last command's load if a command was the last
    /// torque applied (after a hold, the load that hold carried).
    fn latch_hold(&mut self) {
        match self.last_applied {
            Apply::Command | Apply::Servo => {
                self.hold.hold_carrying(&self.q, &self.last_command, &self.gravity)
            }
            Apply::Hold => self.hold.move_to(&self.q),
            Apply::Nothing | Apply::Start | Apply::Limp => self.hold.hold(&self.q),
        }
    }

    /// The posture hold as it applies at the latest state, into `hold_tau`: the hold law, still
    /// blending in from the last command while its entry lasts.
    fn hold_now(&mut self) {
        self.hold.torques(&self.q, &self.qdot, &self.gravity, &mut self.hold_tau);
        self.entry.blend(self.state_time, &self.entry_from, &mut self.hold_tau);
    }

    /// A command about to be applied takes over from the hold without a jump: a command that
    /// follows the hold starts the blend ([`Takeover`]), and while it lasts the command is
    /// blended with the hold torques of the latest state.
    fn take_over(&mut self) {
        if self.last_applied == Apply::Hold {
            self.takeover.start(self.state_time);
            tracing::info!(
                robot = %self.robot,
                tick = self.drive.header.tick,
                over_s = self.takeover.duration(),
                "commands take over from the posture hold"
            );
        }
        if self.takeover.active() {
            self.hold_now();
            self.takeover.blend(self.state_time, &self.hold_tau, &mut self.drive.tau_ff);
            self.counters.blended += 1;
        }
    }

    /// The caller has sent the outputs of the last call.
    pub fn sent(&mut self, sent: &Sent) {
        if let Some(done) = sent.terms_at {
            if let Some(at) = self.state_at {
                self.board.status.dynamics_latency_us = done.duration_since(at).as_secs_f64() * 1e6;
            }
            self.last_dynamics = Some((self.terms.header.tick, done));
        }
        if sent.description {
            self.counters.descriptions += 1;
        }
    }

    /// The status, brought up to date (counters, latest state tick, last applied tick); the
    /// caller stamps and publishes it.
    pub fn status(&mut self) -> &mut AgentStatus {
        self.board.refresh(
            &self.counters,
            self.gate.latest_state_tick(),
            self.gate.last_applied_tick(),
        )
    }

    /// How often the caller should call [`AgentCore::on_timer`].
    pub fn housekeeping_period(&self) -> Duration {
        self.housekeeping
    }

    pub fn team(&self) -> &str {
        &self.team
    }

    pub fn robot(&self) -> &str {
        &self.robot
    }

    /// Actuated joints.
    pub fn joints(&self) -> usize {
        self.joints
    }

    pub fn mode(&self) -> AgentMode {
        self.board.status.mode
    }

    pub fn counters(&self) -> &AgentCounters {
        &self.counters
    }

    /// The contact set the next terms are computed for.
    pub fn contacts(&self) -> &ActiveContacts {
        self.contacts.active()
    }

    /// The robot description the agent publishes, if its source has a model.
    pub fn description(&self) -> Option<&RobotDescription> {
        self.description.as_ref()
    }

    /// The fall, once the robot fell ([`crate::fall`]): the agent is limp and out of the team.
    pub fn fallen(&self) -> Option<&Fall> {
        self.fall.fallen()
    }

    /// Latest state tick at safe-mode entry, if in safe mode.
    pub fn safe_mode_since(&self) -> Option<u64> {
        self.watchdog.safe_mode_since()
    }

    pub fn latest_state_tick(&self) -> Option<u64> {
        self.gate.latest_state_tick()
    }

    /// The team's delay in use, state ticks (the newest command's).
    pub fn team_delay(&self) -> u64 {
        self.gate.delay()
    }

    /// The team's delay this robot asks for in its terms, state ticks.
    pub fn wanted_delay(&self) -> u64 {
        self.delay.ticks()
    }

    pub fn last_applied_tick(&self) -> Option<u64> {
        self.gate.last_applied_tick()
    }

    pub fn source(&self) -> &S {
        &self.source
    }
}
