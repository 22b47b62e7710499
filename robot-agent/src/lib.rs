//! # robot-agent
//!
//! One robot of the team. It turns its measured state into the dynamics terms the coordinator
//! needs (DESIGN.md §2 step 2), checks the torque commands it receives and hands them to its
//! torque sink (step 4).
//!
//! * [`agent`]: the agent loop over Zenoh and the checks of incoming commands.

pub mod agent;
