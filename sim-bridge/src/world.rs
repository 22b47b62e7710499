//! The MuJoCo world of the team, built from the robots' own URDFs (docs/architecture.md).
//!
//! The robots come already loaded (`robot_model::Robot`, one `Arc` per description file,
//! shared with the rest of the process): [`load_robots`] loads those of a [`WorldSpec`] when
//! nobody else has, and [`World::build`] takes them in the spec's order. The palm and foot
//! bodies are the parent links of the hand and foot frames in the robot's model.
//!
//! Each robot's URDF is parsed by MuJoCo's URDF importer into its own `mjSpec` (with the
//! compiler block `fusestatic="false" discardvisual="true" balanceinertia="false"
//! inertiafromgeom="false"` injected, so every URDF link stays a body with exactly the URDF's
//! inertia); a free joint is added to its root body; the contact parameters of its palm and
//! foot geoms are set; then a deep copy is attached under the prefix `{id}/` to a frame of the
//! world spec placed at the robot's base pose. The world spec itself (floor, object, solver
//! options) is MJCF text generated from checked numbers. One motor per actuated joint, with
//! `ctrlrange` = the robot's torque limits, is added by mjSpec. After compiling, the world is
//! checked against each robot's own model ([`check_against_model`]): total mass and actuated
//! joint order.

use std::collections::BTreeMap;
use std::ffi::CString;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use mujoco_rs::mujoco_c::{self, mjModel, mjtObj};
use mujoco_rs::prelude::*;
use mujoco_rs::wrappers::mj_editing::Attach;
use robot_model::{Robot, RobotCache};
use thiserror::Error;

/// Errors while building or checking the world.
#[derive(Debug, Error)]
pub enum WorldError {
    #[error("robot {id}: cannot load its description {path}: {reason}")]
    Description { id: String, path: PathBuf, reason: String },
    #[error("robot {id}: cannot read its URDF {path}: {reason}")]
    Urdf { id: String, path: PathBuf, reason: String },
    #[error("invalid world: {0}")]
    Invalid(String),
    #[error("robot {id}: MuJoCo rejected the URDF: {reason}")]
    Import { id: String, reason: String },
    #[error("MuJoCo could not build the world: {0}")]
    Build(String),
    #[error("MuJoCo has no {kind} named {name:?}")]
    MissingName { kind: &'static str, name: String },
    #[error("robot {id}: total mass in MuJoCo {mujoco} kg, in the robot's model {model} kg")]
    MassMismatch { id: String, mujoco: f64, model: f64 },
    #[error("robot {id}: actuated joints in MuJoCo {mujoco:?}, in the robot's model {model:?}")]
    JointOrderMismatch { id: String, mujoco: Vec<String>, model: Vec<String> },
    #[error("robot {id}: joint override for unknown joint {joint:?}")]
    UnknownJoint { id: String, joint: String },
}

/// A robot of the scenario.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotPlacement {
    /// Robot id (protocol id rules), also the MuJoCo name prefix `{id}/`.
    pub id: String,
    /// Path of the robot's description TOML (`robot_model::description`).
    pub description: PathBuf,
    /// Base position in the world (the default robot stands with its base at z = 0.54882015).
    pub base_position: [f64; 3],
    /// Base yaw about world z, rad.
    pub base_yaw: f64,
    /// Joint positions that replace the standing configuration's, by joint name.
    pub joint_overrides: BTreeMap<String, f64>,
}

/// Base height of the default robot's standing pose (`robot-model/models/legged_manipulator.toml`,
/// `[standing] base_position`), m: for worlds built without loading it first (tests, the
/// paper's pair).
pub const DEFAULT_STANDING_HEIGHT: f64 = 0.54882015;

impl RobotPlacement {
    /// The default robot at `(x, y)` at its standing height ([`DEFAULT_STANDING_HEIGHT`]),
    /// facing `yaw`.
    pub fn default_robot(id: &str, x: f64, y: f64, yaw: f64) -> Self {
        Self::at_height(id, robot_model::default_robot_path(), [x, y, DEFAULT_STANDING_HEIGHT], yaw)
    }

    /// `robot` (loaded from `description`) at `(x, y)` facing `yaw`, its base at the height of
    /// its own description's standing pose (so its feet touch the floor). A fixed-base robot
    /// has no base to place on the floor: an error.
    pub fn standing(
        id: &str,
        description: PathBuf,
        robot: &Robot,
        xy: [f64; 2],
        yaw: f64,
    ) -> Result<Self, WorldError> {
        if !robot.model.floating_base {
            return Err(WorldError::Invalid(format!(
                "robot {id}: {} has a fixed base; only a floating-base robot stands on the floor",
                description.display()
            )));
        }
        Ok(Self::at_height(id, description, [xy[0], xy[1], robot.standing_q[2]], yaw))
    }

