//! The immutable kinematic/dynamic model (Pinocchio's `Model`).
//!
//! Bodies are the rigid bodies left after merging every fixed joint into its parent; they are
//! numbered in depth-first order of the URDF link tree (children in the order their joints
//! appear in the file), so `parent < child` and the velocity order of the joints is that
//! order. Every URDF link stays addressable as a [`Frame`].

use std::collections::HashMap;

use nalgebra::{DVector, Matrix3, Rotation3, UnitQuaternion, Vector3};

use crate::error::{DynamicsError, ModelError};
use crate::spatial::{Inertia, SE3};

/// Index of a frame in [`Model::frames`].
pub type FrameId = usize;

/// Gravity used by the model: 9.81 m/s^2 along -z (docs/conventions.md; the same number as
/// `protocol::conventions::GRAVITY`, which robot-agent's tests check).
pub const GRAVITY: [f64; 3] = [0.0, 0.0, -9.81];

/// Whether the root link is attached to the world through a 6-DoF floating joint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FloatingBase {
    Yes,
    No,
}

/// The joint between a body and its parent (or the world for the root).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum JointType {
    /// Root welded to the world (fixed-base model): no coordinates.
    Fixed,
    /// 6-DoF floating base: q = [p (world); quat (w, x, y, z)], v = [v (base); w (base)].
    Free,
    /// Rotation about a unit axis in the joint frame (URDF revolute or continuous): q = angle.
    Revolute { axis: Vector3<f64> },
    /// Translation along a unit axis in the joint frame: q = displacement.
    Prismatic { axis: Vector3<f64> },
}

impl JointType {
    pub fn nq(&self) -> usize {
        match self {
            JointType::Fixed => 0,
            JointType::Free => 7,
            _ => 1,
        }
    }
    pub fn nv(&self) -> usize {
        match self {
            JointType::Fixed => 0,
            JointType::Free => 6,
            _ => 1,
        }
    }
}

/// A rigid body of the merged tree.
#[derive(Debug, Clone)]
pub struct Body {
    /// Name of the URDF link whose frame is this body's frame.
    pub name: String,
    /// Name of the joint to the parent ("" for a fixed-base root, "base" for a floating base).
    pub joint_name: String,
    pub parent: Option<usize>,
    pub joint: JointType,
    /// Parent body frame -> joint frame at q = 0 (`liMi` at zero).
    pub placement: SE3,
    /// Spatial inertia in the body frame, lumping every link merged into it.
    pub inertia: Inertia,
    pub idx_q: usize,
    pub idx_v: usize,
    /// Velocity indices of the joints between the world and this body (inclusive), increasing.
    pub support: Vec<usize>,
}

/// How a frame came to exist.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    /// The frame of a body (a link with a movable joint, or the root link).
    Body,
    /// A link merged into its parent body through a fixed joint.
    FixedLink,
    /// Added by [`Model::add_frame`].
    Added,
}

/// A named frame rigidly attached to a body.
#[derive(Debug, Clone)]
pub struct Frame {
    pub name: String,
    pub body: usize,
    /// Body frame -> this frame.
    pub placement: SE3,
    pub kind: FrameKind,
    /// The frame this one hangs from in the link tree (Pinocchio's `parentFrame`): for a
    /// URDF link, the frame of its joint's parent link (the URDF link itself, even when that
    /// link was merged into a body); for an added frame, the frame it was added to; `None`
    /// for the root link.
    pub parent_frame: Option<FrameId>,
}

/// Immutable model: build once (from URDF), share, and pair with a [`crate::Data`] per thread.
#[derive(Debug, Clone)]
pub struct Model {
    pub name: String,
    pub bodies: Vec<Body>,
    pub frames: Vec<Frame>,
    pub frame_index: HashMap<String, FrameId>,
    pub floating_base: bool,
    pub nq: usize,
    pub nv: usize,
    /// Names of the 1-DoF joints in velocity order (the floating base is not listed).
    pub joint_names: Vec<String>,
    /// Position limits per configuration coordinate (infinite for the base and continuous joints).
    pub lower_position_limit: DVector<f64>,
    pub upper_position_limit: DVector<f64>,
    /// Velocity and effort limits per velocity coordinate (infinite for the base).
    pub velocity_limit: DVector<f64>,
    pub effort_limit: DVector<f64>,
    /// Per velocity coordinate: driven by an actuator (false for the base and for joints
    /// whose URDF effort limit is zero).
    pub actuated: Vec<bool>,
    pub total_mass: f64,
    pub gravity: Vector3<f64>,
}

