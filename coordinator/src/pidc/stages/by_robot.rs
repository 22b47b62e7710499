//! A team that holds nothing is as many QPs as robots: without grasp rows `P`, `B`, `Y` and
//! `rho` are block-diagonal by robot (eqs. aghili_21, bmatrix, relation_between_lambda_and_Fc),
//! so robot `k`'s contact forces meet only its own contact rows and torque limits (eqs.
//! unilateral_and_friction_cone_constraint, real_torque_limit). When the team's QP fails on
//! such a team, [`solve_by_robot`] solves each robot's block alone and sends a fallback only
//! to the robots whose block fails.
//!
//! Why: solved as one problem, one robot that cannot be held (a torso that is falling, its
//! rows violated by thousands of newtons) made the whole team's QP infeasible, and every robot
//! got the least-violation fallback, whose iterations and step choice are the team's: three
//! robots that had let go of a 2 kg object mid-walk all fell after one of them tipped
//! (README "Walking while holding", Known limits).

use nalgebra::{DMatrix, DVector};
use protocol::QpStatus;

use crate::linalg::{zeros, zeros_v};
use crate::qp::{self, ContactKind, QpInput, QpOutcome, QpSettings, QpWorkspace};
use crate::team::Team;

use super::torque::fallback;

/// One robot's block of the QP's data: its contact variables (a range of `F_c`) and its
/// joints, copied out of the team's.
#[derive(Default)]
struct BlockData {
    y: DMatrix<f64>,
    rho: DMatrix<f64>,
    eta: DVector<f64>,
    tau0: DVector<f64>,
    contacts: Vec<(usize, ContactKind)>,
    actuated: Vec<usize>,
    limits: Vec<f64>,
}

/// A block's data, its forces and its solver's workspace (warm starts stay the robot's own).
#[derive(Default)]
struct Block {
    data: BlockData,
    f: DVector<f64>,
    qp: QpWorkspace,
}

/// Scratch of [`solve_by_robot`], one block per robot, kept between ticks.
#[derive(Default)]
pub struct ByRobotScratch {
    blocks: Vec<Block>,
}

/// What [`solve_by_robot`] did.
#[derive(Debug, Clone)]
pub struct ByRobot {
    /// The worst of the robots' statuses and the sum of their iterations and times.
    pub outcome: QpOutcome,
    /// What was sent instead of a solved QP, robot by robot; `None` when every robot's block
    /// was solved on an unsaturated `tau_0`.
    pub fallback: Option<String>,
}

/// Whether [`solve_by_robot`] applies: two robots or more and no grasp rows in the QP.
pub fn decoupled(team: &Team) -> bool {
    team.robots.len() > 1 && team.hands.is_empty()
}

/// Solve the team's QP (`inp`, a [`decoupled`] team) robot by robot into `f_c` (m): each
/// robot's block is solved, and a robot whose block fails gets [`fallback`] on its own
/// block. `saturated`: `tau_0` was saturated at the limits before (see
/// [`super::torque::saturate`]).
pub fn solve_by_robot(team: &Team, inp: &QpInput, settings: &QpSettings, saturated: bool, ws: &mut ByRobotScratch, f_c: &mut DVector<f64>) -> ByRobot {
    let m = inp.rho.ncols();
    zeros_v(f_c, m);
    ws.blocks.resize_with(team.robots.len(), Block::default);
    let mut outcome = QpOutcome { status: QpStatus::Solved, rows: 0, solver: "by-robot", ..QpOutcome::default() };
    let mut notes: Vec<String> = Vec::new();
    let mut foot = 0;
    for (k, robot) in team.robots.iter().enumerate() {
        let feet = team.feet[foot..].iter().take_while(|f| f.robot == k).count();
        let vars = (3 * foot, 3 * feet);
        foot += feet;
        let Block { data, f, qp: qp_ws } = &mut ws.blocks[k];
        data.copy_from(inp, robot.offset, robot.nv, vars);
        if feet == 0 {
            // Nothing to choose: tau_0 alone, clamped when it is over a limit.
            if data.actuated.iter().zip(&data.limits).any(|(&j, &lim)| data.tau0[j].abs() > lim) {
                notes.push(format!("{}: no stance foot, tau_0 clamped to the torque limits", robot.id));
            }
            continue;
        }
        // Saturation changed this robot's tau_0 only if an entry sits at its limit.
        let saturated = saturated && data.actuated.iter().zip(&data.limits).any(|(&j, &lim)| data.tau0[j].abs() >= lim);
        let sub = data.input(inp);
        let out = qp::solve_with(qp_ws, &sub, settings, f);
        let note = fallback(qp_ws, &sub, settings.max_iter, out.status, saturated, f);
        f_c.rows_mut(vars.0, vars.1).copy_from(f);
        outcome.iterations += out.iterations;
        outcome.solve_us += out.solve_us;
        outcome.setup_us += out.setup_us;
        outcome.rows += out.rows;
        outcome.status = worse(outcome.status, out.status);
        if let Some(n) = note {
            notes.push(format!("{}: {n}", robot.id));
        }
    }
    let fallback = (!notes.is_empty()).then(|| format!("solved robot by robot (no grasp couples them); {}", notes.join("; ")));
    ByRobot { outcome, fallback }
}

/// The worse of two statuses: anything not solved over `AlmostSolved` over `Solved`.
fn worse(a: QpStatus, b: QpStatus) -> QpStatus {
    let rank = |s: QpStatus| match s {
        QpStatus::Solved => 0,
        QpStatus::AlmostSolved => 1,
        _ => 2,
    };
    if rank(b) > rank(a) {
        b
    } else {
        a
    }
}

impl BlockData {
    /// Robot's block of the team's data: joints `offset..offset + nv`, contact variables
    /// `vars = (first, count)` (its stance feet, 3 each, with their rows of `lambda`).
    fn copy_from(&mut self, inp: &QpInput, offset: usize, nv: usize, (v0, nvar): (usize, usize)) {
        zeros(&mut self.y, nv, nvar);
        self.y.copy_from(&inp.y.view((offset, v0), (nv, nvar)));
        zeros(&mut self.rho, nvar, nvar);
        self.rho.copy_from(&inp.rho.view((v0, v0), (nvar, nvar)));
        zeros_v(&mut self.eta, nvar);
        self.eta.copy_from(&inp.eta.rows(v0, nvar));
        zeros_v(&mut self.tau0, nv);
        self.tau0.copy_from(&inp.tau0.rows(offset, nv));
        self.contacts.clear();
        self.contacts.extend(inp.contacts.iter().filter(|(row, _)| (v0..v0 + nvar).contains(row)).map(|(row, kind)| (row - v0, *kind)));
        self.actuated.clear();
        self.limits.clear();
        for (&j, &lim) in inp.actuated.iter().zip(inp.limits) {
            if (offset..offset + nv).contains(&j) {
                self.actuated.push(j - offset);
                self.limits.push(lim);
            }
        }
    }

    /// The block as a QP of its own, with the team's settings.
    fn input<'a>(&'a self, team: &QpInput) -> QpInput<'a> {
        QpInput {
            y: &self.y,
            rho: &self.rho,
            eta: &self.eta,
            contacts: &self.contacts,
            actuated: &self.actuated,
            limits: &self.limits,
            tau0: &self.tau0,
            regularisation: team.regularisation,
            dense_first: team.dense_first,
        }
    }
}
