//! The agent loop: state in, dynamics terms out; command in, checked torque out.

use std::time::Instant;

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, TransportError, TypedPublisher};
use protocol::{DynamicsTerms, Header, Matrix, RobotState, TorqueCommand};
use thiserror::Error;
use tokio::sync::watch;
use zenoh::Session;

/// Errors of the agent.
#[derive(Debug, Error)]
pub enum AgentError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Protocol(#[from] protocol::ProtocolError),
    #[error("state has {got} joints, the robot has {expected}")]
    StateSize { expected: usize, got: usize },
}

/// Why a command was refused. The command is dropped; nothing is applied.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CommandRejection {
    #[error("command for robot {got:?} received by robot {expected:?}")]
    WrongRobot { expected: String, got: String },
    #[error("command for tick {tick} is older than the last applied tick {last}")]
    Stale { tick: u64, last: u64 },
    #[error("command for tick {tick} is from the future (latest state is tick {latest})")]
    FromTheFuture { tick: u64, latest: u64 },
    #[error("command has {got} torques, the robot has {expected} actuated joints")]
    WrongSize { expected: usize, got: usize },
    #[error("command arrived before any state")]
    NoState,
}

/// Identity and size of the robot this agent runs.
#[derive(Debug, Clone)]
pub struct AgentConfig {
    pub team: String,
    pub robot: String,
    /// Number of actuated joints.
    pub joints: usize,
    /// Whether the robot has an unactuated 6-DoF floating base.
    pub floating_base: bool,
}

impl AgentConfig {
    pub fn nv(&self) -> usize {
        self.joints + if self.floating_base { 6 } else { 0 }
    }
}

/// Tick bookkeeping for command checks (robot id, tick, size).
#[derive(Debug, Clone, Default)]
pub struct CommandGate {
    latest_state_tick: Option<u64>,
    last_applied_tick: Option<u64>,
}

impl CommandGate {
    pub fn on_state(&mut self, tick: u64) {
        self.latest_state_tick = Some(self.latest_state_tick.map_or(tick, |t| t.max(tick)));
    }

    /// Accept or refuse a (decoded, hence finite) command; on acceptance it becomes the last
    /// applied tick.
    pub fn check(&mut self, cfg: &AgentConfig, cmd: &TorqueCommand) -> Result<(), CommandRejection> {
        let got = cmd.header.robot_id();
        if got != cfg.robot {
            return Err(CommandRejection::WrongRobot { expected: cfg.robot.clone(), got: got.to_string() });
        }
        let latest = self.latest_state_tick.ok_or(CommandRejection::NoState)?;
        let tick = cmd.header.tick;
        if tick > latest {
            return Err(CommandRejection::FromTheFuture { tick, latest });
        }
        if let Some(last) = self.last_applied_tick {
            if tick <= last {
                return Err(CommandRejection::Stale { tick, last });
            }
        }
        if cmd.tau.len() != cfg.joints {
            return Err(CommandRejection::WrongSize { expected: cfg.joints, got: cmd.tau.len() });
        }
        self.last_applied_tick = Some(tick);
        Ok(())
    }
}

/// Computes a robot's dynamics terms from its state.
pub trait DynamicsSource: Send {
    fn compute(&mut self, state: &RobotState, out: &mut DynamicsTerms) -> Result<(), AgentError>;
}

/// Smoke-run stand-in for the robot model (until the model of the dynamics issue is wired
/// in): unit mass matrix, zero bias, no frames. It exercises the message flow only.
pub struct PlaceholderDynamics {
    pub joints: usize,
    pub nv: usize,
}

impl DynamicsSource for PlaceholderDynamics {
    fn compute(&mut self, state: &RobotState, out: &mut DynamicsTerms) -> Result<(), AgentError> {
        if state.joint_positions.len() != self.joints {
            return Err(AgentError::StateSize { expected: self.joints, got: state.joint_positions.len() });
        }
        let nv = self.nv;
        out.nv = nv as u32;
        out.mass_matrix = Matrix::zeros(nv, nv);
        for i in 0..nv {
            out.mass_matrix.data[i * nv + i] = 1.0;
        }
        out.bias.clear();
        out.bias.resize(nv, 0.0);
        out.velocity.clear();
        if nv > self.joints {
            out.velocity.extend_from_slice(&state.base_twist);
        }
        out.velocity.extend_from_slice(&state.joint_velocities);
        out.frames.clear();
        out.hand_in_grasp = false;
        Ok(())
    }
}

/// What an agent did, for logs and tests.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct AgentCounters {
    pub states: u64,
    pub dynamics: u64,
    pub applied: u64,
    pub rejected: u64,
}


