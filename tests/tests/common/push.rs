//! The push the team cannot hold and what a release must leave: S4 with its 1 kg cube pushed
//! down by 300 N (thirty times its weight) for 0.6 s from 0.5 s into the circle, more than the
//! grasp's friction can carry (`degrade.rs` in lockstep, `realtime.rs` against the wall clock).

use std::path::PathBuf;

use evaluation::evaluate::Metrics;

/// S4's scenario file and its text with the push appended.
pub fn s4_pushed_off() -> (PathBuf, String) {
    let file = super::scenario::repo().join("scenarios/s4_object_circle.toml");
    let text = std::fs::read_to_string(&file).expect("scenario text")
        + "\n[[perturbations]]\non = \"object\"\nstart = 0.5\nduration = 0.6\n\
           wrench = [0.0, 0.0, -300.0, 0.0, 0.0, 0.0]\n";
    (file, text)
}

/// The report names the release: "grasp released at tick N: cause".
pub fn assert_release_named(m: &Metrics) {
    let note = m.release.as_deref().expect("the report names the release");
    let (tick, cause) = note
        .strip_prefix("grasp released at tick ")
        .and_then(|rest| rest.split_once(": "))
        .unwrap_or_else(|| panic!("the release's tick and cause: {note}"));
    assert!(tick.parse::<u64>().is_ok() && !cause.is_empty(), "{note}");
}

/// Every one of `robots` torsos evaluated and within 5 cm and 10 deg of its hold (ground truth).
pub fn assert_team_standing(m: &Metrics, robots: usize) {
    assert_eq!(m.torsos.len(), robots, "every torso evaluated");
    for (r, t) in &m.torsos {
        assert!(t.position_max_m < 0.05, "torso {r} moved {:.3} m from its hold", t.position_max_m);
        assert!(t.orientation_max_deg < 10.0, "torso {r} tilted {:.2} deg", t.orientation_max_deg);
    }
}
