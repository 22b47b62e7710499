//! The paper's controller on team states built from the real default robot.

mod common;

use common::{robot_id, Fixture};
use coordinator::linalg::pinv;
use coordinator::qp::contact_rows;
use coordinator::{ControllerError, Pidc, PidcConfig, TeamController};
use nalgebra::{DMatrix, DVector, Vector3};
use protocol::{DynamicsTerms, QpStatus};
use robot_agent::terms::ActiveContacts;

/// The protocol's `(w, x, y, z)` of a rotation.
fn quat_wxyz(r: &nalgebra::Rotation3<f64>) -> [f64; 4] {
    protocol::conventions::quat_to_wxyz(&nalgebra::UnitQuaternion::from_rotation_matrix(r))
}

fn controller(descs: &[protocol::RobotDescription], cfg: PidcConfig) -> Pidc {
    let mut c = Pidc::new(cfg);
    for d in descs {
        c.set_description(d);
    }
    c
}

fn max_abs(m: &DMatrix<f64>) -> f64 {
    m.iter().fold(0.0, |a, x| a.max(x.abs()))
}

type RandomTeam = (Vec<DynamicsTerms>, Vec<DVector<f64>>, Vec<DVector<f64>>, Pidc);

/// A 2-robot team at a random perturbed configuration with a velocity that keeps the
/// contacts (v in the null space of J_c), and the controller that captured the grasp.
fn random_team(fx: &mut Fixture, seed: u64, amp: f64, vel: f64) -> RandomTeam {
    let mut rng = common::rng(seed);
    let nv = fx.robot.model.nv;
    let qs: Vec<DVector<f64>> = (0..2).map(|k| fx.perturbed_q(k, 2, amp, &mut rng)).collect();
    let descs: Vec<_> = (0..2).map(|k| fx.description(&robot_id(k))).collect();
    let terms0: Vec<_> =
        (0..2).map(|k| fx.terms(&robot_id(k), &qs[k], &DVector::zeros(nv), 1)).collect();
    let mut c = controller(&descs, PidcConfig::default());
    c.compute(&terms0).expect("tick");
    let p = c.materialized().expect("tick").proj.p.clone();
    use rand::Rng;
    let v_rand = DVector::from_fn(2 * nv, |_, _| rng.random_range(-vel..vel));
    let v = &p * v_rand;
    let vs: Vec<DVector<f64>> = (0..2).map(|k| v.rows(k * nv, nv).into_owned()).collect();
    let terms: Vec<_> = (0..2).map(|k| fx.terms(&robot_id(k), &qs[k], &vs[k], 2)).collect();
    (terms, qs, vs, c)
}

#[test]
fn projection_identities_on_random_states() {
    let mut fx = Fixture::new();
    let mut worst = [0.0f64; 5];
    for seed in 0..5 {
        let (terms, _, _, mut c) = random_team(&mut fx, seed, 0.15, 0.5);
        c.compute(&terms).expect("tick");
        let r = c.materialized().expect("tick");
        let p = &r.proj.p;
        let n = p.nrows();
        worst[0] = worst[0].max(max_abs(&(p - p.transpose())));
        worst[1] = worst[1].max(max_abs(&(p * p - p)));
        worst[2] = worst[2].max(max_abs(&(p * r.j_c.transpose())));
        worst[3] = worst[3].max(max_abs(&(&r.proj.mc * &r.proj.mc_inv - DMatrix::identity(n, n))));
        // P v = v for v in N(J_c): the constraint-consistent velocity.
        worst[4] = worst[4].max((p * &r.team.velocity - &r.team.velocity).amax());
        // rank J_c = 3 * 8 feet + 6 (B - 1) for B = 2 hands.
        assert_eq!(r.proj.jc_rank, 24 + 6, "rank of J_c");
        // J_c,ee constrains only relative hand motion: G^T-directions are free.
        let g = r.grasp.as_ref().expect("grasp");
        assert!(max_abs(&(&g.n * g.g.transpose())) < 1e-10);
    }
    println!("worst |P-P^T| {:.2e}, |PP-P| {:.2e}, |P J_c^T| {:.2e}, |M_c M_c^-1 - I| {:.2e}, |Pv - v| {:.2e}", worst[0], worst[1], worst[2], worst[3], worst[4]);
    assert!(
        worst[0] < 1e-12
            && worst[1] < 1e-10
            && worst[2] < 1e-9
            && worst[3] < 1e-9
            && worst[4] < 1e-9,
        "{worst:?}"
    );
}

