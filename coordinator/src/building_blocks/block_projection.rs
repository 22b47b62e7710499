//! The projections of PIDC by the team's structure (`docs/scale.md`): the same
//! [`Projections`] as the dense SVDs of [`Projections::compute_into`], from per-robot blocks
//! and one coupling of the hands through the grasp, kept as factors ([`BlockFactors`]) and
//! applied as operators: no team-sized `n x n` matrix is formed on the tick.
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
//! unactuated columns. `I - P_uu` is block-diagonal by robots but for the grasp's 6-row
//! coupling, so `K` is kept factored by Woodbury (`UnactuatedInverse`).
//!
//! **Operators.** `P`, `Phi` and `Mbar P = M Phi` are each "blocks minus a coupling",
//! `diag(D_r) - S W T^T` with `S`, `T` block-diagonal (k x 6 per robot) and `W` of 6B x 6B:
//! applied to `c` columns they cost `sum_r k^2 c + 12 B k c + 108 B c` (`W` kept factored,
//! `Coupling`) instead of `n^2 c` ([`BlockFactors::apply`]). `(J_c^T)^+` likewise
//! ([`BlockFactors::jct_pinv_apply`]). [`BlockFactors::dense_operators`] forms the team-sized
//! matrices from the same factors, for tests and reports only.
//!
//! Each inverse is of a Gram matrix whose Cholesky pivots pass [`crate::linalg::SPD_TOL`]:
//! then every rank the dense path decides with [`crate::linalg::RANK_TOL`] is full, and both
//! paths compute the same (unique) pseudo-inverses. Otherwise (a stretched leg, a hand at a
//! singularity, two hands on one robot) [`BlockFactors::compute_into`] declines and the
//! caller runs the dense path.

use faer::{MatMut, MatRef};
use nalgebra::{DMatrix, DVector, Matrix6, Vector6};

use crate::building_blocks::grasp::GraspTerms;
use crate::linalg::{
    gemm, mat, mat_mut, shape, spd6_inverse, symmetrise, zeros, zeros_v, SpdInverse, SPD_TOL,
};
use crate::team::Team;

/// One robot's blocks: its feet rows and hand row in the team's `J_c`, and its share of the
/// recursion (see the module docs).
#[derive(Debug, Clone, Default)]
struct RobotBlocks {
    /// Team velocity offset and `nv`; first stance foot and their count; its hand in grasp.
    o: usize,
    k: usize,
    foot0: usize,
    feet: usize,
    hand: Option<usize>,
    /// Its unactuated velocities: first column in the team's unactuated list, and count.
    u0: usize,
    nu: usize,
    a: DMatrix<f64>,
    gram: DMatrix<f64>,
    gram_inv: DMatrix<f64>,
    a_pinv: DMatrix<f64>,
    n_f: DMatrix<f64>,
    m_inv: DMatrix<f64>,
    ma: DMatrix<f64>,
    t: DMatrix<f64>,
    phi_f: DMatrix<f64>,
    /// `M_r Phi_f` and `M_r L_h`: the blocks of `Mbar P = M Phi`.
    mphi_f: DMatrix<f64>,
    ml_h: DMatrix<f64>,
    /// Its hand's Jacobian `J_h` (6 x k), `R_h = N_f J_h^T`, `L_h = Phi_f J_h^T` (k x 6),
    /// `J_h A_r^+` (6 x 3 f).
    j_h: DMatrix<f64>,
    r_h: DMatrix<f64>,
    l_h: DMatrix<f64>,
    jap: DMatrix<f64>,
    inv: [SpdInverse; 3],
}

/// Which "blocks minus a coupling" operator [`BlockFactors::apply`] applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlockOp {
    /// `P = N_f - R W_E R^T` (eq. aghili_21).
    P,
    /// `Phi = M_c^{-1} P = Phi_f - L W_D L^T` (eq. aghili_25).
    Phi,
    /// `Mbar P = M M_c^{-1} P = M Phi_f - M L W_D L^T` (eq. constraint_force).
    MbarP,
}

/// Scratch of the operators (coupling-sized, `6B x columns`, but `z`: n).
#[derive(Debug, Clone, Default)]
pub struct OpScratch {
    t: DMatrix<f64>,
    u: DMatrix<f64>,
    v: DVector<f64>,
    /// The couplings' `Y^T t` and `F^{-1} Y^T t` (6 x columns).
    r: DMatrix<f64>,
    q: DMatrix<f64>,
    /// A team-sized vector ([`BlockFactors::ps_pinv_apply`]).
    z: DVector<f64>,
}

/// Scratch of [`BlockFactors::b_minus_i_u`] (its own: its shapes are not the operators'):
/// `P_{:u}`'s coupling terms (`6B x n_u`, `6 x n_u`) and `K`'s right application (`n x 6`).
#[derive(Debug, Clone, Default)]
pub struct ActuationScratch {
    t: DMatrix<f64>,
    u: DMatrix<f64>,
    r: DMatrix<f64>,
    q: DMatrix<f64>,
    k_t: DMatrix<f64>,
    k_u: DMatrix<f64>,
}

