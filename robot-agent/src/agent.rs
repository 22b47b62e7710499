//! The agent loop: state in, dynamics terms out; command in, checked torques out; watchdog,
//! safe mode, contact set, status and description.
//!
//! One job per module: [`crate::source`] (where states come from), [`crate::sink`] (where
//! torques go), [`crate::dynamics_source`] (state to terms), [`crate::gate`] (command checks
//! and clamping), [`crate::safe_mode`] (watchdog and posture hold), [`crate::status`] (status
//! message and counters). This module only wires them together on a Zenoh session.

use std::time::{Duration, Instant};

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, TransportError, TypedPublisher};
use protocol::{AgentMode, AgentStatus, DynamicsTerms, Header, RobotDescription, TorqueCommand};
use thiserror::Error;
use tokio::sync::watch;
use zenoh::Session;

pub use crate::dynamics_source::{DynamicsSource, ModelDynamics, PlaceholderDynamics, SourceError};
pub use crate::gate::{CommandGate, CommandRejection};
pub use crate::safe_mode::{CommandDeadline, HoldGains, PostureHold, Watchdog};
pub use crate::sink::{TorqueSink, ZenohTorqueSink};
pub use crate::source::{StateEvent, StateSource, ZenohStateSource};
pub use crate::status::AgentCounters;
use crate::status::StatusBoard;
use crate::terms::{empty_terms, ContactSet};

/// Errors that stop the agent.
#[derive(Debug, Error)]
pub enum AgentError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Protocol(#[from] protocol::ProtocolError),
    #[error("agent configuration: {0}")]
    Config(String),
}

/// Identity and timing of an agent. The robot itself (size, limits, frames) comes from its
/// [`DynamicsSource`].
#[derive(Debug, Clone)]
pub struct AgentConfig {
    pub team: String,
    pub robot: String,
    /// Without a valid command for this long (ticks or time) the agent enters safe mode.
    pub deadline: CommandDeadline,
    /// A command older than this is refused (see [`CommandGate::check`]).
    pub max_command_age: Duration,
    /// Gains of the posture hold; default [`HoldGains::from_torque_limits`].
    pub hold_gains: Option<HoldGains>,
    /// Status is published this often, and on every mode change.
    pub status_period: Duration,
    /// The robot description is published at start and this often.
    pub description_period: Duration,
}

impl AgentConfig {
    /// Defaults: deadline 5 ticks or 25 ms, maximum command age 25 ms, status every 100 ms,
    /// description every second.
    pub fn new(team: &str, robot: &str) -> Self {
        let deadline = CommandDeadline::default();
        AgentConfig {
            team: team.to_string(),
            robot: robot.to_string(),
            max_command_age: deadline.time.unwrap_or(Duration::from_millis(25)),
            deadline,
            hold_gains: None,
            status_period: Duration::from_millis(100),
            description_period: Duration::from_secs(1),
        }
    }

    /// Set the time deadline and the maximum command age together (the `--command-deadline-ms`
    /// flag).
    pub fn with_deadline_time(mut self, d: Duration) -> Self {
        self.deadline.time = Some(d);
        self.max_command_age = d;
        self
    }
}

/// Run the agent on the Zenoh state source and torque sink of `cfg.robot` until `stop` turns
/// true (or its sender is dropped).
pub async fn run(
    session: &Session,
    cfg: AgentConfig,
    source: impl DynamicsSource,
    stop: watch::Receiver<bool>,
) -> Result<AgentCounters, AgentError> {
    let states = ZenohStateSource::subscribe(session, &cfg.team, &cfg.robot).await?;
    let sink = ZenohTorqueSink::declare(session, &cfg.team, &cfg.robot).await?;
    run_with(session, cfg, source, states, sink, stop).await
}

