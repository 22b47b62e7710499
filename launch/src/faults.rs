//! Faults injected into a run (`[[faults]]` of a scenario, [`scenario::file::Fault`]): at the
//! fault's tick the component fails ([`crate::launcher::Component`]): an agent or the
//! coordinator dies (killed), or an agent stalls (alive but silent); with `restart_after` (or
//! at the end of a stall's `duration`) it is started again (or goes on). The ticks are read
//! from a robot's own state messages, so that a component fails between two ticks of the run
//! as a real process would, whatever the run's pace.

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, TransportError};
use protocol::{RobotState, RunClock};
use tokio::sync::watch;
use tokio::task::JoinHandle;
use zenoh::Session;

use crate::launcher::Component;
use scenario::file::{Fault, FaultKind};

/// A fault with the component it strikes and its ticks.
pub struct Armed {
    pub fault: Fault,
    /// The tick it strikes at.
    pub tick: u64,
    /// The tick the component comes back at (restarted, or its stall over), if it does.
    pub back: Option<u64>,
    /// The robot whose states count the ticks.
    watched: String,
    component: Component,
}

impl Armed {
    /// `fault` on the run's `clock`, striking `component`; `first_robot` counts the ticks of a
    /// coordinator fault.
    pub fn new(fault: &Fault, clock: &RunClock, component: Component, first_robot: &str) -> Self {
        let tick = clock.first_tick_at(fault.at);
        let back = fault
            .restart_after
            .or(fault.duration)
            .map(|d| clock.first_tick_at(fault.at + d).max(tick + 1));
        let watched = fault.robot().unwrap_or(first_robot).to_string();
        Armed { fault: fault.clone(), tick, back, watched, component }
    }

    /// What the fault does to its component at its tick.
    fn strike(&self) {
        let who = self.fault.robot().unwrap_or("coordinator");
        tracing::warn!(component = who, tick = self.tick, kind = ?self.fault.kind, "fault strikes");
        match self.fault.kind {
            FaultKind::AgentStops | FaultKind::CoordinatorStops => self.component.kill(),
            FaultKind::AgentStalls => {
                if let Err(e) = self.component.stall(true) {
                    tracing::error!("fault: {e}");
                }
            }
        }
    }

    /// What happens at the `back` tick: the component starts again, or its stall ends.
    fn recover(&self) {
        let who = self.fault.robot().unwrap_or("coordinator");
        let outcome = match self.fault.kind {
            FaultKind::AgentStops | FaultKind::CoordinatorStops => self.component.start(),
            FaultKind::AgentStalls => self.component.stall(false),
        };
        match outcome {
            Ok(()) => {
                tracing::warn!(
                    component = who,
                    tick = ?self.back,
                    "fault over: the component runs again"
                )
            }
            Err(e) => tracing::error!(component = who, "fault: could not recover: {e}"),
        }
    }
}

/// Watch a robot's states and strike once a state of the fault's tick or later has been sent
/// (the component then never answers it), then recover at the `back` tick. Ends then, or when
/// the run stops.
pub async fn inject(
    session: &Session,
    team: &str,
    armed: Armed,
    mut stop: watch::Receiver<bool>,
) -> Result<JoinHandle<()>, TransportError> {
    let states =
        transport::subscribe(session, keys::robot(team, &armed.watched, RobotTopic::State)?)
            .await?;
    Ok(tokio::spawn(async move {
        let mut struck = false;
        loop {
            tokio::select! {
                s = states.recv_async() => {
                    let Ok(sample) = s else { return };
                    let Ok(tick) =
                        decode_sample::<RobotState>(&sample).map(|st| st.header.tick)
                    else {
                        continue;
                    };
                    if !struck && tick >= armed.tick {
                        armed.strike();
                        struck = true;
                    }
                    match armed.back {
                        Some(back) if struck && tick >= back => {
                            armed.recover();
                            return;
                        }
                        None if struck => return,
                        _ => {}
                    }
                }
                c = stop.changed() => if c.is_err() || *stop.borrow() { return },
            }
        }
    }))
}
