//! Where the robot is: a [`RobotHardware`] driven by the robot's loop ([`driver`]), in the
//! shape of ros2_control's hardware interface (`hardware_interface::SystemInterface`). The
//! same loop drives the mock, the simulated robot and a real robot's driver: only the
//! hardware differs.
//!
//! ros2_control's calls, what they are here, and what the robot does in each:
//!
//! - `on_init(params)`, the implementer's constructor: parse its settings; nothing is opened.
//! - `on_configure`, [`RobotHardware::configure`]: connect; states are readable, no torques yet
//!   (INACTIVE).
//! - `on_activate`, [`RobotHardware::activate`]: accept torques (ACTIVE).
//! - `read(time, period)`, [`RobotHardware::read`]: measured joint positions and velocities,
//!   base pose and twist.
//! - `write(time, period)`, [`RobotHardware::write`]: the drive command to execute until the
//!   next write: `tau = tau_ff + kp (q_des - q) + kd (qd_des - qd)` per joint
//!   ([`DriveCommand::effort`]).
//! - `on_deactivate`, [`RobotHardware::deactivate`]: stop taking torques; leave the robot safe
//!   (brakes, damping).
//! - `return_type {OK, ERROR, DEACTIVATE}`, [`HwStatus`]: `Error` stops the loop with
//!   [`driver::DriverError`]; `Deactivate` stops it after safe mode. [`HwStatus::Unreadable`]
//!   is ours: a reading that arrived unusable (a corrupted packet) is counted and skipped.
//! - ros2_control's controller manager calls `read` on its own clock. Here that is
//!   [`ReadTiming::Period`]; a simulator whose states come at its own pace (lockstep or real time)
//!   is [`ReadTiming::Robot`], and the loop reads each state as it arrives.
//!
//! * [`driver`]: the robot's loop: state in, core, terms out, commands in, drive command out,
//!   housekeeping, safe mode, fall, leave.
//! * [`link`]: the loop's non-blocking connection to the team ([`link::TeamLink`]; Zenoh:
//!   [`link::ZenohLink`]).
//! * [`bell`]: the one wake-up the loop waits on, rung by each of its inputs.
//! * [`mock`]: an in-memory robot (unit-inertia joints), ros2_control's
//!   `mock_components::GenericSystem`, for tests and for trying the loop without a robot.
//! * [`sim`]: the simulated robot: states from the sim-bridge, drive commands to its simulated
//!   drives, over Zenoh.
//!
//! # Plugging in a robot
//!
//! Implement [`RobotHardware`] over the robot's SDK, then run [`driver::run`] on a thread of
//! its own with the robot's model ([`crate::dynamics_source::ModelDynamics`]) in an
//! [`AgentCore`](crate::core::AgentCore) and a [`ZenohLink`] to the team:
//!
//! ```no_run
//! use std::sync::atomic::AtomicBool;
//! use std::time::{Duration, Instant};
//!
//! use protocol::transport::{self, Qos, Role, ZenohArgs};
//! use protocol::{DriveCommand, RobotState};
//! use robot_agent::core::{AgentConfig, AgentCore};
//! use robot_model::Robot;
//! use robot_agent::dynamics_source::ModelDynamics;
//! use robot_agent::hardware::{
//!     driver, DriverConfig, HardwareError, HwStatus, RobotHardware, ZenohLink,
//! };
//!
//! /// The lab's robot: its SDK handle (here only the last encoder readings).
//! struct MyRobot {
//!     q: Vec<f64>,
//!     v: Vec<f64>,
//! }
//!
//! impl RobotHardware for MyRobot {
//!     fn joints(&self) -> usize {
//!         self.q.len() // in the description's joint order
//!     }
//!     fn configure(&mut self) -> Result<(), HardwareError> {
//!         Ok(()) // open the bus, check that every drive answers, read the encoders once
//!     }
//!     fn activate(&mut self) -> Result<(), HardwareError> {
//!         Ok(()) // drives to torque mode, zero torque
//!     }
//!     fn deactivate(&mut self) -> Result<(), HardwareError> {
//!         Ok(()) // zero torque, then the drives' own damping or brakes
//!     }
//!     fn read(&mut self, _now: Instant, state: &mut RobotState) -> HwStatus {
//!         // encoders -> joints; the state estimator -> base pose and twist (base frame)
//!         state.joint_positions.copy_from_slice(&self.q);
//!         state.joint_velocities.copy_from_slice(&self.v);
//!         HwStatus::Ok
//!     }
//!     fn write(&mut self, cmd: &DriveCommand) -> HwStatus {
//!         // Per motor, the SDK's low-level command (e.g. tau, q, dq, kp, kd): the drive runs the
//!         // law at its own rate. Without gains (`cmd.kp` empty) it is the torque `tau_ff`.
//!         let _ = cmd;
//!         HwStatus::Ok // a drive fault: HwStatus::Error; the e-stop: HwStatus::Deactivate
//!     }
//! }
//!
//! fn main() -> anyhow::Result<()> {
//!     let model = ModelDynamics::new(Robot::load("models/legged_manipulator.toml")?)?;
//!     let cfg = AgentConfig::new("team", "r1");
//!     let mut core = AgentCore::new(&cfg, model)?;
//!     let rt = tokio::runtime::Runtime::new()?;
//!     let session = rt.block_on(transport::open(&ZenohArgs::default(), Role::Member))?;
//!     let mut link = ZenohLink::declare(&session, &cfg.team, &cfg.robot, Qos::NeverWait)?;
//!     let mut robot = MyRobot { q: vec![0.0; core.joints()], v: vec![0.0; core.joints()] };
//!     let stop = AtomicBool::new(false); // set it from a signal handler to stop
//!     let rate = DriverConfig::new(Duration::from_millis(1)); // 1 kHz
//!     let report = driver::run(&mut core, &mut robot, &mut link, &rate, &stop)?;
//!     println!("{report:?}");
//!     Ok(())
//! }
//! ```

