//! Faults injected into a run (`[[faults]]` of a scenario, [`crate::scenario::Fault`]): at the
//! fault's tick the robot's agent is killed ([`crate::launch::AgentKill`]). The tick is read from
//! the robot's own state messages, so that the agent dies between two ticks of the run as a real
//! process would, whatever the run's pace.

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, TransportError};
use protocol::{RobotState, RunClock};
use tokio::sync::watch;
use tokio::task::JoinHandle;
use zenoh::Session;

use crate::launch::AgentKill;
use crate::scenario::{Fault, FaultKind};

/// A fault with its kill switch and the tick it strikes at.
pub struct Armed {
    pub fault: Fault,
    pub tick: u64,
    kill: AgentKill,
}

impl Armed {
    /// `fault` on the run's `clock`, with the agent's kill switch.
    pub fn new(fault: &Fault, clock: &RunClock, kill: AgentKill) -> Self {
        Armed { fault: fault.clone(), tick: clock.first_tick_at(fault.at), kill }
    }
}

/// Watch the faulty robot's states and kill its agent once a state of the fault's tick or later
/// has been sent (the agent then never answers it). Ends at the kill, or when the run stops.
pub async fn inject(session: &Session, team: &str, armed: Armed, mut stop: watch::Receiver<bool>) -> Result<JoinHandle<()>, TransportError> {
    let FaultKind::AgentStops = armed.fault.kind;
    let states = transport::subscribe(session, keys::robot(team, &armed.fault.robot, RobotTopic::State)?).await?;
    Ok(tokio::spawn(async move {
        loop {
            tokio::select! {
                s = states.recv_async() => {
                    let Ok(sample) = s else { return };
                    if decode_sample::<RobotState>(&sample).is_ok_and(|st| st.header.tick >= armed.tick) {
                        tracing::warn!(robot = %armed.fault.robot, tick = armed.tick, "fault: the robot's agent is killed");
                        armed.kill.kill();
                        return;
                    }
                }
                c = stop.changed() => if c.is_err() || *stop.borrow() { return },
            }
        }
    }))
}
