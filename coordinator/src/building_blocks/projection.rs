//! The projections of PIDC (paper §II-B..D): `P` (eq. aghili_21), `Pdot v`, `M_c` and the
//! constraint inertia `Mbar = M M_c^{-1}` (eq. aghili_25, constraint_force), `[P S]^+` and
//! `B` (eqs. ua_solution, bmatrix), all with rank-revealing pseudo-inverses (`docs/controller.md`).
//!
//! Two paths ([`ProjectionPath`]): by the team's blocks
//! ([`crate::building_blocks::block_projection`], the default), which keeps
//! factors and applies the projections as operators without forming
//! a team-sized matrix, and by dense SVDs ([`Projections::compute_into`], the oracle), which
//! fills every matrix below. [`Projections::materialize`] fills them on the block path too
//! (tests, reports). `M` is block-diagonal (one block per robot), so `P M` and `M M_c^{-1}` are
//! products by blocks.

use faer::{MatMut, MatRef};
use nalgebra::{DMatrix, DVector};

use crate::building_blocks::block_projection::{vmat, vmat_mut, BlockFactors, BlockOp, OpScratch};
use crate::building_blocks::grasp::GraspTerms;
use crate::linalg::{
    gemm, mat, mat_mut, product, symmetrise, zeros, zeros_v, Inverse, Pinv, RANK_TOL,
};
use crate::team::Team;
use crate::ControllerError;

/// How the projections are computed. In TOML (`projections = ...`): `"by-blocks"` or
/// `"dense"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ProjectionPath {
    /// By the team's blocks ([`Projections::by_blocks_into`], the default), falling back to
    /// [`ProjectionPath::Dense`] by itself when a block is too ill-conditioned.
    #[default]
    ByBlocks,
    /// By dense SVDs of the team's matrices ([`Projections::compute_into`], the oracle).
    Dense,
}

