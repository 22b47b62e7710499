//! The lockstep loop: publish every robot's state of tick k, wait for every robot's torques
//! of tick k, apply them, step. Deterministic for a deterministic plant.

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, MemberEvent, Qos, TransportError, TypedPublisher};
use protocol::{GroundTruth, PerturbationRequest, RobotState, TorqueCommand};
use thiserror::Error;
use tokio::sync::watch;
use zenoh::Session;

use crate::ground_truth::Recorder;
use crate::plant::{empty_state, DriveLoss, Plant};

/// Errors of the bridge loop.
#[derive(Debug, Error)]
pub enum BridgeError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Protocol(#[from] protocol::ProtocolError),
    #[error("robots {missing:?} did not join the team within {waited:?}")]
    MembersMissing { missing: Vec<String>, waited: Duration },
    #[error("the coordinator was not ready for the team within {waited:?} (last status: {last})")]
    CoordinatorNotReady { last: String, waited: Duration },
    #[error("no torques from robot(s) {missing:?} for tick {tick} within {waited:?}")]
    TorqueTimeout { tick: u64, missing: Vec<String>, waited: Duration },
    #[error("robot {robot}'s agent left the team at tick {tick}")]
    RobotLeft { robot: String, tick: u64 },
    #[error("the coordinator left at tick {since}; the robots held their posture for {ticks} ticks and it did not come back")]
    CoordinatorLost { since: u64, ticks: u64 },
    #[error("stopped")]
    Stopped,
}

/// Settings of the lockstep loop.
#[derive(Debug, Clone)]
pub struct LockstepConfig {
    pub team: String,
    pub ticks: u64,
    /// How long to wait for every robot to join before the first tick.
    pub start_timeout: Duration,
    /// How long a tick may wait for torques before the run fails, naming the robot.
    pub command_timeout: Duration,
    /// While waiting, the states of the tick are sent again this often (a component that
    /// joined late may have missed them); agents and coordinator treat repeats as repeats.
    pub resend_every: Duration,
    /// Log progress every this many ticks (0: never).
    pub progress_every: u64,
    /// Ticks the run goes on after the coordinator's liveliness token disappeared (the agents
    /// hold their posture meanwhile) before it fails; a coordinator that comes back within
    /// them takes the team back.
    pub coordinator_grace_ticks: u64,
    /// Also wait, before the first tick, until the coordinator's status lists every robot as a
    /// member and it is ready to command them (descriptions received). The coordinator learns
    /// of members through liveliness, which may reach it after a robot's first dynamics: a tick
    /// it then completed without that robot was never commanded for it.
    pub wait_for_coordinator: bool,
    /// What a robot whose agent leaves mid-run becomes.
    pub agent_loss: AgentLoss,
    /// Real time: a robot whose torques have not come for this long loses its drives
    /// ([`AgentLoss::Drives`]); until then its drives hold its last torques.
    pub drive_timeout: Duration,
}

/// What the loops do when a robot's agent leaves the team mid-run (its liveliness token is
/// gone: the process died, or was stopped) or, in real time, sends no torques for
/// [`LockstepConfig::drive_timeout`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AgentLoss {
    /// End the run with [`BridgeError::RobotLeft`], naming the robot (the smoke runs). In real
    /// time the drives hold the last torques.
    #[default]
    EndRun,
    /// Go on without it: its drives do what [`DriveLoss`] says (unpowered, or frozen where
    /// they are) and no tick waits for it. An agent that left the team alive (a fallen robot's,
    /// `robot_agent::fall`) and still answers its states drives it with those torques as they
    /// come (a tick late when they come after the tick's step), holding the last ones for up
    /// to [`LOST_DRIVE_TICKS`] (then the drives are lost as above). When its agent joins again
    /// (restarted), the loop waits for its torques from the next tick on, and the first
    /// torques it sends drive the robot again. The run ends with [`BridgeError::RobotLeft`]
    /// when every agent has left.
    Drives(DriveLoss),
}

impl AgentLoss {
    /// What the drives do on a loss, if the run goes on.
    pub fn drive_loss(&self) -> Option<DriveLoss> {
        match self {
            AgentLoss::EndRun => None,
            AgentLoss::Drives(d) => Some(*d),
        }
    }
}

/// [`LockstepConfig::drive_timeout`] by default: twice an agent's own command deadline (25 ms),
/// so that an agent in safe mode (which sends its hold torques) never trips it.
pub const DEFAULT_DRIVE_TIMEOUT: Duration = Duration::from_millis(50);

