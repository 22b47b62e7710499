//! Everything a control tick needs in one pass (Pinocchio's `computeAllTerms`).

use super::{crba, kinematics, rnea};
use crate::data::Data;
use crate::error::DynamicsError;
use crate::model::Model;

/// The whole per-tick update at `(q, v)`: forward kinematics (placements, velocities, bias
/// accelerations of every body and frame), `M(q)` (CRBA), `h(q, v)` and `g(q)` (RNEA) into
/// `data.m`, `data.h`, `data.g`. Frame Jacobians and `Jdot v` can then be read with
/// [`crate::frame_jacobian`] and [`crate::frame_jdot_v`]. Allocation-free.
pub fn compute_all_terms(
    model: &Model,
    data: &mut Data,
    q: &[f64],
    v: &[f64],
) -> Result<(), DynamicsError> {
    model.check_state(q, Some(v))?;
    kinematics::kinematics_pass(model, data, q, Some(v), None);
    crba::crba_from_kinematics(model, data);
    rnea::bias_from_kinematics(model, data);
    Ok(())
}
