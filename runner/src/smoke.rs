//! The smoke run: every component, real messages, placeholder physics.

use std::time::Duration;

use coordinator::service::{self as coordinator_service, CoordinatorConfig};
use coordinator::JointDamping;
use protocol::transport::{self, Role, ZenohArgs};
use robot_agent::agent::{self as robot_agent_loop, AgentConfig, PlaceholderDynamics};

/// The smoke run's agents wait as long as the bridge does for a command before they hold
/// their posture: a lockstep tick that is merely slow must not see safe-mode torques.
pub const SMOKE_COMMAND_DEADLINE: Duration = Duration::from_secs(5);
use sim_bridge::lockstep::{self, LockstepConfig, LockstepReport};

use crate::processes::{free_port, spawn};
use sim_bridge::plant::PlaceholderPlant;
use thiserror::Error;
use tokio::sync::watch;

/// Errors of a smoke run.
#[derive(Debug, Error)]
pub enum SmokeError {
    #[error(transparent)]
    Transport(#[from] protocol::transport::TransportError),
    #[error(transparent)]
    Bridge(#[from] sim_bridge::lockstep::BridgeError),
    #[error("agent {robot}: {source}")]
    Agent { robot: String, source: robot_agent::agent::AgentError },
    #[error(transparent)]
    Process(#[from] crate::processes::ProcessError),
}

/// What to run.
#[derive(Debug, Clone)]
pub struct SmokeConfig {
    pub team: String,
    pub robots: Vec<String>,
    pub joints: usize,
    pub ticks: u64,
    pub dt: f64,
    /// Joint damping of the placeholder controller.
    pub damping: f64,
    /// Initial joint velocity of the placeholder plant.
    pub v0: f64,
}

impl SmokeConfig {
    /// The joint velocity the closed loop must end at: the plant integrates
    /// `v <- v - dt * d * v` once per tick (semi-implicit Euler of `qdd = -d qd`).
    pub fn expected_final_velocity(&self) -> f64 {
        self.v0 * (1.0 - self.dt * self.damping).powi(self.ticks as i32)
    }

    fn lockstep(&self) -> LockstepConfig {
        LockstepConfig {
            team: self.team.clone(),
            ticks: self.ticks,
            start_timeout: Duration::from_secs(20),
            command_timeout: Duration::from_secs(5),
            resend_every: Duration::from_millis(50),
            progress_every: (self.ticks / 10).max(1),
            wait_for_coordinator: false,
        }
    }
}

/// Result of a smoke run.
#[derive(Debug, Clone)]
pub struct SmokeOutcome {
    pub report: LockstepReport,
    /// Final joint velocity of each robot's first joint (embedded mode only).
    pub final_velocities: Vec<f64>,
}

/// Every component in this process, on one Zenoh session.
pub async fn run_embedded(cfg: &SmokeConfig) -> Result<SmokeOutcome, SmokeError> {
    let session = transport::open(&ZenohArgs::default(), Role::Alone).await?;
    let (stop_tx, stop_rx) = watch::channel(false);

    let coord_cfg = CoordinatorConfig { team: cfg.team.clone(), tick_deadline: Duration::from_millis(500) };
    let coordinator = {
        let session = session.clone();
        let rx = stop_rx.clone();
        let damping = cfg.damping;
        tokio::spawn(async move { coordinator_service::run(&session, coord_cfg, Box::new(JointDamping { damping }), rx).await })
    };
    let mut agents = Vec::new();
    for r in &cfg.robots {
        let session = session.clone();
        let rx = stop_rx.clone();
        let acfg = AgentConfig::new(&cfg.team, r).with_deadline_time(SMOKE_COMMAND_DEADLINE);
        let source = PlaceholderDynamics::floating(cfg.joints);
        let robot = r.clone();
        agents.push((robot, tokio::spawn(async move { robot_agent_loop::run(&session, acfg, source, rx).await })));
    }

    let mut plant = PlaceholderPlant::new(cfg.robots.clone(), cfg.joints, cfg.v0, cfg.dt);
    let result = lockstep::run(&session, &cfg.lockstep(), &mut plant, stop_rx.clone()).await;
    let _ = stop_tx.send(true);
    let _ = coordinator.await;
    for (robot, handle) in agents {
        if let Ok(Err(source)) = handle.await {
            return Err(SmokeError::Agent { robot, source });
        }
    }
    let _ = session.close().await;
    let report = result?;
    let final_velocities = (0..cfg.robots.len()).map(|i| plant.velocities(i)[0]).collect();
    Ok(SmokeOutcome { report, final_velocities })
}

/// Every component its own process, on loopback: the coordinator listens on a free port,
/// the agents and the sim-bridge connect to it.
pub fn run_distributed(cfg: &SmokeConfig) -> Result<(), SmokeError> {
    let port = free_port()?;
    let hub = format!("tcp/127.0.0.1:{port}");
    let listen = ZenohArgs::listening(&hub).to_cli();
    let connect = ZenohArgs::connecting(&hub).to_cli();
    let mut args = vec!["run".to_string(), "--team".into(), cfg.team.clone(), "--damping".into(), cfg.damping.to_string()];
    args.extend(listen);
    let _coordinator = spawn("coordinator", &args, "coordinator")?;
    let mut agents = Vec::new();
    for r in &cfg.robots {
        let mut args = vec!["run".to_string(), "--id".into(), r.clone(), "--team".into(), cfg.team.clone()];
        args.extend(["--placeholder-joints".into(), cfg.joints.to_string()]);
        args.extend(["--command-deadline-ms".into(), SMOKE_COMMAND_DEADLINE.as_millis().to_string()]);
        args.extend(connect.clone());
        agents.push(spawn("robot-agent", &args, &format!("robot-agent {r}"))?);
    }
    let mut args = vec!["smoke".to_string(), "--team".into(), cfg.team.clone(), "--robots".into(), cfg.robots.join(",")];
    args.extend(["--joints".into(), cfg.joints.to_string(), "--ticks".into(), cfg.ticks.to_string()]);
    args.extend(["--dt".into(), cfg.dt.to_string()]);
    args.extend(connect);
    let mut bridge = spawn("sim-bridge", &args, "sim-bridge")?;
    bridge.wait_success()?;
    Ok(())
}