impl Model {
    /// Frame id of a named frame.
    pub fn frame_id(&self, name: &str) -> Result<FrameId, ModelError> {
        self.frame_index
            .get(name)
            .copied()
            .ok_or_else(|| ModelError::UnknownFrame { name: name.to_string() })
    }

    /// Name of the link `frame` hangs from (see [`Frame::parent_frame`]); `None` for the root.
    pub fn parent_link(&self, frame: FrameId) -> Option<&str> {
        let parent = self.frames.get(frame)?.parent_frame?;
        Some(self.frames[parent].name.as_str())
    }

    /// Adds a frame `name` rigidly attached to the frame `parent` at `placement` (parent -> new).
    /// Create [`crate::Data`] after adding frames.
    pub fn add_frame(
        &mut self,
        name: &str,
        parent: &str,
        placement: SE3,
    ) -> Result<FrameId, ModelError> {
        if self.frame_index.contains_key(name) {
            return Err(ModelError::DuplicateName { kind: "frame", name: name.to_string() });
        }
        let parent_id = self.frame_id(parent)?;
        let p = &self.frames[parent_id];
        let frame = Frame {
            name: name.to_string(),
            body: p.body,
            placement: p.placement.compose(&placement),
            kind: FrameKind::Added,
            parent_frame: Some(parent_id),
        };
        self.frames.push(frame);
        let id = self.frames.len() - 1;
        self.frame_index.insert(name.to_string(), id);
        Ok(id)
    }

    /// Names of the velocity coordinates: `base_vx .. base_wz` for a floating base, then joints.
    pub fn velocity_names(&self) -> Vec<String> {
        let mut names = Vec::with_capacity(self.nv);
        if self.floating_base {
            for n in ["base_vx", "base_vy", "base_vz", "base_wx", "base_wy", "base_wz"] {
                names.push(n.to_string());
            }
        }
        names.extend(self.joint_names.iter().cloned());
        names
    }

    /// Names of the configuration coordinates.
    pub fn configuration_names(&self) -> Vec<String> {
        let mut names = Vec::with_capacity(self.nq);
        if self.floating_base {
            for n in ["base_x", "base_y", "base_z", "base_qw", "base_qx", "base_qy", "base_qz"] {
                names.push(n.to_string());
            }
        }
        names.extend(self.joint_names.iter().cloned());
        names
    }

    /// Neutral configuration: base at the origin with the identity quaternion, joints at zero
    /// clamped into their limits.
    pub fn neutral(&self) -> DVector<f64> {
        let mut q = DVector::zeros(self.nq);
        for b in &self.bodies {
            match b.joint {
                JointType::Free => q[b.idx_q + 3] = 1.0,
                JointType::Revolute { .. } | JointType::Prismatic { .. } => {
                    let (lo, hi) =
                        (self.lower_position_limit[b.idx_q], self.upper_position_limit[b.idx_q]);
                    q[b.idx_q] = if lo <= hi { 0.0f64.clamp(lo, hi) } else { 0.0 };
                }
                JointType::Fixed => {}
            }
        }
        q
    }

    /// Checks the lengths and finiteness of a state.
    pub fn check_state(&self, q: &[f64], v: Option<&[f64]>) -> Result<(), DynamicsError> {
        check_vec(q, self.nq, "q")?;
        if let Some(v) = v {
            check_vec(v, self.nv, "v")?;
        }
        if self.floating_base {
            let n = q[3] * q[3] + q[4] * q[4] + q[5] * q[5] + q[6] * q[6];
            if n < 1e-20 {
                return Err(DynamicsError::ZeroQuaternion);
            }
        }
        Ok(())
    }

