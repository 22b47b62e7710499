//! The contact map of eq. relation_between_lambda_and_Fc: the contact wrenches `lambda` as an
//! affine function of the QP's variables, `lambda = rho F_c + eta` ([`contact_map`]), and the
//! wrenches predicted for the torque actually sent ([`contact_wrenches`]).
//!
//! With `K = (I - P)(Mbar P - I)` and `Y = B J_c^T` (the torque per unit `F_c`):
//! `rho = (J_c^T)^+ K S Y` and
//! `eta = (J_c^T)^+ [K (S tau_0 + J_x^T F_x) + (I - P)(Mbar (Pdot v - P h) + h)]`
//! (see [`Projections::contact_wrench`]); `rho` is formed right to left, without `K`
//! (`rho_dense`), or with the identities and the projections' operators of
//! `rho_by_blocks` when the projections came from the team's blocks (no `n x n` matrix).
//! The real wrenches on the hands add the object's load distribution `G^+ F_x` (see
//! [`super::tasks`]): `eta_real` and `lambda_real` are `eta` and `lambda` with it.

use nalgebra::{DMatrix, DVector, Vector6};

use crate::building_blocks::block_projection::{ActuationScratch, BlockOp, OpScratch};
use crate::building_blocks::grasp::GraspTerms;
use crate::building_blocks::projection::{Projections, WrenchScratch};
use crate::linalg::{
    add_product, gemm, mat, mat_mut, product, shape, transpose_into, zeros, zeros_v,
};
use crate::team::Team;

/// Scratch of the contact map: `S Y`, two `n x m` products, team-sized vectors.
#[derive(Debug, Clone, Default)]
pub struct ContactMapScratch {
    sy: DMatrix<f64>,
    /// `(B - I)` and `J_c` on the unactuated columns ([`rho_by_blocks`]).
    b_u: DMatrix<f64>,
    jc_u: DMatrix<f64>,
    t_a: DMatrix<f64>,
    t_b: DMatrix<f64>,
    u: DVector<f64>,
    wrench: WrenchScratch,
    ops: OpScratch,
    act: ActuationScratch,
}

/// What [`contact_map`] reads.
pub struct MapInput<'a> {
    pub team: &'a Team,
    pub proj: &'a Projections,
    /// `J_c` ([`contact_map`] reads it; [`contact_offset`] does not).
    pub j_c: &'a DMatrix<f64>,
    /// `tau_0 = [P S]^+ P tau_M` and the object's load `J_x^T F_x` (n).
    pub tau0: &'a DVector<f64>,
    pub load: &'a DVector<f64>,
    /// The grasp (its `G^+`) and the object's load `F_x`, for the hands' share `G^+ F_x`.
    pub grasp: Option<&'a GraspTerms>,
    pub f_x: &'a Vector6<f64>,
}

/// `Y = B J_c^T` (n x m), `rho` (m x m), `eta` (m) and `eta_real` (m: `eta` with `G^+ F_x` on
/// the hand rows) of eq. relation_between_lambda_and_Fc.
pub fn contact_map(
    inp: &MapInput,
    ws: &mut ContactMapScratch,
    y: &mut DMatrix<f64>,
    rho: &mut DMatrix<f64>,
    eta: &mut DVector<f64>,
    eta_real: &mut DVector<f64>,
) {
    let MapInput { team, proj, j_c, .. } = inp;
    if proj.by_blocks {
        rho_by_blocks(team, proj, j_c, ws, y, rho);
    } else {
        rho_dense(team, proj, j_c, ws, y, rho);
    }
    contact_offset(inp, ws, eta, eta_real);
}

/// `eta` and `eta_real` of [`contact_map`] alone (the contact wrenches at `F_c = 0`), without
/// `Y` and `rho`: what the QP's hot start by the robots' blocks reads
/// ([`crate::qp::BlockHotStart`]).
pub fn contact_offset(
    inp: &MapInput,
    ws: &mut ContactMapScratch,
    eta: &mut DVector<f64>,
    eta_real: &mut DVector<f64>,
) {
    let MapInput { team, proj, tau0, load, grasp, f_x, .. } = inp;
    let n = team.n;
    let m = team.contact_rows();
    let nf = team.feet.len();
    zeros_v(&mut ws.u, n);
    ws.u.copy_from(*tau0);
    ws.u.component_mul_assign(&team.s_diag);
    ws.u += *load; // S tau_0 + J_x^T F_x
    proj.contact_wrench(team, &ws.u, eta, &mut ws.wrench);
    // eta_real: the hand rows carry the object's load distribution G^+ F_x.
    zeros_v(eta_real, m);
    eta_real.copy_from(eta);
    if let Some(g) = grasp {
        let mut rows = eta_real.rows_mut(3 * nf, g.g_pinv.nrows());
        rows.gemv(1.0, &g.g_pinv, *f_x, 1.0);
    }
}

/// `Y = B J_c^T` and `rho = (J_c^T)^+ K S Y` as written, `K = (I - P)(Mbar P - I)`, right to
/// left (the dense path's, and the oracle of [`rho_by_blocks`]).
fn rho_dense(
    team: &Team,
    proj: &Projections,
    j_c: &DMatrix<f64>,
    ws: &mut ContactMapScratch,
    y: &mut DMatrix<f64>,
    rho: &mut DMatrix<f64>,
) {
    let (n, m) = (team.n, j_c.nrows());
    product(y, mat(&proj.b), mat(j_c).transpose()); // Y = B J_c^T
    scaled_rows(y, &team.s_diag, &mut ws.sy);
    product(&mut ws.t_a, mat(&proj.p), mat(&ws.sy)); // P S Y
    zeros(&mut ws.t_b, n, m);
    ws.t_b -= &ws.sy;
    add_product(&mut ws.t_b, 1.0, mat(&proj.mbar), mat(&ws.t_a)); // (Mbar P - I) S Y
    product(&mut ws.t_a, mat(&proj.ip), mat(&ws.t_b)); // K S Y
    product(rho, mat(&proj.jct_pinv), mat(&ws.t_a));
}

