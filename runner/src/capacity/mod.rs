//! The payload check of a plan: the static team problem ([`coordinator::capacity`]) at the
//! start pose, before anything runs.
//!
//! The team's terms at the start pose come from the agents' own code: each robot's start
//! configuration (its placement: base pose, standing joints, the arm joints the grasp planner
//! solved), at rest, through `robot_agent::terms::TermsBuilder` with every foot in stance and
//! the hand in grasp, and its description through `robot_description`: the same
//! `DynamicsTerms` and `RobotDescription` the coordinator assembles in a run. The object is
//! taken where the scenario puts it (the hands are placed on its faces).
//!
//! * [`start_hand_loads`]: whether the scenario's object is held ([`crate::plan::plan`] checks
//!   it unless the scenario says `capacity_check = false`) and what each hand carries at the
//!   start (a walk is planned with it);
//! * [`capacity`]: the heaviest object the team holds in that configuration, by bisection
//!   (`team capacity`).

use std::sync::Arc;

use coordinator::capacity::{Capacity, CapacityError, StaticProblem, REACHED_TOL};
use coordinator::{ControllerSpec, PidcConfig};
use nalgebra::{UnitQuaternion, Vector3};
use protocol::{DynamicsTerms, Header, Pose, RobotDescription, RobotState};
use robot_agent::dynamics_source::robot_description;
use robot_agent::terms::{empty_terms, ActiveContacts, TermsBuilder, TermsError};
use robot_model::Robot;
use sim_bridge::world::WorldSpec;
use thiserror::Error;

use planner::gait::HandLoad;
use crate::plan::{Plan, TEAM};

/// Why the check could not run or refused the load.
#[derive(Debug, Error)]
pub enum CheckError {
    #[error("robot {robot}: dynamics terms at the start pose: {source}")]
    Terms { robot: String, source: TermsError },
    #[error("robot {robot}: joint {joint} of its placement is not in its model")]
    UnknownJoint { robot: String, joint: String },
    #[error("the world has no object")]
    NoObject,
    #[error("{0} robots loaded for {1} placements")]
    RobotCount(usize, usize),
    #[error("the payload check needs the pidc controller (this scenario runs {0})")]
    NotPidc(String),
    #[error(transparent)]
    Capacity(#[from] CapacityError),
}

/// Each robot's dynamics terms at its start configuration, at rest, every foot in stance and
/// the hand in grasp, with its description: what the coordinator gets in a run.
pub fn start_terms(world: &WorldSpec, robots: &[Arc<Robot>]) -> Result<(Vec<DynamicsTerms>, Vec<RobotDescription>), CheckError> {
    if robots.len() != world.robots.len() {
        return Err(CheckError::RobotCount(robots.len(), world.robots.len()));
    }
    let mut terms = Vec::new();
    let mut descs = Vec::new();
    for (placement, robot) in world.robots.iter().zip(robots) {
        let id = placement.id.as_str();
        let terms_err = |source| CheckError::Terms { robot: id.to_string(), source };
        let mut joints: Vec<f64> = robot.standing_q.iter().skip(robot.model.nq - robot.model.joint_names.len()).copied().collect();
        for (j, v) in &placement.joint_overrides {
            let k = robot.model.joint_names.iter().position(|n| n == j).ok_or_else(|| CheckError::UnknownJoint { robot: id.to_string(), joint: j.clone() })?;
            joints[k] = *v;
        }
        let yaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), placement.base_yaw);
        let state = RobotState {
            header: Header::new(TEAM, Some(id), 0, 0),
            base_pose: Pose { position: placement.base_position, orientation: [yaw.w, yaw.i, yaw.j, yaw.k] },
            base_twist: [0.0; 6],
            joint_velocities: vec![0.0; joints.len()],
            joint_positions: joints,
            time: 0.0,
            foot_forces: Vec::new(),
        };
        let mut builder = TermsBuilder::new(robot).map_err(terms_err)?;
        builder.load_state(robot, &state).map_err(terms_err)?;
        let mut out = empty_terms(TEAM, id);
        builder.compute(robot, &ActiveContacts::all_stance(robot), &mut out).map_err(terms_err)?;
        terms.push(out);
        descs.push(robot_description(robot, TEAM, id));
    }
    Ok((terms, descs))
}

