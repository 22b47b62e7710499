//! # robot-model
//!
//! One robot as the team knows it, with no transport and no runtime: its rigid-body dynamics
//! from URDF (Pinocchio style: an immutable [`Model`], a preallocated [`Data`] workspace, one
//! file per algorithm, Featherstone's names), its description (the TOML beside the URDF:
//! frames, contacts, torque limits, standing pose; [`Robot`]) and the arm IK ([`ik`]).
//! Load each robot once per process ([`Robot::load`], or [`RobotCache`] for several) and share
//! it (`Arc<Robot>`): the agent, the world builder and the grasp planner all read the same one.
//!
//! * [`model`], [`data`], [`spatial`], [`error`]: `Model`, `Data`, `SE3`/`Motion`/`Force`/
//!   `Inertia`, the typed errors.
//! * [`algorithm`]: kinematics, frame Jacobians, `Jdot v`, CRBA, RNEA, and
//!   [`compute_all_terms`] (the whole per-tick update).
//! * [`parsers`]: URDF to [`Model`] (and composition of URDFs, [`ModelBuilder::attach`]).
//! * [`description`]: [`Robot`], the checked description with its model.
//! * [`ik`]: damped least squares on a frame, rapier-style options and a joint predicate.
//!
//! The default robot (`models/legged_manipulator.{urdf,toml}`) is at [`default_robot_path`].
//!
//! # Coordinates (docs/conventions.md)
//!
//! * Units SI, world z up, gravity 9.81 m/s^2 along -z ([`GRAVITY`]).
//! * Floating base: `q = [p_base (3, world); quaternion (w, x, y, z); joint positions]`,
//!   `nq = 7 + nj`; `v = [base linear velocity in the BASE frame; base angular velocity in the
//!   BASE frame; joint velocities]` (Pinocchio's convention), `nv = 6 + nj`.
//!   MuJoCo's free joint differs (linear velocity in the WORLD frame, angular in the body
//!   frame): convert only with `protocol::conventions` (`base_twist_from_mujoco`,
//!   `base_twist_to_mujoco`, `base_acceleration_to_mujoco`), the project's one place for it.
//! * Fixed base: `q` = joint positions, `v` = joint velocities.
//! * Joint (velocity) order: depth-first traversal of the URDF link tree, children in the
//!   order their joints appear in the file. Revolute and continuous joints have one
//!   coordinate, the angle (continuous joints are not wrapped); prismatic joints the
//!   displacement.
//! * Spatial vectors are `[linear; angular]`; wrenches `[force; moment]`.
//! * Frame Jacobians and `Jdot v` are LOCAL_WORLD_ALIGNED: at the frame origin, world axes,
//!   rows `[linear; angular]`; `Jdot v` is the classical acceleration (with `omega x v`).
//!
//! # Per-tick use
//!
//! ```no_run
//! use robot_model::*;
//! let model = Model::from_urdf_file("robot.urdf", FloatingBase::Yes).unwrap();
//! let mut data = Data::new(&model);
//! let foot = model.frame_id("LF_FOOT").unwrap();
//! let (q, v) = (model.neutral(), nalgebra::DVector::zeros(model.nv));
//! compute_all_terms(&model, &mut data, q.as_slice(), v.as_slice()).unwrap();
//! let mut j = nalgebra::Matrix6xX::zeros(model.nv);
//! frame_jacobian(&model, &data, foot, &mut j).unwrap();
//! let jdv = frame_jdot_v(&model, &data, foot).unwrap();
//! // data.m, data.h, data.g hold M(q), h(q, v), g(q)
//! ```

pub mod algorithm;
pub mod data;
pub mod description;
pub mod error;
pub mod ik;
pub mod model;
pub mod parsers;
pub mod spatial;

pub use algorithm::{
    center_of_mass, compute_all_terms, coriolis_matrix, crba, forward_kinematics, frame_jacobian,
    frame_jacobian_time_variation, frame_jdot_v, frame_placement, frame_velocity, gravity,
    kinetic_energy, nonlinear_effects, point_jacobian, potential_energy, rnea,
    update_frame_placements,
};
pub use data::Data;
pub use description::{
    default_robot_path, DescriptionError, FeetContact, HandContact, HandPoseMismatch, Robot,
    RobotCache,
};
pub use error::{DynamicsError, ModelError};
pub use ik::{IkError, IkOptions, IkSolution};
pub use model::{Body, FloatingBase, Frame, FrameId, FrameKind, JointType, Model, GRAVITY};
pub use parsers::ModelBuilder;
pub use spatial::{Force, Inertia, Motion, SE3};
