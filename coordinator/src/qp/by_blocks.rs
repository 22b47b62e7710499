//! [`BlockHotStart`]: the hot start of the contact-force QP by the robots' blocks, tried
//! before the team-sized problem is built (`docs/scale.md`).
//!
//! The QP of eq. wrench_optim2 written in the contact wrenches' change `z = rho F` instead of
//! `F`. Since `J_c^T rho = -Y` (eq. bmatrix: `Y = B J_c^T` has no unactuated rows;
//! `tests/qp_by_blocks.rs` checks it), the torque's change is `Y F = -J_c^T z`, and `z`
//! ranges over the wrenches `J_c` can hold whose torque leaves every floating base alone:
//!
//! ```text
//! min_z  |J_c^T z|^2                         (eq. wrench_optim2: |Y F|^2, without eps |F|^2)
//! s.t.   (J_r^T z_r)_u = 0     per robot r   (no torque on an unactuated joint)
//!        G z_h = 0                           (internal: z_h in N's range, eq. jacobian_cee)
//!        C_k (eta + z)_k >= d_k              (the same contact rows, eqs.
//!                                            unilateral_and_friction_cone_constraint,
//!                                            moment_constraint)
//!        |tau_0 - (J_c^T z)_a| <= tau_max    (eq. real_torque_limit)
//! ```
//!
//! with `J_r = [J_cf,r; J_ee,r]` robot r's own feet and hand rows on its own columns
//! (`J_ee^T N z_h = J_ee^T z_h` for `z_h` in `N`'s range). The objective and every row but
//! the six of `G z_h = 0` are robot by robot: `|J_c^T z|^2 = sum_r |J_r^T z_r|^2`, the base
//! rows being held at zero. `eps |F|^2` only chooses `F` along `Y`'s null space; dropping it
//! moves the torque by `O(eps / sigma_min(Y)^2)` (measured in `tests/qp_by_blocks.rs`).
//!
//! **The hot start.** On the previous tick's active rows `W` ([`super::DualActiveSet`]'s, in
//! the assembled problem's row order, which is this one's) the equality-constrained minimum is
//! `z = H^{-1} A^T nu` with `H = diag_r(J_r J_r^T)` and `A H^{-1} A^T nu = beta` (`A`: the
//! base rows, the coupling and `W`). `A H^{-1} A^T` is block-diagonal by robots but for the
//! coupling's 6 rows: each robot's block is factored alone, then the coupling's 6 x 6 Schur
//! complement. The answer is accepted only if it is the QP's optimum (for a convex QP the KKT
//! conditions are sufficient): every row held, the active ones with equality, and every
//! active row's multiplier non-negative, to [`super::ACTIVE_SET_TOL`] as the active set's own
//! hot start. Otherwise ([`Decline`]) the caller builds the team-sized QP. The work is a few
//! `18 x 18` factors per robot: linear in the team.

use nalgebra::{DMatrix, DVector, Matrix6, Vector6};

use super::rows::{contact_rows, ContactKind};
use crate::linalg::{
    cholesky_in_place, lower_solve_in_place, lower_transpose_solve_in_place, spd6_inverse, zeros,
    zeros_v,
};
use crate::team::Team;

/// Smallest Cholesky pivot, relative to the largest diagonal entry, of a robot's blocks (the
/// active set's own rule for its Gram matrix).
const PIVOT_REL: f64 = 1e-12;

/// What [`BlockHotStart::solve`] reads: the assembled problem's terms, robot by robot.
pub struct BlockInput<'a> {
    pub team: &'a Team,
    /// The grasp matrix `G` (6 x 6B) when hands hold the object.
    pub g: Option<&'a DMatrix<f64>>,
    /// The QP's contacts, `(first row in lambda, kind)`, feet then hands (see
    /// [`crate::building_blocks::contacts::contact_list`]).
    pub contacts: &'a [(usize, ContactKind)],
    /// `eta` with the object's load on the hand rows (what the contact rows constrain at `z = 0`).
    pub eta_real: &'a DVector<f64>,
    pub tau0: &'a DVector<f64>,
    pub actuated: &'a [usize],
    pub limits: &'a [f64],
}

