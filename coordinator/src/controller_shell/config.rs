//! [`ShellConfig`]: the parameters every team controller of the shell shares (the gains of the
//! four task kinds, the carried object, the grasp as planned, the contacts' margins and the
//! release policy), with their checks; and [`read_flat`], which reads a controller's flat TOML
//! table into the shared part and the controller's own part.

use nalgebra::{Isometry3, Matrix3};
use serde::de::{Deserializer, Error as _, Visitor};
use serde::Deserialize;

use crate::building_blocks::contact_margins::ContactMargins;
use crate::building_blocks::grasp::PlannedHand;
use crate::building_blocks::impedance::Gains;
use crate::building_blocks::release::ReleasePolicy;
use crate::ControllerError;

/// The parameters PIDC and MQP share. In a controller file they sit at the top level among the
/// controller's own keys (the file stays flat); a key left out keeps the controller's default
/// ([`read_flat`]). There is no `Default`: each controller has its own (the gains' units
/// differ: impedances for PIDC, acceleration gains for MQP).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShellConfig {
    /// Gains of the carried object's pose task (6).
    pub object_gains: Gains,
    /// Gains of every torso's pose task (6).
    pub torso_gains: Gains,
    /// Gains of every swing foot's position task (3).
    pub swing_gains: Gains,
    /// Free hands (not in grasp, or let go of: see [`ReleasePolicy`]) hold their pose (6).
    pub hand_gains: Gains,
    /// When the team lets go of an object it cannot hold (degrade, never collapse).
    pub release: ReleasePolicy,
    /// The robots' tick period, s (1 / `control_hz`): the release policy's times in ticks.
    pub robot_period: f64,
    /// Carried object: mass, kg.
    pub object_mass: f64,
    /// Carried object: inertia about its centre in its own frame, kg m^2.
    pub object_inertia: Matrix3<f64>,
    /// Object pose when the grasp first closes (the runner's plan knows it); `None`: the hands'
    /// centroid with world axes, which is the object's centre only for two opposite palms.
    pub object_pose_at_grasp: Option<Isometry3<f64>>,
    /// Each hand's grasp as planned ([`PlannedHand`]): a controller started while the team
    /// holds the object fits it from the hands with these. Empty: captured when the grasp
    /// first closes, with the object at `object_pose_at_grasp`.
    pub planned_grasp: Vec<PlannedHand>,
    /// Minimum normal force of every stance foot, N.
    pub f_min_foot: f64,
    /// Minimum normal force of every hand (the least squeeze), N. The torque-optimal grasp
    /// otherwise sits on the friction limit (weight / mu), where any disturbance slips it.
    pub f_min_hand: f64,
    /// Share of each contact's friction the contact rows may use (`mu` and `xi` are scaled by
    /// it). The paper's pyramid `|f_x|, |f_y| <= mu f_n` reaches `sqrt(2) mu f_n` at its
    /// corners, outside the real (circular) cone; `1/sqrt(2)` makes it the inscribed pyramid. A
    /// hand's rows (sliding and torsion in one cone, `qp::rows`) are carried by the palm up to
    /// 0.8 with `patch_margin` up to 0.6 (checked in `tests/qp_rows.rs`), not at 1.
    pub friction_margin: f64,
    /// Share of the palm's half-sizes the centre of pressure may use (the tilt rows of eqn.
    /// moment_constraint). At 1 the optimal grasp puts the whole squeeze on one palm edge,
    /// where the palm starts to roll on the object (seen in MuJoCo: the palm rolled 27 deg
    /// about its top edge within 3 s).
    pub patch_margin: f64,
}

impl ShellConfig {
    /// The gains of the table (simulations, torso and object motion) of the paper, with the
    /// free hands' `hand_gains`, the default release policy, the default scene's 0.6 m cube of
    /// 1 kg and the default contact margins.
    pub fn with_hand_gains(hand_gains: Gains) -> Self {
        ShellConfig {
            object_gains: Gains::new(
                &[1500.0, 1500.0, 1500.0, 400.0, 400.0, 400.0],
                &[150.0, 150.0, 150.0, 140.0, 140.0, 140.0],
            ),
            torso_gains: Gains::new(
                &[4000.0, 4000.0, 4000.0, 3000.0, 3000.0, 3000.0],
                &[200.0, 200.0, 200.0, 125.0, 125.0, 125.0],
            ),
            swing_gains: Gains::new(&[3500.0, 3500.0, 3500.0], &[20.0, 20.0, 20.0]),
            hand_gains,
            release: ReleasePolicy::default(),
            robot_period: 0.001,
            object_mass: 1.0,
            object_inertia: Matrix3::identity() * (1.0 * (0.36 + 0.36) / 12.0),
            object_pose_at_grasp: None,
            planned_grasp: Vec::new(),
            f_min_foot: 5.0,
            f_min_hand: 30.0,
            friction_margin: std::f64::consts::FRAC_1_SQRT_2,
            patch_margin: 0.5,
        }
    }

    /// The contact parameters of the shared contact rows
    /// ([`crate::building_blocks::contacts::contact_list`]): margins and minimum forces.
    pub fn contact_margins(&self) -> ContactMargins {
        ContactMargins {
            f_min_foot: self.f_min_foot,
            f_min_hand: self.f_min_hand,
            friction_margin: self.friction_margin,
            patch_margin: self.patch_margin,
        }
    }

