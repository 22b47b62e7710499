//! The messages. Every one starts with a [`Header`]; every one implements [`Validate`].
//!
//! Per-robot vectors of joints are in the robot's **velocity order** of actuated joints as its
//! [`RobotDescription::joint_names`] lists them; generalized vectors (`nv` long) put the six
//! base coordinates first (see [`crate::conventions`]).

use serde::{Deserialize, Serialize};

use crate::validate::{
    check_finite, check_len, check_rotation, check_unit_quaternion, validate_id, Validate,
};
use crate::{Matrix, ProtocolError, PROTOCOL_VERSION};

/// Carried by every message.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct Header {
    /// [`PROTOCOL_VERSION`] of the sender.
    pub version: u16,
    /// Team identifier.
    pub team: String,
    /// Robot identifier, where the message concerns one robot.
    pub robot: Option<String>,
    /// Control tick the message belongs to.
    pub tick: u64,
    /// Sender's clock when the message was made, nanoseconds (simulated or wall time; the
    /// components of a team share one clock source, see the README).
    pub stamp_ns: u64,
}

impl Header {
    pub fn new(team: &str, robot: Option<&str>, tick: u64, stamp_ns: u64) -> Self {
        Header {
            version: PROTOCOL_VERSION,
            team: team.to_string(),
            robot: robot.map(str::to_string),
            tick,
            stamp_ns,
        }
    }

    fn check(&self, needs_robot: bool) -> Result<(), ProtocolError> {
        if self.version != PROTOCOL_VERSION {
            return Err(ProtocolError::VersionMismatch {
                found: self.version,
                expected: PROTOCOL_VERSION,
            });
        }
        validate_id("team", &self.team)?;
        match (&self.robot, needs_robot) {
            (Some(r), _) => validate_id("robot", r),
            (None, true) => Err(ProtocolError::invalid("header.robot", "missing robot id")),
            (None, false) => Ok(()),
        }
    }

    /// The robot id; only call on messages whose validation requires one.
    pub fn robot_id(&self) -> &str {
        self.robot.as_deref().unwrap_or("")
    }
}

/// A pose: position in the world and orientation `(w, x, y, z)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct Pose {
    pub position: [f64; 3],
    pub orientation: [f64; 4],
}

impl Pose {
    pub const IDENTITY: Pose = Pose { position: [0.0; 3], orientation: [1.0, 0.0, 0.0, 0.0] };

    fn check(&self, field: &str) -> Result<(), ProtocolError> {
        check_finite(&format!("{field}.position"), &self.position)?;
        check_unit_quaternion(&format!("{field}.orientation"), &self.orientation)
    }
}

// ---------------------------------------------------------------------------------------------
// State source -> agent

/// One robot's measured state at a tick (docs/architecture.md, one tick, step 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct RobotState {
    pub header: Header,
    /// Base position (world) and orientation `(w, x, y, z)`.
    pub base_pose: Pose,
    /// Base twist `[v; omega]`, both in the base frame (the protocol's convention).
    pub base_twist: [f64; 6],
    /// Joint positions, velocity order.
    pub joint_positions: Vec<f64>,
    /// Joint velocities, velocity order.
    pub joint_velocities: Vec<f64>,
    /// Simulated (or hardware) time of the measurement, seconds.
    pub time: f64,
    /// Measured normal contact force of each foot, N, in the description's foot order (the
    /// simulator's contact forces, or a real robot's foot sensors); empty when the robot does
    /// not measure them. The agent confirms a touchdown with it ([`ContactSet`]).
    pub foot_forces: Vec<f64>,
    /// The held object's pose as the robot measures it (motion capture or a camera; the
    /// simulator gives MuJoCo's), `None` when it does not. The coordinator re-fits its grasp
    /// model to it when the palms have slid on the object.
    #[serde(default)]
    pub object_pose: Option<Pose>,
}

impl Validate for RobotState {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(true)?;
        self.base_pose.check("base_pose")?;
        check_finite("base_twist", &self.base_twist)?;
        check_finite("joint_positions", &self.joint_positions)?;
        check_len("joint_velocities", &self.joint_velocities, self.joint_positions.len())?;
        check_finite("joint_velocities", &self.joint_velocities)?;
        check_finite("time", &[self.time])?;
        if self.foot_forces.len() > MAX_CONTACT_FEET {
            return Err(ProtocolError::invalid(
                "foot_forces",
                format!("{} feet, at most {MAX_CONTACT_FEET} are accepted", self.foot_forces.len()),
            ));
        }
        check_finite("foot_forces", &self.foot_forces)?;
        if let Some(f) = self.foot_forces.iter().find(|f| **f < 0.0) {
            return Err(ProtocolError::invalid(
                "foot_forces",
                format!("a normal force of {f} N (it pushes, >= 0)"),
            ));
        }
        self.object_pose.map_or(Ok(()), |p| p.check("object_pose"))
    }
}

// ---------------------------------------------------------------------------------------------
// Agent -> coordinator

/// What a frame is for in the team problem.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub enum FrameRole {
    /// A point foot in stance: 3 contact constraints.
    StanceFoot,
    /// A foot in swing: a 3-D position task.
    SwingFoot,
    /// The flat hand: 6 constraints when in grasp.
    Hand,
    /// The torso: a 6-D pose task.
    Torso,
}