/// Why the hot start did not answer (the caller then builds the team-sized QP).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum Decline {
    #[error("the last active set belongs to another shape of QP")]
    NoHotStart,
    #[error("the contact variables are not one block per robot")]
    NotByRobots,
    #[error(
        "robot {robot}'s contacts are not independent (J_r J_r^T or its active rows' Gram is \
         singular)"
    )]
    Singular { robot: usize },
    #[error("the grasp's coupling is singular on the active rows")]
    Coupling,
    #[error("the last active set is not optimal here (a row or a multiplier misses by {0:.1e})")]
    NotOptimal(f64),
    #[error("a value is not finite")]
    NonFinite,
}

/// One robot's part of the QP and its scratch (kept between ticks).
#[derive(Debug, Default)]
struct RobotQp {
    /// Team index of its first joint, and its joints.
    offset: usize,
    nv: usize,
    /// Its variables' indices in `lambda` (feet, then the hand).
    vars: Vec<usize>,
    /// Local index of its hand's first variable, and the hand's index in the team.
    hand: Option<(usize, usize)>,
    /// `J_r^T` (nv x m_r) and the Cholesky factor of `J_r J_r^T` (m_r x m_r).
    jt: DMatrix<f64>,
    l: DMatrix<f64>,
    /// The equality rows `a^T z_r = beta` as columns (m_r x m_r: at most m_r independent),
    /// then `V = L^{-1} A_r^T` in place; `rows[k]`: the assembled problem's row of column `k`
    /// (`None` for a base row).
    at: DMatrix<f64>,
    beta: DVector<f64>,
    rows: Vec<Option<usize>>,
    /// `U = L^{-1} C_r^T` (m_r x 6), `C_r` its block of the coupling `G`.
    u: DMatrix<f64>,
    /// `D = V^T V` (its Cholesky factor), `X = D^{-1} V^T U`, `y = D^{-1} beta`, the
    /// multipliers `nu` and the answer `z_r`.
    d: DMatrix<f64>,
    x: DMatrix<f64>,
    y: DVector<f64>,
    nu: DVector<f64>,
    z: DVector<f64>,
}

/// The hot start by the robots' blocks (see the module's docs); nothing is allocated once the
/// team's shape is known.
#[derive(Debug, Default)]
pub struct BlockHotStart {
    robots: Vec<RobotQp>,
    /// Which rows of the assembled problem are in `W`.
    in_w: Vec<bool>,
    /// Each contact's first row in the assembled problem.
    row0: Vec<usize>,
    /// The answer: the wrenches' change `z` (m) and the torque's change `-J_c^T z` (n).
    pub z: DVector<f64>,
    pub dtau: DVector<f64>,
    /// Rows of the assembled problem (contacts' and torque limits').
    pub rows: usize,
    /// The active rows of the last call (its answer's, when it answered), and how many times
    /// that call mended them.
    pub active: Vec<usize>,
    pub repairs: u32,
}

/// What [`BlockHotStart::verify`] found.
enum Verdict {
    Optimal,
    /// Not the optimum by `worst`: the active row with the most negative multiplier (`leave`)
    /// and the most violated inactive row (`enter`), when there are.
    NotOptimal {
        worst: f64,
        leave: Option<usize>,
        enter: Option<usize>,
    },
    Declined(Decline),
}

/// [`super::QpOutcome::solver`] of a tick this hot start answered.
pub const SOLVER: &str = "blocks";