/// The block path's factors, kept between ticks (see the module docs).
#[derive(Debug, Clone, Default)]
pub struct BlockFactors {
    robots: Vec<RobotBlocks>,
    /// Per hand: `E_h`, `D_h`; the couplings `W_E`, `W_D` they make, kept factored.
    e: Vec<Matrix6<f64>>,
    d: Vec<Matrix6<f64>>,
    w_e: Coupling,
    w_d: Coupling,
    /// The unactuated team indices `u` and `K = (I - P_uu)^{-1}`, factored (on the block
    /// path's tick neither `P_{:u}` nor `K` is formed: [`BlockFactors::ps_pinv_apply`] applies
    /// them; the team-sized QP's `(B - I)_{:u}` forms `P_{:u}`).
    unact: Vec<usize>,
    k: UnactuatedInverse,
    /// Rows of `J_c`: `3 nf + 6 B`; `3 nf`.
    m: usize,
    nf3: usize,
}

impl BlockFactors {
    /// The factors of the team whose contact Jacobian is `[J_cf; N_G J_ee]` (read from its
    /// frames: `J_c` itself is not needed). `None` when the team is not laid out by robots, a
    /// robot's unactuated velocities are not its first six, or a Gram matrix (or `I - P_uu`)
    /// is too ill-conditioned: run the dense path then.
    pub fn compute_into(&mut self, team: &Team, grasp: Option<&GraspTerms>) -> Option<()> {
        let b = grasp.map_or(0, |_| team.hands.len());
        self.layout(team, b, team.contact_rows())?;
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
            self.w_e.compute(&self.e, &g.g)?;
            self.w_d.compute(&self.d, &g.g)?;
        } else {
            self.w_e.clear();
            self.w_d.clear();
        }
        self.actuation()
    }

    /// The rank of `J_c`: `3 nf + 6 (B - 1)` (`J_c,ee` loses the object's 6 directions).
    pub fn jc_rank(&self) -> usize {
        let b = self.w_e.rows / 6;
        self.nf3 + 6 * b.saturating_sub(1)
    }

    /// Each robot's offset, feet and hand; `None` unless the feet and hands come in robot
    /// order, every robot has at most one hand in grasp and `J_c` has `3 nf + 6 B` rows.
    fn layout(&mut self, team: &Team, b: usize, m: usize) -> Option<()> {
        let nf = team.feet.len();
        let hands_sorted = team.hands.windows(2).all(|w| w[0].robot < w[1].robot);
        if m != 3 * nf + 6 * b
            || team.feet.windows(2).any(|w| w[0].robot > w[1].robot)
            || !hands_sorted
        {
            return None;
        }
        (self.m, self.nf3) = (m, 3 * nf);
        self.unact.clear();
        self.unact.extend((0..team.n).filter(|&i| team.s_diag[i] == 0.0));
        self.robots.resize_with(team.robots.len(), RobotBlocks::default);
        for (r, rb) in self.robots.iter_mut().enumerate() {
            (rb.o, rb.k) = (team.robots[r].offset, team.robots[r].nv);
            rb.foot0 = team.feet.iter().position(|f| f.robot == r).unwrap_or(0);
            rb.feet = team.feet.iter().filter(|f| f.robot == r).count();
            rb.u0 = self.unact.iter().position(|&i| i >= rb.o).unwrap_or(self.unact.len());
            rb.nu = self.unact.iter().filter(|&&i| i >= rb.o && i < rb.o + rb.k).count();
            let mut hands =
                team.hands.iter().enumerate().filter(|(_, h)| h.robot == r).map(|(i, _)| i);
            rb.hand = if b == 0 { None } else { hands.next() };
            if b > 0 && hands.next().is_some() {
                return None;
            }
        }
        for rb in self.robots.iter_mut() {
            let (o, k, f) = (rb.o, rb.k, 3 * rb.feet);
            shape(&mut rb.a, f, k);
            rb.a.copy_from(&team.j_cf.view((3 * rb.foot0, o), (f, k)));
            let h = rb.hand.unwrap_or(0);
            let rows = if rb.hand.is_some() { 6 } else { 0 };
            shape(&mut rb.j_h, rows, k);
            rb.j_h.copy_from(&team.j_ee.view((6 * h, o), (rows, k)));
        }
        Some(())
    }

    /// `K = (I - P_uu)^{-1}` ([`UnactuatedInverse`]); `None` when a robot's unactuated
    /// velocities are not its first six, or `I - P_uu` is too ill-conditioned for the rank of
    /// `P S` to be full.
    fn actuation(&mut self) -> Option<()> {
        for rb in &self.robots {
            let first_six =
                rb.nu == 6 && self.unact[rb.u0] == rb.o && self.unact[rb.u0 + 5] == rb.o + 5;
            if rb.nu != 0 && !first_six {
                return None;
            }
        }
        self.k.compute(&self.robots, &self.w_e)
    }

    /// `P_{:u} = P E_u` (n x nu) from the factors: robot `r`'s unit columns touch only its own
    /// blocks, `N_f E_u` is a copy of columns and `R^T E_u` a copy of rows.
    fn unit_columns(&self, n: usize, pu: &mut DMatrix<f64>, s: &mut ActuationScratch) {
        let nu = self.unact.len();
        let hb = self.w_e.rows;
        zeros(pu, n, nu);
        let ActuationScratch { t, u, r, q, .. } = s;
        zeros(t, hb, nu);
        shape(u, hb, nu);
        for rb in &self.robots {
            for c in rb.u0..rb.u0 + rb.nu {
                let jl = self.unact[c] - rb.o;
                pu.view_mut((rb.o, c), (rb.k, 1)).copy_from(&rb.n_f.column(jl));
                if let Some(h) = rb.hand.filter(|_| hb > 0) {
                    for i in 0..6 {
                        t[(6 * h + i, c)] = rb.r_h[(jl, i)];
                    }
                }
            }
        }
        if hb == 0 {
            return;
        }
        self.w_e.apply(mat(t), mat_mut(u), r, q);
        for rb in &self.robots {
            if let Some(h) = rb.hand {
                gemm(
                    mat_mut(pu).subrows_mut(rb.o, rb.k),
                    1.0,
                    -1.0,
                    mat(&rb.r_h),
                    mat(u).subrows(6 * h, 6),
                );
            }
        }
    }
}

