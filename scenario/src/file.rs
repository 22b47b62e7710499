//! Scenario files: the robots and their poses, the object, the references, the gains per task,
//! the perturbations, duration, rates and seed (`docs/scenarios.md`). Every number is a parameter,
//! and `--set key=value` overrides any of them: `key` is a dotted path into the TOML
//! (`gains.object.stiffness`, `robots.1.base_position`, `duration`), `value` a TOML value
//! (`12.5`, `[1, 2, 3]`, `"pidc"`).
//!
//! `controller` is the kind of the team controller (`"pidc"`, the default; the kinds are the
//! coordinator's, [`coordinator::ControllerSpec::KINDS`]). `[walk]` makes robots walk a
//! static crawl along waypoints ([`WalkSpec`], planned by [`planner::gait`] and
//! [`planner::walk`]); without it every foot stays in stance.

use std::path::{Path, PathBuf};

use serde::Deserialize;
use thiserror::Error;

use planner::reference::PoseMotion;
use planner::walk::WalkSpec;
use robot_agent::delay::TeamDelay;

use crate::pace::Pacing;

/// What can be wrong with a scenario.
#[derive(Debug, Error)]
pub enum ScenarioError {
    #[error("cannot read scenario {path}: {reason}")]
    Io { path: PathBuf, reason: String },
    #[error("malformed scenario {path}: {reason}")]
    Toml { path: PathBuf, reason: String },
    #[error("--set {0:?}: expected key=value")]
    OverrideSyntax(String),
    #[error("--set {key}: {reason}")]
    Override { key: String, reason: String },
    #[error("scenario {path}: {reason}")]
    Invalid { path: PathBuf, reason: String },
}

/// A whole scenario.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// Scenario duration after settling, s.
    pub duration: f64,
    /// Time the team settles under the controller before the scenario clock starts, s.
    #[serde(default = "default_settle")]
    pub settle: f64,
    pub control_hz: f64,
    pub physics_hz: f64,
    pub seed: u64,
    /// Team controller, by kind (`pidc`; see [`coordinator::ControllerSpec`]).
    #[serde(default = "default_controller")]
    pub controller: String,
    /// Minimum normal force of every stance foot in the QP, N.
    #[serde(default = "default_min_foot_force")]
    pub min_foot_force: f64,
    /// Minimum normal force of every hand in the QP (the least squeeze), N.
    #[serde(default = "default_min_hand_force")]
    pub min_hand_force: f64,
    /// Share of each contact's friction the controller's QP may use (PIDC's
    /// `friction_margin`, in (0, 1]; 1/sqrt(2) inscribes a foot's pyramid in its cone; a hand's
    /// rows are carried by the palm up to 0.8, see `coordinator::qp::rows`).
    #[serde(default = "default_friction_margin")]
    pub friction_margin: f64,
    /// Share of the palm's half-sizes the centre of pressure may use (PIDC's `patch_margin`).
    #[serde(default = "default_patch_margin")]
    pub patch_margin: f64,
    /// Before the run, check that contact forces within the controller's limits hold the
    /// object at the start pose (`crate::payload`), and refuse the run when none do.
    /// `false` runs anyway (to watch a refused load).
    #[serde(default = "default_capacity_check")]
    pub capacity_check: bool,
    /// The share of the object's mass the payload check adds: the check is the team problem
    /// along the references, without the tracking errors, and MuJoCo tracks without yielding
    /// down to 0.7 % less than it in the runs measured (default 0.02, in [0, 1)).
    #[serde(default = "default_payload_margin")]
    pub payload_margin: f64,
    /// When the controller (PIDC or MQP) lets go of an object it cannot hold
    /// (`release.after_failed`: s of failed QPs in a row;
    /// `release.max_fit_residual`: m; 0 turns a limit off).
    #[serde(default)]
    pub release: coordinator::building_blocks::release::ReleasePolicy,
    pub object: ObjectSection,
    /// The robots, each with its floor pose; or, instead, `team`.
    #[serde(default)]
    pub robots: Vec<RobotSpec>,
    /// The robots laid out around the object's faces (`planner::placement::around_object`),
    /// named `r1`, `r2`, ... face by face; expanded into `robots` when the file is loaded.
    #[serde(default)]
    pub team: Option<TeamSpec>,
    pub gains: GainsSection,
    #[serde(default)]
    pub references: References,
    #[serde(default)]
    pub perturbations: Vec<PushSection>,
    /// MuJoCo's no-slip iterations (`sim_bridge::world::SolverParams::noslip_iterations`; 0:
    /// off). Default 20: without them a standing robot's feet creep.
    #[serde(default = "default_noslip")]
    pub noslip_iterations: u32,
    /// What the simulated robots measure besides their own state (`[sensors]`; by default
    /// the held object's pose too).
    #[serde(default)]
    pub sensors: sim_bridge::world::Sensors,
    /// Walking: who walks where, with which gait.
    #[serde(default)]
    pub walk: Option<WalkSpec>,
    /// Faults injected while the scenario runs (an agent that dies mid-carry).
    #[serde(default)]
    pub faults: Vec<Fault>,
    /// What a robot's drives do when its agent leaves, or (real time) when its torques stop
    /// for the drive timeout: `"unpowered"` (the default: the robot falls where it stands) or
    /// `"freeze"` (each joint held where it was: the robot stands, and a restarted agent can
    /// take it back).
    #[serde(default)]
    pub drive_loss: sim_bridge::plant::DriveLoss,
    /// The gains the agents send their drives with each command
    /// (`robot_agent::drive_gains`): `"none"` (the default: the drives apply the team's
    /// torque, the paper's loop) or `"inertia"` (per joint from its inertia: the drives hold
    /// the commanded state between team commands).
    #[serde(default)]
    pub drive_gains: robot_agent::drive_gains::DriveGainsMode,
    /// The team loop's rate, Hz: the coordinator solves every `control_hz / team_hz`-th tick
    /// (a whole number, 1 to [`MAX_TEAM_EVERY`]); the robots' own loop stays at `control_hz`
    /// and each agent answers the ticks between alone
    /// (`robot_agent::core::AgentConfig::team_every`).
    /// Default: `control_hz`, the paper's single loop. In real time the team loop is the only
    /// one on the network: its rate (default [`crate::pace::TEAM_HZ`]) becomes the control rate
    /// and the drives fill the physics steps between ([`crate::pace`]).
    #[serde(default)]
    pub team_hz: Option<f64>,
    /// The team's delay, in robot ticks (0 to `robot_agent::core::MAX_TEAM_DELAY`), or
    /// `"auto"`: the team's command for the state of tick k applies at tick k +
    /// `team_delay_ticks` (`robot_agent::core::AgentConfig::team_delay`), so that the team has
    /// that many robot periods to answer. `auto` starts at 0 and each agent raises it while
    /// commands come after the states they apply at (`robot_agent::delay`; in lockstep, which
    /// waits for every answer, it stays 0). Default 0: the command applies at its own state,
    /// the paper's loop.
    #[serde(default)]
    pub team_delay_ticks: TeamDelay,
    /// With a team delay, whether the coordinator carries each robot's state over the
    /// commands still in flight before it solves a tick (`coordinator::team::prediction`, a
    /// Smith predictor; PIDC only). Default `true`; `false` answers each state as measured,
    /// which shows what the delay alone costs.
    #[serde(default = "default_predict_delay")]
    pub predict_delay: bool,
}

