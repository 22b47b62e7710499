//! The projections of PIDC (paper §II-B..D): `P` (eq. aghili_21), `Pdot v`, `M_c` and the
//! constraint inertia `Mbar = M M_c^{-1}` (eq. aghili_25, constraint_force), `[P S]^+` and
//! `B` (eqs. ua_solution, bmatrix), all with rank-revealing pseudo-inverses (DESIGN.md §4).

use nalgebra::{DMatrix, DVector};

use crate::linalg::{pinv, RANK_TOL};
use crate::ControllerError;

/// The projected quantities of one tick.
#[derive(Debug, Clone)]
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
    /// `Pdot v = -J_c^+ (Jdot_c v)`, exact when `J_c v = 0` (see [`pdot_v`]).
    pub pdot_v: DVector<f64>,
    /// `M_c = P M + I - P` and its inverse (eq. aghili_25).
    pub mc: DMatrix<f64>,
    pub mc_inv: DMatrix<f64>,
    /// Constraint inertia `Mbar = M M_c^{-1}` (eq. constraint_force).
    pub mbar: DMatrix<f64>,
    /// `[P S]^+` (eq. ua_solution).
    pub ps_pinv: DMatrix<f64>,
    /// `B = I - [(I - S)(I - P)]^+` (eq. bmatrix).
    pub b: DMatrix<f64>,
}

/// `Pdot v` from `J_c`'s pseudo-inverse and `Jdot_c v`.
///
/// `P = I - J^+ J`, so `Pdot v = -(d/dt J^+) (J v) - J^+ (Jdot v)`. While the contacts hold
/// (`J_c v = 0`, eq. contact_constraint) the first term vanishes and `Pdot v = -J^+ Jdot v`
/// exactly; this needs only `Jdot*v` (what the agents send), not `Jdot`. The measured
/// `|J_c v|` is reported in the diagnostics. Checked against a finite difference of `P` in
/// time in `tests/identities.rs`.
pub fn pdot_v(jc_pinv: &DMatrix<f64>, jdv_c: &DVector<f64>) -> DVector<f64> {
    -(jc_pinv * jdv_c)
}

impl Projections {
    pub fn compute(
        mass: &DMatrix<f64>,
        s_diag: &DVector<f64>,
        j_c: &DMatrix<f64>,
        jdv_c: &DVector<f64>,
    ) -> Result<Projections, ControllerError> {
        let n = mass.nrows();
        let singular = |what: &str| ControllerError::Singular { what: what.to_string() };
        let (jc_pinv, jc_rank) = pinv(j_c, RANK_TOL).ok_or_else(|| singular("SVD of J_c"))?;
        let jct_pinv = jc_pinv.transpose();
        let id = DMatrix::<f64>::identity(n, n);
        let mut p = &id - &jc_pinv * j_c;
        // Symmetrise away round-off (P is symmetric in exact arithmetic).
        let pt = p.transpose();
        p = (&p + pt) * 0.5;
        let ip = &id - &p;
        let pdot_v = pdot_v(&jc_pinv, jdv_c);
        let mc = &p * mass + &ip;
        let mc_inv = mc.clone().lu().try_inverse().ok_or_else(|| singular("M_c"))?;
        if !mc_inv.iter().all(|x| x.is_finite()) {
            return Err(singular("M_c"));
        }
        let mbar = mass * &mc_inv;
        // [P S]^+: S is a 0/1 diagonal, so P S keeps P's actuated columns; the pseudo-inverse
        // of the column-reduced matrix, placed on the actuated rows, is [P S]^+.
        let act: Vec<usize> = (0..n).filter(|&j| s_diag[j] != 0.0).collect();
        let pa = p.select_columns(&act);
        let (pa_pinv, _) = pinv(&pa, RANK_TOL).ok_or_else(|| singular("SVD of P S"))?;
        let mut ps_pinv = DMatrix::zeros(n, n);
        for (k, &j) in act.iter().enumerate() {
            ps_pinv.row_mut(j).copy_from(&pa_pinv.row(k));
        }
        // [(I - S)(I - P)]^+: only the unactuated rows of (I - P) survive; same trick on rows.
        let un: Vec<usize> = (0..n).filter(|&i| s_diag[i] == 0.0).collect();
        let xr = ip.select_rows(&un);
        let (xr_pinv, _) = pinv(&xr, RANK_TOL).ok_or_else(|| singular("SVD of (I-S)(I-P)"))?;
        let mut x_pinv = DMatrix::zeros(n, n);
        for (k, &i) in un.iter().enumerate() {
            x_pinv.column_mut(i).copy_from(&xr_pinv.column(k));
        }
        let b = &id - x_pinv;
        Ok(Projections { jc_pinv, jc_rank, jct_pinv, p, ip, pdot_v, mc, mc_inv, mbar, ps_pinv, b })
    }
}
