//! The carried object's load on the robots: the feed-forward [`object_load`] that PIDC's
//! object task and MQP's object terms share.
//!
//! **Object weight.** The object is not in the generalized coordinates. Its load on the
//! robots is modelled as the paper's external wrench `J_x^T F_x` (eq. js_dynamics) with
//! `J_x = J_o` and `F_x = -w_ff`, `w_ff = [m_o (a_d - g); I_o alpha_d + omega x I_o omega]`
//! (the object's gravity and inertial load at its reference acceleration, acting on the
//! rigid grasp), and compensated by the same feed-forward in the object's impedance task:
//! `F_o = (eq. control_law) + w_ff`. `J_o^T F_x = J_ee^T G^+ F_x`, so the real wrench the object
//! exerts on hand `i` is `lambda_ee,i + (G^+ F_x)_i` (the internal part from the constraint
//! plus the load distribution); that sum is what the diagnostics report and what the QP
//! constrains (see `crate::pidc::stages::wrench`). The hands push the object with the negative
//! of it, so their net wrench on the object is `-G (G^+ F_x) = w_ff`: it balances the weight in
//! a static hold.

use nalgebra::{Isometry3, Matrix3, Vector3, Vector6};
use protocol::conventions::GRAVITY_VECTOR;

/// The object's load feed-forward `w_ff = [m_o (a_d - g); I_o alpha_d + omega x I_o omega]` at
/// its centre (world): `object` its pose, `twist` its twist `[v; omega]`, `acc_d` the reference
/// acceleration `[a_d; alpha_d]`, `inertia` about the centre in the object's frame. The load
/// on the robots is `F_x = -w_ff` (see the module docs).
pub fn object_load(
    object: &Isometry3<f64>,
    twist: &Vector6<f64>,
    acc_d: &[f64; 6],
    mass: f64,
    inertia: &Matrix3<f64>,
) -> Vector6<f64> {
    let r_o = object.rotation.to_rotation_matrix();
    let i_w = r_o.matrix() * *inertia * r_o.matrix().transpose();
    let w = twist.fixed_rows::<3>(3).into_owned();
    let alpha = Vector3::new(acc_d[3], acc_d[4], acc_d[5]);
    let force = mass * (Vector3::new(acc_d[0], acc_d[1], acc_d[2]) - Vector3::from(GRAVITY_VECTOR));
    let moment = i_w * alpha + w.cross(&(i_w * w));
    Vector6::new(force.x, force.y, force.z, moment.x, moment.y, moment.z)
}