/// The most robot ticks a team tick may span ([`Scenario::team_hz`]).
pub const MAX_TEAM_EVERY: u64 = 20;

/// A fault injected into a run, `at` s after the scenario clock starts
/// (`launch::faults`):
///
/// * `agent-stops`: robot `robot`'s agent dies (its task is stopped, or its process killed
///   with SIGKILL in the distributed modes); with `restart_after`, a new agent for the robot
///   starts that many seconds later and rejoins the team;
/// * `agent-stalls`: robot `robot`'s agent stays alive (its liveliness token holds) but
///   handles nothing for `duration` s (its task pauses; its process gets SIGSTOP, then SIGCONT);
/// * `coordinator-stops`: the coordinator dies; with `restart_after`, a new one starts that many
///   seconds later and takes the team back.
///
/// Meanwhile the simulated robot's drives do what the scenario's `drive_loss` says
/// (`sim_bridge::plant::DriveLoss`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Fault {
    pub kind: FaultKind,
    /// The robot whose agent fails (the agent kinds).
    #[serde(default)]
    pub robot: Option<String>,
    pub at: f64,
    /// Start the failed component again this many seconds after the fault.
    #[serde(default)]
    pub restart_after: Option<f64>,
    /// How long an `agent-stalls` fault lasts, s.
    #[serde(default)]
    pub duration: Option<f64>,
}

/// What fails.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// The robot's agent dies.
    AgentStops,
    /// The robot's agent is alive but silent.
    AgentStalls,
    /// The coordinator dies.
    CoordinatorStops,
}

impl Fault {
    /// The fault's robot, for the agent kinds.
    pub fn robot(&self) -> Option<&str> {
        self.robot.as_deref()
    }

