//! # planner
//!
//! The team's planning, pure and deterministic: where the robots stand around the object,
//! where their hands go on it, the reference trajectories the scenarios ask for, and the static
//! walk (crawl) that carries the object. It knows neither the bus (Zenoh) nor the simulator
//! (MuJoCo): its inputs are the robots' own models (`robot_model::Robot`) and small geometric
//! types of its own ([`placement::ObjectBox`], [`placement::BasePlacement`]); its outputs are
//! poses, joint positions and the protocol's reference and contact-set messages. The runner
//! (`team-runner`) composes it with the simulator's world and the controller's configuration.
//!
//! * [`placement`]: robots on a ring or along the object's faces, their footprints, and the
//!   refusal of robots that would stand in each other.
//! * [`grasp`]: where the hands start: flat on the object's faces (arm IK from
//!   `robot_model::ik`), and each hand's pose on the object as planned.
//! * [`reference`]: the scenarios' reference trajectories (holds, sinusoids, circles,
//!   sequences) with exact velocities and accelerations.
//! * [`gait`]: the static walk (crawl) planner: steps, CoM shifts, swing trajectories, ramps.
//! * [`walk`]: a scenario's walk: its specification, the crawl planned from its waypoints
//!   and the robots' standing poses, the arm's reach along it, and the references and contact
//!   sets a run sends for it.

pub mod gait;
pub mod grasp;
pub mod placement;
pub mod reference;
pub mod walk;
