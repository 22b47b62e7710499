//! Spatial algebra on fixed-size nalgebra types (Featherstone, *Rigid Body Dynamics
//! Algorithms*, ch. 2; Pinocchio's `SE3`, `Motion`, `Force`, `Inertia`).
//!
//! Ordering everywhere is `[linear; angular]`, both for motions (velocity `v`, angular
//! velocity `w`) and for forces (force `f`, moment `n`), as in Pinocchio and as the
//! project's wrench convention `[force; moment]` (docs/conventions.md).
//!
//! A motion or force "at frame A" is expressed in A's axes and refers to A's origin: the
//! linear part of a motion is the velocity of the point coinciding with A's origin.

use std::f64::consts::PI;

use nalgebra::{Matrix3, Matrix6, Rotation3, UnitQuaternion, Vector3, Vector6};

/// Skew-symmetric cross-product matrix: `skew(a) * b = a x b`.
#[inline]
pub fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

/// Rotation from URDF roll-pitch-yaw: `R = Rz(yaw) * Ry(pitch) * Rx(roll)` (fixed axes x, y, z).
pub fn rpy_to_matrix(roll: f64, pitch: f64, yaw: f64) -> Matrix3<f64> {
    Rotation3::from_euler_angles(roll, pitch, yaw).into_inner()
}

/// Orientation error as a world-frame rotation vector: `log(R R_d^T)` (zero when `R = R_d`).
///
/// Taken through the quaternion, whose angle is `2 atan2(|v|, |w|)`: `Rotation3::scaled_axis`
/// takes `acos((tr R - 1) / 2)`, which is NaN when rounding puts the trace of a rotation within
/// an ulp of the identity above 3 (four robots holding a cube at rest hit it on the 4th tick).
pub fn rotation_error(r: &Rotation3<f64>, r_d: &Rotation3<f64>) -> Vector3<f64> {
    UnitQuaternion::from_rotation_matrix(&(r * r_d.inverse())).scaled_axis()
}

/// Left Jacobian of SO(3): the world angular velocity of `exp([x])` is `J_l(x) xdot`.
pub fn left_jacobian(x: &Vector3<f64>) -> Matrix3<f64> {
    let a = x.norm();
    let k = skew(x);
    let (c1, c2) = if a < 1e-4 {
        (0.5 - a * a / 24.0, 1.0 / 6.0 - a * a / 120.0)
    } else {
        ((1.0 - a.cos()) / (a * a), (a - a.sin()) / (a * a * a))
    };
    Matrix3::identity() + c1 * k + c2 * k * k
}

/// Rigid transform `aMb`: maps coordinates in frame b to frame a,
/// `p_a = rot * p_b + trans`. `rot` is b's axes seen in a; `trans` is b's origin in a.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SE3 {
    pub rot: Matrix3<f64>,
    pub trans: Vector3<f64>,
}

impl Default for SE3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl SE3 {
    pub fn identity() -> Self {
        Self { rot: Matrix3::identity(), trans: Vector3::zeros() }
    }

    pub fn new(rot: Matrix3<f64>, trans: Vector3<f64>) -> Self {
        Self { rot, trans }
    }

    /// From a translation and URDF roll-pitch-yaw angles.
    pub fn from_xyz_rpy(xyz: [f64; 3], rpy: [f64; 3]) -> Self {
        Self { rot: rpy_to_matrix(rpy[0], rpy[1], rpy[2]), trans: Vector3::from(xyz) }
    }

    /// From a translation and a (not necessarily normalised) quaternion `(w, x, y, z)`.
    pub fn from_translation_quaternion(
        trans: Vector3<f64>,
        w: f64,
        x: f64,
        y: f64,
        z: f64,
    ) -> Self {
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
        Self { rot: q.to_rotation_matrix().into_inner(), trans }
    }

    /// `self * other` (aMb * bMc = aMc).
    #[inline]
    pub fn compose(&self, other: &SE3) -> SE3 {
        SE3 { rot: self.rot * other.rot, trans: self.rot * other.trans + self.trans }
    }

    #[inline]
    pub fn inverse(&self) -> SE3 {
        let rt = self.rot.transpose();
        SE3 { rot: rt, trans: -(rt * self.trans) }
    }