    fn at_height(id: &str, description: PathBuf, base_position: [f64; 3], base_yaw: f64) -> Self {
        RobotPlacement {
            id: id.to_string(),
            description,
            base_position,
            base_yaw,
            joint_overrides: BTreeMap::new(),
        }
    }
}

/// The carried object: a box.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectSpec {
    /// Edge lengths, m.
    pub size: [f64; 3],
    pub mass: f64,
    /// Principal moments about the centre; `None`: a uniform box.
    pub inertia: Option<[f64; 3]>,
    /// MuJoCo friction triple (sliding, torsional, rolling) for object-floor contacts; the
    /// hand-object contact uses the hand's parameters (the hands have priority).
    pub friction: [f64; 3],
    pub position: [f64; 3],
    /// `(w, x, y, z)`.
    pub orientation: [f64; 4],
}

impl ObjectSpec {
    /// The paper's object: a 0.6 m cube of 1 kg, centre at `position`.
    pub fn paper_cube(position: [f64; 3]) -> Self {
        ObjectSpec {
            size: [0.6; 3],
            mass: 1.0,
            inertia: None,
            friction: [0.8, 0.005, 0.0001],
            position,
            orientation: [1.0, 0.0, 0.0, 0.0],
        }
    }

    pub fn principal_inertia(&self) -> [f64; 3] {
        self.inertia.unwrap_or_else(|| {
            let [a, b, c] = self.size;
            let m = self.mass / 12.0;
            [m * (b * b + c * c), m * (a * a + c * c), m * (a * a + b * b)]
        })
    }
}

/// Contact parameters (see README: why these).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactParams {
    /// Feet: sliding friction (torsional/rolling unused with condim 3).
    pub foot_friction: f64,
    pub foot_solref: [f64; 2],
    pub foot_solimp: [f64; 3],
    /// Hands: (sliding, torsional, rolling); condim 6.
    pub hand_friction: [f64; 3],
    pub hand_solref: [f64; 2],
    pub hand_solimp: [f64; 3],
    pub floor_friction: f64,
}

impl Default for ContactParams {
    fn default() -> Self {
        ContactParams {
            foot_friction: 0.8,
            foot_solref: [0.005, 1.0],
            foot_solimp: [0.95, 0.99, 0.001],
            hand_friction: [0.8, 0.03, 0.0001],
            hand_solref: [0.005, 1.0],
            hand_solimp: [0.95, 0.99, 0.001],
            floor_friction: 0.8,
        }
    }
}

/// Solver settings of the world.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverParams {
    /// `implicitfast` (default) or `RK4` or `Euler`.
    pub integrator: String,
    /// `elliptic` (default: needed for a sensible condim-6 patch) or `pyramidal`.
    pub cone: String,
    pub impratio: f64,
    pub iterations: u32,
    pub tolerance: f64,
    /// MuJoCo's no-slip post-processing iterations (`noslip_iterations`, 0: off): without them
    /// its soft contacts let a foot under a steady tangential force creep (about 1 mm/s for a
    /// standing robot's splayed feet, until the knees pass straight after about 150 s), which
    /// real feet do not. On by default ([`DEFAULT_NOSLIP_ITERATIONS`]).
    #[serde(default = "default_noslip")]
    pub noslip_iterations: u32,
}

impl Default for SolverParams {
    fn default() -> Self {
        SolverParams {
            integrator: "implicitfast".into(),
            cone: "elliptic".into(),
            impratio: 10.0,
            iterations: 100,
            tolerance: 1e-10,
            noslip_iterations: DEFAULT_NOSLIP_ITERATIONS,
        }
    }
}

/// MuJoCo's no-slip iterations by default: static friction at the feet and palms, as real
/// contacts have it (docs/sim-bridge.md: what they cost per step, the creep that remains).
pub const DEFAULT_NOSLIP_ITERATIONS: u32 = 20;

fn default_noslip() -> u32 {
    DEFAULT_NOSLIP_ITERATIONS
}

/// What the simulated robots measure besides their own state.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Sensors {
    /// Each robot measures the held object's pose (`RobotState::object_pose`: motion capture or
    /// a camera on a real team; here MuJoCo's pose of the object).
    pub object_pose: bool,
}

impl Default for Sensors {
    fn default() -> Self {
        Sensors { object_pose: true }
    }
}

/// Everything the world is built from.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldSpec {
    pub robots: Vec<RobotPlacement>,
    pub object: Option<ObjectSpec>,
    /// Control ticks per second.
    pub control_hz: f64,
    /// Physics steps per second: an integer multiple of `control_hz`.
    pub physics_hz: f64,
    pub contact: ContactParams,
    pub solver: SolverParams,
    /// What the robots measure besides their own state.
    #[serde(default)]
    pub sensors: Sensors,
    /// Seed of the initial-condition noise.
    pub seed: u64,
    /// Standard deviation of the noise added to the initial joint positions, rad (0: none).
    pub initial_joint_noise: f64,
}

