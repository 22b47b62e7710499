//! The projections by the team's blocks (`building_blocks::block_projection`, the default) against the
//! dense SVDs of the team's matrices (`PidcConfig::projections = ProjectionPath::Dense`, the oracle): the same
//! `P`, `J_c^+`, `M_c^{-1}`, `[P S]^+`, `B` (the block path's operators applied to the
//! identity), the same motion torque `tau_M` (the operational-space inertia by the operator
//! and Cholesky against the dense matrices and an SVD), QP data (`tau_0`, `Y`, `rho`, `eta`),
//! contact wrenches of eq. constraint_force for a given torque, and torque map
//! `tau = tau_0 + Y F_c`, to 1e-9 relative; and the torques sent (each path solving its own
//! QP to its tolerance) to 1e-6, on random moving team states of 2, 3, 4 and 8 robots of the
//! real default robot, with a swing foot, with the hands free, and fully actuated.

mod common;

use common::{robot_id, Case, Fixture};
use coordinator::building_blocks::projection::{ProjectionPath, WrenchScratch};
use coordinator::pidc::MaterializedTick;
use coordinator::{Pidc, PidcConfig};
use nalgebra::{DMatrix, DVector};
use protocol::DynamicsTerms;
use rand::Rng;

/// Agreement asked of every compared quantity: `|a - b|_max <= TOL |b|_max`.
const TOL: f64 = 1e-9;

fn rel(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0.0f64, |m, x| m.max(x.abs())).max(f64::MIN_POSITIVE);
    a.iter().zip(b).fold(0.0f64, |m, (x, y)| m.max((x - y).abs())) / scale
}

fn controller(fx: &Fixture, case: Case, dense: bool) -> Pidc {
    let mut c = Pidc::new(PidcConfig {
        projections: if dense { ProjectionPath::Dense } else { ProjectionPath::ByBlocks },
        fully_actuated: case.fully_actuated,
        ..PidcConfig::default()
    });
    for k in 0..case.robots {
        c.set_description(&fx.description(&robot_id(k)));
    }
    c
}

/// A random configuration of the team at rest (tick 1), then moving with velocities in the
/// constraints' null space (tick 2).
fn team_states(fx: &mut Fixture, case: Case) -> [Vec<DynamicsTerms>; 2] {
    let mut rng = common::rng(case.seed);
    let nv = fx.robot.model.nv;
    let qs: Vec<DVector<f64>> =
        (0..case.robots).map(|k| fx.perturbed_q(k, case.robots, 0.1, &mut rng)).collect();
    let still: Vec<_> = (0..case.robots)
        .map(|k| fx.terms_with(&robot_id(k), &qs[k], &DVector::zeros(nv), 1, &case.contacts(fx, k)))
        .collect();
    let mut c = controller(fx, case, true);
    c.compute(&still).expect("tick");
    let p = c.materialized().expect("tick").proj.p.clone();
    let v = &p * DVector::from_fn(case.robots * nv, |_, _| rng.random_range(-0.5..0.5));
    let moving = (0..case.robots)
        .map(|k| {
            fx.terms_with(
                &robot_id(k),
                &qs[k],
                &v.rows(k * nv, nv).into_owned(),
                2,
                &case.contacts(fx, k),
            )
        })
        .collect();
    [still, moving]
}