    /// Transform a point from b to a.
    #[inline]
    pub fn act_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rot * p + self.trans
    }

    /// Motion at b -> motion at a (`aXb m`, Featherstone eq. 2.24 in [lin; ang] order).
    #[inline]
    pub fn act_motion(&self, m: &Motion) -> Motion {
        let ang = self.rot * m.ang;
        Motion { lin: self.rot * m.lin + self.trans.cross(&ang), ang }
    }

    /// Motion at a -> motion at b.
    #[inline]
    pub fn inv_act_motion(&self, m: &Motion) -> Motion {
        let rt = self.rot.transpose();
        Motion { lin: rt * (m.lin - self.trans.cross(&m.ang)), ang: rt * m.ang }
    }

    /// Force at b -> force at a (`aX*b f`).
    #[inline]
    pub fn act_force(&self, f: &Force) -> Force {
        let lin = self.rot * f.lin;
        Force { lin, ang: self.rot * f.ang + self.trans.cross(&lin) }
    }

    /// Force at a -> force at b.
    #[inline]
    pub fn inv_act_force(&self, f: &Force) -> Force {
        let rt = self.rot.transpose();
        Force { lin: rt * f.lin, ang: rt * (f.ang - self.trans.cross(&f.lin)) }
    }

    /// Inertia at b -> inertia at a.
    #[inline]
    pub fn act_inertia(&self, i: &Inertia) -> Inertia {
        Inertia {
            mass: i.mass,
            com: self.rot * i.com + self.trans,
            rot_inertia: self.rot * i.rot_inertia * self.rot.transpose(),
        }
    }

    /// The 6x6 motion transform `aXb` in [lin; ang] order.
    pub fn to_motion_matrix(&self) -> Matrix6<f64> {
        let mut x = Matrix6::zeros();
        x.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.rot);
        x.fixed_view_mut::<3, 3>(0, 3).copy_from(&(skew(&self.trans) * self.rot));
        x.fixed_view_mut::<3, 3>(3, 3).copy_from(&self.rot);
        x
    }

    /// SE(3) exponential of a twist `[v; w]` expressed in the moving frame
    /// (the displacement after following the constant body twist for unit time).
    pub fn exp6(v: &Vector3<f64>, w: &Vector3<f64>) -> SE3 {
        let theta = w.norm();
        let wx = skew(w);
        let wx2 = wx * wx;
        let (a, b, c) = if theta < 1e-6 {
            let t2 = theta * theta;
            (1.0 - t2 / 6.0, 0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0)
        } else {
            let t2 = theta * theta;
            (theta.sin() / theta, (1.0 - theta.cos()) / t2, (theta - theta.sin()) / (t2 * theta))
        };
        let rot = Matrix3::identity() + a * wx + b * wx2;
        let vmat = Matrix3::identity() + b * wx + c * wx2;
        SE3 { rot, trans: vmat * v }
    }
}

/// Spatial motion vector `[v; w]` (twist or spatial acceleration).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Motion {
    pub lin: Vector3<f64>,
    pub ang: Vector3<f64>,
}

impl Motion {
    pub fn zero() -> Self {
        Self { lin: Vector3::zeros(), ang: Vector3::zeros() }
    }
    pub fn new(lin: Vector3<f64>, ang: Vector3<f64>) -> Self {
        Self { lin, ang }
    }
    pub fn from_vector6(v: &Vector6<f64>) -> Self {
        Self { lin: v.fixed_rows::<3>(0).into(), ang: v.fixed_rows::<3>(3).into() }
    }
    pub fn to_vector6(&self) -> Vector6<f64> {
        Vector6::new(self.lin.x, self.lin.y, self.lin.z, self.ang.x, self.ang.y, self.ang.z)
    }
    /// Motion cross product `self x m` (Featherstone's `crm(self) m`).
    #[inline]
    pub fn cross_motion(&self, m: &Motion) -> Motion {
        Motion { lin: self.ang.cross(&m.lin) + self.lin.cross(&m.ang), ang: self.ang.cross(&m.ang) }
    }
    /// Force cross product `self x* f` (Featherstone's `crf(self) f`).
    #[inline]
    pub fn cross_force(&self, f: &Force) -> Force {
        Force { lin: self.ang.cross(&f.lin), ang: self.ang.cross(&f.ang) + self.lin.cross(&f.lin) }
    }
    /// Dual pairing `m . f` (power).
    #[inline]
    pub fn dot(&self, f: &Force) -> f64 {
        self.lin.dot(&f.lin) + self.ang.dot(&f.ang)
    }
    #[inline]
    pub fn scale(&self, s: f64) -> Motion {
        Motion { lin: self.lin * s, ang: self.ang * s }
    }
}

impl std::ops::Add for Motion {
    type Output = Motion;
    #[inline]
    fn add(self, o: Motion) -> Motion {
        Motion { lin: self.lin + o.lin, ang: self.ang + o.ang }
    }
}
impl std::ops::AddAssign for Motion {
    #[inline]
    fn add_assign(&mut self, o: Motion) {
        self.lin += o.lin;
        self.ang += o.ang;
    }
}
impl std::ops::Sub for Motion {
    type Output = Motion;
    #[inline]
    fn sub(self, o: Motion) -> Motion {
        Motion { lin: self.lin - o.lin, ang: self.ang - o.ang }
    }
}

