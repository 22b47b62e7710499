//! The Zenoh shell of the agent: it receives states, commands and contact sets, hands each to
//! the [`AgentCore`] with the time it arrived, and publishes or applies what the core returns.
//! Every decision (checks, watchdog, safe mode, contact set, status) is the core's.
//!
//! States come from a [`StateSource`] and torques go to a [`TorqueSink`] (the simulated robot
//! over Zenoh by default, [`crate::hardware::zenoh_sim`]); commands, contact sets, dynamics
//! terms, status and description travel on the session. A real robot with a synchronous driver
//! runs the same core in [`crate::hardware::driver`] instead.

use std::time::Instant;

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, TransportError, TypedPublisher};
use protocol::{AgentStatus, DynamicsTerms, RobotDescription, RobotState, TorqueCommand};
use thiserror::Error;
use tokio::sync::watch;
use zenoh::liveliness::LivelinessToken;
use zenoh::sample::Sample;
use zenoh::Session;

pub use crate::core::{AgentConfig, AgentCore, CoreError, Outputs, Sent};
pub use crate::dynamics_source::{DynamicsSource, ModelDynamics, PlaceholderDynamics, SourceError};
pub use crate::gate::{CommandGate, CommandRejection};
pub use crate::hardware::zenoh_sim::{
    StateEvent, StateSource, TorqueSink, ZenohStateSource, ZenohTorqueSink,
};
pub use crate::safe_mode::{CommandDeadline, HoldGains, PostureHold, Watchdog};
pub use crate::status::AgentCounters;