impl WorldSpec {
    /// The paper's team of two default robots 2.3 m apart facing each other, holding the 0.6 m
    /// cube at 0.60 m height, control and physics at 1 kHz.
    pub fn paper_pair() -> Self {
        WorldSpec {
            robots: vec![
                RobotPlacement::default_robot("r1", -1.15, 0.0, 0.0),
                RobotPlacement::default_robot("r2", 1.15, 0.0, std::f64::consts::PI),
            ],
            object: Some(ObjectSpec::paper_cube([0.0, 0.0, 0.60])),
            ..Self::single("r1")
        }
    }

    /// One default robot at the origin, no object.
    pub fn single(id: &str) -> Self {
        WorldSpec {
            robots: vec![RobotPlacement::default_robot(id, 0.0, 0.0, 0.0)],
            object: None,
            control_hz: 1000.0,
            physics_hz: 1000.0,
            contact: ContactParams::default(),
            solver: SolverParams::default(),
            sensors: Sensors::default(),
            seed: 0,
            initial_joint_noise: 0.0,
        }
    }

    /// Physics substeps per control tick, checked.
    pub fn substeps(&self) -> Result<u32, WorldError> {
        protocol::validate::substeps(self.control_hz, self.physics_hz)
            .map_err(|e| WorldError::Invalid(e.to_string()))
    }

    fn validate(&self) -> Result<(), WorldError> {
        self.substeps()?;
        if self.robots.is_empty() {
            return Err(WorldError::Invalid("no robots".into()));
        }
        protocol::validate::check_unique("robots", self.robots.iter().map(|r| r.id.as_str()))
            .map_err(|e| WorldError::Invalid(e.to_string()))?;
        for r in &self.robots {
            r.validate()?;
        }
        if let Some(o) = &self.object {
            o.validate()?;
        }
        self.contact.validate()?;
        if !(self.initial_joint_noise.is_finite() && self.initial_joint_noise >= 0.0) {
            return Err(WorldError::Invalid("initial joint noise must be >= 0".into()));
        }
        self.solver.validate()
    }
}

impl RobotPlacement {
    /// A valid id and finite base pose and joint overrides.
    fn validate(&self) -> Result<(), WorldError> {
        protocol::validate_id("robot", &self.id).map_err(|e| WorldError::Invalid(e.to_string()))?;
        finite(&format!("robot {} base position", self.id), &self.base_position)?;
        finite(&format!("robot {} base yaw", self.id), &[self.base_yaw])?;
        for (j, v) in &self.joint_overrides {
            finite(&format!("robot {} joint {j}", self.id), &[*v])?;
        }
        Ok(())
    }
}

impl ObjectSpec {
    /// Finite numbers, positive size and mass, a physical inertia and a unit orientation.
    fn validate(&self) -> Result<(), WorldError> {
        let o = self;
        finite("object size", &o.size)?;
        finite("object position", &o.position)?;
        finite("object orientation", &o.orientation)?;
        finite("object friction", &o.friction)?;
        if o.size.iter().any(|s| *s <= 0.0) || !(o.mass.is_finite() && o.mass > 0.0) {
            return Err(WorldError::Invalid("object size and mass must be positive".into()));
        }
        let i = o.principal_inertia();
        finite("object inertia", &i)?;
        if i.iter().any(|x| *x <= 0.0)
            || i[0] + i[1] < i[2]
            || i[1] + i[2] < i[0]
            || i[0] + i[2] < i[1]
        {
            return Err(WorldError::Invalid(format!("object inertia {i:?} is not physical")));
        }
        protocol::validate::check_unit_quaternion_within(
            "object orientation",
            &o.orientation,
            protocol::validate::FILE_QUATERNION_TOLERANCE,
        )
        .map_err(|e| WorldError::Invalid(e.to_string()))
    }
}

impl ContactParams {
    /// Finite frictions and solver parameters.
    fn validate(&self) -> Result<(), WorldError> {
        let c = self;
        finite("contact parameters", &[c.foot_friction, c.floor_friction])?;
        finite("contact parameters", &c.hand_friction)?;
        finite(
            "contact parameters",
            &[c.foot_solref[0], c.foot_solref[1], c.hand_solref[0], c.hand_solref[1]],
        )?;
        finite(
            "contact parameters",
            &[
                c.foot_solimp[0],
                c.foot_solimp[1],
                c.foot_solimp[2],
                c.hand_solimp[0],
                c.hand_solimp[1],
                c.hand_solimp[2],
            ],
        )
    }
}