impl BlockHotStart {
    /// The minimum on the active rows `warm` of the assembled problem of shape `warm_shape`
    /// (variables, rows) into [`BlockHotStart::z`] and [`BlockHotStart::dtau`], if it is the
    /// QP's optimum to `tol`. When it is not, up to `repairs` times the active set is mended
    /// and the minimum taken again: the row with the most negative multiplier leaves, or if
    /// none, the most violated row enters (a swap guessed from the multipliers and the
    /// violations, without a step length; the answer is accepted only when its KKT conditions
    /// hold, so a wrong guess costs a solve, never a wrong torque). The active rows of the
    /// answer are in [`BlockHotStart::active`].
    ///
    /// It declines (and the caller builds the team-sized QP) on a robot without contacts or
    /// with fewer contact variables than unactuated joints (its block has no solution), and on
    /// linearly dependent active rows, as when both bounds of a foot being unloaded bind.
    pub fn solve(
        &mut self,
        inp: &BlockInput,
        warm: &[usize],
        warm_shape: (usize, usize),
        tol: f64,
        repairs: u32,
    ) -> Result<(), Decline> {
        let m = inp.eta_real.len();
        let nc = self.contact_row_starts(inp);
        let rows = nc + 2 * inp.actuated.len();
        self.rows = rows;
        self.repairs = 0;
        // Sized before any decline: the first tick of a shape (which has no active set yet)
        // allocates, the next ones do not.
        self.setup(inp)?;
        self.size(m, inp.team.n, rows);
        // Every variable must belong to one robot's block: a variable no block holds would
        // stay at zero unchecked (a robot with two hands in grasp, which the team refuses
        // today, or a hand without a grasp).
        if self.robots.iter().map(|rq| rq.vars.len()).sum::<usize>() != m {
            return Err(Decline::NotByRobots);
        }
        if warm_shape != (m, rows) || warm.iter().any(|&i| i >= rows) {
            return Err(Decline::NoHotStart);
        }
        self.active.clear();
        self.active.extend_from_slice(warm);
        loop {
            self.minimize_on_active(inp, nc)?;
            match self.verify(inp, nc, tol) {
                Verdict::Optimal => return Ok(()),
                Verdict::Declined(d) => return Err(d),
                Verdict::NotOptimal { worst, .. } if self.repairs >= repairs => {
                    return Err(Decline::NotOptimal(worst))
                }
                Verdict::NotOptimal { leave: Some(i), .. } => self.active.retain(|&r| r != i),
                Verdict::NotOptimal { enter: Some(i), .. } => self.active.push(i),
                Verdict::NotOptimal { worst, .. } => return Err(Decline::NotOptimal(worst)),
            }
            self.repairs += 1;
        }
    }

    /// Each contact's first row into `row0`; the number of contact rows.
    fn contact_row_starts(&mut self, inp: &BlockInput) -> usize {
        self.row0.clear();
        let mut nc = 0;
        for (_, kind) in inp.contacts {
            self.row0.push(nc);
            nc += contact_rows(kind).len();
        }
        nc
    }

    /// The minimum with the rows in [`BlockHotStart::active`] held with equality, into
    /// [`BlockHotStart::z`] and [`BlockHotStart::dtau`] (`nc` contact rows).
    fn minimize_on_active(&mut self, inp: &BlockInput, nc: usize) -> Result<(), Decline> {
        self.in_w.iter_mut().for_each(|w| *w = false);
        for &i in &self.active {
            self.in_w[i] = true;
        }
        let active = std::mem::take(&mut self.active);
        let rows_set = self.equality_rows(inp, &active, nc);
        self.active = active;
        rows_set?;
        let nu_c = self.coupling(inp)?;
        self.answer(inp, &nu_c);
        Ok(())
    }

    /// Every buffer at its shape for `m` variables, `n` joints and `rows` rows (reallocated only
    /// when the shape changes).
    fn size(&mut self, m: usize, n: usize, rows: usize) {
        self.in_w.resize(rows, false);
        self.active.clear();
        self.active.reserve(rows);
        zeros_v(&mut self.z, m);
        zeros_v(&mut self.dtau, n);
        for rq in &mut self.robots {
            let mr = rq.vars.len();
            for buf in [&mut rq.at, &mut rq.d] {
                zeros(buf, mr, mr);
            }
            for buf in [&mut rq.u, &mut rq.x] {
                zeros(buf, mr, 6);
            }
            for v in [&mut rq.beta, &mut rq.y, &mut rq.nu, &mut rq.z] {
                zeros_v(v, mr);
            }
            rq.rows.clear();
            rq.rows.reserve(mr);
        }
    }

