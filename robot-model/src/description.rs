//! A robot's description: the TOML file beside its URDF that names the frames the team
//! problem uses (torso, feet, hand), the contact parameters, the torque limits and the standing
//! configuration. Loading checks it against the URDF and says exactly what is wrong.
//!
//! The file format is documented at the top of `robot-model/models/legged_manipulator.toml`.
//!
//! Load a robot once per process and share it: [`Robot::load`] for one file, [`RobotCache`]
//! for a team whose robots may share a description (each file is read and checked once).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::DVector;
use serde::Deserialize;
use thiserror::Error;

use crate::algorithm::{forward_kinematics, frame_placement};
use crate::data::Data;
use crate::error::{DynamicsError, ModelError};
use crate::model::{FloatingBase, Model};

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
    #[error(
        "robot description {path}: {what} names frame {frame:?}, which the URDF does not have"
    )]
    UnknownFrame { path: PathBuf, what: String, frame: String },
    #[error(
        "robot description {path}: {what} names joint {joint:?}, which is not an actuated joint \
         of the URDF"
    )]
    UnknownJoint { path: PathBuf, what: String, joint: String },
    #[error("robot description {path}: {what} is missing joint(s) {missing:?}")]
    MissingJoints { path: PathBuf, what: String, missing: Vec<String> },
    #[error("robot description {path}: {what} = {value} must be {rule}")]
    BadValue { path: PathBuf, what: String, value: f64, rule: &'static str },
    #[error("robot description {path}: {what}")]
    Invalid { path: PathBuf, what: String },
    #[error("{0}")]
    HandPose(Box<HandPoseMismatch>),
}

/// The standing hand pose a description says against the one its URDF gives (boxed in
/// [`DescriptionError::HandPose`]: it is the largest error).
#[derive(Debug, Error)]
#[error(
    "robot description {path}: at standing the URDF puts {frame} at {actual_position:?} (base \
     frame), quaternion {actual_orientation:?}, but standing.hand_position = {position:?} and \
     standing.hand_orientation = {orientation:?}: {distance_mm:.3} mm and {angle_deg:.3} deg \
     apart (tolerance 1 mm, 0.5 deg)"
)]
pub struct HandPoseMismatch {
    pub path: PathBuf,
    pub frame: String,
    pub position: [f64; 3],
    pub orientation: [f64; 4],
    pub actual_position: [f64; 3],
    pub actual_orientation: [f64; 4],
    pub distance_mm: f64,
    pub angle_deg: f64,
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
    /// Where the hand frame is at standing, in the base (root link) frame: position (m) and
    /// orientation `(w, x, y, z)`. Checked against the URDF's forward kinematics at load.
    hand_position: [f64; 3],
    hand_orientation: [f64; 4],
    joints: BTreeMap<String, f64>,
}

/// How far the URDF's hand frame at standing may be from the description's: 1 mm.
pub const HAND_POSITION_TOLERANCE: f64 = 1e-3;
/// ... and 0.5 degree.
pub const HAND_ANGLE_TOLERANCE_DEG: f64 = 0.5;

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
    /// The hand frame at standing in the base frame, as the description says (and the URDF
    /// agrees within 1 mm and 0.5 deg): position (m) and orientation `(w, x, y, z)`.
    pub standing_hand_position: [f64; 3],
    pub standing_hand_orientation: [f64; 4],
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
        let file: File = toml::from_str(text).map_err(|e| DescriptionError::Toml {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let urdf_path = if file.robot.urdf.is_absolute() {
            file.robot.urdf.clone()
        } else {
            dir.join(&file.robot.urdf)
        };
        let floating = if file.robot.floating_base { FloatingBase::Yes } else { FloatingBase::No };
        let model = Model::from_urdf_file(&urdf_path, floating).map_err(|source| {
            DescriptionError::Model { path: path.to_path_buf(), urdf: urdf_path.clone(), source }
        })?;
        check(file, model, path, urdf_path)
    }

    /// Number of actuated joints.
    pub fn joints(&self) -> usize {
        self.actuated_joints.len()
    }
}