impl SolverParams {
    /// A known integrator and cone, finite impedance ratio and tolerance.
    fn validate(&self) -> Result<(), WorldError> {
        if !["implicitfast", "implicit", "RK4", "Euler"].contains(&self.integrator.as_str())
            || !["elliptic", "pyramidal"].contains(&self.cone.as_str())
        {
            return Err(WorldError::Invalid("unknown integrator or cone".into()));
        }
        finite("solver", &[self.impratio, self.tolerance])
    }
}

fn finite(what: &str, xs: &[f64]) -> Result<(), WorldError> {
    if xs.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(WorldError::Invalid(format!("{what} must be finite numbers, got {xs:?}")))
    }
}

/// Where one robot lives in the compiled MuJoCo model (ids, never positions assumed).
#[derive(Debug, Clone)]
pub struct RobotIndex {
    pub id: String,
    /// The robot's own model and description (shared with whoever loaded it).
    pub robot: Arc<Robot>,
    /// qpos address of the free joint (7: position, quaternion w,x,y,z).
    pub free_qpos: usize,
    /// qvel address of the free joint (6).
    pub free_dof: usize,
    /// Per actuated joint in the robot's velocity order: qpos address, dof address, actuator id.
    pub joint_qpos: Vec<usize>,
    pub joint_dof: Vec<usize>,
    pub actuator: Vec<usize>,
    /// Body id of the base.
    pub base_body: usize,
    /// Body ids of every body of this robot.
    pub bodies: Vec<usize>,
    /// Geom ids of the palm and of the four foot spheres.
    pub hand_geoms: Vec<usize>,
    pub foot_geoms: Vec<usize>,
    /// The body id of each foot, in the description's foot order (its contacts are the foot's).
    pub foot_bodies: Vec<usize>,
    /// Body id of the hand contact frame.
    pub hand_contact_body: usize,
    /// Initial configuration: standing with overrides (and noise), the robot's q convention.
    pub initial_q: Vec<f64>,
}

/// The compiled world and its name maps.
pub struct World {
    pub model: std::sync::Arc<MjModel>,
    pub robots: Vec<RobotIndex>,
    /// Body id, free-joint qpos and dof address of the object, if any.
    pub object: Option<(usize, usize, usize)>,
    pub object_geom: Option<usize>,
    pub substeps: u32,
    pub control_dt: f64,
    pub spec: WorldSpec,
}

/// The URDF text with MuJoCo's compiler block right after `<robot ...>`.
pub fn mujoco_urdf_text(urdf: &str) -> Result<String, String> {
    let a = urdf.find("<robot").ok_or("no <robot> element")?;
    let a = a + urdf[a..].find('>').ok_or("unterminated <robot> element")? + 1;
    Ok(format!(
        "{}\n<mujoco><compiler fusestatic=\"false\" discardvisual=\"true\" \
         balanceinertia=\"false\" inertiafromgeom=\"false\" angle=\"radian\"/></mujoco>\n{}",
        &urdf[..a],
        &urdf[a..]
    ))
}

fn world_xml(spec: &WorldSpec, dt: f64) -> String {
    let s = &spec.solver;
    let mut xml = format!(
        concat!(
            r#"<mujoco model="team">
  <compiler angle="radian" fusestatic="false" balanceinertia="false" inertiafromgeom="false""#,
            r#" autolimits="true"/>
  <option timestep="{dt:e}" gravity="0 0 {g:e}" integrator="{integ}" cone="{cone}""#,
            r#" impratio="{imp:e}" iterations="{it}" tolerance="{tol:e}""#,
            r#" noslip_iterations="{noslip}" solver="Newton"/>
  <size memory="64M"/>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.05" friction="{ff:e} 0.005 0.0001" condim="3"/>
"#,
        ),
        dt = dt,
        g = -protocol::conventions::GRAVITY,
        integ = s.integrator,
        cone = s.cone,
        imp = s.impratio,
        it = s.iterations,
        tol = s.tolerance,
        noslip = s.noslip_iterations,
        ff = spec.contact.floor_friction,
    );
    if let Some(o) = &spec.object {
        let i = o.principal_inertia();
        xml += &format!(
            concat!(
                r#"    <body name="object" pos="{:e} {:e} {:e}" quat="{:e} {:e} {:e} {:e}">
      <freejoint name="object"/>
      <inertial pos="0 0 0" mass="{:e}" diaginertia="{:e} {:e} {:e}"/>
      <geom name="object" type="box" size="{:e} {:e} {:e}" friction="{:e} {:e} {:e}""#,
                r#" condim="3" mass="0"/>
    </body>
"#,
            ),
            o.position[0],
            o.position[1],
            o.position[2],
            o.orientation[0],
            o.orientation[1],
            o.orientation[2],
            o.orientation[3],
            o.mass,
            i[0],
            i[1],
            i[2],
            o.size[0] / 2.0,
            o.size[1] / 2.0,
            o.size[2] / 2.0,
            o.friction[0],
            o.friction[1],
            o.friction[2]
        );
    }
    xml += "  </worldbody>\n</mujoco>\n";
    xml
}

