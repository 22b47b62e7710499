//! A fallen robot goes limp and leaves its team.
//!
//! A robot whose torso has tipped over, or sunk far below the height it stood at, can no longer
//! do what the team's controller asks of it: its feet are off the ground, its hand off the
//! object, and the torques it is sent fight the floor. Fighting on, it drags the robots beside
//! it down (a fallen robot crawled into its neighbour in the three-robot walks, README
//! "Walking while holding"). Like a legged robot's own fall handling, the agent decides this
//! locally, from each state ([`FallDetector::observe`]):
//!
//! * **fallen** when the torso's tilt (the angle of its z axis from the world's: the model's
//!   base frame is z-up when the robot stands, as the URDF convention has it) exceeds
//!   [`FallLimits::max_tilt`], or its height is below [`FallLimits::min_height_ratio`] of the
//!   height of the first state (the robot stood when it started; the height check is off when
//!   that height is under [`MIN_REFERENCE_HEIGHT`], a state estimator's origin rather than a
//!   standing torso, and a walk down a ramp or stairs by half the torso's height would trip it);
//! * only for a floating-base robot: a fixed base cannot fall (the core does not watch it);
//! * then, for good (until the agent is restarted), the agent applies only joint damping
//!   (the posture hold's, [`crate::safe_mode::PostureHold::damping`]:
//!   `tau = clamp(-K_d qdot)`): it neither stands up nor swings its limbs; it refuses
//!   commands, stops sending dynamics terms and withdraws its team membership, so the
//!   coordinator solves the team without it (a member that left: with three or more robots
//!   the rest keep the object).

use protocol::Pose;

/// When a robot counts as fallen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FallLimits {
    /// Largest tilt of the torso's z axis from the vertical, rad.
    pub max_tilt: f64,
    /// Smallest torso height, as a fraction of the first state's.
    pub min_height_ratio: f64,
}

impl Default for FallLimits {
    /// 60 degrees of tilt (a standing or walking quadruped tilts by a few degrees; S1's torso
    /// task by at most ten) or half the starting height.
    fn default() -> Self {
        FallLimits { max_tilt: 60f64.to_radians(), min_height_ratio: 0.5 }
    }
}

/// Smallest starting torso height, m, for the height check (below it the check is off).
pub const MIN_REFERENCE_HEIGHT: f64 = 0.1;

/// How and when the robot fell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fall {
    /// The state tick at which the limits were first passed.
    pub tick: u64,
    /// Torso tilt, rad, and height, m, at that state.
    pub tilt: f64,
    pub height: f64,
}

/// Watches the torso's pose state by state; latches the first fall.
#[derive(Debug, Clone)]
pub struct FallDetector {
    limits: FallLimits,
    /// Torso height of the first state.
    start_height: Option<f64>,
    fallen: Option<Fall>,
}

impl FallDetector {
    pub fn new(limits: FallLimits) -> Self {
        FallDetector { limits, start_height: None, fallen: None }
    }

    /// The torso's pose at state `tick`; returns the fall if this state is the one that passed
    /// the limits (`None` before and after it).
    pub fn observe(&mut self, tick: u64, base: &Pose) -> Option<Fall> {
        if self.fallen.is_some() {
            return None;
        }
        let height = base.position[2];
        let start = *self.start_height.get_or_insert(height);
        let tilt = tilt(&base.orientation);
        let low = start >= MIN_REFERENCE_HEIGHT && height < self.limits.min_height_ratio * start;
        if tilt > self.limits.max_tilt || low {
            let fall = Fall { tick, tilt, height };
            self.fallen = Some(fall);
            return Some(fall);
        }
        None
    }

    /// The fall, once it happened.
    pub fn fallen(&self) -> Option<&Fall> {
        self.fallen.as_ref()
    }
}

/// Angle between the body z axis of the orientation `(w, x, y, z)` and the world's z axis, rad:
/// `cos = R_zz = 1 - 2 (x^2 + y^2)` for a unit quaternion (normalised here).
pub fn tilt(q: &[f64; 4]) -> f64 {
    let n2 = q.iter().map(|c| c * c).sum::<f64>();
    if n2.is_nan() || n2 <= 0.0 {
        return 0.0;
    }
    let rzz = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]) / n2;
    rzz.clamp(-1.0, 1.0).acos()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(z: f64, q: [f64; 4]) -> Pose {
        Pose { position: [0.3, -0.2, z], orientation: q }
    }

    /// About the world's x axis by `a` rad.
    fn roll(a: f64) -> [f64; 4] {
        [(a / 2.0).cos(), (a / 2.0).sin(), 0.0, 0.0]
    }

    #[test]
    fn tilt_is_the_angle_of_the_body_z_axis_from_the_vertical() {
        assert!(tilt(&[1.0, 0.0, 0.0, 0.0]).abs() < 1e-12);
        // Yaw does not tilt; roll and pitch do, by their angle; upside down is pi.
        let yaw = [(0.4f64).cos(), 0.0, 0.0, (0.4f64).sin()];
        assert!(tilt(&yaw).abs() < 1e-12);
        assert!((tilt(&roll(0.7)) - 0.7).abs() < 1e-12);
        let pitch = [(0.45f64).cos(), 0.0, (0.45f64).sin(), 0.0];
        assert!((tilt(&pitch) - 0.9).abs() < 1e-12);
        assert!((tilt(&roll(std::f64::consts::PI)) - std::f64::consts::PI).abs() < 1e-9);
        // Not normalised: the same angle. Zero: no tilt rather than NaN.
        let r = roll(0.3);
        assert!((tilt(&[2.0 * r[0], 2.0 * r[1], 0.0, 0.0]) - 0.3).abs() < 1e-12);
        assert_eq!(tilt(&[0.0; 4]), 0.0);
    }

    #[test]
    fn a_fall_is_a_tilt_or_a_drop_past_the_limits_and_is_latched() {
        let limits = FallLimits::default();
        let mut d = FallDetector::new(limits);
        assert_eq!(d.observe(1, &pose(0.6, [1.0, 0.0, 0.0, 0.0])), None);
        // 50 degrees of roll and a crouch to 60 % are not falls.
        assert_eq!(d.observe(2, &pose(0.36, roll(50f64.to_radians()))), None);
        let f = d.observe(3, &pose(0.5, roll(61f64.to_radians()))).expect("tipped over");
        assert_eq!(f.tick, 3);
        assert!((f.tilt - 61f64.to_radians()).abs() < 1e-9 && f.height == 0.5);
        // Latched: standing upright again does not undo it, and it is reported once.
        assert_eq!(d.observe(4, &pose(0.6, [1.0, 0.0, 0.0, 0.0])), None);
        assert_eq!(d.fallen().map(|f| f.tick), Some(3));
        // A drop below half the starting height, upright.
        let mut d = FallDetector::new(limits);
        d.observe(10, &pose(0.6, [1.0, 0.0, 0.0, 0.0]));
        assert_eq!(d.observe(11, &pose(0.31, [1.0, 0.0, 0.0, 0.0])), None);
        assert_eq!(d.observe(12, &pose(0.29, [1.0, 0.0, 0.0, 0.0])).map(|f| f.tick), Some(12));
        // A start near the ground (an estimator's origin): no height check, the tilt still.
        let mut d = FallDetector::new(limits);
        d.observe(20, &pose(0.05, [1.0, 0.0, 0.0, 0.0]));
        assert_eq!(d.observe(21, &pose(0.001, [1.0, 0.0, 0.0, 0.0])), None);
        assert_eq!(d.observe(22, &pose(0.001, roll(1.2))).map(|f| f.tick), Some(22));
    }
}
