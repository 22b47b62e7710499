//! The projections of PIDC by the team's structure (issue 15; DESIGN.md §9): the same
//! [`Projections`] as the dense SVDs of [`Projections::compute_into`], from per-robot blocks
//! and one coupling of the hands through the grasp.
//!
//! Each robot's stance feet `A_r` (3 f x k) and its mass matrix `M_r` are its own; only the
//! grasp couples robots, through `J_c,ee = N_G J_ee` (eq. jacobian_cee, `N_G = I - G^+ G`).
//! With `U` an orthonormal basis of `N(G)` (6B x 6(B-1)), `J_c = diag(I, U) [A; U^T J_ee]`
//! and `[A; U^T J_ee]` has full row rank, so by the recursion over the feet first
//! (`N_f = diag(I - A_r^+ A_r)`, `R = N_f J_ee^T`, `E = J_ee R`):
//!
//! ```text
//! J_c^+ = [A^+ - R W_E J_ee A^+,  R W_E],       P = N_f - R W_E R^T        (eq. aghili_21)
//! W_X   = U (U^T X U)^{-1} U^T = X^{-1} - X^{-1} G^T (G X^{-1} G^T)^{-1} G X^{-1}
//! ```
//!
//! `X` block-diagonal by hands (6 x 6): `W_X` costs a 6 x 6 inverse per hand and one for `G`.
//! The same recursion in the metric `M^{-1}` gives `Phi = P (P M P)^+ P = M_c^{-1} P`:
//! `Phi_f = diag(M_r^{-1} - M_r^{-1} A_r^T (A_r M_r^{-1} A_r^T)^{-1} A_r M_r^{-1})`,
//! `L = Phi_f J_ee^T`, `D = J_ee L`, `Phi = Phi_f - L W_D L^T`, and
//! `M_c^{-1} = I + Phi - Phi M` (eq. aghili_25: `M_c (I + Phi - Phi M) = I` since
//! `P M Phi = P`). The actuation (eqs. ua_solution, bmatrix) needs one inverse of the
//! unactuated rows, `K = (I - P_uu)^{-1}` (6 per robot):
//! `[P S]^+ = S (P + P_{:u} K P_{u:})`, `[(I - S)(I - P)]^+ = (I - P)_{:u} K` on the
//! unactuated columns.
//!
//! Each inverse is of a Gram matrix whose Cholesky pivots pass [`crate::linalg::SPD_TOL`]:
//! then every rank the dense path decides with [`crate::linalg::RANK_TOL`] is full, and both
//! paths compute the same (unique) pseudo-inverses. Otherwise (a stretched leg, a hand at a
//! singularity, two hands on one robot) [`BlockWorkspace::compute_into`] declines and the
//! caller runs the dense path.

use nalgebra::{DMatrix, Matrix6};

use crate::linalg::{gemm, mat, mat_mut, spd6_inverse, zeros, zeros_v, SpdInverse};
use crate::team::Team;
use crate::units::grasp::GraspTerms;
use crate::units::projection::{complement, mbar_into, mc_into, symmetrise, Projections};

/// One robot's blocks: its feet rows and hand row in the team's `J_c`, and its share of the
/// recursion (see the module docs).
#[derive(Default)]
struct RobotBlocks {
    /// Team velocity offset and `nv`; first stance foot and their count; its hand in grasp.
    o: usize,
    k: usize,
    foot0: usize,
    feet: usize,
    hand: Option<usize>,
    a: DMatrix<f64>,
    gram: DMatrix<f64>,
    gram_inv: DMatrix<f64>,
    a_pinv: DMatrix<f64>,
    n_f: DMatrix<f64>,
    m_inv: DMatrix<f64>,
    ma: DMatrix<f64>,
    t: DMatrix<f64>,
    phi_f: DMatrix<f64>,
    /// Its hand's Jacobian `J_h` (6 x k), `R_h = N_f J_h^T`, `L_h = Phi_f J_h^T` (k x 6),
    /// `J_h A_r^+` (6 x 3 f).
    j_h: DMatrix<f64>,
    r_h: DMatrix<f64>,
    l_h: DMatrix<f64>,
    jap: DMatrix<f64>,
    inv: [SpdInverse; 3],
}

