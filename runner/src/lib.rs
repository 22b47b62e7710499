//! # team-runner
//!
//! Runs a whole team: the sim-bridge, one robot-agent per robot and the coordinator.
//!
//! * [`smoke`]: the smoke run of the foundation: placeholder dynamics, controller and plant,
//!   real Zenoh messages, embedded (every component in one process on one session) or
//!   distributed (every component its own process, on loopback).
//! * [`processes`]: the team's binaries as child processes on loopback.
//! * [`scenario`]: scenario files (TOML) with `--set key=value` overrides.
//! * [`reference`]: the scenarios' reference trajectories.
//! * [`metrics`]: the measures of success of DESIGN.md §8.
//! * [`report`]: CSV time series, `metrics.json` and plots of a run.

pub mod metrics;
pub mod processes;
pub mod reference;
pub mod report;
pub mod scenario;
pub mod smoke;
