//! Linear algebra of the tick: rank-revealing pseudo-inverse (`docs/controller.md`), LU inverse and
//! matrix products into preallocated buffers (rotation maps are in
//! `robot_model::spatial`).
//!
//! The team's matrices are nalgebra `DMatrix` (column-major); the decompositions run in faer
//! on zero-copy views of them ([`mat`], [`mat_mut`]), because faer's decompositions take
//! their scratch memory from a caller-owned buffer. [`Pinv`] and [`Inverse`] keep that buffer
//! and their factors between ticks. Products go through [`gemm`] (nano-gemm's kernels), which
//! needs no memory at all.
//!
//! **What still allocates.** Inside faer's SVD and LU, the blocked Householder and triangular
//! updates call the `gemm` crate, which allocates its packing buffers on every call above
//! 16^3 flops; no faer setting avoids it. Those are the only allocations of a steady tick:
//! [`in_decomposition`] tells an allocation counter when they happen (`tests/allocations.rs`
//! asserts that nothing else allocates; the tick bench prints both counts).

use std::cell::Cell;

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::svd::{svd, svd_scratch, ComputeSvdVectors};
use faer::{ColMut, MatMut, MatRef, Par};
use nalgebra::{DMatrix, DVector, Matrix6};

/// Relative tolerance of the pseudo-inverses: singular values below `RANK_TOL * sigma_max`
/// are treated as zero. `J_c,ee` has rank `6(B-1)` (not `6B`), so this matters.
pub const RANK_TOL: f64 = 1e-9;

/// Smallest LU pivot, relative to the largest, of a matrix [`Inverse`] accepts as regular.
pub const PIVOT_TOL: f64 = 1e-13;

thread_local! {
    static IN_DECOMPOSITION: Cell<bool> = const { Cell::new(false) };
}

/// Whether this thread is inside one of faer's decompositions (SVD, LU), whose internal
/// products allocate (see the module docs). For allocation counters.
pub fn in_decomposition() -> bool {
    IN_DECOMPOSITION.try_with(Cell::get).unwrap_or(false)
}

/// Marks a decomposition for [`in_decomposition`] while it lives.
struct Decomposition;

impl Decomposition {
    fn start() -> Self {
        IN_DECOMPOSITION.with(|c| c.set(true));
        Decomposition
    }
}

impl Drop for Decomposition {
    fn drop(&mut self) {
        IN_DECOMPOSITION.with(|c| c.set(false));
    }
}

/// faer view of a column-major nalgebra matrix.
pub fn mat(a: &DMatrix<f64>) -> MatRef<'_, f64> {
    MatRef::from_column_major_slice(a.as_slice(), a.nrows(), a.ncols())
}

/// Mutable faer view of a column-major nalgebra matrix.
pub fn mat_mut(a: &mut DMatrix<f64>) -> MatMut<'_, f64> {
    let (r, c) = a.shape();
    MatMut::from_column_major_slice_mut(a.as_mut_slice(), r, c)
}

/// Make `a` an `r x c` matrix of zeros; the buffer is reallocated only when the shape changes
/// (a new team, a contact set that changed).
pub fn zeros(a: &mut DMatrix<f64>, r: usize, c: usize) {
    if a.shape() == (r, c) {
        // The storage's slice: a memset. nalgebra's `fill` walks an element iterator, which
        // cost a quarter of an eight-robot tick.
        a.as_mut_slice().fill(0.0);
    } else {
        *a = DMatrix::zeros(r, c);
    }
}

/// Make `a` an `r x c` matrix whose contents the caller overwrites (what it held is left, or
/// zeros after a change of shape): [`zeros`] without the clearing, for buffers a product or a
/// copy fills entirely.
pub fn shape(a: &mut DMatrix<f64>, r: usize, c: usize) {
    if a.shape() != (r, c) {
        *a = DMatrix::zeros(r, c);
    }
}

/// Make `v` a zero vector of length `n`, reallocating only when the length changes.
pub fn zeros_v(v: &mut DVector<f64>, n: usize) {
    if v.len() == n {
        v.as_mut_slice().fill(0.0);
    } else {
        *v = DVector::zeros(n);
    }
}

/// `out = a^T` (shaped to fit), by faer's copy of a transposed view.
pub fn transpose_into(a: &DMatrix<f64>, out: &mut DMatrix<f64>) {
    shape(out, a.ncols(), a.nrows());
    mat_mut(out).copy_from(mat(a).transpose());
}

/// `x . y` over the common length, with four partial sums so that the products pipeline (a
/// plain `zip().map().sum()` adds one product at a time, each waiting for the last).
pub fn dot(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len().min(y.len());
    let (x, y) = (&x[..n], &y[..n]);
    let mut s = [0.0; 4];
    let (xc, yc) = (x.chunks_exact(4), y.chunks_exact(4));
    let (xr, yr) = (xc.remainder(), yc.remainder());
    for (a, b) in xc.zip(yc) {
        for k in 0..4 {
            s[k] += a[k] * b[k];
        }
    }
    let tail: f64 = xr.iter().zip(yr).map(|(a, b)| a * b).sum();
    (s[0] + s[1]) + (s[2] + s[3]) + tail
}