/// Scratch of the block path, kept between ticks.
#[derive(Default)]
pub struct BlockWorkspace {
    robots: Vec<RobotBlocks>,
    /// Per hand: `E_h`, `D_h` and, for [`coupling`], their inverses and `X_h^{-1} G_h^T`.
    e: Vec<Matrix6<f64>>,
    d: Vec<Matrix6<f64>>,
    x_inv: Vec<Matrix6<f64>>,
    y: Vec<Matrix6<f64>>,
    w_e: DMatrix<f64>,
    w_d: DMatrix<f64>,
    /// `R W_E` and `L W_D` (n x 6B).
    rw: DMatrix<f64>,
    lw: DMatrix<f64>,
    /// The unactuated rows' `I - P_uu`, its inverse `K`, `P_{:u}`, `P_{:u} K`.
    quu: DMatrix<f64>,
    k_inv: DMatrix<f64>,
    pu: DMatrix<f64>,
    pk: DMatrix<f64>,
    k_spd: SpdInverse,
}

impl BlockWorkspace {
    /// All of `proj` for the team with contact Jacobian `j_c` (`[J_cf; N_G J_ee]`) and its
    /// `Jdot*v`, by blocks. `None` (and `proj` partly written) when the team is not laid out
    /// by robots or a Gram matrix is too ill-conditioned: run the dense path then.
    pub fn compute_into(&mut self, proj: &mut Projections, team: &Team, grasp: Option<&GraspTerms>, j_c: &DMatrix<f64>, jdv_c: &nalgebra::DVector<f64>) -> Option<()> {
        let b = grasp.map_or(0, |_| team.hands.len());
        self.layout(team, b, j_c.nrows())?;
        for rb in &mut self.robots {
            rb.compute(team)?;
        }
        self.e.clear();
        self.d.clear();
        for rb in self.robots.iter().filter(|rb| rb.hand.is_some()) {
            self.e.push(hand_gram(&rb.j_h, &rb.r_h));
            self.d.push(hand_gram(&rb.j_h, &rb.l_h));
        }
        if let Some(g) = grasp {
            coupling(&self.e, &g.g, &mut self.x_inv, &mut self.y, &mut self.w_e)?;
            coupling(&self.d, &g.g, &mut self.x_inv, &mut self.y, &mut self.w_d)?;
        } else {
            zeros(&mut self.w_e, 0, 0);
            zeros(&mut self.w_d, 0, 0);
        }
        self.constraint_space(proj, team, j_c, jdv_c, b);
        self.motion_space(proj, team);
        self.actuation(proj, team)
    }

    /// Each robot's offset, feet and hand; `None` unless the feet and hands come in robot
    /// order, every robot has at most one hand in grasp and `J_c` has `3 nf + 6 B` rows.
    fn layout(&mut self, team: &Team, b: usize, m: usize) -> Option<()> {
        let nf = team.feet.len();
        let hands_sorted = team.hands.windows(2).all(|w| w[0].robot < w[1].robot);
        if m != 3 * nf + 6 * b || team.feet.windows(2).any(|w| w[0].robot > w[1].robot) || !hands_sorted {
            return None;
        }
        self.robots.resize_with(team.robots.len(), RobotBlocks::default);
        for (r, rb) in self.robots.iter_mut().enumerate() {
            (rb.o, rb.k) = (team.robots[r].offset, team.robots[r].nv);
            rb.foot0 = team.feet.iter().position(|f| f.robot == r).unwrap_or(0);
            rb.feet = team.feet.iter().filter(|f| f.robot == r).count();
            let mut hands = team.hands.iter().enumerate().filter(|(_, h)| h.robot == r).map(|(i, _)| i);
            rb.hand = if b == 0 { None } else { hands.next() };
            if b > 0 && hands.next().is_some() {
                return None;
            }
        }
        for rb in self.robots.iter_mut() {
            let (o, k, f) = (rb.o, rb.k, 3 * rb.feet);
            zeros(&mut rb.a, f, k);
            rb.a.copy_from(&team.j_cf.view((3 * rb.foot0, o), (f, k)));
            let h = rb.hand.unwrap_or(0);
            let rows = if rb.hand.is_some() { 6 } else { 0 };
            zeros(&mut rb.j_h, rows, k);
            rb.j_h.copy_from(&team.j_ee.view((6 * h, o), (rows, k)));
        }
        Some(())
    }

