//! Conventions every component shares (docs/conventions.md). Fixed here, converted here.
//!
//! * SI units, world frame with z up, gravity [`GRAVITY`] m/s² along -z.
//! * Quaternions are stored `(w, x, y, z)` (MuJoCo's order), unit norm.
//! * Wrenches are `[f_x, f_y, f_z, m_x, m_y, m_z]` (force first), as the paper's lambda.
//! * A floating-base robot's configuration is `q = [p (3, world); quat (w,x,y,z); joints]`
//!   and its generalized velocity is `v = [v_B (3); omega_B (3); joint velocities]` where
//!   `v_B` is the linear velocity of the base origin and `omega_B` the angular velocity of
//!   the base, **both expressed in the base frame** (Pinocchio's convention). So `nq = nv + 1`.
//! * MuJoCo's free joint stores the linear velocity in the *world* frame and the angular
//!   velocity in the body frame. [`base_twist_from_mujoco`] and [`base_twist_to_mujoco`] are the
//!   only conversion between the two; nothing else in the project converts.
//! * Contact and task Jacobians are taken at the frame origin with axes aligned with the
//!   world; rows `[linear; angular]`. Point feet constrain 3 rows, flat hands 6.

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3, Vector6};

/// Standard gravity magnitude, m/s², acting along -z of the world.
pub const GRAVITY: f64 = 9.81;
/// Gravity acceleration as a world vector, m/s²: `[0, 0, -GRAVITY]`.
pub const GRAVITY_VECTOR: [f64; 3] = [0.0, 0.0, -GRAVITY];

/// Dimension of a point-foot contact constraint.
pub const FOOT_CONSTRAINT_DIM: usize = 3;
/// Dimension of a flat hand contact constraint.
pub const HAND_CONSTRAINT_DIM: usize = 6;

/// Unit quaternion from the protocol's `(w, x, y, z)` array (normalised).
pub fn quat_from_wxyz(q: [f64; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]))
}

/// The protocol's `(w, x, y, z)` array of a unit quaternion.
pub fn quat_to_wxyz(q: &UnitQuaternion<f64>) -> [f64; 4] {
    [q.w, q.i, q.j, q.k]
}

/// Rotation of the protocol's row-major 3x3 array (a frame's axes, as sent; not re-orthogonalised).
pub fn rotation_from_row_major(r: &[f64; 9]) -> Rotation3<f64> {
    Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(r))
}

/// MuJoCo free-joint velocity (`qvel[0..6]`: linear in world, angular in body) to the
/// protocol's base twist (linear and angular both in the base frame).
pub fn base_twist_from_mujoco(orientation_wxyz: [f64; 4], mj_qvel: [f64; 6]) -> [f64; 6] {
    let r = quat_from_wxyz(orientation_wxyz);
    let v_world = Vector3::new(mj_qvel[0], mj_qvel[1], mj_qvel[2]);
    let v_base = r.inverse_transform_vector(&v_world);
    [v_base.x, v_base.y, v_base.z, mj_qvel[3], mj_qvel[4], mj_qvel[5]]
}

/// The protocol's base twist to MuJoCo's free-joint velocity. Inverse of
/// [`base_twist_from_mujoco`].
pub fn base_twist_to_mujoco(orientation_wxyz: [f64; 4], twist: [f64; 6]) -> [f64; 6] {
    let r = quat_from_wxyz(orientation_wxyz);
    let v_world = r.transform_vector(&Vector3::new(twist[0], twist[1], twist[2]));
    [v_world.x, v_world.y, v_world.z, twist[3], twist[4], twist[5]]
}

/// MuJoCo free-joint acceleration (`qacc[0..6]`) that corresponds to the protocol's base
/// acceleration `accel` (the time derivative of the base twist `[v; omega]`, both in the base
/// frame) at base twist `twist`: `[R (a_v + omega x v); a_omega]`, because the world-frame
/// linear velocity `R v` also turns with the base. Needed to compare `h` with MuJoCo's
/// `qfrc_bias`: `h = T^T (qfrc_bias + M_mj c)` with `c` this function at zero acceleration.
pub fn base_acceleration_to_mujoco(
    orientation_wxyz: [f64; 4],
    twist: [f64; 6],
    accel: [f64; 6],
) -> [f64; 6] {
    let r = quat_from_wxyz(orientation_wxyz);
    let v = Vector3::new(twist[0], twist[1], twist[2]);
    let w = Vector3::new(twist[3], twist[4], twist[5]);
    let lin = r.transform_vector(&(Vector3::new(accel[0], accel[1], accel[2]) + w.cross(&v)));
    [lin.x, lin.y, lin.z, accel[3], accel[4], accel[5]]
}

/// A wrench `[force; moment]` as a fixed-size vector.
pub fn wrench(force: Vector3<f64>, moment: Vector3<f64>) -> Vector6<f64> {
    Vector6::new(force.x, force.y, force.z, moment.x, moment.y, moment.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mujoco_twist_round_trip_and_rotation() {
        // 90 degrees about z: world x is base -y.
        let q =
            quat_to_wxyz(&UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2));
        let mj = [1.0, 0.0, 0.0, 0.1, 0.2, 0.3];
        let ours = base_twist_from_mujoco(q, mj);
        assert!((ours[0] - 0.0).abs() < 1e-12 && (ours[1] + 1.0).abs() < 1e-12);
        assert_eq!(&ours[3..], &mj[3..]);
        let back = base_twist_to_mujoco(q, ours);
        for i in 0..6 {
            assert!((back[i] - mj[i]).abs() < 1e-12);
        }
    }
}
