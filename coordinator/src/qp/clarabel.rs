//! The Clarabel 0.11 adapter, the coordinator's one call of Clarabel and its status mapping
//! ([`run`]): the contact-force QP ([`Clarabel`], upper triangle of `P`, one non-negative cone
//! for `b - A F`) and the MQP ([`crate::mqp::solve`]) are both solved through it. Clarabel
//! builds its problem anew on every call (it allocates); for the contact-force QP it runs
//! only when the dense methods did not converge, or always on [`super::QpPath::Clarabel`],
//! and certifies infeasibility.

use std::time::{Duration, Instant};

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettings, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus, SupportedConeT,
};
use nalgebra::{DMatrix, DVector};
use protocol::QpStatus;

use super::problem::QpProblem;
use super::settings::QpSettings;
use super::{QpOutcome, QpSolver};
use crate::linalg::{all_finite, zeros_v};

/// Clarabel as a [`QpSolver`] (stateless: Clarabel keeps nothing between ticks here).
#[derive(Debug, Default, Clone, Copy)]
pub struct Clarabel;

/// Dense column-major matrix to Clarabel's CSC, keeping only the upper triangle if `triu`.
pub fn to_csc(a: &DMatrix<f64>, triu: bool) -> CscMatrix<f64> {
    let (m, n) = a.shape();
    let mut colptr = Vec::with_capacity(n + 1);
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    colptr.push(0);
    for j in 0..n {
        let end = if triu { (j + 1).min(m) } else { m };
        for i in 0..end {
            let x = a[(i, j)];
            if x != 0.0 {
                rowval.push(i);
                nzval.push(x);
            }
        }
        colptr.push(rowval.len());
    }
    CscMatrix::new(m, n, colptr, rowval, nzval)
}

/// A conic problem as Clarabel takes it: `min 1/2 x^T P x + q^T x  s.t.  A x + s = b`,
/// `s` in `cones` (`P` its upper triangle).
#[derive(Clone, Copy)]
pub struct ConicProblem<'a> {
    pub p: &'a CscMatrix<f64>,
    pub q: &'a [f64],
    pub a: &'a CscMatrix<f64>,
    pub b: &'a [f64],
    pub cones: &'a [SupportedConeT<f64>],
}

/// Which of Clarabel's answers [`run`] copies into the caller's `x` (a finite point of the
/// right size in either case).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Accept {
    /// Whatever the status (the contact-force QP keeps the last iterate).
    AnyStatus,
    /// Only a `Solved` or `AlmostSolved` answer (the MQP keeps its last solution otherwise).
    Solved,
}

/// What one call of Clarabel gave.
#[derive(Debug, Clone, Copy)]
pub struct ClarabelRun {
    pub status: QpStatus,
    pub iterations: u32,
    /// Clarabel's setup (`DefaultSolver::new`), µs.
    pub setup_us: f64,
    /// Whether the answer was copied into `x` ([`Accept`]).
    pub written: bool,
}

/// Solve `problem` with Clarabel (`max_iter` iterations, within `time_limit` when given, no
/// presolve, quiet) and copy its answer into `x` (sized to the problem's variables if it is
/// not) when `accept` allows it. `None` when Clarabel refuses the problem at setup.
pub fn run(
    problem: &ConicProblem,
    (max_iter, time_limit): (u32, Option<Duration>),
    accept: Accept,
    x: &mut DVector<f64>,
) -> Option<ClarabelRun> {
    let settings = DefaultSettings::<f64> {
        verbose: false,
        max_iter,
        time_limit: time_limit.map_or(f64::INFINITY, |t| t.as_secs_f64()),
        presolve_enable: false,
        ..DefaultSettings::default()
    };
    let setup_start = Instant::now();
    let mut solver =
        DefaultSolver::new(problem.p, problem.q, problem.a, problem.b, problem.cones, settings)
            .ok()?;
    let setup_us = setup_start.elapsed().as_secs_f64() * 1e6;
    solver.solve();
    let sol = &solver.solution;
    let st = status(sol.status);
    let n = problem.a.n;
    let accepted = match accept {
        Accept::AnyStatus => true,
        Accept::Solved => matches!(st, QpStatus::Solved | QpStatus::AlmostSolved),
    };
    let written = accepted && sol.x.len() == n && all_finite(&sol.x);
    if written {
        if x.len() != n {
            zeros_v(x, n);
        }
        x.copy_from_slice(&sol.x);
    }
    Some(ClarabelRun { status: st, iterations: sol.iterations, setup_us, written })
}

/// Clarabel's status in the protocol's terms.
fn status(s: SolverStatus) -> QpStatus {
    match s {
        SolverStatus::Solved => QpStatus::Solved,
        SolverStatus::AlmostSolved => QpStatus::AlmostSolved,
        SolverStatus::PrimalInfeasible
        | SolverStatus::AlmostPrimalInfeasible
        | SolverStatus::DualInfeasible
        | SolverStatus::AlmostDualInfeasible => QpStatus::Infeasible,
        SolverStatus::MaxIterations | SolverStatus::MaxTime => QpStatus::MaxIterations,
        _ => QpStatus::NumericalError,
    }
}

impl QpSolver for Clarabel {
    fn name(&self) -> &'static str {
        "clarabel"
    }

    /// Writes `x` whenever Clarabel returns a finite point of the right size, whatever its
    /// status (a setup error is a `NumericalError` with `x` untouched).
    fn solve_problem(
        &mut self,
        problem: &QpProblem,
        settings: &QpSettings,
        x: &mut DVector<f64>,
    ) -> QpOutcome {
        let t0 = Instant::now();
        let (m, rows) = (problem.n(), problem.rows());
        let p = to_csc(&problem.p, true);
        let a_csc = to_csc(&problem.a, false);
        let q = vec![0.0; m];
        let cones = [NonnegativeConeT(rows)];
        let conic =
            ConicProblem { p: &p, q: &q, a: &a_csc, b: problem.b.as_slice(), cones: &cones };
        let limits = (settings.max_iter, settings.time_left());
        let Some(run) = run(&conic, limits, Accept::AnyStatus, x) else {
            return QpOutcome {
                status: QpStatus::NumericalError,
                iterations: 0,
                solve_us: 0.0,
                setup_us: 0.0,
                rows,
                solver: "clarabel",
            };
        };
        QpOutcome {
            status: run.status,
            iterations: run.iterations,
            solve_us: t0.elapsed().as_secs_f64() * 1e6,
            setup_us: run.setup_us,
            rows,
            solver: "clarabel",
        }
    }
}