    /// Each robot's variables, `J_r^T` and the Cholesky factor of `J_r J_r^T`.
    fn setup(&mut self, inp: &BlockInput) -> Result<(), Decline> {
        let team = inp.team;
        let nf = team.feet.len();
        self.robots.resize_with(team.robots.len(), RobotQp::default);
        for (r, (rq, block)) in self.robots.iter_mut().zip(&team.robots).enumerate() {
            rq.offset = block.offset;
            rq.nv = block.nv;
            rq.vars.clear();
            rq.hand = None;
            for (k, f) in team.feet.iter().enumerate() {
                if f.robot == r {
                    rq.vars.extend(3 * k..3 * k + 3);
                }
            }
            if inp.g.is_some() {
                if let Some(i) = team.hands.iter().position(|h| h.robot == r) {
                    rq.hand = Some((rq.vars.len(), i));
                    rq.vars.extend(3 * nf + 6 * i..3 * nf + 6 * i + 6);
                }
            }
            let mr = rq.vars.len();
            zeros(&mut rq.jt, rq.nv, mr);
            for (v, &row) in rq.vars.iter().enumerate() {
                let (src, i) =
                    if row < 3 * nf { (&team.j_cf, row) } else { (&team.j_ee, row - 3 * nf) };
                for c in 0..rq.nv {
                    rq.jt[(c, v)] = src[(i, rq.offset + c)];
                }
            }
            zeros(&mut rq.l, mr, mr);
            rq.l.gemm_tr(1.0, &rq.jt, &rq.jt, 0.0);
            if mr == 0 || cholesky_in_place(rq.l.as_mut_slice(), mr, mr, PIVOT_REL).is_none() {
                return Err(Decline::Singular { robot: r });
            }
        }
        Ok(())
    }

    /// Each robot's equality rows (its base rows, then its rows of `W`) as the columns of
    /// `A_r^T`, and `V = L^{-1} A_r^T`.
    fn equality_rows(
        &mut self,
        inp: &BlockInput,
        warm: &[usize],
        nc: usize,
    ) -> Result<(), Decline> {
        let team = inp.team;
        let row0 = &self.row0;
        for (r, rq) in self.robots.iter_mut().enumerate() {
            let mr = rq.vars.len();
            zeros(&mut rq.at, mr, mr);
            zeros_v(&mut rq.beta, mr);
            rq.rows.clear();
            for c in 0..rq.nv {
                if team.s_diag[rq.offset + c] == 0.0 {
                    push_jt_row(rq, r, c, 1.0, 0.0, None)?;
                }
            }
        }
        for &i in warm {
            if i < nc {
                let (start, kind, k) =
                    contact_of_row(inp.contacts, row0, i).ok_or(Decline::NoHotStart)?;
                let r = robot_of_contact(team, start).ok_or(Decline::NoHotStart)?;
                let cr = contact_rows(&kind);
                let (c, lo) = cr.iter().nth(k).ok_or(Decline::NoHotStart)?;
                let dim = kind.dim();
                let rq = &mut self.robots[r];
                let local = rq.vars.iter().position(|&v| v == start).ok_or(Decline::NoHotStart)?;
                let e: f64 = (0..dim).map(|d| c[d] * inp.eta_real[start + d]).sum();
                let col = new_column(rq, r, lo - e, Some(i))?;
                for (d, x) in c.iter().enumerate() {
                    rq.at[(local + d, col)] = *x;
                }
            } else {
                // Torque row pair p: tau_0 - (J^T z)_j <= lim (even) and >= -lim (odd).
                let p = (i - nc) / 2;
                let (j, lim) = (inp.actuated[p], inp.limits[p]);
                let r = team
                    .robots
                    .iter()
                    .position(|b| (b.offset..b.offset + b.nv).contains(&j))
                    .ok_or(Decline::NoHotStart)?;
                let rq = &mut self.robots[r];
                let (sign, beta) = if (i - nc) & 1 == 0 {
                    (1.0, inp.tau0[j] - lim)
                } else {
                    (-1.0, -(lim + inp.tau0[j]))
                };
                push_jt_row(rq, r, j - rq.offset, sign, beta, Some(i))?;
            }
        }
        for rq in &mut self.robots {
            let (mr, k) = (rq.vars.len(), rq.rows.len());
            lower_solve_in_place(rq.l.as_slice(), mr, mr, rq.at.as_mut_slice(), mr, k);
        }
        Ok(())
    }

