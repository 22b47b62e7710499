//! The plan holds what it promises, with MuJoCo in the loop: a run the payload check along the
//! motion accepts holds its object, one it would drop is refused before the simulation, and a
//! motion the contacts cannot carry yields before the grasp is let go.
//!
//! * the three robots at unequal spacing on a 1.8 m beam (`scenarios/beam3_unequal.toml`):
//!   refused at 2.0 kg (86 % of its start-pose capacity) naming where along the circle, and
//!   held at 90 % of the capacity along its motion;
//! * the same beam with its circle's radius doubled mid-run, run past the check: the object's
//!   motion yields and the grasp holds;
//! * seeded random teams around boxes and beams (2-6 robots, unequal spacing, both sides or one
//!   side and the ends), random circles and random masses (half of them within 85-100 % of the
//!   capacity, a quarter up to 20 % over it): every case is held (every acceptance check
//!   passes) or refused by the plan, none dropped.
//!   `TEAM_RANDOM_CASES=300 cargo test --release -p team-tests --test plan_promises random -- --nocapture`
//!   runs more (`TEAM_RANDOM_ONLY=K` case K alone; each case run leaves its `scenario.toml` in
//!   its report folder);
//! * the capacity against MuJoCo: on the first random layouts that hold anything, the heaviest
//!   object held with every check passed (bisection over runs) over the computed capacity.

use experiments::simulated_capacity as simulated;
use scenario::file::Scenario;
use scenario::plan::{self, PlanError};

mod common;
use common::scenario::{repo, run_plan};

fn beam(sets: &[String]) -> Scenario {
    Scenario::load(repo().join("scenarios/beam3_unequal.toml"), sets).expect("scenario")
}

#[test]
fn the_unequally_spaced_beam_is_refused_where_it_would_fall_and_held_below_its_capacity() {
    // 2.0 kg: held at the start pose (capacity 2.32 kg there), not along the circle.
    let err = plan::plan(&beam(&["object.mass=2.0".into()]), &repo())
        .expect_err("refused before the simulation");
    let msg = err.to_string();
    println!("{msg}");
    assert!(
        matches!(
            err,
            PlanError::Capacity { check: scenario::payload::CheckError::AlongMotion { .. }, .. }
        ),
        "{msg}"
    );
    assert!(
        msg.contains("of the motion")
            && msg.contains("hold 2.0")
            && msg.contains("2 % more")
            && msg.contains("robot r"),
        "names the time, the mass and the binding limits: {msg}"
    );
    let p = plan::plan(&beam(&["capacity_check=false".into()]), &repo()).expect("plan");
    let cap = scenario::team_capacity::capacity(&p, 0.01).expect("capacity");
    let (start, whole) = (cap.start.mass, cap.whole().mass);
    println!("capacity {start:.3} kg at the start pose, {whole:.3} kg along the motion, {:.3} kg accepted", cap.mass());
    assert!(
        whole < 0.8 * start,
        "the circle costs the beam a fifth of its start-pose capacity or more"
    );
    // 90 % of the capacity the plan accepts, one turn of the circle: every check passes.
    let held = beam(&[format!("object.mass={}", 0.9 * cap.mass()), "duration=4.0".into()]);
    let m = run_plan(&plan::plan(&held, &repo()).expect("accepted"), "promises-beam-90");
    assert!(
        m.passed,
        "every check passes: {:?}",
        m.checks.iter().filter(|c| !c.passed).collect::<Vec<_>>()
    );
}

