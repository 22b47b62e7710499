//! The payload check in the plan and `team capacity` on the shipped S4 scenario (the paper's
//! two robots on the 0.6 m cube).

use std::path::{Path, PathBuf};

use coordinator::capacity::{CapacityError, Limit, Place};
use team_runner::capacity::{self, CheckError};
use team_runner::plan::{plan, PlanError};
use team_runner::scenario::Scenario;

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
    let PlanError::Capacity(CheckError::Capacity(CapacityError::Infeasible { mass, binding })) = &err else { panic!("{err}") };
    assert_eq!(*mass, 50.0);
    let b = binding.iter().find(|b| matches!(b.place, Place::Joint(_))).expect("a joint binds");
    assert!(["r1", "r2"].contains(&b.robot.as_str()) && matches!(b.limit, Limit::Torque { .. }) && b.over > 0.0, "{b}");
    let msg = err.to_string();
    assert!(msg.contains("50 kg") && msg.contains("robot r") && msg.contains("joint ") && msg.contains("capacity_check = false"), "{msg}");
    // Overridden: the plan goes ahead.
    plan(&s4(&["object.mass=50", "capacity_check=false"]), &repo()).expect("the check is off");
}

#[test]
fn capacity_is_a_bracket_the_plan_agrees_with() {
    let p = plan(&s4(&["capacity_check=false"]), &repo()).expect("plan");
    let report = capacity::capacity(&p, 1e-3).expect("capacity");
    let cap = report.whole().clone();
    assert!(cap.mass > 1.0 && cap.infeasible_at - cap.mass <= 1e-3 && !cap.binding.is_empty(), "{cap:?}");
    let refused = |m: f64| match plan(&s4(&[&format!("object.mass={m}")]), &repo()) {
        Ok(_) => false,
        Err(PlanError::Capacity(_)) => true,
        Err(e) => panic!("{m} kg: {e}"),
    };
    assert!(!refused(cap.mass), "at the capacity: held");
    assert!(refused(cap.infeasible_at + 1e-3), "just above the capacity: refused");
    let text = capacity::summary(&p, &report, 1e-3, 0.0);
    assert!(text.contains("capacity:") && text.contains("binding limits"), "{text}");
}
