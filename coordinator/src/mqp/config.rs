//! [`MqpConfig`]: the parameters of the multi-robot QP baseline (task weights and gains, the
//! carried object, contact margins, joint limits, the QP's regularisation and Clarabel's
//! settings).

use nalgebra::{Isometry3, Matrix3};

use crate::units::contact_margins::ContactMargins;
use crate::units::impedance::Gains;
use crate::units::release::ReleasePolicy;
use crate::ControllerError;

/// Parameters of the MQP controller. In a controller file they follow `kind = "mqp"` (see
/// [`crate::ControllerSpec`]); any subset of the fields may be given, the rest keep their
/// defaults.
///
/// **Gains are acceleration gains** (`xdd_ref = xdd_des + K_p (x_des - x) + K_d (xd_des - xd)`,
/// units 1/s^2 and 1/s), unlike PIDC's impedances (N/m, N s/m). A scenario run gives both
/// controllers the scenario's numbers (the paper's comparison does the same); the defaults
/// here are those of the paper's Table I, like PIDC's.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MqpConfig {
    pub object_gains: Gains,
    pub torso_gains: Gains,
    pub swing_gains: Gains,
    /// Free hands (not in grasp, or let go of) hold their pose.
    pub hand_gains: Gains,
    /// Weights of each task's squared acceleration error in the objective.
    pub object_weight: f64,
    pub torso_weight: f64,
    pub swing_weight: f64,
    pub hand_weight: f64,
    /// When the team lets go of an object it cannot hold (as PIDC's).
    pub release: ReleasePolicy,
    /// Regularisation: weights of `|qdd|^2`, `|lambda|^2`, `|tau|^2` (small).
    pub regularisation_qdd: f64,
    pub regularisation_lambda: f64,
    pub regularisation_tau: f64,
    /// Carried object: mass, inertia about its centre in its own frame.
    pub object_mass: f64,
    pub object_inertia: Matrix3<f64>,
    /// Object pose when the grasp first closes; `None`: the hands' centroid, world axes.
    pub object_pose_at_grasp: Option<Isometry3<f64>>,
    /// Each hand's grasp as planned (`units::grasp::PlannedHand`): a controller started while the
    /// team holds the object fits it from the hands with these. Empty: captured when the grasp
    /// first closes, with the object at `object_pose_at_grasp`.
    pub planned_grasp: Vec<crate::units::grasp::PlannedHand>,
    /// Minimum normal force of stance feet and hands (the least squeeze), N.
    pub f_min_foot: f64,
    pub f_min_hand: f64,
    /// Shares of friction and of the palm's half-sizes the contacts may use (as PIDC's).
    pub friction_margin: f64,
    pub patch_margin: f64,
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

impl Default for MqpConfig {
    fn default() -> Self {
        MqpConfig {
            object_gains: Gains::new(&[1500.0, 1500.0, 1500.0, 400.0, 400.0, 400.0], &[150.0, 150.0, 150.0, 140.0, 140.0, 140.0]),
            torso_gains: Gains::new(&[4000.0, 4000.0, 4000.0, 3000.0, 3000.0, 3000.0], &[200.0, 200.0, 200.0, 125.0, 125.0, 125.0]),
            swing_gains: Gains::new(&[3500.0, 3500.0, 3500.0], &[20.0, 20.0, 20.0]),
            // Acceleration gains: about 1.6 Hz, critically damped.
            hand_gains: Gains::new(&[100.0; 6], &[20.0; 6]),
            object_weight: 1.0,
            torso_weight: 1.0,
            swing_weight: 1.0,
            hand_weight: 0.1,
            release: ReleasePolicy::default(),
            regularisation_qdd: 1e-6,
            regularisation_lambda: 1e-8,
            regularisation_tau: 1e-6,
            object_mass: 1.0,
            object_inertia: Matrix3::identity() * (1.0 * (0.36 + 0.36) / 12.0),
            object_pose_at_grasp: None,
            planned_grasp: Vec::new(),
            f_min_foot: 5.0,
            f_min_hand: 30.0,
            friction_margin: std::f64::consts::FRAC_1_SQRT_2,
            patch_margin: 0.5,
            joint_acceleration_limit: 500.0,
            joint_velocity_limit: 20.0,
            dt: 0.001,
            max_iter: 100,
        }
    }
}

impl MqpConfig {
    /// Gains of the right sizes, finite and non-negative; weights, masses, forces and limits sane.
    pub fn check(&self) -> Result<(), ControllerError> {
        let bad = |what: &str, why: String| Err(ControllerError::Config(format!("{what}: {why}")));
        for (what, g, n) in [("object_gains", &self.object_gains, 6), ("torso_gains", &self.torso_gains, 6), ("swing_gains", &self.swing_gains, 3), ("hand_gains", &self.hand_gains, 6)] {
            if let Err(why) = g.check(n) {
                return bad(what, why);
            }
        }
        if !(self.object_mass.is_finite() && self.object_mass >= 0.0) || self.object_inertia.iter().any(|x| !x.is_finite()) {
            return bad("object", "mass and inertia must be finite, mass non-negative".into());
        }
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
        for (what, x) in [("joint_acceleration_limit", self.joint_acceleration_limit), ("joint_velocity_limit", self.joint_velocity_limit), ("dt", self.dt)] {
            if !(x.is_finite() && x > 0.0) {
                return bad(what, format!("{x} must be finite and positive"));
            }
        }
        self.contact_margins().check_margins()?;
        for h in &self.planned_grasp {
            if let Err(why) = h.check() {
                return bad("planned_grasp", why);
            }
        }
        if let Err(why) = self.release.check() {
            return bad("release", why);
        }
        if self.max_iter == 0 {
            return bad("max_iter", "must be positive".into());
        }
        Ok(())
    }

    /// The contact parameters of the shared contact rows
    /// ([`crate::units::contacts::contact_list`]): margins and minimum forces.
    pub fn contact_margins(&self) -> ContactMargins {
        ContactMargins { f_min_foot: self.f_min_foot, f_min_hand: self.f_min_hand, friction_margin: self.friction_margin, patch_margin: self.patch_margin }
    }
}