#[test]
fn pdot_v_against_finite_difference_in_time() {
    let mut fx = Fixture::new();
    let mut worst = 0.0f64;
    for seed in 10..13 {
        let (terms, qs, vs, mut c) = random_team(&mut fx, seed, 0.15, 0.5);
        let r = c.compute(&terms).expect("tick");
        let analytic = r.proj.pdot_v.clone();
        let v = r.team.velocity.clone();
        let nv = fx.robot.model.nv;
        let dt = 1e-6;
        let mut p_at = |sign: f64, c: &mut Pidc| {
            let t: Vec<_> = (0..2)
                .map(|k| {
                    let q = fx.robot.model.integrate(qs[k].as_slice(), vs[k].as_slice(), sign * dt);
                    fx.terms(&robot_id(k), &q, &DVector::zeros(nv), 3)
                })
                .collect();
            c.compute(&t).expect("tick");
            c.materialized().expect("tick").proj.p.clone()
        };
        let pp = p_at(1.0, &mut c);
        let pm = p_at(-1.0, &mut c);
        let fd = (pp - pm) / (2.0 * dt) * &v;
        let err = (&fd - &analytic).amax() / analytic.amax().max(1e-3);
        println!("seed {seed}: |Pdot v| {:.3e}, relative error vs FD {:.2e}", analytic.amax(), err);
        worst = worst.max(err);
    }
    assert!(worst < 1e-4, "worst relative error {worst:.2e}");
}

/// Independent constrained forward dynamics: the KKT system with min-norm lambda.
fn kkt(
    m: &DMatrix<f64>,
    j_c: &DMatrix<f64>,
    rhs: &DVector<f64>,
    jdv: &DVector<f64>,
) -> (DVector<f64>, DVector<f64>) {
    let (n, k) = (m.nrows(), j_c.nrows());
    let mut a = DMatrix::zeros(n + k, n + k);
    a.view_mut((0, 0), (n, n)).copy_from(m);
    a.view_mut((0, n), (n, k)).copy_from(&(-j_c.transpose()));
    a.view_mut((n, 0), (k, n)).copy_from(j_c);
    let mut b = DVector::zeros(n + k);
    b.rows_mut(0, n).copy_from(rhs);
    b.rows_mut(n, k).copy_from(&(-jdv));
    let (ai, _) = pinv(&a, 1e-11).expect("svd");
    let x = ai * b;
    (x.rows(0, n).into_owned(), x.rows(n, k).into_owned())
}

#[test]
fn lambda_relation_matches_constrained_forward_dynamics() {
    let mut fx = Fixture::new();
    let mut worst = (0.0f64, 0.0f64);
    for seed in 20..24 {
        let (terms, _, _, mut c) = random_team(&mut fx, seed, 0.1, 0.3);
        c.compute(&terms).expect("tick");
        let r = c.materialized().expect("tick");
        let s_tau = r.tau.component_mul(&r.team.s_diag);
        let rhs = &s_tau - &r.team.bias + &r.load;
        let (qdd, lambda) = kkt(&r.team.mass, &r.j_c, &rhs, &r.jdv_c);
        // eq. aghili_25
        let p = &r.proj.p;
        let qdd_25 =
            &r.proj.mc_inv * (p * &s_tau - p * &r.team.bias + &r.proj.pdot_v + p * &r.load);
        let e_q = (&qdd - &qdd_25).amax() / qdd.amax().max(1.0);
        let e_l = (&lambda - &r.lambda).amax() / lambda.amax().max(1.0);
        println!(
            "seed {seed}: |lambda| {:.1}, rel err lambda {:.2e}, qdd {:.2e} (QP {:?})",
            lambda.amax(),
            e_l,
            e_q,
            r.qp.status
        );
        worst = (worst.0.max(e_l), worst.1.max(e_q));
    }
    assert!(worst.0 < 1e-6 && worst.1 < 1e-6, "{worst:?}");
}

#[test]
fn fully_actuated_reduces_to_lin2018() {
    let mut fx = Fixture::new();
    let (terms, _, _, _) = random_team(&mut fx, 30, 0.02, 0.05);
    let descs: Vec<_> = (0..2).map(|k| fx.description(&robot_id(k))).collect();
    let cfg = PidcConfig { fully_actuated: true, ..PidcConfig::default() };
    let mut c = controller(&descs, cfg);
    c.compute(&terms).expect("tick");
    let r = c.materialized().expect("tick");
    let n = r.team.n;
    let id = DMatrix::<f64>::identity(n, n);
    let p = &r.proj.p;
    assert!(max_abs(&(&r.proj.b - &id)) < 1e-12, "B = I");
    // [P S]^+ P = P^+ P = P.
    assert!(max_abs(&(&r.proj.ps_pinv * p - p)) < 1e-9);
    // [Lin2018]: tau = P tau_M + (I - P) tau_C with (I - P) tau_C = J_c^T F_c.
    let tau_lin = p * &r.tau_m + &r.j_c.transpose() * &r.f_c;
    let e_tau = (&r.tau - &tau_lin).amax();
    // [Lin2018]'s contact wrench: lambda = (J_c^T)^+ [(I-P)(Mbar (P tau - P h + Pdot v) + h - tau)] with the load.
    let ip = &id - p;
    let lam_lin = &r.proj.jct_pinv
        * (&ip
            * (&r.proj.mbar * (p * &r.tau - p * &r.team.bias + &r.proj.pdot_v + p * &r.load)
                + &r.team.bias
                - &r.tau
                - &r.load));
    let e_lam = (&lam_lin - &r.lambda).amax();
    // rho = -(J_c^T)^+ J_c^T when S = B = I.
    let e_rho = max_abs(&(&r.rho + &r.proj.jct_pinv * r.j_c.transpose()));
    println!("S = I: |tau - tau_Lin| {e_tau:.2e}, |lambda - lambda_Lin| {e_lam:.2e}, |rho + Jc^T+ Jc^T| {e_rho:.2e}, QP {:?}", r.qp.status);
    assert!(e_tau < 1e-8 && e_lam < 1e-6 && e_rho < 1e-9);
}

