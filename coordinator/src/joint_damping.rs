//! [`JointDamping`]: the smoke run's team controller, `tau = -d * qdot` on every actuated
//! joint. It exercises the message flow only (placeholder robots, no contacts).

use protocol::{DynamicsTerms, TorqueCommand};

use crate::{ControllerError, TeamController};

/// Joint damping `tau = -damping * qdot` for every actuated joint of every robot.
pub struct JointDamping {
    /// N·m·s/rad.
    pub damping: f64,
}

/// Parameters of [`JointDamping`]; in a controller file they follow `kind = "joint-damping"`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct JointDampingConfig {
    /// N·m·s/rad.
    pub damping: f64,
}

impl Default for JointDampingConfig {
    fn default() -> Self {
        JointDampingConfig { damping: 2.0 }
    }
}

impl JointDampingConfig {
    /// The damping is finite and non-negative.
    pub fn check(&self) -> Result<(), ControllerError> {
        if self.damping.is_finite() && self.damping >= 0.0 {
            Ok(())
        } else {
            Err(ControllerError::Config(format!(
                "damping: {} must be finite and non-negative",
                self.damping
            )))
        }
    }
}

impl TeamController for JointDamping {
    fn name(&self) -> &'static str {
        "joint-damping (smoke)"
    }

    fn solve(
        &mut self,
        tick: &[DynamicsTerms],
        out: &mut Vec<TorqueCommand>,
    ) -> Result<(), ControllerError> {
        out.clear();
        for terms in tick {
            // Actuated joints follow the 6 base coordinates of a floating-base robot.
            let v = &terms.velocity[terms.nv() - terms.actuated()..];
            out.push(TorqueCommand {
                header: protocol::Header::new(
                    &terms.header.team,
                    terms.header.robot.as_deref(),
                    terms.header.tick,
                    0,
                ),
                tau: v.iter().map(|qd| -self.damping * qd).collect(),
                hold: false,
                delay_ticks: 0,
                qdd: Vec::new(),
            });
        }
        Ok(())
    }
}