impl BlockFactors {
    /// `out = op x` for `x` (n x c) (see [`BlockOp`]): each robot's block times its rows of
    /// `x`, minus `S_r (W (T^T x))_h` through its hand (module docs). `out` is n x c; every
    /// entry is written (the robots' blocks tile the rows), so it need not be cleared.
    pub fn apply(
        &self,
        op: BlockOp,
        x: MatRef<'_, f64>,
        mut out: MatMut<'_, f64>,
        s: &mut OpScratch,
    ) {
        let w = if op == BlockOp::P { &self.w_e } else { &self.w_d };
        let (hb, c) = (w.rows, x.ncols());
        for rb in &self.robots {
            gemm(
                out.as_mut().subrows_mut(rb.o, rb.k),
                0.0,
                1.0,
                mat(rb.operator(op)[0]),
                x.subrows(rb.o, rb.k),
            );
        }
        if hb == 0 {
            return;
        }
        shape(&mut s.t, hb, c);
        shape(&mut s.u, hb, c);
        for rb in &self.robots {
            if let Some(h) = rb.hand {
                gemm(
                    mat_mut(&mut s.t).subrows_mut(6 * h, 6),
                    0.0,
                    1.0,
                    mat(rb.operator(op)[2]).transpose(),
                    x.subrows(rb.o, rb.k),
                );
            }
        }
        w.apply(mat(&s.t), mat_mut(&mut s.u), &mut s.r, &mut s.q);
        for rb in &self.robots {
            if let Some(h) = rb.hand {
                gemm(
                    out.as_mut().subrows_mut(rb.o, rb.k),
                    1.0,
                    -1.0,
                    mat(rb.operator(op)[1]),
                    mat(&s.u).subrows(6 * h, 6),
                );
            }
        }
    }

    /// `out = (J_c^T)^+ x` (m x c) for `x` (n x c): with `J_c^+ = [A^+ - R W_E J_ee A^+, R W_E]`,
    /// the hand rows are `W_E R^T x` and robot `r`'s feet rows `A_r^{+T} x_r - (J_h A_r^+)^T
    /// (W_E R^T x)_h`. Every entry of `out` is written (the feet rows robot by robot, then
    /// the hand rows), so it need not be cleared.
    pub fn jct_pinv_apply(&self, x: MatRef<'_, f64>, mut out: MatMut<'_, f64>, s: &mut OpScratch) {
        let (hb, c) = (self.w_e.rows, x.ncols());
        shape(&mut s.t, hb, c);
        shape(&mut s.u, hb, c);
        for rb in &self.robots {
            if let Some(h) = rb.hand.filter(|_| hb > 0) {
                gemm(
                    mat_mut(&mut s.t).subrows_mut(6 * h, 6),
                    0.0,
                    1.0,
                    mat(&rb.r_h).transpose(),
                    x.subrows(rb.o, rb.k),
                );
            }
        }
        self.w_e.apply(mat(&s.t), mat_mut(&mut s.u), &mut s.r, &mut s.q);
        for rb in &self.robots {
            let (f0, f) = (3 * rb.foot0, 3 * rb.feet);
            gemm(
                out.as_mut().subrows_mut(f0, f),
                0.0,
                1.0,
                mat(&rb.a_pinv).transpose(),
                x.subrows(rb.o, rb.k),
            );
            if let Some(h) = rb.hand.filter(|_| hb > 0) {
                gemm(
                    out.as_mut().subrows_mut(f0, f),
                    1.0,
                    -1.0,
                    mat(&rb.jap).transpose(),
                    mat(&s.u).subrows(6 * h, 6),
                );
            }
        }
        out.subrows_mut(self.nf3, hb).copy_from(mat(&s.u));
    }

    /// `out = alpha J_c^+ y` (n) for `y` (m): `A^+ y_f + R W_E (y_h - J_ee A^+ y_f)`.
    pub fn jc_pinv_apply(
        &self,
        alpha: f64,
        y: &DVector<f64>,
        out: &mut DVector<f64>,
        s: &mut OpScratch,
    ) {
        let hb = self.w_e.rows;
        zeros_v(out, self.robots.iter().map(|rb| rb.k).sum());
        zeros(&mut s.t, hb, 1);
        zeros(&mut s.u, hb, 1);
        if hb > 0 {
            s.t.column_mut(0).copy_from(&y.rows(self.nf3, hb));
        }
        for rb in &self.robots {
            let yf = y.rows(3 * rb.foot0, 3 * rb.feet);
            out.rows_mut(rb.o, rb.k).gemv(alpha, &rb.a_pinv, &yf, 0.0);
            if let Some(h) = rb.hand.filter(|_| hb > 0) {
                s.t.fixed_view_mut::<6, 1>(6 * h, 0).gemv(-1.0, &rb.jap, &yf, 1.0);
            }
        }
        if hb == 0 {
            return;
        }
        self.w_e.apply(mat(&s.t), mat_mut(&mut s.u), &mut s.r, &mut s.q);
        for rb in &self.robots {
            if let Some(h) = rb.hand {
                out.rows_mut(rb.o, rb.k).gemv(
                    alpha,
                    &rb.r_h,
                    &s.u.fixed_view::<6, 1>(6 * h, 0),
                    1.0,
                );
            }
        }
    }

