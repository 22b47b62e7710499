//! Reference trajectories of the scenarios: holds, sinusoids, circles and sequences of them,
//! for positions and for orientations, with exact velocities and accelerations.
//!
//! An [`OffsetMotion`] is an offset `x(t)` in R^3 from the task's initial value with
//! `x(0) = 0`, so a scenario starts without a jump. A position reference is `p0 + x(t)`; an
//! orientation reference is `exp([x(t)]) R0` (`x` a rotation vector in the world frame), whose
//! angular velocity is `J_l(x) xdot` (the left Jacobian of SO(3)).

use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use protocol::conventions::quat_to_wxyz;
use protocol::{Pose, PoseReference};
use robot_model::spatial::left_jacobian;
use serde::Deserialize;
use std::f64::consts::TAU;

/// Plane of a circle, as the two world axes it spans.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Plane {
    Xy,
    Xz,
    Yz,
}

impl Plane {
    fn axes(self) -> (usize, usize) {
        match self {
            Plane::Xy => (0, 1),
            Plane::Xz => (0, 2),
            Plane::Yz => (1, 2),
        }
    }
}

/// One segment of a [`OffsetMotion::Sequence`].
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Segment {
    /// Length of the segment, s.
    pub duration: f64,
    pub motion: OffsetMotion,
    /// Fade the segment's offset in over its first `ramp` seconds and out over its last (a
    /// smooth window: the segment starts and ends with zero offset, velocity and
    /// acceleration), so that switching segments does not step the velocity. 0: no window.
    #[serde(default)]
    pub ramp: f64,
}

/// Quintic smoothstep `S(u)` on [0, 1] (0 before, 1 after) and its first two derivatives in `u`.
fn smoothstep(u: f64) -> (f64, f64, f64) {
    if u <= 0.0 {
        (0.0, 0.0, 0.0)
    } else if u >= 1.0 {
        (1.0, 0.0, 0.0)
    } else {
        let (u2, u3) = (u * u, u * u * u);
        (
            10.0 * u3 - 15.0 * u2 * u2 + 6.0 * u3 * u2,
            30.0 * u2 - 60.0 * u3 + 30.0 * u2 * u2,
            60.0 * u - 180.0 * u2 + 120.0 * u3,
        )
    }
}

/// The window `w(t)`, `w'`, `w''`: a fade-in over `[0, ramp]` and, with `end = Some(d)`, a
/// fade-out over `[d - ramp, d]`. `ramp <= 0`: no window.
fn window(t: f64, ramp: f64, end: Option<f64>) -> (f64, f64, f64) {
    if ramp <= 0.0 {
        return (1.0, 0.0, 0.0);
    }
    let (a, ad, add) = smoothstep(t / ramp);
    let (ad, add) = (ad / ramp, add / (ramp * ramp));
    let Some(d) = end else { return (a, ad, add) };
    let (b, bd, bdd) = smoothstep((d - t) / ramp);
    let (bd, bdd) = (-bd / ramp, bdd / (ramp * ramp));
    (a * b, ad * b + a * bd, add * b + 2.0 * ad * bd + a * bdd)
}

impl Sample {
    /// `w(t) x(t)` with its derivatives, for a window `(w, w', w'')`.
    fn windowed(self, (w, wd, wdd): (f64, f64, f64)) -> Sample {
        Sample {
            x: w * self.x,
            xd: wd * self.x + w * self.xd,
            xdd: wdd * self.x + 2.0 * wd * self.xd + w * self.xdd,
        }
    }
}

/// An offset trajectory in R^3 with `x(0) = 0`.
#[derive(Debug, Clone, PartialEq, Deserialize, Default)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum OffsetMotion {
    /// Stay at the initial value.
    #[default]
    Hold,
    /// Per axis `A sin(2 pi f t + phi) - A sin(phi)`.
    Sinusoid {
        amplitude: [f64; 3],
        /// Hz.
        frequency: [f64; 3],
        /// rad.
        #[serde(default)]
        phase: [f64; 3],
    },
    /// A circle of `radius` in `plane`, starting at the current point and turning at
    /// `frequency` Hz: `r (cos(wt + phi) - cos(phi), sin(wt + phi) - sin(phi))`.
    Circle {
        radius: f64,
        frequency: f64,
        plane: Plane,
        #[serde(default)]
        phase: f64,
    },
    /// Motions one after another; each starts from where the previous one ended.
    Sequence { segments: Vec<Segment> },
}

