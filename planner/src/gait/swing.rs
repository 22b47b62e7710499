//! Time profiles: the quintic blend with zero velocity and acceleration at both ends
//! ([`quintic`]), and a swing foot's path from lift-off to touchdown ([`swing`]).

use nalgebra::Vector3;

/// `s(u) = 10 u^3 - 15 u^4 + 6 u^5` and its first two derivatives in `u`, for `u` in [0, 1]
/// (clamped outside).
pub fn quintic(u: f64) -> (f64, f64, f64) {
    if u <= 0.0 {
        return (0.0, 0.0, 0.0);
    }
    if u >= 1.0 {
        return (1.0, 0.0, 0.0);
    }
    let (u2, u3) = (u * u, u * u * u);
    (
        u3 * (10.0 - 15.0 * u + 6.0 * u2),
        30.0 * u2 * (1.0 - u) * (1.0 - u),
        60.0 * u * (1.0 - u) * (1.0 - 2.0 * u),
    )
}

/// The lift bump `b(u) = 64 u^3 (1 - u)^3` (1 at mid-swing; zero value and velocity at both
/// ends) and its derivatives in `u`.
fn bump(u: f64) -> (f64, f64, f64) {
    if !(0.0..=1.0).contains(&u) {
        return (0.0, 0.0, 0.0);
    }
    let w = u * (1.0 - u);
    (64.0 * w * w * w, 192.0 * w * w * (1.0 - 2.0 * u), 384.0 * w * ((1.0 - 2.0 * u).powi(2) - w))
}

/// A swing foot from `from` to `to` over `duration` s, `lift` above the straight line at
/// mid-swing: position, velocity and acceleration `t` s after lift-off. Horizontal and
/// vertical progress follow [`quintic`]; the lift follows a bump, so the foot leaves and lands
/// with zero velocity.
pub fn swing(
    from: &Vector3<f64>,
    to: &Vector3<f64>,
    lift: f64,
    duration: f64,
    t: f64,
) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
    let u = t / duration;
    let (s, ds, dds) = quintic(u);
    let (b, db, ddb) = bump(u);
    let d = to - from;
    let up = Vector3::z();
    let p = from + d * s + up * (lift * b);
    let v = (d * ds + up * (lift * db)) / duration;
    let a = (d * dds + up * (lift * ddb)) / (duration * duration);
    (p, v, a)
}