/// The largest relative difference of the block path's tick from the dense path's over the
/// projections, the QP's data and the torque map `tau = tau_0 + Y F_c` (at the dense path's
/// `F_c`), with its name.
fn compare(blocks: &MaterializedTick, dense: &MaterializedTick) -> (f64, &'static str) {
    let (a, b) = (&blocks.proj, &dense.proj);
    assert!(a.by_blocks && !b.by_blocks, "the block path declined");
    assert_eq!(a.jc_rank, b.jc_rank, "rank of J_c");
    let m = |x: &DMatrix<f64>| x.as_slice().to_vec();
    let v = |x: &DVector<f64>| x.as_slice().to_vec();
    let torque = |r: &MaterializedTick| &r.tau0 + &r.y * &dense.f_c;
    // eq. constraint_force for one torque (the sent one of the dense path), by each path.
    let wrench = |r: &MaterializedTick| {
        let u = dense.tau.component_mul(&r.team.s_diag) + &r.load;
        let mut out = DVector::zeros(0);
        r.proj.contact_wrench(&r.team, &u, &mut out, &mut WrenchScratch::default());
        out
    };
    let pairs: [(&'static str, Vec<f64>, Vec<f64>); 16] = [
        ("P", m(&a.p), m(&b.p)),
        ("J_c^+", m(&a.jc_pinv), m(&b.jc_pinv)),
        ("Pdot v", v(&a.pdot_v), v(&b.pdot_v)),
        ("M_c", m(&a.mc), m(&b.mc)),
        ("M_c^-1", m(&a.mc_inv), m(&b.mc_inv)),
        ("M_c^-1 P", m(&a.mcinv_p), m(&b.mcinv_p)),
        ("Mbar", m(&a.mbar), m(&b.mbar)),
        ("[P S]^+", m(&a.ps_pinv), m(&b.ps_pinv)),
        ("B", m(&a.b), m(&b.b)),
        ("tau_M", v(&blocks.tau_m), v(&dense.tau_m)),
        ("tau_0", v(&blocks.tau0), v(&dense.tau0)),
        ("Y", m(&blocks.y), m(&dense.y)),
        ("rho", m(&blocks.rho), m(&dense.rho)),
        ("eta", v(&blocks.eta), v(&dense.eta)),
        ("lambda(tau)", v(&wrench(blocks)), v(&wrench(dense))),
        ("tau(F_c)", v(&torque(blocks)), v(&torque(dense))),
    ];
    if std::env::var_os("STRUCTURED_VERBOSE").is_some() {
        for (name, x, y) in &pairs {
            println!("    {name:10} {:.2e}", rel(x, y));
        }
    }
    pairs.iter().map(|(name, x, y)| (rel(x, y), *name)).fold((0.0, "none"), |w, e| {
        if e.0 > w.0 {
            e
        } else {
            w
        }
    })
}

/// Both paths on both ticks of `case`: the worst relative difference of [`compare`], and of
/// the torques sent, each path with its own QP solve (interior point to
/// [`coordinator::qp::DENSE_TOL`]: the solves agree to their tolerance, not to round-off).
fn agree(fx: &mut Fixture, case: Case) -> (f64, f64) {
    let ticks = team_states(fx, case);
    let (mut blocks, mut dense) = (controller(fx, case, false), controller(fx, case, true));
    let mut w = (0.0f64, 0.0f64);
    for (t, tick) in ticks.iter().enumerate() {
        w = worst(
            w,
            agree_on_tick(
                &mut blocks,
                &mut dense,
                tick,
                &format!("{} robots (seed {}) tick {}", case.robots, case.seed, t + 1),
            ),
        );
    }
    w
}

/// One tick on both paths: the block path forms no team-sized matrix, both QPs end the same
/// way, [`compare`] is within [`TOL`] and the torques sent within the QP's tolerance. Returns
/// both differences; `what` names the tick in the messages.
fn agree_on_tick(
    blocks: &mut Pidc,
    dense: &mut Pidc,
    tick: &[DynamicsTerms],
    what: &str,
) -> (f64, f64) {
    let on_tick = blocks.compute(tick).expect("block tick");
    // The block path forms no team-sized matrix on the tick (only its factors), nor J_c when
    // the QP's blocks answered.
    assert!(
        on_tick.proj.p.is_empty() && on_tick.proj.mc_inv.is_empty() && on_tick.proj.mbar.is_empty(),
        "{what}: an n x n matrix on the block path's tick"
    );
    let solver = on_tick.qp.solver;
    assert!(
        solver != coordinator::qp::by_blocks::SOLVER || !blocks.contact_matrices().j_c_formed,
        "{what}: J_c formed on a tick the blocks answered"
    );
    let b = blocks.materialized().expect("block tick").clone();
    dense.compute(tick).expect("dense tick");
    let d = &dense.materialized().expect("dense tick");
    assert_eq!(b.qp.status, d.qp.status, "{what}");
    let (err, quantity) = compare(&b, d);
    let sent = rel(b.tau.as_slice(), d.tau.as_slice());
    println!("{what}: worst {quantity} {err:.2e}; torques sent {sent:.2e}");
    assert!(err <= TOL, "{what}: {quantity} differs by {err:e} relative");
    assert!(
        sent <= 10.0 * coordinator::qp::DENSE_TOL,
        "{what}: the torques sent differ by {sent:e} relative"
    );
    (err, sent)
}

fn worst(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    (a.0.max(b.0), a.1.max(b.1))
}

fn case(robots: usize, seed: u64) -> Case {
    Case { robots, seed, swing: false, grasp: true, fully_actuated: false }
}

#[test]
fn blocks_match_the_dense_oracle_on_random_teams_of_2_3_4_and_8_robots() {
    let mut fx = Fixture::new();
    let mut w = (0.0, 0.0);
    for robots in [2, 3, 4, 8] {
        for seed in 0..3 {
            w = worst(w, agree(&mut fx, case(robots, 100 * robots as u64 + seed)));
        }
    }
    println!("worst relative difference over all teams: {:.2e}; torques sent {:.2e}", w.0, w.1);
}

#[test]
fn blocks_match_the_dense_oracle_with_a_swing_foot_free_hands_or_full_actuation() {
    let mut fx = Fixture::new();
    let mut w = (0.0, 0.0);
    for robots in [2, 3] {
        w = worst(w, agree(&mut fx, Case { swing: true, ..case(robots, 7) }));
        w = worst(w, agree(&mut fx, Case { grasp: false, ..case(robots, 8) }));
        w = worst(w, agree(&mut fx, Case { fully_actuated: true, ..case(robots, 9) }));
    }
    println!("worst relative difference: {:.2e}; torques sent {:.2e}", w.0, w.1);
}

/// One pair of controllers (blocks and dense) through ticks whose layout changes: all feet
/// down and the hands in grasp, a foot lifted, the hands let go, then all down again. The
/// block path reuses its buffers from tick to tick (some shaped, not cleared, because every
/// entry is written): what a tick of another layout left in them must not show, so every
/// tick agrees with the dense path as on a fresh controller.
#[test]
fn blocks_match_the_dense_oracle_through_changes_of_contacts() {
    let mut fx = Fixture::new();
    let base = case(3, 31);
    let layouts = [
        base,
        Case { swing: true, ..base },
        Case { grasp: false, ..base },
        Case { swing: true, grasp: false, ..base },
        base,
    ];
    let (mut blocks, mut dense) = (controller(&fx, base, false), controller(&fx, base, true));
    let mut tick = 0;
    for (l, layout) in layouts.into_iter().enumerate() {
        for mut terms in team_states(&mut fx, Case { seed: base.seed + l as u64, ..layout }) {
            tick += 1;
            for t in &mut terms {
                t.header.tick = tick;
            }
            agree_on_tick(
                &mut blocks,
                &mut dense,
                &terms,
                &format!("layout {l} (swing {}, grasp {}) tick {tick}", layout.swing, layout.grasp),
            );
        }
    }
}