#[test]
fn a_circle_doubled_mid_run_beyond_the_contacts_makes_the_motion_yield_and_the_grasp_hold() {
    // The beam at 95 % of what its 4 cm circle allows, the circle's radius doubled after one
    // turn: the plan would refuse it, and runs it anyway.
    let p = plan::plan(&beam(&["capacity_check=false".into()]), &repo()).expect("plan");
    let whole = scenario::team_capacity::capacity(&p, 0.01).expect("capacity").whole().mass;
    let file = repo().join("scenarios/beam3_unequal.toml");
    let text = std::fs::read_to_string(&file).expect("scenario").replace(
        "[references.object.position]\nkind = \"circle\"\nradius = 0.04          # m\nfrequency = 0.25       # Hz\nplane = \"xz\"\nphase = 0.0\n",
        "[references.object.position]\nkind = \"sequence\"\nsegments = [\n  { duration = 4.0, motion = { kind = \"circle\", radius = 0.04, frequency = 0.25, plane = \"xz\" } },\n  { duration = 4.0, motion = { kind = \"circle\", radius = 0.08, frequency = 0.25, plane = \"xz\" } },\n]\n",
    );
    assert!(text.contains("sequence"), "the circle is replaced");
    let sets = vec![format!("object.mass={}", 0.95 * whole), "duration=8.0".into()];
    let doubled = Scenario::from_str_with(&text, &file, &sets).expect("scenario");
    let err = plan::plan(&doubled, &repo()).expect_err("the doubled circle is beyond the contacts");
    println!("refused: {err}");
    let mut sets = sets;
    sets.push("capacity_check=false".into());
    let m = run_plan(
        &plan::plan(&Scenario::from_str_with(&text, &file, &sets).expect("scenario"), &repo())
            .expect("plan"),
        "promises-doubled",
    );
    let y = m.motion_yield.as_ref().expect("the motion yielded");
    assert!(y.first_tick > 4000, "not before the circle doubled: {y:?}");
    assert!(!m.drop.dropped, "the object is held");
    assert!(
        m.fallback_ticks.is_empty(),
        "no tick fell back and the grasp was not let go: {:?}",
        m.fallback_ticks
    );
    for (r, slip) in &m.slip_m {
        assert!(*slip < 0.01, "{r}'s palm slipped {slip} m");
    }
    for (r, t) in &m.torsos {
        assert!(t.position_max_m < 0.01, "torso {r} moved {} m", t.position_max_m);
    }
}

/// A small seeded generator (xorshift64*): the cases are the same on every machine.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }

    fn int(&mut self, lo: usize, hi: usize) -> usize {
        lo + ((hi - lo + 1) as f64 * self.next()) as usize % (hi - lo + 1)
    }
}

/// Distance from a face to the base of the robot facing it, m (the shipped teams').
const STANDOFF: f64 = 0.85;
/// Least distance between neighbours along a face, m (the robots' footprints).
const MIN_SPACING: f64 = 0.75;

/// One random case: the scenario text and what it is.
fn random_case(rng: &mut Rng) -> (String, String) {
    let beam = rng.next() < 0.6;
    let (lx, w) = if beam {
        (rng.range(1.2, 2.4), rng.range(0.3, 0.45))
    } else {
        let s = rng.range(0.5, 0.7);
        (s, s)
    };
    let ly = w;
    // (x, y, yaw) of each base: along the long sides, and for a box or "one side and the ends"
    // at the ends too.
    let mut bases: Vec<(f64, f64, f64)> = Vec::new();
    let one_side_and_ends = beam && rng.next() < 0.4;
    // One side and the ends: two robots at the ends and at least one on the side.
    let n = rng.int(if one_side_and_ends { 3 } else { 2 }, 6);
    let sides: Vec<(f64, f64)> = if one_side_and_ends {
        vec![(-1.0, std::f64::consts::FRAC_PI_2)]
    } else {
        vec![(-1.0, std::f64::consts::FRAC_PI_2), (1.0, -std::f64::consts::FRAC_PI_2)]
    };
    let ends = if one_side_and_ends {
        2
    } else if !beam {
        rng.int(0, 2)
    } else {
        0
    };
    let along = n.saturating_sub(ends.min(n - 1));
    let per_side = along.div_ceil(sides.len());
    let mut placed = 0;
    for (sign, yaw) in &sides {
        let on_side = per_side.min(along - placed);
        // Unequal spacing: random positions along the face, at least MIN_SPACING apart.
        let half = (0.5 * lx - 0.1).max(0.0);
        let mut xs: Vec<f64> = Vec::new();
        for _ in 0..200 {
            if xs.len() == on_side {
                break;
            }
            let x = rng.range(-half, half);
            if xs.iter().all(|o| (o - x).abs() >= MIN_SPACING) {
                xs.push(x);
            }
        }
        for x in xs {
            bases.push((x, sign * (0.5 * ly + STANDOFF), *yaw));
        }
        placed += on_side;
    }
    for (k, (sign, yaw)) in [(-1.0, 0.0), (1.0, std::f64::consts::PI)].iter().enumerate() {
        if k < ends && bases.len() < n {
            bases.push((sign * (0.5 * lx + STANDOFF), rng.range(-0.05, 0.05) * ly, *yaw));
        }
    }
    let radius = rng.range(0.01, 0.06);
    let frequency = rng.range(0.2, 0.5);
    let robots: String = bases
        .iter()
        .enumerate()
        .map(|(i, (x, y, yaw))| format!("[[robots]]\nid = \"r{}\"\ndescription = \"robot-model/models/legged_manipulator.toml\"\nbase_xy = [{x}, {y}]\nyaw = {yaw}\n\n", i + 1))
        .collect();
    let what = format!(
        "{} {:.2} x {:.2} x {:.2} m, {} robots{}, circle {:.0} mm at {:.2} Hz",
        if beam { "beam" } else { "box" },
        lx,
        ly,
        w,
        bases.len(),
        if one_side_and_ends { " (one side and the ends)" } else { "" },
        1e3 * radius,
        frequency
    );
    let text = format!(
        "name = \"random\"\ndescription = \"{what}\"\nduration = 2.0\nsettle = 0.5\ncontrol_hz = 1000.0\nphysics_hz = 2000.0\nseed = 1\ncontroller = \"pidc\"\nmin_foot_force = 5.0\nmin_hand_force = 30.0\n\n\
         [object]\nsize = [{lx}, {ly}, {w}]\nmass = 1.0\nfriction = 0.8\nposition = [0.0, 0.0, 0.6]\n\n{robots}\
         [gains.torso]\nstiffness = [2000.0, 2000.0, 2000.0, 375.0, 375.0, 375.0]\ndamping = [50.0, 50.0, 50.0, 15.0, 15.0, 15.0]\n\n\
         [gains.object]\nstiffness = [250.0, 250.0, 250.0, 50.0, 50.0, 50.0]\ndamping = [35.0, 35.0, 35.0, 7.5, 7.5, 7.5]\n\n\
         [references.object.position]\nkind = \"circle\"\nradius = {radius}\nfrequency = {frequency}\nplane = \"xz\"\n"
    );
    (text, what)
}

