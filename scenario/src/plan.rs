//! From a [`Scenario`] to what every component runs: the bridge's [`Scene`] (world with the
//! hands placed on the object by IK, pushes, settle and run lengths), the coordinator's
//! [`ControllerSpec`] (PIDC or MQP with the scenario's gains, object and minimum forces), the
//! agents'
//! description files, and the [`ReferencePlan`] that turns ticks into task references.
//! Each description file is loaded here once ([`RobotCache`]); the loaded robots travel with
//! the plan to the grasp planner, the world build and the agents.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use coordinator::building_blocks::grasp::PlannedHand;
use coordinator::{ControllerSpec, MqpConfig, PidcConfig, ShellConfig};
use nalgebra::{Isometry3, Matrix3, Translation3, Vector3};
use protocol::conventions::quat_from_wxyz;
use robot_model::{DescriptionError, Robot, RobotCache};
use sim_bridge::perturbation::Perturbation;
use sim_bridge::scene::Scene;
use sim_bridge::world::{ContactParams, ObjectSpec, RobotPlacement, SolverParams, WorldSpec};
use thiserror::Error;

use crate::file::{PushSection, Scenario};
use crate::references::{reference_plan, ReferencePlan};
use crate::TEAM;
use planner::gait::HandLoad;

/// What can go wrong turning a scenario into a run.
#[derive(Debug, Error)]
pub enum PlanError {
    #[error("robot {robot}: {source}")]
    Description { robot: String, source: Box<DescriptionError> },
    #[error("placing the hands on the object: {0}")]
    Ik(#[from] planner::grasp::GraspPlanError),
    #[error("invalid world: {0}")]
    Placement(#[from] planner::placement::PlacementError),
    #[error(transparent)]
    World(#[from] sim_bridge::world::WorldError),
    #[error("controller: {0}")]
    Controller(#[from] coordinator::ControllerError),
    /// Not `#[from]`: the message holds the check's whole error, no source chain repeats it.
    #[error(
        "payload check (the object's mass and {} % more, `payload_margin`): {check} \
         (`capacity_check = false` runs anyway)",
        100.0 * margin
    )]
    Capacity { check: crate::payload::CheckError, margin: f64 },
    /// The start pose's statics a walk is planned with could not be solved (no check asked).
    #[error("the start pose's statics for the walk: {0}")]
    Statics(crate::payload::CheckError),
    #[error(transparent)]
    Walk(#[from] planner::walk::WalkError),
}

impl PlanError {
    /// The payload check's refusal of scenario `s`.
    fn capacity(s: &Scenario, check: crate::payload::CheckError) -> Self {
        PlanError::Capacity { check, margin: s.payload_margin }
    }
}

/// Everything a scenario run needs, for either mode.
#[derive(Debug, Clone)]
pub struct Plan {
    pub scenario: Scenario,
    pub scene: Scene,
    pub controller: ControllerSpec,
    /// The robots, in scenario order.
    pub robots: Vec<PlannedRobot>,
    pub references: ReferencePlan,
}

/// A robot of the plan.
#[derive(Debug, Clone)]
pub struct PlannedRobot {
    pub id: String,
    /// Absolute path of its description (TOML).
    pub description: PathBuf,
    /// Its actuated joints, in the order of its torque commands.
    pub joints: Vec<String>,
    /// The loaded description (shared by robots with the same file).
    pub robot: Arc<Robot>,
}

impl Plan {
    /// The team's name on the bus (`team/{team}/...`).
    pub fn team(&self) -> &str {
        &self.scene.team
    }

    /// Run as team `name` on the bus (several teams share a site's router by name).
    pub fn set_team(&mut self, name: &str) -> Result<(), protocol::ProtocolError> {
        protocol::validate_id("team", name)?;
        self.scene.team = name.to_string();
        Ok(())
    }

    /// Ticks of the whole run (settling included).
    pub fn total_ticks(&self) -> u64 {
        self.scene.clock().total_ticks()
    }

    /// The loaded robots in scenario order (the scene's world order).
    pub fn loaded_robots(&self) -> Vec<Arc<Robot>> {
        self.robots.iter().map(|r| r.robot.clone()).collect()
    }
}

/// Where relative robot description paths of a scenario are resolved: the current directory
/// when it holds them (a checkout), else the repository this crate was built from.
pub fn repo_root() -> PathBuf {
    let cwd = std::env::current_dir().unwrap_or_default();
    if cwd.join("robot-model/models").is_dir() {
        return cwd;
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().map(Path::to_path_buf).unwrap_or(cwd)
}

/// Build the plan; relative description paths are taken from `root` (the repository).
pub fn plan(s: &Scenario, root: &Path) -> Result<Plan, PlanError> {
    let (robots, placements) = load_robots(s, root)?;
    let object = s.object.world();
    let mut world = world_spec(s, placements, object);
    world.substeps()?;
    let loaded: Vec<Arc<Robot>> = robots.iter().map(|r| r.robot.clone()).collect();
    let arms = crate::layout::place_hands(&mut world, &loaded)?;
    let scene = scene_of(s, world);

    let object_at_grasp = Isometry3::from_parts(
        Translation3::from(Vector3::from(object.position)),
        quat_from_wxyz(object.orientation),
    );
    // Each hand's grasp as planned: a coordinator (re)started mid-carry finds the object by it.
    let planned_grasp =
        crate::layout::planned_grasp(&scene.world, &loaded, &arms, &object_at_grasp)?;
    let grasp =
        GraspAtStart { principal: object.principal_inertia(), object_at_grasp, planned_grasp };
    let pidc = pidc_config(s, &grasp);
    let controller = controller_spec(s, &pidc, grasp)?;
    controller.check()?;
    let hand_loads = start_hand_loads(s, &scene, &loaded, &pidc, &controller)?;
    let walk = plan_walk(s, &robots, &scene, &object, &hand_loads)?;
    let references = reference_plan(s, &scene, walk);
    if s.capacity_check && matches!(controller, ControllerSpec::Pidc(_)) {
        check_along_motion(s, &scene, &loaded, &pidc, &references)?;
    }
    Ok(Plan { scenario: s.clone(), scene, controller, robots, references })
}

/// Load each robot's description (once per file) and stand it at its floor pose; robots must
/// not stand in each other (a dense layout is refused, naming the pair).
fn load_robots(
    s: &Scenario,
    root: &Path,
) -> Result<(Vec<PlannedRobot>, Vec<RobotPlacement>), PlanError> {
    let mut placements = Vec::new();
    let mut robots = Vec::new();
    let mut cache = RobotCache::new();
    for r in &s.robots {
        let path = if r.description.is_absolute() {
            r.description.clone()
        } else {
            root.join(&r.description)
        };
        let robot = cache.load(&path).map_err(|source| PlanError::Description {
            robot: r.id.clone(),
            source: Box::new(source),
        })?;
        placements.push(sim_bridge::world::RobotPlacement::standing(
            &r.id,
            path.clone(),
            &robot,
            r.base_xy,
            r.yaw,
        )?);
        robots.push(PlannedRobot {
            id: r.id.clone(),
            description: path,
            joints: robot.actuated_joints.clone(),
            robot,
        });
    }
    let footprints = robots
        .iter()
        .map(|r| planner::placement::Footprint::of(&r.robot))
        .collect::<Result<Vec<_>, _>>()?;
    planner::placement::check_clearance(&crate::layout::base_placements(&placements), &footprints)?;
    Ok((robots, placements))
}

/// The simulator's world of the scenario: the placed robots, the object, rates and solver.
fn world_spec(s: &Scenario, placements: Vec<RobotPlacement>, object: ObjectSpec) -> WorldSpec {
    WorldSpec {
        robots: placements,
        object: Some(object),
        control_hz: s.control_hz,
        physics_hz: s.physics_hz,
        contact: ContactParams::default(),
        solver: SolverParams { noslip_iterations: s.noslip_iterations, ..SolverParams::default() },
        sensors: s.sensors,
        seed: s.seed,
        initial_joint_noise: 0.0,
    }
}

/// The bridge's scene: `world` with the scenario's pushes, its settle and run lengths
/// ([`Scenario::clock`]) and the lockstep's waits.
fn scene_of(s: &Scenario, world: WorldSpec) -> Scene {
    let clock = s.clock();
    Scene {
        team: TEAM.into(),
        world,
        perturbations: s.perturbations.iter().map(push_of).collect(),
        settle_ticks: clock.settle_ticks,
        ticks: clock.ticks,
        // Lockstep waits this long for a tick's torques: generous, a loaded machine is slow
        // but a missing robot is still named.
        command_timeout: 30.0,
        start_timeout: 60.0,
        // `team run --realtime` turns it on.
        realtime: false,
        drive_loss: s.drive_loss,
    }
}

/// The simulator's push of a scenario's `[[perturbations]]` entry.
fn push_of(p: &PushSection) -> Perturbation {
    Perturbation {
        target: if p.target.on == "object" {
            protocol::PerturbationTarget::Object
        } else {
            protocol::PerturbationTarget::RobotBody {
                robot: p.target.on.clone(),
                body: p.target.body.clone().unwrap_or_else(|| "base".into()),
            }
        },
        wrench: p.wrench,
        start: p.start,
        duration: p.duration,
    }
}

/// The object and the hands as the grasp closes, which both controllers start from.
struct GraspAtStart {
    /// The object's principal moments of inertia, kg m^2.
    principal: [f64; 3],
    /// Where the object is when the grasp closes.
    object_at_grasp: Isometry3<f64>,
    /// Where each hand holds it.
    planned_grasp: Vec<PlannedHand>,
}

/// The shared controller settings of the scenario (its gains, object, grasp, minimum forces
/// and release policy) over a controller's `defaults`.
fn shell_config(s: &Scenario, grasp: &GraspAtStart, defaults: ShellConfig) -> ShellConfig {
    let swing_gains = s.gains.feet.as_ref().map(|f| f.gains());
    ShellConfig {
        object_gains: s.gains.object.gains(),
        torso_gains: s.gains.torso.gains(),
        swing_gains: swing_gains.unwrap_or_else(|| defaults.swing_gains.clone()),
        object_mass: s.object.mass,
        object_inertia: Matrix3::from_diagonal(&Vector3::from(grasp.principal)),
        // Where the object is when the grasp closes, and where each hand holds it.
        object_pose_at_grasp: Some(grasp.object_at_grasp),
        planned_grasp: grasp.planned_grasp.clone(),
        f_min_foot: s.min_foot_force,
        f_min_hand: s.min_hand_force,
        release: s.release,
        robot_period: 1.0 / s.control_hz,
        ..defaults
    }
}

/// The PIDC configuration of the scenario: the shared settings and the scenario's friction
/// and palm-patch margins.
fn pidc_config(s: &Scenario, grasp: &GraspAtStart) -> PidcConfig {
    let defaults = PidcConfig::default();
    let shell = shell_config(s, grasp, defaults.shell.clone());
    PidcConfig {
        shell: ShellConfig {
            friction_margin: s.friction_margin,
            patch_margin: s.patch_margin,
            ..shell
        },
        ..defaults
    }
}

/// The scenario's controller; PIDC and MQP take the scenario's gains, object and minimum
/// forces, other kinds run with their defaults.
fn controller_spec(
    s: &Scenario,
    pidc: &PidcConfig,
    grasp: GraspAtStart,
) -> Result<ControllerSpec, PlanError> {
    Ok(match ControllerSpec::of_kind(&s.controller)? {
        ControllerSpec::Pidc(_) => ControllerSpec::Pidc(pidc.clone()),
        // MQP: the same gains (as acceleration gains, see MqpConfig), object and minimum
        // forces, its own friction and patch margins; its velocity bound looks one control
        // period ahead.
        ControllerSpec::Mqp(_) => {
            let defaults = MqpConfig::default();
            let shell = shell_config(s, &grasp, defaults.shell.clone());
            ControllerSpec::Mqp(MqpConfig { shell, dt: s.clock().dt(), ..defaults })
        }
        other => other,
    })
}

/// The static team problem at the start pose (crate::payload), solved once: the payload
/// check with the PIDC controller's limits, and the hands' loads a walk is planned with (the
/// same forces whichever controller runs). Empty when neither is wanted.
fn start_hand_loads(
    s: &Scenario,
    scene: &Scene,
    loaded: &[Arc<Robot>],
    pidc: &PidcConfig,
    controller: &ControllerSpec,
) -> Result<Vec<(String, HandLoad)>, PlanError> {
    let check = s.capacity_check && matches!(controller, ControllerSpec::Pidc(_));
    let mut hand_loads = Vec::new();
    if check || s.walk.is_some() {
        let t0 = std::time::Instant::now();
        let margin = check.then_some(s.payload_margin);
        hand_loads = crate::payload::start_hand_loads(&scene.world, loaded, pidc, margin)
            .map_err(|e| if check { PlanError::capacity(s, e) } else { PlanError::Statics(e) })?;
        tracing::info!(
            ms = 1e3 * t0.elapsed().as_secs_f64(),
            mass = s.object.mass,
            checked = check,
            "static team problem at the start pose solved"
        );
    }
    Ok(hand_loads)
}

/// The payload check along the whole motion (crate::payload::motion): the scenario's object
/// held at every pose sampled along the references, or the plan refused naming the time, the
/// object's position and the binding limits.
fn check_along_motion(
    s: &Scenario,
    scene: &Scene,
    loaded: &[Arc<Robot>],
    pidc: &PidcConfig,
    refs: &ReferencePlan,
) -> Result<(), PlanError> {
    let t0 = std::time::Instant::now();
    let samples = crate::payload::samples_of(&scene.world, loaded, refs, pidc)
        .map_err(|e| PlanError::capacity(s, e))?;
    crate::payload::motion::check_along(&samples, s.object.mass * (1.0 + s.payload_margin))
        .map_err(|e| PlanError::capacity(s, e))?;
    tracing::info!(
        ms = 1e3 * t0.elapsed().as_secs_f64(),
        samples = samples.len(),
        mass = s.object.mass,
        "the team problem along the motion solved"
    );
    Ok(())
}

/// The scenario's walk, planned from the robots' start poses (`None` without a `[walk]`).
pub fn plan_walk(
    s: &Scenario,
    robots: &[PlannedRobot],
    scene: &Scene,
    object: &ObjectSpec,
    hand_loads: &[(String, HandLoad)],
) -> Result<Option<Arc<planner::walk::Walk>>, PlanError> {
    let Some(w) = &s.walk else { return Ok(None) };
    let ids: Vec<(String, Arc<Robot>)> =
        robots.iter().map(|r| (r.id.clone(), r.robot.clone())).collect();
    let object_start = Isometry3::from_parts(
        Translation3::from(Vector3::from(object.position)),
        quat_from_wxyz(object.orientation),
    );
    let walk = planner::walk::Walk::plan(
        w,
        &ids,
        &crate::layout::base_placements(&scene.world.robots),
        &object_start,
        hand_loads,
        s.duration,
    )?;
    for st in walk.gait.steps() {
        tracing::debug!(
            robot = %walk.robots[st.robot],
            foot = %walk.feet[st.robot][st.foot],
            liftoff = st.liftoff,
            margin = st.margin,
            cop_margin = ?st.cop_margin,
            "planned step"
        );
    }
    let least = walk.gait.steps().iter().map(|st| st.margin).fold(f64::INFINITY, f64::min);
    tracing::info!(
        steps = walk.gait.steps().len(),
        end_s = walk.gait.end_time(),
        least_margin_m = least,
        "walk planned"
    );
    Ok(Some(Arc::new(walk)))
}
