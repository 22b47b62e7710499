//! The payload check in the plan and `team capacity` on the shipped S4 scenario (the paper's
//! two robots on the 0.6 m cube).

use std::path::{Path, PathBuf};

use coordinator::capacity::{CapacityError, Limit, Place};
use scenario::file::Scenario;
use scenario::payload::{pidc_config, samples_of, CheckError};
use scenario::plan::{plan, PlanError};
use scenario::team_capacity as capacity;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("repo").to_path_buf()
}

fn s4(set: &[&str]) -> Scenario {
    let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
    Scenario::load(repo().join("scenarios/s4_object_circle.toml"), &set).expect("scenario")
}

#[test]
fn one_kilogram_passes_and_fifty_is_refused_with_the_binding_limits() {
    plan(&s4(&[]), &repo()).expect("S4 with its 1 kg cube is held");
    let err = plan(&s4(&["object.mass=50"]), &repo()).expect_err("50 kg is refused");
    let PlanError::Capacity {
        check: CheckError::Capacity(CapacityError::Infeasible { mass, binding }),
        margin,
    } = &err
    else {
        panic!("{err}")
    };
    assert_eq!(*margin, 0.02, "the default payload margin");
    assert_eq!(*mass, 50.0, "refused at the mass itself");
    let b = binding.iter().find(|b| matches!(b.place, Place::Joint(_))).expect("a joint binds");
    assert!(
        ["r1", "r2"].contains(&b.robot.as_str())
            && matches!(b.limit, Limit::Torque { .. })
            && b.over > 0.0,
        "{b}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains("50 kg")
            && msg.contains("2 % more")
            && msg.contains("robot r")
            && msg.contains("joint ")
            && msg.contains("capacity_check = false"),
        "{msg}"
    );
    // Overridden: the plan goes ahead.
    plan(&s4(&["object.mass=50", "capacity_check=false"]), &repo()).expect("the check is off");
}

#[test]
fn capacity_is_a_bracket_the_plan_agrees_with() {
    let p = plan(&s4(&["capacity_check=false"]), &repo()).expect("plan");
    let report = capacity::capacity(&p, 1e-3).expect("capacity");
    let cap = report.whole().clone();
    assert!(
        cap.mass > 1.0 && cap.infeasible_at - cap.mass <= 1e-3 && !cap.binding.is_empty(),
        "{cap:?}"
    );
    let refused = |m: f64, sets: &[&str]| match plan(
        &s4(&[&[format!("object.mass={m}").as_str()], sets].concat()),
        &repo(),
    ) {
        Ok(_) => false,
        Err(PlanError::Capacity { .. }) => true,
        Err(e) => panic!("{m} kg: {e}"),
    };
    assert!(!refused(report.mass(), &[]), "at the capacity: held");
    assert!(refused(cap.infeasible_at / 1.02 + 1e-3, &[]), "just above the capacity: refused");
    assert!(
        !refused(cap.mass, &["payload_margin=0"])
            && refused(cap.infeasible_at + 1e-3, &["payload_margin=0"]),
        "without the margin: the team problem's bracket"
    );
    let text = capacity::summary(&p, &report, 1e-3, 0.0);
    assert!(text.contains("capacity:") && text.contains("binding limits"), "{text}");
}

/// S2: two robots walking with the cube.
fn s2(set: &[&str]) -> Scenario {
    let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
    Scenario::load(repo().join("scenarios/s2_walk.toml"), &set).expect("scenario")
}

#[test]
fn a_walk_is_checked_in_every_swing_on_the_feet_the_gait_plans() {
    let p = plan(&s2(&["capacity_check=false"]), &repo()).expect("plan");
    let walk = p.references.walk.clone().expect("S2 walks");
    let robots = p.loaded_robots();
    let samples = samples_of(
        &p.scene.world,
        &robots,
        &p.references,
        pidc_config(&p.controller).expect("pidc"),
    )
    .expect("samples");
    let duration = p.references.clock.scenario_duration();
    let mut swings = 0;
    for step in walk.gait.steps().iter().filter(|s| 0.5 * (s.liftoff + s.touchdown) <= duration) {
        let t = 0.5 * (step.liftoff + step.touchdown);
        let s = samples
            .iter()
            .find(|s| (s.t - t).abs() < 1e-9)
            .unwrap_or_else(|| panic!("the swing at {t:.2} s is sampled"));
        let (i, k) = (step.robot, step.foot);
        let (q, stance) = &s.robots[i];
        assert!(
            !stance[k] && stance.iter().filter(|x| **x).count() == 3,
            "t = {t:.2}: robot {i} on three feet: {stance:?}"
        );
        // The problem has the stance feet's rows only: three foot contacts of that robot.
        let id = &walk.robots[i];
        let feet_in_rows = s
            .problem
            .rows
            .iter()
            .filter(|r| {
                &r.robot == id
                    && matches!(r.limit, Limit::MinNormal { .. })
                    && matches!(&r.place, Place::Contact(c) if c != "hand_contact")
            })
            .count();
        assert_eq!(feet_in_rows, 3, "t = {t:.2}: {id}'s foot contacts in the problem");
        // Forward kinematics of the sample's configuration: every foot where the gait plans
        // it (the swinging one on its swing), the base at the torso's reference.
        let robot = &robots[i];
        let mut data = robot_model::Data::new(&robot.model);
        robot_model::forward_kinematics(&robot.model, &mut data, q, &vec![0.0; robot.model.nv])
            .expect("kinematics");
        for (kk, frame) in robot.foot_frames.iter().enumerate() {
            let at = nalgebra::Vector3::from(
                data.o_m_f[robot.model.frame_id(frame).expect("foot")].trans,
            );
            if let Some(planned) = walk.gait.foot_position(i, kk, t) {
                assert!(
                    (at - planned).norm() < 1e-3,
                    "t = {t:.2}: {frame} at {at:?}, planned {planned:?}"
                );
            }
        }
        let torso = p.references.torso_at(i, Some(t)).pose.position;
        assert!(
            (0..3).all(|a| (q[a] - torso[a]).abs() < 1e-12),
            "the base at the torso's reference"
        );
        swings += 1;
    }
    assert!(swings >= 30, "S2's steps are sampled: {swings}");
    // The walk costs payload: on three feet and with the torsos shifted the team holds less
    // than at its start pose, and the walk's planner (the arms with the torsos shifted for the
    // steps) less again; the plan agrees with the lower of the two.
    let cap = capacity::capacity(&p, 1e-3).expect("capacity");
    assert!(
        cap.whole().mass < 0.9 * cap.start.mass,
        "along the walk {} kg, at the start {} kg",
        cap.whole().mass,
        cap.start.mass
    );
    let w = cap.walk.clone().expect("the walk's planner limits S2");
    assert!((cap.mass() - w.mass).abs() < 1e-12 && w.refused_at - w.mass <= 1e-3, "{w:?}");
    plan(&s2(&[&format!("object.mass={}", w.mass)]), &repo()).expect("accepted at the capacity");
    let err = plan(&s2(&[&format!("object.mass={}", w.refused_at + 1e-3)]), &repo())
        .expect_err("refused above it");
    assert!(matches!(err, PlanError::Walk(_)), "{err}");
    let text = capacity::summary(&p, &cap, 1e-3, 0.0);
    assert!(
        text.contains("the walk's planner") && text.contains(&format!("{:.3} kg", cap.mass())),
        "{text}"
    );
}
