//! The robots' answers to a lockstep tick: their torques taken as they come, and what becomes of
//! a robot whose agent leaves or comes back ([`super::AgentLoss`]).

use std::time::{Duration, Instant};

use protocol::transport::{self, decode_sample};
use protocol::DriveCommand;
use zenoh::sample::Sample;

use super::config::{BridgeError, LockstepConfig};
use super::liveness::{AgentChange, Liveness};
use super::tick_io::StateOut;
use crate::plant::Plant;

/// The lockstep loop's account of the robots' answers, per robot in plant order.
pub(super) struct Answers {
    pub(super) robots: Vec<String>,
    /// This tick's torques taken (or not waited for).
    pub(super) got: Vec<bool>,
    /// Robots whose agents left: no tick waits for them (until their agent joins again).
    pub(super) lost: Vec<bool>,
    /// The tick of each robot's latest torques taken.
    pub(super) answered: Vec<Option<u64>>,
    pub(super) resends: u64,
    pub(super) rejected: u64,
}

impl Answers {
    pub(super) fn new(robots: Vec<String>) -> Self {
        let n = robots.len();
        Answers {
            robots,
            got: vec![false; n],
            lost: vec![false; n],
            answered: vec![None; n],
            resends: 0,
            rejected: 0,
        }
    }

    /// Wait for every robot's torques of `tick` (but those not waited for), taking agents that
    /// leave or join meanwhile and sending the states again every `cfg.resend_every`; fail
    /// after `timeout`, naming the robots whose torques are missing.
    #[allow(clippy::too_many_arguments)]
    pub(super) async fn wait(
        &mut self,
        cfg: &LockstepConfig,
        tick: u64,
        timeout: Duration,
        torques: &transport::SampleQueue,
        watch: &mut Liveness,
        states: &mut StateOut,
        plant: &mut impl Plant,
    ) -> Result<(), BridgeError> {
        let tick_started = Instant::now();
        let mut last_send = Instant::now();
        while !self.got.iter().all(|g| *g) {
            let waited = tick_started.elapsed();
            if waited >= timeout {
                let missing = self
                    .robots
                    .iter()
                    .zip(&self.got)
                    .filter(|(_, g)| !**g)
                    .map(|(r, _)| r.clone())
                    .collect();
                return Err(BridgeError::TorqueTimeout { tick, missing, waited });
            }
            let wait = cfg.resend_every.saturating_sub(last_send.elapsed()).min(timeout - waited);
            tokio::select! {
                s = torques.recv_async() => match s {
                    Ok(s) => self.take(&s, tick, plant),
                    Err(_) => return Err(BridgeError::Stopped),
                },
                ev = watch.next() => {
                    let change = watch.take(ev, tick, &self.robots)?;
                    self.agent_change(change, cfg, plant, tick)?;
                }
                _ = tokio::time::sleep(wait) => {
                    if last_send.elapsed() >= cfg.resend_every {
                        states.republish().await?;
                        self.resends += 1;
                        last_send = Instant::now();
                    }
                }
            }
        }
        Ok(())
    }

    /// One torque sample during `tick`: this tick's torques of a robot drive it; so do those of
    /// a recent tick from a robot whose agent left.
    fn take(&mut self, sample: &Sample, tick: u64, plant: &mut impl Plant) {
        let cmd = match decode_sample::<DriveCommand>(sample) {
            Ok(c) => c,
            Err(e) => {
                self.rejected += 1;
                tracing::warn!(key = %sample.key_expr(), "rejected torques: {e}");
                return;
            }
        };
        let Some(i) = self.robots.iter().position(|r| r == cmd.header.robot_id()) else { return };
        // A robot whose agent left is not waited for: its torques of a recent tick
        // that came after that tick's step drive it now (the latest only).
        let recent = self.lost[i]
            && cmd.header.tick < tick
            && tick - cmd.header.tick < LOST_DRIVE_TICKS
            && self.answered[i].is_none_or(|t| cmd.header.tick > t);
        if cmd.header.tick != tick && !recent {
            return; // a repeat of an earlier tick
        }
        if cmd.tau_ff.len() != plant.joints(i) {
            self.rejected += 1;
            tracing::warn!(
                robot = %self.robots[i],
                "torques of the wrong size: {} for {} joints",
                cmd.tau_ff.len(),
                plant.joints(i)
            );
            return;
        }
        if !self.got[i] || self.lost[i] {
            // A robot whose agent left the team but still answers its states (a
            // fallen robot's damping, robot_agent::fall) is driven by what it
            // sends; no tick waits for it.
            if plant.drives_lost(i) {
                tracing::info!(
                    robot = %self.robots[i],
                    tick,
                    "the robot's drives take torques again"
                );
                plant.restore_drives(i);
            }
            plant.set_drive(i, &cmd);
            self.got[i] = true;
            self.answered[i] = Some(cmd.header.tick);
        }
    }

    /// A robot's agent left or joined during `tick`.
    fn agent_change(
        &mut self,
        change: Option<AgentChange>,
        cfg: &LockstepConfig,
        plant: &mut impl Plant,
        tick: u64,
    ) -> Result<(), BridgeError> {
        match change {
            Some(AgentChange::Left(i)) => {
                lose_agent(
                    cfg,
                    plant,
                    &self.robots,
                    i,
                    tick,
                    self.answered[i] == Some(tick),
                    &mut self.lost,
                )?;
                self.got[i] = true;
            }
            Some(AgentChange::Joined(i)) if self.lost[i] => {
                // A restarted agent: its torques are waited for from the next tick.
                tracing::info!(
                    robot = %self.robots[i],
                    tick,
                    "the robot's agent joined again: its torques drive it from the next tick its \
                     agent answers"
                );
                self.lost[i] = false;
            }
            _ => {}
        }
        Ok(())
    }
}

/// Robot `i`'s agent left during `tick`: end the run, or its drives are lost
/// ([`super::AgentLoss`]), at once unless it has `answered` this tick (an agent that left alive,
/// a fallen robot's: its torques keep driving it while they come, [`silence_lost_drives`]).
fn lose_agent(
    cfg: &LockstepConfig,
    plant: &mut impl Plant,
    robots: &[String],
    i: usize,
    tick: u64,
    answered: bool,
    lost: &mut [bool],
) -> Result<(), BridgeError> {
    let robot = robots[i].clone();
    let Some(loss) = cfg.agent_loss.drive_loss() else {
        return Err(BridgeError::RobotLeft { robot, tick });
    };
    if !lost[i] {
        if answered {
            tracing::warn!(
                robot = %robot,
                tick,
                "the robot's agent left the team; its torques drive it while they come"
            );
        } else {
            tracing::warn!(
                robot = %robot,
                tick,
                ?loss,
                "the robot's agent left: its drives lose their commands from this tick on"
            );
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
pub(super) fn silence_lost_drives(
    cfg: &LockstepConfig,
    plant: &mut impl Plant,
    robots: &[String],
    tick: u64,
    lost: &[bool],
    answered: &[Option<u64>],
) {
    let Some(loss) = cfg.agent_loss.drive_loss() else { return };
    for (i, robot) in robots.iter().enumerate() {
        if lost[i]
            && !plant.drives_lost(i)
            && answered[i].is_none_or(|t| tick.saturating_sub(t) >= LOST_DRIVE_TICKS)
        {
            tracing::warn!(
                %robot,
                tick,
                since = ?answered[i],
                ?loss,
                "no torques from the robot whose agent left: its drives lose their commands"
            );
            plant.lose_drives(i, loss);
        }
    }
}