    /// Whether the fault is consistent: a robot exactly for the agent kinds, a positive
    /// `duration` exactly for a stall, a positive `restart_after` only where a component dies.
    /// `i` names it in the error.
    fn check(&self, i: usize, robots: &[RobotSpec], scenario: f64) -> Result<(), String> {
        self.check_robot(i, robots)?;
        if !(self.at.is_finite() && self.at >= 0.0 && self.at < scenario) {
            return Err(format!(
                "faults[{i}].at = {} must be within the scenario's [0, {scenario}) s",
                self.at
            ));
        }
        let is_positive = |x: f64| x.is_finite() && x > 0.0;
        match (self.kind, self.duration, self.restart_after) {
            (FaultKind::AgentStalls, Some(d), None) if is_positive(d) => Ok(()),
            (FaultKind::AgentStalls, _, Some(_)) => Err(format!(
                "faults[{i}]: a stalled agent resumes by itself (give duration, not restart_after)"
            )),
            (FaultKind::AgentStalls, _, None) => {
                Err(format!("faults[{i}]: agent-stalls needs a positive duration, s"))
            }
            (_, Some(_), _) => Err(format!(
                "faults[{i}]: duration is for agent-stalls only \
                 (a component that stops comes back with restart_after)"
            )),
            (_, None, Some(r)) if !is_positive(r) => {
                Err(format!("faults[{i}].restart_after = {r} must be positive"))
            }
            _ => Ok(()),
        }
    }

    /// A known robot exactly for the agent kinds, none for the coordinator.
    fn check_robot(&self, i: usize, robots: &[RobotSpec]) -> Result<(), String> {
        let agent = matches!(self.kind, FaultKind::AgentStops | FaultKind::AgentStalls);
        match (&self.robot, agent) {
            (Some(r), true) if !robots.iter().any(|x| x.id == *r) => {
                Err(format!("faults[{i}] names unknown robot {r:?}"))
            }
            (None, true) => {
                Err(format!("faults[{i}] ({:?}) needs the robot whose agent fails", self.kind))
            }
            (Some(r), false) => Err(format!(
                "faults[{i}] (coordinator-stops) names robot {r:?}: \
                 the coordinator serves the whole team"
            )),
            _ => Ok(()),
        }
    }
}

fn default_noslip() -> u32 {
    sim_bridge::world::DEFAULT_NOSLIP_ITERATIONS
}

fn default_settle() -> f64 {
    1.0
}
impl Default for References {
    fn default() -> Self {
        References { ramp: default_ramp(), object: PoseMotion::default(), torsos: Vec::new() }
    }
}

fn default_ramp() -> f64 {
    1.0
}
fn default_controller() -> String {
    "pidc".into()
}
fn default_min_foot_force() -> f64 {
    5.0
}
fn default_min_hand_force() -> f64 {
    30.0
}
fn default_friction_margin() -> f64 {
    coordinator::PidcConfig::default().friction_margin
}
fn default_patch_margin() -> f64 {
    coordinator::PidcConfig::default().patch_margin
}
fn default_predict_delay() -> bool {
    true
}

fn default_capacity_check() -> bool {
    true
}

fn default_payload_margin() -> f64 {
    0.02
}

/// Top-level keys with a default that `--set` may give although the file leaves them out.
pub const OPTIONAL_KEYS: [&str; 17] = [
    "description",
    "settle",
    "controller",
    "min_foot_force",
    "min_hand_force",
    "friction_margin",
    "patch_margin",
    "capacity_check",
    "payload_margin",
    "perturbations",
    "noslip_iterations",
    "faults",
    "drive_loss",
    "drive_gains",
    "team_hz",
    "team_delay_ticks",
    "predict_delay",
];
/// Keys inside a table with a default that `--set` may give although the file leaves them
/// out (`--set team.spacing=0.7` on a layout of one robot per face).
pub const OPTIONAL_NESTED_KEYS: [&str; 6] = [
    "team.spacing",
    "team.standoff",
    "team.description",
    "walk.robots",
    "walk.frame",
    "walk.start",
];
/// Top-level tables a scenario may leave out that `--set` may still reach into
/// (`--set release.after_failed=0.05`, `--set references.ramp=0.5` on a walk); their own
/// fields are checked when the file is read.
pub const OPTIONAL_TABLES: [&str; 3] = ["release", "references", "sensors"];

/// The carried box (`[object]`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectSection {
    /// Full edge lengths, m.
    pub size: [f64; 3],
    pub mass: f64,
    pub friction: f64,
    /// Initial centre position, m (world).
    pub position: [f64; 3],
}

/// One robot of the team.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSpec {
    pub id: String,
    /// Robot description (TOML beside its URDF), relative to the repository root or absolute.
    pub description: PathBuf,
    /// Base position on the ground plane (x, y), m; the height comes from the standing pose.
    pub base_xy: [f64; 2],
    /// Heading about z, rad.
    pub yaw: f64,
}