/// Value, first and second time derivative of an offset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    pub x: Vector3<f64>,
    pub xd: Vector3<f64>,
    pub xdd: Vector3<f64>,
}

impl Sample {
    const ZERO: Sample = Sample {
        x: Vector3::new(0.0, 0.0, 0.0),
        xd: Vector3::new(0.0, 0.0, 0.0),
        xdd: Vector3::new(0.0, 0.0, 0.0),
    };
}

/// What is wrong with a motion's parameters.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct MotionError(pub String);

impl OffsetMotion {
    /// Finite numbers, non-negative frequencies and durations.
    pub fn check(&self, what: &str) -> Result<(), MotionError> {
        let bad = |m: String| Err(MotionError(format!("{what}: {m}")));
        match self {
            OffsetMotion::Hold => Ok(()),
            OffsetMotion::Sinusoid { amplitude, frequency, phase } => {
                if amplitude.iter().chain(frequency).chain(phase).any(|x| !x.is_finite()) {
                    return bad("non-finite sinusoid parameter".into());
                }
                if frequency.iter().any(|f| *f < 0.0) {
                    return bad("negative frequency".into());
                }
                Ok(())
            }
            OffsetMotion::Circle { radius, frequency, phase, .. } => {
                if ![*radius, *frequency, *phase].iter().all(|x| x.is_finite()) || *frequency < 0.0
                {
                    return bad(
                        "circle radius, frequency and phase must be finite, frequency >= 0".into(),
                    );
                }
                Ok(())
            }
            OffsetMotion::Sequence { segments } => {
                for (i, s) in segments.iter().enumerate() {
                    if !(s.duration.is_finite() && s.duration > 0.0) {
                        return bad(format!("segment {i} has duration {}", s.duration));
                    }
                    if !(s.ramp.is_finite() && s.ramp >= 0.0) {
                        return bad(format!("segment {i} has ramp {}", s.ramp));
                    }
                    s.motion.check(&format!("{what}.segments[{i}]"))?;
                }
                Ok(())
            }
        }
    }

    /// The offset and its derivatives at time `t` (s, from the scenario start).
    pub fn sample(&self, t: f64) -> Sample {
        match self {
            OffsetMotion::Hold => Sample::ZERO,
            OffsetMotion::Sinusoid { amplitude, frequency, phase } => {
                let mut s = Sample::ZERO;
                for i in 0..3 {
                    let w = TAU * frequency[i];
                    let (a, ph) = (amplitude[i], phase[i]);
                    s.x[i] = a * (w * t + ph).sin() - a * ph.sin();
                    s.xd[i] = a * w * (w * t + ph).cos();
                    s.xdd[i] = -a * w * w * (w * t + ph).sin();
                }
                s
            }
            OffsetMotion::Circle { radius, frequency, plane, phase } => {
                let (u, v) = plane.axes();
                let w = TAU * frequency;
                let th = w * t + phase;
                let mut s = Sample::ZERO;
                s.x[u] = radius * (th.cos() - phase.cos());
                s.x[v] = radius * (th.sin() - phase.sin());
                s.xd[u] = -radius * w * th.sin();
                s.xd[v] = radius * w * th.cos();
                s.xdd[u] = -radius * w * w * th.cos();
                s.xdd[v] = -radius * w * w * th.sin();
                s
            }
            OffsetMotion::Sequence { segments } => {
                let mut start = 0.0;
                let mut base = Vector3::zeros();
                for seg in segments {
                    let end = start + seg.duration;
                    if t < end {
                        let mut s = seg.motion.sample(t - start).windowed(window(
                            t - start,
                            seg.ramp,
                            Some(seg.duration),
                        ));
                        s.x += base;
                        return s;
                    }
                    base += seg
                        .motion
                        .sample(seg.duration)
                        .windowed(window(seg.duration, seg.ramp, Some(seg.duration)))
                        .x;
                    start = end;
                }
                Sample { x: base, ..Sample::ZERO }
            }
        }
    }
}

/// A pose task's reference: position and orientation motions about the initial pose.
#[derive(Debug, Clone, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct PoseMotion {
    #[serde(default)]
    pub position: OffsetMotion,
    /// Rotation-vector offset in the world frame, rad.
    #[serde(default)]
    pub orientation: OffsetMotion,
}

impl PoseMotion {
    pub fn check(&self, what: &str) -> Result<(), MotionError> {
        self.position.check(&format!("{what}.position"))?;
        self.orientation.check(&format!("{what}.orientation"))
    }

