//! What the lockstep and real-time loops send each tick: every robot's state, and around each
//! physics step the perturbations in and the ground truth out; and [`BridgeIo`], all of it with
//! the robots' torques in, declared once for a whole run.

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, TypedPublisher};
use protocol::{GroundTruth, PerturbationRequest, RobotState};
use zenoh::Session;

use super::config::{BridgeError, LockstepConfig, LoopDuties};
use super::members::wait_for_members;
use crate::plant::{empty_state, Plant};

/// Everything a bridge loop talks through: the robots' torques in, their states out, and the
/// perturbations in and ground truth out around each step. Declared once for a whole run, so
/// that the settle and the scenario phase share it and the hand-over between them declares and
/// waits for nothing.
pub struct BridgeIo {
    pub(crate) torques: transport::SampleQueue,
    pub(crate) states: StateOut,
    pub(crate) side: TickSide,
}

impl BridgeIo {
    /// Declare everything for the plant's `robots`, then wait (within `cfg.start_timeout`) for
    /// every robot to join the team and, if `cfg` asks, for the coordinator to be ready.
    pub async fn open(
        session: &Session,
        cfg: &LockstepConfig,
        robots: &[String],
        extras: &LoopDuties,
        stop: &tokio::sync::watch::Receiver<bool>,
    ) -> Result<Self, BridgeError> {
        let side = TickSide::open(session, &cfg.team, extras).await?;
        let torques =
            transport::subscribe(session, keys::all_robots(&cfg.team, RobotTopic::Torque)?).await?;
        let states = StateOut::declare(session, &cfg.team, robots).await?;
        wait_for_members(session, cfg, robots, stop).await?;
        tracing::info!(robots = ?robots, "all robots present");
        Ok(BridgeIo { torques, states, side })
    }

    /// Drop the torques still queued (copies of ticks already answered, which the lockstep
    /// loop's resends of a state can draw): the next phase starts from the ticks it publishes.
    /// How many were dropped.
    pub fn drain_torques(&self) -> usize {
        let mut n = 0;
        while let Ok(Some(_)) = self.torques.try_recv() {
            n += 1;
        }
        n
    }
}

/// What the lockstep and real-time loops do around every physics step: take the perturbation
/// requests that arrived on the Zenoh key, step the plant, then publish and record the ground
/// truth, as [`LoopDuties`] asks.
pub(crate) struct TickSide {
    truth_pub: Option<TypedPublisher<GroundTruth>>,
    perturbations: Option<transport::SampleQueue>,
    truth: GroundTruth,
    /// Each robot's drive gaps counted before this tick's step (real time).
    gaps_before: Vec<u64>,
}

impl TickSide {
    pub(crate) async fn open(
        session: &Session,
        team: &str,
        extras: &LoopDuties,
    ) -> Result<Self, BridgeError> {
        let truth_pub = if extras.publish_ground_truth {
            Some(
                TypedPublisher::<GroundTruth>::declare(
                    session,
                    keys::ground_truth(team)?,
                    Qos::Telemetry,
                )
                .await?,
            )
        } else {
            None
        };
        let perturbations = if extras.perturbation_key {
            Some(transport::subscribe(session, keys::perturbation(team)?).await?)
        } else {
            None
        };
        Ok(TickSide {
            truth_pub,
            perturbations,
            truth: crate::ground_truth::empty(team),
            gaps_before: Vec::new(),
        })
    }

    /// The drive gaps of the step just done into the loop timing (real time only: lockstep
    /// carries none).
    fn count_gaps(&mut self, plant: &impl Plant) {
        let timing = &mut self.truth.loop_timing;
        if timing.is_empty() {
            return;
        }
        self.gaps_before.resize(timing.len(), 0);
        for (i, t) in timing.iter_mut().enumerate() {
            let now = plant.drive_gap_steps(i);
            t.gap_steps =
                u32::try_from(now.saturating_sub(self.gaps_before[i])).unwrap_or(u32::MAX);
            self.gaps_before[i] = now;
        }
    }

    /// The loop timing the next ground truth carries, one entry per robot (made on first use;
    /// the real-time loop fills it every tick, lockstep never asks for it).
    pub(crate) fn loop_timing(&mut self, robots: &[String]) -> &mut [protocol::LoopTiming] {
        let t = &mut self.truth.loop_timing;
        if t.len() != robots.len() || t.iter().zip(robots).any(|(a, r)| a.robot != *r) {
            *t = robots
                .iter()
                .map(|r| protocol::LoopTiming {
                    robot: r.clone(),
                    latency_us: None,
                    applied_tick: None,
                    late: 0,
                    gap_steps: 0,
                })
                .collect();
        }
        t
    }

    /// Perturbations in, one plant step, ground truth out.
    pub(crate) async fn step(
        &mut self,
        plant: &mut impl Plant,
        team: &str,
        tick: u64,
        extras: &mut LoopDuties,
    ) -> Result<(), BridgeError> {
        if let Some(q) = &self.perturbations {
            while let Ok(Some(sample)) = q.try_recv() {
                match decode_sample::<PerturbationRequest>(&sample)
                    .map_err(|e| e.to_string())
                    .and_then(|r| plant.perturb(&r))
                {
                    Ok(()) => extras.perturbations_taken += 1,
                    Err(e) => {
                        extras.perturbations_refused += 1;
                        tracing::warn!("refused perturbation: {e}");
                    }
                }
            }
        }
        plant.step();
        self.count_gaps(plant);
        if (self.truth_pub.is_some() || extras.truth_log.is_some())
            && plant.ground_truth(team, tick, &mut self.truth)
        {
            // The bridge's wall clock when the step was done (time stays the simulated time).
            self.truth.header.stamp_ns = protocol::wall_clock_ns();
            if let Some(p) = self.truth_pub.as_mut() {
                p.put(&self.truth).await?;
            }
            if let Some(r) = extras.truth_log.as_mut() {
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
    pub(crate) async fn declare(
        session: &Session,
        team: &str,
        robots: &[String],
    ) -> Result<Self, BridgeError> {
        let mut out = StateOut { pubs: Vec::new(), states: Vec::new() };
        for r in robots {
            let key = keys::robot(team, r, RobotTopic::State)?;
            out.pubs.push(TypedPublisher::<RobotState>::declare(session, key, Qos::HotPath).await?);
            out.states.push(empty_state(team, r));
        }
        Ok(out)
    }

    /// Fill every robot's state of `tick` from the plant and publish it.
    pub(crate) async fn publish(
        &mut self,
        plant: &impl Plant,
        tick: u64,
    ) -> Result<(), BridgeError> {
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
