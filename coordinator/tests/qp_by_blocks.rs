//! The QP's hot start by the robots' blocks (`qp::BlockHotStart`, on by default) against the
//! team-sized QP in `F` (the oracle, `PidcConfig::qp_path = QpPath::ActiveSet`), on random moving
//! team states of 2, 3, 4 and 8 robots of the real default robot, with a swing foot, with
//! the hands free and fully actuated:
//!
//! * the identity the block form rests on, `J_c^T rho = -Y` (eq. bmatrix), and that `rho` and
//!   `Y` have the same null space;
//! * the block answer, also after the last tick's active rows were mended
//!   (`qp::BLOCK_REPAIRS`), is the optimum of the paper's QP without `eps |F|^2`, the KKT
//!   conditions written out again in `F`: `F = Y^+ dtau` makes the block answer's wrenches
//!   (`rho F = z`), holds every row of the assembled `A F <= b`, binds the rows of the last
//!   active set, and `2 Y^T Y F + A_W^T u = 0` has non-negative multipliers `u` (Lawson and
//!   Hanson's non-negative least squares, written here);
//! * its torques against the team-sized QP's (with `eps |F|^2`, as the paper's), and the
//!   contact wrenches `lambda`, to the regularisation's effect;
//! * a tick whose last active set is no longer optimal, and a change of shape, go to the
//!   team-sized QP, whose answer the controller then sends.

mod common;

use common::{moving_ticks, nonnegative_least_squares, robot_id, Case, Fixture};
use coordinator::pidc::MaterializedTick;
use coordinator::qp::{self, QpInput, QpPath, QpProblem};
use coordinator::{Pidc, PidcConfig};
use nalgebra::{DMatrix, DVector};

const CASES: [Case; 7] = [
    Case { robots: 2, seed: 21, swing: false, grasp: true, fully_actuated: false },
    Case { robots: 3, seed: 2, swing: false, grasp: true, fully_actuated: false },
    Case { robots: 4, seed: 3, swing: true, grasp: true, fully_actuated: false },
    Case { robots: 8, seed: 4, swing: false, grasp: true, fully_actuated: false },
    Case { robots: 2, seed: 5, swing: true, grasp: true, fully_actuated: false },
    Case { robots: 3, seed: 6, swing: false, grasp: false, fully_actuated: false },
    Case { robots: 2, seed: 27, swing: false, grasp: true, fully_actuated: true },
];

fn controller(fx: &Fixture, case: Case, by_blocks: bool) -> Pidc {
    let mut c = Pidc::new(PidcConfig {
        qp_path: if by_blocks { QpPath::ByBlocks } else { QpPath::ActiveSet },
        fully_actuated: case.fully_actuated,
        ..PidcConfig::default()
    });
    for k in 0..case.robots {
        c.set_description(&fx.description(&robot_id(k)));
    }
    c
}

fn rel(a: &DVector<f64>, b: &DVector<f64>) -> f64 {
    (a - b).amax() / b.amax().max(f64::MIN_POSITIVE)
}

/// The assembled QP in `F` of a report whose `Y` and `rho` are formed, without `eps |F|^2`.
fn problem(r: &MaterializedTick) -> QpProblem {
    let eta_real = &r.lambda_real - &r.lambda + &r.eta;
    let inp = QpInput {
        y: &r.y,
        rho: &r.rho,
        eta: &eta_real,
        contacts: &r.contacts,
        actuated: &r.actuated,
        limits: &r.limits,
        tau0: &r.tau0,
        regularisation: 0.0,
    };
    let mut p = QpProblem::default();
    p.assemble(&inp);
    p
}

/// The KKT conditions of `p` at `f`, written out: the worst row `(a_i F - b_i) / (1 + |b_i|)`,
/// and the stationarity residual of `2 H F + A_W^T u = 0` over the rows within `1e-7` of
/// binding with `u >= 0`, relative to `|2 H F|` (and the largest `|2 H F|`).
fn kkt(p: &QpProblem, f: &DVector<f64>) -> (f64, f64, f64) {
    let s = &p.a * f - &p.b;
    let rows = (0..p.rows()).map(|i| s[i] / (1.0 + p.b[i].abs())).fold(f64::NEG_INFINITY, f64::max);
    let grad = &p.p * f;
    let w: Vec<usize> =
        (0..p.rows()).filter(|&i| s[i].abs() <= 1e-7 * (1.0 + p.b[i].abs())).collect();
    let a_w = DMatrix::from_fn(p.n(), w.len(), |c, k| p.a[(w[k], c)]);
    let u = nonnegative_least_squares(&a_w, &(-&grad));
    let residual = (&grad + &a_w * &u).amax() / grad.amax().max(1.0);
    (rows, residual, grad.amax())
}

