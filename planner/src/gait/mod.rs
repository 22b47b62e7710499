//! The static walk (crawl) planner (`docs/walking.md`): one foot in swing at a time, the torso
//! shifted before each lift-off so that the centre of pressure (where the ground carries the
//! robot's weight and the load in its hand) lies inside the triangle of the other three feet
//! with a margin, the foot unloaded by a force ramp, swung with a lift
//! height and zero velocity at touchdown, and placed where the torso's path puts it. References:
//! the ETH static-gait controllers (CoM over the support polygon), OCS2's swing trajectories.
//!
//! Pure and deterministic: [`GaitPlan::new`] turns each robot's torso waypoints into a timed
//! plan; its queries give, at any time, the torso, object and swing-foot references, the
//! unloading ramps, the planned stance and every contact change.
//!
//! * [`support`]: the centre of pressure with the hand's load, the support triangle, a point's
//!   margin in it and each foot's share of the weight, and the shift that reaches a margin and
//!   a share (along a line, or the shortest).
//! * [`swing`]: the quintic blend and the swing-foot trajectory.
//! * [`schedule`]: waypoints to cycles and steps, the timed plan and its queries.

pub mod schedule;
pub mod support;
pub mod swing;

use nalgebra::{Isometry3, Vector3};
use serde::Deserialize;
use thiserror::Error;

pub use schedule::{GaitPlan, Step, HALT_GUARD};
pub use support::HandLoad;

/// The crawl's parameters (a scenario's `[walk.gait]`; every field has a default).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GaitParams {
    /// Largest horizontal displacement of a foot in one step, m.
    pub stride: f64,
    /// Largest torso yaw change per gait cycle (four steps), deg.
    pub max_turn_deg: f64,
    /// Swing apex above the straight line from lift-off to touchdown, m.
    pub lift_height: f64,
    /// Torso shift before each lift-off, s.
    pub t_shift: f64,
    /// Force ramp that unloads the foot before its lift-off, s.
    pub t_unload: f64,
    pub t_swing: f64,
    /// After the touchdown, before the next shift (the foot's load ramps up), s.
    pub t_load: f64,
    /// Required distance of the centre of pressure (the robot's weight and its hand's load)
    /// inside the support triangle at lift-off, m.
    pub margin: f64,
    /// Least share of the weight each support foot carries at lift-off (`0`: none asked; less
    /// than `1/3`, the triangle's centroid; default 0.1): the centre of pressure's barycentric
    /// coordinate in the support triangle, its distance from a foot's opposite edge over the
    /// foot's own distance from it. A distance margin alone leaves little on the far foot of a
    /// long, thin triangle (README, "Walking while holding").
    pub min_share: f64,
    /// The swing ends this far below the foothold, pressing the foot down, m.
    pub touchdown_depth: f64,
    /// The contact set that lands the foot is due this long before the planned touchdown, s
    /// (a foot that touches a little early is switched as soon as its force says so).
    pub touchdown_window: f64,
    /// Bound on the foot's normal force at the start of the unloading ramp (and at the end of
    /// the loading ramp), N.
    pub unload_force: f64,
    /// Also keep the centre of pressure with the hand's load (`WalkingRobot::hand`) `margin`
    /// inside, not only the bare centre of mass. Off by default: it stopped three robots with
    /// 2 kg from falling in one run, but in the CI's four-robot and three-robot walks the palms
    /// slipped 2 cm at the fourth step and the team let go (README, "Known limits").
    pub hand_load: bool,
    /// Which way the torso shifts before a lift-off (`"least"`, the default, or `"incentre"`).
    pub shift: ShiftRule,
}

/// Which way the torso shifts before a lift-off to put the centre of mass (and of pressure)
/// where [`GaitParams::margin`] and [`GaitParams::min_share`] ask.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ShiftRule {
    /// Towards the incentre of the support triangle until the conditions hold: its shifts are
    /// longer and mostly fore and aft, and three-robot teams rocked onto a diagonal with it
    /// (README, "Known limits").
    Incentre,
    /// The shortest shift that meets them ([`support::least_shift`]): across the triangle's
    /// nearest edge, often mostly sideways, rather than towards its incentre.
    Least,
}

