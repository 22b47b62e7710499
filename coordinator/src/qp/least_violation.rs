//! The fallback when the QP is infeasible or fails: the least-violation relaxation, solved
//! by an active-set Newton method.

use nalgebra::{DMatrix, DVector};

use super::problem::{QpInput, QpProblem};
use super::rows::{contact_rows, ContactKind};
use super::settings::QpSettings;
use super::QpWorkspace;
use crate::linalg::{all_finite, zeros, zeros_v};

/// Scratch of [`solve_least_violation`], kept between ticks in the [`QpWorkspace`].
#[derive(Default)]
pub(crate) struct LeastViolation {
    k: DMatrix<f64>,
    rhs: DVector<f64>,
    r: DVector<f64>,
    hf: DVector<f64>,
    best: DVector<f64>,
    active: Vec<bool>,
    now: Vec<bool>,
    /// Price of each row (see [`row_weights`]).
    weights: Vec<f64>,
}

/// Ridges (times `K`'s largest diagonal entry) tried in turn until `K` factors.
const RIDGES: [f64; 4] = [0.0, 1e-13, 1e-11, 1e-9];

/// Each row's price of violation, in the order of [`super::problem::constraints_into`]: the
/// hands' rows (squeeze, friction, centre of pressure) at `w`, the stance feet's rows and the
/// torque limits at `w * hard_factor`. The object yields first: what cannot be kept is the
/// grasp, never the footing or the joints.
fn row_weights(inp: &QpInput, w: f64, hard_factor: f64, out: &mut Vec<f64>) {
    out.clear();
    for (_, kind) in inp.contacts {
        let price = match kind {
            ContactKind::Foot { .. } => w * hard_factor,
            ContactKind::Hand { .. } => w,
        };
        out.extend(std::iter::repeat_n(price, contact_rows(kind).len()));
    }
    out.extend(std::iter::repeat_n(w * hard_factor, 2 * inp.actuated.len()));
}

/// What one Newton step of [`solve_least_violation_with`] reads: the objective `H`, the rows
/// `A F <= b`, their prices and which rows are violated.
struct NewtonRows<'a> {
    h: &'a DMatrix<f64>,
    a: &'a DMatrix<f64>,
    b: &'a DVector<f64>,
    weights: &'a [f64],
    active: &'a [bool],
}

/// One Newton step with the violated rows `V`: `F` (into `f`) from
/// `(H + A_V^T W_V A_V) F = A_V^T W_V b_V`, with `k` and `rhs` as scratch. The hard rows'
/// prices (1e9) against `H`'s regularisation (1e-6) can leave `K` numerically indefinite:
/// Cholesky is retried with a ridge relative to `K`'s largest diagonal entry ([`RIDGES`]).
/// Whether one of them factored.
fn newton_step(
    rows: NewtonRows,
    k: &mut DMatrix<f64>,
    rhs: &mut DVector<f64>,
    f: &mut DVector<f64>,
) -> bool {
    let NewtonRows { h, a, b, weights, active } = rows;
    let m = h.nrows();
    // K = H + A_V^T W_V A_V, rhs = A_V^T W_V b_V.
    let build = |k: &mut DMatrix<f64>, rhs: &mut DVector<f64>| {
        zeros(k, m, m);
        k.copy_from(h);
        rhs.fill(0.0);
        for i in (0..a.nrows()).filter(|&i| active[i]) {
            let ai = a.row(i);
            k.ger(weights[i], &ai.transpose(), &ai.transpose(), 1.0);
            rhs.axpy(weights[i] * b[i], &ai.transpose(), 1.0);
        }
    };
    for ridge in RIDGES {
        build(k, rhs);
        let top = k.diagonal().amax();
        for i in 0..m {
            k[(i, i)] += ridge * top;
        }
        let kk = std::mem::replace(k, DMatrix::zeros(0, 0));
        if let Some(chol) = kk.cholesky() {
            f.copy_from(rhs);
            chol.solve_mut(f);
            *k = chol.unpack_dirty();
            return true;
        }
    }
    false
}

