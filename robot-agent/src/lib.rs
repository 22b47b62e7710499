//! # robot-agent
//!
//! One robot of the team. It turns its measured state into the dynamics terms the coordinator
//! needs (docs/architecture.md, one tick, step 2), checks the torque commands it receives and
//! hands them to the robot (step 4). The robot itself (URDF model, rigid-body algorithms, the
//! description TOML) is the `robot-model` crate; this crate turns it into protocol messages and
//! runs it.
//!
//! * [`inspect`]: the `robot-agent inspect` report of a model at one state.
//! * [`terms`]: the per-tick dynamics terms (M, h, frame Jacobians and Jdot*v) from the model.
//! * [`core`]: the agent's logic without I/O ([`core::AgentCore`]: `on_state`, `on_command`,
//!   `on_contacts`, `on_timer`, each returning what to send or apply).
//! * [`agent`]: a simulated robot's agent (`robot-agent run`, every agent of `team run`): the
//!   robot's loop over the simulated robot, on a thread of its own.
//! * [`hardware`]: the robot behind a ros2_control-style [`hardware::RobotHardware`] trait and
//!   the one loop that drives every robot, simulated or real ([`hardware::driver`]), its Zenoh
//!   link, the bell its waits share ([`hardware::Bell`]), an in-memory mock robot, and the
//!   simulated robot over Zenoh ([`hardware::SimRobot`]).
//! * [`dynamics_source`]: state to dynamics terms ([`dynamics_source::ModelDynamics`] over the
//!   robot's model; [`dynamics_source::PlaceholderDynamics`] for the smoke run and the mock),
//!   and the robot's protocol description ([`dynamics_source::robot_description`]).
//! * [`contact_switch`]: the contact sets' schedule, lift-offs and force-confirmed touchdowns.
//! * [`delay`]: the team's delay, fixed or raised from the latency the agent measures.
//! * [`drive_gains`]: the gains sent with each drive command (none: the paper's torque loop;
//!   or from each joint's inertia).
//! * [`gate`]: the checks of incoming commands and clamping to the torque limits.
//! * [`safe_mode`]: the watchdog and the posture hold of safe mode.
//! * [`fall`]: a fallen robot goes limp and leaves its team.
//! * [`status`]: the agent's status message and counters.

pub mod agent;
pub mod contact_switch;
pub mod core;
pub mod delay;
pub mod drive_gains;
pub mod dynamics_source;
pub mod early_commands;
pub mod fall;
pub mod gate;
pub mod hardware;
pub mod inspect;
pub mod safe_mode;
pub mod standing;
pub mod status;
pub mod terms;
