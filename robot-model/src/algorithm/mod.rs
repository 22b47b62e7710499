//! The rigid-body algorithms, one file each (Pinocchio's `algorithm/`), all free functions of
//! `(&Model, &mut Data, ...)` that allocate nothing after [`crate::Data::new`].

pub mod com;
pub mod compute_all_terms;
pub mod crba;
pub mod jacobian;
pub mod jdot;
pub mod kinematics;
pub mod rnea;

pub use com::center_of_mass;
pub use compute_all_terms::compute_all_terms;
pub use crba::crba;
pub use jacobian::{frame_jacobian, point_jacobian};
pub use jdot::{frame_jacobian_time_variation, frame_jdot_v};
pub use kinematics::{
    forward_kinematics, frame_placement, frame_velocity, kinetic_energy, potential_energy,
    update_frame_placements,
};
pub use rnea::{coriolis_matrix, gravity, nonlinear_effects, rnea};
