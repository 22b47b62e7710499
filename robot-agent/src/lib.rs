//! # robot-agent
//!
//! One robot of the team. It turns its measured state into the dynamics terms the coordinator
//! needs (DESIGN.md §2 step 2), checks the torque commands it receives and hands them to its
//! torque sink (step 4). The robot itself (URDF model, rigid-body algorithms, the description
//! TOML) is the `robot-model` crate; this crate turns it into protocol messages and runs it.
//!
//! * [`inspect`]: the `robot-agent inspect` report of a model at one state.
//! * [`terms`]: the per-tick dynamics terms (M, h, frame Jacobians and Jdot*v) from the model.
//! * [`agent`]: the agent loop over Zenoh, wiring the modules below together.
//! * [`source`]: where states come from ([`source::StateSource`]; Zenoh today, hardware later).
//! * [`sink`]: where checked torques go ([`sink::TorqueSink`]; the robot's `torque` key).
//! * [`dynamics_source`]: state to dynamics terms ([`dynamics_source::ModelDynamics`] over the
//!   robot's model; [`dynamics_source::PlaceholderDynamics`] for the smoke run only), and the
//!   robot's protocol description ([`dynamics_source::robot_description`]).
//! * [`gate`]: the checks of incoming commands and clamping to the torque limits.
//! * [`safe_mode`]: the watchdog and the posture hold of safe mode.
//! * [`status`]: the agent's status message and counters.

pub mod agent;
pub mod dynamics_source;
pub mod gate;
pub mod inspect;
pub mod safe_mode;
pub mod sink;
pub mod source;
pub mod status;
pub mod terms;
