//! What is solved: the controller's terms ([`QpInput`]) and the QP they make
//! ([`QpProblem`]: `min 1/2 F^T P F  s.t.  A F <= b`, Clarabel's `DefaultProblemData`).
//!
//! ```text
//! min_F  F^T H F,  H = Y^T Y + eps I            (eq. wrench_optim2, Y = B J_c^T, regularised)
//! s.t.   C_k (rho F + eta)_k >= d_k             per contact k (rows: `super::rows`)
//!        tau_min - tau_0 <= Xi F <= tau_max - tau_0     (eq. real_torque_limit, Xi = S_ns^T Y)
//! ```

use nalgebra::{DMatrix, DVector};

use super::rows::{contact_rows, ContactKind};
use crate::linalg::{mat, product, zeros, zeros_v};

/// The QP's data.
pub struct QpInput<'a> {
    /// `Y = B J_c^T` (n x m): `tau_C = Y F`.
    pub y: &'a DMatrix<f64>,
    pub rho: &'a DMatrix<f64>,
    /// `eta` including the object-load offset on the hand rows.
    pub eta: &'a DVector<f64>,
    /// Contacts with their first row in lambda, in lambda order.
    pub contacts: &'a [(usize, ContactKind)],
    /// Team indices of the actuated joints and their symmetric limits.
    pub actuated: &'a [usize],
    pub limits: &'a [f64],
    /// `tau_0 = [P S]^+ P tau_M`.
    pub tau0: &'a DVector<f64>,
    pub regularisation: f64,
    /// Try [`super::DenseIpm`] first (Clarabel if it does not converge). Read into
    /// [`super::QpSettings::dense_first`] by [`super::solve`].
    pub dense_first: bool,
}

/// The constraint matrix `A F <= b` of the QP (friction, moments, torque limits), into `a`
/// and `b`. The contacts' rows come first, in contact order; then two rows per actuated joint,
/// `(Xi_j, -Xi_j)` (eq. real_torque_limit: `tau_0 + Y F <= lim` and `-(tau_0 + Y F) <= lim`),
/// the pairs [`super::DenseIpm`] folds into one row each.
pub fn constraints_into(inp: &QpInput, a: &mut DMatrix<f64>, b: &mut DVector<f64>) {
    let m = inp.rho.ncols();
    let nc: usize = inp.contacts.iter().map(|(_, k)| contact_rows(k).len()).sum();
    let l = inp.actuated.len();
    zeros(a, nc + 2 * l, m);
    zeros_v(b, nc + 2 * l);
    let mut i = 0;
    for (start, kind) in inp.contacts {
        for (c, lo) in contact_rows(kind).iter() {
            // c.(rho F + eta) >= lo  <=>  -(c^T rho) F <= c.eta - lo
            let mut ce = 0.0;
            for (r, cr) in c.iter().enumerate() {
                if *cr != 0.0 {
                    for j in 0..m {
                        a[(i, j)] -= cr * inp.rho[(start + r, j)];
                    }
                    ce += cr * inp.eta[start + r];
                }
            }
            b[i] = ce - lo;
            i += 1;
        }
    }
    for (k, (&j, &lim)) in inp.actuated.iter().zip(inp.limits).enumerate() {
        let xi = inp.y.row(j);
        a.row_mut(nc + 2 * k).copy_from(&xi);
        b[nc + 2 * k] = lim - inp.tau0[j];
        for j in 0..m {
            a[(nc + 2 * k + 1, j)] = -xi[j];
        }
        b[nc + 2 * k + 1] = lim + inp.tau0[j];
    }
}

/// `H = Y^T Y + eps I`: the objective `F^T H F` of eq. wrench_optim2, regularised.
pub fn objective_into(inp: &QpInput, h: &mut DMatrix<f64>) {
    product(h, mat(inp.y).transpose(), mat(inp.y));
    for i in 0..h.nrows() {
        h[(i, i)] += inp.regularisation;
    }
}

/// The assembled QP `min 1/2 F^T P F  s.t.  A F <= b` (`P = 2 H`), kept between ticks.
#[derive(Debug, Default)]
pub struct QpProblem {
    /// Objective `H` (m x m) of `F^T H F`.
    pub h: DMatrix<f64>,
    /// `P = 2 H`: the solvers minimise `1/2 F^T P F`.
    pub p: DMatrix<f64>,
    /// Constraints `A F <= b`.
    pub a: DMatrix<f64>,
    pub b: DVector<f64>,
    /// Rows from here on come in `(a, -a)` pairs (the torque limits).
    pub pairs_from: usize,
}

impl QpProblem {
    /// Build `H`, `P`, `A`, `b` from the controller's terms (reallocates only when the shape
    /// changes).
    pub fn assemble(&mut self, inp: &QpInput) {
        let m = inp.rho.ncols();
        objective_into(inp, &mut self.h);
        zeros(&mut self.p, m, m);
        self.p.copy_from(&self.h);
        self.p *= 2.0;
        constraints_into(inp, &mut self.a, &mut self.b);
        self.pairs_from = self.a.nrows() - 2 * inp.actuated.len();
    }

    /// Number of variables.
    pub fn n(&self) -> usize {
        self.a.ncols()
    }

    /// Number of rows of `A F <= b`.
    pub fn rows(&self) -> usize {
        self.a.nrows()
    }

    /// Every entry of `P`, `A` and `b` finite.
    pub fn is_finite(&self) -> bool {
        all_finite(self.b.iter()) && all_finite(self.p.iter()) && all_finite(self.a.iter())
    }
}

pub(crate) fn all_finite<'a>(xs: impl IntoIterator<Item = &'a f64>) -> bool {
    xs.into_iter().all(|x| x.is_finite())
}
