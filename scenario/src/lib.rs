//! # scenario
//!
//! A scenario file and its plan: what every component of a run gets, checked before anything
//! runs. The runner, the tests and the experiments read scenarios through this crate; it starts
//! nothing and talks to no one.
//!
//! From the bottom up:
//!
//! * [`file`]: scenario files (TOML) with `--set key=value` overrides ([`Scenario`]).
//! * [`pace`]: lockstep or real time, and the loop each runs with ([`pace::Pacing`]).
//! * [`layout`]: the planner on the simulator's world spec: where the robots stand and where
//!   their hands go on the object, and the grasp handed to the controller.
//! * [`references`]: the task references of a run as a function of the tick
//!   ([`ReferencePlan`]).
//! * [`payload`]: the payload check: the static team problem at the start pose, and
//!   [`payload::motion`] along the whole motion.
//! * [`plan`]: a scenario turned into what each component runs ([`Plan`]: scene, controller,
//!   references, the loaded robots); it refuses a load the team cannot hold.
//! * [`team_capacity`]: the heaviest object a plan's team holds (`team capacity`).

pub mod file;
pub mod layout;
pub mod pace;
pub mod payload;
pub mod plan;
pub mod references;
pub mod team_capacity;

pub use file::{Scenario, ScenarioError};
pub use pace::Pacing;
pub use plan::{plan, Plan, PlanError};
pub use references::ReferencePlan;

/// The team's name on the bus when a run is given none ([`Plan::set_team`]).
pub const TEAM: &str = "team";
