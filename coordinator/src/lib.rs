//! # coordinator
//!
//! Solves the team problem every tick (DESIGN.md §2 step 3): it knows who is in the team
//! ([`membership`]), gathers every member's dynamics terms of a tick ([`assembly`]), runs the
//! team controller ([`TeamController`]) and publishes each robot its slice of torques
//! ([`service`]).

pub mod assembly;
pub mod membership;
pub mod service;

use protocol::{DynamicsTerms, TorqueCommand};

/// A controller of the whole team: from every member's dynamics terms of one tick (sorted by
/// robot id) to one torque command per member, in the same order.
pub trait TeamController: Send {
    fn name(&self) -> &'static str;
    fn solve(&mut self, tick: &[DynamicsTerms], out: &mut Vec<TorqueCommand>) -> Result<(), ControllerError>;
}

/// Why a controller could not produce torques for a tick.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ControllerError {
    #[error("robot {robot}: {reason}")]
    BadTerms { robot: String, reason: String },
}

/// Smoke-run stand-in for the team controller (until the paper's controller lands): joint
/// damping `tau = -d * qdot` for every actuated joint. It exercises the message flow only.
pub struct JointDamping {
    pub damping: f64,
}

impl TeamController for JointDamping {
    fn name(&self) -> &'static str {
        "joint-damping (smoke)"
    }

    fn solve(&mut self, tick: &[DynamicsTerms], out: &mut Vec<TorqueCommand>) -> Result<(), ControllerError> {
        out.clear();
        for terms in tick {
            // Actuated joints follow the 6 base coordinates of a floating-base robot.
            let v = &terms.velocity[terms.nv() - terms.actuated()..];
            out.push(TorqueCommand {
                header: protocol::Header::new(&terms.header.team, terms.header.robot.as_deref(), terms.header.tick, 0),
                tau: v.iter().map(|qd| -self.damping * qd).collect(),
            });
        }
        Ok(())
    }
}
