//! The joint torques that hold the robot up at rest: its gravity, the floating base carried by
//! the stance feet.
//!
//! A floating base hangs on its contacts, not on its joints. At rest the joint-space dynamics
//! (paper, eq. `js_dynamics`: `M v' + h = S^T tau + J_c^T lambda`) read
//!
//! ```text
//! g = S^T tau + J_c^T lambda
//! ```
//!
//! Their six base rows, `g_b = J_cb^T lambda`, fix the feet's forces up to internal ones; the
//! least-norm forces are `lambda = A^T (A A^T)^-1 g_b` with `A = J_cb^T` (6 x 3 per foot), and
//! the joints then need `tau = g_a - J_ca^T lambda`. `A A^T` is damped by 1e-10 of its
//! trace, so that feet in a line (rank 5) still give an answer. Without stance feet, or without
//! a floating base, `tau = g_a`: the actuated rows of `g` alone.
//!
//! The actuated rows alone leave the torso's weight to the posture hold's stiffness: an agent
//! that started beside a standing robot and held it sank by 4 cm before its first command.

use nalgebra::{Matrix6, Vector3, Vector6};
use protocol::{FrameRole, FrameTerms};

/// Relative damping of `A A^T` (of its trace).
const DAMPING: f64 = 1e-10;

/// `out[k] = tau_k` of the module docs for the generalized gravity `g` (`nv` entries), the
/// stance feet among `frames` (3 x `nv` Jacobians, row-major) and the velocity indices of the
/// actuated joints `actuated` (`out.len()` of them). Allocates nothing.
pub fn standing_torques(
    g: &[f64],
    floating_base: bool,
    frames: &[FrameTerms],
    actuated: &[usize],
    out: &mut [f64],
) {
    for (o, &i) in out.iter_mut().zip(actuated) {
        *o = g.get(i).copied().unwrap_or(0.0);
    }
    let nv = g.len();
    let feet = || {
        frames.iter().filter(move |f| {
            f.role == FrameRole::StanceFoot && f.jacobian.rows() == 3 && f.jacobian.cols() == nv
        })
    };
    if !floating_base || nv < 6 || feet().next().is_none() {
        return;
    }
    // A A^T = sum over feet of J_b^T J_b (J_b: the foot's 3 x 6 base block).
    let mut aat = Matrix6::<f64>::zeros();
    for f in feet() {
        let jb = base_block(&f.jacobian.data, nv);
        aat += jb.transpose() * jb;
    }
    let damping = DAMPING * aat.trace().max(f64::MIN_POSITIVE);
    aat += Matrix6::identity() * damping;
    let Some(chol) = aat.cholesky() else { return };
    let y = chol.solve(&Vector6::from_column_slice(&g[..6]));
    // lambda_foot = J_b y; tau -= J_a^T lambda_foot.
    for f in feet() {
        let jb = base_block(&f.jacobian.data, nv);
        let lambda: Vector3<f64> = jb * y;
        let j = &f.jacobian.data;
        for (o, &i) in out.iter_mut().zip(actuated) {
            *o -= j[i] * lambda[0] + j[nv + i] * lambda[1] + j[2 * nv + i] * lambda[2];
        }
    }
}

/// The first six columns of a 3 x `nv` row-major Jacobian.
fn base_block(j: &[f64], nv: usize) -> nalgebra::Matrix3x6<f64> {
    nalgebra::Matrix3x6::from_fn(|r, c| j[r * nv + c])
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::Matrix;

    fn foot(j: Matrix) -> FrameTerms {
        FrameTerms {
            name: "foot".into(),
            role: FrameRole::StanceFoot,
            position: [0.0; 3],
            rotation: [0.0; 9],
            jacobian: j,
            jdot_v: vec![0.0; 3],
        }
    }

    /// A planar check written out by hand: a base (3 translations, 3 rotations) on one joint,
    /// one foot whose Jacobian moves with the base's translation and the joint. The base's
    /// weight goes through the foot: lambda = g_b's translation part, and the joint carries
    /// the foot's share through its column.
    #[test]
    fn one_foot_carries_the_base_through_its_joint() {
        let nv = 7;
        let mut j = Matrix::zeros(3, nv);
        for r in 0..3 {
            j.data[r * nv + r] = 1.0; // the base's translation
        }
        j.data[2 * nv + 6] = 0.5; // the joint lifts the foot
        let g = [0.0, 0.0, 100.0, 0.0, 0.0, 0.0, 3.0];
        let mut out = [0.0];
        standing_torques(&g, true, &[foot(j)], &[6], &mut out);
        // lambda = (0, 0, 100) (up to the damping); tau = 3 - 0.5 * 100.
        assert!((out[0] - (3.0 - 50.0)).abs() < 1e-6, "{}", out[0]);
    }

    #[test]
    fn without_feet_or_a_floating_base_it_is_the_actuated_gravity() {
        let g = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0];
        let mut out = [0.0; 2];
        standing_torques(&g, true, &[], &[6, 7], &mut out);
        assert_eq!(out, [7.0, 8.0]);
        let mut j = Matrix::zeros(3, 8);
        j.data[2 * 8 + 2] = 1.0;
        standing_torques(&g, false, &[foot(j)], &[6, 7], &mut out);
        assert_eq!(out, [7.0, 8.0]);
    }
}
