//! The grasp plan (arm IK from robot_model) puts each hand flat on its face of the object, level
//! with the face's centre and in front of its robot along the face: on our model and in
//! MuJoCo's world.

use mujoco_rs::mujoco_c::mjtObj;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use scenario::layout::place_hands;
use sim_bridge::mujoco_plant::MujocoPlant;
use sim_bridge::world::{load_robots, name2id, World, WorldSpec};

#[test]
fn hands_lie_flat_on_the_object_faces_in_our_model_and_in_mujoco() {
    let mut spec = WorldSpec::paper_pair();
    // Move and turn the object so that the standing arm pose is not already the answer.
    let yaw = 4f64.to_radians();
    let o = spec.object.as_mut().unwrap();
    o.position = [0.03, 0.02, 0.63];
    o.orientation = [(yaw / 2.0).cos(), 0.0, 0.0, (yaw / 2.0).sin()];
    let object = *o;
    let robots = load_robots(&spec).unwrap();
    let sols = place_hands(&mut spec, &robots).expect("IK converges");
    assert_eq!(sols.len(), 2);
    let ro = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        object.orientation[0],
        object.orientation[1],
        object.orientation[2],
        object.orientation[3],
    ));
    // Outward normals of the faces toward r1 (-x) and r2 (+x) in the object frame.
    let normals = [ro * Vector3::new(-1.0, 0.0, 0.0), ro * Vector3::new(1.0, 0.0, 0.0)];
    let po = Vector3::from(object.position);
    for (s, n) in sols.iter().zip(&normals) {
        assert!(s.iterations > 0, "nothing to solve?");
        assert!(s.position_error < 1e-3 && s.angle_error < 0.5f64.to_radians(), "{s:?}");
        // On the face plane, inside the face.
        assert!(((s.target_position - po).dot(n) - 0.3).abs() < 1e-9);
        assert!((s.target_rotation.column(2).dot(n) + 1.0).abs() < 1e-9);
    }
    // The same configuration in MuJoCo's compiled world.
    let world = World::build(&spec, &robots).unwrap();
    let plant = MujocoPlant::new(world).unwrap();
    let (m, d) = plant.raw();
    for (i, id) in ["r1", "r2"].iter().enumerate() {
        let b = name2id(m, mjtObj::mjOBJ_BODY, "body", &format!("{id}/hand_contact")).unwrap();
        let p = unsafe {
            Vector3::new(*d.xpos.add(3 * b), *d.xpos.add(3 * b + 1), *d.xpos.add(3 * b + 2))
        };
        let r =
            unsafe { Matrix3::from_row_slice(std::slice::from_raw_parts(d.xmat.add(9 * b), 9)) };
        let n = normals[i];
        let dist = (p - po).dot(&n) - 0.3;
        assert!(dist.abs() < 1e-3, "{id}: hand frame {dist} m off the face plane");
        // Along the face: level with its centre, and horizontally in front of the robot's base
        // (the face's horizontal axis is the object's y for the +-x faces).
        let along = (p - po) - n * (p - po).dot(&n);
        let e = ro * Vector3::y();
        let base = Vector3::from(spec.robots[i].base_position);
        let expected = e * e.dot(&(base - po)).clamp(-0.24, 0.24);
        assert!(
            (along - expected).norm() < 1e-3,
            "{id}: hand at {along:?} on the face, expected in front of the base at {expected:?}"
        );
        let angle = (-r.column(2).dot(&n)).clamp(-1.0, 1.0).acos();
        assert!(angle < 0.5f64.to_radians(), "{id}: palm normal {} deg off", angle.to_degrees());
        let err = (p - sols[i].target_position).norm();
        assert!(err < 1e-3, "{id}: MuJoCo and our model disagree by {err} m");
    }
}