/// Check every friction, moment and torque row on the predicted real wrenches. (The rows
/// themselves are checked against the physical constraints in `tests/qp_rows.rs`.)
fn worst_violation(r: &coordinator::pidc::TickReport) -> (f64, f64) {
    let mut worst_c = f64::NEG_INFINITY;
    for (start, kind) in &r.contacts {
        let d = if matches!(kind, coordinator::qp::ContactKind::Foot { .. }) { 3 } else { 6 };
        let lam = r.lambda_real.rows(*start, d);
        for (c, lo) in contact_rows(kind).iter() {
            worst_c = worst_c.max(lo - c.iter().zip(lam.iter()).map(|(a, b)| a * b).sum::<f64>());
        }
    }
    let mut worst_t = f64::NEG_INFINITY;
    for (&j, &lim) in r.actuated.iter().zip(&r.limits) {
        worst_t = worst_t.max(r.tau[j].abs() - lim);
    }
    (worst_c, worst_t)
}

#[test]
fn static_team_holds_the_object() {
    let mut fx = Fixture::new();
    let (terms, descs) = fx.static_team(2);
    let cfg = PidcConfig::default();
    let mut c = controller(&descs, cfg);
    // References equal to the current poses: first tick captures, then explicit references.
    c.compute(&terms).expect("tick");
    let (obj, torsos) = {
        let r = c.last().expect("last");
        let g = r.grasp.as_ref().expect("grasp");
        (
            g.object,
            r.team
                .torsos
                .iter()
                .map(|t| (r.team.robots[t.robot].id.clone(), t.position, t.rotation))
                .collect::<Vec<_>>(),
        )
    };
    let pose = |p: Vector3<f64>, q: [f64; 4]| protocol::Pose { position: p.into(), orientation: q };
    let refs = protocol::TaskReferences {
        header: protocol::Header::new(common::TEAM, None, 1, 0),
        object: Some(protocol::PoseReference {
            pose: pose(obj.translation.vector, quat_wxyz(&obj.rotation.to_rotation_matrix())),
            twist: [0.0; 6],
            acceleration: [0.0; 6],
        }),
        torsos: torsos
            .iter()
            .map(|(id, p, r)| protocol::TorsoReference {
                robot: id.clone(),
                reference: protocol::PoseReference {
                    pose: pose(*p, quat_wxyz(r)),
                    twist: [0.0; 6],
                    acceleration: [0.0; 6],
                },
            })
            .collect(),
        swing_feet: vec![],
        foot_loads: vec![],
    };
    c.set_references(&refs);
    let mut cmds = Vec::new();
    c.solve(&terms, &mut cmds).expect("tick");
    let d = c.diagnostics().expect("diagnostics");
    assert_eq!(d.contacts.len(), 10);
    assert!(d.object_estimate.is_some());
    let r = c.materialized().expect("last");
    assert_eq!(r.qp.status, QpStatus::Solved, "{:?}", r.fallback);
    assert_eq!(cmds.len(), 2);
    assert!(cmds.iter().all(|c| c.tau.len() == 18));
    let (wc, wt) = worst_violation(&r);
    println!("QP {:?} in {} iterations, {} rows; worst constraint violation {wc:.2e} N, worst torque excess {wt:.2e} Nm", r.qp.status, r.qp.iterations, r.qp.rows);
    assert!(wc < 1e-5 && wt < 1e-5);
    // Net hand wrench on the object balances its weight: hands push with -lambda.
    let g = r.grasp.as_ref().expect("grasp");
    let nf = r.team.feet.len();
    let hands = r.lambda_real.rows(3 * nf, 12).into_owned();
    let net = -(&g.g * hands);
    let weight = DVector::from_vec(vec![0.0, 0.0, 9.81, 0.0, 0.0, 0.0]);
    println!("net hand wrench on the object {:?}", net.as_slice());
    assert!((&net - &weight).amax() < 1e-8);
    // Feet carry robots + object: sum of vertical foot forces vs total weight.
    let fz: f64 = (0..nf).map(|k| r.lambda_real[3 * k + 2]).sum();
    let total = 9.81 * (descs.iter().map(|d| d.total_mass).sum::<f64>() + 1.0);
    // Predicted accelerations: in a static hold with zero task errors they vanish up to the
    // QP's tolerance; the force balance then holds up to (total mass) * |CoM acceleration|.
    let s_tau = r.tau.component_mul(&r.team.s_diag);
    let p = &r.proj.p;
    let qdd = &r.proj.mc_inv * (p * &s_tau - p * &r.team.bias + &r.proj.pdot_v + p * &r.load);
    println!(
        "sum f_z {fz:.6} N vs weight {total:.6} N (diff {:.2e}); |qdd| {:.2e}",
        fz - total,
        qdd.amax()
    );
    for c in &r.contacts {
        println!(
            "  contact at {}: {:?}",
            c.0,
            r.lambda_real
                .rows(c.0, if c.0 < 3 * nf { 3 } else { 6 })
                .iter()
                .map(|x| (x * 100.0).round() / 100.0)
                .collect::<Vec<_>>()
        );
    }
    // The contact-force torque does not reach the motion space (P S B J_c^T F_c = 0: B does
    // its job, checked below), but the superposition of the object and torso impedances
    // (eqn. joint_space_tau_M, each with its own Lambda_c) does not cancel P h exactly when
    // the tasks are dynamically coupled, so the predicted qdd is small but not zero. The feet
    // then carry the weight plus the predicted rate of change of the robots' linear momentum:
    // the base rows of M qdd (v = 0), rotated to the world.
    let leak = (&r.proj.mc_inv * (p * (r.y.clone() * &r.f_c).component_mul(&r.team.s_diag))).amax();
    let mut momentum_z = 0.0;
    for (rb, torso) in r.team.robots.iter().zip(&r.team.torsos) {
        let mq = (&r.team.mass * &qdd).rows(rb.offset, 3).into_owned();
        momentum_z += (torso.rotation * Vector3::new(mq[0], mq[1], mq[2])).z;
    }
    println!("qdd from F_c {leak:.2e}; predicted momentum rate z {momentum_z:.4} N; balance error {:.2e} N", fz - total - momentum_z);
    assert!(leak < 1e-9, "F_c must not accelerate the motion space");
    assert!((fz - total - momentum_z).abs() < 1e-6 * total);
    assert!(momentum_z.abs() < 0.01 * total, "the leak stays small: {momentum_z} N");
    // The dense interior-point method and Clarabel agree on the same QP.
    let solver = r.qp.solver;
    let tau_a = r.tau.clone();
    let mut cc = controller(
        &descs,
        PidcConfig { qp_path: coordinator::qp::QpPath::Clarabel, ..PidcConfig::default() },
    );
    cc.set_references(&refs);
    let rc = cc.compute(&terms).expect("tick");
    let d_tau = (&rc.tau - &tau_a).amax();
    println!(
        "{solver} vs {} ({:?}, {} iterations): |tau difference| {d_tau:.2e} Nm",
        rc.qp.solver, rc.qp.status, rc.qp.iterations
    );
    assert_ne!(solver, "clarabel");
    assert!(d_tau < 1e-4);
}

