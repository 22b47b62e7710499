//! A scenario's walk (`docs/walking.md`): its specification ([`spec`]), the crawl of
//! [`crate::gait`] planned from the scenario's waypoints and the robots' standing poses
//! ([`Walk::plan`]), the arm's reach along it ([`reach`]), and what a run sends for it
//! ([`references`]): the torso, object and swing-foot references, the feet's unloading ramps,
//! and each robot's contact sets, published ahead of time with the tick they apply from. A
//! walk is measured from the ground truth by the runner (`evaluation::walking`).

pub mod reach;
pub mod references;
pub mod spec;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use robot_model::Robot;
use thiserror::Error;

use crate::gait::{GaitError, GaitPlan, HandLoad, WalkingRobot};
use crate::placement::BasePlacement;
pub use spec::{WalkFrame, WalkSpec, WalkSpecError};

/// Why a walk cannot be planned.
#[derive(Debug, Error)]
pub enum WalkError {
    #[error("walk: robot {robot}: {reason}")]
    Robot { robot: String, reason: String },
    #[error("walk: {0}")]
    Gait(#[from] GaitError),
    #[error(
        "walk: the scenario lasts {duration} s but the walk ends at {end:.2} s: \
         set duration >= {end:.1}"
    )]
    TooShort { duration: f64, end: f64 },
    #[error(
        "walk: robot {robot}'s arm cannot keep its hand on the object at {time:.2} s, with its \
         torso {offset:.3} m from its start ({reason}): stand it nearer, or walk less far"
    )]
    Reach { robot: String, time: f64, offset: f64, reason: String },
    #[error(
        "walk: robot {robot}'s arm would need {torque:.1} N m at {joint} (limit {limit} N m) to \
         hold the object with its torso shifted for the step at {time:.2} s: lighten the \
         object, lower walk.gait.margin, or stand the robots otherwise"
    )]
    ArmTorque { robot: String, time: f64, joint: String, torque: f64, limit: f64 },
}

/// A planned walk: the gait and who walks.
#[derive(Debug)]
pub struct Walk {
    pub gait: GaitPlan,
    /// Robot ids, in the scenario's order (the gait's robot indices).
    pub robots: Vec<String>,
    pub walking: Vec<bool>,
    /// Each robot's foot frames, in its description's order (the gait's foot indices), and
    /// the links that carry them (the simulator's contact bodies).
    pub feet: Vec<Vec<String>>,
    pub foot_links: Vec<Vec<String>>,
    /// Each robot's foot sphere radius, m.
    pub foot_radius: Vec<f64>,
    /// The object's reference moves with the team (`frame = "team"`).
    pub moves_object: bool,
}

/// Where a standing robot's feet (centres), torso, hand and centre of mass are, from forward
/// kinematics at its standing pose with the placement's joint overrides (`q`).
struct Standing {
    q: Vec<f64>,
    torso: Isometry3<f64>,
    hand: Isometry3<f64>,
    feet: Vec<Vector3<f64>>,
    com_in_torso: Vector3<f64>,
    mass: f64,
}

impl Standing {
    /// The gait's input for robot `id` standing here, with its hand's load and its torso's
    /// waypoints.
    fn into_walking(
        self,
        id: &str,
        robot: &Robot,
        hand: Option<HandLoad>,
        waypoints: Vec<Isometry3<f64>>,
    ) -> WalkingRobot {
        // The feet's contact points: their sphere's lowest points.
        let ground_z = self.feet.iter().map(|f| f.z).sum::<f64>() / self.feet.len().max(1) as f64
            - robot.feet.radius;
        WalkingRobot {
            robot: id.to_string(),
            feet: robot.foot_frames.iter().cloned().zip(self.feet).collect(),
            com_offset: self.com_in_torso,
            mass: self.mass,
            ground_z,
            hand,
            waypoints,
        }
    }
}

/// A robot's configuration at its placement: the standing pose, the placement's joint
/// overrides (the hands on the object), the base where the placement puts it.
fn placed_q(robot: &Robot, placement: &BasePlacement) -> Result<Vec<f64>, String> {
    let model = &robot.model;
    let mut q: Vec<f64> = robot.standing_q.iter().copied().collect();
    let off = model.nq - model.joint_names.len();
    for (j, v) in &placement.joint_overrides {
        let k = model
            .joint_names
            .iter()
            .position(|n| n == j)
            .ok_or_else(|| format!("unknown joint {j}"))?;
        q[off + k] = *v;
    }
    q[0..3].copy_from_slice(&placement.base_position);
    let yaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), placement.base_yaw);
    q[3..7].copy_from_slice(&[yaw.w, yaw.i, yaw.j, yaw.k]);
    Ok(q)
}

fn standing(robot: &Robot, placement: &BasePlacement) -> Result<Standing, String> {
    let model = &robot.model;
    let q = placed_q(robot, placement)?;
    let mut data = robot_model::Data::new(model);
    robot_model::forward_kinematics(model, &mut data, &q, &vec![0.0; model.nv])
        .map_err(|e| e.to_string())?;
    let frame = |name: &str| model.frame_id(name).map(|f| data.o_m_f[f]).map_err(|e| e.to_string());
    let pose = |name: &str| {
        frame(name).map(|m| {
            Isometry3::from_parts(Translation3::from(m.trans), UnitQuaternion::from_matrix(&m.rot))
        })
    };
    let (torso, hand) = (pose(&robot.torso_frame)?, pose(&robot.hand_frame)?);
    let feet = robot
        .foot_frames
        .iter()
        .map(|f| frame(f).map(|p| p.trans))
        .collect::<Result<Vec<_>, _>>()?;
    let (mass, com) = robot_model::center_of_mass(model, &data);
    Ok(Standing {
        com_in_torso: torso.inverse_transform_point(&com.into()).coords,
        mass,
        q,
        torso,
        hand,
        feet,
    })
}

