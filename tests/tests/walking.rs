//! Walking while holding (the walking issue), the whole stack in the loop: the paper's S2
//! (robot 1 walks a static crawl backwards, back, and turns while robot 2 and the object
//! hold) and the transport of the object by two and four robots walking together. Shortened
//! for CI (the README's figures run them whole). Acceptance, from the ground truth: never
//! dropped, palm slip < 5 mm, object RMS < 1 cm and < 2 deg against the (moving) reference,
//! walking torso RMS < 2 cm, final torso pose within 2 cm and 3 deg of its goal, no stance
//! foot sliding more than 1 cm, and every planned step taken (counted from the simulator's
//! foot contacts).

mod common;

use common::scenario::run_scenario;
use team_runner::evaluate::Metrics;
use team_runner::plan::Plan;

fn assert_walked(plan: &Plan, m: &Metrics) {
    for c in &m.checks {
        assert!(c.passed, "{}: {} = {:.5} not below {}", m.scenario, c.name, c.value, c.bound);
    }
    assert_eq!(m.samples as u64, plan.scene.ticks, "a ground-truth sample for every scenario tick");
    let walk = m.walk.as_ref().expect("a walk report");
    let walk_plan = plan.references.walk.as_ref().expect("a planned walk");
    let steps: usize = walk.steps_taken.values().sum();
    assert_eq!(steps, walk_plan.gait.steps().len(), "steps taken {:?}, planned {:?}", walk.steps_taken, walk.steps_planned);
    assert!(steps >= 4, "a real walk: {steps} steps");
    assert!(walk.least_margin_m >= walk_plan.gait.params().margin - 1e-9, "planned CoM margin {}", walk.least_margin_m);
    assert!(m.fallback_ticks.is_empty(), "no fallback or hold ticks: {:?}", m.fallback_ticks);
}

#[test]
fn s2_robot_one_walks_back_returns_and_turns_while_the_team_holds() {
    let sets = ["walk.path=[[-0.09, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, -10.0]]", "duration=21.0", "settle=0.5"];
    let (plan, m) = run_scenario("s2_walk.toml", &sets, false, "s2_walk");
    let walk = m.walk.as_ref().expect("walk report");
    assert_eq!(walk.steps_planned["r2"], 0, "robot 2 holds");
    assert_eq!(walk.steps_taken["r2"], 0, "robot 2 never lifts a foot");
    assert_walked(&plan, &m);
}

#[test]
fn two_robots_carry_the_object_forward_sideways_and_turn() {
    let sets = ["walk.path=[[0.1, 0.0, 0.0], [0.1, 0.05, 0.0], [0.1, 0.05, 3.0]]", "duration=24.0", "settle=0.5"];
    let (plan, m) = run_scenario("transport2.toml", &sets, false, "transport2");
    assert_walked(&plan, &m);
}

#[test]
fn four_robots_carry_the_object_forward() {
    let sets = ["walk.path=[[0.1, 0.0, 0.0]]", "duration=9.0", "settle=0.5"];
    let (plan, m) = run_scenario("transport4.toml", &sets, false, "transport4");
    assert_walked(&plan, &m);
}

/// A landing the simulator delays: the first step's foot is pushed up (120 N on its shank) over
/// its planned touchdown, so it touches the ground late. The contact switch keeps it in swing
/// until its force confirms the touchdown, and the walk goes on; the early landings of every
/// other step (the swing presses 1 cm below the ground) are switched as they touch.
#[test]
fn a_late_touchdown_is_waited_for_and_the_walk_goes_on() {
    let base = ["walk.path=[[-0.09, 0.0, 0.0]]".to_string(), "duration=8.0".into(), "settle=0.5".into()];
    let scenario = team_runner::scenario::Scenario::load(common::scenario::repo().join("scenarios/s2_walk.toml"), &base).expect("scenario");
    let planned = team_runner::plan::plan(&scenario, &common::scenario::repo()).expect("plan");
    let walk = planned.references.walk.as_ref().expect("walk");
    let first = walk.gait.steps()[0].clone();
    let shank = walk.feet[first.robot][first.foot].replace("_FOOT", "_SHANK");
    let push = format!("perturbations=[{{on = \"r1\", body = \"{shank}\", start = {:.3}, duration = 0.35, wrench = [0.0, 0.0, 120.0, 0.0, 0.0, 0.0]}}]", first.touchdown - 0.1);
    let sets: Vec<&str> = base.iter().map(String::as_str).chain([push.as_str()]).collect();
    let (plan, m) = run_scenario("s2_walk.toml", &sets, false, "s2_late_touchdown");
    let offsets = m.walk.as_ref().expect("walk report").touchdown_offset_ms;
    assert!(offsets[1] > 50.0, "the pushed foot ({shank}) landed late: {offsets:?} ms");
    assert!(offsets[0] < 0.0, "the others landed early: {offsets:?} ms");
    assert_walked(&plan, &m);
}
