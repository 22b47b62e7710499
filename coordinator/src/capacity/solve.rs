//! Solving the static problem with Clarabel: the relaxed problem (decides feasibility and
//! names the binding limits), the hard problem (the forces themselves), the capacity by
//! bisection.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettings, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus, SupportedConeT,
    ZeroConeT,
};
use nalgebra::{DMatrix, DVector};

use super::limits::Limit;
use super::problem::StaticProblem;
use super::report::{BindingLimit, CapacityError};
use crate::qp::to_csc;

/// A slack above this (N or Nm) makes the mass infeasible.
pub const FEASIBILITY_TOL: f64 = 1e-6;

/// Default width of the capacity's bracket, kg.
pub const CAPACITY_TOLERANCE: f64 = 1e-3;

/// Weight of each slack's square beside its sum in the relaxed objective, per N^2: it makes
/// the excess unique (shared evenly between symmetric robots) without changing which masses
/// are feasible.
const SLACK_SQUARE: f64 = 1e-3;

/// A limit row this close to its bound (N or Nm) counts as reached at the capacity.
pub const REACHED_TOL: f64 = 0.05;

/// Largest mass the bisection looks at, kg.
const MAX_MASS: f64 = 1e6;

/// The relaxed problem's answer at a mass: `min sum s + SLACK_SQUARE |s|^2` subject to the
/// equalities and `A lambda - s <= b`, `s >= 0`.
#[derive(Debug, Clone)]
pub struct Relaxed {
    pub mass: f64,
    pub lambda: DVector<f64>,
    /// One slack per limit row (N or Nm).
    pub slack: DVector<f64>,
}

impl Relaxed {
    /// No limit row exceeded by more than [`FEASIBILITY_TOL`].
    pub fn feasible(&self) -> bool {
        self.slack.iter().all(|s| *s <= FEASIBILITY_TOL)
    }

    /// The rows over by more than [`FEASIBILITY_TOL`], largest first.
    pub fn binding(&self, p: &StaticProblem) -> Vec<BindingLimit> {
        let over: Vec<(usize, f64)> = self
            .slack
            .iter()
            .enumerate()
            .filter(|(_, s)| **s > FEASIBILITY_TOL)
            .map(|(i, s)| (i, *s))
            .collect();
        p.limits_at(&self.lambda, &over)
    }
}

/// Contact wrenches that hold the object at a mass.
#[derive(Debug, Clone)]
pub struct StaticSolution {
    pub mass: f64,
    /// `lambda`: 3 per stance foot, then 6 per hand (world-aligned, on the robot).
    pub lambda: DVector<f64>,
    /// The actuated joints' torques (team order of [`StaticProblem::actuated`]).
    pub torques: DVector<f64>,
    /// Largest `A lambda - b` (<= about [`FEASIBILITY_TOL`]) and `|E lambda - e|_inf`.
    pub worst_limit: f64,
    pub equality_residual: f64,
}

/// The capacity: the heaviest mass found feasible, within `infeasible_at - mass`.
#[derive(Debug, Clone)]
pub struct Capacity {
    pub mass: f64,
    /// The lightest mass found infeasible, and its binding limits.
    pub infeasible_at: f64,
    pub binding: Vec<BindingLimit>,
    /// The limits the forces holding `mass` reach (within [`REACHED_TOL`]).
    pub reached: Vec<BindingLimit>,
    /// Relaxed problems solved.
    pub solves: usize,
}

fn check_mass(mass: f64) -> Result<(), CapacityError> {
    if mass.is_finite() && mass >= 0.0 {
        Ok(())
    } else {
        Err(CapacityError::InvalidMass(mass))
    }
}

