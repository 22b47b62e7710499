//! Our dynamics against MuJoCo 3.17 on the same URDF, on seeded random states:
//! M vs `mj_fullM`, h vs `qfrc_bias`, g vs `qfrc_bias` at v = 0, frame placements vs
//! `xpos`/`xmat`, frame Jacobians vs `mj_jacBody`, Jdot v vs `mj_jacDot` and vs
//! `mj_objectAcceleration(mjOBJ_XBODY)` after `mj_rnePostConstraint` (see tests/common). Relative error = |a - b| / max(1, |b|) < 1e-8.

mod common;

use common::*;
use nalgebra::Matrix6xX;
use protocol::conventions::{
    base_twist_from_mujoco as base_velocity_from_mujoco,
    base_twist_to_mujoco as base_velocity_to_mujoco,
};
use robot_model::*;

const SAMPLES: usize = 60;
const TOL: f64 = 1e-8;

fn compare(name: &str, model: &Model, mj: &MjRobot, seed: u64) {
    let frames: Vec<&str> = model.frames.iter().map(|f| f.name.as_str()).collect();
    // same robot: every URDF link is a MuJoCo body (fusestatic off), same total mass
    let (mj_mass, mj_bodies) = mj.mass_and_bodies();
    assert_eq!(
        mj_bodies,
        frames.len() + 1,
        "{name}: MuJoCo bodies (with world) vs our link frames"
    );
    assert!(
        (mj_mass - model.total_mass).abs() < 1e-12 * model.total_mass,
        "{name}: mass {mj_mass} vs {}",
        model.total_mass
    );
    let mut data = Data::new(model);
    let mut rng = rng(seed);
    let mut worst = [0.0f64; 7];
    let mut jac = Matrix6xX::zeros(model.nv);
    for s in 0..SAMPLES {
        let (q, v) = random_state(model, &mut rng);
        compute_all_terms(model, &mut data, q.as_slice(), v.as_slice()).unwrap();
        let mj_terms = mj.eval(model, &q, &v, &frames);
        let e_m = rel_err(&data.m, &mj_terms.m);
        let e_h = rel_err_v(data.h.as_slice(), mj_terms.h.as_slice());
        let e_g = rel_err_v(data.g.as_slice(), mj_terms.g.as_slice());
        let (mut e_p, mut e_j, mut e_a, mut e_c) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (f, mjf) in mj_terms.frames.iter().enumerate() {
            let x = frame_placement(model, &data, f).unwrap();
            e_p = e_p.max((x.trans - mjf.pos).norm()).max((x.rot - mjf.rot).norm());
            frame_jacobian(model, &data, f, &mut jac).unwrap();
            e_j = e_j.max((&jac - &mjf.jac).norm() / mjf.jac.norm().max(1.0));
            let jdv = frame_jdot_v(model, &data, f).unwrap();
            e_a = e_a.max((jdv - mjf.jdot_v).norm() / mjf.jdot_v.norm().max(1.0));
            e_c = e_c.max((jdv - mjf.acc).norm() / mjf.acc.norm().max(1.0));
        }
        let errs = [e_m, e_h, e_g, e_p, e_j, e_a, e_c];
        for (w, e) in worst.iter_mut().zip(errs) {
            *w = w.max(e);
        }
        assert!(
            errs.iter().all(|e| *e < TOL),
            "{name} sample {s}: errors M, h, g, pose, J, Jdot*v (jacDot), Jdot*v (cacc) = {errs:?}"
        );
    }
    println!("{name}: {SAMPLES} samples, {} frames; worst relative errors M {:.1e}, h {:.1e}, g {:.1e}, pose {:.1e}, J {:.1e}, Jdot*v vs mj_jacDot {:.1e}, vs cacc {:.1e}", frames.len(), worst[0], worst[1], worst[2], worst[3], worst[4], worst[5], worst[6]);
}

#[test]
fn fixed_base_arm_matches_mujoco() {
    let model = arm_model();
    assert_eq!(model.nv, 6);
    let mj = MjRobot::new(ARM, None);
    compare("arm", &model, &mj, 1);
}

