//! Analytic identities on seeded random states, with finite differences as the oracle:
//! M symmetric positive definite, Mdot - 2C skew-symmetric, 1/2 v^T M v = sum of body kinetic
//! energies, g = dU/dq, RNEA = M a + h, J and Jdot against differentiated kinematics.

mod common;

use common::*;
use nalgebra::{DMatrix, DVector, Matrix3xX, Matrix6xX, Vector3, Vector6};
use robot_model::*;

const SAMPLES: usize = 50;

fn models() -> Vec<(&'static str, Model)> {
    vec![
        ("arm", arm_model()),
        ("quadruped", quadruped_model()),
        ("legged manipulator", composed_model()),
    ]
}

fn mass_matrix(model: &Model, q: &DVector<f64>) -> DMatrix<f64> {
    let mut d = Data::new(model);
    crba(model, &mut d, q.as_slice()).unwrap().clone()
}

#[test]
fn mass_matrix_is_symmetric_positive_definite() {
    for (name, model) in models() {
        let mut data = Data::new(&model);
        let mut r = rng(10);
        for _ in 0..SAMPLES {
            let (q, _) = random_state(&model, &mut r);
            let m = crba(&model, &mut data, q.as_slice()).unwrap().clone();
            assert!((&m - m.transpose()).norm() <= 1e-14 * m.norm(), "{name}: M not symmetric");
            let eig = m.clone().symmetric_eigen();
            let min = eig.eigenvalues.min();
            assert!(min > 1e-9, "{name}: M not positive definite, min eigenvalue {min}");
        }
    }
}

#[test]
fn mdot_minus_two_c_is_skew_and_c_v_is_the_bias_without_gravity() {
    let dt = 1e-6;
    let mut worst = 0.0f64;
    for (name, model) in models() {
        let mut data = Data::new(&model);
        let mut r = rng(11);
        for _ in 0..SAMPLES {
            let (q, v) = random_state(&model, &mut r);
            let c = coriolis_matrix(&model, &mut data, q.as_slice(), v.as_slice()).unwrap().clone();
            compute_all_terms(&model, &mut data, q.as_slice(), v.as_slice()).unwrap();
            let cv = &c * &v;
            let bias = &data.h - &data.g;
            assert!(rel_err_v(cv.as_slice(), bias.as_slice()) < 1e-12, "{name}: C v != h - g");
            let qp = model.integrate(q.as_slice(), v.as_slice(), dt);
            let qm = model.integrate(q.as_slice(), v.as_slice(), -dt);
            let mdot = (mass_matrix(&model, &qp) - mass_matrix(&model, &qm)) / (2.0 * dt);
            let n = &mdot - 2.0 * &c;
            let sym = (&n + n.transpose()).norm() / mdot.norm().max(1.0);
            worst = worst.max(sym);
            assert!(sym < 1e-7, "{name}: Mdot - 2C not skew ({sym:e})");
            // and the FD Mdot is not trivially zero
            assert!(mdot.norm() > 1e-3);
        }
    }
    println!("worst |N + N^T| / |Mdot| = {worst:.1e}");
}

#[test]
fn kinetic_energy_matches_sum_over_bodies() {
    for (name, model) in models() {
        let mut data = Data::new(&model);
        let mut r = rng(12);
        for _ in 0..SAMPLES {
            let (q, v) = random_state(&model, &mut r);
            compute_all_terms(&model, &mut data, q.as_slice(), v.as_slice()).unwrap();
            let e_m = 0.5 * v.dot(&(&data.m * &v));
            let e_b = kinetic_energy(&model, &data);
            assert!((e_m - e_b).abs() <= 1e-12 * e_b.abs().max(1.0), "{name}: {e_m} vs {e_b}");
        }
    }
}