/// Whether every entry is finite. Branch-free by lanes (`x * 0` is `NaN` exactly when `x` is
/// infinite or `NaN`, and a `NaN` stays one through the sums), so that it vectorises: the
/// QP's check of its data (`P`, `A`, `b`) was 2 % of an eight-robot tick as `all(is_finite)`.
pub fn all_finite(xs: &[f64]) -> bool {
    let mut s = [0.0; 8];
    let chunks = xs.chunks_exact(8);
    let rest = chunks.remainder();
    for c in chunks {
        for k in 0..8 {
            s[k] += c[k] * 0.0;
        }
    }
    s.iter().sum::<f64>() == 0.0 && rest.iter().all(|x| x.is_finite())
}

/// `out = a b` (shaped to fit, see [`zeros`]). `a` and `b` are views: `mat(x).transpose()`
/// multiplies by a transpose without forming it.
pub fn product(out: &mut DMatrix<f64>, a: MatRef<'_, f64>, b: MatRef<'_, f64>) {
    // gemm with a zero factor on `dst` writes every entry without reading it.
    shape(out, a.nrows(), b.ncols());
    gemm(mat_mut(out), 0.0, 1.0, a, b);
}

/// `out += alpha a b` (`out` already of the right shape).
pub fn add_product(out: &mut DMatrix<f64>, alpha: f64, a: MatRef<'_, f64>, b: MatRef<'_, f64>) {
    gemm(mat_mut(out), 1.0, alpha, a, b);
}

/// `dst = beta dst + alpha a b` by nano-gemm's register-blocked kernels, which need no packing
/// buffer: faer's and nalgebra's own products pack their operands into memory they allocate
/// on every call above a few thousand flops.
///
/// Panics if the shapes disagree (a programming error: every caller sizes its operands).
pub fn gemm(dst: MatMut<'_, f64>, beta: f64, alpha: f64, a: MatRef<'_, f64>, b: MatRef<'_, f64>) {
    let (m, n, k) = (a.nrows(), b.ncols(), a.ncols());
    assert!(
        dst.nrows() == m && dst.ncols() == n && b.nrows() == k,
        "gemm: {}x{} = {}x{} * {}x{}",
        dst.nrows(),
        dst.ncols(),
        m,
        k,
        b.nrows(),
        n
    );
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        // No product: dst = beta dst, written out here so that `beta = 0` clears what a
        // buffer made by [`shape`] held.
        let mut dst = dst;
        for j in 0..n {
            for i in 0..m {
                dst[(i, j)] = if beta == 0.0 { 0.0 } else { beta * dst[(i, j)] };
            }
        }
        return;
    }
    // SAFETY: the three views are valid for their shapes and strides (checked to agree
    // above), `dst` is borrowed mutably so it aliases neither operand, and nano-gemm reads
    // and writes exactly the `m x k`, `k x n` and `m x n` elements those describe; with a
    // zero `beta` it writes `dst` without reading it.
    unsafe {
        nano_gemm::planless::execute_f64(
            m,
            n,
            k,
            dst.as_ptr_mut(),
            dst.row_stride(),
            dst.col_stride(),
            a.as_ptr(),
            a.row_stride(),
            a.col_stride(),
            b.as_ptr(),
            b.row_stride(),
            b.col_stride(),
            beta,
            alpha,
            false,
            false,
        );
    }
}

/// Moore-Penrose pseudo-inverse by SVD with a relative rank tolerance, allocating its
/// result. For tests and one-off use; the tick uses [`Pinv`]. Also returns the rank; `None`
/// when the SVD fails to converge or the input is not finite.
pub fn pinv(a: &DMatrix<f64>, rel_tol: f64) -> Option<(DMatrix<f64>, usize)> {
    let mut out = DMatrix::zeros(0, 0);
    let rank = Pinv::default().compute(mat(a), rel_tol, &mut out)?;
    Some((out, rank))
}

/// Workspace of a pseudo-inverse `A^+ = V diag(1/s) U^T` (thin SVD, singular values below
/// `rel_tol * s_max` dropped), kept between ticks.
#[derive(Default)]
pub struct Pinv {
    shape: (usize, usize),
    u: DMatrix<f64>,
    v: DMatrix<f64>,
    s: Vec<f64>,
    buf: Option<MemBuffer>,
}

impl Pinv {
    /// `out = a^+` (shaped `cols x rows`); returns the rank. `None` when `a` is not finite or
    /// the SVD does not converge.
    pub fn compute(
        &mut self,
        a: MatRef<'_, f64>,
        rel_tol: f64,
        out: &mut DMatrix<f64>,
    ) -> Option<usize> {
        let (r, c) = (a.nrows(), a.ncols());
        zeros(out, c, r);
        let k = r.min(c);
        if k == 0 {
            return Some(0);
        }
        for j in 0..c {
            if !a.col(j).iter().all(|x| x.is_finite()) {
                return None;
            }
        }
        self.size_for(r, c, k);
        let stack = MemStack::new(self.buf.as_mut().expect("allocated above"));
        let scope = Decomposition::start();
        let result = svd(
            a,
            ColMut::from_slice_mut(&mut self.s).as_diagonal_mut(),
            Some(mat_mut(&mut self.u)),
            Some(mat_mut(&mut self.v)),
            Par::Seq,
            stack,
            Default::default(),
        );
        drop(scope);
        result.ok()?;
        let finite = |m: &DMatrix<f64>| m.iter().all(|x| x.is_finite());
        if !(self.s.iter().all(|x| x.is_finite()) && finite(&self.u) && finite(&self.v)) {
            // Seen on one tick of an eight-robot run (its 192 x 144 P S, after the team let go
            // of a beam it could not hold): faer's SVD reported success with NaN in its
            // factors. nalgebra's SVD then, on this rare path (it allocates).
            return Self::fallback(a, rel_tol, out);
        }
        let smax = self.s.iter().cloned().fold(0.0, f64::max);
        let eps = (rel_tol * smax).max(1e-300);
        let mut rank = 0;
        for (j, s) in self.s.iter().enumerate() {
            let inv = if *s > eps {
                rank += 1;
                1.0 / s
            } else {
                0.0
            };
            self.v.column_mut(j).scale_mut(inv);
        }
        gemm(mat_mut(out), 0.0, 1.0, mat(&self.v), mat(&self.u).transpose());
        Some(rank)
    }
}