/// References that ask the held object (the controller's last grasp) to be 0.5 m above where it
/// is, accelerating up at 5 g: more than the contacts can carry.
fn push_object_up(c: &mut Pidc) {
    let obj = c.last().and_then(|r| r.grasp.as_ref()).expect("grasp").object;
    let mut above = obj.translation.vector;
    above.z += 0.5;
    let refs = protocol::TaskReferences {
        header: protocol::Header::new(common::TEAM, None, 1, 0),
        object: Some(protocol::PoseReference {
            pose: protocol::Pose {
                position: above.into(),
                orientation: quat_wxyz(&obj.rotation.to_rotation_matrix()),
            },
            twist: [0.0; 6],
            acceleration: [0.0, 0.0, 50.0, 0.0, 0.0, 0.0],
        }),
        torsos: vec![],
        swing_feet: vec![],
        foot_loads: vec![],
    };
    c.set_references(&refs);
}

/// A motion the contacts cannot carry (the object's reference far above it, accelerating up at
/// 5 g) yields before anything else gives: the tick is solved with the object's motion cut to
/// the share the contact forces carry and the torsos tracked whole, every friction, moment and
/// torque row kept (written out again by `worst_violation`), no fallback, and the diagnostics
/// say how much of the motion was kept. The same team asked to hold still keeps its whole motion.
#[test]
fn a_motion_the_contacts_cannot_carry_yields_the_object_first_and_keeps_every_row() {
    let mut fx = Fixture::new();
    let (terms, descs) = fx.static_team(2);
    let mut c = controller(&descs, PidcConfig::default());
    c.compute(&terms).expect("tick");
    assert_eq!(
        c.last().expect("tick").motion,
        coordinator::building_blocks::impedance::MotionScale::FULL,
        "holding still needs no yield"
    );
    push_object_up(&mut c);
    let mut cmds = Vec::new();
    c.solve(&terms, &mut cmds).expect("tick");
    let d = c.diagnostics().expect("diagnostics").clone();
    let r = c.materialized().expect("tick");
    println!(
        "motion kept: object {:.3}, torsos {:.3}; QP {:?}, fallback {:?}",
        r.motion.object, r.motion.torso, r.qp.status, r.fallback
    );
    assert!(
        r.motion.object < 1.0 && r.motion.object >= 0.0,
        "the object's motion yielded: {:?}",
        r.motion
    );
    assert_eq!(r.motion.torso, 1.0, "the torsos yield only after the object is held still");
    assert!(
        matches!(r.qp.status, QpStatus::Solved | QpStatus::AlmostSolved) && r.fallback.is_none(),
        "{:?} {:?}",
        r.qp.status,
        r.fallback
    );
    let (wc, wt) = worst_violation(&r);
    println!("worst constraint violation {wc:.2e} N, worst torque excess {wt:.2e} Nm");
    assert!(wc < 1e-5 && wt < 1e-5);
    assert_eq!(
        d.motion_yield,
        Some(protocol::MotionYield { object: r.motion.object, torso: 1.0, reserve: false })
    );
    assert!(d.fallback.is_none() && d.qp_status == QpStatus::Solved, "{d:?}");
    // What the yield kept still lifts the object: its predicted vertical force exceeds its weight.
    let g = r.grasp.as_ref().expect("grasp");
    let nf = r.team.feet.len();
    let net = -(&g.g * r.lambda_real.rows(3 * nf, 12).into_owned());
    println!("net hand force on the object, z: {:.2} N (weight 9.81 N)", net[2]);
    assert!(r.motion.object == 0.0 || net[2] > 9.81, "{}", net[2]);
}