impl LockstepConfig {
    /// The smoke run's lockstep (placeholder plant): 20 s for every robot to join, `command_timeout`
    /// per tick, resends every 50 ms, progress every tenth of the run, and the coordinator's
    /// readiness awaited (under load its members' liveliness reached it after their first
    /// terms: it ordered a hold at tick 0, and the closed loop's analytic answer was off). The
    /// embedded launcher and `sim-bridge smoke` both use it.
    pub fn smoke(team: &str, ticks: u64, command_timeout: Duration) -> Self {
        LockstepConfig {
            team: team.to_string(),
            ticks,
            start_timeout: Duration::from_secs(20),
            command_timeout,
            resend_every: Duration::from_millis(50),
            progress_every: (ticks / 10).max(1),
            wait_for_coordinator: true,
            coordinator_grace_ticks: DEFAULT_COORDINATOR_GRACE_TICKS,
            agent_loss: AgentLoss::EndRun,
            drive_timeout: DEFAULT_DRIVE_TIMEOUT,
        }
    }
}

/// [`LockstepConfig::coordinator_grace_ticks`] by default: half a second at 1 kHz.
pub const DEFAULT_COORDINATOR_GRACE_TICKS: u64 = 500;

/// What a lockstep run did.
#[derive(Debug, Clone, PartialEq)]
pub struct LockstepReport {
    pub ticks: u64,
    pub sim_time: f64,
    pub wall_time: Duration,
    pub resends: u64,
    pub rejected_torques: u64,
}

/// What the loop does besides states and torques.
#[derive(Debug, Default)]
pub struct Extras {
    /// Publish the plant's ground truth on `team/{team}/ground-truth` after every step.
    pub publish_ground_truth: bool,
    /// Keep the ground truth in memory (every `Recorder::every` ticks).
    pub recorder: Option<Recorder>,
    /// Take perturbation requests from `team/{team}/perturbation`.
    pub perturbation_key: bool,
    /// Perturbation requests taken and refused.
    pub perturbations_taken: u64,
    pub perturbations_refused: u64,
    /// Number of the first tick (a run that continues an earlier one, e.g. after settling,
    /// continues its tick numbers: agents refuse ticks older than the last they applied).
    pub first_tick: u64,
}

/// Run `cfg.ticks` lockstep ticks of `plant`.
pub async fn run(
    session: &Session,
    cfg: &LockstepConfig,
    plant: &mut impl Plant,
    stop: watch::Receiver<bool>,
) -> Result<LockstepReport, BridgeError> {
    run_with(session, cfg, plant, &mut Extras::default(), stop).await
}