/// Id of a named MuJoCo object.
pub fn name2id(
    model: &mjModel,
    kind: mjtObj,
    what: &'static str,
    name: &str,
) -> Result<usize, WorldError> {
    let c = CString::new(name)
        .map_err(|_| WorldError::MissingName { kind: what, name: name.to_string() })?;
    let id = unsafe { mujoco_c::mj_name2id(model, kind as i32, c.as_ptr()) };
    if id < 0 {
        return Err(WorldError::MissingName { kind: what, name: name.to_string() });
    }
    Ok(id as usize)
}

/// Name of a MuJoCo object (empty if unnamed).
pub fn id2name(model: &mjModel, kind: mjtObj, id: usize) -> String {
    let p = unsafe { mujoco_c::mj_id2name(model, kind as i32, id as i32) };
    if p.is_null() {
        return String::new();
    }
    unsafe { std::ffi::CStr::from_ptr(p) }.to_string_lossy().into_owned()
}

fn yaw_quat(yaw: f64) -> [f64; 4] {
    [(yaw / 2.0).cos(), 0.0, 0.0, (yaw / 2.0).sin()]
}

/// Load the robots of `spec`, in its order: each description file once, robots that share one
/// share its `Arc`.
pub fn load_robots(spec: &WorldSpec) -> Result<Vec<Arc<Robot>>, WorldError> {
    let mut cache = RobotCache::new();
    spec.robots
        .iter()
        .map(|p| {
            cache.load(&p.description).map_err(|e| WorldError::Description {
                id: p.id.clone(),
                path: p.description.clone(),
                reason: e.to_string(),
            })
        })
        .collect()
}

/// `robots` are those of `spec`, in its order, each loaded from its placement's description.
fn check_robots(spec: &WorldSpec, robots: &[Arc<Robot>]) -> Result<(), WorldError> {
    if robots.len() != spec.robots.len() {
        return Err(WorldError::Invalid(format!(
            "{} robots loaded for {} placements",
            robots.len(),
            spec.robots.len()
        )));
    }
    for (placement, robot) in spec.robots.iter().zip(robots) {
        if robot.path != placement.description {
            return Err(WorldError::Invalid(format!(
                "robot {}: its placement names {} but the robot given was loaded from {}",
                placement.id,
                placement.description.display(),
                robot.path.display()
            )));
        }
    }
    Ok(())
}

impl World {
    /// Build and compile the world from `spec` and its already loaded `robots` (the spec's
    /// order, see [`load_robots`]), and check it against each robot's own model.
    pub fn build(spec: &WorldSpec, robots: &[Arc<Robot>]) -> Result<World, WorldError> {
        spec.validate()?;
        check_robots(spec, robots)?;
        let substeps = spec.substeps()?;
        let dt = 1.0 / spec.physics_hz;
        let contact = stable_contact(spec.contact, dt);

        let mut world = MjSpec::from_xml_string(&world_xml(spec, dt))
            .map_err(|e| WorldError::Build(e.to_string()))?;
        let mut hand_bodies = Vec::new();
        for (placement, robot) in spec.robots.iter().zip(robots) {
            hand_bodies.push(attach_robot(&mut world, placement, robot, &contact)?);
        }
        // One motor per actuated joint, limited to the robot's torque limits.
        for (placement, robot) in spec.robots.iter().zip(robots) {
            add_motors(&mut world, &placement.id, robot)?;
        }
        let mut model = world.compile().map_err(|e| WorldError::Build(e.to_string()))?;
        remove_joint_losses(&mut model);
        let model = std::sync::Arc::new(model);
        let raw = model.ffi();
        let mut indexed = Vec::new();
        let mut rng = SplitMix(spec.seed ^ 0x9e37_79b9_7f4a_7c15);
        for ((placement, robot), hand_body) in spec.robots.iter().zip(robots).zip(hand_bodies) {
            indexed.push(index_robot(raw, spec, placement, robot.clone(), &hand_body, &mut rng)?);
        }
        let (object, object_geom) = index_object(raw, spec)?;
        let world = World {
            model,
            robots: indexed,
            object,
            object_geom,
            substeps,
            control_dt: 1.0 / spec.control_hz,
            spec: spec.clone(),
        };
        for r in &world.robots {
            check_against_model(&world.model, r)?;
        }
        Ok(world)
    }
}