impl FrameRole {
    /// Rows of this frame's Jacobian: 3 for point feet, 6 otherwise.
    pub const fn dim(self) -> usize {
        match self {
            FrameRole::StanceFoot | FrameRole::SwingFoot => 3,
            FrameRole::Hand | FrameRole::Torso => 6,
        }
    }
}

/// Kinematic terms of one frame: pose, Jacobian and `Jdot*v`, at the frame origin with
/// world-aligned axes, rows `[linear; angular]` (only linear rows for point feet).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct FrameTerms {
    pub name: String,
    pub role: FrameRole,
    pub position: [f64; 3],
    /// Rotation of the frame in the world, row-major.
    pub rotation: [f64; 9],
    /// `role.dim() x nv`.
    pub jacobian: Matrix,
    /// `role.dim()` entries: the frame's acceleration at zero generalized acceleration.
    pub jdot_v: Vec<f64>,
}

/// A robot's dynamics terms at a tick (docs/architecture.md, one tick, step 2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct DynamicsTerms {
    pub header: Header,
    /// Whether the first 6 generalized coordinates are an unactuated floating base
    /// (the selection matrix S of the paper); the remaining `nv - 6` are actuated joints.
    pub floating_base: bool,
    /// Generalized velocity dimension (6 + joints for a floating base).
    pub nv: u32,
    /// Mass matrix `M(q)`, `nv x nv`.
    pub mass_matrix: Matrix,
    /// Bias `h(q, v) = C(q, v) v + g(q)`, `nv` entries.
    pub bias: Vec<f64>,
    /// The generalized velocity the terms were computed at, `nv` entries.
    pub velocity: Vec<f64>,
    /// The frames the team problem uses this tick: stance feet, swing feet, hand, torso.
    pub frames: Vec<FrameTerms>,
    /// Whether the hand is in the grasp (its 6 constraints are active).
    pub hand_in_grasp: bool,
    /// Tick of the state the terms were computed from.
    pub state_tick: u64,
    /// The team's delay this robot asks for, state ticks (at most [`MAX_TEAM_DELAY_TICKS`]):
    /// its configured delay, or the one its measured latency needs. The coordinator sends the
    /// largest its tick's robots ask for with every command ([`TorqueCommand::delay_ticks`]).
    pub team_delay_ticks: u64,
    /// The held object's pose measured with the state of `state_tick`
    /// ([`RobotState::object_pose`]), `None` when the robot does not measure it.
    #[serde(default)]
    pub object_pose: Option<Pose>,
}

/// The longest team delay, state ticks ([`DynamicsTerms::team_delay_ticks`],
/// [`TorqueCommand::delay_ticks`]).
pub const MAX_TEAM_DELAY_TICKS: u64 = 8;

impl DynamicsTerms {
    pub fn nv(&self) -> usize {
        self.nv as usize
    }

    /// Number of actuated joints: `nv - 6` with a floating base, `nv` without.
    pub fn actuated(&self) -> usize {
        self.nv().saturating_sub(if self.floating_base { 6 } else { 0 })
    }

    /// Frames with the given role, in message order.
    pub fn frames_with(&self, role: FrameRole) -> impl Iterator<Item = &FrameTerms> {
        self.frames.iter().filter(move |f| f.role == role)
    }
}

impl Validate for DynamicsTerms {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(true)?;
        let nv = self.nv();
        if nv == 0 || (self.floating_base && nv <= 6) {
            return Err(ProtocolError::invalid(
                "nv",
                format!("{nv} degrees of freedom leave no actuated joint"),
            ));
        }
        self.mass_matrix.check("mass_matrix", Some(nv), Some(nv))?;
        check_len("bias", &self.bias, nv)?;
        check_finite("bias", &self.bias)?;
        check_len("velocity", &self.velocity, nv)?;
        check_finite("velocity", &self.velocity)?;
        let mut hands = 0;
        let mut torsos = 0;
        for (i, f) in self.frames.iter().enumerate() {
            let field = format!("frames[{i}]({})", f.name);
            if f.name.is_empty() {
                return Err(ProtocolError::invalid(field, "empty frame name"));
            }
            check_finite(&format!("{field}.position"), &f.position)?;
            check_rotation(&format!("{field}.rotation"), &f.rotation)?;
            f.jacobian.check(&format!("{field}.jacobian"), Some(f.role.dim()), Some(nv))?;
            check_len(&format!("{field}.jdot_v"), &f.jdot_v, f.role.dim())?;
            check_finite(&format!("{field}.jdot_v"), &f.jdot_v)?;
            if self.frames[..i].iter().any(|g| g.name == f.name && g.role == f.role) {
                return Err(ProtocolError::invalid(field, "frame listed twice"));
            }
            hands += (f.role == FrameRole::Hand) as usize;
            torsos += (f.role == FrameRole::Torso) as usize;
        }
        if hands > 1 || torsos > 1 {
            return Err(ProtocolError::invalid(
                "frames",
                "at most one hand and one torso per robot",
            ));
        }
        if self.hand_in_grasp && hands == 0 {
            return Err(ProtocolError::invalid(
                "hand_in_grasp",
                "hand in grasp but no hand frame sent",
            ));
        }
        check_delay(self.team_delay_ticks)?;
        self.object_pose.map_or(Ok(()), |p| p.check("object_pose"))
    }
}

// ---------------------------------------------------------------------------------------------
// Coordinator -> agent -> torque sink