/// Spatial force vector `[f; n]` (wrench; moment `n` about the reference point).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Force {
    pub lin: Vector3<f64>,
    pub ang: Vector3<f64>,
}

impl Force {
    pub fn zero() -> Self {
        Self { lin: Vector3::zeros(), ang: Vector3::zeros() }
    }
    pub fn to_vector6(&self) -> Vector6<f64> {
        Vector6::new(self.lin.x, self.lin.y, self.lin.z, self.ang.x, self.ang.y, self.ang.z)
    }
}

impl std::ops::Add for Force {
    type Output = Force;
    #[inline]
    fn add(self, o: Force) -> Force {
        Force { lin: self.lin + o.lin, ang: self.ang + o.ang }
    }
}
impl std::ops::AddAssign for Force {
    #[inline]
    fn add_assign(&mut self, o: Force) {
        self.lin += o.lin;
        self.ang += o.ang;
    }
}

/// Spatial inertia of a rigid body: mass, centre of mass `com` (in the reference frame) and
/// rotational inertia `rot_inertia` about the centre of mass (in the reference frame's axes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Inertia {
    pub mass: f64,
    pub com: Vector3<f64>,
    pub rot_inertia: Matrix3<f64>,
}

impl Default for Inertia {
    fn default() -> Self {
        Self::zero()
    }
}

impl Inertia {
    pub fn zero() -> Self {
        Self { mass: 0.0, com: Vector3::zeros(), rot_inertia: Matrix3::zeros() }
    }

    pub fn new(mass: f64, com: Vector3<f64>, rot_inertia: Matrix3<f64>) -> Self {
        Self { mass, com, rot_inertia }
    }

    /// `I m`: momentum of a body moving with the spatial velocity `m` (both at the same frame).
    #[inline]
    pub fn mul_motion(&self, m: &Motion) -> Force {
        // velocity of the centre of mass, linear momentum, angular momentum about the origin
        let vc = m.lin + m.ang.cross(&self.com);
        let lin = vc * self.mass;
        Force { lin, ang: self.rot_inertia * m.ang + self.com.cross(&lin) }
    }

    /// Kinetic energy `1/2 m^T I m`.
    pub fn kinetic_energy(&self, m: &Motion) -> f64 {
        0.5 * m.dot(&self.mul_motion(m))
    }

    /// Sum of two inertias expressed in the same frame (parallel-axis theorem).
    pub fn add(&self, o: &Inertia) -> Inertia {
        let mass = self.mass + o.mass;
        if mass <= 0.0 {
            return Inertia {
                mass: 0.0,
                com: Vector3::zeros(),
                rot_inertia: self.rot_inertia + o.rot_inertia,
            };
        }
        let com = (self.com * self.mass + o.com * o.mass) / mass;
        let d1 = self.com - com;
        let d2 = o.com - com;
        // -m skew(d)^2 = m (|d|^2 I - d d^T)
        let s1 = skew(&d1);
        let s2 = skew(&d2);
        let rot_inertia =
            self.rot_inertia + o.rot_inertia - (s1 * s1) * self.mass - (s2 * s2) * o.mass;
        Inertia { mass, com, rot_inertia }
    }

    /// The 6x6 spatial inertia matrix in [lin; ang] order, about the frame origin.
    pub fn to_matrix(&self) -> Matrix6<f64> {
        let c = skew(&self.com);
        let mut i = Matrix6::zeros();
        i.fixed_view_mut::<3, 3>(0, 0).copy_from(&(Matrix3::identity() * self.mass));
        i.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-c * self.mass));
        i.fixed_view_mut::<3, 3>(3, 0).copy_from(&(c * self.mass));
        i.fixed_view_mut::<3, 3>(3, 3).copy_from(&(self.rot_inertia - c * c * self.mass));
        i
    }
}