/// Robots loaded once per description file: the first [`RobotCache::load`] of a path reads and
/// checks it, later ones share the same `Arc<Robot>`. Paths are compared as given.
#[derive(Debug, Default, Clone)]
pub struct RobotCache {
    loaded: BTreeMap<PathBuf, Arc<Robot>>,
}

impl RobotCache {
    pub fn new() -> Self {
        Self::default()
    }

    /// The robot described at `path`, loaded on first use.
    // The same (large) error as `Robot::load`, once per file at start-up, never per tick.
    #[allow(clippy::result_large_err)]
    pub fn load(&mut self, path: &Path) -> Result<Arc<Robot>, DescriptionError> {
        if let Some(robot) = self.loaded.get(path) {
            return Ok(robot.clone());
        }
        let robot = Arc::new(Robot::load(path)?);
        self.loaded.insert(path.to_path_buf(), robot.clone());
        Ok(robot)
    }

    /// How many distinct descriptions were loaded.
    pub fn len(&self) -> usize {
        self.loaded.len()
    }

    pub fn is_empty(&self) -> bool {
        self.loaded.is_empty()
    }
}

fn check(
    file: File,
    model: Model,
    path: &Path,
    urdf_path: PathBuf,
) -> Result<Robot, DescriptionError> {
    check_frames(&model, &file.frames, path)?;
    check_contact(&file.contact, path)?;
    let (actuated_joints, actuated_indices) = actuated_joints(&model);
    let torque_limits = check_torque_limits(
        &model,
        &file.torque_limits,
        &actuated_joints,
        &actuated_indices,
        path,
    )?;
    let s = &file.standing;
    check_standing_numbers(&model, s, path)?;
    let standing_q = standing_configuration(&model, s, path)?;
    check_standing_hand(&model, &standing_q, &file.frames.hand, s, path)?;

    Ok(Robot {
        standing_hand_position: s.hand_position,
        standing_hand_orientation: s.hand_orientation,
        path: path.to_path_buf(),
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

/// `value` is a positive finite number, or the error naming `what`.
fn positive(path: &Path, what: String, value: f64) -> Result<(), DescriptionError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(DescriptionError::BadValue {
            path: path.to_path_buf(),
            what,
            value,
            rule: "a positive finite number",
        })
    }
}

/// Every frame the description names is a frame of the URDF; there are feet, and the swing
/// feet are among them.
fn check_frames(
    model: &Model,
    frames: &FramesSection,
    path: &Path,
) -> Result<(), DescriptionError> {
    let p = || path.to_path_buf();
    let frame = |what: &str, name: &str| -> Result<(), DescriptionError> {
        model.frame_id(name).map(|_| ()).map_err(|_| DescriptionError::UnknownFrame {
            path: p(),
            what: what.to_string(),
            frame: name.to_string(),
        })
    };
    frame("frames.torso", &frames.torso)?;
    frame("frames.hand", &frames.hand)?;
    if frames.feet.is_empty() {
        return Err(DescriptionError::Invalid { path: p(), what: "frames.feet is empty".into() });
    }
    for f in &frames.feet {
        frame("frames.feet", f)?;
    }
    for f in &frames.swing_feet {
        frame("frames.swing_feet", f)?;
        if !frames.feet.contains(f) {
            return Err(DescriptionError::Invalid {
                path: p(),
                what: format!("swing foot {f:?} is not one of frames.feet"),
            });
        }
    }
    Ok(())
}

/// Every contact parameter is a positive finite number.
fn check_contact(contact: &ContactSection, path: &Path) -> Result<(), DescriptionError> {
    positive(path, "contact.feet.mu".into(), contact.feet.mu)?;
    positive(path, "contact.feet.radius".into(), contact.feet.radius)?;
    positive(path, "contact.hand.mu".into(), contact.hand.mu)?;
    positive(path, "contact.hand.xi".into(), contact.hand.xi)?;
    positive(path, "contact.hand.half_size_x".into(), contact.hand.half_size_x)?;
    positive(path, "contact.hand.half_size_y".into(), contact.hand.half_size_y)?;
    Ok(())
}

/// The model's actuated joints in velocity order: their names and velocity indices.
fn actuated_joints(model: &Model) -> (Vec<String>, Vec<usize>) {
    let base = if model.floating_base { 6 } else { 0 };
    let mut actuated_joints = Vec::new();
    let mut actuated_indices = Vec::new();
    for (k, name) in model.joint_names.iter().enumerate() {
        if model.actuated[base + k] {
            actuated_joints.push(name.clone());
            actuated_indices.push(base + k);
        }
    }
    (actuated_joints, actuated_indices)
}

/// The torque limit of each actuated joint (velocity order): one positive limit per actuated
/// joint and no other, none above the URDF's effort limit.
fn check_torque_limits(
    model: &Model,
    limits: &BTreeMap<String, f64>,
    actuated_joints: &[String],
    actuated_indices: &[usize],
    path: &Path,
) -> Result<Vec<f64>, DescriptionError> {
    let p = || path.to_path_buf();
    for (name, limit) in limits {
        if !actuated_joints.contains(name) {
            return Err(DescriptionError::UnknownJoint {
                path: p(),
                what: "torque_limits".into(),
                joint: name.clone(),
            });
        }
        positive(path, format!("torque_limits.{name}"), *limit)?;
    }
    let missing: Vec<String> =
        actuated_joints.iter().filter(|j| !limits.contains_key(*j)).cloned().collect();
    if !missing.is_empty() {
        return Err(DescriptionError::MissingJoints {
            path: p(),
            what: "torque_limits".into(),
            missing,
        });
    }
    let torque_limits: Vec<f64> = actuated_joints.iter().map(|j| limits[j]).collect();
    for (j, (&idx, &limit)) in actuated_indices.iter().zip(&torque_limits).enumerate() {
        let urdf_effort = model.effort_limit[idx];
        if urdf_effort.is_finite() && limit > urdf_effort * (1.0 + 1e-9) {
            return Err(DescriptionError::Invalid {
                path: p(),
                what: format!(
                    "torque_limits.{} = {limit} exceeds the URDF effort limit {urdf_effort}",
                    actuated_joints[j]
                ),
            });
        }
    }
    Ok(torque_limits)
}

/// The standing section's numbers: finite poses, unit quaternions, and one finite position for
/// every joint of the model and no other.
fn check_standing_numbers(
    model: &Model,
    s: &StandingSection,
    path: &Path,
) -> Result<(), DescriptionError> {
    check_standing_poses(s, path)?;
    check_standing_joints(model, s, path)
}

/// The standing base and hand poses: finite, their quaternions of unit norm.
fn check_standing_poses(s: &StandingSection, path: &Path) -> Result<(), DescriptionError> {
    let p = || path.to_path_buf();
    for (what, xs) in [
        ("standing.base_position", &s.base_position[..]),
        ("standing.base_orientation", &s.base_orientation[..]),
        ("standing.hand_position", &s.hand_position[..]),
        ("standing.hand_orientation", &s.hand_orientation[..]),
    ] {
        if let Some(x) = xs.iter().find(|x| !x.is_finite()) {
            return Err(DescriptionError::BadValue {
                path: p(),
                what: what.into(),
                value: *x,
                rule: "finite",
            });
        }
    }
    for (what, q) in [
        ("standing.base_orientation", &s.base_orientation),
        ("standing.hand_orientation", &s.hand_orientation),
    ] {
        let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
        if (n - 1.0).abs() > 1e-6 {
            return Err(DescriptionError::BadValue {
                path: p(),
                what: format!("norm of {what}"),
                value: n,
                rule: "1 (a unit quaternion w, x, y, z)",
            });
        }
    }
    Ok(())
}

/// The standing joint positions: one finite value for every joint of the model and no other.
fn check_standing_joints(
    model: &Model,
    s: &StandingSection,
    path: &Path,
) -> Result<(), DescriptionError> {
    let p = || path.to_path_buf();
    for (name, value) in &s.joints {
        if !model.joint_names.contains(name) {
            return Err(DescriptionError::UnknownJoint {
                path: p(),
                what: "standing.joints".into(),
                joint: name.clone(),
            });
        }
        if !value.is_finite() {
            return Err(DescriptionError::BadValue {
                path: p(),
                what: format!("standing.joints.{name}"),
                value: *value,
                rule: "finite",
            });
        }
    }
    let missing: Vec<String> =
        model.joint_names.iter().filter(|j| !s.joints.contains_key(*j)).cloned().collect();
    if !missing.is_empty() {
        return Err(DescriptionError::MissingJoints {
            path: p(),
            what: "standing.joints".into(),
            missing,
        });
    }
    Ok(())
}

/// The standing configuration `q` (the model's convention), each joint within its limits.
fn standing_configuration(
    model: &Model,
    s: &StandingSection,
    path: &Path,
) -> Result<DVector<f64>, DescriptionError> {
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
        let (lo, hi) =
            (model.lower_position_limit[qbase + k], model.upper_position_limit[qbase + k]);
        if value < lo - 1e-9 || value > hi + 1e-9 {
            return Err(DescriptionError::Invalid {
                path: path.to_path_buf(),
                what: format!(
                    "standing.joints.{name} = {value} is outside the joint limits [{lo}, {hi}]"
                ),
            });
        }
        standing_q[qbase + k] = value;
    }
    Ok(standing_q)
}

