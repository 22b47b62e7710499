//! # coordinator
//!
//! Solves the team problem every tick (DESIGN.md §2 step 3): it knows who is in the team
//! ([`membership`]), gathers every member's dynamics terms of a tick ([`assembly`]), runs the
//! team controller ([`TeamController`]) and publishes each robot its slice of torques
//! ([`service`]).

pub mod assembly;
pub mod controller;
pub mod diagnostics;
pub mod grasp;
pub mod impedance;
pub mod linalg;
pub mod membership;
pub mod projection;
pub mod qp;
pub mod service;
pub mod team;

pub use controller::{ControllerConfig, PaperController};

use protocol::{DynamicsTerms, RobotDescription, TaskReferences, TickDiagnostics, TorqueCommand};

/// A controller of the whole team: from every member's dynamics terms of one tick (sorted by
/// robot id) to one torque command per member, in the same order.
pub trait TeamController: Send {
    fn name(&self) -> &'static str;
    fn solve(&mut self, tick: &[DynamicsTerms], out: &mut Vec<TorqueCommand>) -> Result<(), ControllerError>;
    /// Diagnostics of the last solved tick, if the controller makes any.
    fn diagnostics(&self) -> Option<&TickDiagnostics> {
        None
    }
    /// Whether the last tick's command came from the controller's fallback.
    fn used_fallback(&self) -> bool {
        false
    }
    /// A robot's description arrived (limits, contact parameters).
    fn set_description(&mut self, _description: &RobotDescription) {}
    /// New task references arrived.
    fn set_references(&mut self, _references: &TaskReferences) {}
    /// The present members changed (sorted ids).
    fn set_members(&mut self, _members: &[String]) {}
    /// Why the controller cannot run yet (e.g. descriptions missing), if so.
    fn not_ready(&self, _members: &[String]) -> Option<String> {
        None
    }
}

/// Why a controller could not produce torques for a tick.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ControllerError {
    #[error("robot {robot}: {reason}")]
    BadTerms { robot: String, reason: String },
    #[error("robot {robot} is missing from the tick")]
    MissingRobot { robot: String },
    #[error("robot {robot} is in the tick but not expected")]
    UnknownRobot { robot: String },
    #[error("no description received for robot {robot}")]
    MissingDescription { robot: String },
    #[error("dimension mismatch in {what}: {detail}")]
    Dimension { what: String, detail: String },
    #[error("robot {robot}: non-finite {what}")]
    NonFinite { robot: String, what: String },
    #[error("singular {what}")]
    Singular { what: String },
    #[error("controller configuration: {0}")]
    Config(String),
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