    /// `P`, `I - P`, `J_c^+`, `(J_c^T)^+`, the rank of `J_c` and `Pdot v = -J_c^+ Jdot_c v`.
    fn constraint_space(&mut self, proj: &mut Projections, team: &Team, j_c: &DMatrix<f64>, jdv_c: &nalgebra::DVector<f64>, b: usize) {
        let (n, m, nf) = (team.n, j_c.nrows(), 3 * team.feet.len());
        blocks_minus_coupling(&self.robots, |rb| (&rb.n_f, &rb.r_h), &self.w_e, &mut self.rw, &mut proj.p, n);
        complement(&proj.p, &mut proj.ip);
        // J_c^+ = [A^+ - R W_E J_ee A^+, R W_E].
        zeros(&mut proj.jc_pinv, n, m);
        for rb in &self.robots {
            let (o, k, f0, f) = (rb.o, rb.k, 3 * rb.foot0, 3 * rb.feet);
            proj.jc_pinv.view_mut((o, f0), (k, f)).copy_from(&rb.a_pinv);
            if let Some(h) = rb.hand {
                let cols = mat_mut(&mut proj.jc_pinv).subcols_mut(f0, f);
                gemm(cols, 1.0, -1.0, mat(&self.rw).subcols(6 * h, 6), mat(&rb.jap));
            }
        }
        if b > 0 {
            proj.jc_pinv.columns_mut(nf, 6 * b).copy_from(&self.rw);
        }
        proj.jc_rank = nf + 6 * b.saturating_sub(1);
        zeros(&mut proj.jct_pinv, m, n);
        proj.jc_pinv.transpose_to(&mut proj.jct_pinv);
        zeros_v(&mut proj.pdot_v, n);
        proj.pdot_v.gemv(-1.0, &proj.jc_pinv, jdv_c, 0.0);
    }

    /// `Phi = M_c^{-1} P`, `M_c`, `M_c^{-1} = I + Phi - Phi M`, `Mbar = M M_c^{-1}`.
    fn motion_space(&mut self, proj: &mut Projections, team: &Team) {
        let n = team.n;
        blocks_minus_coupling(&self.robots, |rb| (&rb.phi_f, &rb.l_h), &self.w_d, &mut self.lw, &mut proj.mcinv_p, n);
        // M_c^{-1} = I + Phi - Phi M (Phi M by M's diagonal blocks, into mc_inv).
        zeros(&mut proj.mc_inv, n, n);
        for r in &team.robots {
            let (o, k) = (r.offset, r.nv);
            let m_blk = mat(&team.mass).submatrix(o, o, k, k);
            gemm(mat_mut(&mut proj.mc_inv).subcols_mut(o, k), 0.0, -1.0, mat(&proj.mcinv_p).subcols(o, k), m_blk);
        }
        proj.mc_inv += &proj.mcinv_p;
        for i in 0..n {
            proj.mc_inv[(i, i)] += 1.0;
        }
        mc_into(team, proj);
        mbar_into(team, proj);
    }

