//! Where robots stand: the one place that turns floor positions into [`RobotPlacement`]s.
//!
//! * [`standing`]: a robot at `(x, y)` facing `yaw`, its base at the height of its own
//!   description's standing pose (so its feet touch the floor);
//! * [`facing_ring`]: `n` floor poses on a circle around a centre, each facing it (the first at
//!   the circle's `-x` point; two robots are the paper's facing pair);
//! * [`DEFAULT_STANDING_HEIGHT`]: the default robot's base height, for worlds built without
//!   loading it first (tests, the paper's pair).
//!
//! Scenarios name each robot's floor pose (`base_xy`, `yaw`); the runner's plan and the
//! `sim-bridge run` command both place robots through these functions.

use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::PathBuf;

use robot_model::Robot;

use crate::world::{RobotPlacement, WorldError};

/// Base height of the default robot's standing pose (`robot-model/models/legged_manipulator.toml`,
/// `[standing] base_position`), m.
pub const DEFAULT_STANDING_HEIGHT: f64 = 0.54882015;

/// `robot` (loaded from `description`) at `(x, y)` facing `yaw`, its base at its standing
/// height. A fixed-base robot has no base to place on the floor: an error.
pub fn standing(id: &str, description: PathBuf, robot: &Robot, xy: [f64; 2], yaw: f64) -> Result<RobotPlacement, WorldError> {
    if !robot.model.floating_base {
        return Err(WorldError::Invalid(format!("robot {id}: {} has a fixed base; only a floating-base robot stands on the floor", description.display())));
    }
    Ok(at_height(id, description, [xy[0], xy[1], robot.standing_q[2]], yaw))
}

/// The default robot at `(x, y)` facing `yaw`, at [`DEFAULT_STANDING_HEIGHT`].
pub fn default_robot(id: &str, xy: [f64; 2], yaw: f64) -> RobotPlacement {
    at_height(id, robot_model::default_robot_path(), [xy[0], xy[1], DEFAULT_STANDING_HEIGHT], yaw)
}

fn at_height(id: &str, description: PathBuf, base_position: [f64; 3], base_yaw: f64) -> RobotPlacement {
    RobotPlacement { id: id.to_string(), description, base_position, base_yaw, joint_overrides: BTreeMap::new() }
}

/// `n` floor poses `((x, y), yaw)` on a circle of `radius` about `centre`, each facing the
/// centre, the first at angle `pi` (the circle's `-x` point), the rest counter-clockwise at
/// equal spacing. One robot stands on the centre facing `+x`. Yaw in `(-pi, pi]`.
pub fn facing_ring(centre: [f64; 2], radius: f64, n: usize) -> Vec<([f64; 2], f64)> {
    (0..n)
        .map(|i| {
            let th = PI + 2.0 * PI * i as f64 / n as f64;
            let r = if n == 1 { 0.0 } else { radius };
            let yaw = (th + PI).rem_euclid(2.0 * PI);
            let yaw = if yaw > PI { yaw - 2.0 * PI } else { yaw };
            ([centre[0] + r * th.cos(), centre[1] + r * th.sin()], yaw)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_poses_face_the_centre_at_the_radius() {
        for n in 2..=8 {
            let c = [0.3, -0.2];
            let poses = facing_ring(c, 1.15, n);
            assert_eq!(poses.len(), n);
            for (i, ([x, y], yaw)) in poses.iter().enumerate() {
                let (dx, dy) = (x - c[0], y - c[1]);
                assert!(((dx * dx + dy * dy).sqrt() - 1.15).abs() < 1e-12, "robot {i} of {n} at the radius");
                // Facing the centre: the heading points from the base to the centre.
                let (hx, hy) = (yaw.cos(), yaw.sin());
                assert!((hx * -dx + hy * -dy) / 1.15 > 1.0 - 1e-12, "robot {i} of {n} faces the centre");
                assert!(*yaw > -PI && *yaw <= PI + 1e-12);
            }
        }
        // Two robots: the paper's pair, first on -x facing +x, second on +x facing -x.
        let pair = facing_ring([0.0, 0.0], 1.15, 2);
        assert!((pair[0].0[0] + 1.15).abs() < 1e-12 && pair[0].1.abs() < 1e-12);
        assert!((pair[1].0[0] - 1.15).abs() < 1e-12 && (pair[1].1.abs() - PI).abs() < 1e-12);
        assert_eq!(facing_ring([1.0, 2.0], 5.0, 1), vec![([1.0, 2.0], 0.0)]);
    }

    #[test]
    fn the_default_height_is_the_default_robots_standing_height() {
        let robot = Robot::load(&robot_model::default_robot_path()).unwrap();
        assert_eq!(robot.standing_q[2], DEFAULT_STANDING_HEIGHT);
        let p = standing("r1", robot_model::default_robot_path(), &robot, [1.0, 2.0], 0.5).unwrap();
        assert_eq!(p.base_position, [1.0, 2.0, DEFAULT_STANDING_HEIGHT]);
        assert_eq!(p, default_robot("r1", [1.0, 2.0], 0.5));
    }
}