/// A team laid out around the object: `per_face` robots on each of `faces` (`"+x"`, `"-x"`,
/// `"+y"`, `"-y"`: the object's vertical faces by outward normal), `spacing` m apart along a
/// face, each `standoff` m from its face.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TeamSpec {
    /// Every robot's description (default: the project's legged manipulator).
    #[serde(default = "default_description")]
    pub description: PathBuf,
    pub faces: Vec<planner::placement::Face>,
    pub per_face: usize,
    #[serde(default)]
    pub spacing: f64,
    #[serde(default = "default_standoff")]
    pub standoff: f64,
}

fn default_description() -> PathBuf {
    PathBuf::from("robot-model/models/legged_manipulator.toml")
}
fn default_standoff() -> f64 {
    planner::placement::DEFAULT_STANDOFF
}

impl TeamSpec {
    /// The robots of this layout around `object`.
    pub fn robots(&self, object: &ObjectSection) -> Result<Vec<RobotSpec>, String> {
        let layout = planner::placement::FaceLayout {
            faces: self.faces.clone(),
            per_face: self.per_face,
            spacing: self.spacing,
            standoff: self.standoff,
        };
        let poses =
            planner::placement::around_object(&crate::layout::object_box(&object.world()), &layout)
                .map_err(|e| e.to_string())?;
        Ok(poses
            .into_iter()
            .enumerate()
            .map(|(i, (base_xy, yaw))| RobotSpec {
                id: format!("r{}", i + 1),
                description: self.description.clone(),
                base_xy,
                yaw,
            })
            .collect())
    }
}

impl ObjectSection {
    /// The simulator's object: this box, world-aligned, a uniform inertia.
    pub fn world(&self) -> sim_bridge::world::ObjectSpec {
        sim_bridge::world::ObjectSpec {
            size: self.size,
            mass: self.mass,
            inertia: None,
            friction: [self.friction, 0.005, 0.0001],
            position: self.position,
            orientation: [1.0, 0.0, 0.0, 0.0],
        }
    }
}

/// Stiffness and damping of a task, per axis (`[x, y, z, rx, ry, rz]`, or 3 for feet).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaskGains {
    pub stiffness: Vec<f64>,
    pub damping: Vec<f64>,
}

/// Gains of every task kind (`[gains]`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GainsSection {
    pub object: TaskGains,
    pub torso: TaskGains,
    pub feet: Option<TaskGains>,
}

/// References about the settled initial poses.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct References {
    /// Every task's motion fades in over the first `ramp` seconds of the scenario (a smooth
    /// window), so that motions starting with a velocity do not step the reference velocity.
    #[serde(default = "default_ramp")]
    pub ramp: f64,
    #[serde(default)]
    pub object: PoseMotion,
    #[serde(default)]
    pub torsos: Vec<TorsoMotion>,
}

/// A torso's reference.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TorsoMotion {
    pub robot: String,
    #[serde(flatten)]
    pub motion: PoseMotion,
}

/// What a push acts on.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PushTarget {
    /// `object`, or a robot id.
    pub on: String,
    /// Body of the robot (ignored for the object).
    #[serde(default)]
    pub body: Option<String>,
}

/// A timed external wrench `[f; m]` in the world frame (an entry of `[[perturbations]]`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PushSection {
    #[serde(flatten)]
    pub target: PushTarget,
    /// Start, s after the scenario clock starts.
    pub start: f64,
    pub duration: f64,
    pub wrench: [f64; 6],
}

impl Scenario {
    /// Load a scenario file and apply `--set` overrides (`key=value`), for a lockstep run.
    pub fn load(path: impl AsRef<Path>, overrides: &[String]) -> Result<Scenario, ScenarioError> {
        Self::load_paced(path, overrides, Pacing::Lockstep)
    }

