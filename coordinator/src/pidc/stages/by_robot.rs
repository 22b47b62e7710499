//! A team that holds nothing is as many QPs as robots: without grasp rows `P`, `B`, `Y` and
//! `rho` are block-diagonal by robot (eqs. aghili_21, bmatrix, relation_between_lambda_and_Fc),
//! so robot `k`'s contact forces meet only its own contact rows and torque limits (eqs.
//! unilateral_and_friction_cone_constraint, real_torque_limit). When the team's QP fails on
//! such a team, [`ByRobotScratch`] takes the degradation steps robot by robot: each block is
//! solved ([`ByRobotScratch::solve`]); only the robots whose block fails get their `tau_0`
//! saturated and their block solved again on the rebuilt map
//! ([`ByRobotScratch::saturate_failed`]), then the least-violation fallback if it still fails
//! ([`ByRobotScratch::finish`]). A robot whose block is feasible gets its exact optimum.
//!
//! Why: solved as one problem, one robot that cannot be held (a torso that is falling, its
//! rows violated by thousands of newtons) made the whole team's QP infeasible, and every robot
//! got the least-violation fallback, whose iterations and step choice are the team's
//! (`tests/by_robot.rs`: a standing robot's torques then differed by 176 % from its own
//! optimum).

use std::ops::Range;

use nalgebra::{DMatrix, DVector};
use protocol::QpStatus;

use crate::linalg::{zeros, zeros_v};
use crate::qp::{self, ContactKind, QpInput, QpOutcome, QpSettings, QpWorkspace};
use crate::team::Team;

use super::torque::{fallback, saturate};

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

/// A block's data, its forces, its solver's workspace (warm starts stay the robot's own) and
/// how its last solve went.
#[derive(Default)]
struct Block {
    data: BlockData,
    f: DVector<f64>,
    qp: QpWorkspace,
    /// Its contact variables in `F_c`: `(first, count)`.
    vars: (usize, usize),
    out: QpOutcome,
    /// Its `tau_0` was saturated at the limits ([`ByRobotScratch::saturate_failed`]).
    saturated: bool,
}

impl Block {
    fn solved(&self) -> bool {
        matches!(self.out.status, QpStatus::Solved | QpStatus::AlmostSolved)
    }
}

/// Scratch of the robot-by-robot solve, one block per robot, kept between ticks.
#[derive(Default)]
pub struct ByRobotScratch {
    blocks: Vec<Block>,
}

/// What the robot-by-robot solve did ([`ByRobotScratch::finish`]).
#[derive(Debug, Clone)]
pub struct ByRobot {
    /// The worst of the robots' statuses and the sum of their iterations and times.
    pub outcome: QpOutcome,
    /// What was sent instead of a solved QP, robot by robot; `None` when every robot's block
    /// was solved on its unsaturated `tau_0`.
    pub fallback: Option<String>,
    /// Some robot's `tau_0` was saturated at the limits.
    pub saturated: bool,
}

/// Whether the robot-by-robot solve applies: two robots or more and no grasp rows in the QP.
pub fn decoupled(team: &Team) -> bool {
    team.robots.len() > 1 && team.hands.is_empty()
}

impl ByRobotScratch {
    /// Solve each robot's block of `inp` (a [`decoupled`] team's QP) into its range of `f_c`
    /// (m): every block when `retry` is false, else only the blocks whose `tau_0` was just
    /// saturated (their contact map was built again by the caller).
    pub fn solve(
        &mut self,
        team: &Team,
        inp: &QpInput,
        settings: &QpSettings,
        retry: bool,
        f_c: &mut DVector<f64>,
    ) {
        if !retry {
            zeros_v(f_c, inp.rho.ncols());
            self.blocks.resize_with(team.robots.len(), Block::default);
        }
        let mut foot = 0;
        for (k, robot) in team.robots.iter().enumerate() {
            let feet = team.feet[foot..].iter().take_while(|f| f.robot == k).count();
            let b = &mut self.blocks[k];
            if !retry {
                b.vars = (3 * foot, 3 * feet);
                b.saturated = false;
                b.out = QpOutcome {
                    status: QpStatus::Solved,
                    solver: "by-robot",
                    ..QpOutcome::default()
                };
            }
            foot += feet;
            if (retry && !b.saturated) || feet == 0 {
                continue;
            }
            b.data.copy_from(inp, robot.offset, robot.nv, b.vars);
            b.out = qp::solve_with(&mut b.qp, &b.data.input(inp), settings, &mut b.f);
            f_c.rows_mut(b.vars.0, b.vars.1).copy_from(&b.f);
        }
    }