/// Waypoint `w = [dx, dy, yaw_deg]` applied to a start pose: in the pose's own frame
/// (`robot`), or as the team's rigid motion about `centre` (`team`).
fn moved(
    start: &Isometry3<f64>,
    w: &[f64; 3],
    frame: WalkFrame,
    centre: &Vector3<f64>,
) -> Isometry3<f64> {
    let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), w[2].to_radians());
    match frame {
        WalkFrame::Robot => start * Isometry3::from_parts(Translation3::new(w[0], w[1], 0.0), turn),
        WalkFrame::Team => {
            let about = Translation3::from(centre + Vector3::new(w[0], w[1], 0.0))
                * Isometry3::from_parts(Translation3::identity(), turn)
                * Translation3::from(-centre);
            about * start
        }
    }
}

impl Walk {
    /// The walk of `spec` for robots standing at `placements` around an object starting at
    /// `object_start`, on a scenario of `duration` s, with what the object applies to each
    /// robot's hand at the start (`hand_loads`, by robot id; a robot not named carries nothing:
    /// the planner then keeps its bare centre of mass inside the support triangle).
    pub fn plan(
        spec: &WalkSpec,
        robots: &[(String, std::sync::Arc<Robot>)],
        placements: &[BasePlacement],
        object_start: &Isometry3<f64>,
        hand_loads: &[(String, HandLoad)],
        duration: f64,
    ) -> Result<Walk, WalkError> {
        let centre = object_start.translation.vector;
        let mut inputs = Vec::new();
        let mut walking = Vec::new();
        let mut feet = Vec::new();
        let mut foot_links = Vec::new();
        let mut foot_radius = Vec::new();
        // Each robot's standing configuration, torso and hand, for the reach check.
        let mut arms = Vec::new();
        for ((id, robot), placement) in robots.iter().zip(placements) {
            let s = standing(robot, placement)
                .map_err(|reason| WalkError::Robot { robot: id.clone(), reason })?;
            arms.push((s.q.clone(), s.torso, s.hand));
            let walks = spec.frame == WalkFrame::Team || spec.walks(id);
            let waypoints = torso_waypoints(spec, &s.torso, walks, &centre);
            let hand = hand_loads.iter().find(|(r, _)| r == id).map(|(_, h)| *h);
            tracing::debug!(robot = %id, ?hand, "walk: the hand's load");
            inputs.push(s.into_walking(id, robot, hand, waypoints));
            walking.push(walks);
            feet.push(robot.foot_frames.clone());
            foot_links.push(foot_links_of(robot));
            foot_radius.push(robot.feet.radius);
        }
        let object = object_path(spec, object_start, &centre);
        let gait = GaitPlan::new(&inputs, object.as_deref(), &spec.gait, spec.start)?;
        if gait.end_time() > duration {
            return Err(WalkError::TooShort { duration, end: gait.end_time() });
        }
        let walk = Walk {
            gait,
            robots: robots.iter().map(|(id, _)| id.clone()).collect(),
            walking,
            feet,
            foot_links,
            foot_radius,
            moves_object: object.is_some(),
        };
        walk.check_reach(robots, &arms, object_start, hand_loads)?;
        Ok(walk)
    }

    /// Every walking robot's arm keeps its hand on the object along the walk ([`reach::check`]),
    /// from its standing configuration, torso and hand (`arms`).
    fn check_reach(
        &self,
        robots: &[(String, std::sync::Arc<Robot>)],
        arms: &[StandingArm],
        object_start: &Isometry3<f64>,
        hand_loads: &[(String, HandLoad)],
    ) -> Result<(), WalkError> {
        for (i, ((id, robot), (q, torso, hand))) in
            robots.iter().zip(arms).enumerate().filter(|(i, _)| self.walking[*i])
        {
            let load = hand_loads.iter().find(|(r, _)| r == id).map(|(_, h)| h);
            reach::check(self, i, robot, q, torso, hand, object_start, load)?;
        }
        Ok(())
    }
}

/// A standing robot's configuration, torso pose and hand pose, for the reach check.
type StandingArm = (Vec<f64>, Isometry3<f64>, Isometry3<f64>);

/// The torso's waypoints: its standing pose `torso`, then the spec's path (where it stays when
/// the robot does not walk).
fn torso_waypoints(
    spec: &WalkSpec,
    torso: &Isometry3<f64>,
    walks: bool,
    centre: &Vector3<f64>,
) -> Vec<Isometry3<f64>> {
    let mut waypoints = vec![*torso];
    waypoints.extend(spec.path.iter().map(|w| {
        if walks {
            moved(torso, w, spec.frame, centre)
        } else {
            *torso
        }
    }));
    waypoints
}

/// The links that carry the robot's foot frames (an empty name for a frame without one).
fn foot_links_of(robot: &Robot) -> Vec<String> {
    let link = |f: &String| {
        robot
            .model
            .frame_id(f)
            .ok()
            .and_then(|id| robot.model.parent_link(id))
            .map(str::to_string)
            .unwrap_or_default()
    };
    robot.foot_frames.iter().map(link).collect()
}

/// The object's waypoints when the team walks it (`frame = "team"`): its start, then the path
/// as the team's rigid motion about `centre`; `None` otherwise.
fn object_path(
    spec: &WalkSpec,
    object_start: &Isometry3<f64>,
    centre: &Vector3<f64>,
) -> Option<Vec<Isometry3<f64>>> {
    (spec.frame == WalkFrame::Team).then(|| {
        std::iter::once(*object_start)
            .chain(spec.path.iter().map(|w| moved(object_start, w, WalkFrame::Team, centre)))
            .collect()
    })
}