    /// Load a scenario file and apply `--set` overrides for a run at `pace`: a real-time run
    /// gets the real-time loop's defaults where the file and the overrides say nothing
    /// ([`crate::pace`]).
    pub fn load_paced(
        path: impl AsRef<Path>,
        overrides: &[String],
        pace: Pacing,
    ) -> Result<Scenario, ScenarioError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path)
            .map_err(|e| ScenarioError::Io { path: path.to_path_buf(), reason: e.to_string() })?;
        Self::from_str_paced(&text, path, overrides, pace)
    }

    /// Parse scenario text (named `path` in errors) and apply overrides, for a lockstep run.
    pub fn from_str_with(
        text: &str,
        path: &Path,
        overrides: &[String],
    ) -> Result<Scenario, ScenarioError> {
        Self::from_str_paced(text, path, overrides, Pacing::Lockstep)
    }

    /// Parse scenario text (named `path` in errors) and apply overrides, for a run at `pace`.
    pub fn from_str_paced(
        text: &str,
        path: &Path,
        overrides: &[String],
        pace: Pacing,
    ) -> Result<Scenario, ScenarioError> {
        let toml_err = |e: String| ScenarioError::Toml { path: path.to_path_buf(), reason: e };
        let mut value: toml::Value = toml::from_str(text).map_err(|e| toml_err(e.to_string()))?;
        for o in overrides {
            apply_override(&mut value, o)?;
        }
        if pace == Pacing::Realtime {
            crate::pace::realtime_defaults(&mut value);
        }
        let mut s: Scenario =
            value.try_into().map_err(|e: toml::de::Error| toml_err(e.to_string()))?;
        if pace == Pacing::Realtime {
            crate::pace::realtime_rate(&mut s.control_hz, &mut s.team_hz);
        }
        let invalid = |reason: String| ScenarioError::Invalid { path: path.to_path_buf(), reason };
        match (&s.team, s.robots.is_empty()) {
            (Some(t), true) => s.robots = t.robots(&s.object).map_err(invalid)?,
            (Some(_), false) => {
                return Err(invalid("give either [[robots]] or [team], not both".into()))
            }
            (None, _) => {}
        }
        s.check().map_err(|reason| ScenarioError::Invalid { path: path.to_path_buf(), reason })?;
        Ok(s)
    }

    /// The run's ticks: `settle` and `duration` at `control_hz`, each to the nearest tick.
    pub fn clock(&self) -> protocol::RunClock {
        protocol::RunClock::from_seconds(self.control_hz, self.settle, self.duration)
    }

    /// Number of control ticks of the scenario proper (after settling).
    pub fn ticks(&self) -> u64 {
        protocol::RunClock::ticks_in(self.duration, self.control_hz)
    }

    /// Robot ticks per team tick ([`Scenario::team_hz`]).
    pub fn team_every(&self) -> Result<u64, String> {
        let Some(hz) = self.team_hz else { return Ok(1) };
        let n = self.control_hz / hz;
        if !(hz.is_finite() && hz > 0.0)
            || (n - n.round()).abs() > 1e-9
            || n.round() < 1.0
            || n.round() > MAX_TEAM_EVERY as f64
        {
            return Err(format!(
                "team_hz = {hz} must divide control_hz = {} a whole number of times, \
                 1 to {MAX_TEAM_EVERY}",
                self.control_hz
            ));
        }
        Ok(n.round() as u64)
    }

    fn check(&self) -> Result<(), String> {
        self.check_rates()?;
        self.check_forces_and_margins()?;
        self.check_object()?;
        self.check_robots()?;
        self.check_gains_and_references()?;
        for (i, f) in self.faults.iter().enumerate() {
            f.check(i, &self.robots, self.duration)?;
        }
        self.check_perturbations()
    }

    /// Duration, rates, settling time, team rate and controller kind.
    fn check_rates(&self) -> Result<(), String> {
        positive("duration", self.duration)?;
        positive("control_hz", self.control_hz)?;
        positive("physics_hz", self.physics_hz)?;
        if !(self.settle.is_finite() && self.settle >= 0.0) {
            return Err(format!("settle = {} must be non-negative", self.settle));
        }
        protocol::validate::substeps(self.control_hz, self.physics_hz)
            .map_err(|e| format!("control_hz, physics_hz: {e}"))?;
        self.team_every()?;
        coordinator::ControllerSpec::of_kind(&self.controller)
            .map_err(|e| format!("controller: {e}"))?;
        Ok(())
    }

    /// Minimum contact forces, friction and patch margins, payload margin.
    fn check_forces_and_margins(&self) -> Result<(), String> {
        for (what, f) in
            [("min_foot_force", self.min_foot_force), ("min_hand_force", self.min_hand_force)]
        {
            if !(f.is_finite() && f >= 0.0) {
                return Err(format!("{what} = {f} must be non-negative"));
            }
        }
        for (what, x) in
            [("friction_margin", self.friction_margin), ("patch_margin", self.patch_margin)]
        {
            if !(x.is_finite() && x > 0.0 && x <= 1.0) {
                return Err(format!("{what} = {x} must be in (0, 1]"));
            }
        }
        if !(self.payload_margin.is_finite() && (0.0..1.0).contains(&self.payload_margin)) {
            return Err(format!("payload_margin = {} must be in [0, 1)", self.payload_margin));
        }
        Ok(())
    }

    /// The object's mass, friction, size and position.
    fn check_object(&self) -> Result<(), String> {
        positive("object.mass", self.object.mass)?;
        positive("object.friction", self.object.friction)?;
        for (i, s) in self.object.size.iter().enumerate() {
            positive(&format!("object.size[{i}]"), *s)?;
        }
        if self.object.position.iter().any(|x| !x.is_finite()) {
            return Err("object.position must be finite".into());
        }
        Ok(())
    }

    /// At least two robots, with unique valid ids and finite poses.
    fn check_robots(&self) -> Result<(), String> {
        if self.robots.len() < 2 {
            return Err("a team needs at least two robots to hold the object".into());
        }
        protocol::validate::check_unique("robots", self.robots.iter().map(|r| r.id.as_str()))
            .map_err(|e| e.to_string())?;
        for (i, r) in self.robots.iter().enumerate() {
            protocol::validate_id("robot", &r.id).map_err(|e| format!("robots[{i}].id: {e}"))?;
            if r.base_xy.iter().chain([&r.yaw]).any(|x| !x.is_finite()) {
                return Err(format!("robots[{i}] pose must be finite"));
            }
        }
        Ok(())
    }

    /// Task gains, the reference motions (each torso's on a known robot) and the walk.
    fn check_gains_and_references(&self) -> Result<(), String> {
        check_gains("gains.object", &self.gains.object, 6)?;
        check_gains("gains.torso", &self.gains.torso, 6)?;
        if let Some(f) = &self.gains.feet {
            check_gains("gains.feet", f, 3)?;
        }
        if !(self.references.ramp.is_finite() && self.references.ramp >= 0.0) {
            return Err(format!("references.ramp = {} must be non-negative", self.references.ramp));
        }
        self.references.object.check("references.object").map_err(|e| e.0)?;
        for (i, t) in self.references.torsos.iter().enumerate() {
            if !self.robots.iter().any(|r| r.id == t.robot) {
                return Err(format!("references.torsos[{i}] names unknown robot {:?}", t.robot));
            }
            t.motion.check(&format!("references.torsos[{i}]")).map_err(|e| e.0)?;
        }
        if let Some(w) = &self.walk {
            w.check(&self.robots.iter().map(|r| r.id.as_str()).collect::<Vec<_>>())
                .map_err(|e| e.0)?;
        }
        Ok(())
    }

    /// Each perturbation acts on the object or a known robot, over a valid window, with a
    /// finite wrench.
    fn check_perturbations(&self) -> Result<(), String> {
        for (i, p) in self.perturbations.iter().enumerate() {
            if p.target.on != "object" && !self.robots.iter().any(|r| r.id == p.target.on) {
                return Err(format!(
                    "perturbations[{i}] acts on unknown {:?} (object or a robot id)",
                    p.target.on
                ));
            }
            if !(p.start.is_finite()
                && p.start >= 0.0
                && p.duration.is_finite()
                && p.duration > 0.0)
            {
                return Err(format!("perturbations[{i}] needs start >= 0 and duration > 0"));
            }
            if p.wrench.iter().any(|x| !x.is_finite()) {
                return Err(format!("perturbations[{i}].wrench must be finite"));
            }
        }
        Ok(())
    }
}