/// Real time: a tick with its solve budget spent answers with the fallback after its first QP.
/// The motion of the test above, with no time to spend: no yield, no second solver down the
/// chain (the active set's refusal stands, Clarabel never runs), the least-violation forces
/// with the torques clamped to the limits. The budget removed, the same tick yields again.
#[test]
fn a_tick_past_its_solve_budget_answers_with_the_fallback() {
    let mut fx = Fixture::new();
    let (terms, descs) = fx.static_team(2);
    let mut c = controller(&descs, PidcConfig::default());
    assert!(c.set_solve_budget(Some(std::time::Duration::ZERO)), "PIDC keeps a budget");
    c.compute(&terms).expect("tick");
    let r = c.last().expect("tick");
    assert!(r.fallback.is_none(), "holding still is solved by the first QP: {:?}", r.fallback);
    push_object_up(&mut c);
    let mut cmds = Vec::new();
    c.solve(&terms, &mut cmds).expect("tick");
    let d = c.diagnostics().expect("diagnostics").clone();
    let r = c.materialized().expect("tick");
    println!("QP {:?} by {}, fallback {:?}", r.qp.status, r.qp.solver, r.fallback);
    assert_eq!(r.motion, coordinator::building_blocks::impedance::MotionScale::FULL);
    assert!(d.motion_yield.is_none(), "{:?}", d.motion_yield);
    assert!(r.fallback.is_some() && r.qp.solver != "clarabel", "{} {:?}", r.qp.solver, r.fallback);
    let (_, wt) = worst_violation(&r);
    assert!(wt < 1e-9, "torques within the limits: worst excess {wt:.2e} Nm");
    assert!(cmds.iter().all(|t| t.tau.iter().all(|x| x.is_finite())));
    c.set_solve_budget(None);
    c.solve(&terms, &mut cmds).expect("tick");
    let r = c.last().expect("tick");
    assert!(r.motion.object < 1.0 && r.fallback.is_none(), "{:?} {:?}", r.motion, r.fallback);
}

