//! What the static check reports: [`CapacityError`] (typed, with the binding limits when no
//! contact forces exist) and [`BindingLimit`] (which robot, which joint or contact, which
//! limit, how far over).

use std::fmt;

use super::limits::{Limit, Place};
use crate::ControllerError;

/// Binding limits shown in an error message (all are in [`CapacityError::Infeasible`]).
pub const SHOWN_LIMITS: usize = 6;

/// A limit the relaxed problem had to exceed.
#[derive(Debug, Clone, PartialEq)]
pub struct BindingLimit {
    pub robot: String,
    pub place: Place,
    pub limit: Limit,
    /// How far over, in [`Limit::unit`] (N or Nm); negative: how far within (a limit reached,
    /// [`super::StaticProblem::reached`]).
    pub over: f64,
    /// For a torque limit: the torque the relaxed solution needs there, Nm.
    pub torque: Option<f64>,
}

impl fmt::Display for BindingLimit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let sign = |p: bool| if p { '+' } else { '-' };
        match &self.place {
            Place::Joint(j) => write!(f, "robot {} joint {j}: ", self.robot)?,
            Place::Contact(c) => write!(f, "robot {} contact {c}: ", self.robot)?,
        }
        match (self.limit, self.torque) {
            (Limit::Torque { max, .. }, Some(t)) => {
                write!(f, "torque {t:.2} Nm, limit {max:.2} Nm")?
            }
            (Limit::Torque { upper, max }, None) => {
                write!(f, "torque limit {}{max:.2} Nm", sign(upper))?
            }
            (Limit::Friction { axis, positive }, _) => {
                write!(f, "friction along {}{axis}", sign(positive))?
            }
            (Limit::MinNormal { f_min }, _) => {
                write!(f, "normal force below its minimum {f_min:.2} N")?
            }
            (Limit::FrictionAndTorsion { x, y, torsion }, _) => write!(
                f,
                "friction along {}x and {}y with torsion ({}) beyond the palm's cone",
                sign(x),
                sign(y),
                sign(torsion)
            )?,
            (Limit::CentreOfPressure { axis, positive }, _) => {
                write!(f, "centre of pressure past the patch's {}{axis} edge", sign(positive))?
            }
        }
        if self.over > 0.0 {
            write!(f, " ({:.3} {} over)", self.over, self.limit.unit())
        } else {
            write!(f, " ({:.3} {} from it)", -self.over, self.limit.unit())
        }
    }
}

/// Why the static check failed.
#[derive(Debug, thiserror::Error)]
pub enum CapacityError {
    #[error("object mass {0} kg: must be finite and non-negative")]
    InvalidMass(f64),
    #[error("static check input: {0}")]
    Input(String),
    #[error("no hand in grasp: nothing holds the object")]
    NoHands,
    #[error("robot {robot} is not at rest (the static check needs v = 0)")]
    NotAtRest { robot: String },
    #[error("assembling the team: {0}")]
    Team(#[from] ControllerError),
    #[error(
        "no contact wrenches balance the robots and a {mass} kg object, whatever the limits (the \
         grasp or the stance cannot carry the load)"
    )]
    NoEquilibrium { mass: f64 },
    #[error("Clarabel: {0}")]
    Solver(String),
    #[error("no contact forces hold {mass} kg: {}", list(binding))]
    Infeasible { mass: f64, binding: Vec<BindingLimit> },
    #[error("the team still holds {mass} kg: no limit found below it")]
    Unbounded { mass: f64 },
}

fn list(binding: &[BindingLimit]) -> String {
    let mut s = format!("{} limit(s) bind, largest first: ", binding.len());
    for (i, b) in binding.iter().take(SHOWN_LIMITS).enumerate() {
        if i > 0 {
            s.push_str("; ");
        }
        s.push_str(&b.to_string());
    }
    if binding.len() > SHOWN_LIMITS {
        s.push_str(&format!("; and {} more", binding.len() - SHOWN_LIMITS));
    }
    s
}
