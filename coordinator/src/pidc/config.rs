//! [`PidcConfig`]: the parameters of the PIDC controller (gains per task kind, the carried
//! object, the QP's margins and settings).

use nalgebra::{Isometry3, Matrix3};

use crate::qp::QpPath;
use crate::units::contact_margins::ContactMargins;
use crate::units::impedance::Gains;
use crate::units::projection::ProjectionPath;
use crate::units::release::ReleasePolicy;
use crate::ControllerError;

/// Parameters of the PIDC controller. In a controller file they follow `kind = "pidc"` (see
/// [`crate::ControllerSpec`]); any subset of the fields may be given, the rest keep their
/// defaults.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PidcConfig {
    pub object_gains: Gains,
    pub torso_gains: Gains,
    pub swing_gains: Gains,
    /// Free hands (not in grasp, or let go of: see [`ReleasePolicy`]) hold their pose.
    pub hand_gains: Gains,
    /// When the team lets go of an object it cannot hold (degrade, never collapse).
    pub release: ReleasePolicy,
    /// Carried object: mass, inertia about its centre in its own frame.
    pub object_mass: f64,
    pub object_inertia: Matrix3<f64>,
    /// Object pose when the grasp first closes (the runner's plan knows it); `None`: the hands'
    /// centroid with world axes, which is the object's centre only for two opposite palms.
    pub object_pose_at_grasp: Option<Isometry3<f64>>,
    /// Each hand's grasp as planned (`units::grasp::PlannedHand`): a controller started while the
    /// team holds the object fits it from the hands with these. Empty: captured when the grasp
    /// first closes, with the object at `object_pose_at_grasp`.
    pub planned_grasp: Vec<crate::units::grasp::PlannedHand>,
    /// Minimum normal force of every stance foot, N.
    pub f_min_foot: f64,
    /// Minimum normal force of every hand (the least squeeze), N. The torque-optimal grasp
    /// otherwise sits on the friction limit (weight / mu), where any disturbance slips it.
    pub f_min_hand: f64,
    /// Share of each contact's friction the QP may use (`mu` and `xi` are scaled by it). The
    /// paper's pyramid `|f_x|, |f_y| <= mu f_n` reaches `sqrt(2) mu f_n` at its corners, outside
    /// the real (circular) cone; `1/sqrt(2)` makes it the inscribed pyramid. A hand's rows
    /// (sliding and torsion in one cone, `qp::rows`) are carried by the palm up to 0.8 with
    /// `patch_margin` up to 0.6 (checked in `tests/qp_rows.rs`), not at 1.
    pub friction_margin: f64,
    /// Share of the palm's half-sizes the centre of pressure may use (the tilt rows of eqn.
    /// moment_constraint). At 1 the optimal grasp puts the whole squeeze on one palm edge,
    /// where the palm starts to roll on the object (seen in MuJoCo: the palm rolled 27 deg
    /// about its top edge within 3 s).
    pub patch_margin: f64,
    /// Added to the diagonal of the semi-definite QP objective.
    pub regularisation: f64,
    pub qp_max_iter: u32,
    /// Where the QP's solve starts, falling back down the chain `by-blocks -> active-set ->
    /// dense-ipm -> clarabel` ([`QpPath`]). The default, `by-blocks`, tries the last tick's
    /// active rows by the robots' blocks first; the dual active-set method it falls back to
    /// (and that the release relies on: it lets go at half its slip limit once the QP has
    /// failed 10 ticks in a row, `units::release::SLIP_WHILE_FAILING`) kept
    /// `tests/tests/degrade.rs`'s 300 N push standing as the interior point's 1e-7 answers do.
    pub qp_path: QpPath,
    /// `S = I` (treat the base as actuated): the \[Lin2018\] comparison only.
    pub fully_actuated: bool,
    /// How the projections are computed ([`ProjectionPath`]): by the team's blocks (the
    /// default; it falls back to the dense path by itself when a block is too
    /// ill-conditioned) or by dense SVDs of the team's matrices (the oracle).
    pub projections: ProjectionPath,
}