/// A random case planned without the payload check, and its capacity; `Err` names why the
/// layout is refused whatever its mass (the planner cannot place it, or not even an empty
/// object is held).
fn planned_case(
    text: &str,
    what: &str,
) -> Result<(scenario::plan::Plan, scenario::team_capacity::ScenarioCapacity), String> {
    let file = repo().join("scenarios/random.toml");
    let base = Scenario::from_str_with(text, &file, &["capacity_check=false".into()])
        .map_err(|e| e.to_string())
        .and_then(|s| plan::plan(&s, &repo()).map_err(|e| format!("layout refused: {e}")))?;
    match scenario::team_capacity::capacity(&base, 0.005) {
        Ok(c) => Ok((base, c)),
        Err(e) => {
            let s = Scenario::from_str_with(text, &file, &[]).expect("scenario");
            assert!(
                matches!(plan::plan(&s, &repo()), Err(PlanError::Capacity { .. })),
                "{what}: the plan refuses what the check refuses ({e})"
            );
            Err(format!("refused at any mass: {e}"))
        }
    }
}

/// A mass for a case of capacity `cap`: half the draws within 85-100 % of it (where a check
/// that promises too much would show), a quarter lighter, a quarter up to 20 % over.
fn draw_mass((u, v): (f64, f64), cap: f64) -> f64 {
    cap * if u < 0.5 {
        0.85 + 0.15 * v
    } else if u < 0.75 {
        0.2 + 0.65 * v
    } else {
        1.0 + 0.2 * v
    }
}