/// Joint torques for one robot's actuated joints, velocity order (docs/architecture.md, one
/// tick, step 3); or, from the coordinator, the order to hold posture this tick.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct TorqueCommand {
    pub header: Header,
    /// One torque per actuated joint, N·m (or N for prismatic joints); empty when `hold`.
    pub tau: Vec<f64>,
    /// The coordinator has no torque for this robot this tick (its controller failed the
    /// tick): the robot applies its own posture-hold torque for the tick. A robot is never
    /// left without a command for a tick whose terms the coordinator has.
    pub hold: bool,
    /// The team's delay: the command applies at the state of tick `header.tick` +
    /// `delay_ticks` (at most [`MAX_TEAM_DELAY_TICKS`]). The same for every robot of a tick.
    pub delay_ticks: u64,
    /// What `tau` accelerates the actuated joints by, rad/s² (m/s²), as the coordinator's
    /// model of the team computes it: one per torque, or empty (a hold order, a controller
    /// that does not model it). With drive gains the robot's drives follow a trajectory at
    /// these accelerations until the next command ([`DriveCommand::qdd_des`]).
    #[serde(default)]
    pub qdd: Vec<f64>,
}

impl TorqueCommand {
    /// The order to hold posture at `tick`.
    pub fn hold(team: &str, robot: &str, tick: u64) -> Self {
        TorqueCommand {
            header: Header::new(team, Some(robot), tick, 0),
            tau: Vec::new(),
            hold: true,
            delay_ticks: 0,
            qdd: Vec::new(),
        }
    }
}

fn check_delay(ticks: u64) -> Result<(), ProtocolError> {
    if ticks > MAX_TEAM_DELAY_TICKS {
        return Err(ProtocolError::invalid(
            "team delay",
            format!("{ticks} ticks: at most {MAX_TEAM_DELAY_TICKS}"),
        ));
    }
    Ok(())
}

impl Validate for TorqueCommand {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(true)?;
        check_delay(self.delay_ticks)?;
        if self.hold {
            if !self.tau.is_empty() {
                return Err(ProtocolError::invalid("tau", "a hold command carries no torques"));
            }
            if !self.qdd.is_empty() {
                return Err(ProtocolError::invalid(
                    "qdd",
                    "a hold command carries no accelerations",
                ));
            }
            return Ok(());
        }
        if self.tau.is_empty() {
            return Err(ProtocolError::invalid("tau", "empty torque vector"));
        }
        if !self.qdd.is_empty() && self.qdd.len() != self.tau.len() {
            return Err(ProtocolError::invalid(
                "qdd",
                format!("{} accelerations for {} torques", self.qdd.len(), self.tau.len()),
            ));
        }
        check_finite("tau", &self.tau)?;
        check_finite("qdd", &self.qdd)
    }
}

/// What a robot's drives execute at every drive step until the next command (agent → drives,
/// the `torque` key): per actuated joint, velocity order,
/// `tau = tau_ff + kp (q_des - q) + kd (qd_des - qd)` ([`DriveCommand::effort`]), which the
/// drive clamps to its torque limit. The common low-level command of torque-controlled legs and
/// arms, and ros2_control's effort-plus-position interfaces. Without gains (`kp` and `kd` empty)
/// it is the torque `tau_ff`; a command late from the team leaves the drives following the last
/// one, never a stale constant torque when it has gains.
///
/// The targets may be a short trajectory rather than a point: with `ref_time` they are the
/// joints' state at that time of the robot's clock (`RobotState::time`), which the drives carry
/// forward at every drive step along `qdd_des` ([`DriveCommand::targets_at`]), as a vendor's
/// low-level interface interpolates between packets. Then the drives need nothing from the agent
/// between two commands of the team. `valid_until` is the last time the sender vouches for the
/// command: a drive step after it has no valid command (a drive gap), and the drives hold the
/// trajectory's last point instead of carrying it on.
#[derive(Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct DriveCommand {
    /// Its tick: the state tick it answers.
    pub header: Header,
    /// Feed-forward torque, N·m (N for prismatic joints), one per actuated joint.
    pub tau_ff: Vec<f64>,
    /// Position target, rad (m); as many as `kp`.
    pub q_des: Vec<f64>,
    /// Velocity target, rad/s (m/s); as many as `kd`.
    pub qd_des: Vec<f64>,
    /// Stiffness, N·m/rad, non-negative; empty, or one per joint.
    pub kp: Vec<f64>,
    /// Damping, N·m·s/rad, non-negative; empty, or one per joint.
    pub kd: Vec<f64>,
    /// The time the targets are at, s of the robot's clock; none: the targets are constant.
    pub ref_time: Option<f64>,
    /// Acceleration the targets are carried with from `ref_time`, rad/s² (m/s²); empty (none),
    /// or as many as `kd`.
    pub qdd_des: Vec<f64>,
    /// The last time the command is valid, s of the robot's clock; none: until the next one.
    pub valid_until: Option<f64>,
}

/// `clone_from` reuses the vectors' storage: a drive that keeps the last command copies each new
/// one of the same size without allocating.
impl Clone for DriveCommand {
    fn clone(&self) -> Self {
        DriveCommand {
            header: self.header.clone(),
            tau_ff: self.tau_ff.clone(),
            q_des: self.q_des.clone(),
            qd_des: self.qd_des.clone(),
            kp: self.kp.clone(),
            kd: self.kd.clone(),
            ref_time: self.ref_time,
            qdd_des: self.qdd_des.clone(),
            valid_until: self.valid_until,
        }
    }

