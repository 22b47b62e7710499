//! The gains an agent sends its drives with each command ([`protocol::DriveCommand`]).
//!
//! Between two team commands a robot's drives execute
//! `tau = tau_ff + kp (q_des - q) + kd (qd_des - qd)` at their own rate. With
//! [`DriveGainsMode::None`] the agent sends no gains: the drives apply `tau_ff`, the paper's
//! pure torque loop. With [`DriveGainsMode::Inertia`] each joint gets the gains of a critically
//! damped second-order loop of bandwidth [`BANDWIDTH_HZ`] on its own inertia `M_jj` (the
//! diagonal of the joint-space mass matrix at the robot's first measured state, the standing
//! pose):
//!
//! ```text
//! kp = omega^2 M_jj,   kd = 2 zeta omega M_jj,   omega = 2 pi BANDWIDTH_HZ,  zeta = DAMPING_RATIO
//! ```
//!
//! with `kp` capped so that an error of [`FULL_TORQUE_ERROR`] reaches the joint's torque limit.
//!
//! The reference ([`reference`]) is the latest measured state carried forward over [`lead`]:
//! the drives hold one `q_des` for the whole team period while the joint moves on, so the
//! reference is where the joint is, on average, at the drive steps of that period. The
//! acceleration it is carried with is the one measured over the last two states. On that
//! trajectory the law adds nothing on average to `tau_ff`; a drive left with the command (a
//! late command, a team slower than the drives) pulls the joint back to it instead of applying
//! a stale torque open loop.
//!
//! The bandwidth is a trade: the law acts within each team period too, where the reference is
//! only on average right. S4 in lockstep (2 s, 1 kHz team, 2 kHz drives) keeps an object RMS
//! of 0.073 mm without gains; 0.083 mm at 5 Hz, 0.15 mm at 10 Hz, 0.33 mm at 20 Hz (and 1.7 mm
//! at 20 Hz with the state itself as the reference).

use std::fmt;
use std::str::FromStr;

use serde::Deserialize;

/// The closed-loop bandwidth of a joint under the drive gains, Hz: a leg joint's stiffness is
/// then about the posture hold's (`crate::safe_mode::HoldGains`), which keeps a robot standing.
pub const BANDWIDTH_HZ: f64 = 5.0;
/// The damping ratio of a joint under the drive gains: critical.
pub const DAMPING_RATIO: f64 = 1.0;
/// An error this large reaches the joint's torque limit through `kp` alone, rad (m): the cap
/// on `kp` for light joints with strong motors.
pub const FULL_TORQUE_ERROR: f64 = 0.05;

/// Which gains the agent sends with its commands (the scenario key `drive_gains`, the agent's
/// `--drive-gains` flag).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DriveGainsMode {
    /// No gains: the drives apply the team's torque (the paper's loop).
    #[default]
    None,
    /// Per-joint gains from the joint's inertia ([`DriveGains::from_inertia`]).
    Inertia,
}

impl DriveGainsMode {
    pub fn as_str(self) -> &'static str {
        match self {
            DriveGainsMode::None => "none",
            DriveGainsMode::Inertia => "inertia",
        }
    }
}

impl fmt::Display for DriveGainsMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for DriveGainsMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "none" => Ok(DriveGainsMode::None),
            "inertia" => Ok(DriveGainsMode::Inertia),
            other => Err(format!("unknown drive gains {other:?}: \"none\" or \"inertia\"")),
        }
    }
}

/// Per-joint drive gains, velocity order.
#[derive(Debug, Clone, PartialEq)]
pub struct DriveGains {
    /// Stiffness, N·m/rad.
    pub kp: Vec<f64>,
    /// Damping, N·m·s/rad.
    pub kd: Vec<f64>,
}