#[test]
fn random_teams_hold_their_object_or_are_refused_by_the_plan_none_dropped() {
    let cases: usize =
        std::env::var("TEAM_RANDOM_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(30);
    // `TEAM_RANDOM_ONLY=K`: case K alone (the draws before it are made, not run).
    let only: Option<usize> = std::env::var("TEAM_RANDOM_ONLY").ok().and_then(|v| v.parse().ok());
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let file = repo().join("scenarios/random.toml");
    let (mut held, mut refused, mut unplaceable) = (0, 0, 0);
    let mut failures = Vec::new();
    for case in 0..cases {
        let (text, what) = random_case(&mut rng);
        let draw = (rng.next(), rng.next());
        if only.is_some_and(|k| k != case) {
            continue;
        }
        let cap = match planned_case(&text, &what) {
            Ok((_, cap)) => cap,
            Err(e) => {
                println!("case {case}: {what}: {e}");
                if e.starts_with("layout") {
                    unplaceable += 1
                } else {
                    refused += 1
                }
                continue;
            }
        };
        let limit = cap.mass();
        let mass = draw_mass(draw, limit);
        let share = format!(
            "{mass:.2} kg ({:.0} % of its capacity {limit:.2} kg; {:.2} at the start pose)",
            100.0 * mass / limit,
            cap.start.mass
        );
        let s = Scenario::from_str_with(&text, &file, &[format!("object.mass={mass}")])
            .expect("scenario");
        match plan::plan(&s, &repo()) {
            Err(PlanError::Capacity { check: e, .. }) => {
                println!("case {case}: {what}, {share}: refused: {e}");
                assert!(
                    mass > limit,
                    "case {case}: {what}: {share} is within the capacity and refused: {e}"
                );
                refused += 1;
            }
            Err(e) => panic!("case {case}: {what}: {e}"),
            Ok(p) => {
                assert!(
                    mass <= limit + 0.005,
                    "case {case}: {what}: {share} is over the capacity and accepted"
                );
                let name = format!("promises-random-{case}");
                let m = run_plan(&p, &name);
                // The case's scenario beside its report, to run it again with `team run`.
                std::fs::write(
                    common::scenario::report_dir(&name).join("scenario.toml"),
                    format!("{text}\n# object.mass = {mass}\n"),
                )
                .expect("scenario written");
                println!(
                    "case {case}: {what}, {share}: {}",
                    if m.passed { "held" } else { "FAILED" }
                );
                if m.passed {
                    held += 1;
                } else {
                    failures.push(format!(
                        "case {case}: {what}, {share}: dropped {}, checks failed {:?}",
                        m.drop.dropped,
                        m.checks.iter().filter(|c| !c.passed).map(|c| &c.name).collect::<Vec<_>>()
                    ));
                }
            }
        }
    }
    println!("{cases} random cases: {held} held, {refused} refused by the payload check, {unplaceable} layouts refused, {} failed", failures.len());
    assert!(failures.is_empty(), "every case is held or refused:\n{}", failures.join("\n"));
    assert!(
        only.is_some() || (held >= cases / 4 && refused >= 1),
        "the cases exercise both answers: {held} held, {refused} refused"
    );
}

/// The bounds of the mass tracked in MuJoCo without the motion yielding, over the team
/// problem's capacity along the motion (what the capacity promises: the plan accepts 2 % less).
const TRACKED_RATIO: (f64, f64) = (0.95, 1.05);

#[test]
fn the_capacity_is_what_the_team_holds_in_mujoco() {
    // The first random layouts held at some mass: by bisection over runs, the heaviest object
    // MuJoCo tracks without the motion yielding (what the capacity promises) and the heaviest
    // it holds with every check passed, against the team problem's capacity.
    // `TEAM_ACCURACY_CASES=30 cargo test --release -p team-tests --test plan_promises capacity_is -- --nocapture`
    // measures more.
    let cases: usize =
        std::env::var("TEAM_ACCURACY_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(4);
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    let file = repo().join("scenarios/random.toml");
    let mut ratios = Vec::new();
    for _ in 0..4 * cases {
        if ratios.len() == cases {
            break;
        }
        let (text, what) = random_case(&mut rng);
        let Ok((_, cap)) = planned_case(&text, &what) else { continue };
        let computed = cap.mass();
        let scenario = Scenario::from_str_with(&text, &file, &[]).expect("scenario");
        let k = ratios.len();
        let [held, tracked] = simulated::held_and_tracked(computed, 0.02 * computed, 16, |mass| {
            simulated::run_trial(
                &scenario,
                &repo(),
                mass,
                &common::scenario::report_dir(&format!("promises-accuracy-{k}-{mass:.3}")),
            )
        })
        .expect("the trials run");
        print!(
            "{what}: computed {computed:.3} kg\n{}{}",
            simulated::summary(&held, computed),
            simulated::summary(&tracked, computed)
        );
        assert!(
            held.trials.iter().chain(&tracked.trials).all(|t| !t.dropped || t.mass > computed),
            "{what}: a mass within the capacity was dropped: {:?}",
            held.trials
        );
        let mass = |s: &simulated::SimulatedCapacity| {
            s.held.unwrap_or_else(|| {
                panic!("{what}: not even {:.3} kg {:?}", 0.1 * computed, s.criterion)
            })
        };
        // Against the team problem's capacity along the motion (the plan accepts 2 % less).
        let whole = cap.whole().mass;
        ratios.push((what.clone(), mass(&held) / whole, mass(&tracked) / whole));
    }
    let show = |f: fn(&(String, f64, f64)) -> f64| {
        ratios.iter().map(|r| format!("{:.3}", f(r))).collect::<Vec<_>>()
    };
    println!("held in MuJoCo / the team problem's capacity: {:?}", show(|r| r.1));
    println!(
        "tracked in MuJoCo (the motion never yielding) / the team problem's capacity: {:?}",
        show(|r| r.2)
    );
    for (what, held, tracked) in &ratios {
        assert!(
            (0.95..=1.35).contains(held),
            "{what}: held in MuJoCo / the team problem's capacity = {held:.3}"
        );
        assert!(
            (TRACKED_RATIO.0..=TRACKED_RATIO.1).contains(tracked),
            "{what}: tracked in MuJoCo / the team problem's capacity = {tracked:.3}"
        );
    }
    assert_eq!(ratios.len(), cases, "enough random layouts hold something");
}