    /// `out = [P S]^+ x = S (P x + P_{:u} K P_{u:} x)` (eq. ua_solution) for a vector `x`, as
    /// `S P (x + E_u w)` with `w = K (P x)_u` (`P` is symmetric: `P_{u:} x = (P x)_u`): two
    /// applications of `P` and one of `K`'s factors; `px` is scratch.
    pub fn ps_pinv_apply(
        &self,
        x: &DVector<f64>,
        s_diag: &DVector<f64>,
        out: &mut DVector<f64>,
        px: &mut DVector<f64>,
        s: &mut OpScratch,
    ) {
        let (n, nu) = (x.len(), self.unact.len());
        zeros_v(out, n);
        self.apply(BlockOp::P, vmat(x), vmat_mut(out), s);
        zeros_v(px, nu);
        for (c, &i) in self.unact.iter().enumerate() {
            px[c] = out[i];
        }
        zeros_v(&mut s.v, nu);
        self.k.apply(&self.robots, px, &mut s.v);
        let mut z = std::mem::take(&mut s.z);
        zeros_v(&mut z, n);
        z.copy_from(x);
        for (c, &i) in self.unact.iter().enumerate() {
            z[i] += s.v[c];
        }
        self.apply(BlockOp::P, vmat(&z), vmat_mut(out), s);
        s.z = z;
        out.component_mul_assign(s_diag);
    }

    /// `(B - I)_{:u} = P_{:u} K - E_u K` (n x nu, eq. bmatrix on the unactuated columns, the
    /// only ones where `B` differs from `I`), and the unactuated indices.
    pub fn b_minus_i_u(&self, out: &mut DMatrix<f64>, s: &mut ActuationScratch) -> &[usize] {
        let n = self.robots.iter().map(|rb| rb.k).sum();
        self.unit_columns(n, out, s);
        for (c, &i) in self.unact.iter().enumerate() {
            out[(i, c)] -= 1.0;
        }
        self.k.right_apply(&self.robots, out, s);
        &self.unact
    }

    /// Each robot's feet rows of `J_c` (first row, count) and its unactuated columns in the
    /// team's unactuated list (first, count): the only columns where its feet rows meet `u`.
    pub fn feet_and_unactuated(
        &self,
    ) -> impl Iterator<Item = ((usize, usize), (usize, usize))> + '_ {
        self.robots.iter().map(|rb| ((3 * rb.foot0, 3 * rb.feet), (rb.u0, rb.nu)))
    }

    /// `(m, 3 nf)`: the rows of `J_c` and of its feet.
    pub fn rows(&self) -> (usize, usize) {
        (self.m, self.nf3)
    }
}

/// Scratch of [`BlockFactors::task_gram`] (task-sized: rows of the task stack by 6 or by a
/// robot's `k`).
#[derive(Debug, Clone, Default)]
pub struct GramScratch {
    /// One task's rows times a robot's `Phi_f` (d x k), and its `Q X^{-1}` (d x 6), in
    /// buffers of 6 rows and the largest `k` (one shape for the tick: no allocation).
    b: DMatrix<f64>,
    c: DMatrix<f64>,
    /// `Q = J L` on the current robot's hand (rows x 6), `V = Q Y` summed over the hands
    /// (rows x 6) and `V F^{-1}`.
    q: DMatrix<f64>,
    v: DMatrix<f64>,
    vf: DMatrix<f64>,
    /// The tasks whose columns meet the current robot's.
    touching: Vec<usize>,
}

/// One task of a stack: its first row and row count, and the columns its Jacobian is
/// non-zero on (first, count).
pub type TaskSpan = (usize, usize, usize, usize);