impl Default for GaitParams {
    fn default() -> Self {
        GaitParams {
            stride: 0.10,
            max_turn_deg: 15.0,
            lift_height: 0.08,
            t_shift: 0.8,
            t_unload: 0.15,
            t_swing: 0.5,
            t_load: 0.15,
            margin: 0.04,
            min_share: 0.1,
            touchdown_depth: 0.01,
            touchdown_window: 0.08,
            unload_force: 250.0,
            hand_load: false,
            shift: ShiftRule::Least,
        }
    }
}

impl GaitParams {
    fn check(&self) -> Result<(), GaitError> {
        let positive = [
            ("stride", self.stride),
            ("max_turn_deg", self.max_turn_deg),
            ("t_shift", self.t_shift),
            ("t_unload", self.t_unload),
            ("t_swing", self.t_swing),
            ("t_load", self.t_load),
            ("unload_force", self.unload_force),
        ];
        for (what, x) in positive {
            if !(x.is_finite() && x > 0.0) {
                return Err(GaitError::Params(format!("{what} = {x} must be positive")));
            }
        }
        let non_negative = [
            ("lift_height", self.lift_height),
            ("margin", self.margin),
            ("touchdown_depth", self.touchdown_depth),
            ("touchdown_window", self.touchdown_window),
        ];
        for (what, x) in non_negative {
            if !(x.is_finite() && x >= 0.0) {
                return Err(GaitError::Params(format!("{what} = {x} must be non-negative")));
            }
        }
        if !(self.min_share.is_finite() && (0.0..1.0 / 3.0).contains(&self.min_share)) {
            return Err(GaitError::Params(format!(
                "min_share = {} must be at least 0 and less than 1/3 (the centroid's share)",
                self.min_share
            )));
        }
        if self.touchdown_window >= self.t_swing {
            return Err(GaitError::Params(format!(
                "touchdown_window = {} must be shorter than t_swing = {}",
                self.touchdown_window, self.t_swing
            )));
        }
        Ok(())
    }

    /// One step's duration: shift, unload, swing, load.
    pub fn step_time(&self) -> f64 {
        self.t_shift + self.t_unload + self.t_swing + self.t_load
    }
}

/// A robot the planner walks.
#[derive(Debug, Clone)]
pub struct WalkingRobot {
    pub robot: String,
    /// Its four foot frames (description order) and their start centre positions (world).
    pub feet: Vec<(String, Vector3<f64>)>,
    /// The whole robot's centre of mass in the torso frame, and its mass, kg.
    pub com_offset: Vector3<f64>,
    pub mass: f64,
    /// The ground's height under the feet (their contact points), m.
    pub ground_z: f64,
    /// What the object applies to its hand at the walk's start (`None`: nothing in hand). It
    /// moves with the object: held where it is, or carried along the object's waypoints.
    pub hand: Option<HandLoad>,
    /// Torso poses, the first the start; every robot of a plan has as many. A robot whose
    /// waypoints repeat does not walk there.
    pub waypoints: Vec<Isometry3<f64>>,
}

/// Why a walk cannot be planned.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum GaitError {
    #[error("gait parameters: {0}")]
    Params(String),
    #[error("robot {robot}: {reason}")]
    Robot { robot: String, reason: String },
    #[error("the object has {got} waypoints, the robots {expected}")]
    ObjectWaypoints { expected: usize, got: usize },
    #[error(
        "robot {robot}, step {step} (foot {foot}): the centre of pressure cannot be {margin} m \
         inside the support triangle with every foot carrying {min_share} of the weight (its \
         inradius is {inradius:.3} m); lower walk.gait.margin or walk.gait.min_share, or step \
         shorter"
    )]
    Margin { robot: String, step: usize, foot: String, margin: f64, min_share: f64, inradius: f64 },
}
