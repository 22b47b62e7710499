//! The contact switch: sets apply at their tick, a lift-off keeps enough feet down, a
//! touchdown waits for the foot's force (early or late), and the schedule is bounded.

use robot_agent::contact_switch::{ContactSwitch, SwitchConfig};
use robot_agent::terms::ActiveContacts;

fn set(stance: [bool; 4]) -> ActiveContacts {
    ActiveContacts { stance: stance.to_vec(), hand_in_grasp: true }
}

fn all_down() -> ContactSwitch {
    ContactSwitch::new(SwitchConfig::default(), set([true; 4]))
}

const LOADED: [f64; 4] = [100.0; 4];
/// Foot 0 unloaded by its ramp, the others carrying the robot.
const FOOT0_UNLOADED: [f64; 4] = [0.0, 100.0, 100.0, 100.0];

#[test]
fn a_set_applies_from_its_tick_not_before() {
    let mut s = all_down();
    s.schedule(105, set([false, true, true, true])).unwrap();
    for tick in 100..105 {
        assert!(!s.on_state(tick, &LOADED).changed(), "tick {tick}");
        assert_eq!(s.active().stance, vec![true; 4]);
    }
    let ev = s.on_state(105, &FOOT0_UNLOADED);
    assert_eq!(ev.liftoffs, 1);
    assert_eq!(s.active().stance, vec![false, true, true, true]);
    assert_eq!(s.scheduled(), 0);
}

#[test]
fn sets_in_order_wait_and_a_set_for_an_earlier_tick_is_the_new_plan_from_there() {
    let mut s = all_down();
    s.schedule(10, set([true, false, true, true])).unwrap();
    s.schedule(30, set([true, true, true, true])).unwrap();
    s.schedule(50, set([false, true, true, true])).unwrap();
    assert_eq!(s.scheduled(), 3, "sets sent in tick order all wait");
    // The planner changes its mind at tick 30: all four down from then on, nothing after.
    s.schedule(30, set([true, true, false, true])).unwrap();
    assert_eq!(s.scheduled(), 2, "the set of tick 50 was cancelled");
    s.on_state(10, &[100.0, 0.0, 100.0, 100.0]);
    assert_eq!(s.active().stance, vec![true, false, true, true]);
    s.on_state(30, &[100.0, 100.0, 0.0, 100.0]);
    assert_eq!(s.active().stance, vec![true, true, false, true], "the newer set of tick 30 wins");
    for t in 31..200 {
        s.on_state(t, &[0.0, 100.0, 0.0, 100.0]);
    }
    assert_eq!(
        s.active().stance,
        vec![true, true, false, true],
        "the cancelled lift-off of tick 50 never happens"
    );
    assert_eq!(s.scheduled(), 0);
}

#[test]
fn a_liftoff_that_would_leave_two_feet_is_deferred() {
    let mut s = all_down();
    s.schedule(1, set([false, false, true, true])).unwrap();
    let unloaded = [0.0, 0.0, 150.0, 150.0];
    let ev = s.on_state(1, &unloaded);
    assert_eq!((ev.liftoffs, ev.deferred), (1, 1));
    assert_eq!(s.active().stance.iter().filter(|x| **x).count(), 3);
    let ev = s.on_state(2, &unloaded);
    assert_eq!((ev.liftoffs, ev.deferred), (0, 1), "still deferred while the goal asks for it");
}

#[test]
fn a_touchdown_waits_for_the_force_late_or_early() {
    let mut s = all_down();
    s.schedule(1, set([false, true, true, true])).unwrap();
    s.on_state(1, &FOOT0_UNLOADED);
    // The set that lands the foot is due at tick 50 (its planned touchdown minus the lead).
    s.schedule(50, set([true; 4])).unwrap();
    // Early contact (tick 40, before the set is due): the foot stays in swing.
    assert!(!s.on_state(40, &[80.0, 100.0, 100.0, 100.0]).changed());
    // Due, but the foot is still in the air (late touchdown): swing, awaiting.
    let ev = s.on_state(50, &[0.0, 100.0, 100.0, 100.0]);
    assert_eq!((ev.touchdowns, ev.awaiting_touchdown), (0, 1));
    assert!(!s.active().stance[0]);
    let ev = s.on_state(51, &[19.0, 100.0, 100.0, 100.0]);
    assert_eq!(ev.touchdowns, 0, "below the 20 N threshold");
    let ev = s.on_state(52, &[25.0, 100.0, 100.0, 100.0]);
    assert_eq!(ev.touchdowns, 1);
    assert_eq!(s.active().stance, vec![true; 4]);
}

#[test]
fn a_landing_lets_the_next_foot_lift_in_the_same_state() {
    let mut s = all_down();
    s.schedule(1, set([false, true, true, true])).unwrap();
    s.on_state(1, &FOOT0_UNLOADED);
    // The next step is due before foot 0 is confirmed down: deferred, then both at once.
    s.schedule(10, set([true, false, true, true])).unwrap();
    let ev = s.on_state(10, &[0.0, 5.0, 150.0, 150.0]);
    assert_eq!((ev.touchdowns, ev.liftoffs, ev.deferred), (0, 0, 1));
    let ev = s.on_state(11, &[60.0, 5.0, 150.0, 150.0]);
    assert_eq!((ev.touchdowns, ev.liftoffs), (1, 1));
    assert_eq!(s.active().stance, vec![true, false, true, true]);
}

#[test]
fn without_force_sensing_a_touchdown_is_the_planned_tick() {
    let mut s = all_down();
    s.schedule(1, set([false, true, true, true])).unwrap();
    s.on_state(1, &[]);
    s.schedule(5, set([true; 4])).unwrap();
    assert!(!s.on_state(4, &[]).changed());
    assert_eq!(s.on_state(5, &[]).touchdowns, 1);
}

#[test]
fn the_schedule_is_bounded() {
    let cfg = SwitchConfig { max_scheduled: 3, ..SwitchConfig::default() };
    let mut s = ContactSwitch::new(cfg, set([true; 4]));
    for t in 0..3 {
        s.schedule(100 + t, set([true; 4])).unwrap();
    }
    let full = s.schedule(200, set([true; 4])).unwrap_err();
    assert_eq!((full.tick, full.capacity), (200, 3));
    assert!(
        s.schedule(101, set([false, true, true, true])).is_ok(),
        "replacing a scheduled tick needs no room"
    );
    assert_eq!(s.scheduled(), 2, "and cancels the later one");
}

#[test]
fn a_foot_still_loaded_does_not_lift_off_until_its_force_is_down() {
    let mut s = all_down();
    s.schedule(1, set([false, true, true, true])).unwrap();
    let ev = s.on_state(1, &[60.0, 100.0, 100.0, 100.0]);
    assert_eq!(
        (ev.liftoffs, ev.deferred),
        (0, 1),
        "60 N on the foot: the ramp has not unloaded it"
    );
    assert!(s.active().stance[0]);
    let ev = s.on_state(2, &[4.0, 150.0, 150.0, 150.0]);
    assert_eq!(ev.liftoffs, 1);
    assert!(!s.active().stance[0]);
}