impl BlockFactors {
    /// `out = J Phi J^T` (rows x rows; eq. control_law's `Lambda_c^{-1}` with
    /// `Phi = M_c^{-1} P`) for a stack of tasks `j` (rows x n) laid out by `spans`, without
    /// the n x rows `Phi J^T`. With `Phi = Phi_f - L W_D L^T` and `W_D = X^{-1} - Y F^{-1} Y^T`
    /// (module docs), `Q = J L`:
    ///
    /// `J Phi J^T = sum_r J_r Phi_f,r J_r^T - sum_h Q_h X_h^{-1} Q_h^T + (Q Y) F^{-1} (Q Y)^T`
    ///
    /// each sum robot by robot over the tasks whose columns meet its own (a torso's meet one
    /// robot, the object's every grasping robot): linear in the team but for the result.
    pub fn task_gram(
        &self,
        j: MatRef<'_, f64>,
        spans: &[TaskSpan],
        out: &mut DMatrix<f64>,
        s: &mut GramScratch,
    ) {
        let rows = j.nrows();
        zeros(out, rows, rows);
        let coupled = !self.w_d.x_inv.is_empty();
        zeros(&mut s.q, rows, 6);
        zeros(&mut s.v, rows, 6);
        shape(&mut s.b, 6, self.robots.iter().map(|rb| rb.k).max().unwrap_or(0));
        shape(&mut s.c, 6, 6);
        for rb in &self.robots {
            s.touching.clear();
            s.touching.extend((0..spans.len()).filter(|&t| {
                let (_, d, c0, nc) = spans[t];
                d > 0 && c0 < rb.o + rb.k && rb.o < c0 + nc
            }));
            let j_r = j.subcols(rb.o, rb.k);
            robot_gram(rb, j_r, spans, out, s);
            let Some(h) = rb.hand.filter(|_| coupled) else { continue };
            self.hand_gram(h, rb, j_r, spans, out, s);
        }
        if coupled {
            shape(&mut s.vf, rows, 6);
            gemm(mat_mut(&mut s.vf), 0.0, 1.0, mat(&s.v), m6(&self.w_d.f_inv));
            gemm(mat_mut(out), 1.0, 1.0, mat(&s.vf), mat(&s.v).transpose());
        }
    }

    /// Hand `h`'s robot `rb`'s share of the grasp's coupling in [`BlockFactors::task_gram`]:
    /// `- Q_h X_h^{-1} Q_h^T` into `out` and `Q_h Y_h` added to `s.v`, over the tasks
    /// `s.touching` meeting its columns (`j_r`: the stack's columns of the robot).
    fn hand_gram(
        &self,
        h: usize,
        rb: &RobotBlocks,
        j_r: MatRef<'_, f64>,
        spans: &[TaskSpan],
        out: &mut DMatrix<f64>,
        s: &mut GramScratch,
    ) {
        let (x_inv, y) = (&self.w_d.x_inv[h], &self.w_d.y[h]);
        for &ti in &s.touching {
            let (ri, di, ..) = spans[ti];
            gemm(
                mat_mut(&mut s.q).subrows_mut(ri, di),
                0.0,
                1.0,
                j_r.subrows(ri, di),
                mat(&rb.l_h),
            );
        }
        for &ti in &s.touching {
            let (ri, di, ..) = spans[ti];
            let q_i = mat(&s.q).subrows(ri, di);
            gemm(mat_mut(&mut s.c).subrows_mut(0, di), 0.0, 1.0, q_i, m6(x_inv));
            for &tj in &s.touching {
                let (rj, dj, ..) = spans[tj];
                gemm(
                    mat_mut(out).submatrix_mut(ri, rj, di, dj),
                    1.0,
                    -1.0,
                    mat(&s.c).subrows(0, di),
                    mat(&s.q).subrows(rj, dj).transpose(),
                );
            }
            gemm(mat_mut(&mut s.v).subrows_mut(ri, di), 1.0, 1.0, q_i, m6(y));
        }
    }
}

/// Robot `rb`'s own blocks in [`BlockFactors::task_gram`]: `J_r Phi_f,r J_r^T` added to `out`
/// for every pair of the tasks `s.touching` meeting its columns (`j_r`: the stack's columns of
/// the robot).
fn robot_gram(
    rb: &RobotBlocks,
    j_r: MatRef<'_, f64>,
    spans: &[TaskSpan],
    out: &mut DMatrix<f64>,
    s: &mut GramScratch,
) {
    for &ti in &s.touching {
        let (ri, di, ..) = spans[ti];
        gemm(
            mat_mut(&mut s.b).submatrix_mut(0, 0, di, rb.k),
            0.0,
            1.0,
            j_r.subrows(ri, di),
            mat(&rb.phi_f),
        );
        for &tj in &s.touching {
            let (rj, dj, ..) = spans[tj];
            gemm(
                mat_mut(out).submatrix_mut(ri, rj, di, dj),
                1.0,
                1.0,
                mat(&s.b).submatrix(0, 0, di, rb.k),
                j_r.subrows(rj, dj).transpose(),
            );
        }
    }
}

/// The team-sized operators of the block path (see [`BlockFactors::dense_operators`]).
#[derive(Debug, Clone)]
pub struct DenseOperators {
    /// `P`, symmetrised.
    pub p: DMatrix<f64>,
    /// `Phi = M_c^{-1} P`, symmetrised.
    pub mcinv_p: DMatrix<f64>,
    /// `(J_c^T)^+` (m x n).
    pub jct_pinv: DMatrix<f64>,
    /// `[P S]^+`.
    pub ps_pinv: DMatrix<f64>,
    /// `B`.
    pub b: DMatrix<f64>,
}

