//! The team's actuated joints and their torque limits (eq. original_torque_limit: `S_ns` and
//! `tau_max`), from each robot's description.

use std::collections::BTreeMap;

use protocol::RobotDescription;

use crate::team::Team;
use crate::ControllerError;

/// Torque limit given to the base coordinates when they are treated as actuated (the
/// `fully_actuated` comparison): large enough never to bind.
pub const UNBOUNDED_BASE_LIMIT: f64 = 1e9;

/// The team velocity indices of the actuated joints (robot order) into `actuated` and their
/// torque limits into `limits`. With `fully_actuated` (`S = I`) each floating base's six
/// coordinates come first, with [`UNBOUNDED_BASE_LIMIT`]. Errors when a robot has no
/// description or its description disagrees with its terms.
pub fn torque_limits(
    team: &Team,
    descriptions: &BTreeMap<String, RobotDescription>,
    fully_actuated: bool,
    actuated: &mut Vec<usize>,
    limits: &mut Vec<f64>,
) -> Result<(), ControllerError> {
    limits.clear();
    actuated.clear();
    for rb in &team.robots {
        let d = descriptions
            .get(&rb.id)
            .ok_or_else(|| ControllerError::MissingDescription { robot: rb.id.clone() })?;
        if d.torque_limits.len() != rb.actuated.len() || d.nv as usize != rb.nv {
            return Err(ControllerError::Dimension {
                what: format!("{}: description", rb.id),
                detail: format!(
                    "{} limits / nv {} vs {} actuated joints / nv {}",
                    d.torque_limits.len(),
                    d.nv,
                    rb.actuated.len(),
                    rb.nv
                ),
            });
        }
        if fully_actuated {
            let base = rb.nv - rb.actuated.len();
            actuated.extend(rb.offset..rb.offset + base);
            limits.extend(std::iter::repeat_n(UNBOUNDED_BASE_LIMIT, base));
        }
        actuated.extend(&rb.actuated);
        limits.extend(&d.torque_limits);
    }
    Ok(())
}
