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
//!   (`team capacity`);
//! * [`motion`]: the same along the whole motion (poses sampled along the references, with
//!   the object's reference acceleration): the plan's check at the scenario's mass
//!   ([`motion::check_along`]) and the heaviest object held everywhere
//!   ([`motion::capacity_along`]);
//! * [`simulated`]: the heaviest object held in MuJoCo, by bisection over closed-loop runs, to
//!   measure the computed capacity against (`team capacity --simulate`).

pub mod motion;

use std::sync::Arc;

use coordinator::capacity::{CapacityError, StaticProblem};
use coordinator::{ControllerSpec, PidcConfig};
use nalgebra::Vector3;
use protocol::{DynamicsTerms, RobotDescription};
use robot_agent::dynamics_source::robot_description;
use robot_agent::terms::TermsError;
use robot_model::Robot;
use sim_bridge::world::WorldSpec;
use thiserror::Error;

use crate::TEAM;
use planner::gait::HandLoad;

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
    #[error("robot {robot}: {reason}")]
    Kinematics { robot: String, reason: String },
    #[error("robot {robot} cannot follow the references at t = {t:.2} s of the motion: {source}")]
    Reach { robot: String, t: f64, source: robot_model::ik::IkError },
    #[error(
        "at t = {t:.2} s of the motion (object at [{:.3}, {:.3}, {:.3}] m): {source}",
        object[0], object[1], object[2]
    )]
    AlongMotion { t: f64, object: [f64; 3], source: CapacityError },
    #[error("at the start pose: {0}")]
    Capacity(#[from] CapacityError),
}

/// Each robot's dynamics terms at its start configuration, at rest, every foot in stance and
/// the hand in grasp, with its description: what the coordinator gets in a run.
pub fn start_terms(
    world: &WorldSpec,
    robots: &[Arc<Robot>],
) -> Result<(Vec<DynamicsTerms>, Vec<RobotDescription>), CheckError> {
    if robots.len() != world.robots.len() {
        return Err(CheckError::RobotCount(robots.len(), world.robots.len()));
    }
    let mut terms = Vec::new();
    let mut descs = Vec::new();
    for (i, (placement, robot)) in world.robots.iter().zip(robots).enumerate() {
        let q = motion::start_q(world, i, robot)?;
        terms.push(motion::rest_terms(
            robot,
            &placement.id,
            &q,
            &robot_agent::terms::ActiveContacts::all_stance(robot),
        )?);
        descs.push(robot_description(robot, TEAM, &placement.id));
    }
    Ok((terms, descs))
}

/// The static problem of a world (robots at their placements, the object where it starts)
/// with the controller's margins.
pub fn static_problem(
    world: &WorldSpec,
    robots: &[Arc<Robot>],
    cfg: &PidcConfig,
) -> Result<StaticProblem, CheckError> {
    let object = world.object.ok_or(CheckError::NoObject)?;
    let (terms, descs) = start_terms(world, robots)?;
    Ok(StaticProblem::build(
        &terms,
        &descs,
        &cfg.contact_margins(),
        Vector3::from(object.position),
    )?)
}

/// The statics of a plan's start pose from the static team problem: with `check` (the
/// payload margin, a share of the mass), a load that no forces within the controller's limits
/// hold with that margin is refused ([`CapacityError::Infeasible`] names the binding limits);
/// the answer is what the object applies to each robot's hand (the forces that hold it, or
/// where none do, the least-violation ones), which a walk's planner keeps inside the support
/// triangle with each robot's weight.
pub fn start_hand_loads(
    world: &WorldSpec,
    robots: &[Arc<Robot>],
    cfg: &PidcConfig,
    check: Option<f64>,
) -> Result<Vec<(String, HandLoad)>, CheckError> {
    let mass = world.object.ok_or(CheckError::NoObject)?.mass;
    let problem = static_problem(world, robots, cfg)?;
    let lambda = match problem.solve(mass) {
        Ok(sol) => sol.lambda,
        Err(CapacityError::Infeasible { .. }) if check.is_none() => problem.relaxed(mass)?.lambda,
        Err(e) => return Err(e.into()),
    };
    if let Some(margin) = check.filter(|m| *m > 0.0) {
        problem.solve(mass * (1.0 + margin))?;
    }
    Ok(problem
        .hand_wrenches(&lambda)
        .into_iter()
        .map(|(robot, point, w)| {
            (
                robot,
                HandLoad {
                    point,
                    force: w.fixed_rows::<3>(0).into_owned(),
                    moment: w.fixed_rows::<3>(3).into_owned(),
                },
            )
        })
        .collect())
}

/// The PIDC configuration of a controller (the check follows the controller's margins).
pub fn pidc_config(controller: &ControllerSpec) -> Result<&PidcConfig, CheckError> {
    match controller {
        ControllerSpec::Pidc(c) => Ok(c),
        other => Err(CheckError::NotPidc(other.kind().to_string())),
    }
}

/// The team problem along a plan's motion, walks included ([`motion::motion_samples`]).
pub fn samples_of(
    world: &WorldSpec,
    robots: &[Arc<Robot>],
    refs: &crate::references::ReferencePlan,
    cfg: &PidcConfig,
) -> Result<Vec<motion::MotionSample>, CheckError> {
    let object = world.object.ok_or(CheckError::NoObject)?;
    let inertia =
        object.principal_inertia().map(|i| if object.mass > 0.0 { i / object.mass } else { 0.0 });
    motion::motion_samples(world, robots, refs, cfg, inertia)
}