impl BlockFactors {
    /// The team-sized operators from these factors, each applied to the identity (it
    /// allocates: for tests and reports, never on the tick): `P`, `M_c^{-1} P`, `(J_c^T)^+`,
    /// `[P S]^+ = S (P + P_{:u} K P_{u:})` and `B = I + (B - I)_{:u}`.
    pub fn dense_operators(&self, n: usize) -> DenseOperators {
        let id = DMatrix::<f64>::identity(n, n);
        let mut s = OpScratch::default();
        let mut op = |which: BlockOp| {
            let mut out = DMatrix::zeros(n, n);
            self.apply(which, mat(&id), mat_mut(&mut out), &mut s);
            symmetrise(&mut out);
            out
        };
        let p = op(BlockOp::P);
        let mcinv_p = op(BlockOp::Phi);
        let mut jct_pinv = DMatrix::zeros(self.m, n);
        self.jct_pinv_apply(mat(&id), mat_mut(&mut jct_pinv), &mut s);
        let mut pu = DMatrix::zeros(0, 0);
        let mut act = ActuationScratch::default();
        self.unit_columns(n, &mut pu, &mut act);
        // K itself: I K (K is symmetric).
        let mut k = DMatrix::identity(self.unact.len(), self.unact.len());
        self.k.right_apply(&self.robots, &mut k, &mut act);
        let mut ps_pinv = &p + &pu * k * pu.transpose();
        for &i in &self.unact {
            ps_pinv.row_mut(i).fill(0.0);
        }
        let mut z = DMatrix::zeros(0, 0);
        self.b_minus_i_u(&mut z, &mut act);
        let mut b = id;
        for (c, &j) in self.unact.iter().enumerate() {
            let mut col = b.column_mut(j);
            col += z.column(c);
        }
        DenseOperators { p, mcinv_p, jct_pinv, ps_pinv, b }
    }
}

impl RobotBlocks {
    /// This robot's `[D_r, S_r, T_r]` of `op = diag(D_r) - S W T^T`.
    fn operator(&self, op: BlockOp) -> [&DMatrix<f64>; 3] {
        match op {
            BlockOp::P => [&self.n_f, &self.r_h, &self.r_h],
            BlockOp::Phi => [&self.phi_f, &self.l_h, &self.l_h],
            BlockOp::MbarP => [&self.mphi_f, &self.ml_h, &self.l_h],
        }
    }

    /// `A^+`, `N_f`, `Phi_f`, `M_r Phi_f` and the hand's `R_h`, `L_h`, `M_r L_h`, `J_h A^+`.
    fn compute(&mut self, team: &Team) -> Option<()> {
        let (o, k, f) = (self.o, self.k, 3 * self.feet);
        let [gram_inv, m_inv, ama_inv] = &mut self.inv;
        let m_r = mat(&team.mass).submatrix(o, o, k, k);
        // A^+ = A^T (A A^T)^{-1}, N_f = I - A^+ A.
        shape(&mut self.gram, f, f);
        gemm(mat_mut(&mut self.gram), 0.0, 1.0, mat(&self.a), mat(&self.a).transpose());
        gram_inv.compute(mat(&self.gram), &mut self.gram_inv)?;
        shape(&mut self.a_pinv, k, f);
        gemm(mat_mut(&mut self.a_pinv), 0.0, 1.0, mat(&self.a).transpose(), mat(&self.gram_inv));
        shape(&mut self.n_f, k, k);
        self.n_f.fill_with_identity();
        gemm(mat_mut(&mut self.n_f), 1.0, -1.0, mat(&self.a_pinv), mat(&self.a));
        // Phi_f = M^{-1} - M^{-1} A^T (A M^{-1} A^T)^{-1} A M^{-1}.
        m_inv.compute(m_r, &mut self.m_inv)?;
        shape(&mut self.ma, k, f);
        gemm(mat_mut(&mut self.ma), 0.0, 1.0, mat(&self.m_inv), mat(&self.a).transpose());
        gemm(mat_mut(&mut self.gram), 0.0, 1.0, mat(&self.a), mat(&self.ma));
        ama_inv.compute(mat(&self.gram), &mut self.gram_inv)?;
        shape(&mut self.t, k, f);
        gemm(mat_mut(&mut self.t), 0.0, 1.0, mat(&self.ma), mat(&self.gram_inv));
        shape(&mut self.phi_f, k, k);
        self.phi_f.copy_from(&self.m_inv);
        gemm(mat_mut(&mut self.phi_f), 1.0, -1.0, mat(&self.t), mat(&self.ma).transpose());
        symmetrise(&mut self.phi_f);
        shape(&mut self.mphi_f, k, k);
        gemm(mat_mut(&mut self.mphi_f), 0.0, 1.0, m_r, mat(&self.phi_f));
        // The hand's R_h = N_f J_h^T, L_h = Phi_f J_h^T, M_r L_h, J_h A^+.
        let rows = self.j_h.nrows();
        for (out, left) in [(&mut self.r_h, &self.n_f), (&mut self.l_h, &self.phi_f)] {
            shape(out, k, rows);
            gemm(mat_mut(out), 0.0, 1.0, mat(left), mat(&self.j_h).transpose());
        }
        shape(&mut self.ml_h, k, rows);
        gemm(mat_mut(&mut self.ml_h), 0.0, 1.0, m_r, mat(&self.l_h));
        shape(&mut self.jap, rows, f);
        gemm(mat_mut(&mut self.jap), 0.0, 1.0, mat(&self.j_h), mat(&self.a_pinv));
        Some(())
    }
}

/// faer view of a vector as one column.
pub fn vmat(v: &DVector<f64>) -> MatRef<'_, f64> {
    MatRef::from_column_major_slice(v.as_slice(), v.len(), 1)
}

/// Mutable faer view of a vector as one column.
pub fn vmat_mut(v: &mut DVector<f64>) -> MatMut<'_, f64> {
    let n = v.len();
    MatMut::from_column_major_slice_mut(v.as_mut_slice(), n, 1)
}