    /// Each robot's block of `A H^{-1} A^T` factored (`D = V^T V = L_D L_D^T`), and the
    /// coupling's multipliers from the 6 x 6 Schur complement
    /// `sum_r (U^T U - E~^T E~) nu_c = -sum_r E~^T y~` (`E~ = L_D^{-1} V^T U`,
    /// `y~ = L_D^{-1} beta`); zero without a grasp.
    fn coupling(&mut self, inp: &BlockInput) -> Result<Vector6<f64>, Decline> {
        let mut schur = Matrix6::zeros();
        let mut rhs = Vector6::zeros();
        for (r, rq) in self.robots.iter_mut().enumerate() {
            let (mr, k) = (rq.vars.len(), rq.rows.len());
            zeros(&mut rq.u, mr, 6);
            if let (Some(g), Some((h0, i))) = (inp.g, rq.hand) {
                // C_r^T = G_i^T on the hand's variables.
                for a in 0..6 {
                    for b in 0..6 {
                        rq.u[(h0 + a, b)] = g[(b, 6 * i + a)];
                    }
                }
                lower_solve_in_place(rq.l.as_slice(), mr, mr, rq.u.as_mut_slice(), mr, 6);
            }
            zeros(&mut rq.d, mr, mr);
            zeros(&mut rq.x, mr, 6);
            zeros_v(&mut rq.y, mr);
            {
                let v = rq.at.columns(0, k);
                rq.d.view_mut((0, 0), (k, k)).gemm_tr(1.0, &v, &v, 0.0);
                rq.x.view_mut((0, 0), (k, 6)).gemm_tr(1.0, &v, &rq.u, 0.0);
            }
            if k > 0 && cholesky_in_place(rq.d.as_mut_slice(), mr, k, PIVOT_REL).is_none() {
                return Err(Decline::Singular { robot: r });
            }
            rq.y.rows_mut(0, k).copy_from(&rq.beta.rows(0, k));
            lower_solve_in_place(rq.d.as_slice(), mr, k, rq.x.as_mut_slice(), mr, 6);
            lower_solve_in_place(rq.d.as_slice(), mr, k, rq.y.as_mut_slice(), mr, 1);
            for a in 0..6 {
                rhs[a] -= (0..k).map(|c| rq.x[(c, a)] * rq.y[c]).sum::<f64>();
                for b in 0..=a {
                    let s = (0..mr).map(|c| rq.u[(c, a)] * rq.u[(c, b)]).sum::<f64>()
                        - (0..k).map(|c| rq.x[(c, a)] * rq.x[(c, b)]).sum::<f64>();
                    schur[(a, b)] += s;
                    if a != b {
                        schur[(b, a)] += s;
                    }
                }
            }
        }
        if inp.g.is_none() {
            return Ok(Vector6::zeros());
        }
        let inv = spd6_inverse(&schur).ok_or(Decline::Coupling)?;
        Ok(inv * rhs)
    }