/// How far ahead of the latest state the reference is, s: the mean offset of the drive steps
/// within a team period `h`, `(h - drive_period) / 2` (drive steps at `0, dt, ..., h - dt`;
/// `None`: drives much faster than the team, `h / 2`). Drives that step once per team period
/// get the state itself: the law is then exactly the torque.
pub fn lead(h: f64, drive_period: Option<f64>) -> f64 {
    ((h - drive_period.unwrap_or(0.0)) / 2.0).max(0.0)
}

/// The reference of a command: the latest state `q`, `qd` carried over `lead` s at the
/// acceleration measured from the velocities `qd_prev` of the state `h` s before (zero without
/// one, `h` not positive): `q_des = q + qd lead + a lead^2 / 2`, `qd_des = qd + a lead`.
pub fn reference(q: &[f64], qd: &[f64], qd_prev: Option<&[f64]>, h: f64, lead: f64, q_des: &mut Vec<f64>, qd_des: &mut Vec<f64>) {
    q_des.clear();
    q_des.extend_from_slice(q);
    qd_des.clear();
    qd_des.extend_from_slice(qd);
    for j in 0..q.len() {
        let a = match qd_prev {
            Some(p) if h > 0.0 => (qd[j] - p[j]) / h,
            _ => 0.0,
        };
        q_des[j] += qd[j] * lead + 0.5 * a * lead * lead;
        qd_des[j] += a * lead;
    }
}

/// Why no gains could be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DriveGainsError {
    #[error("{inertia} joint inertias for {limits} torque limits")]
    Sizes { inertia: usize, limits: usize },
    #[error("joint {joint}: inertia {value} is not positive and finite")]
    Inertia { joint: usize, value: f64 },
}