impl Default for PidcConfig {
    fn default() -> Self {
        // Gains of the paper's Table (simulations, torso and object motion).
        PidcConfig {
            object_gains: Gains::new(&[1500.0, 1500.0, 1500.0, 400.0, 400.0, 400.0], &[150.0, 150.0, 150.0, 140.0, 140.0, 140.0]),
            torso_gains: Gains::new(&[4000.0, 4000.0, 4000.0, 3000.0, 3000.0, 3000.0], &[200.0, 200.0, 200.0, 125.0, 125.0, 125.0]),
            swing_gains: Gains::new(&[3500.0, 3500.0, 3500.0], &[20.0, 20.0, 20.0]),
            // Gains are forces on the task's own inertia: a few kg of arm at the hand (about
            // 1 Hz, damped; stiffer hands asked more than the arm's limits after a push) and a wrist of a few 1e-3 kg m^2 about the palm's normal, which a
            // damping of 6 N m s/rad set into a limit cycle at 1 kHz (seen in MuJoCo).
            hand_gains: Gains::new(&[150.0, 150.0, 150.0, 5.0, 5.0, 5.0], &[30.0, 30.0, 30.0, 0.3, 0.3, 0.3]),
            release: ReleasePolicy::default(),
            // The default scene's 0.6 m cube of 1 kg.
            object_mass: 1.0,
            object_inertia: Matrix3::identity() * (1.0 * (0.36 + 0.36) / 12.0),
            object_pose_at_grasp: None,
            planned_grasp: Vec::new(),
            f_min_foot: 5.0,
            f_min_hand: 30.0,
            friction_margin: std::f64::consts::FRAC_1_SQRT_2,
            patch_margin: 0.5,
            regularisation: 1e-6,
            qp_max_iter: 50,
            qp_path: QpPath::ByBlocks,
            fully_actuated: false,
            projections: ProjectionPath::ByBlocks,
        }
    }
}

impl PidcConfig {
    /// Parse a TOML controller configuration and check it.
    pub fn from_toml(text: &str) -> Result<Self, ControllerError> {
        let table: toml::Table = toml::from_str(text).map_err(|e| ControllerError::Config(e.to_string()))?;
        if let Some(why) = retired_key(&table) {
            return Err(ControllerError::Config(why));
        }
        let c: PidcConfig = toml::Value::Table(table).try_into().map_err(|e: toml::de::Error| ControllerError::Config(e.to_string()))?;
        c.check()?;
        Ok(c)
    }

    /// The TOML text of this configuration.
    pub fn to_toml(&self) -> Result<String, ControllerError> {
        toml::to_string(self).map_err(|e| ControllerError::Config(e.to_string()))
    }

    /// The contact parameters of the contact rows ([`crate::units::contacts::contact_list`]):
    /// margins and minimum forces.
    pub fn contact_margins(&self) -> ContactMargins {
        ContactMargins { f_min_foot: self.f_min_foot, f_min_hand: self.f_min_hand, friction_margin: self.friction_margin, patch_margin: self.patch_margin }
    }

    /// Gains of the right sizes, finite and non-negative; masses, forces and limits sane.
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
        self.contact_margins().check_forces()?;
        if !(self.regularisation.is_finite() && self.regularisation >= 0.0) {
            return bad("regularisation", format!("{} must be finite and non-negative", self.regularisation));
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
        if self.qp_max_iter == 0 {
            return bad("qp_max_iter", "must be positive".into());
        }
        Ok(())
    }
}

/// Keys the configuration no longer has, and what took their place: the four booleans that
/// chose among the contact forces' paths are now two named choices.
const RETIRED_KEYS: [(&str, &str); 4] = [
    ("dense_qp", "`qp_path` (`dense_qp = false` is `qp_path = \"clarabel\"`)"),
    ("active_set_qp", "`qp_path` (`active_set_qp = false` is `qp_path = \"dense-ipm\"`)"),
    ("qp_by_blocks", "`qp_path` (`qp_by_blocks = false` is `qp_path = \"active-set\"`)"),
    ("dense_projections", "`projections` (`dense_projections = true` is `projections = \"dense\"`)"),
];

/// What is wrong with a PIDC table that holds a retired key: the key that replaced it (a
/// retired key is refused, not taken for an unknown field, and never ignored).
pub fn retired_key(table: &toml::Table) -> Option<String> {
    RETIRED_KEYS.iter().find(|(old, _)| table.contains_key(*old)).map(|(old, new)| format!("`{old}` is no longer a key: use {new}"))
}