#[test]
fn floating_base_quadruped_matches_mujoco() {
    let model = quadruped_model();
    assert_eq!(model.nv, 18);
    let mj = MjRobot::new(QUADRUPED, Some("trunk"));
    compare("quadruped", &model, &mj, 2);
}

#[test]
fn composed_legged_manipulator_matches_mujoco() {
    let model = composed_model();
    assert_eq!(model.nv, 24);
    let mj = MjRobot::new(&composed_urdf_text(), Some("trunk"));
    compare("legged manipulator", &model, &mj, 3);
}

#[test]
fn mujoco_velocity_conversion_round_trips() {
    let quat = [0.8, 0.2, -0.4, 0.4];
    let v = [0.3, -1.0, 2.0, 0.5, 0.1, -0.7];
    let back = base_velocity_from_mujoco(quat, base_velocity_to_mujoco(quat, v));
    assert!(v.iter().zip(back).all(|(a, b)| (a - b).abs() < 1e-14));
    // the angular part is shared, the linear part is rotated (unless the rotation is identity)
    let mj = base_velocity_to_mujoco(quat, v);
    assert_eq!(&mj[3..], &v[3..]);
    assert!((mj[0] - v[0]).abs() > 1e-3);
}

#[test]
fn default_legged_manipulator_matches_mujoco() {
    // The project's own robot (robot-model/models), as the agents run it.
    let robot = Robot::load(default_robot_path()).unwrap();
    assert_eq!(robot.model.nv, 24);
    let urdf = std::fs::read_to_string(&robot.urdf_path).unwrap();
    let mj = MjRobot::new(&urdf, Some("base"));
    compare("default legged manipulator", &robot.model, &mj, 4);
}

/// A published URDF (`tests/data/unitree`, unitreerobotics/unitree_ros, BSD-3-Clause), as
/// ROS tools load it: `<visual>` elements with several `<material>` children, which the parser
/// leaves out with the other display parts (`parsers::urdf_filter`).
fn unitree(name: &str) -> String {
    std::fs::read_to_string(data_path(&format!("unitree/{name}"))).unwrap()
}

#[test]
fn published_unitree_go2_loads_and_matches_mujoco() {
    let urdf = unitree("go2_description.urdf");
    assert!(urdf.contains("<material"), "the published file, materials and all");
    let model = Model::from_urdf_str(&urdf, FloatingBase::Yes).unwrap();
    assert_eq!((model.nv, model.nq), (18, 19), "a floating base and twelve joints");
    compare("go2", &model, &MjRobot::new(&urdf, Some("base")), 10);
}

/// The sum of the `<mass value="...">` written in `urdf`, read as text.
fn written_mass(urdf: &str) -> f64 {
    urdf.split("<mass value=\"")
        .skip(1)
        .map(|rest| rest[..rest.find('"').unwrap()].parse::<f64>().unwrap())
        .sum()
}

#[test]
fn published_unitree_b2_loads_with_the_mass_it_writes() {
    // MuJoCo refuses B2 as published (its lidar link weighs 4e-15 kg, an inertia below
    // MuJoCo's threshold), so the oracle here is the file's own masses.
    let urdf = unitree("b2_description.urdf");
    let model = Model::from_urdf_str(&urdf, FloatingBase::Yes).unwrap();
    assert_eq!((model.nv, model.nq), (18, 19), "a floating base and twelve joints");
    let written = written_mass(&urdf);
    assert!(written > 50.0, "B2 weighs tens of kg: {written}");
    assert!(
        (model.total_mass - written).abs() < 1e-9 * written,
        "{} vs {written}",
        model.total_mass
    );
}

#[test]
fn a_published_urdf_with_a_joint_we_do_not_model_is_refused_by_name() {
    // unitree_ros's AS2 joins its base to the world with a `floating` joint.
    let e = Model::from_urdf_str(&unitree("as2.urdf"), FloatingBase::Yes).unwrap_err();
    let e = e.to_string();
    assert!(e.contains("floating_base_joint") && e.contains("floating"), "{e}");
}