#[test]
fn gravity_is_the_gradient_of_potential_energy() {
    let eps = 1e-6;
    for (name, model) in models() {
        let mut data = Data::new(&model);
        let mut r = rng(13);
        let zero = DVector::zeros(model.nv);
        for _ in 0..SAMPLES {
            let (q, _) = random_state(&model, &mut r);
            let g = gravity(&model, &mut data, q.as_slice()).unwrap().clone();
            let mut fd = DVector::zeros(model.nv);
            for k in 0..model.nv {
                let mut e = DVector::zeros(model.nv);
                e[k] = 1.0;
                let mut u = |s: f64| {
                    let qk = model.integrate(q.as_slice(), e.as_slice(), s);
                    forward_kinematics(&model, &mut data, qk.as_slice(), zero.as_slice()).unwrap();
                    potential_energy(&model, &data)
                };
                fd[k] = (u(eps) - u(-eps)) / (2.0 * eps);
            }
            let err = rel_err_v(g.as_slice(), fd.as_slice());
            assert!(err < 1e-7, "{name}: g vs dU/dq: {err:e}");
        }
    }
}

#[test]
fn rnea_equals_m_a_plus_h_and_all_terms_agree_with_single_algorithms() {
    for (name, model) in models() {
        let mut data = Data::new(&model);
        let mut other = Data::new(&model);
        let mut r = rng(14);
        for _ in 0..SAMPLES {
            let (q, v) = random_state(&model, &mut r);
            let (_, a) = random_state(&model, &mut r);
            compute_all_terms(&model, &mut data, q.as_slice(), v.as_slice()).unwrap();
            let tau =
                rnea(&model, &mut other, q.as_slice(), v.as_slice(), a.as_slice()).unwrap().clone();
            let expect = &data.m * &a + &data.h;
            assert!(
                rel_err_v(tau.as_slice(), expect.as_slice()) < 1e-12,
                "{name}: rnea != M a + h"
            );
            let h =
                nonlinear_effects(&model, &mut other, q.as_slice(), v.as_slice()).unwrap().clone();
            let g = gravity(&model, &mut other, q.as_slice()).unwrap().clone();
            let m = crba(&model, &mut other, q.as_slice()).unwrap().clone();
            assert!(rel_err_v(h.as_slice(), data.h.as_slice()) < 1e-14);
            assert!(rel_err_v(g.as_slice(), data.g.as_slice()) < 1e-14);
            assert!(rel_err(&m, &data.m) < 1e-14);
        }
    }
}

/// Rotation vector of a small rotation matrix: vee((R - R^T) / 2) = sin(theta) axis, exact
/// to O(theta^3) and free of the acos cancellation of a general log map.
fn vee_log(r: &nalgebra::Matrix3<f64>) -> Vector3<f64> {
    let a = (r - r.transpose()) * 0.5;
    Vector3::new(a[(2, 1)], a[(0, 2)], a[(1, 0)])
}