/// `J_h X` for `X` (k x 6): a hand's 6 x 6 Gram block (`E_h` or `D_h`), symmetrised.
fn hand_gram(j_h: &DMatrix<f64>, x: &DMatrix<f64>) -> Matrix6<f64> {
    let mut g = Matrix6::zeros();
    let view = faer::MatMut::from_column_major_slice_mut(g.as_mut_slice(), 6, 6);
    gemm(view, 0.0, 1.0, mat(j_h), mat(x));
    (g + g.transpose()) * 0.5
}

/// `W = X^{-1} - X^{-1} G^T (G X^{-1} G^T)^{-1} G X^{-1}` (6B x 6B) for `X = diag(x_h)`:
/// `U (U^T X U)^{-1} U^T` with `U` a basis of `N(G)` (module docs). Kept factored,
/// `W = X^{-1} - Y F^{-1} Y^T` with `Y = X^{-1} G^T` (6 x 6 per hand) and
/// `F = G X^{-1} G^T` (6 x 6): applied to `c` columns it costs `108 B c` multiply-adds
/// instead of the dense `36 B^2 c`, and forming it `B` 6 x 6 products instead of `B^2`.
#[derive(Debug, Clone, Default)]
struct Coupling {
    x_inv: Vec<Matrix6<f64>>,
    y: Vec<Matrix6<f64>>,
    f: Matrix6<f64>,
    f_inv: Matrix6<f64>,
    /// `6 B`, zero without a grasp.
    rows: usize,
}

/// A 6 x 6 matrix as a faer view.
fn m6(m: &Matrix6<f64>) -> MatRef<'_, f64> {
    MatRef::from_column_major_slice(m.as_slice(), 6, 6)
}

impl Coupling {
    /// From the hands' blocks `x` and `G`. `None` when a block or `G X^{-1} G^T` fails the
    /// pivot rule. One hand: `N(G) = 0`, `W = 0`.
    fn compute(&mut self, x: &[Matrix6<f64>], g: &DMatrix<f64>) -> Option<()> {
        self.rows = 6 * x.len();
        self.x_inv.clear();
        self.y.clear();
        if x.len() <= 1 {
            return Some(());
        }
        let mut f = Matrix6::zeros();
        for (h, xh) in x.iter().enumerate() {
            let g_h: Matrix6<f64> = g.fixed_view::<6, 6>(0, 6 * h).into_owned();
            let xi = spd6_inverse(xh)?;
            let yh = xi * g_h.transpose();
            f += g_h * yh;
            self.x_inv.push(xi);
            self.y.push(yh);
        }
        self.f = (f + f.transpose()) * 0.5;
        self.f_inv = spd6_inverse(&self.f)?;
        Some(())
    }

    /// No grasp: no rows.
    fn clear(&mut self) {
        self.rows = 0;
        self.x_inv.clear();
        self.y.clear();
    }

    /// `u = W t` (`t`, `u`: 6B x c); `r`, `q` are scratch.
    fn apply(
        &self,
        t: MatRef<'_, f64>,
        mut u: MatMut<'_, f64>,
        r: &mut DMatrix<f64>,
        q: &mut DMatrix<f64>,
    ) {
        let c = t.ncols();
        if self.x_inv.is_empty() {
            for j in 0..c {
                for i in 0..self.rows {
                    u[(i, j)] = 0.0;
                }
            }
            return;
        }
        shape(r, 6, c);
        shape(q, 6, c);
        for (h, y) in self.y.iter().enumerate() {
            gemm(
                mat_mut(r),
                if h == 0 { 0.0 } else { 1.0 },
                1.0,
                m6(y).transpose(),
                t.subrows(6 * h, 6),
            );
        }
        gemm(mat_mut(q), 0.0, 1.0, m6(&self.f_inv), mat(r));
        for (h, (xi, y)) in self.x_inv.iter().zip(&self.y).enumerate() {
            gemm(u.as_mut().subrows_mut(6 * h, 6), 0.0, 1.0, m6(xi), t.subrows(6 * h, 6));
            gemm(u.as_mut().subrows_mut(6 * h, 6), 1.0, -1.0, m6(y), mat(q));
        }
    }
}

/// `K = (I - P_uu)^{-1}` (eq. bmatrix's inverse on the unactuated rows), kept factored.
/// With `P = N_f - R W_E R^T` and `W_E = X^{-1} - Y F^{-1} Y^T` (module docs),
/// `I - P_uu = D - V F^{-1} V^T` with `D = diag_r(I - (N_f,r)_uu + R_u,r X_h^{-1} R_u,r^T)` (6 x 6
/// per floating-base robot, `R_u,r` its unactuated rows of `R_h`) and `V = R_u Y` (6 x 6 per
/// robot with a hand). By Woodbury, `K = D^{-1} + D^{-1} V S^{-1} V^T D^{-1}` with
/// `S = F - V^T D^{-1} V`: a 6 x 6 inverse per robot and one for the grasp instead of the
/// team's `n_u x n_u`. `D` and `S` are positive definite exactly when `I - P_uu` is (`D`
/// exceeds it, `S` is the Schur complement of `D` in `[D V; V^T F]`); each passes
/// [`spd6_inverse`]'s pivot rule, and `K`'s norm (which bounds the condition of
/// `I - P_uu`) [`SPD_TOL`], or the block path declines. Without the grasp's coupling
/// (`W_E = 0`, one hand or none) `K = D^{-1}` with `D = diag_r(I - (N_f,r)_uu)`.
#[derive(Debug, Clone, Default)]
struct UnactuatedInverse {
    /// Per robot: `D_r^{-1}` and `D_r^{-1} V_r` (zeros for a robot without unactuated joints
    /// or without a hand in the coupling).
    d_inv: Vec<Matrix6<f64>>,
    dv: Vec<Matrix6<f64>>,
    /// `S^{-1}`, and whether the grasp couples the robots.
    s_inv: Matrix6<f64>,
    coupled: bool,
}