impl Pinv {
    /// The SVD's workspace and thin factors for an `r x c` matrix (`k = min(r, c)`),
    /// reallocated only when the shape changes.
    fn size_for(&mut self, r: usize, c: usize, k: usize) {
        if self.shape != (r, c) || self.buf.is_none() {
            let req = svd_scratch::<f64>(
                r,
                c,
                ComputeSvdVectors::Thin,
                ComputeSvdVectors::Thin,
                Par::Seq,
                Default::default(),
            );
            self.buf = Some(MemBuffer::new(req.or(StackReq::EMPTY)));
            self.u = DMatrix::zeros(r, k);
            self.v = DMatrix::zeros(c, k);
            self.s = vec![0.0; k];
            self.shape = (r, c);
        }
    }

    /// `out = a^+` by nalgebra's SVD (allocates), with the same rank rule; `None` if it fails.
    fn fallback(a: MatRef<'_, f64>, rel_tol: f64, out: &mut DMatrix<f64>) -> Option<usize> {
        zeros(out, a.ncols(), a.nrows());
        let m = DMatrix::from_fn(a.nrows(), a.ncols(), |i, j| a[(i, j)]);
        let svd = m.try_svd(true, true, f64::EPSILON, 0)?;
        let smax = svd.singular_values.max();
        let rank =
            svd.singular_values.iter().filter(|&&x| x > (rel_tol * smax).max(1e-300)).count();
        let pinv = svd.pseudo_inverse((rel_tol * smax).max(1e-300)).ok()?;
        if !pinv.iter().all(|x| x.is_finite()) {
            return None;
        }
        out.copy_from(&pinv);
        Some(rank)
    }
}

/// Workspace of an inverse by LU with partial pivoting, kept between ticks.
#[derive(Default)]
pub struct Inverse {
    lu: DMatrix<f64>,
    perm: Vec<usize>,
    perm_inv: Vec<usize>,
    buf: Option<MemBuffer>,
}

impl Inverse {
    /// `out = a^{-1}`. `None` when `a` is not square or finite, or a pivot is below
    /// [`PIVOT_TOL`] times the largest (numerically singular).
    pub fn compute(&mut self, a: &DMatrix<f64>, out: &mut DMatrix<f64>) -> Option<()> {
        use faer::linalg::lu::partial_pivoting::{factor, inverse};
        let n = a.nrows();
        if a.ncols() != n || !a.iter().all(|x| x.is_finite()) {
            return None;
        }
        zeros(out, n, n);
        if self.lu.shape() != (n, n) || self.buf.is_none() {
            let req = factor::lu_in_place_scratch::<usize, f64>(n, n, Par::Seq, Default::default())
                .or(inverse::inverse_scratch::<usize, f64>(n, Par::Seq));
            self.buf = Some(MemBuffer::new(req));
            self.lu = DMatrix::zeros(n, n);
            self.perm = vec![0; n];
            self.perm_inv = vec![0; n];
        }
        self.lu.copy_from(a);
        let buf = self.buf.as_mut().expect("allocated above");
        let _scope = Decomposition::start();
        let (_, perm) = factor::lu_in_place(
            mat_mut(&mut self.lu),
            &mut self.perm,
            &mut self.perm_inv,
            Par::Seq,
            MemStack::new(buf),
            Default::default(),
        );
        let (lo, hi) = (0..n)
            .map(|i| self.lu[(i, i)].abs())
            .fold((f64::INFINITY, 0.0f64), |(lo, hi), p| (lo.min(p), hi.max(p)));
        if !(hi.is_finite() && lo > PIVOT_TOL * hi) {
            return None;
        }
        inverse::inverse(
            mat_mut(out),
            mat(&self.lu),
            mat(&self.lu),
            perm,
            Par::Seq,
            MemStack::new(buf),
        );
        out.iter().all(|x| x.is_finite()).then_some(())
    }
}

/// Smallest squared Cholesky pivot, relative to the largest, of a matrix [`SpdInverse`] and
/// [`spd6_inverse`] accept: a Gram matrix this well conditioned has full rank under any
/// rank rule of [`RANK_TOL`] (its singular values' ratio is the square root).
pub const SPD_TOL: f64 = 1e-12;

/// Whether Cholesky pivots `l_ii` are positive and their squared ratio above [`SPD_TOL`].
fn pivots_ok(diag: impl Iterator<Item = f64>) -> bool {
    let (lo, hi) = diag.fold((f64::INFINITY, 0.0f64), |(lo, hi), p| (lo.min(p), hi.max(p)));
    hi.is_finite() && lo > 0.0 && lo * lo > SPD_TOL * hi * hi
}

