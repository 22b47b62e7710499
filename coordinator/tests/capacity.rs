//! The static team problem (coordinator::capacity) on the real default robot: the forces it
//! finds balance every robot and the object (checked against robot_model's own g(q) and
//! Jacobians), an impossible load is refused with named limits, the capacity bisection is
//! monotone, bad input gives typed errors.

mod common;

use common::{robot_id, Fixture};
use coordinator::capacity::{CapacityError, Limit, Place, StaticProblem};
use coordinator::PidcConfig;
use nalgebra::{DVector, Matrix3xX, Matrix6xX, Vector3};
use protocol::{DynamicsTerms, FrameRole, RobotDescription};
use robot_agent::terms::ActiveContacts;
use robot_model::{
    forward_kinematics, frame_jacobian, point_jacobian, rnea, update_frame_placements, Data,
};

/// The two robots of the paper facing each other, hands on the 0.6 m cube, and its centre.
fn pair(fx: &mut Fixture) -> (Vec<DynamicsTerms>, Vec<RobotDescription>, Vector3<f64>) {
    let (terms, descs) = fx.static_team(2);
    (terms.clone(), descs, hand_midpoint(&terms))
}

fn hand_midpoint(terms: &[DynamicsTerms]) -> Vector3<f64> {
    let hands: Vec<Vector3<f64>> = terms
        .iter()
        .flat_map(|t| {
            t.frames.iter().filter(|f| f.role == FrameRole::Hand).map(|f| Vector3::from(f.position))
        })
        .collect();
    hands.iter().sum::<Vector3<f64>>() / hands.len() as f64
}

#[test]
fn static_solution_balances_each_robot_and_the_object() {
    let mut fx = Fixture::new();
    let (terms, descs, centre) = pair(&mut fx);
    let cfg = PidcConfig::default();
    let problem =
        StaticProblem::build(&terms, &descs, &cfg.contact_margins(), centre).expect("problem");
    let mass = 1.0;
    let sol = problem.solve(mass).expect("1 kg is held");
    assert!(
        sol.equality_residual < 1e-8 && sol.worst_limit < 1e-6,
        "{} {}",
        sol.equality_residual,
        sol.worst_limit
    );

    // Written out again with robot_model: g(q) by RNEA at v = a = 0, the foot contact point
    // (radius below the foot frame, world z) by point_jacobian, the hand by frame_jacobian.
    let model = &fx.robot.model;
    let nv = model.nv;
    let nfeet = fx.robot.foot_frames.len();
    let mut data = Data::new(model);
    let (mut object_force, mut object_moment) = (Vector3::zeros(), Vector3::zeros());
    for (k, desc) in descs.iter().enumerate() {
        let q = fx.standing_q(k, 2);
        let zero = vec![0.0; nv];
        let g = rnea(model, &mut data, q.as_slice(), &zero, &zero).expect("rnea").clone();
        forward_kinematics(model, &mut data, q.as_slice(), &zero).expect("fk");
        update_frame_placements(model, &mut data);
        let mut jt_lambda = DVector::<f64>::zeros(nv);
        for (i, foot) in fx.robot.foot_frames.iter().enumerate() {
            let id = model.frame_id(foot).expect("foot");
            let r = data.o_m_f[id].rot.transpose() * Vector3::new(0.0, 0.0, -fx.robot.feet.radius);
            let mut j = Matrix3xX::zeros(nv);
            point_jacobian(model, &data, id, &r, &mut j).expect("foot jacobian");
            let f = sol.lambda.fixed_rows::<3>(3 * (nfeet * k + i)).into_owned();
            assert!(f.z >= cfg.f_min_foot - 1e-6, "foot {foot} of robot {k}: f_z {}", f.z);
            jt_lambda += j.transpose() * f;
        }
        let hid = model.frame_id(&fx.robot.hand_frame).expect("hand");
        let mut jh = Matrix6xX::zeros(nv);
        frame_jacobian(model, &data, hid, &mut jh).expect("hand jacobian");
        let w = sol.lambda.fixed_rows::<6>(3 * 2 * nfeet + 6 * k).into_owned();
        jt_lambda += jh.transpose() * w;
        // Base rows: J^T lambda = g; actuated rows: tau = g - J^T lambda, within the limits.
        for i in 0..6 {
            assert!(
                (jt_lambda[i] - g[i]).abs() < 1e-8,
                "robot {k} base row {i}: {} vs {}",
                jt_lambda[i],
                g[i]
            );
        }
        let limits = &desc.torque_limits;
        for j in 0..nv - 6 {
            let tau = g[6 + j] - jt_lambda[6 + j];
            assert!((tau - sol.torques[(nv - 6) * k + j]).abs() < 1e-8);
            assert!(tau.abs() <= limits[j] + 1e-6, "robot {k} joint {j}: {tau} Nm");
        }
        // The palm pushes into the object with at least the least squeeze.
        let n = data.o_m_f[hid].rot.column(2).into_owned();
        assert!(-n.dot(&w.fixed_rows::<3>(0)) >= cfg.f_min_hand - 1e-6);
        // The object receives -w at the palm: sum its forces and moments about the centre.
        let p = data.o_m_f[hid].trans;
        object_force -= w.fixed_rows::<3>(0);
        object_moment -= (p - centre).cross(&w.fixed_rows::<3>(0)) + w.fixed_rows::<3>(3);
    }
    object_force += mass * Vector3::new(0.0, 0.0, -9.81);
    assert!(
        object_force.amax() < 1e-8 && object_moment.amax() < 1e-8,
        "object: {object_force:?} {object_moment:?}"
    );
}

