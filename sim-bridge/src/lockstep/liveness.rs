//! The liveliness of the run's components while the lockstep loop runs: agents that leave or
//! join, the coordinator's outages.

use std::time::{Duration, Instant};

use protocol::transport::{self, MemberEvent};
use zenoh::Session;

use super::config::BridgeError;

/// A robot's agent that left or joined the team during a run (index in the plant's robots).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum AgentChange {
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
pub(super) struct Liveness {
    members: transport::EventQueue,
    coordinator: transport::EventQueue,
    coordinator_lost: Option<u64>,
    /// The coordinator came back after an outage (taken by [`Liveness::take_returned`]).
    returned: bool,
    /// Wall instant and simulated time at which the outage's pacing started.
    outage_clock: Option<(Instant, f64)>,
}

/// What the liveliness queues said.
pub(super) enum LivenessEvent {
    Member(zenoh::sample::Sample),
    Coordinator(zenoh::sample::Sample),
    Closed,
}

impl Liveness {
    pub(super) async fn open(session: &Session, team: &str) -> Result<Self, BridgeError> {
        Ok(Liveness {
            members: transport::watch_members(session, team).await?,
            coordinator: transport::watch_coordinator(session, team).await?,
            coordinator_lost: None,
            returned: false,
            outage_clock: None,
        })
    }

    /// Whether the coordinator came back since the last call.
    pub(super) fn take_returned(&mut self) -> bool {
        std::mem::take(&mut self.returned)
    }

    /// Before a tick at simulated time `sim_time`: while the coordinator is gone, wait until
    /// the wall clock has caught up with the simulated time since the outage began.
    pub(super) async fn pace_outage(&mut self, sim_time: f64) {
        if self.coordinator_lost.is_none() {
            self.outage_clock = None;
            return;
        }
        let (wall0, sim0) = *self.outage_clock.get_or_insert((Instant::now(), sim_time));
        let due = wall0 + Duration::from_secs_f64((sim_time - sim0).max(0.0));
        tokio::time::sleep_until(due.into()).await;
    }

    pub(super) async fn next(&self) -> LivenessEvent {
        tokio::select! {
            m = self.members.recv_async() => m.map_or(LivenessEvent::Closed, LivenessEvent::Member),
            c = self.coordinator.recv_async() => {
                c.map_or(LivenessEvent::Closed, LivenessEvent::Coordinator)
            }
        }
    }

    /// Take one event during `tick`: a robot of `robots` whose agent left or joined.
    pub(super) fn take(
        &mut self,
        ev: LivenessEvent,
        tick: u64,
        robots: &[String],
    ) -> Result<Option<AgentChange>, BridgeError> {
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
    pub(super) fn check(&mut self, tick: u64, grace: u64) -> Result<(), BridgeError> {
        while let Ok(s) = self.coordinator.try_recv() {
            self.take(LivenessEvent::Coordinator(s), tick, &[])?;
        }
        match self.coordinator_lost {
            Some(since) if tick.saturating_sub(since) >= grace => {
                Err(BridgeError::CoordinatorLost { since, ticks: tick - since })
            }
            _ => Ok(()),
        }
    }
}
