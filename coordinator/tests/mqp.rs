//! The multi-robot QP baseline (MQP) on team states built from the real default robot:
//! its solution satisfies the team's dynamics and contact kinematics, recomputed here from
//! each robot's own terms (not through the controller's team, grasp or object code); with
//! the same state PIDC and MQP produce contact wrenches and torques inside the same limits,
//! each limit written out again here as the physical statement.

mod common;

use common::{robot_id, Fixture};
use coordinator::building_blocks::contact_margins::ContactMargins;
use coordinator::{Mqp, MqpConfig, Pidc, PidcConfig};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3, Vector6};
use protocol::conventions::GRAVITY_VECTOR;
use protocol::{DynamicsTerms, FrameRole, QpStatus, RobotDescription};
use rand::Rng;
use robot_model::spatial::skew;

/// A 2-robot team at a random perturbed configuration (`amp`) with a velocity that keeps the
/// contacts (the PIDC projector applied to a random velocity of size `vel`).
fn random_team(
    fx: &mut Fixture,
    seed: u64,
    amp: f64,
    vel: f64,
) -> (Vec<DynamicsTerms>, Vec<RobotDescription>) {
    let mut rng = common::rng(seed);
    let nv = fx.robot.model.nv;
    let qs: Vec<DVector<f64>> = (0..2).map(|k| fx.perturbed_q(k, 2, amp, &mut rng)).collect();
    let descs: Vec<_> = (0..2).map(|k| fx.description(&robot_id(k))).collect();
    let terms0: Vec<_> =
        (0..2).map(|k| fx.terms(&robot_id(k), &qs[k], &DVector::zeros(nv), 1)).collect();
    let mut pidc = Pidc::new(PidcConfig::default());
    descs.iter().for_each(|d| pidc.set_description(d));
    pidc.compute(&terms0).expect("tick");
    let p = pidc.materialized().expect("tick").proj.p.clone();
    let v = &p * DVector::from_fn(2 * nv, |_, _| rng.random_range(-vel..vel));
    let terms = (0..2)
        .map(|k| fx.terms(&robot_id(k), &qs[k], &v.rows(k * nv, nv).into_owned(), 2))
        .collect();
    (terms, descs)
}

fn mqp(descs: &[RobotDescription]) -> Mqp {
    let mut c = Mqp::new(MqpConfig::default());
    descs.iter().for_each(|d| c.set_description(d));
    c
}

/// Robot `t`'s frames of `role`, as (Jacobian d x nv, Jdot v, position).
fn frames(t: &DynamicsTerms, role: FrameRole) -> Vec<(DMatrix<f64>, DVector<f64>, Vector3<f64>)> {
    let nv = t.nv();
    t.frames
        .iter()
        .filter(|f| f.role == role)
        .map(|f| {
            let d = role.dim();
            (
                DMatrix::from_row_slice(d, nv, &f.jacobian.data),
                DVector::from_column_slice(&f.jdot_v),
                Vector3::from(f.position),
            )
        })
        .collect()
}