/// Run `cfg.ticks` lockstep ticks of `plant`, with ground truth and perturbations as `extras` says.
pub async fn run_with(
    session: &Session,
    cfg: &LockstepConfig,
    plant: &mut impl Plant,
    extras: &mut Extras,
    stop: watch::Receiver<bool>,
) -> Result<LockstepReport, BridgeError> {
    let mut side = TickSide::open(session, &cfg.team, extras).await?;
    let robots: Vec<String> = plant.robots().to_vec();
    let torques = transport::subscribe(session, keys::all_robots(&cfg.team, RobotTopic::Torque)?).await?;
    let mut states = StateOut::declare(session, &cfg.team, &robots).await?;

    wait_for_members(session, cfg, &robots, &stop).await?;
    tracing::info!(robots = ?robots, "all robots present, lockstep starts");

    let run_started = Instant::now();
    let mut resends = 0u64;
    let mut rejected = 0u64;
    let mut got = vec![false; robots.len()];
    // Robots whose agents left: no tick waits for them (until their agent joins again).
    let mut lost = vec![false; robots.len()];
    // The tick of each robot's latest torques taken.
    let mut answered: Vec<Option<u64>> = vec![None; robots.len()];
    let mut watch = Liveness::open(session, &cfg.team).await?;
    for tick in extras.first_tick..extras.first_tick + cfg.ticks {
        if *stop.borrow() {
            return Err(BridgeError::Stopped);
        }
        watch.check(tick, cfg.coordinator_grace_ticks)?;
        if watch.take_returned() && cfg.wait_for_coordinator {
            // As at the start: a tick the coordinator answers before its team has formed is one
            // it holds, and in lockstep its start-up is not the robots' time.
            let present: Vec<String> = robots.iter().zip(&lost).filter(|(_, l)| !**l).map(|(r, _)| r.clone()).collect();
            let status_q = transport::subscribe(session, keys::coordinator_status(&cfg.team)?).await?;
            coordinator_ready(&status_q, &present, Instant::now(), cfg.start_timeout, &stop).await?;
            tracing::info!(tick, "the coordinator that came back is ready for the team");
        }
        watch.pace_outage(plant.time()).await;
        states.publish(plant, tick).await?;
        got.copy_from_slice(&lost);
        let tick_started = Instant::now();
        let mut last_send = Instant::now();
        while !got.iter().all(|g| *g) {
            let waited = tick_started.elapsed();
            let timeout = if tick == extras.first_tick { cfg.command_timeout.max(cfg.start_timeout) } else { cfg.command_timeout };
            if waited >= timeout {
                let missing = robots.iter().zip(&got).filter(|(_, g)| !**g).map(|(r, _)| r.clone()).collect();
                return Err(BridgeError::TorqueTimeout { tick, missing, waited });
            }
            let wait = cfg.resend_every.saturating_sub(last_send.elapsed()).min(timeout - waited);
            let sample = tokio::select! {
                s = torques.recv_async() => match s {
                    Ok(s) => Some(s),
                    Err(_) => return Err(BridgeError::Stopped),
                },
                ev = watch.next() => {
                    match watch.take(ev, tick, &robots)? {
                        Some(AgentChange::Left(i)) => {
                            lose_agent(cfg, plant, &robots, i, tick, answered[i] == Some(tick), &mut lost)?;
                            got[i] = true;
                        }
                        Some(AgentChange::Joined(i)) if lost[i] => {
                            // A restarted agent: its torques are waited for from the next tick.
                            tracing::info!(robot = %robots[i], tick, "the robot's agent joined again: its torques drive it from the next tick its agent answers");
                            lost[i] = false;
                        }
                        _ => {}
                    }
                    continue;
                }
                _ = tokio::time::sleep(wait) => None,
            };
            match sample {
                Some(sample) => {
                    let cmd = match decode_sample::<TorqueCommand>(&sample) {
                        Ok(c) => c,
                        Err(e) => {
                            rejected += 1;
                            tracing::warn!(key = %sample.key_expr(), "rejected torques: {e}");
                            continue;
                        }
                    };
                    let Some(i) = robots.iter().position(|r| r == cmd.header.robot_id()) else { continue };
                    // A robot whose agent left is not waited for: its torques of a recent tick
                    // that came after that tick's step drive it now (the latest only).
                    let recent = lost[i] && cmd.header.tick < tick && tick - cmd.header.tick < LOST_DRIVE_TICKS && answered[i].is_none_or(|t| cmd.header.tick > t);
                    if cmd.header.tick != tick && !recent {
                        continue; // a repeat of an earlier tick
                    }
                    if cmd.tau.len() != plant.joints(i) {
                        rejected += 1;
                        tracing::warn!(robot = %robots[i], "torques of the wrong size: {} for {} joints", cmd.tau.len(), plant.joints(i));
                        continue;
                    }
                    if !got[i] || lost[i] {
                        // A robot whose agent left the team but still answers its states (a
                        // fallen robot's damping, robot_agent::fall) is driven by what it
                        // sends; no tick waits for it.
                        if plant.drives_lost(i) {
                            tracing::info!(robot = %robots[i], tick, "the robot's drives take torques again");
                            plant.restore_drives(i);
                        }
                        plant.set_torques(i, &cmd.tau);
                        got[i] = true;
                        answered[i] = Some(cmd.header.tick);
                    }
                }
                None => {
                    if last_send.elapsed() >= cfg.resend_every {
                        states.republish().await?;
                        resends += 1;
                        last_send = Instant::now();
                    }
                }
            }
        }
        silence_lost_drives(cfg, plant, &robots, tick, &lost, &answered);
        side.step(plant, &cfg.team, tick, extras).await?;
        if cfg.progress_every > 0 && (tick + 1 - extras.first_tick) % cfg.progress_every == 0 {
            tracing::info!(tick = tick + 1, of = cfg.ticks, sim_time = plant.time(), "progress");
        }
    }
    Ok(LockstepReport {
        ticks: cfg.ticks,
        sim_time: plant.time(),
        wall_time: run_started.elapsed(),
        resends,
        rejected_torques: rejected,
    })
}