/// `A = L L^T` into `l`'s lower triangle (`a` square, symmetric: its lower triangle is read),
/// with the pivot rule of [`SpdInverse`]: for solving with [`spd_solve_in_place`] where the
/// inverse itself is not needed. `None` when `a` is not positive definite or its pivots fail
/// [`SPD_TOL`].
pub fn spd_factor(a: MatRef<'_, f64>, l: &mut DMatrix<f64>) -> Option<()> {
    let n = a.nrows();
    shape(l, n, n);
    let ls = l.as_mut_slice();
    for j in 0..n {
        for i in j..n {
            ls[j * n + i] = a[(i, j)];
        }
    }
    cholesky_in_place(ls, n, n, 0.0)?;
    pivots_ok((0..n).map(|i| ls[i * n + i])).then_some(())
}

/// `x = A^{-1} x` with `l` from [`spd_factor`]: `L y = x`, then `L^T x = y`.
pub fn spd_solve_in_place(l: &DMatrix<f64>, x: &mut [f64]) {
    let n = l.nrows();
    lower_solve_in_place(l.as_slice(), n, n, x, n, 1);
    lower_transpose_solve_in_place(l.as_slice(), n, n, x);
}

/// `x = L^{-T} x` for the lower triangle of `l`'s leading `n x n` block (leading dimension
/// `ld`, as [`cholesky_in_place`] leaves it): back substitution on one vector.
pub fn lower_transpose_solve_in_place(l: &[f64], ld: usize, n: usize, x: &mut [f64]) {
    for i in (0..n).rev() {
        let s = dot(&l[i * ld + i + 1..i * ld + n], &x[i + 1..n]);
        x[i] = (x[i] - s) / l[i * ld + i];
    }
}

/// Workspace of the inverse of a symmetric positive definite matrix by Cholesky, kept
/// between ticks (no allocation once shaped): `A = L L^T` in place ([`cholesky_in_place`]),
/// `X = L^{-1}` ([`lower_inverse`]), `A^{-1} = X^T X` by [`gemm`]. (nalgebra's
/// `Cholesky::solve_mut` on the identity, column by column, was a fifth of an eight-robot tick.)
#[derive(Debug, Clone, Default)]
pub struct SpdInverse {
    l: DMatrix<f64>,
    x: DMatrix<f64>,
}

impl SpdInverse {
    /// `out = a^{-1}` (`a` square, symmetric: its lower triangle is read). `None` when `a` is
    /// not positive definite or its pivots fail [`SPD_TOL`]; `out` is then `n x n` with
    /// unspecified contents. A 0 x 0 `a` gives a 0 x 0 `out`.
    pub fn compute(&mut self, a: MatRef<'_, f64>, out: &mut DMatrix<f64>) -> Option<()> {
        let n = a.nrows();
        // `l` is written by spd_factor, `x` by lower_inverse, `out` by gemm.
        shape(out, n, n);
        shape(&mut self.l, n, n);
        shape(&mut self.x, n, n);
        if n == 0 {
            return Some(());
        }
        spd_factor(a, &mut self.l)?;
        lower_inverse(self.l.as_slice(), n, self.x.as_mut_slice());
        // A^{-1} = X^T X with X = L^{-1} lower triangular: column block J of its lower
        // triangle is X[j0.., j0..]^T X[j0.., J] (the rows of X above j0 are zero in both
        // factors), a third of the full product's work; the upper triangle is mirrored.
        let x = mat(&self.x);
        for j0 in (0..n).step_by(CHOLESKY_BLOCK) {
            let nj = CHOLESKY_BLOCK.min(n - j0);
            gemm(
                mat_mut(out).submatrix_mut(j0, j0, n - j0, nj),
                0.0,
                1.0,
                x.submatrix(j0, j0, n - j0, n - j0).transpose(),
                x.submatrix(j0, j0, n - j0, nj),
            );
        }
        let o = out.as_mut_slice();
        for j in 0..n {
            for i in j + 1..n {
                o[i * n + j] = o[j * n + i];
            }
        }
        all_finite(out.as_slice()).then_some(())
    }
}