    /// Saturate `tau_0` at the limits ([`saturate`]) on the robots whose block failed (a robot
    /// without a stance foot has no block and is clamped when over); whether any entry
    /// changed. Only those robots' blocks are solved again.
    pub fn saturate_failed(
        &mut self,
        team: &Team,
        tau0: &mut DVector<f64>,
        actuated: &[usize],
        limits: &[f64],
    ) -> bool {
        let mut any = false;
        for (robot, b) in team.robots.iter().zip(&mut self.blocks) {
            if b.solved() && b.vars.1 > 0 {
                continue;
            }
            let own = own_joints(actuated, robot.offset, robot.nv);
            b.saturated = saturate(tau0, &actuated[own.clone()], &limits[own]);
            any |= b.saturated;
        }
        any
    }

    /// The fallback ([`fallback`]) on every block that still fails, on the `tau_0` it was
    /// last solved with; the tick's outcome and note.
    pub fn finish(
        &mut self,
        team: &Team,
        inp: &QpInput,
        settings: &QpSettings,
        f_c: &mut DVector<f64>,
    ) -> ByRobot {
        let mut outcome = QpOutcome {
            status: QpStatus::Solved,
            rows: 0,
            solver: "by-robot",
            ..QpOutcome::default()
        };
        let mut notes: Vec<String> = Vec::new();
        let mut saturated = false;
        for (robot, b) in team.robots.iter().zip(&mut self.blocks) {
            saturated |= b.saturated;
            if b.vars.1 == 0 {
                if b.saturated {
                    notes.push(format!(
                        "{}: no stance foot, tau_0 clamped to the torque limits",
                        robot.id
                    ));
                }
                continue;
            }
            let note = fallback(
                &mut b.qp,
                &b.data.input(inp),
                settings.max_iter,
                b.out.status,
                b.saturated,
                &mut b.f,
            );
            f_c.rows_mut(b.vars.0, b.vars.1).copy_from(&b.f);
            outcome.iterations += b.out.iterations;
            outcome.solve_us += b.out.solve_us;
            outcome.setup_us += b.out.setup_us;
            outcome.rows += b.out.rows;
            outcome.status = worse(outcome.status, b.out.status);
            if let Some(n) = note {
                notes.push(format!("{}: {n}", robot.id));
            }
        }
        let fallback = (!notes.is_empty()).then(|| {
            format!("solved robot by robot (no grasp couples them); {}", notes.join("; "))
        });
        ByRobot { outcome, fallback, saturated }
    }
}

/// Where a robot's joints `offset..offset + nv` sit in the team's `actuated` (team indices in
/// robot order, [`super::limits::torque_limits`]): a contiguous range.
fn own_joints(actuated: &[usize], offset: usize, nv: usize) -> Range<usize> {
    actuated.partition_point(|&j| j < offset)..actuated.partition_point(|&j| j < offset + nv)
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
        self.contacts.extend(
            inp.contacts
                .iter()
                .filter(|(row, _)| (v0..v0 + nvar).contains(row))
                .map(|(row, kind)| (row - v0, *kind)),
        );
        let own = own_joints(inp.actuated, offset, nv);
        self.actuated.clear();
        self.actuated.extend(inp.actuated[own.clone()].iter().map(|j| j - offset));
        self.limits.clear();
        self.limits.extend_from_slice(&inp.limits[own]);
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
        }
    }
}