/// The fallback when the QP is infeasible: every row `A F <= b` may be violated at a price,
/// `min F^T H F + sum_i w_i max(0, a_i F - b_i)^2`, `w_i` = [`super::VIOLATION_WEIGHT`] on the
/// hands' rows and [`super::HARD_ROW_FACTOR`] times that on the feet's rows and the torque
/// limits (the object yields first). Always solvable; it keeps what can be kept (the footing
/// and the joints, then as much squeeze as is left) instead of dropping every contact force.
/// Solved by the active-set Newton method of this piecewise quadratic: with the violated rows
/// `V`, `(H + A_V^T W_V A_V) F = A_V^T W_V b_V`, until `V` repeats (a few 36 x 36
/// solves; a slack per row in the interior-point method instead, 170 variables, takes a
/// second per tick). Writes `F` into `f` and returns the largest violation, or
/// `None` if a solve fails. It builds `H`, `A` and `b` into `ws` itself (as [`super::solve`]
/// does), so it does not depend on what ran before; on this rare path that is cheap next to
/// its solves.
pub fn solve_least_violation(
    ws: &mut QpWorkspace,
    inp: &QpInput,
    max_iter: u32,
    f: &mut DVector<f64>,
) -> Option<f64> {
    solve_least_violation_with(ws, inp, &QpSettings { max_iter, ..QpSettings::default() }, f)
}

/// [`solve_least_violation`] with explicit settings (`max_iter`, `violation_weight`,
/// `hard_row_factor`, `least_violation_min_iter`).
pub fn solve_least_violation_with(
    ws: &mut QpWorkspace,
    inp: &QpInput,
    settings: &QpSettings,
    f: &mut DVector<f64>,
) -> Option<f64> {
    let m = inp.rho.ncols();
    let w = settings.violation_weight;
    ws.problem.assemble(inp);
    let QpWorkspace { problem: QpProblem { h, a, b, .. }, lv, .. } = ws;
    if !(all_finite(b.as_slice()) && all_finite(a.as_slice()) && all_finite(h.as_slice())) {
        return None;
    }
    let rows = a.nrows();
    row_weights(inp, w, settings.hard_row_factor, &mut lv.weights);
    if lv.weights.len() != rows {
        return None;
    }
    let weights = &lv.weights[..];
    let cost = ViolationCost { h, a, b, weights };
    zeros_v(f, m);
    zeros_v(&mut lv.r, rows);
    zeros_v(&mut lv.hf, m);
    zeros_v(&mut lv.rhs, m);
    zeros_v(&mut lv.best, m);
    let mut best = cost.of(f, &mut lv.r, &mut lv.hf);
    lv.active.clear();
    lv.active.resize(rows, false);
    let mut first = true;
    for _ in 0..settings.max_iter.max(settings.least_violation_min_iter) {
        lv.now.clear();
        lv.now.extend(lv.r.iter().map(|r| *r > 0.0));
        let any = lv.now.iter().any(|x| *x);
        if !first && lv.now == lv.active {
            break;
        }
        first = false;
        std::mem::swap(&mut lv.active, &mut lv.now);
        let violated = NewtonRows { h, a, b, weights, active: &lv.active };
        if !newton_step(violated, &mut lv.k, &mut lv.rhs, f) {
            return None;
        }
        let c = cost.of(f, &mut lv.r, &mut lv.hf);
        if c < best {
            best = c;
            lv.best.copy_from(f);
        }
        if !any {
            break;
        }
    }
    f.copy_from(&lv.best);
    cost.of(f, &mut lv.r, &mut lv.hf);
    Some(lv.r.iter().copied().fold(0.0, f64::max))
}

/// The least-violation cost `F^T H F + sum_i w_i max(0, (A F - b)_i)^2` of a problem's terms.
struct ViolationCost<'a> {
    h: &'a DMatrix<f64>,
    a: &'a DMatrix<f64>,
    b: &'a DVector<f64>,
    weights: &'a [f64],
}

impl ViolationCost<'_> {
    /// The cost of `f`; leaves the residual `A F - b` in `r` (and `H F` in `hf`).
    fn of(&self, f: &DVector<f64>, r: &mut DVector<f64>, hf: &mut DVector<f64>) -> f64 {
        r.copy_from(self.b);
        r.gemv(1.0, self.a, f, -1.0);
        hf.gemv(1.0, self.h, f, 0.0);
        f.dot(hf) + r.iter().zip(self.weights).map(|(v, wi)| wi * v.max(0.0).powi(2)).sum::<f64>()
    }
}
