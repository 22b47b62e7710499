//! The stages of one PIDC tick, in the order [`super::Pidc::compute`] runs them, each a
//! function of typed inputs writing into buffers kept between ticks (tests call them alone):
//!
//! * [`tasks`]: each task's target, the object's load `F_x`, `M_c^{-1} P` terms, `tau_M`
//!   (eqs. control_law, joint_space_tau_M, js_dynamics).
//! * [`wrench`]: the contact map `lambda = rho F_c + eta`, and `lambda` for the torque sent
//!   (eqs. relation_between_lambda_and_Fc, constraint_force).
//! * [`torque`]: `tau_0 = [P S]^+ P tau_M`, the fallback `F_c`, `tau = tau_0 + Y F_c` (eq.
//!   ua_solution).
//! * [`yielding`]: a QP infeasible at the tick's motion solved with the motion yielding (the
//!   object's first) (eqs. control_law, wrench_optim2).
//! * [`acceleration`]: the team's accelerations under the torque sent (for the team's delay)
//!   (eq. aghili_25).
//! * [`by_robot`]: a team's QP that failed, solved robot by robot when no grasp couples them
//!   (eq. wrench_optim2 by blocks).
//!
//! Before them run the team's assembly ([`crate::team::Team::assemble_into`]), the torque
//! limits ([`crate::building_blocks::limits`]), the grasp
//! ([`crate::building_blocks::grasp::GraspTracker`]) and
//! the contacts (`J_c`, `Jdot_c v`: [`crate::building_blocks::contact_jacobian`]); between them the
//! projections ([`crate::building_blocks::projection::Projections`]), the contact list
//! ([`crate::building_blocks::contacts`]) and the contact-force QP ([`crate::qp::solve`]).

pub mod acceleration;
pub mod by_robot;
pub mod tasks;
pub mod torque;
pub mod wrench;
pub mod yielding;