/// Robot `i`'s agent left during `tick`: end the run, or its drives are lost ([`AgentLoss`]),
/// at once unless it has `answered` this tick (an agent that left alive, a fallen robot's: its
/// torques keep driving it while they come, [`silence_lost_drives`]).
fn lose_agent(cfg: &LockstepConfig, plant: &mut impl Plant, robots: &[String], i: usize, tick: u64, answered: bool, lost: &mut [bool]) -> Result<(), BridgeError> {
    let robot = robots[i].clone();
    let Some(loss) = cfg.agent_loss.drive_loss() else {
        return Err(BridgeError::RobotLeft { robot, tick });
    };
    if !lost[i] {
        if answered {
            tracing::warn!(robot = %robot, tick, "the robot's agent left the team; its torques drive it while they come");
        } else {
            tracing::warn!(robot = %robot, tick, ?loss, "the robot's agent left: its drives lose their commands from this tick on");
            plant.lose_drives(i, loss);
        }
        lost[i] = true;
    }
    if lost.iter().all(|u| *u) {
        return Err(BridgeError::RobotLeft { robot, tick });
    }
    Ok(())
}

/// Ticks a robot whose agent left keeps its last torques without new ones before its drives
/// are lost: the agents' own command deadline (5 ticks). Its torques are not waited for: one
/// that comes after its tick's step drives the robot from the next step on (if no newer one
/// came), the last one applied meanwhile.
pub const LOST_DRIVE_TICKS: u64 = 5;

/// Before stepping `tick`: a robot whose agent left and whose drives its torques still drive
/// (a fallen robot's damping) loses them once no torques came for [`LOST_DRIVE_TICKS`] (its
/// agent died after leaving).
fn silence_lost_drives(cfg: &LockstepConfig, plant: &mut impl Plant, robots: &[String], tick: u64, lost: &[bool], answered: &[Option<u64>]) {
    let Some(loss) = cfg.agent_loss.drive_loss() else { return };
    for (i, robot) in robots.iter().enumerate() {
        if lost[i] && !plant.drives_lost(i) && answered[i].is_none_or(|t| tick.saturating_sub(t) >= LOST_DRIVE_TICKS) {
            tracing::warn!(%robot, tick, since = ?answered[i], ?loss, "no torques from the robot whose agent left: its drives lose their commands");
            plant.lose_drives(i, loss);
        }
    }
}

/// A robot's agent that left or joined the team during a run (index in the plant's robots).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum AgentChange {
    Left(usize),
    Joined(usize),
}

/// The liveliness of the run's components while it runs: a robot whose agent leaves or joins
/// again is named to the loop (which ends the run or takes the robot's drives away and back,
/// [`AgentLoss`]); the coordinator's leaving starts a count of ticks (the agents hold their
/// posture meanwhile) that ends the run after the grace unless it comes back.
///
/// While the coordinator is gone, ticks run no faster than the wall clock
/// ([`Liveness::pace_outage`]): nothing then waits for a computation (the agents answer each
/// state with their hold at once), and the outage lasts in simulated time what it lasts on the
/// machine, a restart included, as it would on robots. Without it the ticks of the hold ran at
/// several thousand per second, and how far the references had moved on when a restarted
/// coordinator took over depended on the machine's load.
struct Liveness {
    members: transport::EventQueue,
    coordinator: transport::EventQueue,
    coordinator_lost: Option<u64>,
    /// The coordinator came back after an outage (taken by [`Liveness::take_returned`]).
    returned: bool,
    /// Wall instant and simulated time at which the outage's pacing started.
    outage_clock: Option<(Instant, f64)>,
}

/// What the liveliness queues said.
enum LivenessEvent {
    Member(zenoh::sample::Sample),
    Coordinator(zenoh::sample::Sample),
    Closed,
}

impl Liveness {
    async fn open(session: &Session, team: &str) -> Result<Self, BridgeError> {
        Ok(Liveness { members: transport::watch_members(session, team).await?, coordinator: transport::watch_coordinator(session, team).await?, coordinator_lost: None, returned: false, outage_clock: None })
    }

    /// Whether the coordinator came back since the last call.
    fn take_returned(&mut self) -> bool {
        std::mem::take(&mut self.returned)
    }

    /// Before a tick at simulated time `sim_time`: while the coordinator is gone, wait until
    /// the wall clock has caught up with the simulated time since the outage began.
    async fn pace_outage(&mut self, sim_time: f64) {
        if self.coordinator_lost.is_none() {
            self.outage_clock = None;
            return;
        }
        let (wall0, sim0) = *self.outage_clock.get_or_insert((Instant::now(), sim_time));
        let due = wall0 + Duration::from_secs_f64((sim_time - sim0).max(0.0));
        tokio::time::sleep_until(due.into()).await;
    }