/// The team's equations written out from the robots' terms: the residuals
/// `M qdd + h - J_o^T F_x - S tau - J_c^T lambda` (eq. js_dynamics with the object's load
/// `F_x = -(M_o a_o + b_o)`, `a_o = J_o qdd + Jdot_o v`) and `J_c qdd + Jdot_c v` of the feet.
/// `G`, `G^+`, `N`, `J_c,ee`, `J_o` are formed here from the hand positions and the object
/// centre; `Jdot_o v` (zero for a static team) is the grasp unit's.
fn residuals(terms: &[DynamicsTerms], c: &Mqp, cfg: &MqpConfig) -> (f64, f64) {
    let r = c.last().expect("a tick");
    let nv: Vec<usize> = terms.iter().map(|t| t.nv()).collect();
    let n: usize = nv.iter().sum();
    let (mut m, mut h, mut v) = (DMatrix::zeros(n, n), DVector::zeros(n), DVector::zeros(n));
    let (mut j_cf, mut jdv_cf, mut j_ee, mut hand_p) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut off = 0;
    for t in terms {
        let k = t.nv();
        m.view_mut((off, off), (k, k)).copy_from(&DMatrix::from_row_slice(
            k,
            k,
            &t.mass_matrix.data,
        ));
        h.rows_mut(off, k).copy_from(&DVector::from_column_slice(&t.bias));
        v.rows_mut(off, k).copy_from(&DVector::from_column_slice(&t.velocity));
        let widen = |j: &DMatrix<f64>| {
            let mut w = DMatrix::zeros(j.nrows(), n);
            w.view_mut((0, off), (j.nrows(), k)).copy_from(j);
            w
        };
        for (j, jdv, _) in frames(t, FrameRole::StanceFoot) {
            j_cf.push(widen(&j));
            jdv_cf.push(jdv);
        }
        if t.hand_in_grasp {
            for (j, _, p) in frames(t, FrameRole::Hand) {
                j_ee.push(widen(&j));
                hand_p.push(p);
            }
        }
        off += k;
    }
    let nf = j_cf.len();
    let b = j_ee.len();
    let x = &r.x;
    let qdd = x.rows(0, n).into_owned();
    let lambda = x.rows(n, 3 * nf + 6 * b).into_owned();
    // S tau: every robot's actuated rows (after its 6 base rows) in order.
    let mut s_tau = DVector::zeros(n);
    let (mut off, mut k) = (0, 0);
    for &nvi in &nv {
        for j in 6..nvi {
            s_tau[off + j] = r.tau[k];
            k += 1;
        }
        off += nvi;
    }
    let mut rhs = &s_tau + DVector::zeros(n);
    let mut kin: f64 = 0.0;
    for (i, (j, jdv)) in j_cf.iter().zip(&jdv_cf).enumerate() {
        rhs += j.transpose() * lambda.rows(3 * i, 3);
        kin = kin.max((j * &qdd + jdv).amax());
    }
    let mut lhs = &m * &qdd + &h;
    if b > 0 {
        let po = r.grasp.as_ref().expect("grasp").object.translation.vector;
        let mut g = DMatrix::zeros(6, 6 * b);
        let mut jee = DMatrix::zeros(6 * b, n);
        for i in 0..b {
            g.view_mut((0, 6 * i), (3, 3)).copy_from(&Matrix3::identity());
            g.view_mut((3, 6 * i + 3), (3, 3)).copy_from(&Matrix3::identity());
            g.view_mut((3, 6 * i), (3, 3)).copy_from(&skew(&(hand_p[i] - po)));
            jee.rows_mut(6 * i, 6).copy_from(&j_ee[i]);
        }
        let g_pinv = g.transpose() * (&g * g.transpose()).try_inverse().expect("G G^T regular");
        let nproj = DMatrix::identity(6 * b, 6 * b) - &g_pinv * &g;
        let j_cee = &nproj * &jee;
        rhs += j_cee.transpose() * lambda.rows(3 * nf, 6 * b);
        let j_o = g_pinv.transpose() * &jee;
        let twist = &j_o * &v;
        let jdv_o = &r.grasp.as_ref().expect("grasp").jdv_o;
        let a_o = &j_o * &qdd + jdv_o;
        let rot = r.grasp.as_ref().expect("grasp").object.rotation.to_rotation_matrix();
        let i_w = rot.matrix() * cfg.object_inertia * rot.matrix().transpose();
        let w = Vector3::new(twist[3], twist[4], twist[5]);
        let f = cfg.object_mass
            * (Vector3::new(a_o[0], a_o[1], a_o[2]) - Vector3::from(GRAVITY_VECTOR));
        let mo = i_w * Vector3::new(a_o[3], a_o[4], a_o[5]) + w.cross(&(i_w * w));
        let f_x = -Vector6::new(f.x, f.y, f.z, mo.x, mo.y, mo.z);
        lhs -= j_o.transpose() * f_x;
    }
    ((lhs - rhs).amax(), kin)
}