impl ProjectionPath {
    /// Every path with its name in files.
    pub const NAMES: [(ProjectionPath, &'static str); 2] =
        [(ProjectionPath::ByBlocks, "by-blocks"), (ProjectionPath::Dense, "dense")];
}

impl std::str::FromStr for ProjectionPath {
    type Err = String;

    /// A path by its name in files (`"by-blocks"`, `"dense"`); the error lists the names.
    fn from_str(s: &str) -> Result<Self, String> {
        match Self::NAMES.iter().find(|(_, n)| *n == s) {
            Some((p, _)) => Ok(*p),
            None => Err(format!(
                "unknown projection path `{s}` (one of: {})",
                Self::NAMES.map(|(_, n)| n).join(", ")
            )),
        }
    }
}

/// The projected quantities of one tick. On the block path (`by_blocks`) only `jc_rank`,
/// `pdot_v` and the factors are computed on the tick; the matrices are empty until
/// [`Projections::materialize`].
#[derive(Debug, Clone, Default)]
pub struct Projections {
    /// `J_c^+` (n x m) and the rank of `J_c`.
    pub jc_pinv: DMatrix<f64>,
    pub jc_rank: usize,
    /// `(J_c^T)^+ = (J_c^+)^T` (m x n).
    pub jct_pinv: DMatrix<f64>,
    /// `P = I - J_c^T (J_c^+)^T = I - J_c^+ J_c` (eq. aghili_21).
    pub p: DMatrix<f64>,
    /// `I - P`.
    pub ip: DMatrix<f64>,
    /// `Pdot v = -J_c^+ (Jdot_c v)`, exact when `J_c v = 0` (see below).
    pub pdot_v: DVector<f64>,
    /// `M_c = P M + I - P` and its inverse (eq. aghili_25).
    pub mc: DMatrix<f64>,
    pub mc_inv: DMatrix<f64>,
    /// `M_c^{-1} P` (eq. control_law's `Lambda_c`; `= P (P M P)^+ P`).
    pub mcinv_p: DMatrix<f64>,
    /// Constraint inertia `Mbar = M M_c^{-1}` (eq. constraint_force).
    pub mbar: DMatrix<f64>,
    /// `[P S]^+` (eq. ua_solution).
    pub ps_pinv: DMatrix<f64>,
    /// `B = I - [(I - S)(I - P)]^+` (eq. bmatrix).
    pub b: DMatrix<f64>,
    /// Whether the team's blocks made these ([`crate::building_blocks::block_projection`]) or the
    /// dense SVDs ([`Projections::compute_into`]).
    pub by_blocks: bool,
    /// The block path's factors (valid when `by_blocks`).
    pub blocks: BlockFactors,
}

/// Scratch of [`Projections::compute_into`]: the decompositions' workspaces and the reduced
/// matrices whose pseudo-inverses give `[P S]^+` and `B`.
#[derive(Default)]
pub struct ProjectionWorkspace {
    ops: OpScratch,
    jc: Pinv,
    ps: Pinv,
    x: Pinv,
    mc: Inverse,
    pa: DMatrix<f64>,
    pa_pinv: DMatrix<f64>,
    xr: DMatrix<f64>,
    xr_pinv: DMatrix<f64>,
}

/// Team-sized scratch of [`Projections::contact_wrench`].
#[derive(Debug, Clone, Default)]
pub struct WrenchScratch {
    t1: DVector<f64>,
    t2: DVector<f64>,
    t3: DVector<f64>,
    ops: OpScratch,
}

impl Projections {
    /// The contact wrenches of eq. constraint_force for a generalized force `u` (actuation
    /// `S tau` plus external `J_x^T F_x`): with `K = (I - P)(Mbar P - I)`,
    /// `lambda = (J_c^T)^+ [K u + (I - P)(Mbar (Pdot v - P h) + h)]
    ///         = (J_c^T)^+ (I - P) [Mbar (P (u - h) + Pdot v) + h - u]`, into `out`.
    pub fn contact_wrench(
        &self,
        team: &Team,
        u: &DVector<f64>,
        out: &mut DVector<f64>,
        s: &mut WrenchScratch,
    ) {
        let (n, h) = (team.n, &team.bias);
        let WrenchScratch { t1, t2, t3, ops } = s;
        for t in [&mut *t1, &mut *t2, &mut *t3] {
            zeros_v(t, n);
        }
        t2.copy_from(u);
        *t2 -= h;
        if !self.by_blocks {
            t1.copy_from(&self.pdot_v);
            t1.gemv(1.0, &self.p, t2, 1.0); // P (u - h) + Pdot v
            t2.copy_from(h);
            *t2 -= u;
            t2.gemv(1.0, &self.mbar, t1, 1.0); // Mbar (...) + h - u
            t1.gemv(1.0, &self.ip, t2, 0.0);
            zeros_v(out, self.jct_pinv.nrows());
            out.gemv(1.0, &self.jct_pinv, t1, 0.0);
            return;
        }
        let f = &self.blocks;
        f.apply(BlockOp::P, vmat(t2), vmat_mut(t1), ops);
        // P (u - h) + Pdot v
        *t1 += &self.pdot_v;
        // Mbar t1 = M M_c^{-1} t1 with M_c^{-1} = I + Phi - Phi M (eq. aghili_25).
        t3.copy_from(t1);
        mass_times(team, -1.0, vmat(t1), 1.0, vmat_mut(t3)); // t1 - M t1
        f.apply(BlockOp::Phi, vmat(t3), vmat_mut(t2), ops);
        *t2 += &*t1; // M_c^{-1} t1
        t3.copy_from(h);
        *t3 -= u;
        mass_times(team, 1.0, vmat(t2), 1.0, vmat_mut(t3)); // Mbar (...) + h - u
        f.apply(BlockOp::P, vmat(t3), vmat_mut(t1), ops);
        *t3 -= &*t1; // (I - P) (...)
        let m = f.rows().0;
        zeros_v(out, m);
        f.jct_pinv_apply(vmat(t3), vmat_mut(out), ops);
    }

    /// `out = [P S]^+ x` (eq. ua_solution) for a vector `x`; `px` is scratch.
    pub fn ps_pinv_times(
        &self,
        x: &DVector<f64>,
        s_diag: &DVector<f64>,
        out: &mut DVector<f64>,
        px: &mut DVector<f64>,
        ops: &mut OpScratch,
    ) {
        if self.by_blocks {
            self.blocks.ps_pinv_apply(x, s_diag, out, px, ops);
        } else {
            zeros_v(out, x.len());
            out.gemv(1.0, &self.ps_pinv, x, 0.0);
        }
    }

    /// `out = P x` for a vector `x`.
    pub fn p_times(&self, x: &DVector<f64>, out: &mut DVector<f64>, ops: &mut OpScratch) {
        zeros_v(out, x.len());
        if self.by_blocks {
            self.blocks.apply(BlockOp::P, vmat(x), vmat_mut(out), ops);
        } else {
            out.gemv(1.0, &self.p, x, 0.0);
        }
    }

    /// The team-sized matrices of the block path from its factors (each operator applied to
    /// the identity; it allocates): for tests and reports, never on the tick. Nothing to do
    /// on the dense path. `I - P`, `J_c^+`, `M_c^{-1} = I + Phi - Phi M`, `M_c` and `Mbar`
    /// follow from the block path's
    /// [`DenseOperators`](crate::building_blocks::block_projection::DenseOperators).
    pub fn materialize(&mut self, team: &Team) {
        if self.by_blocks {
            let d = self.blocks.dense_operators(team.n);
            let id = DMatrix::<f64>::identity(team.n, team.n);
            complement(&d.p, &mut self.ip);
            self.jc_pinv = d.jct_pinv.transpose();
            self.mc_inv = &id + &d.mcinv_p - &d.mcinv_p * &team.mass;
            (self.p, self.mcinv_p, self.jct_pinv) = (d.p, d.mcinv_p, d.jct_pinv);
            (self.ps_pinv, self.b) = (d.ps_pinv, d.b);
            mc_into(team, self);
            mbar_into(team, self);
        }
    }

    /// All projections of the team by the team's blocks
    /// ([`crate::building_blocks::block_projection`];
    /// `J_c` is not formed), with `Jdot_c v` (`jdv_c`). Returns whether the blocks answered:
    /// when they decline, run the dense SVDs ([`Projections::compute_into`]). Both give the
    /// same matrices (`coordinator/tests/structured.rs`).
    pub fn by_blocks_into(
        &mut self,
        ws: &mut ProjectionWorkspace,
        team: &Team,
        grasp: Option<&GraspTerms>,
        jdv_c: &DVector<f64>,
    ) -> bool {
        self.by_blocks = self.blocks.compute_into(team, grasp).is_some();
        if !self.by_blocks {
            return false;
        }
        self.jc_rank = self.blocks.jc_rank();
        // Pdot v = -J_c^+ (Jdot_c v) (see compute_into).
        self.blocks.jc_pinv_apply(-1.0, jdv_c, &mut self.pdot_v, &mut ws.ops);
        for m in [
            &mut self.jc_pinv,
            &mut self.jct_pinv,
            &mut self.p,
            &mut self.ip,
            &mut self.mc,
            &mut self.mc_inv,
            &mut self.mcinv_p,
            &mut self.mbar,
            &mut self.ps_pinv,
            &mut self.b,
        ] {
            zeros(m, 0, 0);
        }
        true
    }

    /// All projections of the team with contact Jacobian `j_c` and its `Jdot*v`, by dense
    /// SVDs of team-sized matrices (the oracle of the block path).
    ///
    /// `Pdot v`: `P = I - J^+ J`, so `Pdot v = -(d/dt J^+) (J v) - J^+ (Jdot v)`. While the
    /// contacts hold (`J_c v = 0`, eq. contact_constraint) the first term vanishes and
    /// `Pdot v = -J^+ Jdot v` exactly; this needs only `Jdot*v` (what the agents send), not
    /// `Jdot`. The measured `|J_c v|` is reported in the diagnostics. Checked against a finite
    /// difference of `P` in time in `tests/controller.rs`.
    pub fn compute_into(
        &mut self,
        ws: &mut ProjectionWorkspace,
        team: &Team,
        j_c: &DMatrix<f64>,
        jdv_c: &DVector<f64>,
    ) -> Result<(), ControllerError> {
        self.by_blocks = false;
        let n = team.n;
        let m = j_c.nrows();
        let singular = |what: &str| ControllerError::Singular { what: what.to_string() };
        self.jc_rank = ws
            .jc
            .compute(mat(j_c), RANK_TOL, &mut self.jc_pinv)
            .ok_or_else(|| singular("SVD of J_c"))?;
        zeros(&mut self.jct_pinv, m, n);
        self.jc_pinv.transpose_to(&mut self.jct_pinv);
        // P = I - J^+ J, symmetrised (P is symmetric in exact arithmetic).
        product(&mut self.p, mat(&self.jc_pinv), mat(j_c));
        self.p.neg_mut();
        for i in 0..n {
            self.p[(i, i)] += 1.0;
        }
        symmetrise(&mut self.p);
        complement(&self.p, &mut self.ip);
        zeros_v(&mut self.pdot_v, n);
        self.pdot_v.gemv(-1.0, &self.jc_pinv, jdv_c, 0.0);
        // M_c = P M + I - P by M's diagonal blocks, its inverse, Mbar = M M_c^{-1}.
        mc_into(team, self);
        ws.mc.compute(&self.mc, &mut self.mc_inv).ok_or_else(|| singular("M_c"))?;
        mbar_into(team, self);
        product(&mut self.mcinv_p, mat(&self.mc_inv), mat(&self.p));
        self.actuation_into(ws, team)
    }

    /// `[P S]^+` and `B` (eqs. ua_solution, bmatrix) from `P` and `I - P`, by dense SVDs of
    /// `P`'s actuated columns and of `I - P`'s unactuated rows.
    fn actuation_into(
        &mut self,
        ws: &mut ProjectionWorkspace,
        team: &Team,
    ) -> Result<(), ControllerError> {
        let n = team.n;
        let singular = |what: &str| ControllerError::Singular { what: what.to_string() };
        // [P S]^+: S is a 0/1 diagonal, so P S keeps P's actuated columns; the pseudo-inverse
        // of the column-reduced matrix, placed on the actuated rows, is [P S]^+.
        let s = &team.s_diag;
        let na = s.iter().filter(|x| **x != 0.0).count();
        zeros(&mut ws.pa, n, na);
        for (k, j) in (0..n).filter(|&j| s[j] != 0.0).enumerate() {
            ws.pa.column_mut(k).copy_from(&self.p.column(j));
        }
        ws.ps
            .compute(mat(&ws.pa), RANK_TOL, &mut ws.pa_pinv)
            .ok_or_else(|| singular("SVD of P S"))?;
        zeros(&mut self.ps_pinv, n, n);
        for (k, j) in (0..n).filter(|&j| s[j] != 0.0).enumerate() {
            self.ps_pinv.row_mut(j).copy_from(&ws.pa_pinv.row(k));
        }
        // [(I - S)(I - P)]^+: only the unactuated rows of (I - P) survive; same trick on rows.
        zeros(&mut ws.xr, n - na, n);
        for (k, i) in (0..n).filter(|&i| s[i] == 0.0).enumerate() {
            ws.xr.row_mut(k).copy_from(&self.ip.row(i));
        }
        ws.x.compute(mat(&ws.xr), RANK_TOL, &mut ws.xr_pinv)
            .ok_or_else(|| singular("SVD of (I-S)(I-P)"))?;
        zeros(&mut self.b, n, n);
        self.b.fill_with_identity();
        for (k, i) in (0..n).filter(|&i| s[i] == 0.0).enumerate() {
            let mut col = self.b.column_mut(i);
            col -= &ws.xr_pinv.column(k);
        }
        Ok(())
    }
}

/// `ip = I - p`.
fn complement(p: &DMatrix<f64>, ip: &mut DMatrix<f64>) {
    let n = p.nrows();
    zeros(ip, n, n);
    *ip -= p;
    for i in 0..n {
        ip[(i, i)] += 1.0;
    }
}

/// `out = beta out + alpha M x` for `x` (n x c), by `M`'s diagonal blocks.
pub(crate) fn mass_times(
    team: &Team,
    alpha: f64,
    x: MatRef<'_, f64>,
    beta: f64,
    mut out: MatMut<'_, f64>,
) {
    for r in &team.robots {
        let (o, k) = (r.offset, r.nv);
        gemm(
            out.as_mut().subrows_mut(o, k),
            beta,
            alpha,
            mat(&team.mass).submatrix(o, o, k, k),
            x.subrows(o, k),
        );
    }
}

/// `M_c = P M + I - P` (eq. aghili_25) from `proj.p` and `proj.ip`, by `M`'s diagonal blocks.
fn mc_into(team: &Team, proj: &mut Projections) {
    let n = team.n;
    zeros(&mut proj.mc, n, n);
    proj.mc.copy_from(&proj.ip);
    for r in &team.robots {
        let (o, k) = (r.offset, r.nv);
        let m_blk = mat(&team.mass).submatrix(o, o, k, k);
        gemm(mat_mut(&mut proj.mc).subcols_mut(o, k), 1.0, 1.0, mat(&proj.p).subcols(o, k), m_blk);
    }
}

/// `Mbar = M M_c^{-1}` (eq. constraint_force) from `proj.mc_inv`, by `M`'s diagonal blocks.
fn mbar_into(team: &Team, proj: &mut Projections) {
    let n = team.n;
    zeros(&mut proj.mbar, n, n);
    for r in &team.robots {
        let (o, k) = (r.offset, r.nv);
        let m_blk = mat(&team.mass).submatrix(o, o, k, k);
        gemm(
            mat_mut(&mut proj.mbar).subrows_mut(o, k),
            0.0,
            1.0,
            m_blk,
            mat(&proj.mc_inv).subrows(o, k),
        );
    }
}