/// The agent loop with any state source and torque sink; commands, contacts, dynamics, status
/// and description travel on `session`. Subscribes before it declares its membership so that
/// whoever sees it join can already reach it.
pub async fn run_with(
    session: &Session,
    cfg: AgentConfig,
    mut source: impl DynamicsSource,
    mut states: impl StateSource,
    mut sink: impl TorqueSink,
    mut stop: watch::Receiver<bool>,
) -> Result<AgentCounters, AgentError> {
    let (team, robot) = (cfg.team.as_str(), cfg.robot.as_str());
    let commands = transport::subscribe(session, keys::robot(team, robot, RobotTopic::Command)?).await?;
    let contacts_q = transport::subscribe(session, keys::contacts(team, robot)?).await?;
    let mut dynamics_pub: TypedPublisher<DynamicsTerms> =
        TypedPublisher::declare(session, keys::robot(team, robot, RobotTopic::Dynamics)?, Qos::HotPath).await?;
    let mut status_pub: TypedPublisher<AgentStatus> =
        TypedPublisher::declare(session, keys::robot(team, robot, RobotTopic::Status)?, Qos::Telemetry).await?;
    let mut description = source.description(team, robot);
    let mut description_pub = match &description {
        Some(_) => Some(
            TypedPublisher::<RobotDescription>::declare(session, keys::robot(team, robot, RobotTopic::Description)?, Qos::Telemetry)
                .await?,
        ),
        None => None,
    };

    let joints = source.joints();
    let limits = source.torque_limits();
    if limits.len() != joints {
        return Err(AgentError::Config(format!("{} torque limits for {joints} joints", limits.len())));
    }
    let gains = cfg.hold_gains.clone().unwrap_or_else(|| HoldGains::from_torque_limits(&limits));
    if gains.kp.len() != joints || gains.kd.len() != joints {
        return Err(AgentError::Config(format!(
            "posture-hold gains have {} kp and {} kd for {joints} joints",
            gains.kp.len(),
            gains.kd.len()
        )));
    }
    let feet: Vec<String> = source.foot_frames().to_vec();
    let mut gate = CommandGate::new(robot, limits.clone(), cfg.max_command_age);
    let mut watchdog = Watchdog::new(cfg.deadline);
    let mut hold = PostureHold::new(gains, limits);
    let mut contacts = ContactSet { stance: vec![true; feet.len()], hand_in_grasp: true };
    let mut terms = empty_terms(team, robot);
    let mut torques = TorqueCommand { header: Header::new(team, Some(robot), 0, 0), tau: Vec::with_capacity(joints) };
    let mut q = vec![0.0; joints];
    let mut qdot = vec![0.0; joints];
    let mut gravity = vec![0.0; joints];
    let mut counters = AgentCounters::default();
    let mut board = StatusBoard::new(team, robot);
    let mut last_dynamics: Option<(u64, Instant)> = None;

    let _token = transport::declare_member(session, team, robot).await?;
    tracing::info!(%robot, %team, joints, deadline = ?cfg.deadline, max_command_age = ?cfg.max_command_age, "agent joined the team");
    if let (Some(p), Some(d)) = (description_pub.as_mut(), description.as_mut()) {
        publish_description(p, d, &mut counters).await;
    }
    let mut last_description = Instant::now();
    let mut last_status = Instant::now();
    publish_status(&mut status_pub, &mut board, &counters, &gate).await;

    // Housekeeping (watchdog by time, periodic status and description): a fifth of the time
    // deadline, between 1 and 20 ms.
    let period = cfg.deadline.time.map_or(Duration::from_millis(20), |d| d / 5).clamp(Duration::from_millis(1), Duration::from_millis(20));
    let mut housekeeping = tokio::time::interval(period);
    housekeeping.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);

    loop {
        let mode_before = board.status.mode;
        // Set when safe mode is entered: publish the hold torques of the latest tick.
        let mut hold_now = false;
        tokio::select! {
            r = stop.changed() => { if r.is_err() || *stop.borrow() { break; } }
            ev = states.next() => {
                let state = match ev {
                    StateEvent::State(s) => s,
                    StateEvent::Invalid(reason) => {
                        counters.states_rejected += 1;
                        tracing::warn!(%robot, "dropped state: {reason}");
                        continue;
                    }
                    StateEvent::Closed => break,
                };
                let now = Instant::now();
                let tick = state.header.tick;
                if state.header.robot_id() != robot {
                    counters.states_rejected += 1;
                    tracing::warn!(%robot, got = state.header.robot_id(), "dropped state of another robot");
                    continue;
                }
                if state.joint_positions.len() != joints {
                    counters.states_rejected += 1;
                    tracing::warn!(%robot, tick, "dropped state with {} joints, the robot has {joints}", state.joint_positions.len());
                    continue;
                }
                if !gate.on_state(tick, state.header.stamp_ns, now) {
                    counters.states_rejected += 1;
                    tracing::warn!(%robot, tick, latest = ?gate.latest_state_tick(), "dropped out-of-order state");
                    continue;
                }
                counters.states += 1;
                watchdog.on_state(tick, now);
                q.copy_from_slice(&state.joint_positions);
                qdot.copy_from_slice(&state.joint_velocities);
                match source.compute(&state, &contacts, &mut terms) {
                    Ok(()) => {
                        terms.header.tick = tick;
                        terms.header.stamp_ns = protocol::wall_clock_ns();
                        terms.state_tick = tick;
                        dynamics_pub.put(&terms).await?;
                        counters.dynamics += 1;
                        let done = Instant::now();
                        board.status.dynamics_latency_us = done.duration_since(now).as_secs_f64() * 1e6;
                        last_dynamics = Some((tick, done));
                    }
                    Err(e) => tracing::warn!(%robot, tick, "no dynamics for this tick: {e}"),
                }
                source.actuated_gravity(&mut gravity);
                if watchdog.expired(tick, now) {
                    enter_safe_mode(&mut watchdog, &mut hold, &q, tick, &mut counters, &mut board, "no valid command in time");
                }
                hold_now = watchdog.safe_mode_since().is_some();
            }
            c = commands.recv_async() => {
                let Ok(sample) = c else { break };
                let now = Instant::now();
                let cmd = match decode_sample::<TorqueCommand>(&sample) {
                    Ok(c) => c,
                    Err(e) => {
                        reject(&mut counters, &mut board, robot, CommandRejection::Undecodable(e.to_string()));
                        continue;
                    }
                };
                let clamped = match gate.check(&cmd, now, &mut torques.tau) {
                    Ok(n) => n,
                    Err(r) => { reject(&mut counters, &mut board, robot, r); continue; }
                };
                let tick = cmd.header.tick;
                if let Err(entered) = watchdog.admits(tick) {
                    reject(&mut counters, &mut board, robot, CommandRejection::BeforeSafeMode { tick, entered });
                    continue;
                }
                torques.header.tick = tick;
                torques.header.stamp_ns = protocol::wall_clock_ns();
                sink.apply(&torques).await?;
                gate.mark_applied(tick);
                counters.applied += 1;
                if clamped > 0 {
                    counters.clamped += 1;
                    if counters.clamped.is_power_of_two() {
                        tracing::warn!(%robot, tick, joints = ?gate.clamped(), times = counters.clamped, "command clamped to the torque limits");
                    } else {
                        tracing::debug!(%robot, tick, joints = ?gate.clamped(), "command clamped to the torque limits");
                    }
                }
                if let Some((t, at)) = last_dynamics {
                    if t == tick {
                        board.status.command_latency_us = now.saturating_duration_since(at).as_secs_f64() * 1e6;
                    }
                }
                if watchdog.on_applied(tick, now) {
                    tracing::info!(%robot, tick, "left safe mode: the coordinator commands again");
                }
                board.status.mode = AgentMode::Commanded;
            }
            c = contacts_q.recv_async() => {
                let Ok(sample) = c else { break };
                match contact_set(&sample, robot, &feet) {
                    Ok(set) => {
                        tracing::info!(%robot, stance = ?set.stance, hand_in_grasp = set.hand_in_grasp, "contact set changed");
                        contacts = set;
                        counters.contacts_applied += 1;
                    }
                    Err(reason) => {
                        counters.contacts_rejected += 1;
                        tracing::warn!(%robot, "rejected contact set: {reason}");
                    }
                }
            }
            _ = housekeeping.tick() => {
                let now = Instant::now();
                if let Some(tick) = gate.latest_state_tick() {
                    if watchdog.expired(tick, now) {
                        enter_safe_mode(&mut watchdog, &mut hold, &q, tick, &mut counters, &mut board, "no valid command in time");
                        hold_now = true;
                    }
                }
                if now.duration_since(last_status) >= cfg.status_period {
                    publish_status(&mut status_pub, &mut board, &counters, &gate).await;
                    last_status = now;
                }
                if now.duration_since(last_description) >= cfg.description_period {
                    if let (Some(p), Some(d)) = (description_pub.as_mut(), description.as_mut()) {
                        publish_description(p, d, &mut counters).await;
                    }
                    last_description = now;
                }
            }
        }
        if hold_now {
            if let Some(tick) = gate.latest_state_tick() {
                hold.torques(&q, &qdot, &gravity, &mut torques.tau);
                torques.header.tick = tick;
                torques.header.stamp_ns = protocol::wall_clock_ns();
                sink.apply(&torques).await?;
                counters.hold_torques += 1;
            }
        }
        if board.status.mode != mode_before {
            publish_status(&mut status_pub, &mut board, &counters, &gate).await;
            last_status = Instant::now();
        }
    }
    publish_status(&mut status_pub, &mut board, &counters, &gate).await;
    tracing::info!(%robot, ?counters, "agent stopped");
    Ok(counters)
}