#[test]
fn bad_input_is_an_error_or_fallback_never_a_panic() {
    let mut fx = Fixture::new();
    let (terms, descs) = fx.static_team(2);
    let mut out = Vec::new();
    // Missing robot.
    let mut c = controller(&descs, PidcConfig::default());
    c.set_expected(Some(vec!["r1".into(), "r2".into()]));
    assert!(matches!(c.solve(&terms[..1], &mut out), Err(ControllerError::MissingRobot { .. })));
    // No description.
    let mut c2 = controller(&descs[..1], PidcConfig::default());
    assert!(matches!(c2.solve(&terms, &mut out), Err(ControllerError::MissingDescription { .. })));
    // Dimensions that disagree.
    let mut bad = terms.clone();
    bad[1].bias.pop();
    assert!(matches!(c.solve(&bad, &mut out), Err(ControllerError::Dimension { .. })));
    let mut bad = terms.clone();
    bad[0].frames[0].jacobian.cols -= 1;
    assert!(matches!(c.solve(&bad, &mut out), Err(ControllerError::Dimension { .. })));
    // Non-finite numbers.
    let mut bad = terms.clone();
    bad[0].mass_matrix.data[5] = f64::NAN;
    assert!(matches!(c.solve(&bad, &mut out), Err(ControllerError::NonFinite { .. })));
    // Singular: a zero mass matrix (M_c = I - P is singular).
    let mut bad = terms.clone();
    bad[0].mass_matrix.data.iter_mut().for_each(|x| *x = 0.0);
    let res = c.solve(&bad, &mut out);
    println!("zero mass matrix: {res:?}");
    // Refused as a singular M_c (measured: `Singular { what: "M_c" }`); every tick of this
    // controller so far was refused, so nothing was sent.
    assert!(matches!(res, Err(ControllerError::Singular { .. })), "zero mass matrix: {res:?}");
    assert!(out.is_empty(), "no command for refused ticks");
    // Singular kinematics: both hands at the same point with zero Jacobians.
    let mut bad = terms.clone();
    for t in bad.iter_mut() {
        for f in t.frames.iter_mut() {
            f.jacobian.data.iter_mut().for_each(|x| *x = 0.0);
        }
    }
    let res = c.solve(&bad, &mut out);
    println!("zero Jacobians: {res:?}, fallback {}", c.used_fallback());
    // Solved through the fallback: with J_c = 0 no contact force reaches the hands, so the QP
    // is infeasible (the hands' squeeze rows) and the least-violation F_c misses each hand's
    // f_min_hand (30 N) by all of it (measured 29.9999988 N: the object's load has a 1e-6 N
    // normal part); no task or contact torque reaches the joints (measured exactly 0), so the
    // commands sit inside every limit (the smallest is 9 N m).
    assert!(res.is_ok(), "zero Jacobians: {res:?}");
    assert!(c.used_fallback());
    let r = c.last().expect("last");
    assert_eq!(r.qp.status, QpStatus::Infeasible);
    let (wc, wt) = worst_violation(r);
    let f_min_hand = PidcConfig::default().f_min_hand;
    assert!(
        (wc - f_min_hand).abs() < 1e-3,
        "worst row violated by {wc} N, expected f_min_hand {f_min_hand} N"
    );
    assert!(wt <= -1.0, "torques at least 1 N m inside the limits: {wt}");
    assert_eq!(out.len(), 2, "one command per robot");
    for (o, d) in out.iter().zip(&descs) {
        assert_eq!(o.tau.len(), d.torque_limits.len());
        assert!(
            o.tau.iter().zip(&d.torque_limits).all(|(t, lim)| t.is_finite() && t.abs() <= *lim),
            "{:?}",
            o.tau
        );
        assert!(
            o.tau.iter().all(|t| t.abs() < 1e-9),
            "nothing to command without Jacobians: {:?}",
            o.tau
        );
    }
    // Infeasible QP (absurd minimum normal force): the fallback, within the torque limits.
    let mut c3 = controller(
        &descs,
        PidcConfig {
            shell: coordinator::ShellConfig { f_min_foot: 1e5, ..PidcConfig::default().shell },
            ..PidcConfig::default()
        },
    );
    c3.solve(&terms, &mut out).expect("fallback, not an error");
    let r = c3.last().expect("last");
    println!("f_min_foot 1e5: QP {:?}, fallback: {:?}", r.qp.status, r.fallback);
    assert!(c3.used_fallback());
    assert_ne!(r.qp.status, QpStatus::Solved);
    let (_, wt) = worst_violation(r);
    assert!(wt <= 1e-9);
    assert_eq!(c3.diagnostics().expect("diag").qp_status, r.qp.status);
}

#[test]
fn contact_set_changes_and_more_robots() {
    let mut fx = Fixture::new();
    // One foot in swing on robot 1, hand released on robot 2 -> hands: 1.
    let (mut terms, descs) = fx.static_team(2);
    let nv = fx.robot.model.nv;
    let q = fx.standing_q(0, 2);
    let cs = ActiveContacts { stance: vec![false, true, true, true], hand_in_grasp: true };
    terms[0] = fx.terms_with("r1", &q, &DVector::zeros(nv), 1, &cs);
    let mut c = controller(&descs, PidcConfig::default());
    c.compute(&terms).expect("tick");
    let r = c.materialized().expect("tick");
    assert_eq!(r.team.feet.len(), 7);
    assert_eq!(r.team.swing_feet.len(), 1);
    assert_eq!(r.j_c.nrows(), 21 + 12);
    assert_eq!(
        r.qp.status,
        QpStatus::Solved,
        "a foot in swing and a hand released, standing still: {:?}",
        r.fallback
    );
    // Back to all stance: the next tick reassembles.
    let (terms, _) = fx.static_team(2);
    c.compute(&terms).expect("tick");
    let r = c.materialized().expect("tick");
    assert_eq!(r.j_c.nrows(), 36);
    // 4 robots on a circle.
    let (terms, descs) = fx.static_team(4);
    let mut c = controller(&descs, PidcConfig::default());
    let mut out = Vec::new();
    c.solve(&terms, &mut out).expect("tick");
    let r = c.materialized().expect("last");
    assert_eq!(
        r.qp.status,
        QpStatus::Solved,
        "four robots standing around the object: {:?}",
        r.fallback
    );
    assert_eq!(r.team.n, 4 * nv, "four robots' velocities");
    assert_eq!(out.len(), 4);
}