    /// The reference at time `t` about the initial pose `(p0, r0)`, both motions faded in over
    /// the first `ramp` seconds (a smooth window; 0: none): a motion that starts with a
    /// velocity (a sinusoid) would otherwise step the reference velocity at `t = 0`.
    pub fn reference(
        &self,
        p0: &Vector3<f64>,
        r0: &UnitQuaternion<f64>,
        t: f64,
        ramp: f64,
    ) -> PoseReference {
        let p = self.position.sample(t).windowed(window(t, ramp, None));
        let (rot, w, wd) =
            orientation(|t| self.orientation.sample(t).windowed(window(t, ramp, None)), t);
        let q = UnitQuaternion::from_rotation_matrix(&rot) * r0;
        let pos = p0 + p.x;
        PoseReference {
            pose: Pose { position: [pos.x, pos.y, pos.z], orientation: quat_to_wxyz(&q) },
            twist: [p.xd.x, p.xd.y, p.xd.z, w.x, w.y, w.z],
            acceleration: [p.xdd.x, p.xdd.y, p.xdd.z, wd.x, wd.y, wd.z],
        }
    }
}

/// Rotation, angular velocity and angular acceleration (world frame) of `exp([x(t)])`. The
/// acceleration is the central difference of the exact angular velocity (step 1e-5 s; error
/// of order 1e-10 for the scenario's frequencies).
fn orientation(
    sample: impl Fn(f64) -> Sample,
    t: f64,
) -> (Rotation3<f64>, Vector3<f64>, Vector3<f64>) {
    let omega = |t: f64| {
        let s = sample(t);
        left_jacobian(&s.x) * s.xd
    };
    let s = sample(t);
    let rot = Rotation3::new(s.x);
    let h = 1e-5;
    let wd = (omega(t + h) - omega(t - h)) / (2.0 * h);
    (rot, omega(t), wd)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fd(m: &OffsetMotion, t: f64) -> (Vector3<f64>, Vector3<f64>) {
        let h = 1e-6;
        let (a, b, c) = (m.sample(t - h).x, m.sample(t).x, m.sample(t + h).x);
        ((c - a) / (2.0 * h), (c - 2.0 * b + a) / (h * h))
    }

    fn motions() -> Vec<OffsetMotion> {
        vec![
            OffsetMotion::Sinusoid {
                amplitude: [0.03, 0.0, 0.02],
                frequency: [0.25, 0.5, 0.4],
                phase: [0.0, 1.0, 1.5],
            },
            OffsetMotion::Circle { radius: 0.05, frequency: 0.2, plane: Plane::Xz, phase: 0.3 },
            OffsetMotion::Sequence {
                segments: vec![
                    Segment {
                        duration: 2.0,
                        motion: OffsetMotion::Sinusoid {
                            amplitude: [0.1, 0.0, 0.0],
                            frequency: [0.5, 0.0, 0.0],
                            phase: [0.0; 3],
                        },
                        ramp: 0.0,
                    },
                    Segment {
                        duration: 1.5,
                        motion: OffsetMotion::Circle {
                            radius: 0.02,
                            frequency: 1.0,
                            plane: Plane::Xy,
                            phase: 0.0,
                        },
                        ramp: 0.4,
                    },
                ],
            },
        ]
    }

    #[test]
    fn offsets_start_at_zero_and_derivatives_match_finite_differences() {
        for m in motions() {
            assert!(m.sample(0.0).x.norm() < 1e-15, "{m:?}");
            for t in [0.3, 1.1, 2.7, 3.2] {
                let s = m.sample(t);
                let (v, a) = fd(&m, t);
                assert!((s.xd - v).norm() < 1e-6, "{m:?} at {t}: {} vs {}", s.xd, v);
                assert!((s.xdd - a).norm() < 1e-3, "{m:?} at {t}: {} vs {}", s.xdd, a);
            }
        }
    }

    #[test]
    fn a_sequence_continues_from_where_the_previous_segment_ended() {
        let m = &motions()[2];
        let before = m.sample(2.0 - 1e-9).x;
        let after = m.sample(2.0 + 1e-9).x;
        assert!((before - after).norm() < 1e-7);
        // After the last segment it holds the end point.
        assert_eq!(m.sample(10.0).x, m.sample(3.5).x);
    }

    #[test]
    fn orientation_reference_has_the_right_angular_velocity() {
        let pm = PoseMotion {
            position: OffsetMotion::Hold,
            orientation: OffsetMotion::Sinusoid {
                amplitude: [0.17, 0.1, 0.15],
                frequency: [0.3, 0.2, 0.25],
                phase: [0.0, 0.5, 1.0],
            },
        };
        let r0 = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3);
        let p0 = Vector3::new(1.0, 0.0, 0.6);
        for t in [0.0, 0.7, 2.3] {
            let h = 1e-6;
            let q = |t: f64| {
                protocol::conventions::quat_from_wxyz(
                    pm.reference(&p0, &r0, t, 0.5).pose.orientation,
                )
            };
            // World angular velocity: log(R(t+h) R(t-h)^T) / 2h.
            let dq = q(t + h) * q(t - h).inverse();
            let w_fd = dq.scaled_axis() / (2.0 * h);
            let r = pm.reference(&p0, &r0, t, 0.5);
            let w = Vector3::new(r.twist[3], r.twist[4], r.twist[5]);
            assert!((w - w_fd).norm() < 1e-6, "t {t}: {w} vs {w_fd}");
            // Angular acceleration against a finite difference of the angular velocity.
            let wv = |t: f64| {
                let r = pm.reference(&p0, &r0, t, 0.5);
                Vector3::new(r.twist[3], r.twist[4], r.twist[5])
            };
            let a_fd = (wv(t + 1e-4) - wv(t - 1e-4)) / 2e-4;
            let a = Vector3::new(r.acceleration[3], r.acceleration[4], r.acceleration[5]);
            assert!((a - a_fd).norm() < 1e-5, "t {t}: {a} vs {a_fd}");
        }
        // At t = 0 the reference is the initial pose.
        let r = pm.reference(&p0, &r0, 0.0, 0.5);
        assert!(protocol::conventions::quat_from_wxyz(r.pose.orientation).angle_to(&r0) < 1e-12);
    }

    #[test]
    fn ramps_start_and_end_segments_at_rest_with_exact_derivatives() {
        // A faded-in sinusoid starts with zero velocity and acceleration, reaches the plain
        // sinusoid after the ramp, and its derivatives match finite differences inside the ramp.
        let pm = PoseMotion {
            position: OffsetMotion::Sinusoid {
                amplitude: [0.03, 0.0, 0.02],
                frequency: [0.2, 0.0, 0.25],
                phase: [0.0; 3],
            },
            orientation: OffsetMotion::Hold,
        };
        let (p0, r0) = (Vector3::new(1.0, 0.0, 0.6), UnitQuaternion::identity());
        let r = pm.reference(&p0, &r0, 0.0, 1.0);
        assert!(r.twist.iter().chain(&r.acceleration).all(|x| x.abs() < 1e-15), "{r:?}");
        let late = pm.reference(&p0, &r0, 1.5, 1.0);
        let plain = pm.reference(&p0, &r0, 1.5, 0.0);
        assert_eq!(late, plain);
        for t in [0.2, 0.5, 0.9] {
            let h = 1e-6;
            let x = |t: f64| Vector3::from(pm.reference(&p0, &r0, t, 1.0).pose.position);
            let v = Vector3::from_row_slice(&pm.reference(&p0, &r0, t, 1.0).twist[..3]);
            let a = Vector3::from_row_slice(&pm.reference(&p0, &r0, t, 1.0).acceleration[..3]);
            assert!((v - (x(t + h) - x(t - h)) / (2.0 * h)).norm() < 1e-8, "t {t}");
            assert!((a - (x(t + 1e-4) - 2.0 * x(t) + x(t - 1e-4)) / 1e-8).norm() < 1e-5, "t {t}");
        }
        // A windowed segment ends at rest: no velocity step into the next one.
        let m = &motions()[2];
        let end = m.sample(3.5 - 1e-9);
        assert!(end.xd.norm() < 1e-6 && end.xdd.norm() < 1e-3, "{end:?}");
    }

    #[test]
    fn bad_parameters_are_named() {
        let m = OffsetMotion::Sinusoid {
            amplitude: [f64::NAN, 0.0, 0.0],
            frequency: [1.0; 3],
            phase: [0.0; 3],
        };
        assert!(m.check("object.position").unwrap_err().0.contains("object.position"));
        let m = OffsetMotion::Sequence {
            segments: vec![Segment { duration: -1.0, motion: OffsetMotion::Hold, ramp: 0.0 }],
        };
        assert!(m.check("x").is_err());
    }
}