    fn clone_from(&mut self, src: &Self) {
        self.header.version = src.header.version;
        self.header.team.clone_from(&src.header.team);
        self.header.robot.clone_from(&src.header.robot);
        self.header.tick = src.header.tick;
        self.header.stamp_ns = src.header.stamp_ns;
        self.tau_ff.clone_from(&src.tau_ff);
        self.q_des.clone_from(&src.q_des);
        self.qd_des.clone_from(&src.qd_des);
        self.kp.clone_from(&src.kp);
        self.kd.clone_from(&src.kd);
        self.ref_time = src.ref_time;
        self.qdd_des.clone_from(&src.qdd_des);
        self.valid_until = src.valid_until;
    }
}

impl DriveCommand {
    /// The torque `tau_ff` at `tick`, with no gains.
    pub fn torque(team: &str, robot: &str, tick: u64, tau: Vec<f64>) -> Self {
        DriveCommand {
            header: Header::new(team, Some(robot), tick, 0),
            tau_ff: tau,
            q_des: Vec::new(),
            qd_des: Vec::new(),
            kp: Vec::new(),
            kd: Vec::new(),
            ref_time: None,
            qdd_des: Vec::new(),
            valid_until: None,
        }
    }

    /// Whether it has gains (else the drives apply `tau_ff` as it is).
    pub fn has_gains(&self) -> bool {
        !self.kp.is_empty() || !self.kd.is_empty()
    }

    /// Whether the command is past its `valid_until` at robot time `t`.
    pub fn expired(&self, t: f64) -> bool {
        self.valid_until.is_some_and(|end| t > end)
    }

    /// Joint `j`'s position and velocity targets at robot time `t`: `q_des`, `qd_des` carried
    /// from `ref_time` along `qdd_des` (`q + qd s + a s^2 / 2`, `qd + a s` with `s = t -
    /// ref_time`, not before `ref_time`), up to `valid_until`, after which the targets stay at
    /// the trajectory's last position with no velocity. Constant targets without `ref_time`.
    pub fn targets_at(&self, j: usize, t: f64) -> (Option<f64>, Option<f64>) {
        let (q, qd) = (self.q_des.get(j).copied(), self.qd_des.get(j).copied());
        let Some(t0) = self.ref_time else { return (q, qd) };
        let end = self.valid_until.unwrap_or(f64::INFINITY);
        let s = (t.min(end) - t0).max(0.0);
        let (v, a) = (qd.unwrap_or(0.0), self.qdd_des.get(j).copied().unwrap_or(0.0));
        let q = q.map(|q| q + v * s + 0.5 * a * s * s);
        let qd = if t > end { qd.map(|_| 0.0) } else { qd.map(|v| v + a * s) };
        (q, qd)
    }

    /// The drive law at robot time `t` and joint positions `q` and velocities `qd` (the
    /// actuated joints', velocity order), into `out`: `tau_ff + kp (q_des(t) - q) + kd (qd_des(t)
    /// - qd)` ([`DriveCommand::targets_at`]), before the drive's clamp. The sizes are the
    /// command's (checked by [`Validate`]); `q`, `qd` and `out` must have as many entries as
    /// `tau_ff`.
    pub fn effort(&self, t: f64, q: &[f64], qd: &[f64], out: &mut [f64]) {
        for (j, o) in out.iter_mut().enumerate().take(self.tau_ff.len()) {
            let mut tau = self.tau_ff[j];
            let (qs, qds) = self.targets_at(j, t);
            if let (Some(kp), Some(qs)) = (self.kp.get(j), qs) {
                tau += kp * (qs - q[j]);
            }
            if let (Some(kd), Some(qds)) = (self.kd.get(j), qds) {
                tau += kd * (qds - qd[j]);
            }
            *o = tau;
        }
    }
}

impl Validate for DriveCommand {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(true)?;
        let n = self.tau_ff.len();
        if n == 0 {
            return Err(ProtocolError::invalid("tau_ff", "empty torque vector"));
        }
        check_finite("tau_ff", &self.tau_ff)?;
        for (gain, target, gname, tname) in
            [(&self.kp, &self.q_des, "kp", "q_des"), (&self.kd, &self.qd_des, "kd", "qd_des")]
        {
            if !gain.is_empty() && gain.len() != n {
                return Err(ProtocolError::invalid(
                    gname,
                    format!("{} gains for {n} joints", gain.len()),
                ));
            }
            if target.len() != gain.len() {
                return Err(ProtocolError::invalid(
                    tname,
                    format!("{} targets for {} gains", target.len(), gain.len()),
                ));
            }
            check_finite(gname, gain)?;
            check_finite(tname, target)?;
            if let Some(j) = gain.iter().position(|g| *g < 0.0) {
                return Err(ProtocolError::invalid(
                    gname,
                    format!("joint {j}: {} is negative", gain[j]),
                ));
            }
        }
        self.check_trajectory()
    }
}