    /// `[P S]^+` and `B` from `K = (I - P_uu)^{-1}` (module docs); `None` when `I - P_uu` is
    /// too ill-conditioned for the rank of `P S` to be full.
    fn actuation(&mut self, proj: &mut Projections, team: &Team) -> Option<()> {
        let (n, s) = (team.n, &team.s_diag);
        let unact = || (0..n).filter(|&i| s[i] == 0.0);
        let nu = unact().count();
        zeros(&mut self.pu, n, nu);
        for (c, j) in unact().enumerate() {
            self.pu.column_mut(c).copy_from(&proj.p.column(j));
        }
        zeros(&mut self.quu, nu, nu);
        for (r, i) in unact().enumerate() {
            for c in 0..nu {
                self.quu[(r, c)] = -self.pu[(i, c)];
            }
            self.quu[(r, r)] += 1.0;
        }
        self.k_spd.compute(mat(&self.quu), &mut self.k_inv)?;
        zeros(&mut self.pk, n, nu);
        gemm(mat_mut(&mut self.pk), 0.0, 1.0, mat(&self.pu), mat(&self.k_inv));
        // [P S]^+ = S (P + P_{:u} K P_{u:}).
        zeros(&mut proj.ps_pinv, n, n);
        proj.ps_pinv.copy_from(&proj.p);
        gemm(mat_mut(&mut proj.ps_pinv), 1.0, 1.0, mat(&self.pk), mat(&self.pu).transpose());
        for i in unact() {
            proj.ps_pinv.row_mut(i).fill(0.0);
        }
        // B = I - (I - P)_{:u} K on the unactuated columns = I - E_u K + P_{:u} K.
        zeros(&mut proj.b, n, n);
        proj.b.fill_with_identity();
        for (c, j) in unact().enumerate() {
            proj.b.column_mut(j).axpy(1.0, &self.pk.column(c), 1.0);
            for (r, i) in unact().enumerate() {
                proj.b[(i, j)] -= self.k_inv[(r, c)];
            }
        }
        Some(())
    }
}

impl RobotBlocks {
    /// `A^+`, `N_f`, `Phi_f` and the hand's `R_h`, `L_h`, `J_h A^+` of this robot.
    fn compute(&mut self, team: &Team) -> Option<()> {
        let (o, k, f) = (self.o, self.k, 3 * self.feet);
        let [gram_inv, m_inv, ama_inv] = &mut self.inv;
        // A^+ = A^T (A A^T)^{-1}, N_f = I - A^+ A.
        zeros(&mut self.gram, f, f);
        gemm(mat_mut(&mut self.gram), 0.0, 1.0, mat(&self.a), mat(&self.a).transpose());
        gram_inv.compute(mat(&self.gram), &mut self.gram_inv)?;
        zeros(&mut self.a_pinv, k, f);
        gemm(mat_mut(&mut self.a_pinv), 0.0, 1.0, mat(&self.a).transpose(), mat(&self.gram_inv));
        zeros(&mut self.n_f, k, k);
        self.n_f.fill_with_identity();
        gemm(mat_mut(&mut self.n_f), 1.0, -1.0, mat(&self.a_pinv), mat(&self.a));
        // Phi_f = M^{-1} - M^{-1} A^T (A M^{-1} A^T)^{-1} A M^{-1}.
        m_inv.compute(mat(&team.mass).submatrix(o, o, k, k), &mut self.m_inv)?;
        zeros(&mut self.ma, k, f);
        gemm(mat_mut(&mut self.ma), 0.0, 1.0, mat(&self.m_inv), mat(&self.a).transpose());
        gemm(mat_mut(&mut self.gram), 0.0, 1.0, mat(&self.a), mat(&self.ma));
        ama_inv.compute(mat(&self.gram), &mut self.gram_inv)?;
        zeros(&mut self.t, k, f);
        gemm(mat_mut(&mut self.t), 0.0, 1.0, mat(&self.ma), mat(&self.gram_inv));
        zeros(&mut self.phi_f, k, k);
        self.phi_f.copy_from(&self.m_inv);
        gemm(mat_mut(&mut self.phi_f), 1.0, -1.0, mat(&self.t), mat(&self.ma).transpose());
        // The hand's R_h = N_f J_h^T, L_h = Phi_f J_h^T, J_h A^+.
        let rows = self.j_h.nrows();
        for (out, left) in [(&mut self.r_h, &self.n_f), (&mut self.l_h, &self.phi_f)] {
            zeros(out, k, rows);
            gemm(mat_mut(out), 0.0, 1.0, mat(left), mat(&self.j_h).transpose());
        }
        zeros(&mut self.jap, rows, f);
        gemm(mat_mut(&mut self.jap), 0.0, 1.0, mat(&self.j_h), mat(&self.a_pinv));
        Some(())
    }
}