/// Run the agent until `stop` turns true. Subscribes before it declares its membership so
/// that whoever sees it join can already reach it.
pub async fn run(
    session: &Session,
    cfg: AgentConfig,
    mut source: impl DynamicsSource,
    mut stop: watch::Receiver<bool>,
) -> Result<AgentCounters, AgentError> {
    let states = transport::subscribe(session, keys::robot(&cfg.team, &cfg.robot, RobotTopic::State)?).await?;
    let commands = transport::subscribe(session, keys::robot(&cfg.team, &cfg.robot, RobotTopic::Command)?).await?;
    let mut dynamics_pub: TypedPublisher<DynamicsTerms> =
        TypedPublisher::declare(session, keys::robot(&cfg.team, &cfg.robot, RobotTopic::Dynamics)?, Qos::HotPath).await?;
    let mut torque_pub: TypedPublisher<TorqueCommand> =
        TypedPublisher::declare(session, keys::robot(&cfg.team, &cfg.robot, RobotTopic::Torque)?, Qos::HotPath).await?;
    let _token = transport::declare_member(session, &cfg.team, &cfg.robot).await?;
    tracing::info!(robot = %cfg.robot, team = %cfg.team, "agent joined the team");

    let nv = cfg.nv();
    let mut terms = DynamicsTerms {
        header: Header::new(&cfg.team, Some(&cfg.robot), 0, 0),
        floating_base: cfg.floating_base,
        nv: nv as u32,
        mass_matrix: Matrix::zeros(nv, nv),
        bias: vec![0.0; nv],
        velocity: vec![0.0; nv],
        frames: Vec::new(),
        hand_in_grasp: false,
        state_tick: 0,
    };
    let mut gate = CommandGate::default();
    let mut counters = AgentCounters::default();
    let mut last_state_at = Instant::now();
    loop {
        tokio::select! {
            _ = stop.changed() => { if *stop.borrow() { break; } }
            s = states.recv_async() => {
                let Ok(sample) = s else { break };
                let state = match decode_sample::<RobotState>(&sample) {
                    Ok(s) => s,
                    Err(e) => { tracing::warn!(robot = %cfg.robot, "dropped state: {e}"); continue; }
                };
                if state.header.robot_id() != cfg.robot {
                    tracing::warn!(robot = %cfg.robot, got = state.header.robot_id(), "dropped state of another robot");
                    continue;
                }
                last_state_at = Instant::now();
                counters.states += 1;
                gate.on_state(state.header.tick);
                if let Err(e) = source.compute(&state, &mut terms) {
                    tracing::warn!(robot = %cfg.robot, "no dynamics for tick {}: {e}", state.header.tick);
                    continue;
                }
                terms.header.tick = state.header.tick;
                terms.header.stamp_ns = protocol::wall_clock_ns();
                terms.state_tick = state.header.tick;
                dynamics_pub.put(&terms).await?;
                counters.dynamics += 1;
            }
            c = commands.recv_async() => {
                let Ok(sample) = c else { break };
                let cmd = match decode_sample::<TorqueCommand>(&sample) {
                    Ok(c) => c,
                    Err(e) => { counters.rejected += 1; tracing::warn!(robot = %cfg.robot, "rejected command: {e}"); continue; }
                };
                match gate.check(&cfg, &cmd) {
                    Ok(()) => {
                        torque_pub.put(&cmd).await?;
                        counters.applied += 1;
                        tracing::trace!(robot = %cfg.robot, tick = cmd.header.tick, latency_us = last_state_at.elapsed().as_micros() as u64, "applied");
                    }
                    Err(e) => { counters.rejected += 1; tracing::warn!(robot = %cfg.robot, "rejected command: {e}"); }
                }
            }
        }
    }
    tracing::info!(robot = %cfg.robot, ?counters, "agent stopped");
    Ok(counters)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> AgentConfig {
        AgentConfig { team: "t".into(), robot: "r1".into(), joints: 3, floating_base: true }
    }

    fn cmd(robot: &str, tick: u64, n: usize) -> TorqueCommand {
        TorqueCommand { header: Header::new("t", Some(robot), tick, 0), tau: vec![0.0; n] }
    }

    #[test]
    fn gate_checks_robot_tick_and_size() {
        let c = cfg();
        let mut g = CommandGate::default();
        assert_eq!(g.check(&c, &cmd("r1", 0, 3)), Err(CommandRejection::NoState));
        g.on_state(5);
        assert!(matches!(g.check(&c, &cmd("r2", 5, 3)), Err(CommandRejection::WrongRobot { .. })));
        assert!(matches!(g.check(&c, &cmd("r1", 6, 3)), Err(CommandRejection::FromTheFuture { .. })));
        assert!(matches!(g.check(&c, &cmd("r1", 5, 4)), Err(CommandRejection::WrongSize { .. })));
        assert_eq!(g.check(&c, &cmd("r1", 5, 3)), Ok(()));
        assert!(matches!(g.check(&c, &cmd("r1", 5, 3)), Err(CommandRejection::Stale { .. })));
        g.on_state(6);
        assert_eq!(g.check(&c, &cmd("r1", 6, 3)), Ok(()));
    }
}