#[test]
fn jacobians_and_jdot_match_differentiated_kinematics() {
    let dt = 1e-6;
    for (name, model) in models() {
        let mut data = Data::new(&model);
        let mut dp = Data::new(&model);
        let mut dm = Data::new(&model);
        let mut r = rng(15);
        let mut j = Matrix6xX::zeros(model.nv);
        let mut jp = Matrix6xX::zeros(model.nv);
        let mut jm = Matrix6xX::zeros(model.nv);
        let mut jdot = Matrix6xX::zeros(model.nv);
        let mut pj = Matrix3xX::zeros(model.nv);
        for _ in 0..SAMPLES {
            let (q, v) = random_state(&model, &mut r);
            let qp = model.integrate(q.as_slice(), v.as_slice(), dt);
            let qm = model.integrate(q.as_slice(), v.as_slice(), -dt);
            compute_all_terms(&model, &mut data, q.as_slice(), v.as_slice()).unwrap();
            forward_kinematics(&model, &mut dp, qp.as_slice(), v.as_slice()).unwrap();
            forward_kinematics(&model, &mut dm, qm.as_slice(), v.as_slice()).unwrap();
            for f in 0..model.frames.len() {
                frame_jacobian(&model, &data, f, &mut j).unwrap();
                // J v = [dp/dt; omega] with omega from R(t+) R(t-)^T
                let (xp, xm) = (dp.o_m_f[f], dm.o_m_f[f]);
                let lin = (xp.trans - xm.trans) / (2.0 * dt);
                let ang = vee_log(&(xp.rot * xm.rot.transpose())) / (2.0 * dt);
                let fd = Vector6::new(lin.x, lin.y, lin.z, ang.x, ang.y, ang.z);
                let jv = &j * &v;
                assert!(
                    (jv - fd).norm() < 1e-7 * fd.norm().max(1.0),
                    "{name} frame {f}: J v vs FD {jv:?} {fd:?}"
                );
                let vel = frame_velocity(&model, &data, f).unwrap().to_vector6();
                assert!((jv - vel).norm() < 1e-13 * vel.norm().max(1.0));
                // Jdot (analytic) vs FD of J along v; Jdot v vs Jdot * v
                frame_jacobian_time_variation(&model, &data, f, &mut jdot).unwrap();
                frame_jacobian(&model, &dp, f, &mut jp).unwrap();
                frame_jacobian(&model, &dm, f, &mut jm).unwrap();
                let jdot_fd = (&jp - &jm) / (2.0 * dt);
                assert!(
                    (&jdot - &jdot_fd).norm() < 1e-7 * jdot_fd.norm().max(1.0),
                    "{name} frame {f}: Jdot vs FD"
                );
                let jdv = frame_jdot_v(&model, &data, f).unwrap();
                assert!(
                    (&jdot * &v - jdv).norm() < 1e-12 * jdv.norm().max(1.0),
                    "{name} frame {f}: Jdot v vs Jdot * v"
                );
                // point Jacobian at an offset point = linear rows of the J of that point
                let off = Vector3::new(0.03, -0.02, 0.05);
                point_jacobian(&model, &data, f, &off, &mut pj).unwrap();
                let pw = data.o_m_f[f].rot * off;
                let expect = j.rows(0, 3) - skew_cols(&pw, &j);
                assert!((&pj - expect).norm() < 1e-13 * pj.norm().max(1.0));
            }
        }
    }
}

/// `pw x J_ang` column by column (velocity of a point offset by pw is v + w x pw = v - pw x w).
fn skew_cols(pw: &Vector3<f64>, j: &Matrix6xX<f64>) -> Matrix3xX<f64> {
    let mut out = Matrix3xX::zeros(j.ncols());
    for k in 0..j.ncols() {
        let w = Vector3::new(j[(3, k)], j[(4, k)], j[(5, k)]);
        out.set_column(k, &pw.cross(&w));
    }
    out
}

/// The centre of mass against the gravity term of RNEA (an independent path): for a floating
/// base, `g = dU/dq` (checked above) with `U = -M g0 . c`, so the base's linear rows are
/// `-M R^T g0` and its angular rows `-M R^T ((c - p) x g0)` (`p`, `R`: the base's pose).
#[test]
fn center_of_mass_gives_the_gravity_wrench_on_the_floating_base() {
    let model = composed_model();
    let mut data = Data::new(&model);
    let mut r = rng(17);
    let zero = DVector::zeros(model.nv);
    for _ in 0..SAMPLES {
        let (q, _) = random_state(&model, &mut r);
        forward_kinematics(&model, &mut data, q.as_slice(), zero.as_slice()).unwrap();
        let (mass, c) = center_of_mass(&model, &data);
        let base = data.o_m_i[0];
        let g = gravity(&model, &mut data, q.as_slice()).unwrap().clone();
        let g0 = model.gravity;
        let lin = -mass * base.rot.transpose() * g0;
        let ang = -mass * base.rot.transpose() * (c - base.trans).cross(&g0);
        let want = [lin.x, lin.y, lin.z, ang.x, ang.y, ang.z];
        for k in 0..6 {
            assert!(
                (g[k] - want[k]).abs() < 1e-8 * (1.0 + want[k].abs()),
                "row {k}: rnea {} vs centre of mass {}",
                g[k],
                want[k]
            );
        }
        assert!(mass > 1.0, "total mass {mass}");
    }
}
