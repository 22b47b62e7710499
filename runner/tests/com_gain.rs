//! The CoM's shift gain of the default robot against its own kinematics: the torso moved 3 cm
//! along the constrained motion (small steps, Jacobians recomputed) leaves the feet and the
//! hand where they were (forward kinematics) and moves the CoM by the gain times the shift.

use nalgebra::{Vector2, Vector3};
use robot_model::{center_of_mass, default_robot_path, forward_kinematics, Data, Robot};
use team_runner::walk::com_gain::{advance, com_shift_gain, held_motion};

fn frames(robot: &Robot, q: &[f64], names: &[&str]) -> (Vec<Vector3<f64>>, Vector3<f64>) {
    let mut data = Data::new(&robot.model);
    forward_kinematics(&robot.model, &mut data, q, &vec![0.0; robot.model.nv]).unwrap();
    let at = names.iter().map(|n| data.o_m_f[robot.model.frame_id(n).unwrap()].trans).collect();
    (at, center_of_mass(&robot.model, &data).1)
}

#[test]
fn the_com_moves_by_the_gain_when_the_torso_shifts_with_feet_and_hand_held() {
    let robot = Robot::load(default_robot_path()).expect("default robot");
    let mut q0: Vec<f64> = robot.standing_q.iter().copied().collect();
    // Turned 40 deg, so that the gain's frame matters.
    let yaw = nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 40f64.to_radians());
    q0[3..7].copy_from_slice(&[yaw.w, yaw.i, yaw.j, yaw.k]);
    for hand_held in [true, false] {
        let mut names: Vec<&str> = robot.foot_frames.iter().map(String::as_str).collect();
        if hand_held {
            names.push(robot.hand_frame.as_str());
        }
        let gain = com_shift_gain(&robot, &q0, hand_held).unwrap();
        for dir in [Vector2::new(1.0, 0.0), Vector2::new(0.3, -1.0).normalize()] {
            let e = Vector3::new(dir.x, dir.y, 0.0);
            let (mut q, n) = (q0.clone(), 60);
            for _ in 0..n {
                let v = held_motion(&robot, &q, &e, &names).unwrap();
                q = advance(&q, &v, &e, 0.03 / n as f64);
            }
            let ((before, com0), (after, com1)) = (frames(&robot, &q0, &names), frames(&robot, &q, &names));
            for (k, (a, b)) in before.iter().zip(&after).enumerate() {
                assert!((a - b).norm() < 2e-4, "hand held {hand_held}: {} moved {:.2e} m", names[k], (a - b).norm());
            }
            let r = nalgebra::Rotation2::new(40f64.to_radians()).into_inner();
            let want = r * gain * r.transpose() * (0.03 * dir);
            let got = (com1 - com0).xy();
            assert!((got - want).norm() < 3e-4, "hand held {hand_held}: CoM moved {got:?}, the gain says {want:?}");
            assert!(got.dot(&dir) < 0.95 * 0.03 && got.dot(&dir) > 0.5 * 0.03, "the legs and arm lag the torso: {got:?}");
        }
    }
}
