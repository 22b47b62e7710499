//! A simulated robot's agent: the robot's loop ([`crate::hardware::driver`], the same loop a
//! real robot runs) over the simulated robot ([`SimRobot`]) and the team over Zenoh
//! ([`ZenohLink`]), on a thread of its own. `robot-agent run` and every agent of `team run`
//! start it; every decision (checks, watchdog, safe mode, contact set, status) is the core's.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use protocol::transport::{Qos, TransportError};
use thiserror::Error;
use zenoh::Session;

pub use crate::core::{AgentConfig, AgentCore, CoreError, Outputs, Sent};
pub use crate::dynamics_source::{DynamicsSource, ModelDynamics, PlaceholderDynamics, SourceError};
pub use crate::gate::{CommandGate, CommandRejection};
use crate::hardware::driver::{self, DriverConfig, DriverError, DriverReport};
use crate::hardware::{Bell, SimRobot, ZenohLink};
pub use crate::safe_mode::{CommandDeadline, HoldGains, PostureHold, Watchdog};
pub use crate::status::AgentCounters;

/// Errors that stop the agent.
#[derive(Debug, Error)]
pub enum AgentError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Core(#[from] CoreError),
    #[error(transparent)]
    Driver(#[from] DriverError),
    #[error("the agent's thread: {0}")]
    Thread(String),
}

/// Run the agent of the simulated robot `cfg.robot` until `stop` is set, stalled while `stall`
/// is ([`driver::run_stallable`]). Blocks: call it from a thread outside any async runtime
/// (or use [`spawn`]). The robot's states are subscribed before it joins its team, so that
/// whoever sees it join can already reach it.
pub fn run<S: DynamicsSource>(
    session: &Session,
    cfg: AgentConfig,
    source: S,
    stop: &AtomicBool,
    stall: &AtomicBool,
) -> Result<DriverReport, AgentError> {
    run_ringing(session, cfg, source, stop, stall, Bell::new())
}

/// [`run`] on the loop's `bell`, which whoever sets `stop` rings so that the loop sees it at
/// once.
fn run_ringing<S: DynamicsSource>(
    session: &Session,
    cfg: AgentConfig,
    source: S,
    stop: &AtomicBool,
    stall: &AtomicBool,
    bell: Bell,
) -> Result<DriverReport, AgentError> {
    let mut core = AgentCore::new(&cfg, source)?;
    let (team, id) = (cfg.team.as_str(), cfg.robot.as_str());
    let mut robot = SimRobot::declare(session, team, id, core.joints(), bell.clone())?;
    // In lockstep the coordinator waits for every robot's terms: nothing may be dropped.
    let mut link = ZenohLink::declare_with_bell(session, team, id, Qos::HotPath, bell)?;
    tracing::info!(
        robot = %id,
        %team,
        joints = core.joints(),
        deadline = ?cfg.deadline,
        max_command_age = ?cfg.max_command_age,
        "agent joined the team"
    );
    // The simulator sets the pace; the period is not used.
    let rate = DriverConfig::new(Duration::from_millis(1));
    let report = driver::run_stallable(&mut core, &mut robot, &mut link, &rate, stop, stall)?;
    tracing::info!(robot = %id, counters = ?report.counters, "agent stopped");
    Ok(report)
}

/// A simulated robot's agent running on a thread of its own ([`spawn`]).
pub struct AgentThread {
    stop: Arc<AtomicBool>,
    stall: Arc<AtomicBool>,
    bell: Bell,
    handle: Option<JoinHandle<Result<DriverReport, AgentError>>>,
}

/// Start [`run`] on a thread named after the robot.
pub fn spawn<S: DynamicsSource + Send + 'static>(
    session: &Session,
    cfg: AgentConfig,
    source: S,
) -> Result<AgentThread, AgentError> {
    let stop = Arc::new(AtomicBool::new(false));
    let stall = Arc::new(AtomicBool::new(false));
    let bell = Bell::new();
    let (s, st, b, session) = (stop.clone(), stall.clone(), bell.clone(), session.clone());
    let handle = std::thread::Builder::new()
        .name(format!("agent-{}", cfg.robot))
        .spawn(move || run_ringing(&session, cfg, source, &s, &st, b))
        .map_err(|e| AgentError::Thread(e.to_string()))?;
    Ok(AgentThread { stop, stall, bell, handle: Some(handle) })
}

impl AgentThread {
    /// Ask the loop to stop: it does once the turn it is in ends.
    pub fn stop(&self) {
        self.stop.store(true, Ordering::Release);
        self.bell.ring();
    }

    /// Stall the agent (alive, handling nothing) or let it go on.
    pub fn stall(&self, on: bool) {
        self.stall.store(on, Ordering::Release);
    }

    /// Whether the loop has ended (stopped, or an error).
    pub fn is_finished(&self) -> bool {
        self.handle.as_ref().is_none_or(|h| h.is_finished())
    }

    /// Stop the loop and wait for its report.
    pub fn join(mut self) -> Result<DriverReport, AgentError> {
        self.stop();
        let handle = self.handle.take().ok_or_else(|| AgentError::Thread("joined".into()))?;
        handle.join().map_err(|_| AgentError::Thread("the agent's loop panicked".into()))?
    }
}

impl Drop for AgentThread {
    /// A handle dropped stops its loop and waits for it (a housekeeping period at most).
    fn drop(&mut self) {
        self.stop();
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}
