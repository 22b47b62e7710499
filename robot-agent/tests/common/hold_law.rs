//! The posture hold's law written out from the torque limits, for the tests that check the
//! agent's hold against it (`robot_agent::safe_mode::HoldGains` is the code under test). Also
//! included by the team tests' `fall.rs` (`#[path]`).

/// The posture hold's gains written out from a joint's torque limit: the limit is reached at
/// 0.5 rad of error (`Kp = limit / 0.5 rad`), `Kd = Kp * 25 ms`; 100 N m/rad and 2.5 N m s/rad
/// for a joint without a finite limit.
pub fn hold_kp(limit: f64) -> f64 {
    if limit.is_finite() {
        limit / 0.5
    } else {
        100.0
    }
}

/// See [`hold_kp`].
pub fn hold_kd(limit: f64) -> f64 {
    hold_kp(limit) * 0.025
}
