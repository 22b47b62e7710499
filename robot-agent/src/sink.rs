//! Where the checked torques go: a [`TorqueSink`]. Today the robot's `torque` key, which the
//! sim-bridge applies ([`ZenohTorqueSink`]); a hardware driver implements the same trait.

use std::future::Future;

use protocol::keys::{self, RobotTopic};
use protocol::transport::{Qos, TransportError, TypedPublisher};
use protocol::TorqueCommand;
use zenoh::Session;

/// Takes checked, clamped torques (commanded or safe mode) and applies them.
pub trait TorqueSink: Send {
    fn apply(&mut self, torques: &TorqueCommand) -> impl Future<Output = Result<(), TransportError>> + Send;
}

/// Publishes the torques on `team/{team}/robot/{id}/torque` (hot-path QoS).
pub struct ZenohTorqueSink {
    publisher: TypedPublisher<TorqueCommand>,
}

impl ZenohTorqueSink {
    pub async fn declare(session: &Session, team: &str, robot: &str) -> Result<Self, TransportError> {
        let key = keys::robot(team, robot, RobotTopic::Torque)?;
        Ok(ZenohTorqueSink { publisher: TypedPublisher::declare(session, key, Qos::HotPath).await? })
    }
}

impl TorqueSink for ZenohTorqueSink {
    async fn apply(&mut self, torques: &TorqueCommand) -> Result<(), TransportError> {
        self.publisher.put(torques).await
    }
}