/// The contact parameters with each time constant at least two physics steps of `dt`: a
/// shorter one is unstable (MuJoCo docs).
fn stable_contact(mut contact: ContactParams, dt: f64) -> ContactParams {
    contact.foot_solref[0] = contact.foot_solref[0].max(2.0 * dt);
    contact.hand_solref[0] = contact.hand_solref[0].max(2.0 * dt);
    contact
}

/// Import the robot's URDF into its own mjSpec, give its root body a free joint named `base`,
/// set its palm and foot contacts, and attach a copy under the prefix `{id}/` to a frame of
/// `world` at its base pose. Returns the name of its hand body.
fn attach_robot(
    world: &mut MjSpec,
    placement: &RobotPlacement,
    robot: &Robot,
    contact: &ContactParams,
) -> Result<String, WorldError> {
    let id = &placement.id;
    let urdf = std::fs::read_to_string(&robot.urdf_path).map_err(|e| WorldError::Urdf {
        id: id.clone(),
        path: robot.urdf_path.clone(),
        reason: e.to_string(),
    })?;
    let text =
        mujoco_urdf_text(&urdf).map_err(|reason| WorldError::Import { id: id.clone(), reason })?;
    let mut child = MjSpec::from_xml_string(&text)
        .map_err(|e| WorldError::Import { id: id.clone(), reason: e.to_string() })?;
    let root = robot.model.bodies[0].name.clone();
    let hand_body = hand_body_name(robot)?;
    let foot_bodies = foot_body_names(robot);
    {
        let root_body = child.world_body_mut().child_mut(&root).ok_or_else(|| {
            WorldError::Import { id: id.clone(), reason: format!("no root body {root}") }
        })?;
        root_body
            .add_free_joint()
            .set_name("base")
            .map_err(|e| WorldError::Build(e.to_string()))?;
    }
    configure_geoms(&mut child, robot, contact, &hand_body, &foot_bodies, id)?;
    let q = yaw_quat(placement.base_yaw);
    let frame = world.world_body_mut().add_frame();
    *frame.pos_mut() = placement.base_position;
    *frame.quat_mut() = q;
    let body = child.body_mut(&root).ok_or_else(|| WorldError::Import {
        id: id.clone(),
        reason: format!("no root body {root}"),
    })?;
    frame
        .attach_by_deep_copy(body, &format!("{id}/"), "")
        .map_err(|e| WorldError::Build(format!("attaching {id}: {e}")))?;
    Ok(hand_body)
}

/// One motor per actuated joint of robot `id`, its `ctrlrange` the joint's torque limit.
fn add_motors(world: &mut MjSpec, id: &str, robot: &Robot) -> Result<(), WorldError> {
    for (name, limit) in robot.actuated_joints.iter().zip(&robot.torque_limits) {
        let act = world.add_actuator();
        act.set_name(&format!("{id}/{name}")).map_err(|e| WorldError::Build(e.to_string()))?;
        act.set_target(&format!("{id}/{name}"));
        act.set_trntype(MjtTrn::mjTRN_JOINT);
        act.set_to_motor();
        *act.ctrlrange_mut() = [-limit, *limit];
        act.set_ctrllimited(mujoco_rs::wrappers::mj_editing::MjtLimited::mjLIMITED_TRUE);
    }
    Ok(())
}

/// No joint damping, armature or friction loss: the simulator's robot is the model's robot.
fn remove_joint_losses(model: &mut MjModel) {
    let raw = unsafe { model.ffi_mut() };
    for k in 0..raw.nv as usize {
        unsafe {
            *raw.dof_armature.add(k) = 0.0;
            *raw.dof_damping.add(k) = 0.0;
            *raw.dof_frictionloss.add(k) = 0.0;
        }
    }
}

