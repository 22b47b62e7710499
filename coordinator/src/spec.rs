//! [`ControllerSpec`]: which team controller runs, with its parameters, as data: parsed from
//! a controller file, checked, and built into a [`TeamController`].
//!
//! **A second controller plugs in** by implementing [`TeamController`] and adding a variant
//! `Kind(KindConfig)` to [`ControllerSpec`], named in [`ControllerSpec::KINDS`] and handled in
//! the `match`es of this file (kind, parse, check, build). The coordinator binary, the
//! scenario files and both run modes of the runner then take it by its kind, with no change
//! of their own.

use crate::joint_damping::{JointDamping, JointDampingConfig};
use crate::mqp::{Mqp, MqpConfig};
use crate::pidc::{Pidc, PidcConfig};
use crate::{ControllerError, TeamController};

/// Which team controller runs, with its parameters. In TOML (a controller file, what
/// `coordinator run --controller-config FILE` reads) the kind comes first, then the
/// controller's own fields, any of which may be left out (they keep their defaults):
///
/// ```toml
/// kind = "pidc"          # or "joint-damping", "mqp"
/// f_min_hand = 30.0
/// [object_gains]
/// kp = [1500, 1500, 1500, 400, 400, 400]
/// kd = [150, 150, 150, 140, 140, 140]
/// ```
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
#[allow(clippy::large_enum_variant)] // made once per run: a box would only burden its users
pub enum ControllerSpec {
    /// Projected inverse dynamics control with the contact-force QP (the paper's §III,
    /// [`crate::pidc`]).
    Pidc(PidcConfig),
    /// Joint damping `tau = -damping * qdot` ([`JointDamping`]): the smoke run's stand-in, it
    /// exercises the message flow only.
    JointDamping(JointDampingConfig),
    /// The paper's baseline, the multi-robot QP of Bouyarmane et al. 2019 ([`crate::mqp`]).
    Mqp(MqpConfig),
}

/// Former names of controller kinds, and what they are now.
const RENAMED: [(&str, &str); 2] = [("paper", "pidc"), ("smoke", "joint-damping")];

impl ControllerSpec {
    /// Every kind, as written in files and on the command line.
    pub const KINDS: [&'static str; 3] = ["pidc", "joint-damping", "mqp"];

    /// The kind of this controller (`kind = ...` in its TOML).
    pub fn kind(&self) -> &'static str {
        match self {
            ControllerSpec::Pidc(_) => "pidc",
            ControllerSpec::JointDamping(_) => "joint-damping",
            ControllerSpec::Mqp(_) => "mqp",
        }
    }

    /// The controller of kind `kind` with its default parameters.
    pub fn of_kind(kind: &str) -> Result<Self, ControllerError> {
        let mut table = toml::Table::new();
        table.insert("kind".into(), toml::Value::String(kind.to_string()));
        Self::from_table(table)
    }

    /// Parse a controller file (see the type's docs) and check it.
    pub fn from_toml(text: &str) -> Result<Self, ControllerError> {
        let table: toml::Table =
            toml::from_str(text).map_err(|e| ControllerError::Config(e.to_string()))?;
        Self::from_table(table)
    }

    /// The kind's fields are read by the kind's own configuration type, so that an error names
    /// the field it is about.
    fn from_table(mut table: toml::Table) -> Result<Self, ControllerError> {
        let known = || Self::KINDS.join(", ");
        let kind = match table.remove("kind") {
            Some(toml::Value::String(k)) => k,
            Some(other) => {
                return Err(ControllerError::Config(format!(
                    "`kind` must be a string (one of: {}), not {other}",
                    known()
                )))
            }
            None => {
                return Err(ControllerError::Config(format!("no `kind` (one of: {})", known())))
            }
        };
        let fields = toml::Value::Table(table);
        let bad = |e: toml::de::Error| {
            ControllerError::Config(format!(
                "{kind}: {}",
                e.to_string().trim_end().replace('\n', " ")
            ))
        };
        let spec = match kind.as_str() {
            "pidc" => {
                if let Some(why) = fields.as_table().and_then(crate::pidc::config::retired_key) {
                    return Err(ControllerError::Config(format!("{kind}: {why}")));
                }
                ControllerSpec::Pidc(fields.try_into().map_err(bad)?)
            }
            "joint-damping" => ControllerSpec::JointDamping(fields.try_into().map_err(bad)?),
            "mqp" => ControllerSpec::Mqp(fields.try_into().map_err(bad)?),
            k => {
                return Err(ControllerError::Config(
                    match RENAMED.iter().find(|(old, _)| *old == k) {
                        Some((old, new)) => {
                            format!("controller kind `{old}` is now `{new}` (known: {})", known())
                        }
                        None => format!("unknown controller kind `{k}` (known: {})", known()),
                    },
                ));
            }
        };
        spec.check()?;
        Ok(spec)
    }

