//! The MQP solved by Clarabel (sparse, interior point; certifies infeasibility), and the
//! fallback torque when it fails.
//!
//! **Allocations.** The problem's dense and CSC matrices are kept between ticks
//! ([`super::problem`]); Clarabel's `DefaultSolver::new` builds its KKT system, factorisation
//! and iterates anew on every tick (it allocates: the certified general solver is called as
//! it is; the no-allocation rule holds for the controller's own code path).

use std::time::Instant;

use clarabel::solver::{DefaultSettings, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus, ZeroConeT};
use nalgebra::DVector;
use protocol::QpStatus;

use crate::linalg::zeros_v;
use crate::mqp::problem::MqpProblem;

/// The solve's outcome (the solution is written to the caller's vector).
#[derive(Debug, Clone, Copy)]
pub struct SolveOutcome {
    pub status: QpStatus,
    pub iterations: u32,
    /// Clarabel's whole call (setup and solve), µs.
    pub solve_us: f64,
}

impl Default for SolveOutcome {
    fn default() -> Self {
        SolveOutcome { status: QpStatus::NotRun, iterations: 0, solve_us: 0.0 }
    }
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

/// Solve `problem` with Clarabel into `x` (sized to the problem). `x` is written only when the
/// status is `Solved` or `AlmostSolved` and the point is finite; otherwise it is left as it was.
pub fn solve(problem: &MqpProblem, max_iter: u32, x: &mut DVector<f64>) -> SolveOutcome {
    let t0 = Instant::now();
    let l = problem.layout;
    let us = || t0.elapsed().as_secs_f64() * 1e6;
    let finite = problem.p.iter().chain(problem.q.iter()).chain(problem.a.iter()).chain(problem.b.iter()).all(|v| v.is_finite());
    if !finite {
        return SolveOutcome { status: QpStatus::NumericalError, iterations: 0, solve_us: us() };
    }
    let cones = [ZeroConeT(l.eq), NonnegativeConeT(l.ineq)];
    let settings = DefaultSettings::<f64> { verbose: false, max_iter, presolve_enable: false, ..DefaultSettings::default() };
    let Ok(mut solver) = DefaultSolver::new(&problem.p_csc, problem.q.as_slice(), &problem.a_csc, problem.b.as_slice(), &cones, settings) else {
        return SolveOutcome { status: QpStatus::NumericalError, iterations: 0, solve_us: us() };
    };
    solver.solve();
    let sol = &solver.solution;
    let st = status(sol.status);
    if matches!(st, QpStatus::Solved | QpStatus::AlmostSolved) && sol.x.len() == l.vars() && sol.x.iter().all(|v| v.is_finite()) {
        if x.len() != l.vars() {
            zeros_v(x, l.vars());
        }
        x.copy_from_slice(&sol.x);
        return SolveOutcome { status: st, iterations: sol.iterations, solve_us: us() };
    }
    let st = if matches!(st, QpStatus::Solved | QpStatus::AlmostSolved) { QpStatus::NumericalError } else { st };
    SolveOutcome { status: st, iterations: sol.iterations, solve_us: us() }
}
