//! The names of the static problem's limit rows: where a limit acts ([`Place`]), which limit
//! it is ([`Limit`]), and a named row ([`LimitRow`]). The problem builds them, the report
//! prints them.

/// Where a limit acts: a joint or a contact frame of a robot.
#[derive(Debug, Clone, PartialEq)]
pub enum Place {
    Joint(String),
    Contact(String),
}

/// Which limit a row is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Limit {
    /// `tau <= tau_max` (`upper`) or `-tau <= tau_max`, Nm.
    Torque { upper: bool, max: f64 },
    /// Tangential force along the contact's `x` or `y` axis (`+` or `-`) within `mu f_n`, N.
    Friction { axis: char, positive: bool },
    /// Normal force at least `f_min`, N.
    MinNormal { f_min: f64 },
    /// A hand's sliding and torsional friction together, `s_x t_x.f / mu + s_y t_y.f / mu +
    /// s_z n.m / xi <= f_n` (`x`, `y`, `torsion`: the signs `s` are `+`), in N of `mu f_n`.
    FrictionAndTorsion { x: bool, y: bool, torsion: bool },
    /// Centre of pressure within the palm patch along `axis` (the tilt moment), Nm.
    CentreOfPressure { axis: char, positive: bool },
}

impl Limit {
    /// The unit of the row's excess.
    pub fn unit(&self) -> &'static str {
        match self {
            Limit::Friction { .. } | Limit::FrictionAndTorsion { .. } | Limit::MinNormal { .. } => {
                "N"
            }
            _ => "Nm",
        }
    }
}

/// A named limit row of `A lambda <= b`.
#[derive(Debug, Clone, PartialEq)]
pub struct LimitRow {
    pub robot: String,
    pub place: Place,
    pub limit: Limit,
}