#[test]
fn fifty_kilograms_is_refused_naming_a_robot_and_a_joint() {
    let mut fx = Fixture::new();
    let (terms, descs, centre) = pair(&mut fx);
    let problem =
        StaticProblem::build(&terms, &descs, &PidcConfig::default().contact_margins(), centre)
            .expect("problem");
    let Err(CapacityError::Infeasible { mass, binding }) = problem.solve(50.0) else {
        panic!("50 kg must be refused")
    };
    assert_eq!(mass, 50.0);
    assert!(binding.windows(2).all(|w| w[0].over >= w[1].over), "largest first");
    let joint = binding.iter().find(|b| matches!(b.place, Place::Joint(_))).expect("a joint binds");
    assert!(["r1", "r2"].contains(&joint.robot.as_str()));
    let Limit::Torque { max, .. } = joint.limit else { panic!("a joint's limit is its torque") };
    let tau = joint.torque.expect("torque");
    assert!(
        (tau.abs() - max - joint.over).abs() < 1e-4,
        "over = |tau| - max: {tau} {max} {}",
        joint.over
    );
    let msg = CapacityError::Infeasible { mass, binding }.to_string();
    assert!(msg.contains("robot r") && msg.contains("joint arm_joint_"), "{msg}");
}

#[test]
fn capacity_bisection_is_monotone() {
    let mut fx = Fixture::new();
    let (terms, descs, centre) = pair(&mut fx);
    let problem =
        StaticProblem::build(&terms, &descs, &PidcConfig::default().contact_margins(), centre)
            .expect("problem");
    let cap = problem.capacity(1e-3).expect("capacity");
    assert!(cap.mass > 1.0 && cap.infeasible_at - cap.mass <= 1e-3, "{cap:?}");
    assert!(!cap.binding.is_empty());
    for m in [0.0, 0.5 * cap.mass, cap.mass] {
        problem.solve(m).unwrap_or_else(|e| panic!("{m} kg below the capacity {}: {e}", cap.mass));
    }
    for m in [cap.infeasible_at, cap.infeasible_at + 0.01, 2.0 * cap.infeasible_at] {
        assert!(
            matches!(problem.solve(m), Err(CapacityError::Infeasible { .. })),
            "{m} kg above the capacity {}",
            cap.mass
        );
    }
    // Relaxing the margins can only add forces: the capacity does not drop.
    let relaxed = PidcConfig {
        shell: coordinator::ShellConfig {
            friction_margin: 1.0,
            patch_margin: 1.0,
            f_min_hand: 0.0,
            ..PidcConfig::default().shell
        },
        ..PidcConfig::default()
    };
    let wide = StaticProblem::build(&terms, &descs, &relaxed.contact_margins(), centre)
        .expect("problem")
        .capacity(1e-3)
        .expect("capacity");
    assert!(wide.mass >= cap.mass - 1e-3, "{} vs {}", wide.mass, cap.mass);
}

#[test]
fn bad_input_gives_typed_errors() {
    let mut fx = Fixture::new();
    let (terms, descs, centre) = pair(&mut fx);
    let cfg = PidcConfig::default();
    let problem =
        StaticProblem::build(&terms, &descs, &cfg.contact_margins(), centre).expect("problem");
    assert!(matches!(problem.solve(f64::NAN), Err(CapacityError::InvalidMass(m)) if m.is_nan()));
    assert!(matches!(problem.solve(-1.0), Err(CapacityError::InvalidMass(_))));
    assert!(matches!(problem.capacity(0.0), Err(CapacityError::Input(_))));
    assert!(matches!(
        StaticProblem::build(
            &terms,
            &descs,
            &cfg.contact_margins(),
            Vector3::new(f64::NAN, 0.0, 0.0)
        ),
        Err(CapacityError::Input(_))
    ));
    // No hand in grasp.
    let nv = fx.robot.model.nv;
    let open = ActiveContacts { hand_in_grasp: false, ..ActiveContacts::all_stance(&fx.robot) };
    let free: Vec<_> = (0..2)
        .map(|k| fx.terms_with(&robot_id(k), &fx.standing_q(k, 2), &DVector::zeros(nv), 1, &open))
        .collect();
    assert!(matches!(
        StaticProblem::build(&free, &descs, &cfg.contact_margins(), centre),
        Err(CapacityError::NoHands)
    ));
    // Moving: h is not g(q).
    let mut v = DVector::zeros(nv);
    v[8] = 0.3;
    let mut moving = terms.clone();
    moving[1] = fx.terms(&robot_id(1), &fx.standing_q(1, 2), &v, 1);
    assert!(
        matches!(StaticProblem::build(&moving, &descs, &cfg.contact_margins(), centre), Err(CapacityError::NotAtRest { robot }) if robot == "r2")
    );
    // A robot without its description.
    assert!(matches!(
        StaticProblem::build(&terms, &descs[..1], &cfg.contact_margins(), centre),
        Err(CapacityError::Team(_))
    ));
}
