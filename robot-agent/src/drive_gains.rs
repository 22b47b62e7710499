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
//! The reference ([`Reference`]) is a trajectory: the latest measured state at its time and the
//! acceleration measured over the last two states, which the drives carry forward at every
//! step (`protocol::DriveCommand::targets_at`). On it the law adds nothing to `tau_ff`; a drive
//! left with the command (a late command) pulls the joint back to it instead of applying a
//! stale torque open loop. With the team slower than the robot in lockstep
//! (`crate::core::AgentConfig::team_every`) the agent answers each state between team ticks
//! with the last team torque and the trajectory from that state.
//!
//! S4 at 250 Hz (2 kHz drives) keeps an object RMS of 0.10 mm with these gains, as without
//! them; with the reference held constant over each period at the drive steps' mean time it was
//! 0.66 mm: the law fought the motion inside every period.

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

/// The reference a drive command goes with: a trajectory from the latest measured state at the
/// accelerations the team's last command commands (`protocol::TorqueCommand::qdd`, the
/// coordinator's model of what its torques do), which the drives carry forward at every step;
/// without them (a hold order, a controller that does not model them) at the state's velocity.
/// On ticks between team ticks too (lockstep's two rates): carrying the team tick's state over
/// the ticks since instead pulled the joints towards an extrapolation that the team's next
/// torques did not follow (S4 with the team at 100 Hz: object RMS 1.35 mm against 0.21 mm).
///
/// Not the acceleration measured between the last two states: carried past a late command's
/// state by the drives' gains, a measured acceleration feeds back on itself (the damping alone
/// adds `kd (t - t_ref) qdd`, a share `2 omega (t - t_ref)` of the joint's inertia), and a
/// robot whose hands let go of its load across processes could not stop the motion it measured.
#[derive(Debug, Clone)]
pub struct Reference {
    /// Time of the latest state; the period from the one before (0: none yet).
    last: Option<f64>,
    period: f64,
    q: Vec<f64>,
    qd: Vec<f64>,
    /// The last command's accelerations (zeros: none).
    a: Vec<f64>,
}

impl Reference {
    /// For `joints` joints. Every buffer is allocated here.
    pub fn new(joints: usize) -> Self {
        let z = || vec![0.0; joints];
        Reference { last: None, period: 0.0, q: z(), qd: z(), a: z() }
    }

    /// A new state (not a repeat of the latest) at `time`.
    pub fn on_state(&mut self, time: f64, q: &[f64], qd: &[f64]) {
        if let Some(h) = self.last.map(|t| time - t).filter(|h| *h > 0.0) {
            self.period = h;
        }
        self.last = Some(time);
        self.q.copy_from_slice(q);
        self.qd.copy_from_slice(qd);
    }

    /// A command of the team applies: its accelerations `qdd` (one per joint) from now on;
    /// none (empty, or not one per joint) carries the state at its velocity.
    pub fn on_command(&mut self, qdd: &[f64]) {
        if qdd.len() == self.a.len() {
            self.a.copy_from_slice(qdd);
        } else {
            self.a.fill(0.0);
        }
    }

    /// The reference as a trajectory from the latest state into `cmd`: `q_des`, `qd_des` the
    /// state's, `qdd_des` the last command's accelerations, `ref_time` the state's time; the drives
    /// carry it forward at every drive step ([`protocol::DriveCommand::targets_at`]). Nothing
    /// before a state.
    pub fn fill_trajectory(&self, cmd: &mut protocol::DriveCommand) {
        let Some(t) = self.last else { return };
        cmd.q_des.clone_from(&self.q);
        cmd.qd_des.clone_from(&self.qd);
        cmd.qdd_des.clone_from(&self.a);
        cmd.ref_time = Some(t);
    }

    /// The period between the last two states, s (0 before two).
    pub fn period(&self) -> f64 {
        self.period
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

    /// `q(t) = q0 + v0 t + a t^2 / 2` of two joints, with its velocity.
    fn trajectory(t: f64) -> (Vec<f64>, Vec<f64>) {
        let (q0, v0, a) = ([0.3, -1.0], [0.5, 2.0], [4.0, -10.0]);
        (0..2).map(|j| (q0[j] + v0[j] * t + 0.5 * a[j] * t * t, v0[j] + a[j] * t)).unzip()
    }

    #[test]
    fn at_the_commanded_acceleration_the_drives_follow_the_trajectory_itself() {
        // States 1 ms apart on the trajectory; the drives evaluate the command at 4 kHz.
        let (h, dt) = (1e-3, 2.5e-4);
        let mut cmd = protocol::DriveCommand::torque("t", "r1", 0, vec![0.0; 2]);
        (cmd.kp, cmd.kd) = (vec![1.0; 2], vec![1.0; 2]);
        let mut r = Reference::new(2);
        for k in 0..4u32 {
            let t = 0.2 + f64::from(k) * h;
            let (q, qd) = trajectory(t);
            r.on_state(t, &q, &qd);
            r.fill_trajectory(&mut cmd);
            assert_eq!(cmd.ref_time, Some(t));
            if k == 0 {
                // No command yet: the state carried at its velocity, whatever it measured.
                assert_eq!(cmd.qdd_des, vec![0.0; 2]);
                r.on_command(&[4.0, -10.0]);
                continue;
            }
            for step in 0..4u32 {
                let at = t + f64::from(step) * dt;
                let (qt, vt) = trajectory(at);
                for j in 0..2 {
                    let (qs, vs) = cmd.targets_at(j, at);
                    assert!(
                        (qs.unwrap() - qt[j]).abs() < 1e-12 && (vs.unwrap() - vt[j]).abs() < 1e-9,
                        "state {k}, step {step}, joint {j}: {qs:?} {vs:?} vs {qt:?} {vt:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_command_without_accelerations_carries_the_state_at_its_velocity() {
        let mut r = Reference::new(2);
        let (q, qd) = trajectory(0.1);
        r.on_state(0.1, &q, &qd);
        r.on_command(&[4.0, -10.0]);
        let mut cmd = protocol::DriveCommand::torque("t", "r1", 0, vec![0.0; 2]);
        r.fill_trajectory(&mut cmd);
        assert_eq!(cmd.qdd_des, vec![4.0, -10.0]);
        // A hold order (no accelerations), then one of the wrong size: none carried.
        for qdd in [&[][..], &[1.0, 2.0, 3.0][..]] {
            r.on_command(&[4.0, -10.0]);
            r.on_command(qdd);
            r.fill_trajectory(&mut cmd);
            assert_eq!(cmd.qdd_des, vec![0.0; 2], "{qdd:?}");
            let (qs, vs) = cmd.targets_at(0, 0.11);
            assert!((qs.unwrap() - (q[0] + qd[0] * 0.01)).abs() < 1e-12);
            assert_eq!(vs, Some(qd[0]));
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
