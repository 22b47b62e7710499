//! The contact-force QP (eq. wrench_optim2):
//!
//! ```text
//! min_F  F^T (J_c B^T B J_c^T + eps I) F
//! s.t.   C_k (rho F + eta)_k >= d_k     friction + unilateral
//!                                       (eqn. unilateral_and_friction_cone_constraint)
//!                                       and hand moments (eqn. moment_constraint), per contact k
//!        tau_min - tau_0 <= Xi F <= tau_max - tau_0
//!                                       (eq. real_torque_limit, Xi = S_ns^T B J_c^T)
//! ```
//!
//! where `lambda = rho F + eta` (eq. relation_between_lambda_and_Fc) are the predicted real
//! contact wrenches ON the robots (world-aligned, at the contact frame origins; for hands the
//! offset of the object load is already in `eta`, see `pidc/stages/wrench.rs`).
//!
//! Laid out as Clarabel is, data apart from solvers, one file per concept:
//!
//! - [`rows`]: one contact's rows `c . lambda_k >= lo` ([`ContactKind`], [`contact_rows`]); the
//!   sign conventions, a palm's sliding and torsion in one cone and the tilt-moment pairing,
//!   which deviate from the paper.
//! - [`problem`]: the controller's terms ([`QpInput`]) and the assembled
//!   `min 1/2 F^T P F, A F <= b` ([`QpProblem`], [`constraints_into`], [`objective_into`]).
//! - [`settings`]: [`QpSettings`]: where the solve starts ([`QpPath`]), iterations, tolerances,
//!   the fallback's price.
//! - [`by_blocks`]: [`BlockHotStart`], the hot start by the robots' blocks in the wrenches'
//!   change `z = rho F`, tried before the team-sized QP is built.
//! - [`active_set`]: [`DualActiveSet`], the Goldfarb–Idnani dual active-set method hot-started
//!   from the last tick, tried first on the team-sized QP.
//! - [`dense_ipm`]: [`DenseIpm`], the dense interior-point method tried next.
//! - [`clarabel`]: [`Clarabel`], the adapter to Clarabel 0.11 ([`to_csc`]).
//! - [`least_violation`]: [`solve_least_violation`], the fallback when the QP is infeasible.
//! - here: the [`QpSolver`] interface, [`QpOutcome`], [`QpWorkspace`] and [`solve`] (down the
//!   [`QpPath`] chain: active set, dense, then Clarabel).

pub mod active_set;
pub mod by_blocks;
pub mod clarabel;
pub mod dense_ipm;
pub mod least_violation;
pub mod problem;
pub mod rows;
pub mod settings;

use std::time::Instant;

use nalgebra::DVector;
pub use protocol::QpStatus;

pub use active_set::{ActiveSetError, DualActiveSet};
pub use by_blocks::{BlockHotStart, BlockInput, Decline};
pub use clarabel::{to_csc, Clarabel};
pub use dense_ipm::DenseIpm;
pub use least_violation::{solve_least_violation, solve_least_violation_with};
pub use problem::{constraints_into, objective_into, QpInput, QpProblem};
pub use rows::{contact_rows, ContactKind, ContactRows, FRICTION_SIGNS, MAX_CONTACT_ROWS};
pub use settings::{
    QpPath, QpSettings, ACTIVE_SET_MAX_ITER, ACTIVE_SET_TOL, BLOCK_REPAIRS, DENSE_TOL,
    HARD_ROW_FACTOR, LEAST_VIOLATION_MIN_ITER, REDUCED_TOL, VIOLATION_WEIGHT,
};

use crate::linalg::zeros_v;
use least_violation::LeastViolation;

/// A solver of the assembled QP `min 1/2 x^T P x  s.t.  A x <= b` ([`QpProblem`]).
pub trait QpSolver {
    /// What [`QpOutcome::solver`] reports.
    fn name(&self) -> &'static str;
    /// Solve `problem` under `settings` into `x` (sized to `problem.n()` if it is not). Each
    /// solver says when it writes `x`; the outcome's `solve_us` is the solver's own time.
    fn solve_problem(
        &mut self,
        problem: &QpProblem,
        settings: &QpSettings,
        x: &mut DVector<f64>,
    ) -> QpOutcome;
}