/// The static problem of a world (robots at their placements, the object where it starts)
/// with the controller's margins.
pub fn static_problem(world: &WorldSpec, robots: &[Arc<Robot>], cfg: &PidcConfig) -> Result<StaticProblem, CheckError> {
    let object = world.object.ok_or(CheckError::NoObject)?;
    let (terms, descs) = start_terms(world, robots)?;
    Ok(StaticProblem::build(&terms, &descs, &cfg.contact_margins(), Vector3::from(object.position))?)
}

/// The statics of a plan's start pose from one solve of the static team problem: with
/// `check`, a load that no forces within the controller's limits hold is refused
/// ([`CapacityError::Infeasible`] names the binding limits); the answer is what the object applies to each robot's hand (the forces
/// that hold it, or without `check` and where none do, the least-violation ones), which a
/// walk's planner keeps inside the support triangle with each robot's weight.
pub fn start_hand_loads(world: &WorldSpec, robots: &[Arc<Robot>], cfg: &PidcConfig, check: bool) -> Result<Vec<(String, HandLoad)>, CheckError> {
    let mass = world.object.ok_or(CheckError::NoObject)?.mass;
    let problem = static_problem(world, robots, cfg)?;
    let lambda = match problem.solve(mass) {
        Ok(sol) => sol.lambda,
        Err(CapacityError::Infeasible { .. }) if !check => problem.relaxed(mass)?.lambda,
        Err(e) => return Err(e.into()),
    };
    Ok(problem
        .hand_wrenches(&lambda)
        .into_iter()
        .map(|(robot, point, w)| (robot, HandLoad { point, force: w.fixed_rows::<3>(0).into_owned(), moment: w.fixed_rows::<3>(3).into_owned() }))
        .collect())
}

/// The PIDC configuration of a controller (the check follows the controller's margins).
pub fn pidc_config(controller: &ControllerSpec) -> Result<&PidcConfig, CheckError> {
    match controller {
        ControllerSpec::Pidc(c) => Ok(c),
        other => Err(CheckError::NotPidc(other.kind().to_string())),
    }
}

/// The heaviest object the plan's team holds in its start configuration, within `tolerance` kg.
pub fn capacity(plan: &Plan, tolerance: f64) -> Result<Capacity, CheckError> {
    let problem = static_problem(&plan.scene.world, &plan.loaded_robots(), pidc_config(&plan.controller)?)?;
    Ok(problem.capacity(tolerance)?)
}

/// The capacity as `team capacity` prints it.
pub fn summary(plan: &Plan, cap: &Capacity, tolerance: f64, seconds: f64) -> String {
    let s = &plan.scenario;
    let mut out = format!(
        "{}: {} robots, object {:?} m at {:?}, friction_margin {:.3}, patch_margin {:.3}, min_hand_force {} N, min_foot_force {} N\n",
        s.name,
        s.robots.len(),
        s.object.size,
        s.object.position,
        s.friction_margin,
        s.patch_margin,
        s.min_hand_force,
        s.min_foot_force
    );
    out += &format!(
        "capacity: {:.3} kg (held; {:.3} kg is not; bisection to {tolerance} kg, {} static problems, {:.0} ms)\n",
        cap.mass,
        cap.infeasible_at,
        cap.solves,
        1e3 * seconds
    );
    out += &format!("limits the forces holding {:.3} kg reach (within {REACHED_TOL} N or Nm):\n", cap.mass);
    for b in &cap.reached {
        out += &format!("  {b}\n");
    }
    out += &format!("binding limits at {:.3} kg (the relaxed problem's excess), largest first:\n", cap.infeasible_at);
    for b in &cap.binding {
        out += &format!("  {b}\n");
    }
    out
}