/// The hand frame at the standing configuration, relative to the root link, against what the
/// description says.
fn check_standing_hand(
    model: &Model,
    standing_q: &DVector<f64>,
    hand: &str,
    s: &StandingSection,
    path: &Path,
) -> Result<(), DescriptionError> {
    use nalgebra::{Quaternion, Rotation3, UnitQuaternion, Vector3};
    let fk_err = |e: DynamicsError| DescriptionError::Invalid {
        path: path.to_path_buf(),
        what: format!("forward kinematics at the standing configuration: {e}"),
    };
    let mut data = Data::new(model);
    let v = vec![0.0; model.nv];
    forward_kinematics(model, &mut data, standing_q.as_slice(), &v).map_err(fk_err)?;
    let id = model.frame_id(hand).map_err(|_| DescriptionError::UnknownFrame {
        path: path.to_path_buf(),
        what: "frames.hand".into(),
        frame: hand.to_string(),
    })?;
    let hand_w = *frame_placement(model, &data, id).map_err(fk_err)?;
    // The root link's pose in the world: the floating base's (position, quaternion) or identity.
    let (base_rot, base_pos) = if model.floating_base {
        let q = standing_q.as_slice();
        let uq = UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[4], q[5], q[6]));
        (uq.to_rotation_matrix().into_inner(), Vector3::new(q[0], q[1], q[2]))
    } else {
        (nalgebra::Matrix3::identity(), Vector3::zeros())
    };
    let rel_pos = base_rot.transpose() * (hand_w.trans - base_pos);
    let rel_rot = Rotation3::from_matrix_unchecked(base_rot.transpose() * hand_w.rot);
    let actual_q = UnitQuaternion::from_rotation_matrix(&rel_rot);
    let o = s.hand_orientation;
    let said_q = UnitQuaternion::from_quaternion(Quaternion::new(o[0], o[1], o[2], o[3]));
    let said_p = Vector3::from(s.hand_position);
    let distance = (rel_pos - said_p).norm();
    let angle = said_q.angle_to(&actual_q);
    if distance <= HAND_POSITION_TOLERANCE && angle.to_degrees() <= HAND_ANGLE_TOLERANCE_DEG {
        return Ok(());
    }
    let aq = actual_q.quaternion();
    Err(DescriptionError::HandPose(Box::new(HandPoseMismatch {
        path: path.to_path_buf(),
        frame: hand.to_string(),
        position: s.hand_position,
        orientation: s.hand_orientation,
        actual_position: [rel_pos.x, rel_pos.y, rel_pos.z],
        actual_orientation: [aq.w, aq.i, aq.j, aq.k],
        distance_mm: distance * 1e3,
        angle_deg: angle.to_degrees(),
    })))
}
