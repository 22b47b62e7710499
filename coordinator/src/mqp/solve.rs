//! The MQP solved by Clarabel (sparse, interior point; certifies infeasibility) through the
//! coordinator's one Clarabel call ([`crate::qp::clarabel::run`]).
//!
//! **Allocations.** The problem's dense and CSC matrices are kept between ticks
//! ([`super::problem`]); Clarabel's `DefaultSolver::new` builds its KKT system, factorisation
//! and iterates anew on every tick (it allocates: the certified general solver is called as
//! it is; the no-allocation rule holds for the controller's own code path).

use std::time::Instant;

use ::clarabel::solver::{NonnegativeConeT, ZeroConeT};
use nalgebra::DVector;
use protocol::QpStatus;

use crate::mqp::problem::MqpProblem;
use crate::qp::clarabel::{self, Accept, ConicProblem};

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

/// Solve `problem` with Clarabel into `x` (sized to the problem). `x` is written only when the
/// status is `Solved` or `AlmostSolved` and the point is finite; otherwise it is left as it was.
pub fn solve(problem: &MqpProblem, max_iter: u32, x: &mut DVector<f64>) -> SolveOutcome {
    let t0 = Instant::now();
    let l = problem.layout;
    let us = || t0.elapsed().as_secs_f64() * 1e6;
    let finite = problem
        .p
        .iter()
        .chain(problem.q.iter())
        .chain(problem.a.iter())
        .chain(problem.b.iter())
        .all(|v| v.is_finite());
    if !finite {
        return SolveOutcome { status: QpStatus::NumericalError, iterations: 0, solve_us: us() };
    }
    let cones = [ZeroConeT(l.eq), NonnegativeConeT(l.ineq)];
    let conic = ConicProblem {
        p: &problem.p_csc,
        q: problem.q.as_slice(),
        a: &problem.a_csc,
        b: problem.b.as_slice(),
        cones: &cones,
    };
    let Some(run) = clarabel::run(&conic, (max_iter, None), Accept::Solved, x) else {
        return SolveOutcome { status: QpStatus::NumericalError, iterations: 0, solve_us: us() };
    };
    // A solved status without a finite point of the right size is a numerical error.
    let solved = matches!(run.status, QpStatus::Solved | QpStatus::AlmostSolved);
    let status = if solved && !run.written { QpStatus::NumericalError } else { run.status };
    SolveOutcome { status, iterations: run.iterations, solve_us: us() }
}
