//! The team's generalized accelerations under the torque sent: what a command does to its
//! robots over the periods before the next one applies (the team's delay,
//! [`crate::team::prediction`]).
//!
//! The controller's own model carries the object as a load at its reference acceleration
//! (`J_x^T F_x`, [`crate::building_blocks::object_load`]). What the command does depends on the
//! acceleration the object really gets, so here the grasped object is a rigid body on the
//! hands: its wrench on them is `-(Lambda_o a_o + b_o)`, with `a_o = J_o qdd + Jdot_o v`,
//! `Lambda_o = diag(m I, I_o)` (world) and `b_o = [-m g; omega x I_o omega]`. With the
//! constrained dynamics of eq. aghili_25 (`Phi = M_c^{-1} P`, `mu_c = M_c^{-1} (P h - Pdot v)`):
//!
//! ```text
//! q1  = Phi (S tau - J_o^T b_o) - mu_c                 (the object without inertia)
//! qdd = q1 - Phi J_o^T Lambda_o a_o
//! a_o = (I + A Lambda_o)^{-1} (J_o q1 + Jdot_o v),     A = J_o Phi J_o^T
//! ```
//!
//! (`A` is the inverse of the hands' operational-space inertia at the object's centre.) The
//! object's inertia matters most where the hands' own is small: the roll of the object about
//! the axis through two palms, which the wrists alone would turn tens of times faster.

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, Vector6};

use crate::building_blocks::block_projection::{vmat, vmat_mut, BlockOp, OpScratch};
use crate::building_blocks::grasp::GraspTerms;
use crate::building_blocks::object_load::object_load;
use crate::building_blocks::projection::Projections;
use crate::linalg::{mat, mat_mut, shape, transpose_into, zeros_v};
use crate::team::Team;

/// The carried object as a rigid body: mass, kg, and inertia about its centre in its frame.
#[derive(Debug, Clone, Copy)]
pub struct ObjectBody {
    pub mass: f64,
    pub inertia: Matrix3<f64>,
}

/// Scratch of [`commanded_accelerations`] (sized on first use).
#[derive(Debug, Clone, Default)]
pub struct AccelerationScratch {
    x: DVector<f64>,
    jot: DMatrix<f64>,
    phi_jot: DMatrix<f64>,
    /// The operators' scratch, one for vectors and one for the six columns of `J_o^T` (a
    /// scratch shaped for the one and then the other would be resized twice a tick).
    ops: OpScratch,
    ops_cols: OpScratch,
}

/// `y = Phi x` (n) by the projections' blocks or their dense `M_c^{-1} P`.
fn phi_times(proj: &Projections, x: &DVector<f64>, y: &mut DVector<f64>, ops: &mut OpScratch) {
    zeros_v(y, x.len());
    if proj.by_blocks {
        proj.blocks.apply(BlockOp::Phi, vmat(x), vmat_mut(y), ops);
    } else {
        y.gemv(1.0, &proj.mcinv_p, x, 0.0);
    }
}

/// `qdd` (n) for the team torque `tau` (n) with the motion-space bias `mcinv_bias` (`mu_c`, n)
/// and, when the team holds an object, that object as a rigid body on the hands (module docs);
/// NaN where it cannot be computed (non-finite inputs).
pub fn commanded_accelerations(
    team: &Team,
    proj: &Projections,
    tau: &DVector<f64>,
    mcinv_bias: &DVector<f64>,
    held: Option<(&GraspTerms, &ObjectBody)>,
    qdd: &mut DVector<f64>,
    s: &mut AccelerationScratch,
) {
    let n = team.n;
    zeros_v(&mut s.x, n);
    for i in 0..n {
        s.x[i] = team.s_diag[i] * tau[i];
    }
    let Some((g, body)) = held else {
        phi_times(proj, &s.x, qdd, &mut s.ops);
        *qdd -= mcinv_bias;
        return;
    };
    // b_o: the object's wrench at zero acceleration, its load feed-forward at a_d = 0.
    let b_o = object_load(&g.object, &g.object_twist, &[0.0; 6], body.mass, &body.inertia);
    // S tau - J_o^T b_o
    s.x.gemv_tr(-1.0, &g.j_o, &b_o, 1.0);
    phi_times(proj, &s.x, qdd, &mut s.ops);
    // q1
    *qdd -= mcinv_bias;
    let a = object_mobility(g, proj, n, s);
    let lambda_o = object_inertia(g, body);
    let mut a1 = Vector6::<f64>::zeros();
    for rr in 0..6 {
        a1[rr] =
            g.j_o.row(rr).iter().zip(qdd.iter()).map(|(x, y)| x * y).sum::<f64>() + g.jdv_o[rr];
    }
    let k: Matrix6<f64> = Matrix6::identity() + a * lambda_o;
    // I + A Lambda_o has eigenvalues of at least 1 (A and Lambda_o are positive semi-definite):
    // only non-finite inputs fail here, and then no acceleration is given.
    let Some(a_o) = k.lu().solve(&a1) else {
        qdd.fill(f64::NAN);
        return;
    };
    let f = lambda_o * a_o;
    qdd.gemv(-1.0, &s.phi_jot, &f, 1.0);
}

/// `A = J_o Phi J_o^T` (6 x 6) for the team's `n` joints, with `Phi J_o^T` left in
/// `s.phi_jot`.
fn object_mobility(
    g: &GraspTerms,
    proj: &Projections,
    n: usize,
    s: &mut AccelerationScratch,
) -> Matrix6<f64> {
    transpose_into(&g.j_o, &mut s.jot);
    shape(&mut s.phi_jot, n, 6);
    if proj.by_blocks {
        s.phi_jot.fill(0.0);
        proj.blocks.apply(BlockOp::Phi, mat(&s.jot), mat_mut(&mut s.phi_jot), &mut s.ops_cols);
    } else {
        s.phi_jot.gemm(1.0, &proj.mcinv_p, &s.jot, 0.0);
    }
    let mut a = Matrix6::<f64>::zeros();
    for c in 0..6 {
        for rr in 0..6 {
            a[(rr, c)] = g
                .j_o
                .row(rr)
                .iter()
                .zip(s.phi_jot.column(c).iter())
                .map(|(x, y)| x * y)
                .sum::<f64>();
        }
    }
    a
}

/// The object's spatial inertia in the world frame, `Lambda_o = diag(m I, R I_o R^T)`.
fn object_inertia(g: &GraspTerms, body: &ObjectBody) -> Matrix6<f64> {
    let r = g.object.rotation.to_rotation_matrix();
    let i_w = r.matrix() * body.inertia * r.matrix().transpose();
    let mut lambda_o = Matrix6::<f64>::zeros();
    lambda_o.fixed_view_mut::<3, 3>(0, 0).copy_from(&(Matrix3::identity() * body.mass));
    lambda_o.fixed_view_mut::<3, 3>(3, 3).copy_from(&i_w);
    lambda_o
}