    /// Each robot's multipliers `nu_r = L_D^{-T} (y~ - E~ nu_c)` and answer
    /// `z_r = L^{-T} (V nu_r + U nu_c)`, then `z` and `dtau = -J_c^T z`.
    fn answer(&mut self, inp: &BlockInput, nu_c: &Vector6<f64>) {
        let m = inp.eta_real.len();
        zeros_v(&mut self.z, m);
        zeros_v(&mut self.dtau, inp.team.n);
        for rq in &mut self.robots {
            let (mr, k) = (rq.vars.len(), rq.rows.len());
            zeros_v(&mut rq.nu, mr);
            for c in 0..k {
                rq.nu[c] = rq.y[c] - (0..6).map(|b| rq.x[(c, b)] * nu_c[b]).sum::<f64>();
            }
            lower_transpose_solve_in_place(rq.d.as_slice(), mr, k, rq.nu.as_mut_slice());
            zeros_v(&mut rq.z, mr);
            for c in 0..k {
                rq.z.axpy(rq.nu[c], &rq.at.column(c), 1.0);
            }
            rq.z.gemv(1.0, &rq.u, nu_c, 1.0);
            lower_transpose_solve_in_place(rq.l.as_slice(), mr, mr, rq.z.as_mut_slice());
            for (v, &row) in rq.vars.iter().enumerate() {
                self.z[row] = rq.z[v];
            }
            let mut dt = self.dtau.rows_mut(rq.offset, rq.nv);
            dt.gemv(-1.0, &rq.jt, &rq.z, 0.0);
        }
    }

    /// The KKT conditions on what [`BlockHotStart::answer`] found: every row of the assembled
    /// problem held (slack `>= -tol (1 + |b_i|)`, `b_i` its value at `z = 0`), the rows of `W`
    /// with equality, the base rows and the coupling at zero, every multiplier of `W`
    /// non-negative (to `tol` of the largest).
    fn verify(&self, inp: &BlockInput, nc: usize, tol: f64) -> Verdict {
        let Some((mut worst, enter)) = self.row_misses(inp, nc, tol) else {
            return Verdict::Declined(Decline::NonFinite);
        };
        let equalities = self.equality_residual(inp);
        if equalities.is_nan() || equalities > tol {
            return Verdict::Declined(Decline::NotOptimal(equalities));
        }
        let multipliers = || {
            self.robots
                .iter()
                .flat_map(|rq| rq.rows.iter().zip(rq.nu.iter()))
                .filter_map(|(w, u)| w.map(|i| (i, *u)))
        };
        if multipliers().any(|(_, u)| !u.is_finite()) {
            return Verdict::Declined(Decline::NonFinite);
        }
        let numax = multipliers().fold(0.0f64, |m, (_, u)| m.max(u.abs()));
        let mut leave: Option<(usize, f64)> = None;
        for (i, u) in multipliers() {
            let miss = -u / (1.0 + numax);
            worst = worst.max(miss);
            if miss > tol && leave.is_none_or(|(_, m)| miss > m) {
                leave = Some((i, miss));
            }
        }
        if worst > tol || worst.is_nan() {
            return Verdict::NotOptimal {
                worst,
                leave: leave.map(|l| l.0),
                enter: enter.map(|e| e.0),
            };
        }
        Verdict::Optimal
    }

    /// The rows' worst relative miss (slack `>= -tol (1 + |b_i|)`, `b_i` its value at `z = 0`;
    /// the rows of `W` with equality) and the row outside `W` missed most beyond `tol`, or
    /// `None` when a slack is not finite.
    fn row_misses(
        &self,
        inp: &BlockInput,
        nc: usize,
        tol: f64,
    ) -> Option<(f64, Option<(usize, f64)>)> {
        let mut worst: f64 = 0.0;
        let mut enter: Option<(usize, f64)> = None;
        let mut finite = true;
        let mut row = |slack: f64, b: f64, i: usize| {
            let miss = if self.in_w[i] { slack.abs() } else { -slack } / (1.0 + b.abs());
            worst = worst.max(miss);
            if !self.in_w[i] && miss > tol && enter.is_none_or(|(_, m)| miss > m) {
                enter = Some((i, miss));
            }
            finite &= slack.is_finite();
        };
        let mut i = 0;
        for (start, kind) in inp.contacts {
            for (c, lo) in contact_rows(kind).iter() {
                let dim = kind.dim();
                let b: f64 = (0..dim).map(|d| c[d] * inp.eta_real[start + d]).sum::<f64>() - lo;
                let slack = b + (0..dim).map(|d| c[d] * self.z[start + d]).sum::<f64>();
                row(slack, b, i);
                i += 1;
            }
        }
        debug_assert_eq!(i, nc);
        for (p, (&j, &lim)) in inp.actuated.iter().zip(inp.limits).enumerate() {
            let t = inp.tau0[j] + self.dtau[j];
            row(lim - t, lim - inp.tau0[j], nc + 2 * p);
            row(lim + t, lim + inp.tau0[j], nc + 2 * p + 1);
        }
        finite.then_some((worst, enter))
    }

