//! The dual active-set method (`qp::DualActiveSet`, tried first) against Clarabel, the
//! oracle, on the real team QPs of 2, 3, 4 and 8 robots (random moving states of the default
//! robot, with a swing foot or free hands too), cold and hot-started from the previous tick:
//! the KKT conditions written out here (rows held, multipliers of the active rows
//! non-negative, stationarity; at a degenerate vertex, where a hand's friction faces meet, the
//! multipliers are not unique and non-negative ones are looked for by Lawson and Hanson's
//! method), the objective, and the torques `Y F` and wrenches `rho F` the
//! forces make (F itself is not unique to Clarabel's tolerance: `Y` has rank about 60 % of
//! `F`'s size, so `F`'s components in its null space cost only `eps |F|^2`). Infeasible and
//! non-finite problems keep their statuses.

mod common;

use common::{moving_ticks, nonnegative_least_squares, robot_id, Case, Fixture};
use coordinator::pidc::MaterializedTick;
use coordinator::qp::{
    self, DualActiveSet, QpInput, QpPath, QpProblem, QpSettings, QpSolver, QpWorkspace,
};
use coordinator::{Pidc, PidcConfig};
use nalgebra::{DMatrix, DVector};
use protocol::{DynamicsTerms, QpStatus};
use rand::Rng;

/// The QP's data of a tick, from its report (`eta_real = lambda_real - lambda + eta`).
struct Data {
    r: MaterializedTick,
    eta: DVector<f64>,
}

impl Data {
    fn new(r: &MaterializedTick) -> Self {
        Data { eta: &r.lambda_real - &r.lambda + &r.eta, r: r.clone() }
    }
    fn input(&self) -> QpInput<'_> {
        let r = &self.r;
        QpInput {
            y: &r.y,
            rho: &r.rho,
            eta: &self.eta,
            contacts: &r.contacts,
            actuated: &r.actuated,
            limits: &r.limits,
            tau0: &r.tau0,
            regularisation: 1e-6,
        }
    }
}

/// Two consecutive ticks (1 ms apart) of a randomly perturbed, moving team.
fn ticks(
    fx: &mut Fixture,
    robots: usize,
    seed: u64,
    swing: bool,
    grasp: bool,
) -> Vec<Vec<DynamicsTerms>> {
    moving_ticks(fx, Case { robots, seed, swing, grasp, fully_actuated: false }, 2, 0.3)
}

/// Worst differences of one comparison.
#[derive(Default, Debug, Clone, Copy)]
struct Worst {
    rows: f64,
    objective: f64,
    torque: f64,
    wrench: f64,
    force: f64,
    multiplier: f64,
    stationarity: f64,
}

impl Worst {
    fn max(self, o: Worst) -> Worst {
        Worst {
            rows: self.rows.max(o.rows),
            objective: self.objective.max(o.objective),
            torque: self.torque.max(o.torque),
            wrench: self.wrench.max(o.wrench),
            force: self.force.max(o.force),
            multiplier: self.multiplier.max(o.multiplier),
            stationarity: self.stationarity.max(o.stationarity),
        }
    }
}

