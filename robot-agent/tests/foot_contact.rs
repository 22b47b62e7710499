//! A stance foot is a sphere rolling on flat ground: its contact rows are those of the point
//! `radius` below the sphere's centre (what stays on the ground), not of the centre. Oracles:
//! the velocity of the shank's material point at the contact, by finite differences of the
//! foot frame's forward kinematics; `Jdot v` by finite differences of `J(q(t)) v` along `v`.

#[path = "../../robot-model/tests/common/mod.rs"]
mod common;

use common::*;
use nalgebra::{DVector, Matrix3, Vector3};
use protocol::{FrameRole, Header, Pose, RobotState};
use robot_agent::terms::{empty_terms, ActiveContacts, TermsBuilder};
use robot_model::{default_robot_path, Robot};

fn state_of(robot: &Robot, q: &DVector<f64>, v: &DVector<f64>) -> RobotState {
    let n = robot.joints();
    RobotState {
        header: Header::new("t", Some("r1"), 0, 0),
        base_pose: Pose { position: [q[0], q[1], q[2]], orientation: [q[3], q[4], q[5], q[6]] },
        base_twist: [v[0], v[1], v[2], v[3], v[4], v[5]],
        joint_positions: q.as_slice()[7..7 + n].to_vec(),
        joint_velocities: v.as_slice()[6..6 + n].to_vec(),
        time: 0.0,
        foot_forces: Vec::new(),
        object_pose: None,
    }
}

/// A stance foot's frame in the terms: position, rotation, J (3 x nv), Jdot v.
type FootFrame = (Vector3<f64>, Matrix3<f64>, nalgebra::DMatrix<f64>, Vector3<f64>);

/// Stance-foot frames of the terms at `(q, v)`.
fn feet(robot: &Robot, b: &mut TermsBuilder, q: &DVector<f64>, v: &DVector<f64>) -> Vec<FootFrame> {
    let mut terms = empty_terms("t", "r1");
    b.load_state(robot, &state_of(robot, q, v)).unwrap();
    b.compute(robot, &ActiveContacts::all_stance(robot), &mut terms).unwrap();
    terms
        .frames
        .iter()
        .filter(|f| f.role == FrameRole::StanceFoot)
        .map(|f| {
            let nv = f.jacobian.cols();
            (
                Vector3::from(f.position),
                Matrix3::from_row_slice(&f.rotation),
                nalgebra::DMatrix::from_row_slice(3, nv, &f.jacobian.data),
                Vector3::from_row_slice(&f.jdot_v),
            )
        })
        .collect()
}

#[test]
fn stance_rows_are_the_rolling_contact_point() {
    let robot = Robot::load(default_robot_path()).unwrap();
    let model = &robot.model;
    let r = robot.feet.radius;
    let mut b = TermsBuilder::new(&robot).unwrap();
    let mut rng = rng(31);
    let h = 1e-6;
    let (mut worst_v, mut worst_a) = (0.0f64, 0.0f64);
    for _ in 0..30 {
        let (q, v) = random_state(model, &mut rng);
        let now = feet(&robot, &mut b, &q, &v);
        let plus = feet(&robot, &mut b, &model.integrate(q.as_slice(), v.as_slice(), h), &v);
        let minus = feet(&robot, &mut b, &model.integrate(q.as_slice(), v.as_slice(), -h), &v);
        assert_eq!(now.len(), 4);
        for k in 0..4 {
            let (p, rot, j, jdv) = &now[k];
            // The contact point is `radius` below the centre; the shank's material point there,
            // in the foot frame, moves with the frame.
            let centre = p + Vector3::z() * r;
            let local = rot.transpose() * (p - centre);
            let at = |f: &(Vector3<f64>, Matrix3<f64>, nalgebra::DMatrix<f64>, Vector3<f64>)| {
                f.0 + Vector3::z() * r + f.1 * local
            };
            let v_fd = (at(&plus[k]) - at(&minus[k])) / (2.0 * h);
            let v_j: Vector3<f64> = Vector3::from_column_slice((j * &v).as_slice());
            worst_v = worst_v.max((v_j - v_fd).norm() / v_fd.norm().max(1.0));
            // d/dt (J(q(t)) v) along v.
            let a_fd = (&plus[k].2 * &v - &minus[k].2 * &v) / (2.0 * h);
            worst_a = worst_a.max(
                (jdv - Vector3::from_column_slice(a_fd.as_slice())).norm() / a_fd.norm().max(1.0),
            );
            // Not the centre's velocity: the rows differ by the rolling term.
            let c_fd = ((plus[k].0 - minus[k].0) / (2.0 * h)).norm();
            assert!(
                (v_j - (plus[k].0 - minus[k].0) / (2.0 * h)).norm() > 1e-6 * c_fd.max(1.0),
                "rolling term missing"
            );
        }
    }
    println!("contact-point velocity vs finite differences: {worst_v:.2e}; Jdot v: {worst_a:.2e}");
    assert!(worst_v < 1e-7, "{worst_v}");
    assert!(worst_a < 1e-5, "{worst_a}");
}

#[test]
fn standing_feet_touch_the_ground_at_their_contact_points() {
    let robot = Robot::load(default_robot_path()).unwrap();
    let mut b = TermsBuilder::new(&robot).unwrap();
    let v = DVector::zeros(robot.model.nv);
    for (p, ..) in feet(&robot, &mut b, &robot.standing_q, &v) {
        assert!(p.z.abs() < 1e-6, "contact point at height {}", p.z);
    }
}