/// Clarabel on `min 1/2 x^T P x + q^T x` s.t. `A_eq x = b_eq`, `A_in x <= b_in`: the point
/// when (almost) solved, `Ok(None)` when infeasible.
fn clarabel(
    p: &DMatrix<f64>,
    q: &DVector<f64>,
    a: &DMatrix<f64>,
    b: &DVector<f64>,
    eq: usize,
) -> Result<Option<DVector<f64>>, CapacityError> {
    let settings = DefaultSettings::<f64> {
        verbose: false,
        max_iter: 200,
        tol_feas: 1e-10,
        tol_gap_abs: 1e-10,
        tol_gap_rel: 1e-10,
        ..DefaultSettings::default()
    };
    let cones: [SupportedConeT<f64>; 2] = [ZeroConeT(eq), NonnegativeConeT(a.nrows() - eq)];
    let (pc, ac): (CscMatrix<f64>, CscMatrix<f64>) = (to_csc(p, true), to_csc(a, false));
    let mut solver = DefaultSolver::new(&pc, q.as_slice(), &ac, b.as_slice(), &cones, settings)
        .map_err(|e| CapacityError::Solver(format!("{e:?}")))?;
    solver.solve();
    let sol = &solver.solution;
    match sol.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved
            if sol.x.iter().all(|x| x.is_finite()) =>
        {
            Ok(Some(DVector::from_column_slice(&sol.x)))
        }
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => Ok(None),
        s => Err(CapacityError::Solver(format!("status {s:?}"))),
    }
}

impl StaticProblem {
    /// The named limits of rows `(i, over)` at `lambda`, largest `over` first.
    fn limits_at(&self, lambda: &DVector<f64>, rows: &[(usize, f64)]) -> Vec<BindingLimit> {
        let tau = self.torques(lambda);
        // The torque rows come last, two per actuated joint.
        let first_torque = self.rows.len() - 2 * self.actuated.len();
        let mut out: Vec<BindingLimit> = rows
            .iter()
            .map(|&(i, over)| {
                let row = &self.rows[i];
                let torque =
                    matches!(row.limit, Limit::Torque { .. }).then(|| tau[(i - first_torque) / 2]);
                BindingLimit {
                    robot: row.robot.clone(),
                    place: row.place.clone(),
                    limit: row.limit,
                    over,
                    torque,
                }
            })
            .collect();
        out.sort_by(|a, b| b.over.total_cmp(&a.over));
        out
    }

    /// The limits `lambda` reaches: rows within `tol` (N or Nm) of their bound or over it,
    /// closest to (or furthest over) first; `over` is `A lambda - b` (<= 0 when within).
    pub fn reached(&self, lambda: &DVector<f64>, tol: f64) -> Vec<BindingLimit> {
        let r = &self.a * lambda - &self.b;
        let rows: Vec<(usize, f64)> =
            r.iter().enumerate().filter(|(_, x)| **x > -tol).map(|(i, x)| (i, *x)).collect();
        self.limits_at(lambda, &rows)
    }

    /// The equalities' right-hand side at `mass`.
    fn rhs(&self, mass: f64) -> DVector<f64> {
        &self.e0 + &self.e1 * mass
    }

    /// The relaxed problem at `mass` (variables `[lambda; s]`).
    pub fn relaxed(&self, mass: f64) -> Result<Relaxed, CapacityError> {
        check_mass(mass)?;
        let (m, r, ne) = (self.unknowns(), self.a.nrows(), self.e.nrows());
        let mut p = DMatrix::zeros(m + r, m + r);
        p.view_mut((0, 0), (m, m)).copy_from(&self.p);
        p.view_mut((m, m), (r, r)).fill_diagonal(2.0 * SLACK_SQUARE);
        let mut q = DVector::zeros(m + r);
        q.rows_mut(m, r).fill(1.0);
        let mut a = DMatrix::zeros(ne + 2 * r, m + r);
        a.view_mut((0, 0), (ne, m)).copy_from(&self.e);
        a.view_mut((ne, 0), (r, m)).copy_from(&self.a);
        a.view_mut((ne, m), (r, r)).fill_diagonal(-1.0);
        a.view_mut((ne + r, m), (r, r)).fill_diagonal(-1.0);
        let mut b = DVector::zeros(ne + 2 * r);
        b.rows_mut(0, ne).copy_from(&self.rhs(mass));
        b.rows_mut(ne, r).copy_from(&self.b);
        let x = clarabel(&p, &q, &a, &b, ne)?.ok_or(CapacityError::NoEquilibrium { mass })?;
        Ok(Relaxed {
            mass,
            lambda: x.rows(0, m).into_owned(),
            slack: x.rows(m, r).map(|s| s.max(0.0)),
        })
    }

