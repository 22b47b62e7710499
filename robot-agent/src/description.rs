//! A robot's description: the TOML file beside its URDF that names the frames the team
//! problem uses (torso, feet, hand), the contact parameters, the torque limits and the standing
//! configuration. Loading checks it against the URDF and says exactly what is wrong.
//!
//! The file format is documented at the top of `robot-agent/models/legged_manipulator.toml`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::DVector;
use serde::Deserialize;
use thiserror::Error;

use crate::dynamics::{FloatingBase, Model, ModelError};

/// The default robot shipped with the project.
pub fn default_robot_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models/legged_manipulator.toml")
}

/// What can be wrong with a description.
#[derive(Debug, Error)]
pub enum DescriptionError {
    #[error("cannot read robot description {path}: {reason}")]
    Io { path: PathBuf, reason: String },
    #[error("malformed robot description {path}: {reason}")]
    Toml { path: PathBuf, reason: String },
    #[error("robot description {path}: URDF {urdf}: {source}")]
    Model { path: PathBuf, urdf: PathBuf, source: ModelError },
    #[error("robot description {path}: {what} names frame {frame:?}, which the URDF does not have")]
    UnknownFrame { path: PathBuf, what: String, frame: String },
    #[error("robot description {path}: {what} names joint {joint:?}, which is not an actuated joint of the URDF")]
    UnknownJoint { path: PathBuf, what: String, joint: String },
    #[error("robot description {path}: {what} is missing joint(s) {missing:?}")]
    MissingJoints { path: PathBuf, what: String, missing: Vec<String> },
    #[error("robot description {path}: {what} = {value} must be {rule}")]
    BadValue { path: PathBuf, what: String, value: f64, rule: &'static str },
    #[error("robot description {path}: {what}")]
    Invalid { path: PathBuf, what: String },
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    robot: RobotSection,
    frames: FramesSection,
    contact: ContactSection,
    torque_limits: BTreeMap<String, f64>,
    standing: StandingSection,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RobotSection {
    name: String,
    urdf: PathBuf,
    floating_base: bool,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct FramesSection {
    torso: String,
    feet: Vec<String>,
    hand: String,
    swing_feet: Vec<String>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct ContactSection {
    feet: FeetContact,
    hand: HandContact,
}

/// Foot contact parameters.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeetContact {
    /// Friction coefficient.
    pub mu: f64,
    /// Foot sphere radius: the foot frame is this far above the ground in contact.
    pub radius: f64,
}

/// Hand (palm) contact parameters, as in eq. moment_constraint.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandContact {
    /// Friction coefficient.
    pub mu: f64,
    /// Torsional friction coefficient xi (m): |m_z| <= xi f_z.
    pub xi: f64,
    /// Patch half-size along the hand frame's x (the paper's delta_x).
    pub half_size_x: f64,
    /// Patch half-size along the hand frame's y (the paper's delta_y).
    pub half_size_y: f64,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct StandingSection {
    base_position: [f64; 3],
    base_orientation: [f64; 4],
    joints: BTreeMap<String, f64>,
}

/// A loaded, checked robot: its model and what the team needs to know about it.
#[derive(Debug, Clone)]
pub struct Robot {
    /// Where the description was read from.
    pub path: PathBuf,
    /// Absolute path of the URDF.
    pub urdf_path: PathBuf,
    pub name: String,
    pub model: Model,
    pub torso_frame: String,
    pub foot_frames: Vec<String>,
    pub hand_frame: String,
    pub swing_foot_frames: Vec<String>,
    pub feet: FeetContact,
    pub hand: HandContact,
    /// Names of the actuated joints in velocity order.
    pub actuated_joints: Vec<String>,
    /// Velocity index of each actuated joint.
    pub actuated_indices: Vec<usize>,
    /// Symmetric torque limit of each actuated joint, velocity order.
    pub torque_limits: Vec<f64>,
    /// Standing configuration `q` (nq entries, the model's convention).
    pub standing_q: DVector<f64>,
}

impl Robot {
    /// Load a description and its URDF, and check one against the other.
    pub fn load(path: impl AsRef<Path>) -> Result<Robot, DescriptionError> {
        let path = path.as_ref().to_path_buf();
        let text = std::fs::read_to_string(&path)
            .map_err(|e| DescriptionError::Io { path: path.clone(), reason: e.to_string() })?;
        Self::from_toml_str(&text, &path)
    }

    /// Parse a description whose relative URDF path is resolved against `path`'s folder.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Robot, DescriptionError> {
        let file: File =
            toml::from_str(text).map_err(|e| DescriptionError::Toml { path: path.to_path_buf(), reason: e.to_string() })?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let urdf_path = if file.robot.urdf.is_absolute() { file.robot.urdf.clone() } else { dir.join(&file.robot.urdf) };
        let floating = if file.robot.floating_base { FloatingBase::Yes } else { FloatingBase::No };
        let model = Model::from_urdf_file(&urdf_path, floating).map_err(|source| DescriptionError::Model {
            path: path.to_path_buf(),
            urdf: urdf_path.clone(),
            source,
        })?;
        check(file, model, path, urdf_path)
    }

    /// Number of actuated joints.
    pub fn joints(&self) -> usize {
        self.actuated_joints.len()
    }

    /// The protocol's summary of this robot, for robot `id` of team `team`.
    pub fn summary(&self, team: &str, id: &str) -> protocol::RobotDescription {
        protocol::RobotDescription {
            header: protocol::Header::new(team, Some(id), 0, protocol::wall_clock_ns()),
            joint_names: self.actuated_joints.clone(),
            torque_limits: self.torque_limits.clone(),
            floating_base: self.model.floating_base,
            nq: self.model.nq as u32,
            nv: self.model.nv as u32,
            foot_frames: self.foot_frames.clone(),
            hand_frame: self.hand_frame.clone(),
            torso_frame: self.torso_frame.clone(),
            foot_mu: self.feet.mu,
            hand_mu: self.hand.mu,
            hand_xi: self.hand.xi,
            hand_half_size: [self.hand.half_size_x, self.hand.half_size_y],
            total_mass: self.model.total_mass,
        }
    }
}

fn check(file: File, model: Model, path: &Path, urdf_path: PathBuf) -> Result<Robot, DescriptionError> {
    let p = || path.to_path_buf();
    let frame = |what: &str, name: &str| -> Result<(), DescriptionError> {
        model.frame_id(name).map(|_| ()).map_err(|_| DescriptionError::UnknownFrame {
            path: p(),
            what: what.to_string(),
            frame: name.to_string(),
        })
    };
    frame("frames.torso", &file.frames.torso)?;
    frame("frames.hand", &file.frames.hand)?;
    if file.frames.feet.is_empty() {
        return Err(DescriptionError::Invalid { path: p(), what: "frames.feet is empty".into() });
    }
    for f in &file.frames.feet {
        frame("frames.feet", f)?;
    }
    for f in &file.frames.swing_feet {
        frame("frames.swing_feet", f)?;
        if !file.frames.feet.contains(f) {
            return Err(DescriptionError::Invalid { path: p(), what: format!("swing foot {f:?} is not one of frames.feet") });
        }
    }
    let positive = |what: String, value: f64| -> Result<(), DescriptionError> {
        if value.is_finite() && value > 0.0 {
            Ok(())
        } else {
            Err(DescriptionError::BadValue { path: p(), what, value, rule: "a positive finite number" })
        }
    };
    positive("contact.feet.mu".into(), file.contact.feet.mu)?;
    positive("contact.feet.radius".into(), file.contact.feet.radius)?;
    positive("contact.hand.mu".into(), file.contact.hand.mu)?;
    positive("contact.hand.xi".into(), file.contact.hand.xi)?;
    positive("contact.hand.half_size_x".into(), file.contact.hand.half_size_x)?;
    positive("contact.hand.half_size_y".into(), file.contact.hand.half_size_y)?;

    // Actuated joints in velocity order.
    let base = if model.floating_base { 6 } else { 0 };
    let mut actuated_joints = Vec::new();
    let mut actuated_indices = Vec::new();
    for (k, name) in model.joint_names.iter().enumerate() {
        if model.actuated[base + k] {
            actuated_joints.push(name.clone());
            actuated_indices.push(base + k);
        }
    }
    for (name, limit) in &file.torque_limits {
        if !actuated_joints.contains(name) {
            return Err(DescriptionError::UnknownJoint { path: p(), what: "torque_limits".into(), joint: name.clone() });
        }
        positive(format!("torque_limits.{name}"), *limit)?;
    }
    let missing: Vec<String> = actuated_joints.iter().filter(|j| !file.torque_limits.contains_key(*j)).cloned().collect();
    if !missing.is_empty() {
        return Err(DescriptionError::MissingJoints { path: p(), what: "torque_limits".into(), missing });
    }
    let torque_limits: Vec<f64> = actuated_joints.iter().map(|j| file.torque_limits[j]).collect();
    for (j, (&idx, &limit)) in actuated_indices.iter().zip(&torque_limits).enumerate() {
        let urdf_effort = model.effort_limit[idx];
        if urdf_effort.is_finite() && limit > urdf_effort * (1.0 + 1e-9) {
            return Err(DescriptionError::Invalid {
                path: p(),
                what: format!("torque_limits.{} = {limit} exceeds the URDF effort limit {urdf_effort}", actuated_joints[j]),
            });
        }
    }

    // Standing configuration.
    let s = &file.standing;
    for (what, xs) in [("standing.base_position", &s.base_position[..]), ("standing.base_orientation", &s.base_orientation[..])] {
        if let Some(x) = xs.iter().find(|x| !x.is_finite()) {
            return Err(DescriptionError::BadValue { path: p(), what: what.into(), value: *x, rule: "finite" });
        }
    }
    let qn = s.base_orientation.iter().map(|x| x * x).sum::<f64>().sqrt();
    if (qn - 1.0).abs() > 1e-6 {
        return Err(DescriptionError::BadValue {
            path: p(),
            what: "norm of standing.base_orientation".into(),
            value: qn,
            rule: "1 (a unit quaternion w, x, y, z)",
        });
    }
    for (name, value) in &s.joints {
        if !model.joint_names.contains(name) {
            return Err(DescriptionError::UnknownJoint { path: p(), what: "standing.joints".into(), joint: name.clone() });
        }
        if !value.is_finite() {
            return Err(DescriptionError::BadValue { path: p(), what: format!("standing.joints.{name}"), value: *value, rule: "finite" });
        }
    }
    let missing: Vec<String> = model.joint_names.iter().filter(|j| !s.joints.contains_key(*j)).cloned().collect();
    if !missing.is_empty() {
        return Err(DescriptionError::MissingJoints { path: p(), what: "standing.joints".into(), missing });
    }
    let mut standing_q = model.neutral();
    let qbase = if model.floating_base {
        standing_q.as_mut_slice()[0..3].copy_from_slice(&s.base_position);
        standing_q.as_mut_slice()[3..7].copy_from_slice(&s.base_orientation);
        7
    } else {
        0
    };
    for (k, name) in model.joint_names.iter().enumerate() {
        let value = s.joints[name];
        let (lo, hi) = (model.lower_position_limit[qbase + k], model.upper_position_limit[qbase + k]);
        if value < lo - 1e-9 || value > hi + 1e-9 {
            return Err(DescriptionError::Invalid {
                path: p(),
                what: format!("standing.joints.{name} = {value} is outside the joint limits [{lo}, {hi}]"),
            });
        }
        standing_q[qbase + k] = value;
    }

    Ok(Robot {
        path: p(),
        urdf_path,
        name: file.robot.name,
        torso_frame: file.frames.torso,
        foot_frames: file.frames.feet,
        hand_frame: file.frames.hand,
        swing_foot_frames: file.frames.swing_feet,
        feet: file.contact.feet,
        hand: file.contact.hand,
        actuated_joints,
        actuated_indices,
        torque_limits,
        standing_q,
        model,
    })
}
