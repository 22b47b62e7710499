//! The controller interface: [`TeamController`] (what [`crate::service::run`] drives every
//! tick) and [`ControllerError`]. Which controller runs is data: [`crate::ControllerSpec`].
//!
//! **A second controller plugs in** by writing its law ([`crate::controller_shell::ControlLaw`],
//! in its own module, composing the building blocks of [`crate::building_blocks`] and the QP of
//! [`crate::qp`]):
//! [`crate::Shell`] of it is a [`TeamController`]; then a variant of [`crate::ControllerSpec`]
//! ([`crate::spec`]).

use protocol::{DynamicsTerms, RobotDescription, TaskReferences, TickDiagnostics, TorqueCommand};

/// A controller of the whole team: from every member's dynamics terms of one tick (sorted by
/// robot id) to one torque command per member, in the same order.
pub trait TeamController: Send {
    fn name(&self) -> &'static str;
    fn solve(
        &mut self,
        tick: &[DynamicsTerms],
        out: &mut Vec<TorqueCommand>,
    ) -> Result<(), ControllerError>;
    /// Diagnostics of the last solved tick, if the controller makes any.
    fn diagnostics(&self) -> Option<&TickDiagnostics> {
        None
    }
    /// Whether the last tick's command came from the controller's fallback.
    fn used_fallback(&self) -> bool {
        false
    }
    /// The tick after which the team let go of the object (`crate::building_blocks::release`),
    /// while it
    /// stays released.
    fn released_at(&self) -> Option<u64> {
        None
    }
    /// A robot's description arrived (limits, contact parameters).
    fn set_description(&mut self, _description: &RobotDescription) {}
    /// New task references arrived.
    fn set_references(&mut self, _references: &TaskReferences) {}
    /// The present members changed (sorted ids).
    fn set_members(&mut self, _members: &[String]) {}
    /// Robots that joined the running team with their hands out of the grasp (sorted ids):
    /// their free hands keep clear of the object (`building_blocks::targets::Targets::keep_clear`).
    fn set_late(&mut self, _robots: &[String]) {}
    /// Why the controller cannot run yet (e.g. descriptions missing), if so.
    fn not_ready(&self, _members: &[String]) -> Option<String> {
        None
    }
    /// Whether the controller can command robot `robot` (its description arrived).
    fn ready(&self, _robot: &str) -> bool {
        true
    }
    /// Whether `terms` fit the controller (sizes, its robot's description), checked as they
    /// arrive: terms that do not are refused and their robot holds its posture for that tick,
    /// instead of failing the whole team's tick.
    fn check_terms(&self, _terms: &protocol::DynamicsTerms) -> Result<(), ControllerError> {
        Ok(())
    }

    /// Whether the ticks from now on should also compute what their torques accelerate
    /// ([`TeamController::accelerations`]; off by default, and off costs nothing). Returns
    /// whether the controller models them at all: only then does the coordinator carry the
    /// state over the team's delay ([`crate::team::prediction`]).
    fn keep_accelerations(&mut self, _keep: bool) -> bool {
        false
    }

    /// The generalized accelerations (in the order of its terms' velocity) that the last
    /// solved tick's torques command for `robot`: what carries a robot's state over the team's
    /// delay. `None` when the controller does not model them, was not asked to keep them, or
    /// the robot was not in the tick.
    fn accelerations(&self, _robot: &str) -> Option<&[f64]> {
        None
    }

    /// Real time: how long a tick may take to choose its contact forces, from its start, before
    /// the controller's fallback answers (the steps of "degrade, never collapse" that would run
    /// past it are not started, and a solver running stops at it). A tick the controller
    /// cannot solve in time is sent as the fallback, not late: a late command is no command.
    /// Returns whether the controller keeps a budget at all (PIDC does); `None` removes it.
    fn set_solve_budget(&mut self, _budget: Option<std::time::Duration>) -> bool {
        false
    }
}

/// Why a controller could not produce torques for a tick, or could not be configured.
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