    /// Contact wrenches holding `mass`, or [`CapacityError::Infeasible`] with the binding limits.
    pub fn solve(&self, mass: f64) -> Result<StaticSolution, CapacityError> {
        let relaxed = self.relaxed(mass)?;
        if !relaxed.feasible() {
            return Err(CapacityError::Infeasible { mass, binding: relaxed.binding(self) });
        }
        let (ne, r) = (self.e.nrows(), self.a.nrows());
        let mut a = DMatrix::zeros(ne + r, self.unknowns());
        a.rows_mut(0, ne).copy_from(&self.e);
        a.rows_mut(ne, r).copy_from(&self.a);
        let mut b = DVector::zeros(ne + r);
        b.rows_mut(0, ne).copy_from(&self.rhs(mass));
        b.rows_mut(ne, r).copy_from(&self.b);
        // Right at the capacity the hard problem may fail to converge: the relaxed point holds.
        let mut lambda =
            clarabel(&self.p, &self.q, &a, &b, ne).ok().flatten().unwrap_or(relaxed.lambda);
        self.polish(mass, &mut lambda)?;
        let worst_limit = (&self.a * &lambda - &self.b).max();
        let equality_residual = (&self.e * &lambda - self.rhs(mass)).amax();
        Ok(StaticSolution {
            mass,
            torques: self.torques(&lambda),
            lambda,
            worst_limit,
            equality_residual,
        })
    }

    /// The least change of `lambda` that satisfies the equalities to rounding
    /// (`lambda -= E^+ (E lambda - e)`).
    fn polish(&self, mass: f64, lambda: &mut DVector<f64>) -> Result<(), CapacityError> {
        let res = &self.e * &*lambda - self.rhs(mass);
        let svd = self.e.clone().svd(true, true);
        let d = svd
            .solve(&res, 1e-12)
            .map_err(|e| CapacityError::Solver(format!("equality polish: {e}")))?;
        *lambda -= d;
        Ok(())
    }

    /// The heaviest object the team holds, by bisection on the relaxed problem until the
    /// bracket is narrower than `tolerance` kg. Errors when not even 0 kg is held.
    pub fn capacity(&self, tolerance: f64) -> Result<Capacity, CapacityError> {
        if !(tolerance.is_finite() && tolerance > 0.0) {
            return Err(CapacityError::Input(format!(
                "capacity tolerance {tolerance} kg must be positive"
            )));
        }
        let mut solves = 2;
        let zero = self.relaxed(0.0)?;
        if !zero.feasible() {
            return Err(CapacityError::Infeasible { mass: 0.0, binding: zero.binding(self) });
        }
        let (mut lo, mut hi) = (0.0, 1.0);
        let mut at_hi = self.relaxed(hi)?;
        while at_hi.feasible() {
            (lo, hi) = (hi, 2.0 * hi);
            if hi > MAX_MASS {
                return Err(CapacityError::Unbounded { mass: lo });
            }
            at_hi = self.relaxed(hi)?;
            solves += 1;
        }
        while hi - lo > tolerance {
            let mid = 0.5 * (lo + hi);
            let r = self.relaxed(mid)?;
            solves += 1;
            if r.feasible() {
                lo = mid;
            } else {
                (hi, at_hi) = (mid, r);
            }
        }
        let reached = self.reached(&self.solve(lo)?.lambda, REACHED_TOL);
        Ok(Capacity { mass: lo, infeasible_at: hi, binding: at_hi.binding(self), reached, solves })
    }
}