/// The service reuses the command buffer; after a tick of hold orders (a controller error)
/// the controller's next commands must be torques again, not holds carrying torques (which the
/// protocol refuses: an eight-robot run lost its coordinator that way).
#[test]
fn commands_after_a_hold_tick_are_torques_again() {
    let mut fx = Fixture::new();
    let (terms, descs) = fx.static_team(2);
    let mut c = controller(&descs, PidcConfig::default());
    let mut out: Vec<protocol::TorqueCommand> =
        ["r1", "r2"].iter().map(|r| protocol::TorqueCommand::hold(common::TEAM, r, 0)).collect();
    c.solve(&terms, &mut out).expect("tick");
    assert_eq!(out.len(), 2);
    for cmd in &out {
        assert!(!cmd.hold, "{} still a hold order", cmd.header.robot_id());
        assert!(!cmd.tau.is_empty());
        protocol::validate::Validate::validate(cmd).expect("a valid torque command");
    }
}

#[test]
fn controller_configuration_from_toml_keeps_defaults_and_refuses_bad_values() {
    let c = PidcConfig::from_toml(
        "f_min_hand = 20.0\n[object_gains]\nkp = [1, 2, 3, 4, 5, 6]\nkd = [6, 5, 4, 3, 2, 1]\n",
    )
    .expect("partial file");
    assert_eq!(c.f_min_hand, 20.0);
    assert_eq!(c.object_gains.kp, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    let d = PidcConfig::default();
    assert_eq!(c.torso_gains, d.torso_gains);
    assert_eq!(c.f_min_foot, d.f_min_foot);
    // A whole configuration round trips.
    let back = PidcConfig::from_toml(&d.to_toml().unwrap()).unwrap();
    assert_eq!(back.object_inertia, d.object_inertia);
    assert_eq!((back.friction_margin, back.patch_margin), (d.friction_margin, d.patch_margin));
    for (bad, says) in [
        ("[object_gains]\nkp = [1, 2]\nkd = [1, 2]\n", "object_gains"),
        ("f_min_hand = -1.0\n", "f_min_hand"),
        ("patch_margin = 1.5\n", "patch_margin"),
        ("friction_margin = 0.0\n", "friction_margin"),
        ("qp_max_iter = 0\n", "qp_max_iter"),
        ("object_mass = nan\n", "object"),
        ("gain = 3\n", "gain"),
        ("f_min_hand = \"a lot\"\n", "f_min_hand"),
    ] {
        let e = PidcConfig::from_toml(bad).expect_err(bad).to_string();
        assert!(e.contains(says), "{bad}: {e}");
    }
}

/// A swing foot without a reference holds where it lifted off, each time it swings: once it
/// lands its held target is forgotten (it used to be kept, and a second swing pulled the foot
/// back to its first lift-off point).
#[test]
fn a_swing_foot_without_a_reference_holds_where_it_lifted_off_this_time() {
    use coordinator::building_blocks::targets::Targets;
    use coordinator::team::Team;
    let mut fx = Fixture::new();
    let nv = fx.robot.model.nv;
    let swing = ActiveContacts { stance: vec![false, true, true, true], hand_in_grasp: false };
    let stance = ActiveContacts { stance: vec![true; 4], hand_in_grasp: false };
    let q0 = fx.standing_q(0, 2);
    let mut q1 = q0.clone();
    let hfe = fx.robot.model.joint_names.iter().position(|j| j == "LF_HFE").expect("LF_HFE");
    q1[7 + hfe] += 0.2;
    let mut team_at = |q: &DVector<f64>, cs: &ActiveContacts| {
        let terms = fx.terms_with("r1", q, &DVector::zeros(nv), 1, cs);
        let mut team = Team::default();
        team.assemble_into(&[terms], None, false).expect("team");
        team
    };
    let first = team_at(&q0, &swing);
    let (name, p0) = (first.swing_feet[0].name.clone(), first.swing_feet[0].position);
    let mut targets = Targets::default();
    assert_eq!(targets.swing_foot(None, "r1", &name, &p0).0, p0);
    // Still swinging, elsewhere: the lift-off point is held.
    let moved = team_at(&q1, &swing);
    let p1 = moved.swing_feet[0].position;
    assert!((p1 - p0).norm() > 0.02, "the foot moved {:.3} m", (p1 - p0).norm());
    targets.keep_swing_feet(&moved);
    assert_eq!(targets.swing_foot(None, "r1", &name, &p1).0, p0);
    // It lands, then lifts off again at p1: p1 is held now.
    targets.keep_swing_feet(&team_at(&q0, &stance));
    let again = team_at(&q1, &swing);
    targets.keep_swing_feet(&again);
    assert_eq!(targets.swing_foot(None, "r1", &name, &p1).0, p1);
}

/// The diagnostics' `constraint_residual` is `|J_c v|`: written out here row by row from the
/// tick's `J_c` and the team's velocity, on a team moving off its constraints (random
/// velocities, not projected), where it is far from zero, and on the team at rest, where it
/// is zero.
#[test]
fn the_constraint_residual_is_the_norm_of_the_constraints_velocity() {
    use rand::Rng;
    let mut fx = Fixture::new();
    let (_, descs) = fx.static_team(2);
    let mut rng = common::rng(41);
    let nv = fx.robot.model.nv;
    let qs: Vec<DVector<f64>> = (0..2).map(|k| fx.perturbed_q(k, 2, 0.05, &mut rng)).collect();
    let mut c = controller(&descs, PidcConfig::default());
    let mut cmds = Vec::new();
    for moving in [false, true] {
        let tick: Vec<DynamicsTerms> = (0..2)
            .map(|k| {
                let v = if moving {
                    DVector::from_fn(nv, |_, _| rng.random_range(-0.3..0.3))
                } else {
                    DVector::zeros(nv)
                };
                fx.terms(&robot_id(k), &qs[k], &v, 1 + moving as u64)
            })
            .collect();
        c.solve(&tick, &mut cmds).expect("tick");
        let reported = c.diagnostics().expect("diagnostics").constraint_residual;
        // J_c as formed for this tick (the block path reports J_c v without forming it).
        let r = c.materialized().expect("last");
        assert!(c.contact_matrices().j_c_formed);
        let (j, v) = (&r.j_c, &r.team.velocity);
        let written_out = (0..j.nrows())
            .map(|i| (0..j.ncols()).map(|k| j[(i, k)] * v[k]).sum::<f64>().powi(2))
            .sum::<f64>()
            .sqrt();
        println!("moving {moving}: |J_c v| {written_out:.6e}, reported {reported:.6e}");
        assert!(
            (reported - written_out).abs() <= 1e-12 * (1.0 + written_out),
            "reported {reported}, written out {written_out}"
        );
        if moving {
            assert!(written_out > 1e-2, "random velocities leave the constraints: {written_out}");
        } else {
            assert!(written_out == 0.0, "at rest: {written_out}");
        }
    }
}

/// Terms are taken only when they fit their robot's description: the same velocity dimension,
/// base and number of joints (each written out against the default robot: nv 24, a floating
/// base, 18 joints). The controller says so through `TeamController::check_terms`, which the
/// service asks before a tick takes them.
#[test]
fn terms_that_do_not_fit_the_robots_description_are_refused() {
    let mut fx = Fixture::new();
    let q = fx.standing_q(0, 2);
    let terms = fx.terms("r1", &q, &DVector::zeros(fx.robot.model.nv), 3);
    let d = fx.description("r1");
    assert_eq!((terms.nv(), terms.floating_base, d.joint_names.len()), (24, true, 18));
    assert!(coordinator::team::terms_fit(&terms, Some(&d)).is_ok());
    assert!(
        coordinator::team::terms_fit(&terms, None).is_ok(),
        "before the description, the terms' own consistency only"
    );
    let mut wrong = d.clone();
    wrong.nv = 26;
    let e = coordinator::team::terms_fit(&terms, Some(&wrong)).expect_err("another nv");
    assert!(e.to_string().contains("nv 24") && e.to_string().contains("nv 26"), "{e}");
    let mut wrong = d.clone();
    wrong.joint_names.pop();
    assert!(coordinator::team::terms_fit(&terms, Some(&wrong)).is_err(), "17 joints described");
    let mut wrong = d.clone();
    wrong.floating_base = false;
    assert!(coordinator::team::terms_fit(&terms, Some(&wrong)).is_err(), "a fixed base described");
    let mut c = controller(&[d.clone(), fx.description("r2")], PidcConfig::default());
    c.set_description(&wrong);
    assert!(
        c.check_terms(&terms).is_err(),
        "the controller checks against the description it holds"
    );
    c.set_description(&d);
    assert!(c.check_terms(&terms).is_ok());
}
