//! The lockstep loop: publish every robot's state of tick k, wait for every robot's torques
//! of tick k, apply them, step. Deterministic for a deterministic plant.
//!
//! * `config`: the loop's settings, report, extras and errors.
//! * `answers`: the robots' torques of a tick, and agents that leave or come back.
//! * `liveness`: the components' liveliness while the loop runs.
//! * `members`: waiting for the team before the first tick.
//! * `tick_io`: the states out, the torques in and what happens around each physics step
//!   ([`BridgeIo`], shared with [`crate::realtime`]).

mod answers;
mod config;
mod liveness;
mod members;
mod tick_io;

use std::time::Instant;

use protocol::keys;
use protocol::transport;
use tokio::sync::watch;
use zenoh::Session;

use crate::plant::Plant;
use answers::{silence_lost_drives, Answers};
use liveness::Liveness;
use members::coordinator_ready;

pub use answers::LOST_DRIVE_TICKS;
pub use config::{
    AgentLoss, BridgeError, LockstepConfig, LockstepReport, LoopDuties,
    DEFAULT_COORDINATOR_GRACE_TICKS, DEFAULT_DRIVE_TIMEOUT,
};
pub use tick_io::BridgeIo;
pub(crate) use tick_io::TickSide;

/// Run `cfg.ticks` lockstep ticks of `plant`.
pub async fn run(
    session: &Session,
    cfg: &LockstepConfig,
    plant: &mut impl Plant,
    stop: watch::Receiver<bool>,
) -> Result<LockstepReport, BridgeError> {
    run_with(session, cfg, plant, &mut LoopDuties::default(), stop).await
}

/// Run `cfg.ticks` lockstep ticks of `plant`, with ground truth and perturbations as `extras` says.
pub async fn run_with(
    session: &Session,
    cfg: &LockstepConfig,
    plant: &mut impl Plant,
    extras: &mut LoopDuties,
    stop: watch::Receiver<bool>,
) -> Result<LockstepReport, BridgeError> {
    let robots: Vec<String> = plant.robots().to_vec();
    let mut io = BridgeIo::open(session, cfg, &robots, extras, &stop).await?;
    run_on(session, &mut io, cfg, plant, extras, stop).await
}

/// Run `cfg.ticks` lockstep ticks of `plant` through `io`, whose robots are present (a phase of
/// a run that opened `io` once).
pub async fn run_on(
    session: &Session,
    io: &mut BridgeIo,
    cfg: &LockstepConfig,
    plant: &mut impl Plant,
    extras: &mut LoopDuties,
    stop: watch::Receiver<bool>,
) -> Result<LockstepReport, BridgeError> {
    let BridgeIo { torques, states, side } = io;
    let run_started = Instant::now();
    let mut answers = Answers::new(plant.robots().to_vec());
    let mut watch = Liveness::open(session, &cfg.team).await?;
    for tick in extras.first_tick..extras.first_tick + cfg.ticks {
        if *stop.borrow() {
            return Err(BridgeError::Stopped);
        }
        watch.check(tick, cfg.coordinator_grace_ticks)?;
        if watch.take_returned() && cfg.wait_for_coordinator {
            coordinator_back(session, cfg, &answers, tick, &stop).await?;
        }
        watch.pace_outage(plant.time()).await;
        states.publish(plant, tick).await?;
        answers.got.copy_from_slice(&answers.lost);
        let timeout = if tick == extras.first_tick {
            cfg.command_timeout.max(cfg.start_timeout)
        } else {
            cfg.command_timeout
        };
        answers.wait(cfg, tick, timeout, torques, &mut watch, states, plant).await?;
        silence_lost_drives(cfg, plant, &answers.robots, tick, &answers.lost, &answers.answered);
        side.step(plant, &cfg.team, tick, extras).await?;
        if cfg.progress_every > 0 && (tick + 1 - extras.first_tick) % cfg.progress_every == 0 {
            tracing::info!(tick = tick + 1, of = cfg.ticks, sim_time = plant.time(), "progress");
        }
    }
    Ok(LockstepReport {
        ticks: cfg.ticks,
        sim_time: plant.time(),
        wall_time: run_started.elapsed(),
        resends: answers.resends,
        rejected_torques: answers.rejected,
    })
}

/// The coordinator came back during `tick`: wait, as at the start, until it is ready for the
/// robots still present. A tick the coordinator answers before its team has formed is one it
/// holds, and in lockstep its start-up is not the robots' time.
async fn coordinator_back(
    session: &Session,
    cfg: &LockstepConfig,
    answers: &Answers,
    tick: u64,
    stop: &watch::Receiver<bool>,
) -> Result<(), BridgeError> {
    let present: Vec<String> = answers
        .robots
        .iter()
        .zip(&answers.lost)
        .filter(|(_, l)| !**l)
        .map(|(r, _)| r.clone())
        .collect();
    let status_q = transport::subscribe(session, keys::coordinator_status(&cfg.team)?).await?;
    coordinator_ready(&status_q, &present, Instant::now(), cfg.start_timeout, stop).await?;
    tracing::info!(tick, "the coordinator that came back is ready for the team");
    Ok(())
}