/// `Ok` when `x` is finite and positive, else an error naming `what`.
fn positive(what: &str, x: f64) -> Result<(), String> {
    if x.is_finite() && x > 0.0 {
        Ok(())
    } else {
        Err(format!("{what} = {x} must be positive"))
    }
}

fn check_gains(what: &str, g: &TaskGains, n: usize) -> Result<(), String> {
    g.gains().check(n).map_err(|why| format!("{what}: {why}"))
}

impl TaskGains {
    /// The coordinator's gains of this task.
    pub fn gains(&self) -> coordinator::building_blocks::impedance::Gains {
        coordinator::building_blocks::impedance::Gains::new(&self.stiffness, &self.damping)
    }
}

/// Apply one `key=value` override to a TOML tree. Array elements are addressed by index
/// (`robots.1.yaw`); the key must exist (or be one of [`OPTIONAL_KEYS`] or
/// [`OPTIONAL_NESTED_KEYS`]), so a typo is an
/// error rather than a silent no-op.
pub fn apply_override(root: &mut toml::Value, assignment: &str) -> Result<(), ScenarioError> {
    let (key, raw) = assignment
        .split_once('=')
        .ok_or_else(|| ScenarioError::OverrideSyntax(assignment.to_string()))?;
    let key = key.trim();
    let err = |reason: String| ScenarioError::Override { key: key.to_string(), reason };
    let value = override_value(raw).map_err(err)?;
    let mut node = root;
    let parts: Vec<&str> = key.split('.').collect();
    if parts.iter().any(|p| p.is_empty()) {
        return Err(err("empty key segment".into()));
    }
    for (i, part) in parts.iter().enumerate() {
        let last = i == parts.len() - 1;
        node = match node {
            toml::Value::Table(t) => {
                if i == 0 && !last && OPTIONAL_TABLES.contains(part) && !t.contains_key(*part) {
                    t.insert(part.to_string(), toml::Value::Table(toml::Table::new()));
                }
                if !t.contains_key(*part) && !may_be_absent(&parts, i) {
                    return Err(err(format!(
                        "no such key {part:?} (known: {})",
                        t.keys().cloned().collect::<Vec<_>>().join(", ")
                    )));
                }
                if last {
                    t.insert(part.to_string(), value);
                    return Ok(());
                }
                t.get_mut(*part).expect("checked")
            }
            toml::Value::Array(a) => {
                let idx: usize = part
                    .parse()
                    .map_err(|_| err(format!("{part:?} is not an index into an array")))?;
                let len = a.len();
                let slot = a
                    .get_mut(idx)
                    .ok_or_else(|| err(format!("index {idx} out of range ({len} elements)")))?;
                if last {
                    *slot = value;
                    return Ok(());
                }
                slot
            }
            _ => return Err(err(format!("{part:?} goes into a value that has no fields"))),
        };
    }
    Ok(())
}

