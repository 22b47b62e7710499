//! Recursive Newton-Euler Algorithm (Featherstone, *RBDA* §5.3, Table 5.1; world-frame
//! variant): inverse dynamics `tau = M(q) qdd + h(q, v)`, the bias `h = C(q, v) v + g(q)`,
//! the generalized gravity `g(q)`, and a Coriolis matrix `C(q, v)`.
//!
//! Gravity enters as a fictitious base acceleration `a_0 = -g` (Featherstone §5.3).

use nalgebra::{DMatrix, DVector};

use super::kinematics::kinematics_pass;
use crate::data::Data;
use crate::error::DynamicsError;
use crate::model::{check_vec, Model};
use crate::spatial::{Force, Motion};

#[inline]
fn col(m: &nalgebra::Matrix6xX<f64>, k: usize) -> Motion {
    Motion::new(m.fixed_view::<3, 1>(0, k).into(), m.fixed_view::<3, 1>(3, k).into())
}

#[inline]
fn gravity_acc(model: &Model) -> Motion {
    Motion::new(-model.gravity, nalgebra::Vector3::zeros())
}

/// Inverse dynamics: `tau = M(q) a + C(q, v) v + g(q)` into `data.tau`.
pub fn rnea<'a>(
    model: &Model,
    data: &'a mut Data,
    q: &[f64],
    v: &[f64],
    a: &[f64],
) -> Result<&'a DVector<f64>, DynamicsError> {
    model.check_state(q, Some(v))?;
    check_vec(a, model.nv, "a")?;
    kinematics_pass(model, data, q, Some(v), Some(a));
    let ag = gravity_acc(model);
    // f_i = I_i (A_i - a_g) + V_i x* I_i V_i  (Newton-Euler, eq. 5.9)
    for i in 0..model.bodies.len() {
        let ii = &data.o_inertia[i];
        let vi = data.ov[i];
        data.of[i] = ii.mul_motion(&(data.oa[i] + ag)) + vi.cross_force(&ii.mul_motion(&vi));
    }
    backward(model, &data.j, &mut data.of, &mut data.tau);
    Ok(&data.tau)
}

/// `tau_k = S_k . f_i` and `f_parent += f_i`, leaves to root.
fn backward(model: &Model, j: &nalgebra::Matrix6xX<f64>, f: &mut [Force], tau: &mut DVector<f64>) {
    for i in (0..model.bodies.len()).rev() {
        let b = &model.bodies[i];
        for k in b.idx_v..b.idx_v + b.joint.nv() {
            tau[k] = col(j, k).dot(&f[i]);
        }
        if let Some(p) = b.parent {
            let fi = f[i];
            f[p] += fi;
        }
    }
}

/// Bias `h = C(q, v) v + g(q)` (RNEA with zero acceleration) into `data.h`.
pub fn nonlinear_effects<'a>(
    model: &Model,
    data: &'a mut Data,
    q: &[f64],
    v: &[f64],
) -> Result<&'a DVector<f64>, DynamicsError> {
    model.check_state(q, Some(v))?;
    kinematics_pass(model, data, q, Some(v), None);
    bias_from_kinematics(model, data);
    Ok(&data.h)
}

/// Generalized gravity `g(q)` (RNEA with zero velocity and acceleration) into `data.g`.
pub fn gravity<'a>(
    model: &Model,
    data: &'a mut Data,
    q: &[f64],
) -> Result<&'a DVector<f64>, DynamicsError> {
    model.check_state(q, None)?;
    kinematics_pass(model, data, q, None, None);
    gravity_from_kinematics(model, data);
    Ok(&data.g)
}

/// `h` and `g` from the last kinematics pass (which must have had zero acceleration).
pub(crate) fn bias_from_kinematics(model: &Model, data: &mut Data) {
    let ag = gravity_acc(model);
    for i in 0..model.bodies.len() {
        let ii = &data.o_inertia[i];
        let vi = data.ov[i];
        let fg = ii.mul_motion(&ag);
        data.of_g[i] = fg;
        data.of[i] = ii.mul_motion(&data.oa[i]) + fg + vi.cross_force(&ii.mul_motion(&vi));
    }
    backward(model, &data.j, &mut data.of, &mut data.h);
    backward(model, &data.j, &mut data.of_g, &mut data.g);
}

pub(crate) fn gravity_from_kinematics(model: &Model, data: &mut Data) {
    let ag = gravity_acc(model);
    for i in 0..model.bodies.len() {
        data.of_g[i] = data.o_inertia[i].mul_motion(&ag);
    }
    backward(model, &data.j, &mut data.of_g, &mut data.g);
}

/// A Coriolis matrix with `C(q, v) v = h - g` and `Mdot - 2C` skew-symmetric, into `data.c`:
/// `C = sum_i J_i^T (I_i Jdot_i + (V_i x*) I_i J_i)` with world-frame body Jacobians `J_i`
/// (columns `S_k^0`, k in support(i)); skew-symmetry follows from
/// `d/dt I_i = V_i x* I_i - I_i V_i x`. O(bodies * depth^2); for tests and analysis.
pub fn coriolis_matrix<'a>(
    model: &Model,
    data: &'a mut Data,
    q: &[f64],
    v: &[f64],
) -> Result<&'a DMatrix<f64>, DynamicsError> {
    model.check_state(q, Some(v))?;
    kinematics_pass(model, data, q, Some(v), None);
    data.c.fill(0.0);
    for (i, b) in model.bodies.iter().enumerate() {
        let ii = data.o_inertia[i];
        let vi = data.ov[i];
        for &k in &b.support {
            let f =
                ii.mul_motion(&col(&data.dj, k)) + vi.cross_force(&ii.mul_motion(&col(&data.j, k)));
            for &l in &b.support {
                data.c[(l, k)] += col(&data.j, l).dot(&f);
            }
        }
    }
    Ok(&data.c)
}
