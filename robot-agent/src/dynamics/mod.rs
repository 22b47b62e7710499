//! Rigid-body dynamics of one robot from its URDF, Pinocchio style: an immutable [`Model`], a
//! preallocated [`Data`] workspace, and one file per algorithm (Featherstone's names).
//!
//! # Coordinates (DESIGN.md §3)
//!
//! * Units SI, world z up, gravity 9.81 m/s^2 along -z.
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
//! use robot_agent::dynamics::*;
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

pub mod crba;
pub mod data;
pub mod error;
pub mod jacobian;
pub mod jdot;
pub mod kinematics;
pub mod model;
pub mod rnea;
pub mod spatial;
pub mod urdf;

pub use crba::crba;
pub use data::Data;
pub use error::{DynamicsError, ModelError};
pub use jacobian::{frame_jacobian, point_jacobian};
pub use jdot::{frame_jacobian_time_variation, frame_jdot_v};
pub use kinematics::{forward_kinematics, frame_placement, frame_velocity, kinetic_energy, potential_energy, update_frame_placements};
pub use model::{Body, FloatingBase, Frame, FrameId, FrameKind, JointType, Model, GRAVITY};
pub use rnea::{coriolis_matrix, gravity, nonlinear_effects, rnea};
pub use spatial::{Force, Inertia, Motion, SE3};
pub use urdf::ModelBuilder;

/// The whole per-tick update at `(q, v)`: forward kinematics (placements, velocities, bias
/// accelerations of every body and frame), `M(q)` (CRBA), `h(q, v)` and `g(q)` (RNEA) into
/// `data.m`, `data.h`, `data.g`. Frame Jacobians and `Jdot v` can then be read with
/// [`frame_jacobian`] and [`frame_jdot_v`]. Allocation-free.
pub fn compute_all_terms(model: &Model, data: &mut Data, q: &[f64], v: &[f64]) -> Result<(), DynamicsError> {
    model.check_state(q, Some(v))?;
    kinematics::kinematics_pass(model, data, q, Some(v), None);
    crba::crba_from_kinematics(model, data);
    rnea::bias_from_kinematics(model, data);
    Ok(())
}