fn enter_safe_mode(
    watchdog: &mut Watchdog,
    hold: &mut PostureHold,
    q: &[f64],
    tick: u64,
    counters: &mut AgentCounters,
    board: &mut StatusBoard,
    why: &str,
) {
    watchdog.enter(tick);
    hold.hold(q);
    counters.safe_mode_entries += 1;
    board.status.mode = AgentMode::SafeMode;
    tracing::warn!(robot = %board.status.header.robot_id(), tick, "entering safe mode (posture hold): {why}");
}

fn reject(counters: &mut AgentCounters, board: &mut StatusBoard, robot: &str, r: CommandRejection) {
    counters.rejected += 1;
    tracing::warn!(%robot, "rejected command: {r}");
    board.status.last_rejection = Some(r.to_string());
}

async fn publish_status(p: &mut TypedPublisher<AgentStatus>, board: &mut StatusBoard, c: &AgentCounters, gate: &CommandGate) {
    let status = board.refresh(c, gate.latest_state_tick(), gate.last_applied_tick());
    if let Err(e) = p.put(status).await {
        tracing::warn!("status not published: {e}");
    }
}

async fn publish_description(p: &mut TypedPublisher<RobotDescription>, d: &mut RobotDescription, c: &mut AgentCounters) {
    d.header.stamp_ns = protocol::wall_clock_ns();
    match p.put(d).await {
        Ok(()) => c.descriptions += 1,
        Err(e) => tracing::warn!("description not published: {e}"),
    }
}

/// The contact set a sample asks for, checked against this robot's id and feet.
fn contact_set(sample: &zenoh::sample::Sample, robot: &str, feet: &[String]) -> Result<ContactSet, String> {
    let msg: protocol::ContactSet = decode_sample(sample).map_err(|e| e.to_string())?;
    if msg.header.robot_id() != robot {
        return Err(format!("contact set for robot {:?} received by robot {robot:?}", msg.header.robot_id()));
    }
    let unknown: Vec<&str> = msg.stance_feet.iter().filter(|f| !feet.contains(f)).map(String::as_str).collect();
    if !unknown.is_empty() {
        return Err(format!("unknown foot frame(s) {unknown:?}; this robot's feet are {feet:?}"));
    }
    let stance = feet.iter().map(|f| msg.stance_feet.contains(f)).collect();
    Ok(ContactSet { stance, hand_in_grasp: msg.hand_in_grasp })
}