/// `F` against Clarabel's `fc` on `p`, the KKT conditions written out: rows
/// `(a_i F - b_i) / (1 + |b_i|)`; the multipliers of the rows within 1e-7 of binding by least
/// squares on `2 H F + A_W^T u = 0`, their most negative value and the residual (relative to
/// `|2 H F|`); objective `F^T H F` relative; `Y F`, `rho F` and `F` relative to Clarabel's.
fn check(p: &QpProblem, d: &Data, f: &DVector<f64>, fc: &DVector<f64>) -> Worst {
    // The objective as assembled (by blocks of its lower triangle) is Y^T Y + eps I.
    let h = d.r.y.transpose() * &d.r.y + DMatrix::identity(p.n(), p.n()) * 1e-6;
    assert!((&p.h - &h).amax() <= 1e-12 * (1.0 + h.amax()), "H");
    let slack = &p.b - &p.a * f;
    let rows = (0..p.rows()).map(|i| -slack[i] / (1.0 + p.b[i].abs())).fold(0.0f64, f64::max);
    let obj = |x: &DVector<f64>| x.dot(&(&p.h * x));
    let (o, oc) = (obj(f), obj(fc));
    let rel = |a: DVector<f64>, b: DVector<f64>| (&a - &b).amax() / (1.0 + b.amax());
    let active: Vec<usize> =
        (0..p.rows()).filter(|&i| slack[i].abs() <= 1e-7 * (1.0 + p.b[i].abs())).collect();
    let grad = 2.0 * (&p.h * f);
    let (mut multiplier, mut stationarity) = (0.0, grad.amax() / (1.0 + grad.amax()));
    if !active.is_empty() {
        let aw_t = DMatrix::from_fn(p.n(), active.len(), |c, k| p.a[(active[k], c)]);
        let mut u = aw_t.clone().svd(true, true).solve(&(-&grad), 1e-12).expect("least squares");
        if u.min() < 0.0 {
            // A degenerate vertex (a hand's friction faces meet where a component is zero:
            // more rows bind than the vertex needs) has many multipliers; least squares picks
            // one, which may be negative where non-negative ones exist. Look for those.
            u = nonnegative_least_squares(&aw_t, &(-&grad));
        }
        multiplier = (-u.min()).max(0.0) / (1.0 + u.amax());
        stationarity = (&grad + &aw_t * &u).amax() / (1.0 + grad.amax());
    }
    Worst {
        rows,
        objective: (o - oc).abs() / (1.0 + oc),
        torque: rel(&d.r.y * f, &d.r.y * fc),
        wrench: rel(&d.r.rho * f, &d.r.rho * fc),
        force: rel(f.clone(), fc.clone()),
        multiplier,
        stationarity,
    }
}

impl std::fmt::Display for Worst {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "rows {:.1e}, multipliers {:.1e}, stationarity {:.1e}, objective {:.1e}, Y F {:.1e}, rho F {:.1e}, F {:.1e}",
            self.rows, self.multiplier, self.stationarity, self.objective, self.torque, self.wrench, self.force
        )
    }
}

#[test]
fn active_set_matches_clarabel_cold_and_hot_on_teams_of_2_3_4_and_8_robots() {
    let mut fx = Fixture::new();
    let mut cases = Vec::new();
    for robots in [2usize, 3, 4, 8] {
        for seed in 0..3 {
            cases.push((robots, 1000 * robots as u64 + seed, false, true));
        }
    }
    for robots in [2, 3] {
        cases.push((robots, 77, true, true));
        cases.push((robots, 78, false, false));
    }
    let (mut cold, mut hot, mut hot_fast, mut skipped) = (Worst::default(), Worst::default(), 0, 0);
    let settings = QpSettings::default();
    for &(robots, seed, swing, grasp) in &cases {
        let mut c = Pidc::new(PidcConfig { qp_path: QpPath::Clarabel, ..PidcConfig::default() });
        for k in 0..robots {
            c.set_description(&fx.description(&robot_id(k)));
        }
        let mut solver = DualActiveSet::default();
        let mut ws = QpWorkspace::default();
        for (t, tick) in ticks(&mut fx, robots, seed, swing, grasp).iter().enumerate() {
            c.compute(tick).expect("tick");
            let d = Data::new(&c.materialized().expect("tick"));
            let mut fc = DVector::zeros(0);
            let oracle = qp::solve_with(
                &mut ws,
                &d.input(),
                &QpSettings::new(50, QpPath::Clarabel),
                &mut fc,
            );
            let p = ws.problem();
            let mut f = DVector::zeros(0);
            let out = solver.solve_problem(p, &settings, &mut f);
            if oracle.status != QpStatus::Solved {
                println!("{robots} robots seed {seed} tick {t}: Clarabel {:?}, the active-set method {:?}", oracle.status, out.status);
                assert_ne!(out.status, QpStatus::Solved);
                skipped += 1;
                continue;
            }
            assert_eq!(out.status, QpStatus::Solved, "{robots} robots seed {seed} tick {t}");
            let w = check(p, &d, &f, &fc);
            println!("{robots} robots seed {seed} swing {swing} grasp {grasp} tick {t}: {} iterations{}; {w}", out.iterations, if solver.hot { " (hot)" } else { "" });
            if t == 0 {
                cold = cold.max(w);
            } else {
                hot = hot.max(w);
                hot_fast += usize::from(solver.hot && out.iterations == 0);
            }
        }
    }
    println!("worst cold {cold}\nworst hot {hot}\n{hot_fast} of {} hot starts needed no iteration; {skipped} infeasible ticks", cases.len());
    assert!(
        skipped <= cases.len(),
        "too few feasible ticks: {skipped} of {} infeasible",
        2 * cases.len()
    );
    for w in [cold, hot] {
        assert!(w.rows <= 1e-9, "rows {:e}", w.rows);
        assert!(w.multiplier <= 1e-6 && w.stationarity <= 1e-6, "KKT {w:?}");
        assert!(w.objective <= 1e-7, "objective {:e}", w.objective);
        // Clarabel stops at relative residuals of 1e-8; measured worst 3.2e-5 (4 robots).
        assert!(w.torque <= 1e-4 && w.wrench <= 1e-4, "torque/wrench {w:?}");
        assert!(w.force <= 1e-2, "force {:e}", w.force);
    }
}