/// An override's value: `raw` parsed as TOML; a bare word that is not TOML is taken as a
/// string.
fn override_value(raw: &str) -> Result<toml::Value, String> {
    match toml::from_str::<toml::Table>(&format!("v = {}", raw.trim())) {
        Ok(mut t) => t.remove("v").ok_or_else(|| "no value".to_string()),
        Err(_) => Ok(toml::Value::String(raw.trim().to_string())),
    }
}

/// Whether the key segment `parts[i]` may be missing from its table: the last segment when it
/// is one of [`OPTIONAL_KEYS`] or [`OPTIONAL_NESTED_KEYS`], or a key of one of
/// [`OPTIONAL_TABLES`].
fn may_be_absent(parts: &[&str], i: usize) -> bool {
    let last = i == parts.len() - 1;
    let optional = last
        && if i == 0 {
            OPTIONAL_KEYS.contains(&parts[0])
        } else {
            OPTIONAL_NESTED_KEYS.contains(&parts[..=i].join(".").as_str())
        };
    optional || (i == 1 && OPTIONAL_TABLES.contains(&parts[0]))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scenarios_dir() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios")
    }

    #[test]
    fn every_shipped_scenario_loads() {
        for name in [
            "s1_torso_and_object.toml",
            "s4_object_circle.toml",
            "s5_object_orientation.toml",
            "s6_impedance.toml",
        ] {
            let s = Scenario::load(scenarios_dir().join(name), &[])
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(s.robots.len(), 2, "{name}");
            assert!(s.ticks() > 0);
        }
    }

    #[test]
    fn overrides_change_any_number_and_refuse_typos() {
        let p = scenarios_dir().join("s1_torso_and_object.toml");
        let s = Scenario::load(
            &p,
            &[
                "duration=2.5".into(),
                "gains.object.stiffness=[1,2,3,4,5,6]".into(),
                "robots.1.yaw=0.5".into(),
            ],
        )
        .unwrap();
        assert_eq!(s.duration, 2.5);
        assert_eq!(s.gains.object.stiffness, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        assert_eq!(s.robots[1].yaw, 0.5);
        for bad in [
            "duraton=3",
            "robots.7.yaw=1",
            "duration",
            "gains.object.stiffness=[1,2]",
            "duration=-1",
            "controller=mpc",
            "controller=paper",
        ] {
            assert!(Scenario::load(&p, &[bad.to_string()]).is_err(), "{bad} accepted");
        }
        // Defaulted top-level keys may be set although the file leaves them out.
        let s = Scenario::load(
            &p,
            &["capacity_check=false".into(), "friction_margin=1".into(), "patch_margin=1".into()],
        )
        .unwrap();
        assert!(!s.capacity_check && s.friction_margin == 1.0 && s.patch_margin == 1.0);
        assert!(Scenario::load(&p, &[]).unwrap().capacity_check);
        for bad in [
            "friction_margin=0",
            "patch_margin=1.5",
            "capacity_check=3",
            "object.capacity_check=false",
        ] {
            assert!(Scenario::load(&p, &[bad.to_string()]).is_err(), "{bad} accepted");
        }
        // So may the fields of the optional `release` table; a typo there is still an error.
        let s = Scenario::load(
            &p,
            &["release.after_failed=0.007".into(), "release.retreat=0.1".into()],
        )
        .unwrap();
        assert_eq!((s.release.after_failed, s.release.retreat), (0.007, 0.1));
        assert_eq!(
            s.release.max_fit_residual,
            coordinator::building_blocks::release::ReleasePolicy::default().max_fit_residual
        );
        for bad in ["release.after_failed_ticks=7", "release=3", "release.retreat=[1]"] {
            assert!(Scenario::load(&p, &[bad.to_string()]).is_err(), "{bad} accepted");
        }
        // So may a layout's defaulted keys: four robots two per face, 0.4 m apart.
        let cube = scenarios_dir().join("team4_cube.toml");
        let sets: Vec<String> =
            ["team.faces=[\"-x\", \"+x\"]", "team.per_face=2", "team.spacing=0.4"]
                .map(String::from)
                .to_vec();
        let s = Scenario::load(&cube, &sets).unwrap();
        let ys: Vec<f64> = s.robots.iter().map(|r| r.base_xy[1]).collect();
        assert_eq!(s.robots.len(), 4);
        assert!(ys.iter().all(|y| (y.abs() - 0.2).abs() < 1e-9), "two a face, 0.4 m apart: {ys:?}");
        let e = Scenario::load(&cube, &["team.spacng=0.7".into()]).unwrap_err().to_string();
        assert!(e.contains("no such key \"spacng\""), "{e}");
        assert!(
            Scenario::load(&p, &["team.spacing=0.7".into()]).is_err(),
            "a file without a [team] layout"
        );
        // A file without [references] (a walk) takes its ramp from --set; a typo there is refused.
        let walk = scenarios_dir().join("s2_walk.toml");
        assert_eq!(
            Scenario::load(&walk, &["references.ramp=0.5".into()]).unwrap().references.ramp,
            0.5
        );
        assert!(Scenario::load(&walk, &["references.rmap=0.5".into()]).is_err());
        // The controller is chosen by its kind; the old name says what it became.
        assert_eq!(Scenario::load(&p, &[]).unwrap().controller, "pidc");
        assert_eq!(
            Scenario::load(&p, &["controller=joint-damping".into()]).unwrap().controller,
            "joint-damping"
        );
        let e = Scenario::load(&p, &["controller=paper".into()]).unwrap_err().to_string();
        assert!(e.contains("now `pidc`"), "{e}");
        let e = Scenario::load(&p, &["controller=mpc".into()]).unwrap_err().to_string();
        assert!(e.contains("pidc, joint-damping"), "{e}");
    }

    #[test]
    fn broken_files_say_what_is_wrong() {
        let p = Path::new("x.toml");
        assert!(matches!(
            Scenario::from_str_with("name = ", p, &[]),
            Err(ScenarioError::Toml { .. })
        ));
        let good = std::fs::read_to_string(scenarios_dir().join("s4_object_circle.toml")).unwrap();
        let e = Scenario::from_str_with(
            &good.replace("physics_hz = 2000.0", "physics_hz = 1500.0"),
            p,
            &[],
        )
        .unwrap_err();
        assert!(e.to_string().contains("whole multiple"), "{e}");
        let s6 = std::fs::read_to_string(scenarios_dir().join("s6_impedance.toml")).unwrap();
        let e = Scenario::from_str_with(&s6.replacen("on = \"object\"", "on = \"r9\"", 1), p, &[])
            .unwrap_err();
        assert!(e.to_string().contains("r9"), "{e}");
        assert!(Scenario::load("/nonexistent.toml", &[]).is_err());
    }

    #[test]
    fn the_team_rate_divides_the_robots_and_the_gains_are_named() {
        let p = scenarios_dir().join("s4_object_circle.toml");
        let load = |sets: &[&str]| {
            Scenario::load(&p, &sets.iter().map(|s| s.to_string()).collect::<Vec<_>>())
        };
        assert_eq!(load(&[]).unwrap().team_every(), Ok(1), "the paper's single loop by default");
        assert_eq!(load(&["team_hz=250"]).unwrap().team_every(), Ok(4));
        assert_eq!(load(&[]).unwrap().team_delay_ticks, TeamDelay::Ticks(0), "no delay by default");
        assert_eq!(load(&["team_delay_ticks=3"]).unwrap().team_delay_ticks, TeamDelay::Ticks(3));
        assert_eq!(load(&["team_delay_ticks=auto"]).unwrap().team_delay_ticks, TeamDelay::AUTO);
        assert_eq!(
            load(&["team_delay_ticks=\"auto:6\""]).unwrap().team_delay_ticks,
            TeamDelay::Auto { max: 6 }
        );
        for bad in [
            "team_delay_ticks=9",
            "team_delay_ticks=-1",
            "team_delay_ticks=soon",
            "team_delay_ticks=1.5",
            "team_delay_ticks=auto:9",
        ] {
            let e = load(&[bad]).unwrap_err().to_string();
            assert!(
                e.contains("team_delay_ticks")
                    && e.contains("\"auto:N\" or a whole number of ticks from 0 to 8"),
                "{bad}: {e}"
            );
        }
        for bad in ["team_hz=300", "team_hz=2000", "team_hz=0", "team_hz=10"] {
            let e = load(&[bad]).unwrap_err().to_string();
            assert!(e.contains("team_hz") && e.contains("whole number"), "{bad}: {e}");
        }
        assert_eq!(
            load(&["drive_gains=inertia"]).unwrap().drive_gains,
            robot_agent::drive_gains::DriveGainsMode::Inertia
        );
        assert!(load(&["drive_gains=stiff"]).is_err());
    }
}
