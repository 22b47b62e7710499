//! The arm torques a walk's reach check holds the object with, against virtual work: for each
//! arm joint, the potential energy's derivative minus the hand wrench's work on the hand's
//! motion, both by central differences of forward kinematics.

use nalgebra::Vector3;
use planner::gait::HandLoad;
use planner::walk::reach::arm_torques;
use robot_model::{default_robot_path, forward_kinematics, potential_energy, Data, Robot};

#[test]
fn arm_torques_are_the_virtual_work_of_gravity_and_the_hand_load() {
    let robot = Robot::load(default_robot_path()).expect("default robot");
    let model = &robot.model;
    let mut q: Vec<f64> = robot.standing_q.iter().copied().collect();
    // A bent arm, a tilted base: nothing lines up by accident.
    for (k, name) in model.joint_names.iter().enumerate() {
        if name.starts_with("arm_") {
            q[7 + k] += 0.2 + 0.1 * k as f64 % 0.3;
        }
    }
    let tilt = nalgebra::UnitQuaternion::from_euler_angles(0.05, -0.03, 0.7);
    q[3..7].copy_from_slice(&[tilt.w, tilt.i, tilt.j, tilt.k]);
    let load = HandLoad {
        point: Vector3::zeros(),
        force: Vector3::new(-30.0, 4.0, -9.0),
        moment: Vector3::new(0.6, -1.1, 0.3),
    };
    let torques = arm_torques(&robot, &q, &load).unwrap();
    assert_eq!(torques.len(), 6, "the six arm joints move the hand: {torques:?}");
    let hand = model.frame_id(&robot.hand_frame).unwrap();
    let at = |q: &[f64]| {
        let mut data = Data::new(model);
        forward_kinematics(model, &mut data, q, &vec![0.0; model.nv]).unwrap();
        let m = data.o_m_f[hand];
        (potential_energy(model, &data), m.trans, m.rot)
    };
    let h = 1e-6;
    for (joint, tau, limit) in &torques {
        let k = model.joint_names.iter().position(|n| n == joint).unwrap();
        let (mut qp, mut qm) = (q.clone(), q.clone());
        qp[7 + k] += h;
        qm[7 + k] -= h;
        let ((ep, pp, rp), (em, pm, rm)) = (at(&qp), at(&qm));
        // The small rotation from the skew part of R+ R-^T (acos loses its digits there).
        let d = rp * rm.transpose();
        let omega =
            Vector3::new(d[(2, 1)] - d[(1, 2)], d[(0, 2)] - d[(2, 0)], d[(1, 0)] - d[(0, 1)])
                / (4.0 * h);
        let virtual_work = (ep - em) / (2.0 * h)
            - load.force.dot(&((pp - pm) / (2.0 * h)))
            - load.moment.dot(&omega);
        assert!(
            (tau - virtual_work).abs() < 1e-5 * (1.0 + tau.abs()),
            "{joint}: {tau} vs virtual work {virtual_work}"
        );
        let a = robot.actuated_joints.iter().position(|n| n == joint).unwrap();
        assert_eq!(*limit, robot.torque_limits[a]);
    }
}
