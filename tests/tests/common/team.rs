//! An embedded team for the message-flow tests: coordinator, agents and the lockstep bridge
//! on one Zenoh session, each with its own stop signal so that one can be taken away mid-run.
//! The plant and the agents' dynamics are the placeholders (the subject is the message flow,
//! not the physics).

use std::time::Duration;

use coordinator::service::{self, CoordinatorConfig};
use coordinator::TeamController;
use protocol::transport::{self, Role, ZenohArgs};
use robot_agent::core::AgentConfig;
use robot_agent::dynamics_source::PlaceholderDynamics;
use robot_agent::safe_mode::CommandDeadline;
use sim_bridge::lockstep::{self, BridgeError, LockstepConfig};
use sim_bridge::plant::PlaceholderPlant;
use tokio::sync::watch;
use tokio::task::JoinHandle;
use zenoh::Session;

/// Joints of every placeholder robot.
pub const JOINTS: usize = 3;

pub struct Component<T> {
    pub stop: watch::Sender<bool>,
    pub task: JoinHandle<T>,
}

pub fn coordinator(
    session: &Session,
    team: &str,
    controller: Box<dyn TeamController>,
) -> Component<service::CoordinatorCounters> {
    let (stop, rx) = watch::channel(false);
    let (s, cfg) = (session.clone(), CoordinatorConfig::lockstep(team, Duration::from_secs(5)));
    Component {
        stop,
        task: tokio::spawn(async move {
            service::run(&s, cfg, controller, rx).await.expect("coordinator runs")
        }),
    }
}

pub fn agent(
    session: &Session,
    team: &str,
    robot: &str,
) -> Component<robot_agent::status::AgentCounters> {
    // Lockstep: the agent's own time deadline must not be what ends a wait here.
    agent_with_deadline(
        session,
        team,
        robot,
        CommandDeadline { ticks: 5, time: Some(Duration::from_secs(30)) },
    )
}

/// An agent with its command deadline `deadline` (the real-time default is
/// `CommandDeadline::default()`: 5 ticks or 25 ms).
pub fn agent_with_deadline(
    session: &Session,
    team: &str,
    robot: &str,
    deadline: CommandDeadline,
) -> Component<robot_agent::status::AgentCounters> {
    let mut cfg = AgentConfig::new(team, robot);
    cfg.deadline = deadline;
    cfg.max_command_age = Duration::from_secs(30);
    agent_with_config(session, cfg)
}

/// The agent of `cfg.robot` on its own thread, over the placeholder dynamics.
pub fn agent_with_config(
    session: &Session,
    cfg: AgentConfig,
) -> Component<robot_agent::status::AgentCounters> {
    let (stop, mut rx) = watch::channel(false);
    let agent = robot_agent::agent::spawn(session, cfg, PlaceholderDynamics::floating(JOINTS))
        .expect("agent starts");
    Component {
        stop,
        task: tokio::spawn(async move {
            // The agent's loop runs on its own thread: this task only carries the stop.
            let _ = rx.wait_for(|s| *s).await;
            let report = tokio::task::spawn_blocking(move || agent.join()).await;
            report.expect("agent joins").expect("agent runs").counters
        }),
    }
}

pub fn lockstep_cfg(team: &str, ticks: u64, grace: u64) -> LockstepConfig {
    LockstepConfig {
        team: team.into(),
        ticks,
        start_timeout: Duration::from_secs(20),
        // Far longer than any test waits: a run that ends, ends for another reason.
        command_timeout: Duration::from_secs(60),
        resend_every: Duration::from_millis(50),
        progress_every: 0,
        // As the scenario runs do: the first tick only once the coordinator lists every robot
        // as a member (terms that reach it before a robot's liveliness token are not a tick it
        // commands, and the agent would wait out its time deadline).
        wait_for_coordinator: true,
        coordinator_grace_ticks: grace,
        agent_loss: sim_bridge::lockstep::AgentLoss::EndRun,
        drive_timeout: sim_bridge::lockstep::DEFAULT_DRIVE_TIMEOUT,
    }
}

pub fn bridge(
    session: &Session,
    team: &str,
    robots: &[&str],
    ticks: u64,
    grace: u64,
) -> Component<Result<lockstep::LockstepReport, BridgeError>> {
    let (stop, rx) = watch::channel(false);
    let cfg = lockstep_cfg(team, ticks, grace);
    let mut plant =
        PlaceholderPlant::new(robots.iter().map(|r| r.to_string()).collect(), JOINTS, 0.1, 0.001);
    let s = session.clone();
    Component {
        stop,
        task: tokio::spawn(async move { lockstep::run(&s, &cfg, &mut plant, rx).await }),
    }
}

pub async fn session() -> Session {
    transport::open(&ZenohArgs::default(), Role::Alone).await.expect("session")
}

pub async fn stop<T>(c: Component<T>) -> T {
    let _ = c.stop.send(true);
    tokio::time::timeout(Duration::from_secs(10), c.task)
        .await
        .expect("stops in time")
        .expect("task")
}