impl UnactuatedInverse {
    /// From the robots' blocks (each with no or exactly its first six velocities unactuated,
    /// [`BlockFactors::actuation`]) and `W_E`.
    fn compute(&mut self, robots: &[RobotBlocks], w_e: &Coupling) -> Option<()> {
        self.coupled = !w_e.x_inv.is_empty();
        self.d_inv.clear();
        self.dv.clear();
        let mut s = w_e.f;
        for rb in robots {
            let (mut d_inv, mut dv) = (Matrix6::zeros(), Matrix6::zeros());
            if rb.nu == 6 {
                let mut d = Matrix6::identity() - rb.n_f.fixed_view::<6, 6>(0, 0);
                // The hand's unactuated rows of R_h (k x 6), when the grasp couples it.
                let hand = rb
                    .hand
                    .filter(|_| self.coupled)
                    .map(|h| (h, rb.r_h.fixed_view::<6, 6>(0, 0).into_owned()));
                if let Some((h, r_u)) = hand {
                    d += r_u * w_e.x_inv[h] * r_u.transpose();
                }
                d_inv = spd6_inverse(&((d + d.transpose()) * 0.5))?;
                if let Some((h, r_u)) = hand {
                    let v = r_u * w_e.y[h];
                    dv = d_inv * v;
                    s -= v.transpose() * dv;
                }
            }
            self.d_inv.push(d_inv);
            self.dv.push(dv);
        }
        if self.coupled {
            self.s_inv = spd6_inverse(&((s + s.transpose()) * 0.5))?;
        }
        // The blocks' pivot rules are each relative to their block: `S` small beside `F` but
        // well-conditioned passes them. The team-sized inverse this replaces had one rule over
        // all of `I - P_uu`, whose eigenvalues are at most 1 (`P` is a projector), so its
        // condition is at most `|K|`, bounded by the factors:
        // `|K| <= max_r |D_r^{-1}| + sum_r |D_r^{-1} V_r|^2 |S^{-1}|` (Frobenius norms).
        let d_max = self.d_inv.iter().map(|d| d.norm()).fold(0.0, f64::max);
        let w2: f64 = self.dv.iter().map(|w| w.norm_squared()).sum();
        let k_bound = d_max + if self.coupled { w2 * self.s_inv.norm() } else { 0.0 };
        (k_bound.is_finite() && k_bound * SPD_TOL < 1.0).then_some(())
    }

    /// `out = K w` (`w`, `out`: n_u, each robot's six unactuated entries in robot order).
    fn apply(&self, robots: &[RobotBlocks], w: &DVector<f64>, out: &mut DVector<f64>) {
        let mut q = Vector6::zeros();
        if self.coupled {
            for (r, rb) in robots.iter().enumerate().filter(|(_, rb)| rb.nu == 6) {
                q += self.dv[r].tr_mul(&w.fixed_rows::<6>(rb.u0));
            }
            q = self.s_inv * q;
        }
        for (r, rb) in robots.iter().enumerate().filter(|(_, rb)| rb.nu == 6) {
            let k_w = self.d_inv[r] * w.fixed_rows::<6>(rb.u0) + self.dv[r] * q;
            out.fixed_rows_mut::<6>(rb.u0).copy_from(&k_w);
        }
    }

    /// `a = a K` in place (`a`: rows x n_u); `s`'s `k_t` and `k_u` are scratch.
    fn right_apply(&self, robots: &[RobotBlocks], a: &mut DMatrix<f64>, s: &mut ActuationScratch) {
        let rows = a.nrows();
        // T = A D^{-1} V S^{-1} (rows x 6), from A before it is overwritten.
        zeros(&mut s.k_t, rows, 6);
        if self.coupled {
            for (r, rb) in robots.iter().enumerate().filter(|(_, rb)| rb.nu == 6) {
                gemm(mat_mut(&mut s.k_t), 1.0, 1.0, mat(a).subcols(rb.u0, 6), m6(&self.dv[r]));
            }
            shape(&mut s.k_u, rows, 6);
            gemm(mat_mut(&mut s.k_u), 0.0, 1.0, mat(&s.k_t), m6(&self.s_inv));
        }
        for (r, rb) in robots.iter().enumerate().filter(|(_, rb)| rb.nu == 6) {
            shape(&mut s.k_t, rows, 6);
            mat_mut(&mut s.k_t).copy_from(mat(a).subcols(rb.u0, 6));
            gemm(mat_mut(a).subcols_mut(rb.u0, 6), 0.0, 1.0, mat(&s.k_t), m6(&self.d_inv[r]));
            if self.coupled {
                gemm(
                    mat_mut(a).subcols_mut(rb.u0, 6),
                    1.0,
                    1.0,
                    mat(&s.k_u),
                    m6(&self.dv[r]).transpose(),
                );
            }
        }
    }
}