    async fn next(&self) -> LivenessEvent {
        tokio::select! {
            m = self.members.recv_async() => m.map_or(LivenessEvent::Closed, LivenessEvent::Member),
            c = self.coordinator.recv_async() => c.map_or(LivenessEvent::Closed, LivenessEvent::Coordinator),
        }
    }

    /// Take one event during `tick`: a robot of `robots` whose agent left or joined.
    fn take(&mut self, ev: LivenessEvent, tick: u64, robots: &[String]) -> Result<Option<AgentChange>, BridgeError> {
        match ev {
            LivenessEvent::Member(s) => {
                let index = |r: &str| robots.iter().position(|x| x == r);
                return Ok(match MemberEvent::from_sample(&s) {
                    Some(MemberEvent::Left(r)) => index(&r).map(AgentChange::Left),
                    Some(MemberEvent::Joined(r)) => index(&r).map(AgentChange::Joined),
                    None => None,
                });
            }
            LivenessEvent::Coordinator(s) if transport::coordinator_alive(&s) => {
                if let Some(since) = self.coordinator_lost.take() {
                    tracing::info!(since, tick, "the coordinator is back");
                    self.returned = true;
                }
            }
            LivenessEvent::Coordinator(_) => {
                tracing::warn!(tick, "the coordinator left; the robots hold their posture");
                self.coordinator_lost.get_or_insert(tick);
            }
            LivenessEvent::Closed => return Err(BridgeError::Stopped),
        }
        Ok(None)
    }

    /// Before `tick`: drain what arrived, and fail when the coordinator has been gone for
    /// `grace` ticks.
    fn check(&mut self, tick: u64, grace: u64) -> Result<(), BridgeError> {
        while let Ok(Some(s)) = self.coordinator.try_recv() {
            self.take(LivenessEvent::Coordinator(s), tick, &[])?;
        }
        match self.coordinator_lost {
            Some(since) if tick.saturating_sub(since) >= grace => Err(BridgeError::CoordinatorLost { since, ticks: tick - since }),
            _ => Ok(()),
        }
    }
}

/// Wait until every robot of `robots` has a liveliness token, or fail naming the missing ones.
pub(crate) async fn wait_for_members(
    session: &Session,
    cfg: &LockstepConfig,
    robots: &[String],
    stop: &watch::Receiver<bool>,
) -> Result<(), BridgeError> {
    let members_q = transport::watch_members(session, &cfg.team).await?;
    let status_q = if cfg.wait_for_coordinator { Some(transport::subscribe(session, keys::coordinator_status(&cfg.team)?).await?) } else { None };
    let started = Instant::now();
    let mut present = BTreeSet::new();
    while !robots.iter().all(|r| present.contains(r)) {
        if *stop.borrow() {
            return Err(BridgeError::Stopped);
        }
        let left = cfg.start_timeout.saturating_sub(started.elapsed());
        match tokio::time::timeout(left, members_q.recv_async()).await {
            Ok(Ok(sample)) => match MemberEvent::from_sample(&sample) {
                Some(MemberEvent::Joined(r)) => {
                    present.insert(r);
                }
                Some(MemberEvent::Left(r)) => {
                    present.remove(&r);
                }
                None => {}
            },
            _ => {
                let missing = robots.iter().filter(|r| !present.contains(*r)).cloned().collect();
                return Err(BridgeError::MembersMissing { missing, waited: cfg.start_timeout });
            }
        }
    }
    if let Some(q) = status_q {
        coordinator_ready(&q, robots, started, cfg.start_timeout, stop).await?;
    }
    Ok(())
}

/// Wait, until `timeout` after `started`, for a coordinator status on `q` that lists every robot
/// of `robots` as a member and is ready to command them; or fail with the last status heard.
async fn coordinator_ready(q: &transport::SampleQueue, robots: &[String], started: Instant, timeout: Duration, stop: &watch::Receiver<bool>) -> Result<(), BridgeError> {
    let mut last = String::from("no status heard");
    loop {
        if *stop.borrow() {
            return Err(BridgeError::Stopped);
        }
        let left = timeout.saturating_sub(started.elapsed());
        match tokio::time::timeout(left, q.recv_async()).await {
            Ok(Ok(sample)) => {
                let Ok(st) = decode_sample::<protocol::CoordinatorStatus>(&sample) else { continue };
                let all = robots.iter().all(|r| st.members.contains(r));
                if all && st.mode != protocol::CoordinatorMode::WaitingForMembers {
                    return Ok(());
                }
                last = format!("members {:?}, mode {:?}: {}", st.members, st.mode, st.detail);
            }
            _ => return Err(BridgeError::CoordinatorNotReady { last, waited: timeout }),
        }
    }
}

