//! # team-runner
//!
//! Runs a whole team: the sim-bridge, one robot-agent per robot and the coordinator.
//!
//! * [`smoke`]: the smoke run of the foundation: placeholder dynamics, controller and plant,
//!   real Zenoh messages, embedded (every component in one process on one session) or
//!   distributed (every component its own process, on loopback).

pub mod smoke;