pub mod bell;
pub mod driver;
pub mod link;
pub mod mock;
pub mod sim;

use std::time::Instant;

use protocol::{DriveCommand, RobotState};
use thiserror::Error;

pub use bell::Bell;
pub use driver::{DriverConfig, DriverError, DriverExit, DriverReport};
pub use link::{Inbound, Presence, TeamLink, ZenohLink};
pub use mock::{MockConfig, MockFault, MockHardware};
pub use sim::SimRobot;

/// What [`RobotHardware::read`] and [`RobotHardware::write`] report, as ros2_control's
/// `hardware_interface::return_type`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HwStatus {
    /// Done.
    Ok,
    /// The hardware failed: the loop enters safe mode, deactivates the hardware (best effort)
    /// and stops with [`driver::DriverError::Hardware`].
    Error,
    /// The hardware asks to leave the active state (an e-stop, a fault it can recover from):
    /// the loop enters safe mode, deactivates it and stops with
    /// [`driver::DriverExit::Deactivated`].
    Deactivate,
    /// `read` only: this reading arrived unusable (a corrupted packet, a message that does not
    /// decode). The loop counts it and goes on without a state this time.
    Unreadable,
}

/// Who sets the loop's pace.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadTiming {
    /// The loop reads the robot once every period of its own clock
    /// ([`driver::DriverConfig::period`]), numbers the ticks and stamps their time: a real
    /// robot's drives, the mock.
    Period,
    /// The robot sends its states at its own pace, each with its tick and time (a simulator,
    /// in lockstep or real time): the loop reads each as [`RobotHardware::state_ready`] says
    /// it has arrived, woken by the bell the robot rings ([`Bell`]).
    Robot,
}

/// Why a lifecycle transition ([`RobotHardware::configure`], `activate`, `deactivate`) failed.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("{0}")]
pub struct HardwareError(pub String);

impl HardwareError {
    pub fn new(reason: impl std::fmt::Display) -> Self {
        HardwareError(reason.to_string())
    }
}

/// A robot the loop ([`driver::run`]) can drive. The loop calls, in this order, `configure`,
/// `activate`, then `read` once per state and `write` once per drive command, and
/// `deactivate` when it stops. None of them may block for longer than a fraction of the
/// robot's period.
pub trait RobotHardware {
    /// Actuated joints, in the robot description's velocity order (checked against the model).
    fn joints(&self) -> usize;

    /// Connect (ros2_control `on_configure`). States are readable afterwards; torques are not
    /// taken yet.
    fn configure(&mut self) -> Result<(), HardwareError>;

    /// Start taking torques (ros2_control `on_activate`).
    fn activate(&mut self) -> Result<(), HardwareError>;

    /// Stop taking torques and leave the robot in its own safe state (brakes, damping mode)
    /// (ros2_control `on_deactivate`). Called when the loop stops, for whatever reason.
    fn deactivate(&mut self) -> Result<(), HardwareError>;

    /// Who sets the loop's pace ([`ReadTiming::Period`] unless the robot sends its own states).
    fn timing(&self) -> ReadTiming {
        ReadTiming::Period
    }

    /// [`ReadTiming::Robot`]: whether a state has arrived that `read` has not yet returned. Never
    /// waits.
    fn state_ready(&mut self) -> bool {
        true
    }

    /// Write the measured state into `state` at the loop's time `now`: `joint_positions` and
    /// `joint_velocities` (one entry per actuated joint; the loop sizes them to `joints()`),
    /// `base_pose` and `base_twist` (base linear velocity in the base frame, as everywhere in
    /// the project; a fixed-base robot leaves them as they are). On the loop's clock
    /// ([`ReadTiming::Period`]) the loop owns the header (team, robot, tick, stamp) and `time`; a
    /// [`ReadTiming::Robot`] robot writes the whole state, its tick and time included.
    fn read(&mut self, now: Instant, state: &mut RobotState) -> HwStatus;

    /// Execute `cmd` until the next write (`HwStatus::Unreadable` counts as `Ok` here): per
    /// actuated joint, at the drive's own rate,
    /// `tau = tau_ff + kp (q_des - q) + kd (qd_des - qd)` ([`DriveCommand::effort`]), clamped to
    /// the joint's torque limit. `tau_ff` is already checked and clamped; without gains (`kp`
    /// and `kd` empty) the command is the torque `tau_ff`. Sizes are the robot's (checked).
    /// A drive that only takes torques computes the law at each write from its latest reading.
    fn write(&mut self, cmd: &DriveCommand) -> HwStatus;
}
