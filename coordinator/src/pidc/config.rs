//! [`PidcConfig`]: the parameters of the PIDC controller (gains per task kind, the carried
//! object, the QP's margins and settings).

use crate::building_blocks::impedance::Gains;
use crate::building_blocks::projection::ProjectionPath;
use crate::controller_shell::config::flat_shell_config;
use crate::controller_shell::ShellConfig;
use crate::qp::QpPath;
use crate::ControllerError;

/// Parameters of the PIDC controller. In a controller file they follow `kind = "pidc"` (see
/// [`crate::ControllerSpec`]), flat: the shared keys of [`ShellConfig`] and PIDC's own; any
/// subset of them may be given, the rest keep their defaults. Reads as its [`ShellConfig`]
/// (`Deref`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(remote = "Self", default, deny_unknown_fields)]
pub struct PidcConfig {
    /// The gains of the four task kinds (impedances: N/m, N s/m), the object, the grasp as
    /// planned, the contacts' margins and the release policy.
    #[serde(flatten, skip_deserializing)]
    pub shell: ShellConfig,
    /// Added to the diagonal of the semi-definite QP objective.
    pub regularisation: f64,
    pub qp_max_iter: u32,
    /// Where the QP's solve starts, falling back down the chain `by-blocks -> active-set ->
    /// dense-ipm -> clarabel` ([`QpPath`]). The default, `by-blocks`, tries the last tick's
    /// active rows by the robots' blocks first; the dual active-set method it falls back to
    /// (and that the release relies on: it lets go at half its slip limit once the QP has
    /// failed for 10 ticks, `building_blocks::release::SLIP_WHILE_FAILING`) kept
    /// `tests/tests/degrade.rs`'s 300 N push standing as the interior point's 1e-7 answers do.
    pub qp_path: QpPath,
    /// `S = I` (treat the base as actuated): the \[Lin2018\] comparison only.
    pub fully_actuated: bool,
    /// How the projections are computed ([`ProjectionPath`]): by the team's blocks (the
    /// default; it falls back to the dense path by itself when a block is too
    /// ill-conditioned) or by dense SVDs of the team's matrices (the oracle).
    pub projections: ProjectionPath,
}

flat_shell_config!(PidcConfig);

impl Default for PidcConfig {
    fn default() -> Self {
        // Gains of the paper's Table (simulations, torso and object motion). Free hands' gains
        // are forces on the task's own inertia: a few kg of arm at the hand (about 1 Hz,
        // damped; stiffer hands asked more than the arm's limits after a push) and a wrist of
        // a few 1e-3 kg m^2 about the palm's normal, which a damping of 6 N m s/rad set into a
        // limit cycle at 1 kHz (seen in MuJoCo).
        let hand_gains =
            Gains::new(&[150.0, 150.0, 150.0, 5.0, 5.0, 5.0], &[30.0, 30.0, 30.0, 0.3, 0.3, 0.3]);
        PidcConfig {
            shell: ShellConfig::with_hand_gains(hand_gains),
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
        let table: toml::Table =
            toml::from_str(text).map_err(|e| ControllerError::Config(e.to_string()))?;
        if let Some(why) = retired_key(&table) {
            return Err(ControllerError::Config(why));
        }
        let c: PidcConfig = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| ControllerError::Config(e.to_string()))?;
        c.check()?;
        Ok(c)
    }

    /// The TOML text of this configuration.
    pub fn to_toml(&self) -> Result<String, ControllerError> {
        toml::to_string(self).map_err(|e| ControllerError::Config(e.to_string()))
    }

    /// Gains of the right sizes, finite and non-negative; masses, forces and limits sane.
    pub fn check(&self) -> Result<(), ControllerError> {
        self.shell.check_tasks()?;
        self.contact_margins().check_forces()?;
        if !(self.regularisation.is_finite() && self.regularisation >= 0.0) {
            return Err(ControllerError::Config(format!(
                "regularisation: {} must be finite and non-negative",
                self.regularisation
            )));
        }
        self.shell.check_contacts()?;
        if self.qp_max_iter == 0 {
            return Err(ControllerError::Config("qp_max_iter: must be positive".into()));
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
    (
        "dense_projections",
        "`projections` (`dense_projections = true` is `projections = \"dense\"`)",
    ),
];

/// What is wrong with a PIDC table that holds a retired key: the key that replaced it (a
/// retired key is refused, not taken for an unknown field, and never ignored).
pub fn retired_key(table: &toml::Table) -> Option<String> {
    RETIRED_KEYS
        .iter()
        .find(|(old, _)| table.contains_key(*old))
        .map(|(old, new)| format!("`{old}` is no longer a key: use {new}"))
}
