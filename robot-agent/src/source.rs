//! Where the agent's state comes from: a [`StateSource`]. Today the sim-bridge over Zenoh
//! ([`ZenohStateSource`]); a hardware driver implements the same trait.

use std::future::Future;

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, SampleQueue, TransportError};
use protocol::RobotState;
use zenoh::Session;

/// What a state source yields.
#[derive(Debug)]
pub enum StateEvent {
    /// A decoded, validated state.
    State(RobotState),
    /// Something arrived that is not a valid state (the reason, for the log).
    Invalid(String),
    /// The source has ended (session closed, driver stopped).
    Closed,
}

/// A source of the robot's measured states.
pub trait StateSource: Send {
    /// The next state. Must be cancel-safe: the agent awaits it in a `select!` with its other
    /// inputs, and a state must not be lost when another input wins.
    fn next(&mut self) -> impl Future<Output = StateEvent> + Send;
}

/// States published by the sim-bridge (or any state source) on `team/{team}/robot/{id}/state`.
pub struct ZenohStateSource {
    queue: SampleQueue,
}

impl ZenohStateSource {
    pub async fn subscribe(session: &Session, team: &str, robot: &str) -> Result<Self, TransportError> {
        let queue = transport::subscribe(session, keys::robot(team, robot, RobotTopic::State)?).await?;
        Ok(ZenohStateSource { queue })
    }
}

impl StateSource for ZenohStateSource {
    async fn next(&mut self) -> StateEvent {
        // flume's recv_async is cancel-safe: a sample stays queued if the future is dropped.
        match self.queue.recv_async().await {
            Ok(sample) => match decode_sample::<RobotState>(&sample) {
                Ok(s) => StateEvent::State(s),
                Err(e) => StateEvent::Invalid(e.to_string()),
            },
            Err(_) => StateEvent::Closed,
        }
    }
}
