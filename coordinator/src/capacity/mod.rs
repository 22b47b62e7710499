//! Payload capacity: the static team problem at a pose (every robot at rest, `v = 0`).
//!
//! Given one tick's dynamics terms of the team at rest (so `h = g(q)`), the robots'
//! descriptions and the controller's [`ContactMargins`] (margins and minimum forces), find contact
//! wrenches `lambda` (3 per stance foot, 6 per hand in grasp, world-aligned, acting ON the
//! robot, the real hand wrenches) such that
//!
//! * every robot's unactuated base rows balance: `S_u (J_c^T lambda - g) = 0` (eq. js_dynamics
//!   at `v = 0`, `vdot = 0`), with `J_c = [J_cf; J_ee]` (the hands' own Jacobians: the object
//!   is not in the generalized coordinates, its weight comes through the hands);
//! * every actuated joint's torque `tau = g_a - J_c,a^T lambda` stays within `|tau| <= tau_max`
//!   (eq. original_torque_limit);
//! * the object balances: `G lambda_hands = m [g_vec; 0]` at its centre (eq. graspmatrix; the
//!   object pushes each palm with `-lambda_k`);
//! * every contact keeps the controller's rows (eqn. unilateral_and_friction_cone_constraint,
//!   eqn. moment_constraint) with the controller's margins and minimum forces: the rows are
//!   [`crate::qp::contact_rows`] of [`crate::building_blocks::contacts::contact_list`], the torque
//!   limits [`crate::building_blocks::limits::torque_limits`], `G`
//!   [`crate::building_blocks::grasp::GraspTerms`].
//!
//! At rest the controller's QP has no task acceleration to produce, so any `lambda` it may
//! choose must satisfy this problem: a scenario this problem refuses, the controller's QP
//! cannot solve at its start either.
//!
//! Feasibility is decided by the relaxed problem (one slack per limit row, minimise the total
//! slack, [`StaticProblem::relaxed`]): feasible when no slack exceeds [`FEASIBILITY_TOL`].
//! Its slacks name the binding limits ([`BindingLimit`]). The capacity
//! ([`StaticProblem::capacity`]) is found by bisection on the mass with the same test; the
//! feasible masses form an interval (the feasible `(lambda, m)` is a convex polyhedron), so
//! bisection between a feasible and an infeasible mass is exact to its tolerance.
//!
//! * [`problem`]: the rows (equalities, limit rows with their names, objective);
//! * [`solve`]: Clarabel on the hard problem and on the relaxed one, the bisection;
//! * [`report`]: [`CapacityError`], [`BindingLimit`].

pub mod limits;
pub mod problem;
pub mod report;
pub mod solve;

pub use limits::{Limit, LimitRow, Place};
pub use problem::StaticProblem;
pub use report::{BindingLimit, CapacityError};
pub use solve::{
    Capacity, Relaxed, StaticSolution, CAPACITY_TOLERANCE, FEASIBILITY_TOL, REACHED_TOL,
};

#[cfg(doc)]
use crate::building_blocks::contact_margins::ContactMargins;
