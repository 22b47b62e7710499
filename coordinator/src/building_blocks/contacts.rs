//! The contacts a tick's rows constrain: every stance foot (eq.
//! unilateral_and_friction_cone_constraint) and every hand in grasp (with eq.
//! moment_constraint), with the robot's friction and patch scaled by the [`ContactMargins`]
//! ([`contact_list`]), and the references' unloading ramps on the feet ([`unload_feet`]).
//! PIDC's and MQP's QPs and the static team problem ([`crate::capacity`]) read this list.

use std::collections::BTreeMap;

use protocol::{FootLoad, RobotDescription};

use crate::building_blocks::contact_margins::ContactMargins;
use crate::qp::ContactKind;
use crate::team::Team;
use crate::ControllerError;

/// The QP's contacts into `out`: `(first row in J_c, kind)` for every stance foot (friction
/// pyramid and minimum normal force) and every hand in grasp (its contact frame's axes, the
/// sliding-and-torsion, normal-force and centre-of-pressure rows), with the robot's friction and
/// patch sizes scaled by the `margins`.
pub fn contact_list(
    team: &Team,
    descriptions: &BTreeMap<String, RobotDescription>,
    margins: &ContactMargins,
    out: &mut Vec<(usize, ContactKind)>,
) -> Result<(), ControllerError> {
    let description = |robot: usize| {
        let id = &team.robots[robot].id;
        descriptions
            .get(id)
            .ok_or_else(|| ControllerError::MissingDescription { robot: id.clone() })
    };
    let nf = team.feet.len();
    out.clear();
    for (k, f) in team.feet.iter().enumerate() {
        let d = description(f.robot)?;
        out.push((
            3 * k,
            ContactKind::Foot {
                mu: d.foot_mu * margins.friction_margin,
                f_min: margins.f_min_foot,
                f_max: f64::INFINITY,
            },
        ));
    }
    for (k, h) in team.hands.iter().enumerate() {
        let d = description(h.robot)?;
        let rot = h.rotation.matrix();
        out.push((
            3 * nf + 6 * k,
            ContactKind::Hand {
                tx: rot.column(0).into(),
                ty: rot.column(1).into(),
                n: rot.column(2).into(),
                mu: d.hand_mu * margins.friction_margin,
                xi: d.hand_xi * margins.friction_margin,
                half: [
                    d.hand_half_size[0] * margins.patch_margin,
                    d.hand_half_size[1] * margins.patch_margin,
                ],
                f_min: margins.f_min_hand,
            },
        ));
    }
    Ok(())
}

/// The unloading ramps of the references (`loads`): each stance foot named there gets its
/// upper bound on the normal force (eq. unilateral_and_friction_cone_constraint with
/// `f_z <= f_max`, see [`crate::qp::contact_rows`]). `out` is [`contact_list`]'s: the feet
/// first, in the team's order.
pub fn unload_feet(team: &Team, loads: &[FootLoad], out: &mut [(usize, ContactKind)]) {
    if loads.is_empty() {
        return;
    }
    for (f, (_, kind)) in team.feet.iter().zip(out.iter_mut()) {
        let id = &team.robots[f.robot].id;
        if let (Some(l), ContactKind::Foot { f_max, .. }) =
            (loads.iter().find(|l| l.robot == *id && l.frame == f.name), kind)
        {
            *f_max = l.max_normal_force;
        }
    }
}