impl DriveGains {
    /// The gains of the module documentation from each joint's inertia `M_jj` (kg·m², the mass
    /// matrix's diagonal over the actuated joints) and torque limit (`f64::INFINITY`: no cap).
    pub fn from_inertia(inertia: &[f64], limits: &[f64]) -> Result<Self, DriveGainsError> {
        if inertia.len() != limits.len() {
            return Err(DriveGainsError::Sizes { inertia: inertia.len(), limits: limits.len() });
        }
        if let Some(j) = inertia.iter().position(|m| !(m.is_finite() && *m > 0.0)) {
            return Err(DriveGainsError::Inertia { joint: j, value: inertia[j] });
        }
        let omega = 2.0 * std::f64::consts::PI * BANDWIDTH_HZ;
        let kp = inertia.iter().zip(limits).map(|(m, l)| (omega * omega * m).min(l / FULL_TORQUE_ERROR)).collect();
        let kd = inertia.iter().map(|m| 2.0 * DAMPING_RATIO * omega * m).collect();
        Ok(DriveGains { kp, kd })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A joint of inertia `m` under `kp`, `kd`: `m e'' + kd e' + kp e = 0`, natural frequency
    /// `sqrt(kp / m)` and damping ratio `kd / (2 sqrt(kp m))`.
    fn loop_of(m: f64, kp: f64, kd: f64) -> (f64, f64) {
        ((kp / m).sqrt() / (2.0 * std::f64::consts::PI), kd / (2.0 * (kp * m).sqrt()))
    }

    #[test]
    fn each_joint_closes_a_critically_damped_loop_at_the_bandwidth() {
        let inertia = [0.4, 0.02, 1e-3];
        let g = DriveGains::from_inertia(&inertia, &[f64::INFINITY; 3]).unwrap();
        for (j, m) in inertia.iter().enumerate() {
            let (hz, zeta) = loop_of(*m, g.kp[j], g.kd[j]);
            assert!((hz - BANDWIDTH_HZ).abs() < 1e-9, "joint {j}: {hz} Hz");
            assert!((zeta - 1.0).abs() < 1e-9, "joint {j}: damping ratio {zeta}");
        }
    }

    #[test]
    fn a_strong_light_joint_is_capped_at_its_limit() {
        // 2 kg m^2 wants 1974 N m/rad at 5 Hz; with 80 N m the cap is 80 / 0.05 = 1600.
        let g = DriveGains::from_inertia(&[2.0, 1e-3], &[80.0, 80.0]).unwrap();
        assert!((g.kp[0] * 0.05 - 80.0).abs() < 1e-9, "kp {} reaches {} N m at 0.05 rad", g.kp[0], g.kp[0] * 0.05);
        // The light joint is under its cap: its loop is the bandwidth's.
        assert!((loop_of(1e-3, g.kp[1], g.kd[1]).0 - BANDWIDTH_HZ).abs() < 1e-9);
        // Capped stiffness, same damping: overdamped, never oscillating.
        assert!(loop_of(2.0, g.kp[0], g.kd[0]).1 > 1.0);
    }

    #[test]
    fn the_lead_is_the_mean_offset_of_the_drive_steps() {
        let h = 1e-3;
        for n in [1u32, 2, 4, 10] {
            let dt = h / f64::from(n);
            let mean = (0..n).map(|i| f64::from(i) * dt).sum::<f64>() / f64::from(n);
            assert!((lead(h, Some(dt)) - mean).abs() < 1e-15, "{n} drive steps per period");
        }
        assert_eq!(lead(h, Some(h)), 0.0, "one drive step per period: the state itself");
        assert_eq!(lead(h, None), h / 2.0);
    }

    #[test]
    fn at_constant_acceleration_the_reference_is_the_trajectory_ahead() {
        // q(t) = q0 + v0 t + a t^2 / 2, measured at t1 - h and t1; the reference lead s ahead.
        let (q0, v0, a, h, t1, ahead) = ([0.3, -1.0], [0.5, 2.0], [4.0, -10.0], 1e-3, 0.2, 2.5e-4);
        let at = |t: f64, j: usize| (q0[j] + v0[j] * t + 0.5 * a[j] * t * t, v0[j] + a[j] * t);
        let (q, qd): (Vec<f64>, Vec<f64>) = (0..2).map(|j| at(t1, j)).unzip();
        let prev: Vec<f64> = (0..2).map(|j| at(t1 - h, j).1).collect();
        let (mut q_des, mut qd_des) = (Vec::new(), Vec::new());
        reference(&q, &qd, Some(&prev), h, ahead, &mut q_des, &mut qd_des);
        for j in 0..2 {
            let (qt, vt) = at(t1 + ahead, j);
            assert!((q_des[j] - qt).abs() < 1e-12 && (qd_des[j] - vt).abs() < 1e-9, "joint {j}: {} {} vs {qt} {vt}", q_des[j], qd_des[j]);
        }
        // Without a previous state: carried at constant velocity.
        reference(&q, &qd, None, h, ahead, &mut q_des, &mut qd_des);
        assert_eq!((q_des[0], qd_des[0]), (q[0] + qd[0] * ahead, qd[0]));
    }

    #[test]
    fn bad_inertias_and_sizes_are_refused() {
        assert_eq!(DriveGains::from_inertia(&[0.1], &[1.0, 2.0]), Err(DriveGainsError::Sizes { inertia: 1, limits: 2 }));
        assert!(matches!(DriveGains::from_inertia(&[0.1, 0.0], &[1.0, 1.0]), Err(DriveGainsError::Inertia { joint: 1, .. })));
        assert!(matches!(DriveGains::from_inertia(&[f64::NAN], &[1.0]), Err(DriveGainsError::Inertia { joint: 0, .. })));
    }

    #[test]
    fn modes_read_and_print_their_names() {
        for m in [DriveGainsMode::None, DriveGainsMode::Inertia] {
            assert_eq!(m.as_str().parse::<DriveGainsMode>(), Ok(m));
        }
        assert!("stiff".parse::<DriveGainsMode>().unwrap_err().contains("\"none\" or \"inertia\""));
        assert_eq!(DriveGainsMode::default(), DriveGainsMode::None);
    }
}