/// Cholesky `A = L L^T` of the leading `dim x dim` block of the column-major `a` (leading
/// dimension `ld`), in place: the lower triangle becomes `L`; the strict upper triangle is not
/// read, and near the diagonal it is left with unspecified values (the block products write
/// whole diagonal blocks). Nothing outside the leading block is touched. `None` on a pivot not
/// above `rel` times the largest diagonal entry, or not finite.
///
/// Blocked, right-looking: each block of [`CHOLESKY_BLOCK`] columns is factored left-looking
/// (axpys on contiguous columns, its panel below included), then the trailing lower triangle
/// takes `A_22 -= L_21 L_21^T` as [`gemm`]s by column blocks. (The unblocked axpys alone were
/// an eighth of an eight-robot tick: the active set factors the 144 x 144 objective.)
pub fn cholesky_in_place(a: &mut [f64], ld: usize, dim: usize, rel: f64) -> Option<()> {
    let top = (0..dim).map(|k| a[k * ld + k].abs()).fold(0.0, f64::max);
    for k0 in (0..dim).step_by(CHOLESKY_BLOCK) {
        let kb = CHOLESKY_BLOCK.min(dim - k0);
        for jc in k0..k0 + kb {
            // Earlier blocks are already in: only this block's columns left of jc.
            for k in k0..jc {
                let f = a[k * ld + jc];
                if f != 0.0 {
                    let (src, dst) = a.split_at_mut(jc * ld);
                    let src = &src[k * ld + jc..k * ld + dim];
                    for (y, x) in dst[jc..dim].iter_mut().zip(src) {
                        *y -= f * x;
                    }
                }
            }
            let dd = a[jc * ld + jc];
            if !(dd > rel * top && dd.is_finite()) {
                return None;
            }
            let s = dd.sqrt();
            for y in &mut a[jc * ld + jc..jc * ld + dim] {
                *y /= s;
            }
        }
        let t0 = k0 + kb;
        if t0 < dim {
            // A_22 -= L_21 L_21^T on and below the diagonal: L_21 lies in columns k0..t0, A_22
            // in the columns from t0 on (disjoint parts of the slice).
            let (left, right) = a.split_at_mut(t0 * ld);
            let panel = MatRef::from_column_major_slice_with_stride(&left[k0 * ld..], dim, kb, ld);
            let mut trailing =
                MatMut::from_column_major_slice_with_stride_mut(right, dim, dim - t0, ld);
            for j0 in (t0..dim).step_by(CHOLESKY_BLOCK) {
                let nj = CHOLESKY_BLOCK.min(dim - j0);
                let dst = trailing.as_mut().submatrix_mut(j0, j0 - t0, dim - j0, nj);
                gemm(
                    dst,
                    1.0,
                    -1.0,
                    panel.subrows(j0, dim - j0),
                    panel.subrows(j0, nj).transpose(),
                );
            }
        }
    }
    Some(())
}

/// `X = L^{-1} X` in place: forward substitution on the `cols` columns of `x` (column-major,
/// leading dimension `ldx`, `n` rows) with the lower triangle of `l`'s leading `n x n` block
/// (leading dimension `ldl`, as [`cholesky_in_place`] leaves it; its strict upper triangle
/// is not read). Blocked: each block of [`CHOLESKY_BLOCK`] rows is solved by axpys, then the
/// rows below take `X_2 -= L_21 X_1` as one [`gemm`].
pub fn lower_solve_in_place(
    l: &[f64],
    ldl: usize,
    n: usize,
    x: &mut [f64],
    ldx: usize,
    cols: usize,
) {
    if n == 0 || cols == 0 {
        return;
    }
    for k0 in (0..n).step_by(CHOLESKY_BLOCK) {
        let end = (k0 + CHOLESKY_BLOCK).min(n);
        for c in 0..cols {
            let col = &mut x[c * ldx..c * ldx + n];
            for i in k0..end {
                let xi = col[i] / l[i * ldl + i];
                col[i] = xi;
                if xi != 0.0 {
                    for (y, li) in
                        col[i + 1..end].iter_mut().zip(&l[i * ldl + i + 1..i * ldl + end])
                    {
                        *y -= xi * li;
                    }
                }
            }
        }
        if end < n {
            // X_2 -= L_21 X_1: rows end.. of x from its rows k0..end.
            let lm = MatRef::from_column_major_slice_with_stride(l, n, n, ldl);
            let mut xm = MatMut::from_column_major_slice_with_stride_mut(x, n, cols, ldx);
            let (top, below) = xm.as_mut().split_at_row_mut(end);
            gemm(
                below,
                1.0,
                -1.0,
                lm.submatrix(end, k0, n - end, end - k0),
                top.as_ref().subrows(k0, end - k0),
            );
        }
    }
}

/// Column block of [`cholesky_in_place`].
pub const CHOLESKY_BLOCK: usize = 16;

/// `x = L^{-1}` (both `n x n`, column-major) for the lower triangular `l` of
/// [`cholesky_in_place`] (its strict upper triangle is not read); `x`'s strict upper triangle
/// is zero. By blocks of [`CHOLESKY_BLOCK`] columns: block `c0..` of `L^{-1}` is zero above
/// row `c0` and solves `L[c0.., c0..] X = I` ([`lower_solve_in_place`]).
pub fn lower_inverse(l: &[f64], n: usize, x: &mut [f64]) {
    x.fill(0.0);
    for k in 0..n {
        x[k * n + k] = 1.0;
    }
    for c0 in (0..n).step_by(CHOLESKY_BLOCK) {
        let cb = CHOLESKY_BLOCK.min(n - c0);
        lower_solve_in_place(&l[c0 * n + c0..], n, n - c0, &mut x[c0 * n + c0..], n, cb);
    }
}

/// Make `p` exactly symmetric: each pair of entries replaced by their mean.
pub fn symmetrise(p: &mut DMatrix<f64>) {
    for i in 0..p.nrows() {
        for j in 0..i {
            let s = 0.5 * (p[(i, j)] + p[(j, i)]);
            p[(i, j)] = s;
            p[(j, i)] = s;
        }
    }
}