/// Where the robot of `placement` lives in the compiled model, and its initial configuration
/// (noise drawn from `rng`).
fn index_robot(
    raw: &mjModel,
    spec: &WorldSpec,
    placement: &RobotPlacement,
    robot: Arc<Robot>,
    hand_body: &str,
    rng: &mut SplitMix,
) -> Result<RobotIndex, WorldError> {
    let id = placement.id.clone();
    let p = |n: &str| format!("{id}/{n}");
    let free = name2id(raw, mjtObj::mjOBJ_JOINT, "joint", &p("base"))?;
    let free_qpos = unsafe { *raw.jnt_qposadr.add(free) } as usize;
    let free_dof = unsafe { *raw.jnt_dofadr.add(free) } as usize;
    let mut joint_qpos = Vec::new();
    let mut joint_dof = Vec::new();
    let mut actuator = Vec::new();
    for name in &robot.actuated_joints {
        let j = name2id(raw, mjtObj::mjOBJ_JOINT, "joint", &p(name))?;
        joint_qpos.push(unsafe { *raw.jnt_qposadr.add(j) } as usize);
        joint_dof.push(unsafe { *raw.jnt_dofadr.add(j) } as usize);
        actuator.push(name2id(raw, mjtObj::mjOBJ_ACTUATOR, "actuator", &p(name))?);
    }
    let root = &robot.model.bodies[0].name;
    let base_body = name2id(raw, mjtObj::mjOBJ_BODY, "body", &p(root))?;
    let bodies: Vec<usize> = (0..raw.nbody as usize)
        .filter(|&b| id2name(raw, mjtObj::mjOBJ_BODY, b).starts_with(&format!("{id}/")))
        .collect();
    let hb = name2id(raw, mjtObj::mjOBJ_BODY, "body", &p(hand_body))?;
    let hand_geoms = body_geoms(raw, hb);
    let foot_geoms = foot_geoms(raw, &bodies, robot.feet.radius);
    let foot_bodies = foot_body_names(&robot)
        .iter()
        .map(|b| name2id(raw, mjtObj::mjOBJ_BODY, "body", &p(b)))
        .collect::<Result<Vec<_>, _>>()?;
    let hand_contact_body = name2id(raw, mjtObj::mjOBJ_BODY, "body", &p(&robot.hand_frame))?;
    let initial_q = initial_configuration(spec, placement, &robot, rng)?;
    Ok(RobotIndex {
        id,
        robot,
        free_qpos,
        free_dof,
        joint_qpos,
        joint_dof,
        actuator,
        base_body,
        bodies,
        hand_geoms,
        foot_geoms,
        foot_bodies,
        hand_contact_body,
        initial_q,
    })
}

/// The robot's initial `q`: standing, with the placement's joint overrides, the spec's joint
/// noise (drawn from `rng`) and the placement's base pose.
fn initial_configuration(
    spec: &WorldSpec,
    placement: &RobotPlacement,
    robot: &Robot,
    rng: &mut SplitMix,
) -> Result<Vec<f64>, WorldError> {
    let mut initial_q: Vec<f64> = robot.standing_q.iter().copied().collect();
    let off = robot.model.nq - robot.model.joint_names.len();
    for (j, v) in &placement.joint_overrides {
        let k = robot.model.joint_names.iter().position(|n| n == j).ok_or_else(|| {
            WorldError::UnknownJoint { id: placement.id.clone(), joint: j.clone() }
        })?;
        initial_q[off + k] = *v;
    }
    if spec.initial_joint_noise > 0.0 {
        for k in 0..robot.model.joint_names.len() {
            initial_q[off + k] += spec.initial_joint_noise * rng.gaussian();
        }
    }
    initial_q[0..3].copy_from_slice(&placement.base_position);
    initial_q[3..7].copy_from_slice(&yaw_quat(placement.base_yaw));
    Ok(initial_q)
}

/// Body id, free-joint qpos address and dof address of the object ([`World::object`]).
type ObjectAddresses = (usize, usize, usize);

/// The object's body id, free-joint qpos and dof addresses, and geom id (none without an
/// object).
fn index_object(
    raw: &mjModel,
    spec: &WorldSpec,
) -> Result<(Option<ObjectAddresses>, Option<usize>), WorldError> {
    if spec.object.is_none() {
        return Ok((None, None));
    }
    let b = name2id(raw, mjtObj::mjOBJ_BODY, "body", "object")?;
    let j = name2id(raw, mjtObj::mjOBJ_JOINT, "joint", "object")?;
    let g = name2id(raw, mjtObj::mjOBJ_GEOM, "geom", "object")?;
    Ok((
        Some((b, unsafe { *raw.jnt_qposadr.add(j) } as usize, unsafe { *raw.jnt_dofadr.add(j) }
            as usize)),
        Some(g),
    ))
}

/// Geom ids of body `body`.
fn body_geoms(raw: &mjModel, body: usize) -> Vec<usize> {
    (0..raw.ngeom as usize)
        .filter(|&g| unsafe { *raw.geom_bodyid.add(g) } as usize == body)
        .collect()
}

/// Geom ids of the foot spheres (condim 3, the feet's radius) among the geoms of `bodies`.
fn foot_geoms(raw: &mjModel, bodies: &[usize], radius: f64) -> Vec<usize> {
    (0..raw.ngeom as usize)
        .filter(|&g| {
            bodies.contains(&(unsafe { *raw.geom_bodyid.add(g) } as usize))
                && unsafe { *raw.geom_condim.add(g) } == 3
                && is_foot_geom(raw, g, radius)
        })
        .collect()
}

fn is_foot_geom(raw: &mjModel, g: usize, radius: f64) -> bool {
    let t = unsafe { *raw.geom_type.add(g) };
    let size = unsafe { *raw.geom_size.add(3 * g) };
    t == mujoco_c::mjtGeom::mjGEOM_SPHERE as i32 && (size - radius).abs() < 1e-9
}