/// `J_h X` for `X` (k x 6): a hand's 6 x 6 Gram block (`E_h` or `D_h`), symmetrised.
fn hand_gram(j_h: &DMatrix<f64>, x: &DMatrix<f64>) -> Matrix6<f64> {
    let mut g = Matrix6::zeros();
    let view = faer::MatMut::from_column_major_slice_mut(g.as_mut_slice(), 6, 6);
    gemm(view, 0.0, 1.0, mat(j_h), mat(x));
    (g + g.transpose()) * 0.5
}

/// `W = X^{-1} - X^{-1} G^T (G X^{-1} G^T)^{-1} G X^{-1}` (6B x 6B) for `X = diag(x_h)`:
/// `U (U^T X U)^{-1} U^T` with `U` a basis of `N(G)` (module docs). Zero for one hand
/// (`N(G) = 0`). `None` when a block or `G X^{-1} G^T` fails the pivot rule.
fn coupling(x: &[Matrix6<f64>], g: &DMatrix<f64>, x_inv: &mut Vec<Matrix6<f64>>, y: &mut Vec<Matrix6<f64>>, w: &mut DMatrix<f64>) -> Option<()> {
    let b = x.len();
    zeros(w, 6 * b, 6 * b);
    if b <= 1 {
        return Some(());
    }
    x_inv.clear();
    y.clear();
    let mut f = Matrix6::zeros();
    for (h, xh) in x.iter().enumerate() {
        let g_h: Matrix6<f64> = g.fixed_view::<6, 6>(0, 6 * h).into_owned();
        let xi = spd6_inverse(xh)?;
        let yh = xi * g_h.transpose();
        f += g_h * yh;
        x_inv.push(xi);
        y.push(yh);
    }
    let f_inv = spd6_inverse(&((f + f.transpose()) * 0.5))?;
    for h in 0..b {
        let yf = y[h] * f_inv;
        for h2 in 0..b {
            let mut blk = -(yf * y[h2].transpose());
            if h == h2 {
                blk += x_inv[h];
            }
            w.fixed_view_mut::<6, 6>(6 * h, 6 * h2).copy_from(&blk);
        }
    }
    Some(())
}

/// `out = diag(D_r) - S W S^T` (n x n) where robot `r`'s hand block of `S` (n x 6B) is
/// `S_r` on its rows, `(D_r, S_r) = part(r)`; `sw = S W` (n x 6B) is kept for the caller.
fn blocks_minus_coupling(robots: &[RobotBlocks], part: impl Fn(&RobotBlocks) -> (&DMatrix<f64>, &DMatrix<f64>), w: &DMatrix<f64>, sw: &mut DMatrix<f64>, out: &mut DMatrix<f64>, n: usize) {
    let hb = w.nrows();
    zeros(out, n, n);
    zeros(sw, n, hb);
    for rb in robots {
        let (d, s) = part(rb);
        out.view_mut((rb.o, rb.o), (rb.k, rb.k)).copy_from(d);
        if let Some(h) = rb.hand.filter(|_| hb > 0) {
            gemm(mat_mut(sw).subrows_mut(rb.o, rb.k), 0.0, 1.0, mat(s), mat(w).subrows(6 * h, 6));
        }
    }
    for rb in robots {
        if let Some(h) = rb.hand.filter(|_| hb > 0) {
            let (_, s) = part(rb);
            gemm(mat_mut(out).subcols_mut(rb.o, rb.k), 1.0, -1.0, mat(sw).subcols(6 * h, 6), mat(s).transpose());
        }
    }
    symmetrise(out);
}