    /// The first of the checks: gains of the right sizes, finite and non-negative; the
    /// object's mass and inertia finite, the mass non-negative. A controller checks the
    /// minimum forces next ([`ContactMargins::check_forces`]), then its own numbers, then
    /// [`ShellConfig::check_contacts`].
    pub fn check_tasks(&self) -> Result<(), ControllerError> {
        for (what, g, n) in [
            ("object_gains", &self.object_gains, 6),
            ("torso_gains", &self.torso_gains, 6),
            ("swing_gains", &self.swing_gains, 3),
            ("hand_gains", &self.hand_gains, 6),
        ] {
            if let Err(why) = g.check(n) {
                return bad(what, why);
            }
        }
        if !(self.object_mass.is_finite() && self.object_mass >= 0.0)
            || self.object_inertia.iter().any(|x| !x.is_finite())
        {
            return bad("object", "mass and inertia must be finite, mass non-negative".into());
        }
        Ok(())
    }

    /// The last of the shared checks: the contacts' margins, the planned grasp and the release
    /// policy.
    pub fn check_contacts(&self) -> Result<(), ControllerError> {
        self.contact_margins().check_margins()?;
        for h in &self.planned_grasp {
            if let Err(why) = h.check() {
                return bad("planned_grasp", why);
            }
        }
        if let Err(why) = self.release.check() {
            return bad("release", why);
        }
        if !(self.robot_period.is_finite() && self.robot_period > 0.0) {
            return bad("robot_period", format!("{} s must be positive", self.robot_period));
        }
        Ok(())
    }
}

/// A configuration error about `what`.
fn bad(what: &str, why: String) -> Result<(), ControllerError> {
    Err(ControllerError::Config(format!("{what}: {why}")))
}

/// Reads a controller's flat table: the keys of [`ShellConfig`] into the shared part (a key
/// left out keeps `defaults`' value), every other key through `own`, the controller's own
/// derived reading (`#[serde(remote = "Self", deny_unknown_fields)]`, its `shell` field
/// skipped), whose field names `own_fields` gives. A key of neither is refused, named. Each
/// part is read by TOML's own reader, so that a bad value's error names its key.
pub fn read_flat<'de, D, C>(
    d: D,
    defaults: &ShellConfig,
    own_fields: &[&str],
    own: impl FnOnce(toml::Value) -> Result<C, toml::de::Error>,
) -> Result<(ShellConfig, C), D::Error>
where
    D: Deserializer<'de>,
{
    let mut table = toml::Table::deserialize(d)?;
    let shell_fields = field_names(|f| ShellConfig::deserialize(f).map(drop));
    if let Some(key) = table
        .keys()
        .find(|k| !shell_fields.contains(&k.as_str()) && !own_fields.contains(&k.as_str()))
    {
        let expected: Vec<String> =
            shell_fields.iter().chain(own_fields).map(|f| format!("`{f}`")).collect();
        return Err(D::Error::custom(format!(
            "unknown field `{key}`, expected one of {}",
            expected.join(", ")
        )));
    }
    let mut shell = toml::Table::try_from(defaults).map_err(D::Error::custom)?;
    for f in shell_fields {
        if let Some(v) = table.remove(*f) {
            shell.insert(f.to_string(), v);
        }
    }
    let shell: ShellConfig = toml::Value::Table(shell).try_into().map_err(D::Error::custom)?;
    let own = own(toml::Value::Table(table)).map_err(D::Error::custom)?;
    Ok((shell, own))
}

/// The field names a derived struct reading asks for, read off the reading itself: `read`
/// runs it on a deserializer that records them.
pub fn field_names(
    read: impl FnOnce(&mut FieldNames) -> Result<(), serde::de::value::Error>,
) -> &'static [&'static str] {
    let mut names = FieldNames(&[]);
    // The recorder refuses every reading once it has the names: the error is expected.
    let _ = read(&mut names);
    names.0
}

/// A deserializer that records the field names a struct's reading asks for, and reads nothing
/// ([`field_names`]).
pub struct FieldNames(&'static [&'static str]);

impl<'de> Deserializer<'de> for &mut FieldNames {
    type Error = serde::de::value::Error;

    fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Self::Error> {
        Err(Self::Error::custom("only a struct's field names are read"))
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        fields: &'static [&'static str],
        _visitor: V,
    ) -> Result<V::Value, Self::Error> {
        self.0 = fields;
        Err(Self::Error::custom("field names read"))
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes byte_buf
        option unit unit_struct newtype_struct seq tuple tuple_struct map enum identifier
        ignored_any
    }
}

/// The serde reading and writing of a controller configuration `$config` that holds a
/// [`ShellConfig`] in its field `shell`, flat in the file, and its reading as that
/// `ShellConfig` (`Deref`). `$config` derives `Serialize` and `Deserialize` with
/// `#[serde(remote = "Self", default, deny_unknown_fields)]` (inherent readings of its own
/// keys) and marks `shell` `#[serde(flatten, skip_deserializing)]`; keys it leaves out keep
/// `$config::default()`'s values ([`read_flat`]).
macro_rules! flat_shell_config {
    ($config:ident) => {
        impl serde::Serialize for $config {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                $config::serialize(self, s)
            }
        }

        impl<'de> serde::Deserialize<'de> for $config {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                use $crate::controller_shell::config::{field_names, read_flat};
                let own_fields = field_names(|f| $config::deserialize(f).map(drop));
                let defaults = $config::default();
                let (shell, own) =
                    read_flat(d, &defaults.shell, own_fields, |v| $config::deserialize(v))?;
                Ok($config { shell, ..own })
            }
        }

        impl std::ops::Deref for $config {
            type Target = $crate::controller_shell::ShellConfig;

            fn deref(&self) -> &Self::Target {
                &self.shell
            }
        }

        impl std::ops::DerefMut for $config {
            fn deref_mut(&mut self) -> &mut Self::Target {
                &mut self.shell
            }
        }
    };
}
pub(crate) use flat_shell_config;