#[test]
fn the_blocks_answer_is_the_qps_optimum_and_the_team_sized_qps_torque() {
    let mut fx = Fixture::new();
    let (mut worst_kkt, mut worst_tau, mut worst_lambda, mut worst_id): (f64, f64, f64, f64) =
        (0.0, 0.0, 0.0, 0.0);
    let (mut answered, mut repaired) = (0, 0);
    let mut total = 0;
    for case in CASES {
        let seq = moving_ticks(&mut fx, case, 6, 0.2);
        let (mut blocks, mut dense) = (controller(&fx, case, true), controller(&fx, case, false));
        for (t, tick) in seq.iter().enumerate() {
            blocks.compute(tick).expect("block tick");
            let d = dense.compute(tick).expect("dense tick").clone();
            let b = blocks.materialized().expect("block tick").clone();
            assert!(
                matches!(d.qp.status, qp::QpStatus::Solved | qp::QpStatus::AlmostSolved),
                "{case:?} tick {t}: the oracle's QP {:?}",
                d.qp.status
            );
            if let Some(why) = b.blocks_declined {
                println!("{case:?} tick {t}: {why}");
            }
            // J_c^T rho = -Y, on every tick (the block form's premise).
            let id = (b.j_c.transpose() * &b.rho + &b.y).amax() / b.y.amax();
            worst_id = worst_id.max(id);
            total += 1;
            if b.qp.solver != qp::by_blocks::SOLVER {
                continue;
            }
            answered += 1;
            repaired += usize::from(b.qp.iterations > 0);
            // F = Y^+ dtau makes the block answer: the torque and the wrenches.
            let dtau = &b.tau - &b.tau0;
            assert!(rel(&(&b.y * &b.f_c), &dtau) < 1e-9, "{case:?} tick {t}: Y F != dtau");
            assert!(
                rel(&(&b.rho * &b.f_c + &b.eta), &b.lambda) < 1e-9,
                "{case:?} tick {t}: rho F + eta != lambda"
            );
            let p = problem(&b);
            let (rows, stationarity, _) = kkt(&p, &b.f_c);
            worst_kkt = worst_kkt.max(rows.max(stationarity));
            assert!(rows < 1e-8, "{case:?} tick {t}: a row misses by {rows:.2e}");
            assert!(stationarity < 1e-7, "{case:?} tick {t}: stationarity {stationarity:.2e}");
            let (dt, dl) = (rel(&b.tau, &d.tau), rel(&b.lambda_real, &d.lambda_real));
            worst_tau = worst_tau.max(dt);
            worst_lambda = worst_lambda.max(dl);
        }
    }
    println!("{answered} of {total} ticks answered by the blocks ({repaired} after mending the last active set); J_c^T rho + Y {worst_id:.1e}; KKT {worst_kkt:.1e}; against the team-sized QP (eps = 1e-6): torque {worst_tau:.1e}, wrenches {worst_lambda:.1e} relative");
    assert!(worst_id < 1e-12, "J_c^T rho = -Y misses by {worst_id:.2e}");
    // Every tick but each case's first (no active set yet) is answered by the blocks, some
    // after mending the last tick's active rows (each answer checked above all the same).
    assert!(answered >= total - CASES.len(), "only {answered} of {total} ticks by the blocks");
    assert!(repaired > 0, "no tick needed its active set mended: the repair path is not exercised");
    assert!(
        worst_tau < 1e-4 && worst_lambda < 1e-4,
        "torque {worst_tau:.2e}, wrenches {worst_lambda:.2e}"
    );
}