#[test]
fn infeasible_and_non_finite_problems_keep_their_statuses() {
    let mut fx = Fixture::new();
    let tick = ticks(&mut fx, 2, 5, false, true).swap_remove(0);
    let mut c = Pidc::new(PidcConfig { qp_path: QpPath::Clarabel, ..PidcConfig::default() });
    for k in 0..2 {
        c.set_description(&fx.description(&robot_id(k)));
    }
    c.compute(&tick).expect("tick");
    let mut d = Data::new(&c.materialized().expect("tick"));
    // Joints that can give almost no torque: the load cannot be carried.
    d.r.limits.iter_mut().for_each(|l| *l = 1e-3);
    d.r.tau0.fill(0.0);
    let (mut ws, mut f) = (QpWorkspace::default(), DVector::zeros(0));
    let oracle =
        qp::solve_with(&mut ws, &d.input(), &QpSettings::new(50, QpPath::Clarabel), &mut f);
    let ours = qp::solve_with(&mut ws, &d.input(), &QpSettings::default(), &mut f);
    let mut solver = DualActiveSet::default();
    let alone = solver.solve_problem(ws.problem(), &QpSettings::default(), &mut f);
    println!("infeasible: Clarabel {:?}, the default path {:?} by {}, the active-set method alone {:?} ({:?})", oracle.status, ours.status, ours.solver, alone.status, solver.solve(ws.problem(), &QpSettings::default()));
    assert_eq!(oracle.status, QpStatus::Infeasible);
    assert_eq!((ours.status, ours.solver), (oracle.status, "clarabel"));
    assert_ne!(alone.status, QpStatus::Solved);
    // NaN: a status, no panic, through the default path and the method alone.
    d.eta[0] = f64::NAN;
    let out = qp::solve_with(&mut ws, &d.input(), &QpSettings::default(), &mut f);
    assert_eq!(out.status, QpStatus::NumericalError);
    let mut bad = QpProblem::default();
    bad.assemble(&d.input());
    let alone = solver.solve_problem(&bad, &QpSettings::default(), &mut f);
    assert_ne!(alone.status, QpStatus::Solved);
    bad.p[(0, 0)] = f64::NAN;
    assert_ne!(solver.solve_problem(&bad, &QpSettings::default(), &mut f).status, QpStatus::Solved);
}

#[test]
fn the_controller_sends_the_same_torques_with_each_qp_path_over_moving_ticks() {
    // 4 and 8 robots, 20 ticks of a moving team: the active set (`QpPath::ActiveSet`), the
    // dense interior-point method first (`QpPath::DenseIpm`) and Clarabel alone
    // (`QpPath::Clarabel`). Prints each path's QP time (median and worst over the ticks after the first).
    let mut fx = Fixture::new();
    for robots in [4, 8] {
        moving_team(&mut fx, robots);
    }
}

