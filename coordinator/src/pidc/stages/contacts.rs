//! The contacts of a tick: the constraint Jacobian `J_c = [J_cf; J_c,ee]` with its `Jdot_c v`
//! (eq. jacobian_c), and the list of contacts the QP constrains (eqn.
//! unilateral_and_friction_cone_constraint for feet, with eqn. moment_constraint for hands).

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector};
use protocol::{FootLoad, RobotDescription};

use crate::linalg::{shape, zeros_v};
use crate::pidc::PidcConfig;
use crate::qp::ContactKind;
use crate::team::Team;
use crate::units::grasp::GraspTerms;
use crate::ControllerError;

/// `J_c = [J_cf; J_c,ee]` (eq. jacobian_c) and `Jdot_c v = [Jdot_cf v; d/dt(J_c,ee) v]` into
/// `j_c` (`3 nf + 6 B` x n) and `jdv_c`: the stance feet's rows, then the grasp's (zero rows
/// for the hands in grasp when there is no grasp).
pub fn contact_jacobian(team: &Team, grasp: Option<&GraspTerms>, j_c: &mut DMatrix<f64>, jdv_c: &mut DVector<f64>) {
    let n = team.n;
    let nf = team.feet.len();
    let m = team.contact_rows();
    // Every row is written: the feet's, then the grasp's or zeros.
    shape(j_c, m, n);
    zeros_v(jdv_c, m);
    j_c.rows_mut(0, 3 * nf).copy_from(&team.j_cf);
    jdv_c.rows_mut(0, 3 * nf).copy_from(&team.jdv_cf);
    let mut filled = 3 * nf;
    if let Some(g) = grasp {
        j_c.rows_mut(filled, g.j_cee.nrows()).copy_from(&g.j_cee);
        jdv_c.rows_mut(filled, g.j_cee.nrows()).copy_from(&g.jdv_cee);
        filled += g.j_cee.nrows();
    }
    j_c.rows_mut(filled, m - filled).fill(0.0);
}

/// The QP's contacts into `out`: `(first row in J_c, kind)` for every stance foot (friction
/// pyramid and minimum normal force) and every hand in grasp (its contact frame's axes, the
/// sliding-and-torsion, normal-force and centre-of-pressure rows), with the robot's friction and patch sizes
/// scaled by the configuration's margins.
pub fn contact_list(team: &Team, descriptions: &BTreeMap<String, RobotDescription>, cfg: &PidcConfig, out: &mut Vec<(usize, ContactKind)>) -> Result<(), ControllerError> {
    let description = |robot: usize| {
        let id = &team.robots[robot].id;
        descriptions.get(id).ok_or_else(|| ControllerError::MissingDescription { robot: id.clone() })
    };
    let nf = team.feet.len();
    out.clear();
    for (k, f) in team.feet.iter().enumerate() {
        let d = description(f.robot)?;
        out.push((3 * k, ContactKind::Foot { mu: d.foot_mu * cfg.friction_margin, f_min: cfg.f_min_foot, f_max: f64::INFINITY }));
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
                mu: d.hand_mu * cfg.friction_margin,
                xi: d.hand_xi * cfg.friction_margin,
                half: [d.hand_half_size[0] * cfg.patch_margin, d.hand_half_size[1] * cfg.patch_margin],
                f_min: cfg.f_min_hand,
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
        if let (Some(l), ContactKind::Foot { f_max, .. }) = (loads.iter().find(|l| l.robot == *id && l.frame == f.name), kind) {
            *f_max = l.max_normal_force;
        }
    }
}