/// The QP's outcome (the forces are written to the caller's vector).
#[derive(Debug, Clone, Copy)]
pub struct QpOutcome {
    pub status: QpStatus,
    pub iterations: u32,
    pub solve_us: f64,
    pub setup_us: f64,
    pub rows: usize,
    /// Which solver produced the answer: "blocks" ([`BlockHotStart`], run by `Pidc` before the
    /// team-sized QP), "active-set", "dense-ipm" or "clarabel".
    pub solver: &'static str,
}

impl Default for QpOutcome {
    fn default() -> Self {
        QpOutcome {
            status: QpStatus::NotRun,
            iterations: 0,
            solve_us: 0.0,
            setup_us: 0.0,
            rows: 0,
            solver: "none",
        }
    }
}

/// The QP's matrices and its solvers' scratch, kept between ticks.
#[derive(Default)]
pub struct QpWorkspace {
    problem: QpProblem,
    active_set: DualActiveSet,
    ipm: DenseIpm,
    lv: LeastViolation,
}

impl QpWorkspace {
    /// The problem last assembled by [`solve`] or [`solve_least_violation`].
    pub fn problem(&self) -> &QpProblem {
        &self.problem
    }

    /// The dual active set's last active rows and problem shape ([`DualActiveSet::warm`]).
    pub fn warm(&self) -> (&[usize], (usize, usize)) {
        self.active_set.warm()
    }

    /// The next hot start's rows ([`DualActiveSet::set_warm`]).
    pub fn set_warm(&mut self, rows: &[usize], shape: (usize, usize)) {
        self.active_set.set_warm(rows, shape);
    }
}

/// Solve the QP into `f` (length m), with [`QpSettings::new`]`(max_iter, QpPath::default())`.
/// Never panics; a solver error is a `NumericalError` status with `F = 0`.
///
/// The dense interior-point method runs in `ws` and allocates nothing once the team's shape
/// is set; Clarabel, when it has to finish a tick, builds its problem anew (it allocates).
pub fn solve(
    ws: &mut QpWorkspace,
    inp: &QpInput,
    max_iter: u32,
    f: &mut DVector<f64>,
) -> QpOutcome {
    solve_with(ws, inp, &QpSettings::new(max_iter, QpPath::default()), f)
}

/// [`solve`] with explicit settings, down the chain of `settings.path` ([`QpPath`]; the hot
/// start by the robots' blocks of [`QpPath::ByBlocks`] is the controller's, before this):
/// [`DualActiveSet`] (hot-started from the last call's active rows), then [`DenseIpm`] when
/// it does not solve the QP, [`Clarabel`] when neither does (it also certifies
/// infeasibility, so the status of an infeasible QP is always Clarabel's). Past
/// `settings.deadline` the chain stops after the solver that was running (its outcome is
/// returned), and Clarabel stops at it.
/// `solve_us` is the whole call's time, assembly included.
pub fn solve_with(
    ws: &mut QpWorkspace,
    inp: &QpInput,
    settings: &QpSettings,
    f: &mut DVector<f64>,
) -> QpOutcome {
    let t0 = Instant::now();
    zeros_v(f, inp.rho.ncols());
    ws.problem.assemble(inp);
    if !ws.problem.is_finite() {
        let rows = ws.problem.rows();
        return QpOutcome {
            status: QpStatus::NumericalError,
            iterations: 0,
            solve_us: 0.0,
            setup_us: 0.0,
            rows,
            solver: "clarabel",
        };
    }
    let timed = |out: QpOutcome| QpOutcome { solve_us: t0.elapsed().as_secs_f64() * 1e6, ..out };
    if settings.path.tries_active_set() {
        let out = ws.active_set.solve_problem(&ws.problem, settings, f);
        if out.status == QpStatus::Solved
            || (settings.active_set_refuses && out.status == QpStatus::Infeasible)
            || settings.out_of_time()
        {
            return timed(out);
        }
    }
    if settings.path.tries_dense_ipm() {
        let out = ws.ipm.solve_problem(&ws.problem, settings, f);
        if matches!(out.status, QpStatus::Solved | QpStatus::AlmostSolved) || settings.out_of_time()
        {
            return timed(out);
        }
    }
    timed(Clarabel.solve_problem(&ws.problem, settings, f))
}
