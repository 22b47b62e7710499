//! What is solved: the controller's terms ([`QpInput`]) and the QP they make
//! ([`QpProblem`]: `min 1/2 F^T P F  s.t.  A F <= b`, Clarabel's `DefaultProblemData`).
//!
//! ```text
//! min_F  F^T H F,  H = Y^T Y + eps I            (eq. wrench_optim2, Y = B J_c^T, regularised)
//! s.t.   C_k (rho F + eta)_k >= d_k             per contact k (rows: `super::rows`)
//!        tau_min - tau_0 <= Xi F <= tau_max - tau_0     (eq. real_torque_limit, Xi = S_ns^T Y)
//! ```

use nalgebra::{DMatrix, DVector};

use faer::MatRef;

use super::rows::{contact_rows, ContactKind, MAX_CONTACT_ROWS};
use crate::linalg::{all_finite, gemm, mat, mat_mut, shape, transpose_into, zeros_v};

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
}

/// The constraint matrix `A F <= b` of the QP (friction, moments, torque limits), into `a`
/// and `b`. The contacts' rows come first, in contact order; then two rows per actuated joint,
/// `(Xi_j, -Xi_j)` (eq. real_torque_limit: `tau_0 + Y F <= lim` and `-(tau_0 + Y F) <= lim`),
/// the pairs [`super::DenseIpm`] folds into one row each.
pub fn constraints_into(inp: &QpInput, a: &mut DMatrix<f64>, b: &mut DVector<f64>) {
    let m = inp.rho.ncols();
    let nc: usize = inp.contacts.iter().map(|(_, k)| contact_rows(k).len()).sum();
    let l = inp.actuated.len();
    // Every entry is written below: the contacts' rows by one product each, the torque rows
    // by copies.
    shape(a, nc + 2 * l, m);
    zeros_v(b, nc + 2 * l);
    // Contact k's rows: c . (rho F + eta)_k >= lo  <=>  -(C_k rho_k) F <= C_k eta_k - lo, with
    // C_k its rows' coefficients (r x dim) and rho_k its dim rows of rho.
    let mut c = [0.0; MAX_CONTACT_ROWS * 6];
    let mut i = 0;
    for (start, kind) in inp.contacts {
        let rows = contact_rows(kind);
        let (r, dim) = (rows.len(), kind.dim());
        for (k, (cr, lo)) in rows.iter().enumerate() {
            b[i + k] =
                cr.iter().zip(inp.eta.rows(*start, dim).iter()).map(|(x, e)| x * e).sum::<f64>()
                    - lo;
            for (d, x) in cr.iter().enumerate() {
                c[d * r + k] = *x;
            }
        }
        let ck = MatRef::from_column_major_slice(&c[..r * dim], r, dim);
        gemm(
            mat_mut(a).submatrix_mut(i, 0, r, m),
            0.0,
            -1.0,
            ck,
            mat(inp.rho).submatrix(*start, 0, dim, m),
        );
        i += r;
    }
    for (k, (&j, &lim)) in inp.actuated.iter().zip(inp.limits).enumerate() {
        b[nc + 2 * k] = lim - inp.tau0[j];
        b[nc + 2 * k + 1] = lim + inp.tau0[j];
    }
    for c in 0..m {
        let yc = inp.y.column(c);
        let mut col = a.column_mut(c);
        for (k, &j) in inp.actuated.iter().enumerate() {
            col[nc + 2 * k] = yc[j];
            col[nc + 2 * k + 1] = -yc[j];
        }
    }
}

/// `H = Y^T Y + eps I`: the objective `F^T H F` of eq. wrench_optim2, regularised.
///
/// `H` is symmetric: only its blocks on and below the diagonal are multiplied (column blocks
/// of [`OBJECTIVE_BLOCK`]), the rest is mirrored; about 60 % of the full product's work. The
/// left factor is `Y^T` copied into `yt` (m x n) first: the product's kernels run a third
/// faster on a column-major left operand than on a transposed view (measured on the
/// eight-robot `Y`, 192 x 144: 205 µs as a view, 145 µs with the copy).
pub fn objective_into(inp: &QpInput, yt: &mut DMatrix<f64>, h: &mut DMatrix<f64>) {
    let (n, m) = inp.y.shape();
    // Every entry is written: the blocks on and below the diagonal by the products, the rest
    // mirrored.
    shape(h, m, m);
    shape(yt, m, n);
    transpose_into(inp.y, yt);
    let y = mat(inp.y);
    for j0 in (0..m).step_by(OBJECTIVE_BLOCK) {
        let nj = OBJECTIVE_BLOCK.min(m - j0);
        // Rows j0.. of the column block j0..j0 + nj: Y[:, j0..]^T Y[:, j0..j0 + nj].
        let dst = mat_mut(h).submatrix_mut(j0, j0, m - j0, nj);
        gemm(dst, 0.0, 1.0, mat(yt).subrows(j0, m - j0), y.subcols(j0, nj));
    }
    let hs = h.as_mut_slice();
    for j in 0..m {
        hs[j * m + j] += inp.regularisation;
        for i in j + 1..m {
            hs[i * m + j] = hs[j * m + i];
        }
    }
}

/// Column block of [`objective_into`]'s product.
pub const OBJECTIVE_BLOCK: usize = 24;

/// The assembled QP `min 1/2 F^T P F  s.t.  A F <= b` (`P = 2 H`), kept between ticks.
#[derive(Debug, Default)]
pub struct QpProblem {
    /// Objective `H` (m x m) of `F^T H F`.
    pub h: DMatrix<f64>,
    /// `Y^T` (m x n), the left factor of [`objective_into`].
    yt: DMatrix<f64>,
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
        objective_into(inp, &mut self.yt, &mut self.h);
        shape(&mut self.p, self.h.nrows(), self.h.ncols());
        for (p, h) in self.p.as_mut_slice().iter_mut().zip(self.h.as_slice()) {
            *p = 2.0 * h;
        }
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
        all_finite(self.b.as_slice())
            && all_finite(self.p.as_slice())
            && all_finite(self.a.as_slice())
    }
}