    /// The TOML text of this specification (what [`ControllerSpec::from_toml`] reads back).
    pub fn to_toml(&self) -> Result<String, ControllerError> {
        toml::to_string(self).map_err(|e| ControllerError::Config(e.to_string()))
    }

    /// The parameters are usable (sizes, signs, ranges; the error says which).
    pub fn check(&self) -> Result<(), ControllerError> {
        match self {
            ControllerSpec::Pidc(c) => c.check(),
            ControllerSpec::JointDamping(c) => c.check(),
            ControllerSpec::Mqp(c) => c.check(),
        }
    }

    /// The controller, once the parameters are checked.
    pub fn build(&self) -> Result<Box<dyn TeamController>, ControllerError> {
        self.check()?;
        Ok(match self {
            ControllerSpec::Pidc(c) => Box::new(Pidc::new(c.clone())),
            ControllerSpec::JointDamping(c) => Box::new(JointDamping { damping: c.damping }),
            ControllerSpec::Mqp(c) => Box::new(Mqp::new(c.clone())),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::controller_shell::ShellConfig;

    #[test]
    fn every_kind_round_trips_through_toml_and_builds() {
        let pidc = ControllerSpec::Pidc(PidcConfig {
            shell: ShellConfig {
                f_min_hand: 12.5,
                object_mass: 2.0,
                ..PidcConfig::default().shell
            },
            qp_path: crate::qp::QpPath::Clarabel,
            ..PidcConfig::default()
        });
        let damping = ControllerSpec::JointDamping(JointDampingConfig { damping: 3.5 });
        let mqp = ControllerSpec::Mqp(MqpConfig {
            object_weight: 2.0,
            dt: 0.0005,
            ..MqpConfig::default()
        });
        for spec in [pidc, damping, mqp] {
            let text = spec.to_toml().expect("toml");
            assert!(text.starts_with(&format!("kind = \"{}\"", spec.kind())), "{text}");
            assert_eq!(ControllerSpec::from_toml(&text).expect("read back"), spec, "{text}");
            // serde's own reading of the tagged enum agrees (for a spec inside another file).
            assert_eq!(toml::from_str::<ControllerSpec>(&text).expect("serde"), spec);
        }
        for kind in ControllerSpec::KINDS {
            let spec = ControllerSpec::of_kind(kind).expect("known kind");
            assert_eq!(spec.kind(), kind);
            assert!(spec.build().is_ok());
        }
        assert_eq!(
            ControllerSpec::of_kind("pidc"),
            Ok(ControllerSpec::Pidc(PidcConfig::default()))
        );
        assert_eq!(
            ControllerSpec::of_kind("joint-damping"),
            Ok(ControllerSpec::JointDamping(JointDampingConfig::default()))
        );
        assert!(ControllerSpec::of_kind("pidc")
            .expect("pidc")
            .build()
            .expect("built")
            .name()
            .starts_with("pidc"));
    }

    #[test]
    fn a_file_names_the_kind_and_any_subset_of_its_fields() {
        let text = "kind = \"pidc\"\nf_min_hand = 20.0\n[object_gains]\nkp = [1, 2, 3, 4, 5, 6]\nkd = [6, 5, 4, 3, 2, 1]\n";
        let Ok(ControllerSpec::Pidc(c)) = ControllerSpec::from_toml(text) else {
            panic!("{text} is a pidc file")
        };
        let d = PidcConfig::default();
        assert_eq!(
            c,
            PidcConfig {
                shell: ShellConfig {
                    f_min_hand: 20.0,
                    object_gains: crate::building_blocks::impedance::Gains::new(
                        &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
                        &[6.0, 5.0, 4.0, 3.0, 2.0, 1.0]
                    ),
                    ..d.shell.clone()
                },
                ..d
            }
        );
        assert_eq!(
            ControllerSpec::from_toml("kind = \"joint-damping\"\ndamping = 0.5"),
            Ok(ControllerSpec::JointDamping(JointDampingConfig { damping: 0.5 }))
        );
    }

    #[test]
    fn unknown_kinds_and_fields_and_bad_values_say_what_is_wrong() {
        for (text, says) in [
            (
                "kind = \"paper\"",
                "controller kind `paper` is now `pidc` (known: pidc, joint-damping, mqp)",
            ),
            ("kind = \"smoke\"", "`smoke` is now `joint-damping`"),
            ("kind = \"mpc\"", "unknown controller kind `mpc` (known: pidc, joint-damping, mqp)"),
            ("f_min_hand = 3.0", "no `kind` (one of: pidc, joint-damping, mqp)"),
            ("kind = 3", "`kind` must be a string"),
            ("kind = \"pidc\"\nf_min_hnad = 3.0", "f_min_hnad"),
            (
                "kind = \"pidc\"\nf_min_hand = \"a lot\"",
                "pidc: invalid type: string \"a lot\", expected f64 in `f_min_hand`",
            ),
            ("kind = \"pidc\"\npatch_margin = 1.5", "patch_margin"),
            ("kind = \"pidc\"\n[torso_gains]\nkp = [1]\nkd = [1]", "torso_gains"),
            ("kind = \"joint-damping\"\ndampng = 3.0", "dampng"),
            (
                "kind = \"joint-damping\"\ndamping = -1.0",
                "damping: -1 must be finite and non-negative",
            ),
            ("kind = \"mqp\"\nobject_wieght = 1.0", "object_wieght"),
            ("kind = \"mqp\"\ndt = 0.0", "dt: 0 must be finite and positive"),
            ("kind = \"mqp\"\n[torso_gains]\nkp = [1]\nkd = [1]", "torso_gains"),
            ("kind = ", "controller configuration"),
        ] {
            let e = ControllerSpec::from_toml(text).expect_err(text).to_string();
            println!("{text:?}: {e}");
            assert!(e.contains(says), "{text:?}: {e}");
        }
        assert!(ControllerSpec::of_kind("paper")
            .expect_err("renamed")
            .to_string()
            .contains("now `pidc`"));
        assert!(ControllerSpec::JointDamping(JointDampingConfig { damping: f64::NAN })
            .build()
            .is_err());
    }

    #[test]
    fn paths_are_named_choices_and_the_retired_booleans_name_their_replacement() {
        let text = "kind = \"pidc\"\nqp_path = \"dense-ipm\"\nprojections = \"dense\"\n";
        let Ok(ControllerSpec::Pidc(c)) = ControllerSpec::from_toml(text) else {
            panic!("{text} is a pidc file")
        };
        assert_eq!(
            (c.qp_path, c.projections),
            (
                crate::qp::QpPath::DenseIpm,
                crate::building_blocks::projection::ProjectionPath::Dense
            )
        );
        assert_eq!(
            (PidcConfig::default().qp_path, PidcConfig::default().projections),
            (
                crate::qp::QpPath::ByBlocks,
                crate::building_blocks::projection::ProjectionPath::ByBlocks
            )
        );
        for (path, name) in crate::qp::QpPath::NAMES {
            assert_eq!(name.parse::<crate::qp::QpPath>(), Ok(path));
            assert_eq!(path.name(), name);
        }
        for (key, new) in [
            ("dense_qp = false", "`qp_path`"),
            ("active_set_qp = true", "`qp_path`"),
            ("qp_by_blocks = false", "`qp_path`"),
            ("dense_projections = true", "`projections`"),
        ] {
            let text = format!("kind = \"pidc\"\n{key}\n");
            let e = ControllerSpec::from_toml(&text).expect_err(&text).to_string();
            assert!(e.contains("is no longer a key") && e.contains(new), "{text:?}: {e}");
            let e = PidcConfig::from_toml(key).expect_err(key).to_string();
            assert!(e.contains(new), "{key:?}: {e}");
        }
        assert!(ControllerSpec::from_toml("kind = \"pidc\"\nqp_path = \"dense\"").is_err());
    }
}