#[test]
fn mqp_solution_satisfies_the_team_dynamics_to_1e_8() {
    let mut fx = Fixture::new();
    let cfg = MqpConfig::default();
    let (terms, descs) = fx.static_team(2);
    let mut states = vec![(terms, descs)];
    for seed in 0..3 {
        states.push(random_team(&mut fx, seed, 0.1, 0.3));
    }
    for (k, (terms, descs)) in states.iter().enumerate() {
        let mut c = mqp(descs);
        let r = c.compute(terms).expect("tick");
        assert!(matches!(r.outcome.status, QpStatus::Solved), "state {k}: {:?}", r.outcome);
        assert!(r.fallback.is_none());
        let (dyn_res, kin_res) = residuals(terms, &c, &cfg);
        println!("state {k}: dynamics residual {dyn_res:.2e}, foot kinematics {kin_res:.2e}, clarabel {:.0} us", c.last().unwrap().outcome.solve_us);
        assert!(
            dyn_res < 1e-8,
            "state {k}: |M qdd + h - J_o^T F_x - S tau - J_c^T lambda| = {dyn_res:e}"
        );
        assert!(kin_res < 1e-8, "state {k}: |J_cf qdd + Jdot_cf v| = {kin_res:e}");
    }
}

/// How far the wrenches `w` (feet 3, hands 6, team order) and the torques `tau` (actuated,
/// team order) exceed the limits, each written out as its physical statement: feet
/// `f_z >= f_min`, `|f_x|, |f_y| <= mu f_z`; hands (palm axes `t_x, t_y`, outward normal `n`,
/// `f_n = -n . f`) `f_n >= f_min`, sliding and torsional friction in one cone
/// `|t_x . f| / mu + |t_y . f| / mu + |n . m| / xi <= f_n`, centre of pressure in the patch
/// `|t_x . m| <= delta_y f_n`, `|t_y . m| <= delta_x f_n`;
/// `|tau_j| <= tau_max,j`. Friction and patch sizes scaled by the margins both controllers
/// share. Returns the largest excess (<= 0 when every limit holds).
fn limit_excess(
    terms: &[DynamicsTerms],
    descs: &[RobotDescription],
    cfg: &ContactMargins,
    w: &[f64],
    tau: &[f64],
) -> f64 {
    let mut excess = f64::NEG_INFINITY;
    let mut check = |value: f64, bound: f64| excess = excess.max(value - bound);
    let mut row = 0;
    for (t, d) in terms.iter().zip(descs) {
        let mu = d.foot_mu * cfg.friction_margin;
        for _ in t.frames.iter().filter(|f| f.role == FrameRole::StanceFoot) {
            let f = &w[row..row + 3];
            check(cfg.f_min_foot, f[2]);
            check(f[0].abs(), mu * f[2]);
            check(f[1].abs(), mu * f[2]);
            row += 3;
        }
    }
    for (t, d) in terms.iter().zip(descs) {
        let Some(hand) = t.frames.iter().find(|f| f.role == FrameRole::Hand && t.hand_in_grasp)
        else {
            continue;
        };
        let r = Matrix3::from_row_slice(&hand.rotation);
        let (tx, ty, n) =
            (r.column(0).into_owned(), r.column(1).into_owned(), r.column(2).into_owned());
        let f = Vector3::new(w[row], w[row + 1], w[row + 2]);
        let m = Vector3::new(w[row + 3], w[row + 4], w[row + 5]);
        let f_n = -n.dot(&f);
        let (mu, xi) = (d.hand_mu * cfg.friction_margin, d.hand_xi * cfg.friction_margin);
        let (dx, dy) =
            (d.hand_half_size[0] * cfg.patch_margin, d.hand_half_size[1] * cfg.patch_margin);
        check(cfg.f_min_hand, f_n);
        check(
            mu * (tx.dot(&f).abs() / mu + ty.dot(&f).abs() / mu + n.dot(&m).abs() / xi),
            mu * f_n,
        );
        check(tx.dot(&m).abs(), dy * f_n);
        check(ty.dot(&m).abs(), dx * f_n);
        row += 6;
    }
    assert_eq!(row, w.len(), "every contact row checked");
    let limits: Vec<f64> = descs.iter().flat_map(|d| d.torque_limits.iter().copied()).collect();
    assert_eq!(limits.len(), tau.len());
    for (t, l) in tau.iter().zip(&limits) {
        check(t.abs(), *l);
    }
    excess
}

