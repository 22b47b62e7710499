//! The constraint Jacobian of a tick: `J_c = [J_cf; J_c,ee]` with its `Jdot_c v` (eq.
//! jacobian_c) and the constraints' velocity `J_c v`.

use nalgebra::{DMatrix, DVector};

use crate::building_blocks::grasp::{times_hand_jacobians, GraspTerms};
use crate::linalg::{mat, mat_mut, shape, zeros_v};
use crate::team::Team;

/// `J_c = [J_cf; J_c,ee]` (eq. jacobian_c, `J_c,ee = N J_ee`, eq. jacobian_cee) and
/// `Jdot_c v` ([`contact_drift`]) into `j_c` (`3 nf + 6 B` x n) and `jdv_c`: the stance
/// feet's rows, then the grasp's (zero rows for the hands in grasp when there is no grasp).
/// The block path does not need `J_c` on the tick: `Pidc` forms it only for the dense
/// projections and the team-sized QP.
pub fn contact_jacobian(
    team: &Team,
    grasp: Option<&GraspTerms>,
    j_c: &mut DMatrix<f64>,
    jdv_c: &mut DVector<f64>,
) {
    let n = team.n;
    let nf = team.feet.len();
    let m = team.contact_rows();
    // Every row is written: the feet's, then the grasp's or zeros.
    shape(j_c, m, n);
    j_c.rows_mut(0, 3 * nf).copy_from(&team.j_cf);
    j_c.rows_mut(3 * nf, m - 3 * nf).fill(0.0);
    if let Some(g) = grasp {
        times_hand_jacobians(team, mat(&g.n), mat_mut(j_c).subrows_mut(3 * nf, g.n.nrows()));
    }
    contact_drift(team, grasp, jdv_c);
}

/// `Jdot_c v = [Jdot_cf v; d/dt(J_c,ee) v]` (m; zeros for the hands in grasp when there is no
/// grasp).
pub fn contact_drift(team: &Team, grasp: Option<&GraspTerms>, jdv_c: &mut DVector<f64>) {
    let nf3 = 3 * team.feet.len();
    zeros_v(jdv_c, team.contact_rows());
    jdv_c.rows_mut(0, nf3).copy_from(&team.jdv_cf);
    if let Some(g) = grasp {
        jdv_c.rows_mut(nf3, g.jdv_cee.len()).copy_from(&g.jdv_cee);
    }
}

/// `J_c v` (m) by the frames: each stance foot's Jacobian on its robot's columns, then
/// `J_c,ee v = N J_ee v` ([`GraspTerms::jcee_v`]; zeros without a grasp).
pub fn contact_velocity(team: &Team, grasp: Option<&GraspTerms>, jc_v: &mut DVector<f64>) {
    let nf3 = 3 * team.feet.len();
    zeros_v(jc_v, team.contact_rows());
    for (k, f) in team.feet.iter().enumerate() {
        jc_v.rows_mut(3 * k, 3).copy_from(&f.velocity(&team.velocity).fixed_rows::<3>(0));
    }
    if let Some(g) = grasp {
        jc_v.rows_mut(nf3, g.jcee_v.len()).copy_from(&g.jcee_v);
    }
}
