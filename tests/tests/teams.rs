//! Teams of any size (the teams issue): three and four robots on the 0.6 m cube, six and eight
//! on a 2.4 m beam, each laid out by `planner::placement::around_object`, holding and then
//! moving the object on S4's circle, with the whole stack in the loop. Acceptance as S4 (never
//! dropped, slip < 5 mm, object position RMS < 1 cm, orientation RMS < 2 deg, torso RMS < 1 cm),
//! evaluated on the ground truth; shortened for CI (the README's figures run them whole).
//!
//! Besides the bounds: the controller never failed a tick (the four-robot team hit a NaN on its
//! third tick before), and its own object-pose fit agrees with the hands (residual < 2 mm; the
//! centroid estimate put three robots' object 99 mm off).

mod common;

use std::path::Path;

use common::scenario::{repo, run_scenario};
use evaluation::evaluate::Metrics;
use scenario::file::Scenario;
use scenario::plan::{self, Plan};

fn assert_team_accepted(plan: &Plan, m: &Metrics, robots: usize) {
    assert_eq!(plan.robots.len(), robots);
    assert_eq!(m.torsos.len(), robots, "every torso evaluated");
    assert_eq!(m.slip_m.len(), robots, "every palm evaluated");
    for c in &m.checks {
        assert!(c.passed, "{}: {} = {:.5} not below {}", m.scenario, c.name, c.value, c.bound);
    }
    assert_eq!(m.samples as u64, plan.scene.ticks, "a ground-truth sample for every scenario tick");
    assert!(m.fallback_ticks.is_empty(), "no fallback or hold ticks: {:?}", m.fallback_ticks);
    let solved = m.qp_status.get("Solved").copied().unwrap_or(0)
        + m.qp_status.get("AlmostSolved").copied().unwrap_or(0);
    let total: u64 = m.qp_status.values().sum();
    assert!(total as f64 >= 0.9 * plan.scene.ticks as f64, "diagnostics of {total} ticks");
    assert!(solved as f64 >= 0.99 * total as f64, "QP statuses {:?}", m.qp_status);
    assert!(
        m.grasp_fit_residual_max_m < 2e-3,
        "the controller's pose fit is off the hands by {} m",
        m.grasp_fit_residual_max_m
    );
    for (r, f) in &m.mean_squeeze_n {
        assert!(*f > 0.8 * plan.scenario.min_hand_force, "{r} squeezes {f} N only");
    }
    // The object moved, and not by a tracking error: its reference went further during the
    // run than ten times the largest error from it.
    let refs = &plan.references;
    let at = |t: f64| nalgebra::Vector3::from(refs.object_at(Some(t)).pose.position);
    let travel = (0..=100)
        .map(|i| (at(plan.scenario.duration * i as f64 / 100.0) - at(0.0)).norm())
        .fold(0.0, f64::max);
    assert!(
        travel > 0.01 && travel > 10.0 * m.object.position_max_m,
        "the object's reference moved {travel} m, its error up to {} m",
        m.object.position_max_m
    );
}

#[test]
fn three_robots_hold_and_move_the_cube() {
    let (plan, m) =
        run_scenario("team3_cube.toml", &["duration=2.0", "settle=0.5"], false, "team3_cube");
    assert_team_accepted(&plan, &m, 3);
}

#[test]
fn four_robots_hold_and_move_the_cube() {
    let (plan, m) =
        run_scenario("team4_cube.toml", &["duration=2.0", "settle=0.5"], false, "team4_cube");
    assert_team_accepted(&plan, &m, 4);
}

#[test]
fn six_robots_hold_and_move_the_beam() {
    let (plan, m) =
        run_scenario("team6_beam.toml", &["duration=1.5", "settle=0.5"], false, "team6_beam");
    assert_team_accepted(&plan, &m, 6);
}

#[test]
fn eight_robots_hold_and_move_the_beam() {
    let (plan, m) =
        run_scenario("team8_beam.toml", &["duration=1.25", "settle=0.5"], false, "team8_beam");
    assert_team_accepted(&plan, &m, 8);
}

/// The payload the plan's static check promises is held in the closed loop: three robots on
/// the cube with nine tenths of `team capacity`'s mass, on S4's circle. With the paper's
/// separate friction and torsion rows the check promised 4.39 kg, and 3 kg already dropped
/// within 0.4 s of settling (the palms turned on the cube: the QP's wrench sat where the
/// tangential force and the torsion were each at their bound, which no palm carries); the hand
/// rows now share one cone (`coordinator::qp::rows`) and the check promises 2.53 kg.
#[test]
fn three_robots_hold_nine_tenths_of_the_payload_the_check_promises() {
    let base = Scenario::load(repo().join("scenarios/team3_cube.toml"), &[]).expect("scenario");
    let cap = scenario::team_capacity::capacity(&plan::plan(&base, &repo()).expect("plan"), 0.01)
        .expect("capacity")
        .mass();
    let mass = format!("object.mass={}", 0.9 * cap);
    let (plan, m) = run_scenario(
        "team3_cube.toml",
        &["duration=2.0", "settle=0.5", &mass],
        false,
        "team3_cube_heavy",
    );
    println!("capacity {cap:.3} kg, carried {:.3} kg", plan.scenario.object.mass);
    assert_team_accepted(&plan, &m, 3);
}

/// Layouts that cannot be stood are refused before anything runs, with the reason: robots in
/// each other's footprint (eight on the beam 0.6 m apart stood in each other and the team fell),
/// hands beyond a face's end, both `[team]` and `[[robots]]`.
#[test]
fn impossible_layouts_are_refused_when_planning() {
    let load = |sets: &[&str]| {
        Scenario::load(
            repo().join("scenarios/team8_beam.toml"),
            &sets.iter().map(|s| s.to_string()).collect::<Vec<_>>(),
        )
    };
    let crowded = load(&["team.spacing=0.6"]).expect("the layout itself fits the beam");
    let e = plan::plan(&crowded, &repo()).expect_err("robots in each other").to_string();
    assert!(e.contains("robots r") && e.contains("stand in each other"), "{e}");
    let e = load(&["team.per_face=5"])
        .expect_err("five robots 0.7 m apart do not fit on 2.4 m")
        .to_string();
    assert!(e.contains("team layout") && e.contains("-y"), "{e}");
    let text = std::fs::read_to_string(repo().join("scenarios/team3_cube.toml")).unwrap()
        + "\n[[robots]]\nid = \"r9\"\ndescription = \"robot-model/models/legged_manipulator.toml\"\nbase_xy = [3.0, 0.0]\nyaw = 0.0\n";
    let e =
        Scenario::from_str_with(&text, Path::new("both.toml"), &[]).expect_err("both").to_string();
    assert!(e.contains("either [[robots]] or [team]"), "{e}");
}