    /// The largest miss of the equalities (no torque on an unactuated joint, no coupling
    /// wrench `G z_h`), relative to the scale of the answer. They hold by construction: this
    /// checks them against round-off.
    fn equality_residual(&self, inp: &BlockInput) -> f64 {
        let scale = 1.0 + self.dtau.amax() + self.z.amax();
        let mut equalities: f64 = 0.0;
        for rq in &self.robots {
            for c in 0..rq.nv {
                if inp.team.s_diag[rq.offset + c] == 0.0 {
                    equalities = equalities.max(self.dtau[rq.offset + c].abs() / scale);
                }
            }
        }
        if let Some(g) = inp.g {
            let nf3 = 3 * inp.team.feet.len();
            for a in 0..6 {
                let gz: f64 = (0..g.ncols()).map(|c| g[(a, c)] * self.z[nf3 + c]).sum();
                equalities = equalities.max(gz.abs() / scale);
            }
        }
        equalities
    }
}

/// A new equality column `a^T z_r = beta` of robot `robot`'s block, from the assembled
/// problem's row `row` (`None` for a base row): its index, its entries left at zero for the
/// caller to write; an error when the robot already has as many as it has variables (they
/// cannot be independent).
fn new_column(
    rq: &mut RobotQp,
    robot: usize,
    beta: f64,
    row: Option<usize>,
) -> Result<usize, Decline> {
    let col = rq.rows.len();
    if col >= rq.vars.len() {
        return Err(Decline::Singular { robot });
    }
    rq.beta[col] = beta;
    rq.rows.push(row);
    Ok(col)
}

/// `sign` times row `c` of `J_r^T` as a new equality column ([`new_column`]).
fn push_jt_row(
    rq: &mut RobotQp,
    robot: usize,
    c: usize,
    sign: f64,
    beta: f64,
    row: Option<usize>,
) -> Result<(), Decline> {
    let col = new_column(rq, robot, beta, row)?;
    for v in 0..rq.vars.len() {
        rq.at[(v, col)] = sign * rq.jt[(c, v)];
    }
    Ok(())
}

/// The contact of the assembled problem's row `i` (`i` below the contacts' rows), with
/// `row0` each contact's first row: its first row in `lambda`, its kind and the row's number
/// among its rows.
fn contact_of_row(
    contacts: &[(usize, ContactKind)],
    row0: &[usize],
    i: usize,
) -> Option<(usize, ContactKind, usize)> {
    let c = row0.partition_point(|&first| first <= i).checked_sub(1)?;
    let (start, kind) = *contacts.get(c)?;
    (i - row0[c] < contact_rows(&kind).len()).then_some((start, kind, i - row0[c]))
}

/// The robot of the contact whose first row in `lambda` is `start` (feet, then hands).
fn robot_of_contact(team: &Team, start: usize) -> Option<usize> {
    let nf3 = 3 * team.feet.len();
    if start < nf3 {
        team.feet.get(start / 3).map(|f| f.robot)
    } else {
        team.hands.get((start - nf3) / 6).map(|h| h.robot)
    }
}