/// `n` floor poses `((x, y), yaw)` on a circle of `radius` about `centre`, each facing the
/// centre, the first at angle `pi` (the circle's `-x` point), the rest counter-clockwise at
/// equal spacing. One robot stands on the centre facing `+x`. Yaw in `(-pi, pi]`.
pub fn facing_ring(centre: [f64; 2], radius: f64, n: usize) -> Vec<([f64; 2], f64)> {
    (0..n)
        .map(|i| {
            let th = PI + 2.0 * PI * i as f64 / n as f64;
            let r = if n == 1 { 0.0 } else { radius };
            let yaw = (th + PI).rem_euclid(2.0 * PI);
            let yaw = if yaw > PI { yaw - 2.0 * PI } else { yaw };
            ([centre[0] + r * th.cos(), centre[1] + r * th.sin()], yaw)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(a: [f64; 6]) -> Motion {
        Motion::from_vector6(&Vector6::from(a))
    }

    #[test]
    fn transforms_are_consistent_with_matrices() {
        let x = SE3::from_xyz_rpy([0.3, -0.2, 0.5], [0.4, -1.1, 2.0]);
        let mm = m([0.1, 0.2, -0.3, 0.7, -0.5, 0.25]);
        let via_matrix = x.to_motion_matrix() * mm.to_vector6();
        assert!((x.act_motion(&mm).to_vector6() - via_matrix).norm() < 1e-14);
        let back = x.inv_act_motion(&x.act_motion(&mm));
        assert!((back.to_vector6() - mm.to_vector6()).norm() < 1e-14);
        // power is frame invariant
        let f = Force { lin: Vector3::new(1.0, -2.0, 0.5), ang: Vector3::new(0.3, 0.1, -0.4) };
        let p_b = mm.dot(&f);
        let p_a = x.act_motion(&mm).dot(&x.act_force(&f));
        assert!((p_a - p_b).abs() < 1e-14);
        let comp = x.compose(&x.inverse());
        assert!((comp.rot - Matrix3::identity()).norm() < 1e-14 && comp.trans.norm() < 1e-14);
    }

    #[test]
    fn inertia_matrix_matches_struct_and_transforms() {
        let i = Inertia::new(
            2.0,
            Vector3::new(0.1, -0.05, 0.2),
            Matrix3::new(0.3, 0.01, -0.02, 0.01, 0.2, 0.03, -0.02, 0.03, 0.25),
        );
        let mm = m([0.1, 0.2, -0.3, 0.7, -0.5, 0.25]);
        let f = i.mul_motion(&mm).to_vector6();
        assert!((i.to_matrix() * mm.to_vector6() - f).norm() < 1e-14);
        let x = SE3::from_xyz_rpy([0.3, -0.2, 0.5], [0.4, -1.1, 2.0]);
        // X* I X^-1 == act_inertia
        let xm = x.to_motion_matrix();
        let xinv = x.inverse().to_motion_matrix();
        let lhs = xinv.transpose() * i.to_matrix() * xinv;
        assert!((lhs - x.act_inertia(&i).to_matrix()).norm() < 1e-13);
        let _ = xm;
        // addition equals matrix addition
        let j = x.act_inertia(&i);
        assert!(((i.add(&j)).to_matrix() - i.to_matrix() - j.to_matrix()).norm() < 1e-13);
    }

    #[test]
    fn exp6_of_pure_rotation_and_translation() {
        let e = SE3::exp6(&Vector3::new(1.0, 2.0, 3.0), &Vector3::zeros());
        assert!((e.trans - Vector3::new(1.0, 2.0, 3.0)).norm() < 1e-15);
        let w = Vector3::new(0.3, -0.2, 0.9);
        let e = SE3::exp6(&Vector3::zeros(), &w);
        let r = Rotation3::from_scaled_axis(w).into_inner();
        assert!((e.rot - r).norm() < 1e-14);
    }

    /// `exp(w) R_d` against `R_d` gives back `w` for angles below pi (the exponential map is
    /// nalgebra's `from_scaled_axis`, an independent formula).
    #[test]
    fn rotation_error_inverts_the_exponential() {
        let mut worst = 0.0f64;
        for i in 0..2000 {
            let t = i as f64;
            let r_d = Rotation3::from_euler_angles(0.37 * t, -0.11 * t + 0.2, 0.05 * t);
            let axis = Vector3::new((0.7 * t).sin(), (1.3 * t).cos(), (0.3 * t).sin()).normalize();
            let w = axis * (3.1 * ((0.1 * t).sin()).abs());
            let r = Rotation3::from_scaled_axis(w) * r_d;
            worst = worst.max((rotation_error(&r, &r_d) - w).norm());
        }
        assert!(worst < 1e-9, "log(exp(w)) differs from w by {worst}");
    }

    /// A rotation within rounding of the identity whose trace rounds above 3 (what the
    /// four-robot hold produced): `Rotation3::scaled_axis` gave NaN there.
    #[test]
    fn rotation_error_is_finite_when_the_trace_rounds_above_three() {
        let mut m = Matrix3::identity();
        m[(0, 0)] = 1.0 + f64::EPSILON;
        m[(1, 1)] = 1.0 + f64::EPSILON;
        m[(1, 0)] = 1e-12;
        m[(0, 1)] = -1e-12;
        let r = Rotation3::from_matrix_unchecked(m);
        assert!(r.scaled_axis().x.is_nan(), "the case no longer reproduces nalgebra's NaN");
        let e = rotation_error(&r, &Rotation3::identity());
        assert!(
            e.iter().all(|x| x.is_finite()) && (e - Vector3::new(0.0, 0.0, 1e-12)).norm() < 1e-15,
            "error {e:?}"
        );
    }
}
