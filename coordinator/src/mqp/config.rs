//! [`MqpConfig`]: the parameters of the multi-robot QP baseline (task weights and gains, the
//! carried object, contact margins, joint limits, the QP's regularisation and Clarabel's
//! settings).

use crate::building_blocks::impedance::Gains;
use crate::controller_shell::config::flat_shell_config;
use crate::controller_shell::ShellConfig;
use crate::ControllerError;

/// Parameters of the MQP controller. In a controller file they follow `kind = "mqp"` (see
/// [`crate::ControllerSpec`]), flat: the shared keys of [`ShellConfig`] and MQP's own; any
/// subset of them may be given, the rest keep their defaults. Reads as its [`ShellConfig`]
/// (`Deref`).
///
/// **Gains are acceleration gains** (`xdd_ref = xdd_des + K_p (x_des - x) + K_d (xd_des - xd)`,
/// units 1/s^2 and 1/s), unlike PIDC's impedances (N/m, N s/m). A scenario run gives both
/// controllers the scenario's numbers (the paper's comparison does the same); the defaults
/// here are those of the paper's Table I, like PIDC's.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(remote = "Self", default, deny_unknown_fields)]
pub struct MqpConfig {
    /// The gains of the four task kinds (free hands hold their pose), the object, the grasp as
    /// planned, the contacts' minimum forces and margins (as PIDC's), the release policy (as
    /// PIDC's).
    #[serde(flatten, skip_deserializing)]
    pub shell: ShellConfig,
    /// Weights of each task's squared acceleration error in the objective.
    pub object_weight: f64,
    pub torso_weight: f64,
    pub swing_weight: f64,
    pub hand_weight: f64,
    /// Regularisation: weights of `|qdd|^2`, `|lambda|^2`, `|tau|^2` (small).
    pub regularisation_qdd: f64,
    pub regularisation_lambda: f64,
    pub regularisation_tau: f64,
    /// Joint acceleration limit `|qdd_j|` of every actuated joint, rad/s^2.
    pub joint_acceleration_limit: f64,
    /// Joint velocity limit `|v_j|` of every actuated joint, rad/s, imposed one tick ahead:
    /// `|v_j + dt qdd_j| <= limit`.
    pub joint_velocity_limit: f64,
    /// The control period `dt` of the velocity bound, s (the runner sets 1 / control rate).
    pub dt: f64,
    /// Clarabel's iteration limit.
    pub max_iter: u32,
}

flat_shell_config!(MqpConfig);

impl Default for MqpConfig {
    fn default() -> Self {
        MqpConfig {
            // Acceleration gains of the free hands: about 1.6 Hz, critically damped.
            shell: ShellConfig::with_hand_gains(Gains::new(&[100.0; 6], &[20.0; 6])),
            object_weight: 1.0,
            torso_weight: 1.0,
            swing_weight: 1.0,
            hand_weight: 0.1,
            regularisation_qdd: 1e-6,
            regularisation_lambda: 1e-8,
            regularisation_tau: 1e-6,
            joint_acceleration_limit: 500.0,
            joint_velocity_limit: 20.0,
            dt: 0.001,
            max_iter: 100,
        }
    }
}

impl MqpConfig {
    /// Gains of the right sizes, finite and non-negative; weights, masses, forces and limits
    /// sane.
    pub fn check(&self) -> Result<(), ControllerError> {
        let bad = |what: &str, why: String| Err(ControllerError::Config(format!("{what}: {why}")));
        self.shell.check_tasks()?;
        let non_negative = [
            ("object_weight", self.object_weight),
            ("torso_weight", self.torso_weight),
            ("swing_weight", self.swing_weight),
            ("hand_weight", self.hand_weight),
            ("regularisation_qdd", self.regularisation_qdd),
            ("regularisation_lambda", self.regularisation_lambda),
            ("regularisation_tau", self.regularisation_tau),
        ];
        for (what, x) in non_negative {
            if !(x.is_finite() && x >= 0.0) {
                return bad(what, format!("{x} must be finite and non-negative"));
            }
        }
        self.contact_margins().check_forces()?;
        for (what, x) in [
            ("joint_acceleration_limit", self.joint_acceleration_limit),
            ("joint_velocity_limit", self.joint_velocity_limit),
            ("dt", self.dt),
        ] {
            if !(x.is_finite() && x > 0.0) {
                return bad(what, format!("{x} must be finite and positive"));
            }
        }
        self.shell.check_contacts()?;
        if self.max_iter == 0 {
            return bad("max_iter", "must be positive".into());
        }
        Ok(())
    }
}
