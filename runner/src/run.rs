//! `team run SCENARIO`: the whole stack on one scenario. Embedded (default): the sim-bridge,
//! one robot-agent per robot (the robot's own model), the coordinator (the scenario's
//! controller, built from the plan's `ControllerSpec`) and the scenario driver are tasks of
//! this process on one Zenoh session. Distributed: each is its own process on loopback (the
//! coordinator listens, the rest connect), started from the files this run writes into the
//! report folder (`scene.toml`, `controller.toml`: the spec, `kind` first). Either way every
//! message goes over Zenoh and the same [`crate::plan::Plan`] is simulated.

use std::path::Path;
use std::time::{Duration, Instant};

use coordinator::service::{self as coordinator_service, CoordinatorConfig};
use protocol::transport::{self, Role, ZenohArgs};
use robot_agent::agent::{self as agent_loop, AgentConfig};
use robot_agent::dynamics_source::ModelDynamics;
use thiserror::Error;
use tokio::sync::watch;

use crate::driver::{Driver, Records};
use crate::plan::{Plan, TEAM};
use crate::processes::{free_port, spawn, ProcessError};

/// In lockstep, an agent waits this long for its command before it holds its posture: a tick
/// that is merely slow (a loaded machine) must not see safe-mode torques.
pub const AGENT_COMMAND_DEADLINE: Duration = Duration::from_secs(20);
/// The coordinator abandons a tick whose terms are incomplete after this long.
pub const COORDINATOR_TICK_DEADLINE: Duration = Duration::from_secs(20);

