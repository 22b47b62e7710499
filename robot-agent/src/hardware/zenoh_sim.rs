//! The simulated robot over Zenoh, as the asynchronous Zenoh shell ([`crate::agent`]) drives it:
//! states come from the sim-bridge on `team/{team}/robot/{id}/state` ([`ZenohStateSource`]),
//! checked torques go to `team/{team}/robot/{id}/torque`, which the sim-bridge applies
//! ([`ZenohTorqueSink`]). The traits [`StateSource`] and [`TorqueSink`] are the shell's
//! asynchronous counterparts of [`super::RobotHardware::read`] and
//! [`super::RobotHardware::write`].

use std::future::Future;

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, SampleQueue, TransportError, TypedPublisher};
use protocol::{DriveCommand, RobotState};
use zenoh::Session;

/// What a state source yields. A state is carried by value, not boxed: one comes every tick,
/// and the tick allocates nothing.
#[derive(Debug)]
#[allow(clippy::large_enum_variant)]
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

/// Takes drive commands of checked, clamped torques (commanded or safe mode) and applies them.
pub trait TorqueSink: Send {
    fn apply(
        &mut self,
        drive: &DriveCommand,
    ) -> impl Future<Output = Result<(), TransportError>> + Send;
}

/// States published by the sim-bridge (or any state source) on `team/{team}/robot/{id}/state`.
pub struct ZenohStateSource {
    queue: SampleQueue,
}

impl ZenohStateSource {
    pub async fn subscribe(
        session: &Session,
        team: &str,
        robot: &str,
    ) -> Result<Self, TransportError> {
        let queue =
            transport::subscribe(session, keys::robot(team, robot, RobotTopic::State)?).await?;
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

/// Publishes the drive commands on `team/{team}/robot/{id}/torque` (hot-path QoS), which the
/// simulated drives execute at every physics step.
pub struct ZenohTorqueSink {
    publisher: TypedPublisher<DriveCommand>,
}

impl ZenohTorqueSink {
    pub async fn declare(
        session: &Session,
        team: &str,
        robot: &str,
    ) -> Result<Self, TransportError> {
        let key = keys::robot(team, robot, RobotTopic::Torque)?;
        Ok(ZenohTorqueSink {
            publisher: TypedPublisher::declare(session, key, Qos::HotPath).await?,
        })
    }
}

impl TorqueSink for ZenohTorqueSink {
    async fn apply(&mut self, drive: &DriveCommand) -> Result<(), TransportError> {
        self.publisher.put(drive).await
    }
}