impl DriveCommand {
    /// `ref_time`, `qdd_des` and `valid_until`: finite, sized as `kd`, the end not before the
    /// start.
    fn check_trajectory(&self) -> Result<(), ProtocolError> {
        if !self.qdd_des.is_empty() && self.qdd_des.len() != self.kd.len() {
            return Err(ProtocolError::invalid(
                "qdd_des",
                format!("{} accelerations for {} gains", self.qdd_des.len(), self.kd.len()),
            ));
        }
        if !self.qdd_des.is_empty() && self.ref_time.is_none() {
            return Err(ProtocolError::invalid("qdd_des", "accelerations without ref_time"));
        }
        check_finite("qdd_des", &self.qdd_des)?;
        for (name, t) in [("ref_time", self.ref_time), ("valid_until", self.valid_until)] {
            if t.is_some_and(|t| !t.is_finite()) {
                return Err(ProtocolError::invalid(name, "not finite"));
            }
        }
        if let (Some(t0), Some(end)) = (self.ref_time, self.valid_until) {
            if end < t0 {
                return Err(ProtocolError::invalid(
                    "valid_until",
                    format!("{end} s is before ref_time {t0} s"),
                ));
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Scenario runner -> coordinator

/// Desired pose, twist and acceleration of a 6-D task (object, torso).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct PoseReference {
    pub pose: Pose,
    /// `[v; omega]` in the world frame.
    pub twist: [f64; 6],
    /// `[a; alpha]` in the world frame.
    pub acceleration: [f64; 6],
}

impl PoseReference {
    fn check(&self, field: &str) -> Result<(), ProtocolError> {
        self.pose.check(&format!("{field}.pose"))?;
        check_finite(&format!("{field}.twist"), &self.twist)?;
        check_finite(&format!("{field}.acceleration"), &self.acceleration)
    }
}

/// Desired position, velocity and acceleration of a 3-D task (swing foot).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct PointReference {
    pub position: [f64; 3],
    pub velocity: [f64; 3],
    pub acceleration: [f64; 3],
}

/// A torso reference for one robot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct TorsoReference {
    pub robot: String,
    pub reference: PoseReference,
}

/// A swing-foot reference for one robot's foot frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct SwingFootReference {
    pub robot: String,
    pub frame: String,
    pub reference: PointReference,
}

/// An upper bound on a stance foot's normal force, N: the ramp that unloads a foot before it
/// lifts off (the gait planner sends it; the controller's QP keeps the foot's normal force at
/// most `max_normal_force`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct FootLoad {
    pub robot: String,
    pub frame: String,
    pub max_normal_force: f64,
}

/// Task references for a tick: the object, each torso, each swing foot, and the stance feet
/// being unloaded. A swing-foot reference is used while the robot's contact set has that foot
/// in swing; references of feet in stance are ignored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct TaskReferences {
    pub header: Header,
    pub object: Option<PoseReference>,
    pub torsos: Vec<TorsoReference>,
    pub swing_feet: Vec<SwingFootReference>,
    /// Unloading ramps of stance feet (empty when no foot is about to lift off).
    #[serde(default)]
    pub foot_loads: Vec<FootLoad>,
}

impl Validate for TaskReferences {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(false)?;
        if let Some(o) = &self.object {
            o.check("object")?;
        }
        for (i, t) in self.torsos.iter().enumerate() {
            validate_id("robot", &t.robot)?;
            t.reference.check(&format!("torsos[{i}]"))?;
        }
        for (i, s) in self.swing_feet.iter().enumerate() {
            validate_id("robot", &s.robot)?;
            let f = format!("swing_feet[{i}]");
            check_finite(&format!("{f}.position"), &s.reference.position)?;
            check_finite(&format!("{f}.velocity"), &s.reference.velocity)?;
            check_finite(&format!("{f}.acceleration"), &s.reference.acceleration)?;
        }
        for (i, l) in self.foot_loads.iter().enumerate() {
            validate_id("robot", &l.robot)?;
            let f = format!("foot_loads[{i}].max_normal_force");
            check_finite(&f, &[l.max_normal_force])?;
            if l.max_normal_force < 0.0 {
                return Err(ProtocolError::invalid(
                    f,
                    format!("{} N: a bound on a pushing force is >= 0", l.max_normal_force),
                ));
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Tools -> sim-bridge

/// What an external wrench acts on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub enum PerturbationTarget {
    /// The carried object, at its centre of mass.
    Object,
    /// A body of a robot, at the body's origin.
    RobotBody { robot: String, body: String },
}

/// A timed external wrench `[force; moment]` in the world frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct PerturbationRequest {
    pub header: Header,
    pub target: PerturbationTarget,
    pub wrench: [f64; 6],
    /// Simulated start time, s; `None` means as soon as received.
    pub start: Option<f64>,
    /// Duration, s (> 0).
    pub duration: f64,
}

impl Validate for PerturbationRequest {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(false)?;
        if let PerturbationTarget::RobotBody { robot, body } = &self.target {
            validate_id("robot", robot)?;
            if body.is_empty() {
                return Err(ProtocolError::invalid("target.body", "empty body name"));
            }
        }
        check_finite("wrench", &self.wrench)?;
        if let Some(s) = self.start {
            check_finite("start", &[s])?;
        }
        if !(self.duration.is_finite() && self.duration > 0.0) {
            return Err(ProtocolError::invalid(
                "duration",
                format!("{} is not a positive duration", self.duration),
            ));
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Status and diagnostics

/// What the coordinator is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub enum CoordinatorMode {
    /// Not all expected members are present.
    WaitingForMembers,
    /// Solving the team problem every tick.
    Running,
    /// The last tick used the fallback (see [`QpStatus`]).
    Fallback,
    /// The team let go of the object it could not hold: the hands are free, the feet carry
    /// the robots. A planner stops moving the team (a walk halts at once before a lift-off,
    /// else at its next quiet point);
    /// the mode stays until the hands are in a grasp again.
    Released,
}

/// Outcome of the contact-force QP of a tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub enum QpStatus {
    Solved,
    AlmostSolved,
    Infeasible,
    MaxIterations,
    NumericalError,
    /// No QP this tick (e.g. placeholder controller, or missing members).
    NotRun,
}

/// The coordinator's status, published every tick.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct CoordinatorStatus {
    pub header: Header,
    pub mode: CoordinatorMode,
    /// Present members (liveliness), sorted.
    pub members: Vec<String>,
    /// Ticks completed, commands sent, ticks that missed their deadline, fallbacks used.
    pub ticks: u64,
    pub commands_sent: u64,
    pub deadline_misses: u64,
    pub fallbacks: u64,
    /// Human-readable reason for the current mode.
    pub detail: String,
    /// Members whose terms the last solved tick took from an earlier tick (theirs were late),
    /// sorted.
    #[serde(default)]
    pub stale: Vec<String>,
    /// Members left out of the team: silent (alive, but no terms for longer than the
    /// coordinator reuses them), sorted.
    #[serde(default)]
    pub silent: Vec<String>,
    /// Members that joined a running team (or came back after a silence): they stand with
    /// their hand out of the grasp, sorted.
    #[serde(default)]
    pub late: Vec<String>,
    /// Terms reused in all (one per member per tick).
    #[serde(default)]
    pub reused_terms: u64,
    /// Messages the coordinator refused as they arrived (terms, descriptions, references):
    /// undecodable, out of range, or from another sender than their key's.
    #[serde(default)]
    pub refused: u64,
    /// The last refusal, naming the key and the reason.
    #[serde(default)]
    pub last_refusal: Option<String>,
}

