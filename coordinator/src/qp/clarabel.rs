//! The Clarabel 0.11 adapter: the assembled QP handed to Clarabel's `DefaultSolver` (upper
//! triangle of `P`, one non-negative cone for `b - A F`). It builds its problem anew on every
//! call (it allocates); it runs only when [`super::DenseIpm`] did not converge, or always when
//! `dense_first` is off, and certifies infeasibility.

use std::time::Instant;

use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettings, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus};
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

/// Clarabel's status in the protocol's terms.
fn status(s: SolverStatus) -> QpStatus {
    match s {
        SolverStatus::Solved => QpStatus::Solved,
        SolverStatus::AlmostSolved => QpStatus::AlmostSolved,
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible | SolverStatus::DualInfeasible | SolverStatus::AlmostDualInfeasible => QpStatus::Infeasible,
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
    fn solve_problem(&mut self, problem: &QpProblem, settings: &QpSettings, x: &mut DVector<f64>) -> QpOutcome {
        let t0 = Instant::now();
        let (m, rows) = (problem.n(), problem.rows());
        let fail = |status| QpOutcome { status, iterations: 0, solve_us: 0.0, setup_us: 0.0, rows, solver: "clarabel" };
        let p = to_csc(&problem.p, true);
        let a_csc = to_csc(&problem.a, false);
        let q = vec![0.0; m];
        let cones = [NonnegativeConeT(rows)];
        let clarabel_settings = DefaultSettings::<f64> { verbose: false, max_iter: settings.max_iter, presolve_enable: false, ..DefaultSettings::default() };
        let setup_start = Instant::now();
        let Ok(mut solver) = DefaultSolver::new(&p, &q, &a_csc, problem.b.as_slice(), &cones, clarabel_settings) else {
            return fail(QpStatus::NumericalError);
        };
        let setup_us = setup_start.elapsed().as_secs_f64() * 1e6;
        solver.solve();
        let sol = &solver.solution;
        if sol.x.len() == m && all_finite(&sol.x) {
            if x.len() != m {
                zeros_v(x, m);
            }
            x.copy_from_slice(&sol.x);
        }
        QpOutcome { status: status(sol.status), iterations: sol.iterations, solve_us: t0.elapsed().as_secs_f64() * 1e6, setup_us, rows, solver: "clarabel" }
    }
}