/// Inverse of a symmetric positive definite 6 x 6 matrix (a hand's block), with the pivot
/// rule of [`SpdInverse`].
pub fn spd6_inverse(a: &Matrix6<f64>) -> Option<Matrix6<f64>> {
    let chol = a.cholesky()?;
    pivots_ok(chol.l_dirty().diagonal().iter().copied()).then(|| chol.inverse())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The transpose agrees with nalgebra's on small, square and eight-robot shapes, into a
    /// buffer of another shape; the four-sum dot agrees with the sum written out; the
    /// branch-free finiteness check finds one NaN or infinity at any place, in the lanes and
    /// in the remainder.
    #[test]
    fn transpose_dot_and_finiteness_check_agree_with_the_plain_ones() {
        for (r, c) in [(1, 1), (3, 17), (16, 16), (33, 20), (144, 192)] {
            let a = DMatrix::<f64>::from_fn(r, c, |i, j| (i * 1000 + j) as f64);
            let mut out = DMatrix::from_element(2, 5, f64::NAN);
            transpose_into(&a, &mut out);
            assert_eq!(out, a.transpose(), "{r} x {c}");
        }
        for n in [0, 1, 3, 4, 7, 8, 145] {
            let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
            let y: Vec<f64> = (0..n).map(|i| (i as f64 * 1.3).cos() - 0.2).collect();
            let plain: f64 = x.iter().zip(&y).map(|(a, b)| a * b).sum();
            assert!((dot(&x, &y) - plain).abs() <= 1e-12 * (1.0 + plain.abs()), "n = {n}");
        }
        assert_eq!(dot(&[1.0, 2.0, 3.0], &[4.0, 5.0]), 14.0, "the common length");
        for n in [0, 5, 8, 21] {
            let v: Vec<f64> = (0..n).map(|i| i as f64 - 3.0).collect();
            assert!(all_finite(&v), "n = {n}");
            for at in 0..n {
                for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                    let mut w = v.clone();
                    w[at] = bad;
                    assert!(!all_finite(&w), "n = {n}, {bad} at {at}");
                }
            }
        }
        assert!(all_finite(&[f64::MAX, -f64::MAX, -0.0, f64::MIN_POSITIVE]));
    }

    /// The fallback pseudo-inverse (nalgebra's SVD) satisfies the Moore-Penrose conditions
    /// and keeps the rank rule of faer's path, on a rank-deficient matrix.
    #[test]
    fn the_fallback_pseudo_inverse_is_a_pseudo_inverse_of_the_same_rank() {
        let mut seed = 12345u64;
        let mut next = move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let b = DMatrix::from_fn(12, 5, |_, _| next());
        let c = DMatrix::from_fn(5, 9, |_, _| next());
        let a = &b * &c; // 12 x 9, rank 5
        let mut fast = DMatrix::zeros(0, 0);
        let mut slow = DMatrix::zeros(0, 0);
        let rank = Pinv::default().compute(mat(&a), 1e-10, &mut fast).expect("faer");
        let rank_fallback = Pinv::fallback(mat(&a), 1e-10, &mut slow).expect("nalgebra");
        assert_eq!((rank, rank_fallback), (5, 5));
        let scale = a.amax();
        assert!((&a * &slow * &a - &a).amax() < 1e-10 * scale, "A A+ A = A");
        assert!((&slow * &a * &slow - &slow).amax() < 1e-10 * slow.amax(), "A+ A A+ = A+");
        assert!((&a * &slow - (&a * &slow).transpose()).amax() < 1e-10, "A A+ symmetric");
        assert!((&slow - &fast).amax() < 1e-8 * slow.amax(), "both paths agree");
    }

    /// Against nalgebra's own SVD and the Moore-Penrose conditions, on a rank-deficient matrix.
    #[test]
    fn pinv_meets_the_penrose_conditions_and_reports_the_rank() {
        let b = DMatrix::<f64>::from_fn(7, 3, |i, j| ((i * 5 + j * 3) % 7) as f64 - 2.5);
        let c = DMatrix::<f64>::from_fn(3, 9, |i, j| ((i * 2 + j * 7) % 5) as f64 - 1.5);
        let a = &b * &c; // 7 x 9, rank 3
        let mut ws = Pinv::default();
        let mut x = DMatrix::zeros(0, 0);
        assert_eq!(ws.compute(mat(&a), RANK_TOL, &mut x), Some(3));
        assert_eq!(x.shape(), (9, 7));
        assert!((&a * &x * &a - &a).amax() < 1e-10);
        assert!((&x * &a * &x - &x).amax() < 1e-10);
        assert!(((&a * &x).transpose() - &a * &x).amax() < 1e-10);
        assert!(((&x * &a).transpose() - &x * &a).amax() < 1e-10);
        let oracle = a.clone().svd(true, true).pseudo_inverse(1e-9).unwrap();
        assert!((&x - oracle).amax() < 1e-10);
        // Same workspace, another shape, then a non-finite input.
        let a2 = a.transpose();
        assert_eq!(ws.compute(mat(&a2), RANK_TOL, &mut x), Some(3));
        assert!((&a2 * &x * &a2 - &a2).amax() < 1e-10);
        let mut bad = a.clone();
        bad[(1, 1)] = f64::NAN;
        assert_eq!(ws.compute(mat(&bad), RANK_TOL, &mut x), None);
    }

    #[test]
    fn spd_inverse_inverts_gram_matrices_and_declines_rank_deficient_ones() {
        let j = DMatrix::<f64>::from_fn(5, 8, |i, k| {
            ((i * 3 + k * 5) % 7) as f64 - 3.0 + if i == k { 4.0 } else { 0.0 }
        });
        let gram = &j * j.transpose();
        let mut ws = SpdInverse::default();
        let mut x = DMatrix::zeros(0, 0);
        ws.compute(mat(&gram), &mut x).expect("positive definite");
        assert!((&gram * &x - DMatrix::identity(5, 5)).amax() < 1e-12);
        let six =
            Matrix6::from_fn(|i, k| gram[(i.min(4), k.min(4))] + if i == k { 1.0 } else { 0.0 });
        assert!((six * spd6_inverse(&six).expect("regular") - Matrix6::identity()).amax() < 1e-10);
        let mut low = j.clone();
        let r0 = low.row(0).into_owned();
        low.row_mut(4).copy_from(&(r0 * 2.0));
        assert!(ws.compute(mat(&(&low * low.transpose())), &mut x).is_none(), "rank-deficient");
        ws.compute(mat(&DMatrix::zeros(0, 0)), &mut x).expect("empty");
        assert_eq!(x.shape(), (0, 0));
        // Across the column blocks of the product X^T X, into a dirty buffer of that shape,
        // symmetric to the last bit (the upper triangle is mirrored).
        for n in [16, 17, 40, 54] {
            let j = DMatrix::<f64>::from_fn(n, n + 3, |i, k| {
                ((i * 7 + k * 3) % 13) as f64 - 6.0 + if i == k { 9.0 } else { 0.0 }
            });
            let gram = &j * j.transpose();
            let mut inv = DMatrix::from_element(n, n, f64::NAN);
            ws.compute(mat(&gram), &mut inv).expect("positive definite");
            let err = (&gram * &inv - DMatrix::identity(n, n)).amax();
            assert!(err < 1e-9, "n = {n}: |A A^-1 - I| = {err:e}");
            assert_eq!(inv, inv.transpose(), "n = {n}: symmetric");
        }
    }

    /// `spd_factor` then `spd_solve_in_place` solve `A x = b` (residual written out), across
    /// the factor's column blocks and in a dirty buffer, and the factor refuses what
    /// `SpdInverse` refuses: a rank-deficient Gram matrix.
    #[test]
    fn spd_factor_solves_and_declines_as_the_inverse_does() {
        let mut l = DMatrix::from_element(3, 3, f64::NAN);
        for n in [1, 5, 16, 17, 54] {
            let j = DMatrix::<f64>::from_fn(n, n + 3, |i, k| {
                ((i * 7 + k * 3) % 13) as f64 - 6.0 + if i == k { 9.0 } else { 0.0 }
            });
            let gram = &j * j.transpose();
            spd_factor(mat(&gram), &mut l).expect("positive definite");
            let b = DVector::from_fn(n, |i, _| (i as f64 * 0.37).sin() + 0.5);
            let mut x = b.clone();
            spd_solve_in_place(&l, x.as_mut_slice());
            let err = (&gram * &x - &b).amax() / b.amax();
            assert!(err < 1e-10, "n = {n}: |A x - b| = {err:e}");
        }
        let j = DMatrix::<f64>::from_fn(5, 8, |i, k| {
            ((i * 3 + k * 5) % 7) as f64 - 3.0 + if i == k { 4.0 } else { 0.0 }
        });
        let mut low = j.clone();
        let r0 = low.row(0).into_owned();
        low.row_mut(4).copy_from(&(r0 * 2.0));
        assert!(spd_factor(mat(&(&low * low.transpose())), &mut l).is_none(), "rank-deficient");
    }

    /// The in-place Cholesky factor reproduces `A = L L^T` and `lower_inverse` gives
    /// `L X = I`; a reused, dirty `SpdInverse` output buffer is overwritten; the factor refuses
    /// an indefinite matrix.
    #[test]
    fn cholesky_in_place_and_lower_inverse_are_a_factor_and_its_inverse() {
        let j = DMatrix::<f64>::from_fn(7, 9, |i, k| {
            ((i * 5 + k * 3) % 11) as f64 - 5.0 + if i == k { 6.0 } else { 0.0 }
        });
        let a = &j * j.transpose();
        let mut l = a.clone();
        cholesky_in_place(l.as_mut_slice(), 7, 7, 0.0).expect("positive definite");
        let low = l.lower_triangle();
        assert!((&low * low.transpose() - &a).amax() < 1e-10 * a.amax());
        let mut x = DMatrix::from_element(7, 7, f64::NAN);
        lower_inverse(l.as_slice(), 7, x.as_mut_slice());
        assert!((&low * &x - DMatrix::identity(7, 7)).amax() < 1e-12);
        let mut ws = SpdInverse::default();
        let mut inv = DMatrix::from_element(7, 7, f64::NAN);
        ws.compute(mat(&a), &mut inv).expect("positive definite");
        assert!((&a * &inv - DMatrix::identity(7, 7)).amax() < 1e-10);
        let mut indefinite = a.clone();
        indefinite[(3, 3)] = -1.0;
        assert!(cholesky_in_place(indefinite.as_mut_slice(), 7, 7, 0.0).is_none());
    }

    /// The blocked factor over several blocks, of a leading `dim x dim` block (`dim` not a
    /// multiple of the block) inside a larger buffer, as the active set's Gram matrices are:
    /// `L L^T = A`, the buffer outside the leading block untouched; `L^{-1}` over several
    /// blocks.
    #[test]
    fn blocked_cholesky_of_a_leading_block_is_a_factor() {
        let (ld, dim) = (70, 2 * CHOLESKY_BLOCK + 13);
        let j = DMatrix::<f64>::from_fn(dim, dim + 5, |i, k| {
            (((i * 7 + k * 13) % 17) as f64 - 8.0) / 8.0 + if i == k { 3.0 } else { 0.0 }
        });
        let a = &j * j.transpose();
        let mut buf = DMatrix::from_element(ld, ld, 7.0);
        buf.view_mut((0, 0), (dim, dim)).copy_from(&a);
        cholesky_in_place(buf.as_mut_slice(), ld, dim, 0.0).expect("positive definite");
        let low = buf.view((0, 0), (dim, dim)).lower_triangle();
        assert!((&low * low.transpose() - &a).amax() < 1e-12 * a.amax());
        for c in 0..ld {
            for r in 0..ld {
                if r >= dim || c >= dim {
                    assert_eq!(buf[(r, c)], 7.0, "({r}, {c}) written");
                }
            }
        }
        // The blocked inverse of that factor, in its own buffer.
        let mut x = DMatrix::from_element(dim, dim, f64::NAN);
        lower_inverse(low.as_slice(), dim, x.as_mut_slice());
        assert!((&low * &x - DMatrix::identity(dim, dim)).amax() < 1e-12, "L X = I");
        assert!((0..dim).all(|c| (0..c).all(|r| x[(r, c)] == 0.0)), "X lower triangular");
        let mut indefinite = a.clone();
        indefinite[(dim - 2, dim - 2)] = -1.0;
        assert!(
            cholesky_in_place(indefinite.as_mut_slice(), dim, dim, 0.0).is_none(),
            "a pivot in the last block fails"
        );
    }

    /// The blocked forward substitution solves `L X = B` over several blocks, in buffers
    /// larger than the system (leading dimensions above `n`), and leaves the rest untouched.
    #[test]
    fn lower_solve_in_place_solves_the_triangular_system() {
        let (n, cols, ldl, ldx) =
            (3 * CHOLESKY_BLOCK + 5, 7, 60 + 3 * CHOLESKY_BLOCK, 4 * CHOLESKY_BLOCK);
        let low = DMatrix::<f64>::from_fn(n, n, |i, k| {
            if i < k {
                0.0
            } else if i == k {
                2.0 + (i % 3) as f64
            } else {
                (((i * 5 + k * 3) % 11) as f64 - 5.0) / 20.0
            }
        });
        let b = DMatrix::<f64>::from_fn(n, cols, |i, k| ((i * 3 + k * 7) % 13) as f64 - 6.0);
        let mut l = DMatrix::from_element(ldl, n, f64::NAN);
        for c in 0..n {
            for r in c..n {
                l[(r, c)] = low[(r, c)];
            }
        }
        let mut x = DMatrix::from_element(ldx, cols + 1, 5.0);
        x.view_mut((0, 0), (n, cols)).copy_from(&b);
        lower_solve_in_place(l.as_slice(), ldl, n, x.as_mut_slice(), ldx, cols);
        let sol = x.view((0, 0), (n, cols)).into_owned();
        assert!((&low * &sol - &b).amax() < 1e-12 * b.amax(), "L X = B");
        assert!(
            x.view((n, 0), (ldx - n, cols + 1))
                .iter()
                .chain(x.column(cols).iter())
                .all(|&v| v == 5.0),
            "outside X written"
        );
    }

    /// `gemm` with an empty inner dimension: `dst = beta dst`, and `beta = 0` clears a buffer
    /// that `shape` left dirty (what `product` relies on).
    #[test]
    fn gemm_without_inner_dimension_scales_or_clears() {
        let a = DMatrix::<f64>::zeros(3, 0);
        let b = DMatrix::<f64>::zeros(0, 2);
        let mut d = DMatrix::from_element(3, 2, 4.0);
        gemm(mat_mut(&mut d), 0.5, 1.0, mat(&a), mat(&b));
        assert!(d.iter().all(|&x| x == 2.0));
        let mut dirty = DMatrix::from_element(3, 2, f64::NAN);
        product(&mut dirty, mat(&a), mat(&b));
        assert!(dirty.iter().all(|&x| x == 0.0));
        let m = DMatrix::<f64>::from_fn(3, 4, |i, k| (i + 2 * k) as f64);
        let n = DMatrix::<f64>::from_fn(4, 2, |i, k| (3 * i) as f64 - k as f64);
        let mut p = DMatrix::from_element(3, 2, f64::NAN);
        product(&mut p, mat(&m), mat(&n));
        assert_eq!(p, &m * &n);
    }

    #[test]
    fn inverse_by_lu_and_singular_matrices() {
        let a = DMatrix::<f64>::from_fn(6, 6, |i, j| {
            if i == j {
                4.0
            } else {
                ((i + 2 * j) % 3) as f64 - 1.0
            }
        });
        let mut ws = Inverse::default();
        let mut x = DMatrix::zeros(0, 0);
        ws.compute(&a, &mut x).expect("regular");
        assert!((&a * &x - DMatrix::identity(6, 6)).amax() < 1e-12);
        let mut s = a.clone();
        let r0 = s.row(0).into_owned();
        s.row_mut(3).copy_from(&(r0 * 2.0));
        assert!(ws.compute(&s, &mut x).is_none(), "rank-deficient");
        assert!(ws.compute(&DMatrix::zeros(4, 4), &mut x).is_none());
    }
}