/// What the lockstep and real-time loops do around every physics step: take the perturbation
/// requests that arrived on the Zenoh key, step the plant, then publish and record the ground
/// truth, as [`Extras`] asks.
pub(crate) struct TickSide {
    truth_pub: Option<TypedPublisher<GroundTruth>>,
    perturbations: Option<transport::SampleQueue>,
    truth: GroundTruth,
}

impl TickSide {
    pub(crate) async fn open(session: &Session, team: &str, extras: &Extras) -> Result<Self, BridgeError> {
        let truth_pub = if extras.publish_ground_truth {
            Some(TypedPublisher::<GroundTruth>::declare(session, keys::ground_truth(team)?, Qos::Telemetry).await?)
        } else {
            None
        };
        let perturbations = if extras.perturbation_key { Some(transport::subscribe(session, keys::perturbation(team)?).await?) } else { None };
        Ok(TickSide { truth_pub, perturbations, truth: crate::ground_truth::empty(team) })
    }

    /// The loop timing the next ground truth carries, one entry per robot (made on first use;
    /// the real-time loop fills it every tick, lockstep never asks for it).
    pub(crate) fn loop_timing(&mut self, robots: &[String]) -> &mut [protocol::LoopTiming] {
        let t = &mut self.truth.loop_timing;
        if t.len() != robots.len() || t.iter().zip(robots).any(|(a, r)| a.robot != *r) {
            *t = robots.iter().map(|r| protocol::LoopTiming { robot: r.clone(), latency_us: None, applied_tick: None, late: 0 }).collect();
        }
        t
    }

    /// Perturbations in, one plant step, ground truth out.
    pub(crate) async fn step(&mut self, plant: &mut impl Plant, team: &str, tick: u64, extras: &mut Extras) -> Result<(), BridgeError> {
        if let Some(q) = &self.perturbations {
            while let Ok(Some(sample)) = q.try_recv() {
                match decode_sample::<PerturbationRequest>(&sample).map_err(|e| e.to_string()).and_then(|r| plant.perturb(&r)) {
                    Ok(()) => extras.perturbations_taken += 1,
                    Err(e) => {
                        extras.perturbations_refused += 1;
                        tracing::warn!("refused perturbation: {e}");
                    }
                }
            }
        }
        plant.step();
        if (self.truth_pub.is_some() || extras.recorder.is_some()) && plant.ground_truth(team, tick, &mut self.truth) {
            if let Some(p) = self.truth_pub.as_mut() {
                p.put(&self.truth).await?;
            }
            if let Some(r) = extras.recorder.as_mut() {
                r.offer(&self.truth);
            }
        }
        Ok(())
    }
}

/// Every robot's state publisher and reused state message, for the lockstep and real-time loops.
pub(crate) struct StateOut {
    pubs: Vec<TypedPublisher<RobotState>>,
    states: Vec<RobotState>,
}

impl StateOut {
    pub(crate) async fn declare(session: &Session, team: &str, robots: &[String]) -> Result<Self, BridgeError> {
        let mut out = StateOut { pubs: Vec::new(), states: Vec::new() };
        for r in robots {
            let key = keys::robot(team, r, RobotTopic::State)?;
            out.pubs.push(TypedPublisher::<RobotState>::declare(session, key, Qos::HotPath).await?);
            out.states.push(empty_state(team, r));
        }
        Ok(out)
    }

    /// Fill every robot's state of `tick` from the plant and publish it.
    pub(crate) async fn publish(&mut self, plant: &impl Plant, tick: u64) -> Result<(), BridgeError> {
        let now = protocol::wall_clock_ns();
        for (i, s) in self.states.iter_mut().enumerate() {
            plant.state(i, s);
            s.header.tick = tick;
            s.header.stamp_ns = now;
        }
        self.republish().await
    }

    /// Publish the last states again, unchanged.
    pub(crate) async fn republish(&mut self) -> Result<(), BridgeError> {
        for (p, s) in self.pubs.iter_mut().zip(&self.states) {
            p.put(s).await?;
        }
        Ok(())
    }
}
