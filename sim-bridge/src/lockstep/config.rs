//! The lockstep loop's settings ([`LockstepConfig`], [`AgentLoss`]), what a run did
//! ([`LockstepReport`]), what it does besides states and torques ([`LoopDuties`]) and its errors.

use std::time::Duration;

use protocol::transport::TransportError;
use thiserror::Error;

use crate::ground_truth::GroundTruthLog;
use crate::plant::DriveLoss;

/// Errors of the bridge loop.
#[derive(Debug, Error)]
pub enum BridgeError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Protocol(#[from] protocol::ProtocolError),
    #[error("robots {missing:?} did not join the team within {waited:?}")]
    MembersMissing { missing: Vec<String>, waited: Duration },
    #[error("the coordinator was not ready for the team within {waited:?} (last status: {last})")]
    CoordinatorNotReady { last: String, waited: Duration },
    #[error("no torques from robot(s) {missing:?} for tick {tick} within {waited:?}")]
    TorqueTimeout { tick: u64, missing: Vec<String>, waited: Duration },
    #[error("robot {robot}'s agent left the team at tick {tick}")]
    RobotLeft { robot: String, tick: u64 },
    #[error(
        "the coordinator left at tick {since}; the robots held their posture for {ticks} ticks \
         and it did not come back"
    )]
    CoordinatorLost { since: u64, ticks: u64 },
    #[error("stopped")]
    Stopped,
}

/// Settings of the lockstep loop.
#[derive(Debug, Clone)]
pub struct LockstepConfig {
    pub team: String,
    pub ticks: u64,
    /// How long to wait for every robot to join before the first tick.
    pub start_timeout: Duration,
    /// How long a tick may wait for torques before the run fails, naming the robot.
    pub command_timeout: Duration,
    /// While waiting, the states of the tick are sent again this often (a component that
    /// joined late may have missed them); agents and coordinator treat repeats as repeats.
    pub resend_every: Duration,
    /// Log progress every this many ticks (0: never).
    pub progress_every: u64,
    /// Ticks the run goes on after the coordinator's liveliness token disappeared (the agents
    /// hold their posture meanwhile) before it fails; a coordinator that comes back within
    /// them takes the team back.
    pub coordinator_grace_ticks: u64,
    /// Also wait, before the first tick, until the coordinator's status lists every robot as a
    /// member and it is ready to command them (descriptions received). The coordinator learns
    /// of members through liveliness, which may reach it after a robot's first dynamics: a tick
    /// it then completed without that robot was never commanded for it.
    pub wait_for_coordinator: bool,
    /// What a robot whose agent leaves mid-run becomes.
    pub agent_loss: AgentLoss,
    /// Real time: a robot whose torques have not come for this long loses its drives
    /// ([`AgentLoss::Drives`]); until then its drives hold its last torques.
    pub drive_timeout: Duration,
}

/// What the loops do when a robot's agent leaves the team mid-run (its liveliness token is
/// gone: the process died, or was stopped) or, in real time, sends no torques for
/// [`LockstepConfig::drive_timeout`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AgentLoss {
    /// End the run with [`BridgeError::RobotLeft`], naming the robot (the smoke runs). In real
    /// time the drives hold the last torques.
    #[default]
    EndRun,
    /// Go on without it: its drives do what [`DriveLoss`] says (unpowered, or frozen where
    /// they are) and no tick waits for it. An agent that left the team alive (a fallen robot's,
    /// `robot_agent::fall`) and still answers its states drives it with those torques as they
    /// come (a tick late when they come after the tick's step), holding the last ones for up
    /// to [`super::LOST_DRIVE_TICKS`] (then the drives are lost as above). When its agent joins
    /// again (restarted), the loop waits for its torques from the next tick on, and the first
    /// torques it sends drive the robot again. The run ends with [`BridgeError::RobotLeft`]
    /// when every agent has left.
    Drives(DriveLoss),
}

impl AgentLoss {
    /// What the drives do on a loss, if the run goes on.
    pub fn drive_loss(&self) -> Option<DriveLoss> {
        match self {
            AgentLoss::EndRun => None,
            AgentLoss::Drives(d) => Some(*d),
        }
    }
}

/// [`LockstepConfig::drive_timeout`] by default: twice an agent's own command deadline (25 ms),
/// so that an agent in safe mode (which sends its hold torques) never trips it.
pub const DEFAULT_DRIVE_TIMEOUT: Duration = Duration::from_millis(50);

impl LockstepConfig {
    /// The smoke run's lockstep (placeholder plant): 20 s for every robot to join,
    /// `command_timeout` per tick, resends every 50 ms, progress every tenth of the run, and the
    /// coordinator's readiness awaited (under load its members' liveliness reached it after their
    /// first terms: it ordered a hold at tick 0, and the closed loop's analytic answer was off).
    /// The embedded launcher and `sim-bridge smoke` both use it.
    pub fn smoke(team: &str, ticks: u64, command_timeout: Duration) -> Self {
        LockstepConfig {
            team: team.to_string(),
            ticks,
            start_timeout: Duration::from_secs(20),
            command_timeout,
            resend_every: Duration::from_millis(50),
            progress_every: (ticks / 10).max(1),
            wait_for_coordinator: true,
            coordinator_grace_ticks: DEFAULT_COORDINATOR_GRACE_TICKS,
            agent_loss: AgentLoss::EndRun,
            drive_timeout: DEFAULT_DRIVE_TIMEOUT,
        }
    }
}

/// [`LockstepConfig::coordinator_grace_ticks`] by default: three seconds at 1 kHz. A new
/// coordinator process takes up to a second to be back on a loaded machine (start-up, then the
/// agents' reconnection to the hub, up to their half-second retry period); the robots hold
/// their posture meanwhile, and a team that stands can hold for longer than that.
pub const DEFAULT_COORDINATOR_GRACE_TICKS: u64 = 3000;

/// What a lockstep run did.
#[derive(Debug, Clone, PartialEq)]
pub struct LockstepReport {
    pub ticks: u64,
    pub sim_time: f64,
    pub wall_time: Duration,
    pub resends: u64,
    pub rejected_torques: u64,
}

/// What the loop does besides states and torques.
#[derive(Debug, Default)]
pub struct LoopDuties {
    /// Publish the plant's ground truth on `team/{team}/ground-truth` after every step.
    pub publish_ground_truth: bool,
    /// Keep the ground truth in memory (every `GroundTruthLog::every` ticks).
    pub truth_log: Option<GroundTruthLog>,
    /// Take perturbation requests from `team/{team}/perturbation`.
    pub perturbation_key: bool,
    /// Perturbation requests taken and refused.
    pub perturbations_taken: u64,
    pub perturbations_refused: u64,
    /// Number of the first tick (a run that continues an earlier one, e.g. after settling,
    /// continues its tick numbers: agents refuse ticks older than the last they applied).
    pub first_tick: u64,
}