/// Errors of a run.
#[derive(Debug, Error)]
pub enum RunError {
    #[error(transparent)]
    Transport(#[from] protocol::transport::TransportError),
    #[error(transparent)]
    Scene(#[from] sim_bridge::scene::SceneError),
    #[error(transparent)]
    World(#[from] sim_bridge::world::WorldError),
    #[error("robot {robot}: {reason}")]
    Agent { robot: String, reason: String },
    #[error(transparent)]
    Process(#[from] ProcessError),
    #[error("writing {path}: {reason}")]
    Write { path: String, reason: String },
    #[error("the run ended after {seen} of {expected} ticks")]
    Incomplete { seen: u64, expected: u64 },
    #[error("controller configuration: {0}")]
    Controller(#[from] coordinator::ControllerError),
    #[error("{what}: {reason}")]
    Task { what: String, reason: String },
}

/// How to run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub distributed: bool,
    /// A progress bar (terminal) or progress log lines.
    pub progress: bool,
}

/// Run the plan; `out` is the report folder (the distributed run writes its component files
/// there).
pub fn run(plan: &Plan, opts: &RunOptions, out: &Path) -> Result<Records, RunError> {
    let rt = tokio::runtime::Runtime::new().map_err(|e| RunError::Task { what: "starting the async runtime".into(), reason: e.to_string() })?;
    let records = if opts.distributed { rt.block_on(run_distributed(plan, opts, out))? } else { rt.block_on(run_embedded(plan, opts))? };
    if records.ticks_seen < plan.total_ticks() {
        return Err(RunError::Incomplete { seen: records.ticks_seen, expected: plan.total_ticks() });
    }
    Ok(records)
}

/// Every component a task of this process, on one session.
pub async fn run_embedded(plan: &Plan, opts: &RunOptions) -> Result<Records, RunError> {
    let controller = plan.controller.build()?;
    let session = transport::open(&ZenohArgs::default(), Role::Alone).await?;
    let (stop_tx, stop_rx) = watch::channel(false);
    let driver = Driver::start(&session, plan.references.clone(), plan.total_ticks(), opts.progress).await?;

    let coordinator = {
        let session = session.clone();
        let rx = stop_rx.clone();
        let cfg = CoordinatorConfig { team: TEAM.into(), tick_deadline: COORDINATOR_TICK_DEADLINE };
        tokio::spawn(async move { coordinator_service::run(&session, cfg, controller, rx).await })
    };
    let mut agents = Vec::new();
    for r in &plan.robots {
        let id = &r.id;
        let source = ModelDynamics::shared(r.robot.clone()).map_err(|e| RunError::Agent { robot: id.clone(), reason: e.to_string() })?;
        let acfg = AgentConfig::new(TEAM, id).with_deadline_time(AGENT_COMMAND_DEADLINE);
        let session = session.clone();
        let rx = stop_rx.clone();
        agents.push((id.clone(), tokio::spawn(async move { agent_loop::run(&session, acfg, source, rx).await })));
    }
    let driver_task = tokio::spawn(driver.run(stop_rx.clone()));
    let bridge = sim_bridge::scene::run(&session, &plan.scene, &plan.loaded_robots(), stop_rx.clone()).await;
    if bridge.is_err() {
        let _ = stop_tx.send(true);
    }
    let records = driver_task.await.map_err(|e| RunError::Task { what: "the scenario driver".into(), reason: e.to_string() })?;
    let _ = stop_tx.send(true);
    let _ = coordinator.await;
    for (robot, handle) in agents {
        if let Ok(Err(e)) = handle.await {
            return Err(RunError::Agent { robot, reason: e.to_string() });
        }
    }
    let _ = session.close().await;
    bridge?;
    Ok(records?)
}

/// Every component its own process on loopback; this process runs the scenario driver.
pub async fn run_distributed(plan: &Plan, opts: &RunOptions, out: &Path) -> Result<Records, RunError> {
    let scene_path = out.join("scene.toml");
    plan.scene.save(&scene_path)?;
    let controller_path = out.join("controller.toml");
    let text = plan.controller.to_toml()?;
    std::fs::write(&controller_path, text).map_err(|e| RunError::Write { path: controller_path.display().to_string(), reason: e.to_string() })?;

    let hub = format!("tcp/127.0.0.1:{}", free_port()?);
    let connect = ZenohArgs::connecting(&hub).to_cli();
    let s = |x: &str| x.to_string();
    // The controller file names its kind and parameters: the one way to choose it.
    let mut args = vec![s("run"), s("--team"), s(TEAM), s("--controller-config"), controller_path.display().to_string()];
    args.extend([s("--tick-deadline-ms"), COORDINATOR_TICK_DEADLINE.as_millis().to_string()]);
    args.extend(ZenohArgs::listening(&hub).to_cli());
    let _coordinator = spawn("coordinator", &args, "coordinator")?;

    let session = transport::open(&ZenohArgs::connecting(&hub), Role::Member).await?;
    let (stop_tx, stop_rx) = watch::channel(false);
    let driver = Driver::start(&session, plan.references.clone(), plan.total_ticks(), opts.progress).await?;
    let mut agents = Vec::new();
    for r in &plan.robots {
        let id = &r.id;
        let mut args = vec![s("run"), s("--team"), s(TEAM), s("--id"), id.clone(), s("--robot"), r.description.display().to_string()];
        args.extend([s("--command-deadline-ms"), AGENT_COMMAND_DEADLINE.as_millis().to_string()]);
        args.extend(connect.clone());
        agents.push(spawn("robot-agent", &args, &format!("robot-agent {id}"))?);
    }
    let mut args = vec![s("scene"), scene_path.display().to_string()];
    args.extend(connect.clone());
    let mut bridge = spawn("sim-bridge", &args, "sim-bridge")?;
    let driver_task = tokio::spawn(driver.run(stop_rx));
    // The bridge process ends the run: successfully after the last tick, or with an error.
    let started = Instant::now();
    let bridge_result = tokio::task::spawn_blocking(move || {
        let r = bridge.wait_success();
        (r, bridge)
    })
    .await
    .map_err(|e| RunError::Task { what: "waiting for the sim-bridge process".into(), reason: e.to_string() })?;
    // Give the driver a moment for the last messages, then stop it.
    tokio::time::sleep(Duration::from_millis(200)).await;
    let _ = stop_tx.send(true);
    let records = driver_task.await.map_err(|e| RunError::Task { what: "the scenario driver".into(), reason: e.to_string() })??;
    tracing::debug!(wall = ?started.elapsed(), "distributed run ended");
    let _ = session.close().await;
    bridge_result.0?;
    Ok(records)
}