/// The same `Y` and `rho` by the projections' factors, without an `n x n` matrix:
/// `B = I + (B - I)_{:u}` differs from `I` on the unactuated columns only, so
/// `Y = J_c^T + (B - I)_{:u} J_c[:, u]^T` (eq. bmatrix), where robot `r`'s feet rows of `J_c`
/// meet only its own unactuated columns; `(J_c^T)^+ (I - P) = (J_c^T)^+` and
/// `Mbar P = M M_c^{-1} P`, so `rho = (J_c^T)^+ (Mbar P S Y - S Y)` with both operators by
/// blocks ([`crate::building_blocks::block_projection`]).
fn rho_by_blocks(
    team: &Team,
    proj: &Projections,
    j_c: &DMatrix<f64>,
    ws: &mut ContactMapScratch,
    y: &mut DMatrix<f64>,
    rho: &mut DMatrix<f64>,
) {
    let (n, m, f) = (team.n, j_c.nrows(), &proj.blocks);
    let unact = f.b_minus_i_u(&mut ws.b_u, &mut ws.act);
    shape(&mut ws.jc_u, m, unact.len());
    for (c, &j) in unact.iter().enumerate() {
        ws.jc_u.column_mut(c).copy_from(&j_c.column(j));
    }
    transpose_into(j_c, y);
    for ((f0, nf), (u0, nu)) in f.feet_and_unactuated() {
        let jc_u = mat(&ws.jc_u).submatrix(f0, u0, nf, nu);
        gemm(
            mat_mut(y).subcols_mut(f0, nf),
            1.0,
            1.0,
            mat(&ws.b_u).subcols(u0, nu),
            jc_u.transpose(),
        );
    }
    let nf3 = f.rows().1;
    gemm(
        mat_mut(y).subcols_mut(nf3, m - nf3),
        1.0,
        1.0,
        mat(&ws.b_u),
        mat(&ws.jc_u).subrows(nf3, m - nf3).transpose(),
    );
    scaled_rows(y, &team.s_diag, &mut ws.sy);
    // Both operators write every row of their output (the robots' blocks tile the rows):
    // shaped, not cleared.
    shape(&mut ws.t_a, n, m);
    f.apply(BlockOp::MbarP, mat(&ws.sy), mat_mut(&mut ws.t_a), &mut ws.ops); // Mbar P S Y
    ws.t_a -= &ws.sy;
    shape(rho, m, m);
    f.jct_pinv_apply(mat(&ws.t_a), mat_mut(rho), &mut ws.ops);
}

/// `out = diag(s) y`.
fn scaled_rows(y: &DMatrix<f64>, s: &DVector<f64>, out: &mut DMatrix<f64>) {
    // Every entry is written: shaped, not cleared first. Column by column over the storage
    // (row views are strided).
    shape(out, y.nrows(), y.ncols());
    let n = y.nrows();
    for (dst, src) in
        out.as_mut_slice().chunks_exact_mut(n.max(1)).zip(y.as_slice().chunks_exact(n.max(1)))
    {
        for ((d, x), si) in dst.iter_mut().zip(src).zip(s.as_slice()) {
            *d = x * si;
        }
    }
}

/// What the contact wrenches of a tick follow from.
#[derive(Debug, Clone, Copy)]
pub enum Actuation<'a> {
    /// The QP's `F_c`, sent as `tau = tau_0 + Y F_c`: `lambda = rho F_c + eta`.
    ContactForces(&'a DVector<f64>),
    /// A torque that is not `tau_0 + Y F_c` (clamped after a fallback): `lambda` of eq.
    /// constraint_force for `S tau + J_x^T F_x`.
    Torque(&'a DVector<f64>),
}

/// What [`contact_wrenches`] reads: the map of [`contact_map`] and what it needs for a torque.
pub struct WrenchInput<'a> {
    pub team: &'a Team,
    pub proj: &'a Projections,
    pub load: &'a DVector<f64>,
    pub rho: &'a DMatrix<f64>,
    pub eta: &'a DVector<f64>,
}

/// The predicted contact wrenches `lambda` (m) for what was sent, and `lambda_real`, which
/// holds `eta_real` on entry (see [`contact_map`]) and `lambda + (eta_real - eta)` on return.
pub fn contact_wrenches(
    inp: &WrenchInput,
    sent: Actuation,
    ws: &mut ContactMapScratch,
    lambda: &mut DVector<f64>,
    lambda_real: &mut DVector<f64>,
) {
    let WrenchInput { team, proj, load, rho, eta } = inp;
    zeros_v(lambda, eta.len());
    match sent {
        Actuation::Torque(tau) => {
            // The clamped torque is not tau_0 + Y F_c: predict lambda from the torque actually
            // sent (eq. constraint_force).
            zeros_v(&mut ws.u, team.n);
            ws.u.copy_from(tau);
            ws.u.component_mul_assign(&team.s_diag);
            ws.u += *load; // S tau + J_x^T F_x
            proj.contact_wrench(team, &ws.u, lambda, &mut ws.wrench);
        }
        Actuation::ContactForces(f_c) => {
            lambda.copy_from(*eta);
            lambda.gemv(1.0, *rho, f_c, 1.0);
        }
    }
    // lambda_real = lambda + (eta_real - eta).
    *lambda_real -= *eta;
    *lambda_real += &*lambda;
}
