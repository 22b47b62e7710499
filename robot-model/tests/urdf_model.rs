//! URDF -> Model: tree checks with typed errors, fixed-joint merging, frames, limits, joint
//! order, composition, and state validation.

mod common;

use common::*;
use nalgebra::{DVector, Vector3};
use robot_model::*;

const INERTIAL: &str = r#"<inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>"#;

fn link(name: &str) -> String {
    format!(r#"<link name="{name}">{INERTIAL}</link>"#)
}

fn joint(name: &str, kind: &str, parent: &str, child: &str) -> String {
    format!(
        r#"<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="10" velocity="1"/></joint>"#
    )
}

fn robot(parts: &[String]) -> String {
    format!("<robot name=\"t\">{}</robot>", parts.concat())
}

fn err(urdf: &str) -> ModelError {
    Model::from_urdf_str(urdf, FloatingBase::No).expect_err("must fail")
}

#[test]
fn malformed_urdfs_give_typed_errors() {
    // no root: every link is a child
    let e = err(&robot(&[
        link("a"),
        link("b"),
        joint("j1", "revolute", "a", "b"),
        joint("j2", "revolute", "b", "a"),
    ]));
    assert!(matches!(e, ModelError::NoRoot), "{e}");
    // two roots
    let e = err(&robot(&[link("a"), link("b"), link("c"), joint("j1", "revolute", "a", "b")]));
    match e {
        ModelError::MultipleRoots { roots } => {
            assert_eq!(roots, vec!["a".to_string(), "c".to_string()])
        }
        e => panic!("{e}"),
    }
    // a cycle below a proper root
    let e = err(&robot(&[
        link("r"),
        link("a"),
        link("b"),
        joint("j1", "revolute", "a", "b"),
        joint("j2", "revolute", "b", "a"),
    ]));
    assert!(matches!(e, ModelError::Cycle { .. }), "{e}");
    // unknown parent / child
    let e = err(&robot(&[link("a"), link("b"), joint("j1", "revolute", "x", "b")]));
    assert!(
        matches!(e, ModelError::UnknownParent { ref link, role: "parent", .. } if link == "x"),
        "{e}"
    );
    let e = err(&robot(&[link("a"), joint("j1", "revolute", "a", "y")]));
    assert!(matches!(e, ModelError::UnknownParent { role: "child", .. }), "{e}");
    // a link with two parents
    let e = err(&robot(&[
        link("a"),
        link("b"),
        link("c"),
        joint("j1", "revolute", "a", "c"),
        joint("j2", "revolute", "b", "c"),
    ]));
    assert!(matches!(e, ModelError::SeveralParentJoints { .. }), "{e}");
    // bad numbers: NaN mass, infinite origin, negative mass, unparsable, zero axis
    let nan_mass = r#"<robot name="t"><link name="a"><inertial><mass value="nan"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link></robot>"#;
    assert!(matches!(err(nan_mass), ModelError::BadNumber { .. }));
    let neg_mass = nan_mass.replace("nan", "-1");
    assert!(matches!(err(&neg_mass), ModelError::BadNumber { .. }));
    let inf_origin = robot(&[
        link("a"),
        link("b"),
        joint("j1", "revolute", "a", "b").replace("<parent", r#"<origin xyz="0 inf 0"/><parent"#),
    ]);
    assert!(matches!(err(&inf_origin), ModelError::BadNumber { .. }), "{}", err(&inf_origin));
    let garbage = nan_mass.replace("nan", "1.2.3");
    assert!(matches!(err(&garbage), ModelError::Urdf(_)), "{}", err(&garbage));
    let zero_axis =
        robot(&[link("a"), link("b"), joint("j1", "revolute", "a", "b").replace("0 0 1", "0 0 0")]);
    assert!(matches!(err(&zero_axis), ModelError::BadNumber { .. }));
    // not XML, unsupported joint type, duplicate names
    assert!(matches!(err("this is not xml"), ModelError::Urdf(_)));
    assert!(matches!(
        err(&robot(&[link("a"), link("b"), joint("j1", "planar", "a", "b")])),
        ModelError::UnsupportedJoint { .. }
    ));
    assert!(matches!(err(&robot(&[link("a"), link("a")])), ModelError::DuplicateName { .. }));
    // a missing file is an I/O error, not a panic
    let e = Model::from_urdf_file("/nonexistent/robot.urdf", FloatingBase::No).unwrap_err();
    assert!(matches!(e, ModelError::Io { .. }));
}

#[test]
fn missing_meshes_do_not_matter() {
    // arm.urdf references package://test_arm/meshes/base.stl, which does not exist
    assert!(ARM.contains("meshes/base.stl"));
    let m = Model::from_urdf_file(data_path("arm.urdf"), FloatingBase::No).unwrap();
    assert_eq!(m.nv, 6);
}

#[test]
fn fixed_joints_are_merged_and_frames_stay_addressable() {
    let m = arm_model();
    assert_eq!((m.nq, m.nv, m.bodies.len(), m.frames.len()), (6, 6, 7, 10));
    let link6 = m.frames[m.frame_id("link6").unwrap()].body;
    for f in ["tool0", "hand", "hand_tip"] {
        let fr = &m.frames[m.frame_id(f).unwrap()];
        assert_eq!(fr.body, link6, "{f}");
        assert_eq!(fr.kind, FrameKind::FixedLink);
    }
    // hand (0.4 kg) lumped into link6 (0.2 kg); tool0 and hand_tip have no mass
    assert!((m.bodies[link6].inertia.mass - 0.6).abs() < 1e-12);
    let urdf_mass = 1.5 + 1.1 + 0.9 + 0.6 + 0.5 + 0.35 + 0.2 + 0.4;
    assert!((m.total_mass - urdf_mass).abs() < 1e-12);
    let body_mass: f64 = m.bodies.iter().map(|b| b.inertia.mass).sum();
    assert!((body_mass - urdf_mass).abs() < 1e-12);
    // tool0 placement = joint origin (0, 0, 0.05), yaw 1.2, relative to link6
    let tool = &m.frames[m.frame_id("tool0").unwrap()];
    assert!((tool.placement.trans - Vector3::new(0.0, 0.0, 0.05)).norm() < 1e-15);
    assert!(matches!(m.frame_id("nope"), Err(ModelError::UnknownFrame { .. })));
}

#[test]
fn joint_order_is_depth_first_in_file_order() {
    let urdf = robot(&[
        link("root"),
        link("a1"),
        link("b1"),
        link("a2"),
        joint("ja1", "revolute", "root", "a1"),
        joint("jb1", "continuous", "root", "b1"),
        joint("ja2", "prismatic", "a1", "a2"),
    ]);
    let m = Model::from_urdf_str(&urdf, FloatingBase::No).unwrap();
    assert_eq!(m.joint_names, vec!["ja1", "ja2", "jb1"]);
    assert!(matches!(m.bodies[2].joint, JointType::Prismatic { .. }));
    let q = quadruped_model();
    let expect: Vec<String> = ["LF", "RF", "LH", "RH"]
        .iter()
        .flat_map(|l| ["HAA", "HFE", "KFE"].map(|j| format!("{l}_{j}")))
        .collect();
    assert_eq!(q.joint_names, expect);
    assert_eq!(
        q.velocity_names()[..6],
        ["base_vx", "base_vy", "base_vz", "base_wx", "base_wy", "base_wz"]
    );
}

#[test]
fn limits_actuation_and_neutral_configuration() {
    let m = arm_model();
    let j4 = m.joint_names.iter().position(|n| n == "j4").unwrap();
    assert!(m.lower_position_limit[j4].is_infinite() && m.upper_position_limit[j4].is_infinite());
    let j3 = m.joint_names.iter().position(|n| n == "j3").unwrap();
    assert_eq!((m.lower_position_limit[j3], m.upper_position_limit[j3]), (-0.05, 0.1));
    assert_eq!(m.effort_limit[0], 39.0);
    assert_eq!(m.velocity_limit[j3], 0.5);
    assert!(m.actuated.iter().all(|a| *a));

    let q = quadruped_model();
    assert_eq!((q.nq, q.nv), (19, 18));
    assert_eq!(&q.actuated[..6], &[false; 6]);
    assert!(q.actuated[6..].iter().all(|a| *a));
    let n = q.neutral();
    assert_eq!(&n.as_slice()[..7], &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
    // front knees are limited to [-2.5, -0.2], hind knees to [0.2, 2.5]: zero is clamped
    let kfe =
        |leg: &str| 7 + q.joint_names.iter().position(|j| *j == format!("{leg}_KFE")).unwrap();
    assert_eq!(n[kfe("LF")], -0.2);
    assert_eq!(n[kfe("RH")], 0.2);
    assert_eq!(n[kfe("LF") - 1], 0.0);
}

#[test]
fn composition_prefixes_names_and_places_the_arm() {
    let m = composed_model();
    assert_eq!((m.nq, m.nv), (25, 24));
    assert_eq!(&m.joint_names[12..], &["arm_j1", "arm_j2", "arm_j3", "arm_j4", "arm_j5", "arm_j6"]);
    for f in ["arm_base_link", "arm_tool0", "arm_hand", "trunk", "LF_foot", "imu_link"] {
        m.frame_id(f).unwrap();
    }
    let arm = arm_model();
    let quad = quadruped_model();
    assert!((m.total_mass - arm.total_mass - quad.total_mass).abs() < 1e-12);
    // at the neutral pose, arm_base_link sits at arm_mount * pose
    let mut d = Data::new(&m);
    let q = m.neutral();
    forward_kinematics(&m, &mut d, q.as_slice(), DVector::zeros(m.nv).as_slice()).unwrap();
    let mount = d.o_m_f[m.frame_id(ATTACH_AT).unwrap()];
    let base = d.o_m_f[m.frame_id("arm_base_link").unwrap()];
    let expect = mount.compose(&SE3::from_xyz_rpy(ATTACH_XYZ, ATTACH_RPY));
    assert!((base.trans - expect.trans).norm() < 1e-15 && (base.rot - expect.rot).norm() < 1e-15);
    // errors: unknown attach frame, same prefix twice
    let b = ModelBuilder::from_urdf_str(QUADRUPED).unwrap();
    let e = b.clone().attach_urdf_str(ARM, "no_such_link", SE3::identity(), "arm_").unwrap_err();
    assert!(matches!(e, ModelError::UnknownFrame { .. }));
    let twice = b.attach_urdf_str(ARM, "trunk", SE3::identity(), "x_").unwrap().attach_urdf_str(
        ARM,
        "trunk",
        SE3::identity(),
        "x_",
    );
    assert!(matches!(twice, Err(ModelError::DuplicateName { .. })));
}

#[test]
fn added_frames_follow_their_parent() {
    let mut m = composed_model();
    let x = SE3::from_xyz_rpy([0.0, 0.0, 0.1], [0.0, 0.5, 0.0]);
    let id = m.add_frame("grasp", "arm_tool0", x).unwrap();
    assert!(matches!(m.add_frame("grasp", "trunk", x), Err(ModelError::DuplicateName { .. })));
    assert!(matches!(m.add_frame("g2", "nope", x), Err(ModelError::UnknownFrame { .. })));
    let mut d = Data::new(&m);
    let mut r = rng(3);
    let (q, v) = random_state(&m, &mut r);
    forward_kinematics(&m, &mut d, q.as_slice(), v.as_slice()).unwrap();
    let tool = d.o_m_f[m.frame_id("arm_tool0").unwrap()];
    let g = d.o_m_f[id];
    let expect = tool.compose(&x);
    assert!((g.trans - expect.trans).norm() < 1e-14 && (g.rot - expect.rot).norm() < 1e-14);
}

#[test]
fn bad_states_give_typed_errors() {
    let m = quadruped_model();
    let mut d = Data::new(&m);
    let q = m.neutral();
    let v = DVector::zeros(m.nv);
    let e = compute_all_terms(&m, &mut d, &q.as_slice()[1..], v.as_slice()).unwrap_err();
    assert_eq!(e, DynamicsError::WrongLength { expected: 19, got: 18, what: "q" });
    let mut vbad = v.clone();
    vbad[4] = f64::NAN;
    let e = compute_all_terms(&m, &mut d, q.as_slice(), vbad.as_slice()).unwrap_err();
    assert_eq!(e, DynamicsError::NonFinite { what: "v", index: 4 });
    let mut q0 = q.clone();
    q0[3] = 0.0;
    assert_eq!(
        compute_all_terms(&m, &mut d, q0.as_slice(), v.as_slice()).unwrap_err(),
        DynamicsError::ZeroQuaternion
    );
    let mut small = nalgebra::Matrix6xX::zeros(m.nv - 1);
    assert!(matches!(
        frame_jacobian(&m, &d, 0, &mut small),
        Err(DynamicsError::OutputShape { .. })
    ));
    let mut ok = nalgebra::Matrix6xX::zeros(m.nv);
    assert!(matches!(
        frame_jacobian(&m, &d, 999, &mut ok),
        Err(DynamicsError::FrameOutOfRange { .. })
    ));
}

#[test]
fn mutated_urdf_text_never_panics() {
    use rand::Rng;
    let mut r = rng(99);
    let bytes = QUADRUPED.as_bytes();
    let replacements: [&str; 8] = ["", "x", "-", "nan", "inf", "1e400", "\"", "<"];
    let (mut ok, mut failed) = (0, 0);
    for _ in 0..400 {
        let mut text = String::from_utf8_lossy(bytes).into_owned();
        for _ in 0..r.random_range(1..4) {
            let at = r.random_range(0..text.len());
            if !text.is_char_boundary(at) {
                continue;
            }
            let end = (at + r.random_range(0..6)).min(text.len());
            if !text.is_char_boundary(end) {
                continue;
            }
            text.replace_range(at..end, replacements[r.random_range(0..replacements.len())]);
        }
        let result = std::panic::catch_unwind(|| {
            Model::from_urdf_str(&text, FloatingBase::Yes).map(|m| {
                // a model that loads must also evaluate
                let mut d = Data::new(&m);
                let q = m.neutral();
                compute_all_terms(&m, &mut d, q.as_slice(), DVector::zeros(m.nv).as_slice())
                    .map(|_| d.m.iter().all(|x| x.is_finite()))
            })
        });
        match result {
            Ok(Ok(Ok(finite))) => {
                assert!(finite, "a loaded model gave non-finite M");
                ok += 1
            }
            Ok(Ok(Err(e))) => panic!("loaded model failed to evaluate: {e}"),
            Ok(Err(_)) => failed += 1,
            Err(_) => panic!("panic on mutated URDF:\n{text}"),
        }
    }
    // both outcomes occur, so the mutations exercise the error paths
    assert!(ok > 0 && failed > 0, "ok {ok}, failed {failed}");
}
