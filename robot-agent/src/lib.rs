//! # robot-agent
//!
//! One robot of the team. It turns its measured state into the dynamics terms the coordinator
//! needs (DESIGN.md §2 step 2), checks the torque commands it receives and hands them to its
//! torque sink (step 4).
//!
//! * [`dynamics`]: the robot's model from URDF and its rigid-body algorithms (Pinocchio-style
//!   immutable `Model` and preallocated `Data`, one algorithm per file).
//! * [`description`]: a robot's description (TOML beside its URDF), checked against the URDF.
//! * [`inspect`]: the `robot-agent inspect` report of a model at one state.
//! * [`terms`]: the per-tick dynamics terms (M, h, frame Jacobians and Jdot*v) from the model.
//! * [`agent`]: the agent loop over Zenoh and the checks of incoming commands.

pub mod agent;
pub mod description;
pub mod dynamics;
pub mod inspect;
pub mod terms;