impl Validate for CoordinatorStatus {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(false)?;
        for list in [&self.members, &self.stale, &self.silent, &self.late] {
            list.iter().try_for_each(|m| validate_id("robot", m))?;
        }
        Ok(())
    }
}

/// A predicted contact wrench of one contact of one robot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct ContactWrench {
    pub robot: String,
    pub frame: String,
    /// 3 entries (point foot force) or 6 (hand wrench `[f; m]`), world-aligned.
    pub wrench: Vec<f64>,
}

/// Per-tick diagnostics of the team controller.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct TickDiagnostics {
    pub header: Header,
    pub qp_status: QpStatus,
    pub qp_iterations: u32,
    pub qp_solve_us: f64,
    pub assembly_us: f64,
    pub total_us: f64,
    /// Predicted real contact wrenches lambda (eq. relation_between_lambda_and_Fc).
    pub contacts: Vec<ContactWrench>,
    /// `|J_c v|`: how far the measured motion violates the contact constraints.
    pub constraint_residual: f64,
    /// Object pose fitted to the hands.
    pub object_estimate: Option<Pose>,
    /// Largest distance of a hand from where the fitted object pose puts it, m (the
    /// controller's own slip signal; 0 without a grasp).
    pub grasp_slip: f64,
    /// How often the grasp model was re-fitted to the measured object since the run began.
    #[serde(default)]
    pub grasp_refits: u64,
    /// Largest distance a hand's contact point has moved on the object since the grasp closed,
    /// m (what the re-fits followed; 0 without a grasp).
    #[serde(default)]
    pub grasp_slip_since_closed: f64,
    /// Why this tick's command did not come from the controller's normal path (QP failed,
    /// controller error: what was sent instead); `None` on a normal tick.
    pub fallback: Option<String>,
    /// How much of their motion the object's and the torsos' tasks kept this tick when it had
    /// to yield (the contact forces could not carry the full motion, so the object's motion
    /// gave way first, then the torsos'); `None` when every task was tracked as commanded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub motion_yield: Option<MotionYield>,
}

/// The share of its commanded motion a task kept, from 0 (held still where it is) to 1.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct MotionYield {
    pub object: f64,
    pub torso: f64,
    /// Held still on the contact margins' reserve: nothing was feasible within the margins.
    #[serde(default)]
    pub reserve: bool,
}

impl TickDiagnostics {
    /// The diagnostics of `tick` before anything was solved: no QP run, no contacts, no
    /// object estimate, no fallback.
    pub fn empty(team: &str, tick: u64) -> Self {
        TickDiagnostics {
            header: Header::new(team, None, tick, 0),
            qp_status: QpStatus::NotRun,
            qp_iterations: 0,
            qp_solve_us: 0.0,
            assembly_us: 0.0,
            total_us: 0.0,
            contacts: Vec::new(),
            constraint_residual: 0.0,
            object_estimate: None,
            grasp_slip: 0.0,
            grasp_refits: 0,
            grasp_slip_since_closed: 0.0,
            fallback: None,
            motion_yield: None,
        }
    }
}

impl Validate for TickDiagnostics {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(false)?;
        check_finite(
            "timings",
            &[
                self.qp_solve_us,
                self.assembly_us,
                self.total_us,
                self.constraint_residual,
                self.grasp_slip,
            ],
        )?;
        if let Some(y) = self.motion_yield {
            if ![y.object, y.torso].iter().all(|s| (0.0..=1.0).contains(s)) {
                return Err(ProtocolError::Invalid {
                    field: "motion_yield".into(),
                    reason: format!("shares must lie in [0, 1], not {y:?}"),
                });
            }
        }
        for (i, c) in self.contacts.iter().enumerate() {
            validate_id("robot", &c.robot)?;
            if c.wrench.len() != 3 && c.wrench.len() != 6 {
                return Err(ProtocolError::dim(
                    format!("contacts[{i}].wrench"),
                    "3 or 6",
                    c.wrench.len(),
                ));
            }
            check_finite(&format!("contacts[{i}].wrench"), &c.wrench)?;
        }
        if let Some(p) = &self.object_estimate {
            p.check("object_estimate")?;
        }
        Ok(())
    }
}

