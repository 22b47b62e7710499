//! Where the robot is.
//!
//! * [`zenoh_sim`]: the simulated robot over Zenoh as the asynchronous Zenoh shell
//!   ([`crate::agent`]) drives it (states from the sim-bridge, torques to it).

pub mod zenoh_sim;