    /// `q (+) v*dt`: joints add, the floating base moves along the constant body twist
    /// (SE(3) exponential), the quaternion stays normalised.
    pub fn integrate(&self, q: &[f64], v: &[f64], dt: f64) -> DVector<f64> {
        let mut out = DVector::from_column_slice(q);
        for b in &self.bodies {
            match b.joint {
                JointType::Free => {
                    let (iq, iv) = (b.idx_q, b.idx_v);
                    let m = SE3::from_translation_quaternion(
                        Vector3::new(q[iq], q[iq + 1], q[iq + 2]),
                        q[iq + 3],
                        q[iq + 4],
                        q[iq + 5],
                        q[iq + 6],
                    );
                    let lin = Vector3::new(v[iv], v[iv + 1], v[iv + 2]) * dt;
                    let ang = Vector3::new(v[iv + 3], v[iv + 4], v[iv + 5]) * dt;
                    let m2 = m.compose(&SE3::exp6(&lin, &ang));
                    let uq = UnitQuaternion::from_rotation_matrix(
                        &Rotation3::from_matrix_unchecked(m2.rot),
                    );
                    out[iq] = m2.trans.x;
                    out[iq + 1] = m2.trans.y;
                    out[iq + 2] = m2.trans.z;
                    out[iq + 3] = uq.w;
                    out[iq + 4] = uq.i;
                    out[iq + 5] = uq.j;
                    out[iq + 6] = uq.k;
                }
                JointType::Revolute { .. } | JointType::Prismatic { .. } => {
                    out[b.idx_q] += v[b.idx_v] * dt
                }
                JointType::Fixed => {}
            }
        }
        out
    }

    /// A random configuration: joints uniform within their limits (within [-pi, pi] when
    /// unbounded), base position uniform in [-1, 1]^3 and a uniformly random unit quaternion.
    /// `uniform` returns numbers uniform in [0, 1).
    pub fn random_configuration(&self, uniform: &mut dyn FnMut() -> f64) -> DVector<f64> {
        let mut q = self.neutral();
        for b in &self.bodies {
            match b.joint {
                JointType::Free => {
                    for k in 0..3 {
                        q[b.idx_q + k] = 2.0 * uniform() - 1.0;
                    }
                    // Shoemake's uniform random rotation
                    let (u1, u2, u3) = (uniform(), uniform(), uniform());
                    let tau = std::f64::consts::TAU;
                    let (a, c) = ((1.0 - u1).sqrt(), u1.sqrt());
                    let (x, y, z, w) = (
                        a * (tau * u2).sin(),
                        a * (tau * u2).cos(),
                        c * (tau * u3).sin(),
                        c * (tau * u3).cos(),
                    );
                    q[b.idx_q + 3] = w;
                    q[b.idx_q + 4] = x;
                    q[b.idx_q + 5] = y;
                    q[b.idx_q + 6] = z;
                }
                JointType::Revolute { .. } | JointType::Prismatic { .. } => {
                    let lo = self.lower_position_limit[b.idx_q];
                    let hi = self.upper_position_limit[b.idx_q];
                    let (lo, hi) = if lo.is_finite() && hi.is_finite() && lo <= hi {
                        (lo, hi)
                    } else {
                        (-std::f64::consts::PI, std::f64::consts::PI)
                    };
                    q[b.idx_q] = lo + (hi - lo) * uniform();
                }
                JointType::Fixed => {}
            }
        }
        q
    }

    /// Body index of every velocity coordinate.
    pub fn body_of_velocity(&self) -> Vec<usize> {
        let mut out = vec![0; self.nv];
        for (i, b) in self.bodies.iter().enumerate() {
            for k in 0..b.joint.nv() {
                out[b.idx_v + k] = i;
            }
        }
        out
    }
}

pub(crate) fn check_vec(x: &[f64], n: usize, what: &'static str) -> Result<(), DynamicsError> {
    if x.len() != n {
        return Err(DynamicsError::WrongLength { expected: n, got: x.len(), what });
    }
    if let Some(index) = x.iter().position(|a| !a.is_finite()) {
        return Err(DynamicsError::NonFinite { what, index });
    }
    Ok(())
}

/// Rotation matrix of a base quaternion `(w, x, y, z)` (normalised here).
pub fn quaternion_to_matrix(w: f64, x: f64, y: f64, z: f64) -> Matrix3<f64> {
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z))
        .to_rotation_matrix()
        .into_inner()
}