#[test]
fn a_stale_active_set_or_a_new_shape_goes_to_the_team_sized_qp() {
    let mut fx = Fixture::new();
    let case = Case { robots: 3, seed: 11, swing: false, grasp: true, fully_actuated: false };
    let (mut blocks, mut dense) = (controller(&fx, case, true), controller(&fx, case, false));
    // A fast team: its active rows change from tick to tick.
    let seq = moving_ticks(&mut fx, case, 12, 3.0);
    let mut declined = 0;
    for tick in &seq {
        let b = blocks.compute(tick).expect("tick").clone();
        let d = dense.compute(tick).expect("tick").clone();
        declined += usize::from(b.qp.solver != qp::by_blocks::SOLVER);
        assert!(
            rel(&b.tau, &d.tau) < 1e-4,
            "torque {:.2e} by {}",
            rel(&b.tau, &d.tau),
            b.qp.solver
        );
    }
    assert!(declined > 1, "the blocks answered every tick of a fast team ({declined} declined)");
    // A foot lifts: another shape of QP, which the blocks must not answer from the old rows.
    let swing = Case { swing: true, ..case };
    let lifted = moving_ticks(&mut fx, swing, 2, 0.2);
    let b = blocks.compute(&lifted[0]).expect("tick").clone();
    let d = dense.compute(&lifted[0]).expect("tick").clone();
    assert_eq!(
        b.blocks_declined,
        Some(qp::Decline::NoHotStart),
        "a new shape was answered from the old active set"
    );
    assert!(rel(&b.tau, &d.tau) < 1e-4);
}

/// A torque limit that binds: robot 0's most loaded joint limited to 97 % of the torque the
/// QP gave it, so the team must shift internal forces to keep it. The block answers keep the
/// limit as an active row (a torque row binds in the assembled problem) and are the QP's
/// optimum by the same written-out KKT conditions.
#[test]
fn a_binding_torque_limit_is_an_active_row_of_the_block_answer() {
    let mut fx = Fixture::new();
    let case = Case { robots: 3, seed: 2, swing: false, grasp: true, fully_actuated: false };
    let seq = moving_ticks(&mut fx, case, 6, 0.2);
    let mut probe = controller(&fx, case, false);
    let r = probe.compute(&seq[0]).expect("tick").clone();
    let joints = fx.description(&robot_id(0)).torque_limits.len();
    let p = (0..joints)
        .max_by(|&a, &b| r.tau[r.actuated[a]].abs().total_cmp(&r.tau[r.actuated[b]].abs()))
        .expect("joints");
    let mut d0 = fx.description(&robot_id(0));
    d0.torque_limits[p] = 0.97 * r.tau[r.actuated[p]].abs();
    let (mut blocks, mut dense) = (controller(&fx, case, true), controller(&fx, case, false));
    blocks.set_description(&d0);
    dense.set_description(&d0);
    let (mut binding, mut answered) = (0, 0);
    for (t, tick) in seq.iter().enumerate() {
        blocks.compute(tick).expect("tick");
        let d = dense.compute(tick).expect("tick").clone();
        let b = blocks.materialized().expect("tick").clone();
        assert!(
            matches!(d.qp.status, qp::QpStatus::Solved),
            "tick {t}: the oracle's QP {:?}",
            d.qp.status
        );
        assert!(
            b.tau[b.actuated[p]].abs() <= d0.torque_limits[p] * (1.0 + 1e-9),
            "tick {t}: the limit holds"
        );
        if b.qp.solver != qp::by_blocks::SOLVER {
            continue;
        }
        answered += 1;
        let prob = problem(&b);
        let (rows, stationarity, _) = kkt(&prob, &b.f_c);
        assert!(
            rows < 1e-8 && stationarity < 1e-7,
            "tick {t}: rows {rows:.2e}, stationarity {stationarity:.2e}"
        );
        let slack = &prob.a * &b.f_c - &prob.b;
        let torque_rows = prob.pairs_from..prob.rows();
        binding += usize::from(
            torque_rows.clone().any(|i| slack[i].abs() <= 1e-7 * (1.0 + prob.b[i].abs())),
        );
        assert!(rel(&b.tau, &d.tau) < 1e-4, "tick {t}: torque {:.2e}", rel(&b.tau, &d.tau));
    }
    println!("limit {:.2} N m on joint {p}: {answered} ticks by the blocks, {binding} with a torque row binding", d0.torque_limits[p]);
    assert!(
        answered >= seq.len() - 1 && binding == answered,
        "{answered} answered, {binding} binding"
    );
}
