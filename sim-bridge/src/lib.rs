//! # sim-bridge
//!
//! Stands in for the robots' hardware: it publishes each robot's state every control tick
//! and applies the torques that come back (docs/architecture.md, one tick, steps 1 and 5).
//!
//! * [`plant`]: what is simulated (the [`plant::Plant`] trait).
//! * [`lockstep`]: the lockstep loop over Zenoh: a tick advances only when every robot's
//!   torques for it have arrived; a missing robot is named in a timeout error.
//! * [`world`]: the MuJoCo world built from the robots' URDFs with mjSpec, checked against
//!   the robots' own models (`robot_model::Robot`, loaded once by the caller and shared).
//! * [`mujoco_plant`]: the [`plant::Plant`] over that world.
//! * [`perturbation`]: timed external wrenches.
//!
//! Where robots stand around the object is planning (`planner::placement`); the world takes
//! the placements it is given ([`world::RobotPlacement`]).

// Index loops over MuJoCo's raw arrays read more plainly than iterator chains; the crate's
// rust-version (1.85) predates `is_multiple_of`.
#![allow(clippy::needless_range_loop, clippy::manual_is_multiple_of, unknown_lints)]

pub mod ground_truth;
pub mod lockstep;
pub mod mujoco_plant;
pub mod perturbation;
pub mod plant;
pub mod realtime;
pub mod scene;
pub mod world;
