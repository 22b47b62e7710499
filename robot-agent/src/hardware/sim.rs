//! The simulated robot as a [`RobotHardware`]: its states come from the sim-bridge on
//! `team/{team}/robot/{id}/state`, each with the simulator's tick and time, and its drive
//! commands go to `team/{team}/robot/{id}/torque`, which the simulated drives execute at every
//! physics step. The simulator sets the pace ([`ReadTiming::Robot`]): in lockstep it steps once
//! every robot's drive command of the tick is in, in real time on the wall clock.

use std::time::Instant;

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, SampleQueue, TransportError, TypedPublisher};
use protocol::{DriveCommand, RobotState};
use zenoh::sample::Sample;
use zenoh::Session;

use super::{Bell, HardwareError, HwStatus, ReadTiming, RobotHardware};

/// The simulated robot over Zenoh. See the module documentation.
pub struct SimRobot {
    robot: String,
    joints: usize,
    /// The simulator's states, first in first out (the oldest dropped beyond
    /// [`transport::QUEUE_CAPACITY`]), each ringing the loop's bell.
    states: SampleQueue,
    /// A state taken from the queue by [`RobotHardware::state_ready`], not yet read.
    pending: Option<Sample>,
    drives: TypedPublisher<DriveCommand>,
    /// Readings that did not decode, for the log.
    unreadable: u64,
}

impl SimRobot {
    /// Subscribe to the robot's states (ringing `bell`, the loop's: normally
    /// [`super::ZenohLink::bell`]) and declare its drive commands' publisher.
    pub fn declare(
        session: &Session,
        team: &str,
        robot: &str,
        joints: usize,
        bell: Bell,
    ) -> Result<Self, TransportError> {
        let key = |t| keys::robot(team, robot, t);
        let states = transport::subscribe_notifying(
            session,
            key(RobotTopic::State)?,
            transport::QUEUE_CAPACITY,
            move || bell.ring(),
        )?;
        // Never dropped: in lockstep the simulator waits for every drive command of a tick.
        let drives = TypedPublisher::declare_wait(session, key(RobotTopic::Torque)?, Qos::HotPath)?;
        Ok(SimRobot {
            robot: robot.to_string(),
            joints,
            states,
            pending: None,
            drives,
            unreadable: 0,
        })
    }
}

impl RobotHardware for SimRobot {
    fn joints(&self) -> usize {
        self.joints
    }

    fn configure(&mut self) -> Result<(), HardwareError> {
        Ok(())
    }

    fn activate(&mut self) -> Result<(), HardwareError> {
        Ok(())
    }

    /// Nothing to do: the simulated drives hold the last command until it expires, then their
    /// own safe state (the sim-bridge's drive timeout).
    fn deactivate(&mut self) -> Result<(), HardwareError> {
        Ok(())
    }

    fn timing(&self) -> ReadTiming {
        ReadTiming::Robot
    }

    fn state_ready(&mut self) -> bool {
        if self.pending.is_none() {
            // A closed subscription gives nothing more: the watchdog takes it from there.
            self.pending = self.states.handler().try_recv().ok().flatten();
        }
        self.pending.is_some()
    }

    fn read(&mut self, _now: Instant, state: &mut RobotState) -> HwStatus {
        let Some(sample) = self.pending.take() else { return HwStatus::Unreadable };
        match decode_sample::<RobotState>(&sample) {
            Ok(s) => {
                *state = s;
                HwStatus::Ok
            }
            Err(e) => {
                self.unreadable += 1;
                if self.unreadable.is_power_of_two() {
                    let times = self.unreadable;
                    tracing::warn!(robot = %self.robot, times, "state unreadable: {e}");
                }
                HwStatus::Unreadable
            }
        }
    }

    fn write(&mut self, cmd: &DriveCommand) -> HwStatus {
        match self.drives.put_wait(cmd) {
            Ok(()) => HwStatus::Ok,
            Err(e) => {
                tracing::warn!(robot = %self.robot, "drive command not sent: {e}");
                HwStatus::Error
            }
        }
    }
}