/// The URDF link of `frame`'s joint's parent, from the robot's model (`None`: no such frame,
/// or the root link).
fn parent_link(robot: &Robot, frame: &str) -> Option<String> {
    let id = robot.model.frame_id(frame).ok()?;
    robot.model.parent_link(id).map(str::to_string)
}

/// The URDF link (a MuJoCo body, since fusestatic is off) that carries the palm: the parent
/// link of the hand contact frame.
fn hand_body_name(robot: &Robot) -> Result<String, WorldError> {
    parent_link(robot, &robot.hand_frame).ok_or_else(|| {
        WorldError::Invalid(format!("no joint leads to the hand frame {}", robot.hand_frame))
    })
}

/// Links carrying the foot spheres: the parents of the foot frames.
fn foot_body_names(robot: &Robot) -> Vec<String> {
    robot.foot_frames.iter().filter_map(|f| parent_link(robot, f)).collect()
}

fn configure_geoms(
    child: &mut MjSpec,
    robot: &Robot,
    c: &ContactParams,
    hand_body: &str,
    foot_bodies: &[String],
    id: &str,
) -> Result<(), WorldError> {
    let hand = child.body_mut(hand_body).ok_or_else(|| WorldError::Import {
        id: id.to_string(),
        reason: format!("no hand body {hand_body}"),
    })?;
    let mut n = 0;
    for g in hand.geom_iter_mut(false) {
        g.set_condim(6);
        g.set_priority(1);
        *g.friction_mut() = c.hand_friction;
        g.solref_mut()[..2].copy_from_slice(&c.hand_solref);
        g.solimp_mut()[..3].copy_from_slice(&c.hand_solimp);
        n += 1;
    }
    if n == 0 {
        return Err(WorldError::Import {
            id: id.to_string(),
            reason: format!("the hand body {hand_body} has no collision geom"),
        });
    }
    for fb in foot_bodies {
        let body = child.body_mut(fb).ok_or_else(|| WorldError::Import {
            id: id.to_string(),
            reason: format!("no foot body {fb}"),
        })?;
        for g in body.geom_iter_mut(false) {
            let is_sphere = g.type_() as i32 == mujoco_c::mjtGeom::mjGEOM_SPHERE as i32;
            if is_sphere && (g.size()[0] - robot.feet.radius).abs() < 1e-9 {
                g.set_condim(3);
                *g.friction_mut() = [c.foot_friction, 0.005, 0.0001];
                g.solref_mut()[..2].copy_from_slice(&c.foot_solref);
                g.solimp_mut()[..3].copy_from_slice(&c.foot_solimp);
            }
        }
    }
    Ok(())
}

/// The MuJoCo world's robot `r` has the same total mass and the same actuated joint order
/// (the order of its hinge joints in the compiled model, prefix removed) as its own model.
pub fn check_against_model(model: &MjModel, r: &RobotIndex) -> Result<(), WorldError> {
    let raw = model.ffi();
    let mass: f64 = r.bodies.iter().map(|&b| unsafe { *raw.body_mass.add(b) }).sum();
    if (mass - r.robot.model.total_mass).abs() > 1e-9 * r.robot.model.total_mass.max(1.0) {
        return Err(WorldError::MassMismatch {
            id: r.id.clone(),
            mujoco: mass,
            model: r.robot.model.total_mass,
        });
    }
    let prefix = format!("{}/", r.id);
    let mujoco: Vec<String> = (0..raw.njnt as usize)
        .filter(|&j| is_hinge_or_slide(raw, j))
        .map(|j| id2name(raw, mjtObj::mjOBJ_JOINT, j))
        .filter_map(|n| n.strip_prefix(&prefix).map(str::to_string))
        .collect();
    if mujoco != r.robot.actuated_joints {
        return Err(WorldError::JointOrderMismatch {
            id: r.id.clone(),
            mujoco,
            model: r.robot.actuated_joints.clone(),
        });
    }
    Ok(())
}

/// Joint `j` is a hinge or a slide (a robot's actuated joint, not a free joint).
fn is_hinge_or_slide(raw: &mjModel, j: usize) -> bool {
    let t = unsafe { *raw.jnt_type.add(j) };
    t == mujoco_c::mjtJoint::mjJNT_HINGE as i32 || t == mujoco_c::mjtJoint::mjJNT_SLIDE as i32
}

/// A small deterministic generator for initial-condition noise.
pub(crate) struct SplitMix(pub u64);

impl SplitMix {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn gaussian(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// The description path relative to the workspace, for messages.
pub fn display_path(p: &Path) -> String {
    p.display().to_string()
}