/// What a robot-agent is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub enum AgentMode {
    /// No state received yet.
    WaitingForState,
    /// Applying the coordinator's commands.
    Commanded,
    /// No valid command in time: holding its posture locally.
    SafeMode,
    /// The robot fell (its torso tipped over or sank far below its standing height): it applies
    /// joint damping only, refuses commands and has left its team, until the agent is
    /// restarted.
    Fallen,
}

/// A robot-agent's status.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct AgentStatus {
    pub header: Header,
    pub mode: AgentMode,
    pub states_received: u64,
    pub dynamics_published: u64,
    pub commands_applied: u64,
    pub commands_rejected: u64,
    pub commands_clamped: u64,
    pub safe_mode_entries: u64,
    pub last_applied_tick: Option<u64>,
    /// Time from state received to dynamics published, last tick, µs.
    pub dynamics_latency_us: f64,
    /// Time from dynamics published to command received, last tick, µs.
    pub command_latency_us: f64,
    /// Reason of the last rejection, if any.
    pub last_rejection: Option<String>,
    /// The team's delay in use, state ticks: the team's command for the state of tick k
    /// applies at tick k + this (fixed, or raised from the measured latency).
    #[serde(default)]
    pub team_delay_ticks: u64,
}

impl Validate for AgentStatus {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(true)?;
        check_finite("latencies", &[self.dynamics_latency_us, self.command_latency_us])
    }
}

/// What the team needs to know of a robot, published once and on request.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct RobotDescription {
    pub header: Header,
    /// Actuated joints in velocity order.
    pub joint_names: Vec<String>,
    /// Symmetric torque limit of each actuated joint, > 0.
    pub torque_limits: Vec<f64>,
    /// Whether the robot has a 6-DoF floating base (unactuated).
    pub floating_base: bool,
    pub nq: u32,
    pub nv: u32,
    pub foot_frames: Vec<String>,
    pub hand_frame: String,
    pub torso_frame: String,
    /// Foot friction coefficient.
    pub foot_mu: f64,
    /// Hand friction coefficient, torsional friction coefficient xi and patch half-sizes
    /// (delta_x, delta_y) of eq. moment_constraint.
    pub hand_mu: f64,
    pub hand_xi: f64,
    pub hand_half_size: [f64; 2],
    pub total_mass: f64,
}

impl Validate for RobotDescription {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(true)?;
        let n = self.joint_names.len();
        check_len("torque_limits", &self.torque_limits, n)?;
        check_finite("torque_limits", &self.torque_limits)?;
        if let Some(i) = self.torque_limits.iter().position(|t| *t <= 0.0) {
            return Err(ProtocolError::invalid(format!("torque_limits[{i}]"), "must be positive"));
        }
        let base = if self.floating_base { 6 } else { 0 };
        if self.nv as usize != n + base {
            return Err(ProtocolError::dim("nv", n + base, self.nv));
        }
        check_finite(
            "contact parameters",
            &[
                self.foot_mu,
                self.hand_mu,
                self.hand_xi,
                self.hand_half_size[0],
                self.hand_half_size[1],
                self.total_mass,
            ],
        )?;
        // xi > 0 too: a hand's friction rows divide by it (sliding and torsion share one cone).
        if self.foot_mu <= 0.0
            || self.hand_mu <= 0.0
            || self.hand_xi <= 0.0
            || self.hand_half_size.iter().any(|d| *d <= 0.0)
        {
            return Err(ProtocolError::invalid(
                "contact parameters",
                "friction and patch sizes must be positive",
            ));
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Tools, scenario runner or gait planner -> agent

/// Longest accepted frame name in a [`ContactSet`].
pub const MAX_FRAME_NAME_LEN: usize = 128;

/// Most feet a [`ContactSet`] may name (bounds what a malformed message can make a receiver
/// look up).
pub const MAX_CONTACT_FEET: usize = 16;

/// Which contacts of a robot are closed from the state of tick `header.tick` on: the feet in
/// stance (the other feet of its description are in swing) and whether its hand holds the
/// object. Published on `team/{team}/robot/{robot}/contacts` (see [`crate::keys::contacts`]),
/// possibly ahead of time: the agent keeps a bounded schedule and applies each set at its tick.
/// It checks the names against its own description and refuses unknown feet. A foot that
/// leaves the stance lifts off at that tick (if enough feet stay on the ground); a foot that
/// joins it is in stance once its touchdown is confirmed by its measured normal force
/// (`RobotState::foot_forces`), which may be before or after its planned time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct ContactSet {
    pub header: Header,
    /// Foot frames in stance, each at most once.
    pub stance_feet: Vec<String>,
    /// Whether the hand is in the grasp (its 6 constraints are active).
    pub hand_in_grasp: bool,
}

impl Validate for ContactSet {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(true)?;
        if self.stance_feet.len() > MAX_CONTACT_FEET {
            return Err(ProtocolError::invalid(
                "stance_feet",
                format!("{} feet, at most {MAX_CONTACT_FEET} are accepted", self.stance_feet.len()),
            ));
        }
        for (i, f) in self.stance_feet.iter().enumerate() {
            let field = format!("stance_feet[{i}]");
            if f.is_empty() || f.len() > MAX_FRAME_NAME_LEN {
                return Err(ProtocolError::invalid(
                    field,
                    format!("frame name must have 1 to {MAX_FRAME_NAME_LEN} bytes"),
                ));
            }
            if !f.bytes().all(|b| b.is_ascii_graphic()) {
                return Err(ProtocolError::invalid(
                    field,
                    "frame name must be printable ASCII without spaces",
                ));
            }
        }
        crate::validate::check_unique("stance_feet", self.stance_feet.iter().map(String::as_str))
    }
}

