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
//! The reference ([`Reference`]) is the latest measured state carried forward over [`lead`]:
//! the drives hold one `q_des` until the next state's command while the joint moves on, so the
//! reference is where the joint is, on average, at the drive steps of that period. The
//! acceleration it is carried with is the one measured over the last two states. On that
//! trajectory the law adds nothing on average to `tau_ff`; a drive left with the command (a
//! late command) pulls the joint back to it instead of applying a stale torque open loop. With
//! the team slower than the robot (`crate::core::AgentConfig::team_every`) the agent answers
//! each state between team ticks with the last team torque and the reference at that state.
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

/// `q + qd lead + a lead^2 / 2` into `q_des` and `qd + a lead` into `qd_des`: a state carried
/// `lead` s at the acceleration `a`.
pub fn carry(
    q: &[f64],
    qd: &[f64],
    a: &[f64],
    lead: f64,
    q_des: &mut Vec<f64>,
    qd_des: &mut Vec<f64>,
) {
    q_des.clear();
    qd_des.clear();
    for j in 0..q.len() {
        q_des.push(q[j] + qd[j] * lead + 0.5 * a[j] * lead * lead);
        qd_des.push(qd[j] + a[j] * lead);
    }
}

/// The reference a drive command goes with: the latest measured state, carried over [`lead`]
/// at the acceleration measured from the state before it. On ticks between team ticks too:
/// carrying the team tick's state over the ticks since instead pulled the joints towards an
/// extrapolation that the team's next torques did not follow (S4 with the team at 100 Hz:
/// object RMS 1.35 mm against 0.21 mm).
#[derive(Debug, Clone)]
pub struct Reference {
    drive_period: Option<f64>,
    /// Time of the latest state; the period from the one before (0: none yet).
    last: Option<f64>,
    period: f64,
    q: Vec<f64>,
    qd: Vec<f64>,
    a: Vec<f64>,
}

impl Reference {
    /// For `joints` joints whose drives run at `drive_period` s (`None`: much faster than the
    /// team). Every buffer is allocated here.
    pub fn new(joints: usize, drive_period: Option<f64>) -> Self {
        let z = || vec![0.0; joints];
        Reference { drive_period, last: None, period: 0.0, q: z(), qd: z(), a: z() }
    }

    /// A new state (not a repeat of the latest) at `time`.
    pub fn on_state(&mut self, time: f64, q: &[f64], qd: &[f64]) {
        let h = self.last.map(|t| time - t).filter(|h| *h > 0.0);
        for ((a, qd), qd_last) in self.a.iter_mut().zip(qd).zip(&self.qd) {
            *a = h.map_or(0.0, |h| (qd - qd_last) / h);
        }
        if let Some(h) = h {
            self.period = h;
        }
        self.last = Some(time);
        self.q.copy_from_slice(q);
        self.qd.copy_from_slice(qd);
    }

    /// The reference at the latest state into `q_des`, `qd_des` (nothing before a state).
    pub fn fill(&self, q_des: &mut Vec<f64>, qd_des: &mut Vec<f64>) {
        if self.last.is_none() {
            return;
        }
        let ahead = if self.period > 0.0 { lead(self.period, self.drive_period) } else { 0.0 };
        carry(&self.q, &self.qd, &self.a, ahead, q_des, qd_des);
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
        let kp = inertia
            .iter()
            .zip(limits)
            .map(|(m, l)| (omega * omega * m).min(l / FULL_TORQUE_ERROR))
            .collect();
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
        assert!(
            (g.kp[0] * 0.05 - 80.0).abs() < 1e-9,
            "kp {} reaches {} N m at 0.05 rad",
            g.kp[0],
            g.kp[0] * 0.05
        );
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

    /// `q(t) = q0 + v0 t + a t^2 / 2` of two joints, with its velocity.
    fn trajectory(t: f64) -> (Vec<f64>, Vec<f64>) {
        let (q0, v0, a) = ([0.3, -1.0], [0.5, 2.0], [4.0, -10.0]);
        (0..2).map(|j| (q0[j] + v0[j] * t + 0.5 * a[j] * t * t, v0[j] + a[j] * t)).unzip()
    }

    #[test]
    fn at_constant_acceleration_the_reference_is_the_trajectory_ahead() {
        // States 1 ms apart on the trajectory; drives at 4 kHz: the lead is 0.375 ms.
        let (h, dt) = (1e-3, 2.5e-4);
        let ahead = lead(h, Some(dt));
        let (mut q_des, mut qd_des) = (Vec::new(), Vec::new());
        let mut r = Reference::new(2, Some(dt));
        for k in 0..4u32 {
            let t = 0.2 + f64::from(k) * h;
            let (q, qd) = trajectory(t);
            r.on_state(t, &q, &qd);
            r.fill(&mut q_des, &mut qd_des);
            if k == 0 {
                // No state before it: carried at constant velocity, over no lead.
                assert_eq!((q_des.clone(), qd_des.clone()), (q, qd));
                continue;
            }
            let (qt, vt) = trajectory(t + ahead);
            for j in 0..2 {
                assert!(
                    (q_des[j] - qt[j]).abs() < 1e-12 && (qd_des[j] - vt[j]).abs() < 1e-9,
                    "state {k}, joint {j}: {q_des:?} {qd_des:?} vs {qt:?} {vt:?}"
                );
            }
        }
    }

    #[test]
    fn bad_inertias_and_sizes_are_refused() {
        assert_eq!(
            DriveGains::from_inertia(&[0.1], &[1.0, 2.0]),
            Err(DriveGainsError::Sizes { inertia: 1, limits: 2 })
        );
        assert!(matches!(
            DriveGains::from_inertia(&[0.1, 0.0], &[1.0, 1.0]),
            Err(DriveGainsError::Inertia { joint: 1, .. })
        ));
        assert!(matches!(
            DriveGains::from_inertia(&[f64::NAN], &[1.0]),
            Err(DriveGainsError::Inertia { joint: 0, .. })
        ));
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