#[test]
fn with_the_same_state_both_controllers_keep_the_contact_wrenches_and_torques_inside_the_same_limits(
) {
    let mut fx = Fixture::new();
    let (terms, descs) = fx.static_team(2);
    let mut states = vec![(terms, descs)];
    // Perturbed states with a small velocity (larger ones can leave PIDC's QP infeasible,
    // where its fallback, not its QP, decides the wrenches).
    for seed in 10..13 {
        states.push(random_team(&mut fx, seed, 0.05, 0.05));
    }
    let shared = MqpConfig::default().contact_margins();
    for (k, (terms, descs)) in states.iter().enumerate() {
        let mut pidc = Pidc::new(PidcConfig::default());
        descs.iter().for_each(|d| pidc.set_description(d));
        let p = pidc.compute(terms).expect("pidc tick");
        assert!(p.fallback.is_none(), "state {k}: pidc fell back");
        let p_tau: Vec<f64> = p.actuated.iter().map(|&j| p.tau[j]).collect();
        let p_excess = limit_excess(terms, descs, &shared, p.lambda_real.as_slice(), &p_tau);
        let mut c = mqp(descs);
        let r = c.compute(terms).expect("mqp tick");
        assert!(r.fallback.is_none(), "state {k}: mqp fell back: {:?}", r.fallback);
        let m_excess = limit_excess(terms, descs, &shared, r.wrench.as_slice(), r.tau.as_slice());
        println!("state {k}: largest excess over a limit: pidc {p_excess:.2e}, mqp {m_excess:.2e}");
        assert!(p_excess < 1e-6, "state {k}: pidc exceeds a limit by {p_excess}");
        assert!(m_excess < 1e-6, "state {k}: mqp exceeds a limit by {m_excess}");
        // Not vacuous: some limit is (nearly) active for each, e.g. the least squeeze.
        assert!(p_excess > -1.0 && m_excess > -1.0, "state {k}: no limit within 1 of binding");
    }
}

#[test]
fn when_clarabel_fails_every_robot_is_still_commanded_and_the_status_says_why() {
    use coordinator::TeamController;
    let mut fx = Fixture::new();
    let (terms, descs) = fx.static_team(2);
    // A squeeze no arm can give: infeasible from the first tick, so no valid solution exists
    // yet and the fallback is the bias torque, clamped to the limits.
    let mut c = Mqp::new(MqpConfig {
        shell: coordinator::ShellConfig { f_min_hand: 1e5, ..MqpConfig::default().shell },
        ..MqpConfig::default()
    });
    descs.iter().for_each(|d| c.set_description(d));
    let mut out = Vec::new();
    TeamController::solve(&mut c, &terms, &mut out).expect("a command despite the failure");
    assert!(c.used_fallback());
    let d = c.diagnostics().expect("diagnostics");
    assert_eq!(d.qp_status, QpStatus::Infeasible);
    let why = c.last().and_then(|r| r.fallback.clone()).expect("a reason");
    assert!(why.contains("Infeasible") && why.contains("bias compensation"), "{why}");
    assert_eq!(out.len(), 2);
    for (cmd, (t, desc)) in out.iter().zip(terms.iter().zip(&descs)) {
        assert_eq!(cmd.tau.len(), desc.torque_limits.len());
        for (j, (tau, lim)) in cmd.tau.iter().zip(&desc.torque_limits).enumerate() {
            assert_eq!(*tau, t.bias[6 + j].clamp(-lim, *lim), "{} joint {j}", desc.joint_names[j]);
        }
    }
    // After a valid tick, a failing one holds that tick's torque (clamped to the new limits).
    let mut c = mqp(&descs);
    TeamController::solve(&mut c, &terms, &mut out).expect("tick");
    assert!(!c.used_fallback());
    let valid: Vec<Vec<f64>> = out.iter().map(|o| o.tau.clone()).collect();
    let mut weak = descs[1].clone();
    weak.torque_limits.iter_mut().for_each(|l| *l = 0.5);
    c.set_description(&weak);
    TeamController::solve(&mut c, &terms, &mut out).expect("a command despite the failure");
    assert!(c.used_fallback());
    let why = c.last().and_then(|r| r.fallback.clone()).expect("a reason");
    assert!(why.contains("last valid solution"), "{why}");
    assert_eq!(out[0].tau, valid[0]);
    assert_eq!(out[1].tau, valid[1].iter().map(|t| t.clamp(-0.5, 0.5)).collect::<Vec<_>>());
}