// ---------------------------------------------------------------------------------------------
// Sim-bridge -> evaluation (ground truth; a controller never reads it)

/// A rigid body's pose and twist in the world: `twist = [v; omega]`, the linear velocity of the
/// body frame's origin and the angular velocity, **both in the world frame** (ground truth is for
/// evaluation, so it uses the world frame throughout).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct BodyTruth {
    /// `"object"`, or the robot id for a torso.
    pub name: String,
    pub pose: Pose,
    pub twist: [f64; 6],
}

/// Where a contact touches and what it transmits, world frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct ContactTruth {
    pub robot: String,
    /// The robot's body that touches (MuJoCo body name without the robot prefix).
    pub body: String,
    /// Contact point, world frame.
    pub position: [f64; 3],
    /// Wrench `[force; moment]` in the world frame about `position`: for a hand, what the hand
    /// applies to the object; for a foot, what the ground applies to the foot.
    pub wrench: [f64; 6],
}

/// Ground truth of one control tick, from the simulator: published on
/// `team/{team}/ground-truth` and recorded for reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct GroundTruth {
    pub header: Header,
    /// Simulated time, s.
    pub time: f64,
    pub object: Option<BodyTruth>,
    pub torsos: Vec<BodyTruth>,
    /// Every hand-object contact point (a flat palm on a box gives several).
    pub hand_contacts: Vec<ContactTruth>,
    /// Every foot-ground contact point.
    pub foot_contacts: Vec<ContactTruth>,
    /// Each robot's palm contact frame (named by robot id): where the hand is on the object
    /// (slip is measured from it).
    pub hands: Vec<BodyTruth>,
    /// Each robot's foot centres (named `{robot}/{foot frame}`, world-aligned, twist of the
    /// centre): foot heights and stance-foot slides of walks are measured from them.
    #[serde(default)]
    pub feet: Vec<BodyTruth>,
    /// The control loop as the bridge (the robots' drives) measured it on this tick, one entry
    /// per robot; empty in lockstep, where every tick waits for every torque.
    #[serde(default)]
    pub loop_timing: Vec<LoopTiming>,
}

/// One robot's control loop on one real-time tick, measured where the torques are applied (the
/// bridge; on hardware, the drive interface): a single clock, so no synchronisation is needed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct LoopTiming {
    pub robot: String,
    /// From this tick's state leaving to this tick's torques arriving, µs; `None` if they did
    /// not arrive by the tick's deadline (a deadline miss: the drive held `applied_tick`'s
    /// torques).
    pub latency_us: Option<f64>,
    /// Tick of the torques applied during this tick's step (the tick itself unless missed;
    /// `None` before any torques arrived).
    pub applied_tick: Option<u64>,
    /// Torques of earlier ticks that arrived while this tick waited (late messages).
    pub late: u32,
    /// Physics steps of this tick whose drives had no valid command (past its `valid_until`,
    /// or the drives lost for want of commands): drive gaps.
    #[serde(default)]
    pub gap_steps: u32,
}

impl Validate for GroundTruth {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.header.check(false)?;
        check_finite("time", &[self.time])?;
        let bodies = self
            .object
            .iter()
            .map(|b| ("object", b))
            .chain(self.torsos.iter().map(|b| ("torsos", b)))
            .chain(self.hands.iter().map(|b| ("hands", b)))
            .chain(self.feet.iter().map(|b| ("feet", b)));
        for (field, b) in bodies {
            if b.name.is_empty() {
                return Err(ProtocolError::invalid(field, "empty body name"));
            }
            b.pose.check(&format!("{field}({}).pose", b.name))?;
            check_finite(&format!("{field}({}).twist", b.name), &b.twist)?;
        }
        for t in self.torsos.iter().chain(&self.hands) {
            validate_id("robot", &t.name)?;
        }
        for t in &self.loop_timing {
            validate_id("robot", &t.robot)?;
            if let Some(l) = t.latency_us {
                if !(l.is_finite() && l >= 0.0) {
                    return Err(ProtocolError::invalid(
                        format!("loop_timing({}).latency_us", t.robot),
                        "must be finite and non-negative",
                    ));
                }
            }
            if t.applied_tick.is_some_and(|a| a > self.header.tick) {
                return Err(ProtocolError::invalid(
                    format!("loop_timing({}).applied_tick", t.robot),
                    "is after the tick",
                ));
            }
        }
        for (field, list) in
            [("hand_contacts", &self.hand_contacts), ("foot_contacts", &self.foot_contacts)]
        {
            for (i, c) in list.iter().enumerate() {
                validate_id("robot", &c.robot)?;
                check_finite(&format!("{field}[{i}].position"), &c.position)?;
                check_finite(&format!("{field}[{i}].wrench"), &c.wrench)?;
            }
        }
        Ok(())
    }
}