/// Errors that stop the agent.
#[derive(Debug, Error)]
pub enum AgentError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Protocol(#[from] protocol::ProtocolError),
    #[error(transparent)]
    Core(#[from] CoreError),
}

/// Run the agent on the Zenoh state source and torque sink of `cfg.robot` until `stop` turns
/// true (or its sender is dropped).
pub async fn run(
    session: &Session,
    cfg: AgentConfig,
    source: impl DynamicsSource,
    stop: watch::Receiver<bool>,
) -> Result<AgentCounters, AgentError> {
    let (_never, stall) = watch::channel(false);
    run_stallable(session, cfg, source, stop, stall).await
}

/// [`run`], stalled while `stall` is true: alive (its liveliness token held) but handling
/// nothing, as a hung process would be. A fault injector's hook (`launch::faults`); a
/// separate process is stalled with SIGSTOP instead.
pub async fn run_stallable(
    session: &Session,
    cfg: AgentConfig,
    source: impl DynamicsSource,
    stop: watch::Receiver<bool>,
    stall: watch::Receiver<bool>,
) -> Result<AgentCounters, AgentError> {
    let states = ZenohStateSource::subscribe(session, &cfg.team, &cfg.robot).await?;
    let sink = ZenohTorqueSink::declare(session, &cfg.team, &cfg.robot).await?;
    run_with(session, cfg, source, states, sink, stop, stall).await
}

/// The agent loop with any state source and torque sink; commands, contacts, dynamics, status
/// and description travel on `session`. Subscribes before it declares its membership so that
/// whoever sees it join can already reach it.
pub async fn run_with<S: DynamicsSource>(
    session: &Session,
    cfg: AgentConfig,
    source: S,
    mut states: impl StateSource,
    sink: impl TorqueSink,
    mut stop: watch::Receiver<bool>,
    mut stall: watch::Receiver<bool>,
) -> Result<AgentCounters, AgentError> {
    let mut core = AgentCore::new(&cfg, source)?;
    let (team, robot) = (cfg.team.as_str(), cfg.robot.as_str());
    let commands =
        transport::subscribe(session, keys::robot(team, robot, RobotTopic::Command)?).await?;
    let contacts = transport::subscribe(session, keys::contacts(team, robot)?).await?;
    let mut io = Io::declare(session, team, robot, core.description().is_some(), sink).await?;

    let coordinator = transport::watch_coordinator(session, team).await?;
    // Withdrawn when the robot falls ([`crate::fall`]): the coordinator then solves the team
    // without it.
    let mut token = Some(join_team(session, &cfg, &mut core, &mut io).await?);
    let mut housekeeping = housekeeping_timer(&cfg);

    loop {
        wait_out_stall(robot, &mut stop, &mut stall).await;
        tokio::select! {
            r = stop.changed() => { if r.is_err() || *stop.borrow() { break; } }
            r = stall.changed() => { if r.is_err() { break; } }
            ev = states.next() => {
                if !on_state_event(&mut core, &mut io, ev, robot, &mut token).await? { break; }
            }
            c = commands.recv_async() => {
                let Ok(sample) = c else { break };
                on_command(&mut core, &mut io, &sample).await?;
            }
            c = contacts.recv_async() => {
                let Ok(sample) = c else { break };
                on_contacts(&mut core, &sample);
            }
            c = coordinator.recv_async() => {
                let Ok(sample) = c else { break };
                on_coordinator(&mut core, &mut io, &sample).await?;
            }
            _ = housekeeping.tick() => {
                let out = core.on_timer(Instant::now());
                let done = io.send(out).await?;
                io.done(&mut core, done).await;
            }
        }
    }
    if token.is_some() {
        io.announce_leaving(robot).await;
    }
    io.publish_status(&mut core).await;
    tracing::info!(%robot, counters = ?core.counters(), "agent stopped");
    Ok(core.counters().clone())
}

/// Declare the robot's membership, then send the core's first outputs. Returns the membership
/// token.
async fn join_team<S: DynamicsSource, K: TorqueSink>(
    session: &Session,
    cfg: &AgentConfig,
    core: &mut AgentCore<S>,
    io: &mut Io<K>,
) -> Result<LivelinessToken, AgentError> {
    let (team, robot) = (cfg.team.as_str(), cfg.robot.as_str());
    let token = transport::declare_member(session, team, robot).await?;
    tracing::info!(
        %robot,
        %team,
        joints = core.joints(),
        deadline = ?cfg.deadline,
        max_command_age = ?cfg.max_command_age,
        "agent joined the team"
    );
    let out = core.start(Instant::now());
    let done = io.send(out).await?;
    io.done(core, done).await;
    Ok(token)
}

/// The housekeeping timer (watchdog by time, periodic status and description): it skips the
/// ticks it missed rather than bursting to catch up.
fn housekeeping_timer(cfg: &AgentConfig) -> tokio::time::Interval {
    let mut housekeeping = tokio::time::interval(cfg.housekeeping_period());
    housekeeping.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    housekeeping
}

/// A state event in: a state goes to the core (and the robot leaves the team if it fell), an
/// undecodable one is counted. Whether the loop goes on (false once the source closed).
async fn on_state_event<S: DynamicsSource, K: TorqueSink>(
    core: &mut AgentCore<S>,
    io: &mut Io<K>,
    ev: StateEvent,
    robot: &str,
    token: &mut Option<LivelinessToken>,
) -> Result<bool, AgentError> {
    let state = match ev {
        StateEvent::State(s) => s,
        StateEvent::Invalid(reason) => {
            core.on_undecodable_state(&reason);
            return Ok(true);
        }
        StateEvent::Closed => return Ok(false),
    };
    let leave = on_state(core, io, &state).await?;
    if let Some(t) = token.take_if(|_| leave) {
        leave_after_fall(io, robot, t).await;
    }
    Ok(true)
}

/// While `stall` is true: handle nothing (until `stop`), still a member.
async fn wait_out_stall(
    robot: &str,
    stop: &mut watch::Receiver<bool>,
    stall: &mut watch::Receiver<bool>,
) {
    if *stall.borrow_and_update() {
        tracing::warn!(%robot, "stalled: handling nothing, still a member");
        while *stall.borrow_and_update() && !*stop.borrow() {
            tokio::select! {
                r = stop.changed() => if r.is_err() { break },
                r = stall.changed() => if r.is_err() { break },
            }
        }
        tracing::warn!(%robot, "stall over");
    }
}

/// A state in: the core's answer out. Whether the core says the robot leaves the team (it fell).
async fn on_state<S: DynamicsSource, K: TorqueSink>(
    core: &mut AgentCore<S>,
    io: &mut Io<K>,
    state: &RobotState,
) -> Result<bool, AgentError> {
    let Ok(out) = core.on_state(state, Instant::now()) else { return Ok(false) };
    let leave = out.leave_team;
    let done = io.send(out).await?;
    io.done(core, done).await;
    Ok(leave)
}

/// The fallen robot leaves the team: its leaving announced, then its membership withdrawn.
async fn leave_after_fall<K: TorqueSink>(io: &Io<K>, robot: &str, token: LivelinessToken) {
    // Said first, so that the coordinator does not wait for a link to come back.
    io.announce_leaving(robot).await;
    if let Err(e) = token.undeclare().await {
        tracing::warn!(%robot, "withdrawing the membership after the fall: {e}");
    }
    tracing::warn!(%robot, "fallen: left the team");
}

/// A torque command in: the core's answer out.
async fn on_command<S: DynamicsSource, K: TorqueSink>(
    core: &mut AgentCore<S>,
    io: &mut Io<K>,
    sample: &Sample,
) -> Result<(), AgentError> {
    let now = Instant::now();
    let out = match decode_sample::<TorqueCommand>(sample) {
        Ok(cmd) => core.on_command(&cmd, now),
        Err(e) => Err(core.on_undecodable_command(&e.to_string())),
    };
    let Ok(out) = out else { return Ok(()) };
    let done = io.send(out).await?;
    io.done(core, done).await;
    Ok(())
}

/// A contact set in (the core schedules it or counts its rejection).
fn on_contacts<S: DynamicsSource>(core: &mut AgentCore<S>, sample: &Sample) {
    let _ = match decode_sample::<protocol::ContactSet>(sample) {
        Ok(msg) => core.on_contacts(&msg),
        Err(e) => Err(core.on_undecodable_contacts(&e.to_string())),
    };
}

/// The coordinator's liveliness changed: the core's answer out.
async fn on_coordinator<S: DynamicsSource, K: TorqueSink>(
    core: &mut AgentCore<S>,
    io: &mut Io<K>,
    sample: &Sample,
) -> Result<(), AgentError> {
    let out = if transport::coordinator_alive(sample) {
        // A coordinator that (re)started needs the description to command us.
        core.on_coordinator(Instant::now())
    } else {
        // The coordinator's token went: safe mode if it is not back within the grace
        // (a link that drops and comes back), or at the command deadline if that is sooner.
        core.on_coordinator_lost(Instant::now())
    };
    let done = io.send(out).await?;
    io.done(core, done).await;
    Ok(())
}

/// What [`Io::send`] did.
struct Done {
    sent: Sent,
    status: bool,
}

/// The shell's publishers and torque sink.
struct Io<K: TorqueSink> {
    dynamics: TypedPublisher<DynamicsTerms>,
    status: TypedPublisher<AgentStatus>,
    description: Option<TypedPublisher<RobotDescription>>,
    sink: K,
}

impl<K: TorqueSink> Io<K> {
    async fn declare(
        session: &Session,
        team: &str,
        robot: &str,
        description: bool,
        sink: K,
    ) -> Result<Self, AgentError> {
        let key = |t| keys::robot(team, robot, t);
        let dynamics =
            TypedPublisher::declare(session, key(RobotTopic::Dynamics)?, Qos::HotPath).await?;
        let status =
            TypedPublisher::declare(session, key(RobotTopic::Status)?, Qos::Telemetry).await?;
        let description = match description {
            true => Some(
                TypedPublisher::declare(session, key(RobotTopic::Description)?, Qos::Telemetry)
                    .await?,
            ),
            false => None,
        };
        Ok(Io { dynamics, status, description, sink })
    }

    /// Stamp and send what the core returned, in its order.
    async fn send(&mut self, out: Outputs<'_>) -> Result<Done, AgentError> {
        let mut sent = Sent::default();
        let status = out.status;
        if let Some(terms) = out.terms {
            terms.header.stamp_ns = protocol::wall_clock_ns();
            self.dynamics.put(terms).await?;
            sent.terms_at = Some(Instant::now());
        }
        if let (Some(p), Some(d)) = (self.description.as_mut(), out.description) {
            d.header.stamp_ns = protocol::wall_clock_ns();
            match p.put(d).await {
                Ok(()) => sent.description = true,
                Err(e) => tracing::warn!("description not published: {e}"),
            }
        }
        if let Some(drive) = out.drive {
            drive.header.stamp_ns = protocol::wall_clock_ns();
            self.sink.apply(drive).await?;
        }
        Ok(Done { sent, status })
    }

    /// Tell the coordinator that this robot leaves the team for good (its dynamics key deleted):
    /// a token that vanishes alone may be a link that comes back
    /// (`coordinator::team::membership::DEPARTURE_GRACE`).
    async fn announce_leaving(&self, robot: &str) {
        if let Err(e) = self.dynamics.delete().await {
            tracing::warn!(%robot, "leaving not announced: {e}");
        }
    }

    /// Report what was sent to the core, then publish the status if the core asked for it.
    async fn done<S: DynamicsSource>(&mut self, core: &mut AgentCore<S>, done: Done) {
        core.sent(&done.sent);
        if done.status {
            self.publish_status(core).await;
        }
    }

    async fn publish_status<S: DynamicsSource>(&mut self, core: &mut AgentCore<S>) {
        let status = core.status();
        status.header.stamp_ns = protocol::wall_clock_ns();
        if let Err(e) = self.status.put(status).await {
            tracing::warn!("status not published: {e}");
        }
    }
}
