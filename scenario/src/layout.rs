//! The planner on the simulator's world: the world spec's object and robots as the planner's
//! [`ObjectBox`] and [`BasePlacement`]s, the hands the planner puts on the object written back
//! into the spec's robots, and the planned hands handed to the controller as its grasp
//! ([`PlannedHand`]).

use std::sync::Arc;

use coordinator::building_blocks::grasp::PlannedHand;
use nalgebra::Isometry3;
use planner::grasp::GraspPlanError;
use planner::placement::{BasePlacement, ObjectBox};
use robot_model::ik::IkSolution;
use robot_model::Robot;
use sim_bridge::world::{ObjectSpec, RobotPlacement, WorldSpec};

/// The planner's view of the simulator's object: its box and pose.
pub fn object_box(object: &ObjectSpec) -> ObjectBox {
    ObjectBox { size: object.size, position: object.position, orientation: object.orientation }
}

/// The planner's view of the world's robots: each one's id, base and joint overrides.
pub fn base_placements(robots: &[RobotPlacement]) -> Vec<BasePlacement> {
    robots
        .iter()
        .map(|r| BasePlacement {
            id: r.id.clone(),
            base_position: r.base_position,
            base_yaw: r.base_yaw,
            joint_overrides: r.joint_overrides.clone(),
        })
        .collect()
}

/// Put every robot's hand flat on its face of the world's object (`planner::grasp::place_hands`)
/// and write the arm joints into the spec's placements. `robots`: loaded, in the spec's order.
/// Returns the solutions in robot order.
pub fn place_hands(
    spec: &mut WorldSpec,
    robots: &[Arc<Robot>],
) -> Result<Vec<IkSolution>, GraspPlanError> {
    let object = spec.object.ok_or(GraspPlanError::NoObject)?;
    let mut placements = base_placements(&spec.robots);
    let solutions = planner::grasp::place_hands(&object_box(&object), &mut placements, robots)?;
    for (r, p) in spec.robots.iter_mut().zip(placements) {
        r.joint_overrides = p.joint_overrides;
    }
    Ok(solutions)
}

/// Each hand's grasp as planned ([`PlannedHand`]): its frame's pose at the solved
/// configuration (`solutions`, from [`place_hands`], robot order) against the object at
/// `object`. The controller fits the object from the hands with these whenever it starts.
pub fn planned_grasp(
    spec: &WorldSpec,
    robots: &[Arc<Robot>],
    solutions: &[IkSolution],
    object: &Isometry3<f64>,
) -> Result<Vec<PlannedHand>, GraspPlanError> {
    let hands = planner::grasp::hand_poses(&base_placements(&spec.robots), robots, solutions)?;
    Ok(spec
        .robots
        .iter()
        .zip(robots)
        .zip(&hands)
        .map(|((r, robot), hand)| PlannedHand::new(&r.id, &robot.hand_frame, hand, object))
        .collect())
}