fn moving_team(fx: &mut Fixture, robots: usize) {
    let mut rng = common::rng(11);
    let nv = fx.robot.model.nv;
    let qs: Vec<DVector<f64>> =
        (0..robots).map(|k| fx.perturbed_q(k, robots, 0.05, &mut rng)).collect();
    let vs: Vec<DVector<f64>> = (0..robots)
        .map(|_| DVector::from_fn(nv, |i, _| if i < 6 { 0.0 } else { rng.random_range(-0.2..0.2) }))
        .collect();
    let configs = [
        PidcConfig { qp_path: QpPath::ActiveSet, ..PidcConfig::default() },
        PidcConfig { qp_path: QpPath::DenseIpm, ..PidcConfig::default() },
        PidcConfig { qp_path: QpPath::Clarabel, ..PidcConfig::default() },
    ];
    let mut cs: Vec<Pidc> = configs.into_iter().map(Pidc::new).collect();
    for c in &mut cs {
        for k in 0..robots {
            c.set_description(&fx.description(&robot_id(k)));
        }
    }
    let (mut worst, mut by_active_set) = ([0.0f64; 2], 0);
    let mut times: [Vec<f64>; 3] = Default::default();
    let mut solvable_ticks = 0;
    for t in 0..20u64 {
        let tick: Vec<DynamicsTerms> = (0..robots)
            .map(|k| {
                fx.terms(
                    &robot_id(k),
                    &fx.robot.model.integrate(qs[k].as_slice(), vs[k].as_slice(), 2e-3 * t as f64),
                    &vs[k],
                    1 + t,
                )
            })
            .collect();
        let taus: Vec<(DVector<f64>, &'static str)> = cs
            .iter_mut()
            .map(|c| c.compute(&tick).map(|r| (r.tau.clone(), r.qp.solver)).expect("tick"))
            .collect();
        for (k, c) in cs.iter().enumerate() {
            if t > 0 {
                times[k].push(c.last().expect("tick").timing.qp_us);
            }
        }
        if t == 0 {
            println!(
                "tick 0: {:?}",
                cs.iter()
                    .map(|c| c.last().map(|r| (r.qp.status, r.qp.solver, r.fallback.clone())))
                    .collect::<Vec<_>>()
            );
        }
        let solvable = cs[2].last().is_some_and(|r| r.qp.status == QpStatus::Solved);
        solvable_ticks += usize::from(solvable);
        by_active_set += usize::from(solvable && taus[0].1 == "active-set");
        for k in 0..2 {
            let d = (&taus[0].0 - &taus[k + 1].0).amax() / (1.0 + taus[k + 1].0.amax());
            worst[k] = worst[k].max(d);
        }
    }
    let stat = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[v.len() / 2], v[v.len() - 1])
    };
    let s: Vec<(f64, f64)> = times.iter_mut().map(stat).collect();
    println!("{robots} robots: torques, active set vs dense IPM {:.1e}, vs Clarabel {:.1e} (relative); {by_active_set} of the {solvable_ticks} ticks Clarabel solves by the active set", worst[0], worst[1]);
    println!("{robots} robots: QP time median/worst us: active set {:.0}/{:.0}, dense IPM {:.0}/{:.0}, Clarabel {:.0}/{:.0}", s[0].0, s[0].1, s[1].0, s[1].1, s[2].0, s[2].1);
    assert!(solvable_ticks >= 10);
    assert_eq!(by_active_set, solvable_ticks);
    // The solvers' tolerances (interior point 1e-7, Clarabel 1e-8, relative residuals) on
    // torques: measured worst 1.2e-4 against the dense IPM and 1.5e-5 against Clarabel (8 robots).
    assert!(worst[0] <= 1e-3 && worst[1] <= 1e-4, "{worst:?}");
}
