//! One launcher for every run of the team, embedded or distributed, smoke or scenario.
//!
//! A run is three kinds of component, each described by typed arguments:
//! [`CoordinatorArgs`] (team, tick deadline, the controller as a [`ControllerSpec`]),
//! one [`AgentArgs`] per robot (its id, its model or placeholder dynamics, its command
//! deadline) and one [`BridgeArgs`] (the state source: a MuJoCo scene or the smoke run's
//! placeholder plant). [`Launch::start`] starts the coordinator and the agents in the chosen
//! [`RunMode`]:
//!
//! * [`RunMode::Embedded`]: every component is a task of this process on one Zenoh session;
//! * [`RunMode::Distributed`]: every component is its own process on loopback (the coordinator
//!   listens on a free port, the others connect), or on its own test host
//!   ([`RunMode::Hosts`], `crate::hosts`), started with the command line that
//!   [`CoordinatorArgs::to_cli`], [`AgentArgs::to_cli`] and [`BridgeArgs::to_cli`] write from
//!   the same values; files they need (the controller spec, the scene) go into the run's
//!   folder;
//! * [`RunMode::Tls`]: as [`RunMode::Distributed`], over mutual TLS with the team's access control
//!   (`protocol::access`): each process gets a Zenoh configuration with its identity's
//!   certificate, written into the run's folder; [`RunMode::Hosts`] with certificates does the
//!   same across test hosts.
//! * [`RunMode::Site`]: as [`RunMode::Distributed`], every process a client of a site's Zenoh
//!   router (`protocol::site`), which may carry other teams too.
//!
//! The caller then declares what it observes on [`Running::session`] (the scenario driver),
//! runs the state source to its end with [`Running::run_bridge`] (it ends the run: after its
//! last tick, or with an error that names who is missing) and stops everything with
//! [`Running::finish`], which reports the first component that failed. Either way every
//! message crosses Zenoh, and the lockstep makes both modes compute the same numbers.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use coordinator::service::{self as coordinator_service, CoordinatorConfig};
use coordinator::team::assembly::TermsReuse;
use coordinator::ControllerSpec;
use protocol::access::{secure_endpoint, Identity, SecureConfig};
use protocol::transport::{self, Role, ZenohArgs};
use robot_agent::agent::{self as agent_loop, AgentConfig};
use robot_agent::drive_gains::DriveGainsMode;
use robot_agent::dynamics_source::{ModelDynamics, PlaceholderDynamics};
use robot_model::Robot;
use sim_bridge::lockstep::{self, LockstepConfig, LockstepReport};
use sim_bridge::plant::PlaceholderPlant;
use sim_bridge::scene::{Scene, SceneReport};
use thiserror::Error;
use tokio::sync::watch;
use tokio::task::JoinHandle;
use zenoh::Session;

use crate::hosts::TestHosts;
use crate::processes::{free_port, spawn, spawn_on, ChildGuard, ProcessError};

/// Why a run could not be launched or ended badly.
#[derive(Debug, Error)]
pub enum LaunchError {
    #[error(transparent)]
    Transport(#[from] protocol::transport::TransportError),
    #[error(transparent)]
    Process(#[from] ProcessError),
    #[error("controller: {0}")]
    Controller(#[from] coordinator::ControllerError),
    #[error(transparent)]
    Scene(#[from] sim_bridge::scene::SceneError),
    #[error(transparent)]
    World(#[from] sim_bridge::world::WorldError),
    #[error(transparent)]
    Lockstep(#[from] sim_bridge::lockstep::BridgeError),
    #[error("robot {robot}: {reason}")]
    Agent { robot: String, reason: String },
    #[error("{0}")]
    Hosts(String),
    #[error("the coordinator: {0}")]
    Coordinator(String),
    #[error("writing {path}: {reason}")]
    Write { path: String, reason: String },
    #[error("{what}: {reason}")]
    Task { what: String, reason: String },
    #[error("access control: {0}")]
    Access(#[from] protocol::access::AccessError),
}

/// Where the components run.
#[derive(Debug, Clone)]
pub enum RunMode {
    /// Tasks of this process on one Zenoh session.
    Embedded,
    /// Processes on loopback; `dir` receives the files they read (controller spec, scene).
    Distributed { dir: PathBuf },
    /// Processes on test hosts (`crate::hosts`): the coordinator on host `coordinator`, each
    /// agent on the host named after its robot, the sim-bridge on host `sim`; this process
    /// (the scenario driver) reaches them through the hosts' bridge. With `certs`, over mutual
    /// TLS with the team's access control as [`RunMode::Tls`], the certificates naming the hosts'
    /// addresses ([`TestHosts::issue_certs`]).
    Hosts { dir: PathBuf, hosts: Arc<TestHosts>, certs: Option<PathBuf> },
    /// Processes on loopback over mutual TLS with the team's access control: the identities'
    /// certificates are in `certs` (`scripts/make-test-certs.sh CERTS ROBOT...`), and each
    /// process's Zenoh configuration is written to `dir`. This process is the `runner`.
    Tls { dir: PathBuf, certs: PathBuf },
    /// Processes on loopback, each a Zenoh client of a site's router at `router`
    /// ([`protocol::site`]), with the team's site certificates in `certs`
    /// (`scripts/make-test-certs.sh --ca SITE --team TEAM CERTS ROBOT...`); each process's
    /// configuration is written to `dir`. Several teams share the router by their names.
    Site { dir: PathBuf, certs: PathBuf, router: String },
}

/// The team a Zenoh configuration with access control is written for.
struct TeamIds {
    team: String,
    robots: Vec<String>,
}

/// The test host names of a team: the coordinator, each robot, the sim-bridge.
pub fn host_names(robots: &[String]) -> Vec<String> {
    let mut names = vec![COORDINATOR_HOST.to_string()];
    names.extend(robots.iter().cloned());
    names.push(SIM_HOST.to_string());
    names
}

pub const COORDINATOR_HOST: &str = "coordinator";
pub const SIM_HOST: &str = "sim";
/// The coordinator's port on its host (every host has its own ports).
pub const HUB_PORT: u16 = 7447;

impl RunMode {
    /// A run on this computer's loopback: over mutual TLS when `certs` names the identities'
    /// certificates, else as processes when `distributed`, else embedded; `dir` receives the
    /// processes' files.
    pub fn on_loopback(distributed: bool, certs: Option<&Path>, dir: &Path) -> RunMode {
        match certs {
            Some(certs) => RunMode::Tls { dir: dir.to_path_buf(), certs: certs.to_path_buf() },
            None if distributed => RunMode::Distributed { dir: dir.to_path_buf() },
            None => RunMode::Embedded,
        }
    }

    /// `"embedded"`, `"distributed"`, `"hosts"`, `"hosts-tls"` or `"distributed-tls"`, as
    /// reports name it.
    pub fn name(&self) -> &'static str {
        match self {
            RunMode::Embedded => "embedded",
            RunMode::Distributed { .. } => "distributed",
            RunMode::Hosts { certs: None, .. } => "hosts",
            RunMode::Hosts { certs: Some(_), .. } => "hosts-tls",
            RunMode::Tls { .. } => "distributed-tls",
            RunMode::Site { .. } => "site",
        }
    }

    /// The coordinator's endpoint, which the other processes connect to: a free loopback
    /// port, or [`HUB_PORT`] on the coordinator's host.
    fn hub(&self) -> Result<String, LaunchError> {
        match self {
            RunMode::Hosts { hosts, certs, .. } => {
                let addr =
                    hosts.addr(COORDINATOR_HOST).map_err(|e| LaunchError::Hosts(e.to_string()))?;
                Ok(if certs.is_some() {
                    secure_endpoint(addr, HUB_PORT)
                } else {
                    format!("tcp/{addr}:{HUB_PORT}")
                })
            }
            RunMode::Tls { .. } => Ok(secure_endpoint("127.0.0.1", free_port()?)),
            RunMode::Site { router, .. } => Ok(router.clone()),
            _ => Ok(format!("tcp/127.0.0.1:{}", free_port()?)),
        }
    }

    /// The Zenoh arguments of a process on `host` (`None`: this one) connecting to `hub`.
    fn zenoh_args(
        &self,
        host: Option<&str>,
        hub: &str,
        ids: &TeamIds,
    ) -> Result<ZenohArgs, LaunchError> {
        match self {
            RunMode::Hosts { hosts, certs: None, .. } => {
                hosts.zenoh_args(host, hub).map_err(|e| LaunchError::Hosts(e.to_string()))
            }
            RunMode::Hosts { dir, hosts, certs: Some(certs) } => {
                let addr =
                    hosts.listen_addr(host).map_err(|e| LaunchError::Hosts(e.to_string()))?;
                secure_args(
                    dir,
                    certs,
                    ids,
                    identity_of(host),
                    &secure_endpoint(addr, 0),
                    Some(hub),
                )
            }
            RunMode::Tls { dir, certs } => secure_args(
                dir,
                certs,
                ids,
                identity_of(host),
                &secure_endpoint("127.0.0.1", 0),
                Some(hub),
            ),
            RunMode::Site { dir, certs, router } => {
                site_args(dir, certs, &ids.team, identity_of(host), router)
            }
            _ => Ok(ZenohArgs::connecting(hub)),
        }
    }

    /// The session of this process (the scenario driver's), a member connecting to `hub`, and
    /// where a tool on this machine reaches the team: on loopback without access control it
    /// also listens on the tools' endpoint if it can ([`transport::open_discoverable`]), else
    /// the hub is the place. Test hosts, TLS and sites name their endpoints themselves.
    async fn open_driver(
        &self,
        hub: &str,
        ids: &TeamIds,
    ) -> Result<(Session, Option<String>), LaunchError> {
        let args = self.zenoh_args(None, hub, ids)?;
        if !matches!(self, RunMode::Distributed { .. }) {
            return Ok((transport::open(&args, Role::Member).await?, None));
        }
        let (session, endpoint) = transport::open_discoverable(&args, Role::Member).await?;
        Ok((session, Some(endpoint.unwrap_or_else(|| hub.to_string()))))
    }

    /// The Zenoh arguments of the coordinator, which listens on `hub`.
    fn hub_args(&self, hub: &str, ids: &TeamIds) -> Result<ZenohArgs, LaunchError> {
        match self {
            RunMode::Tls { dir, certs } | RunMode::Hosts { dir, certs: Some(certs), .. } => {
                secure_args(dir, certs, ids, Identity::Coordinator, hub, None)
            }
            RunMode::Site { dir, certs, router } => {
                site_args(dir, certs, &ids.team, Identity::Coordinator, router)
            }
            _ => Ok(ZenohArgs::listening(hub)),
        }
    }

    /// Start one of the team's binaries: on `host` with test hosts, else on this machine.
    fn spawn(
        &self,
        host: &str,
        bin: &str,
        args: &[String],
        what: &str,
    ) -> Result<ChildGuard, ProcessError> {
        match self {
            RunMode::Hosts { hosts, .. } => spawn_on(hosts, host, bin, args, what),
            _ => spawn(bin, args, what),
        }
    }
}

/// The identity of a process on `host` (`None`: this one, the scenario driver) that is not the
/// coordinator.
fn identity_of(host: Option<&str>) -> Identity {
    match host {
        None => Identity::Runner,
        Some(SIM_HOST) => Identity::SimBridge,
        Some(robot) => Identity::Agent(robot.to_string()),
    }
}

/// Write `identity`'s Zenoh configuration (mutual TLS, the team's ACL) into `dir` and return
/// the arguments that use it.
fn secure_args(
    dir: &Path,
    certs: &Path,
    ids: &TeamIds,
    identity: Identity,
    listen: &str,
    connect: Option<&str>,
) -> Result<ZenohArgs, LaunchError> {
    let mut cfg = SecureConfig::in_dir(certs, &ids.team, &ids.robots, identity);
    cfg.listen = vec![listen.to_string()];
    cfg.connect = connect.map(|c| vec![c.to_string()]).unwrap_or_default();
    let path = dir.join(protocol::access::file_name(&cfg.identity));
    cfg.write(&path)?;
    Ok(ZenohArgs { config: Some(path), ..Default::default() })
}

/// Write `identity`'s configuration as a client of the site's router into `dir` and return
/// the arguments that use it.
fn site_args(
    dir: &Path,
    certs: &Path,
    team: &str,
    identity: Identity,
    router: &str,
) -> Result<ZenohArgs, LaunchError> {
    let cfg = protocol::site::ClientConfig::in_dir(certs, team, identity, router);
    let path = dir.join(protocol::access::file_name(&cfg.identity));
    cfg.write(&path)?;
    Ok(ZenohArgs { config: Some(path), ..Default::default() })
}

/// The coordinator of a run.
#[derive(Debug, Clone)]
pub struct CoordinatorArgs {
    pub team: String,
    /// How long a tick may wait for every member's dynamics terms.
    pub tick_deadline: Duration,
    /// Real time: reuse a late member's latest terms (`coordinator::team::assembly::TermsReuse`).
    pub reuse: Option<TermsReuse>,
    /// The team's robots: the first tick waits for all of them (bounded), which a restarted
    /// coordinator needs (`coordinator::team::membership::Roster::expect`).
    pub expected: Vec<String>,
    pub controller: ControllerSpec,
    /// The robots' control rate: with a team delay, states are carried over the commands in
    /// flight (`coordinator::team::prediction`); `None` answers each state as measured.
    pub robot_hz: Option<f64>,
    /// A driver sends the references: the robots hold until the first came, at most this
    /// long (`coordinator::service::CoordinatorConfig::wait_for_references`).
    pub wait_for_references: Option<Duration>,
    /// Real time: how long a tick's solve may take before the fallback answers
    /// (`coordinator::service::CoordinatorConfig::solve_budget`).
    pub solve_budget: Option<Duration>,
}

impl CoordinatorArgs {
    /// `coordinator run ...` for this coordinator; the controller spec is written to
    /// `dir/controller.toml` (its `kind` and parameters: the one way a file chooses it).
    pub fn to_cli(&self, dir: &Path, zenoh: &ZenohArgs) -> Result<Vec<String>, LaunchError> {
        let path = dir.join("controller.toml");
        let text = self.controller.to_toml()?;
        std::fs::write(&path, text).map_err(|e| LaunchError::Write {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        let mut args = vec![
            "run".into(),
            "--team".into(),
            self.team.clone(),
            "--controller-config".into(),
            path.display().to_string(),
        ];
        args.extend(["--tick-deadline-ms".into(), self.tick_deadline.as_millis().to_string()]);
        if let Some(r) = self.reuse {
            args.extend([
                "--reuse-after-us".into(),
                r.after.as_micros().to_string(),
                "--reuse-max-age".into(),
                r.max_age.to_string(),
            ]);
        }
        if !self.expected.is_empty() {
            args.extend(["--expect".into(), self.expected.join(",")]);
        }
        if let Some(hz) = self.robot_hz {
            args.extend(["--robot-hz".into(), hz.to_string()]);
        }
        if let Some(w) = self.wait_for_references {
            args.extend(["--wait-for-references-ms".into(), w.as_millis().max(1).to_string()]);
        }
        if let Some(b) = self.solve_budget {
            args.extend(["--solve-budget-us".into(), b.as_micros().max(1).to_string()]);
        }
        args.extend(zenoh.to_cli());
        Ok(args)
    }

    fn start_task(
        &self,
        session: &Session,
        stop: watch::Receiver<bool>,
        _stall: watch::Receiver<bool>,
    ) -> Result<JoinHandle<Result<(), String>>, LaunchError> {
        let controller = self.controller.build()?;
        let cfg = CoordinatorConfig {
            team: self.team.clone(),
            tick_deadline: self.tick_deadline,
            reuse: self.reuse,
            expected: self.expected.clone(),
            robot_hz: self.robot_hz,
            wait_for_references: self.wait_for_references,
            solve_budget: self.solve_budget,
        };
        let session = session.clone();
        Ok(tokio::spawn(async move {
            coordinator_service::run(&session, cfg, controller, stop)
                .await
                .map(|_| ())
                .map_err(|e| e.to_string())
        }))
    }
}

/// What an agent computes its dynamics terms from.
#[derive(Debug, Clone)]
pub enum AgentModel {
    /// The robot's own model; `description` is the file it was loaded from (what a separate
    /// process loads again).
    Robot { robot: Arc<Robot>, description: PathBuf },
    /// The smoke run's placeholder dynamics: a floating base and `joints` unit-inertia joints.
    Placeholder { joints: usize },
}

/// One robot's agent.
#[derive(Debug, Clone)]
pub struct AgentArgs {
    pub team: String,
    pub id: String,
    pub model: AgentModel,
    /// Without a valid command for this long the agent holds its posture (safe mode).
    pub command_deadline: Duration,
    /// Or for this many state ticks; a command more ticks behind the latest state is refused.
    pub command_deadline_ticks: u64,
    /// The gains sent to the drives with each command.
    pub drive_gains: DriveGainsMode,
    /// The team answers every this many state ticks.
    pub team_every: u64,
    /// The team's command for a state applies this many state ticks later.
    pub team_delay: robot_agent::delay::TeamDelay,
    /// The robot's drives take an answer within this long of its state (`None`: they wait).
    pub answer_within: Option<Duration>,
}

impl AgentArgs {
    /// `robot-agent run ...` for this agent.
    pub fn to_cli(&self, zenoh: &ZenohArgs) -> Vec<String> {
        let mut args =
            vec!["run".into(), "--team".into(), self.team.clone(), "--id".into(), self.id.clone()];
        match &self.model {
            AgentModel::Robot { description, .. } => {
                args.extend(["--robot".into(), description.display().to_string()])
            }
            AgentModel::Placeholder { joints } => {
                args.extend(["--placeholder-joints".into(), joints.to_string()])
            }
        }
        args.extend([
            "--command-deadline-ms".into(),
            self.command_deadline.as_millis().to_string(),
        ]);
        args.extend(["--command-deadline-ticks".into(), self.command_deadline_ticks.to_string()]);
        args.extend(["--drive-gains".into(), self.drive_gains.to_string()]);
        args.extend(["--team-every".into(), self.team_every.to_string()]);
        args.extend(["--team-delay".into(), self.team_delay.to_string()]);
        if let Some(w) = self.answer_within {
            args.extend(["--answer-within-us".into(), w.as_micros().to_string()]);
        }
        args.extend(zenoh.to_cli());
        args
    }

    fn start_task(
        &self,
        session: &Session,
        stop: watch::Receiver<bool>,
        stall: watch::Receiver<bool>,
    ) -> Result<JoinHandle<Result<(), String>>, LaunchError> {
        let mut cfg = AgentConfig::new(&self.team, &self.id)
            .with_deadline_time(self.command_deadline)
            .with_deadline_ticks(self.command_deadline_ticks);
        cfg.drive_gains = self.drive_gains;
        cfg.team_every = self.team_every;
        cfg.team_delay = self.team_delay;
        cfg.answer_within = self.answer_within;
        let agent = match &self.model {
            AgentModel::Robot { robot, .. } => {
                let source = ModelDynamics::shared(robot.clone()).map_err(|e| {
                    LaunchError::Agent { robot: self.id.clone(), reason: e.to_string() }
                })?;
                agent_loop::spawn(session, cfg, source)
            }
            AgentModel::Placeholder { joints } => {
                agent_loop::spawn(session, cfg, PlaceholderDynamics::floating(*joints))
            }
        }
        .map_err(|e| LaunchError::Agent { robot: self.id.clone(), reason: e.to_string() })?;
        Ok(tokio::spawn(watch_agent(agent, stop, stall)))
    }
}

/// Hand the task's stop and stall signals to the agent's thread until it stops or ends on its
/// own, then its outcome.
async fn watch_agent(
    agent: agent_loop::AgentThread,
    mut stop: watch::Receiver<bool>,
    mut stall: watch::Receiver<bool>,
) -> Result<(), String> {
    let mut poll = tokio::time::interval(Duration::from_millis(50));
    let mut stall_open = true;
    while !*stop.borrow_and_update() && !agent.is_finished() {
        agent.stall(*stall.borrow_and_update());
        tokio::select! {
            r = stop.changed() => if r.is_err() { break },
            r = stall.changed(), if stall_open => stall_open = r.is_ok(),
            _ = poll.tick() => {}
        }
    }
    // At once, not from the blocking pool's thread: a killed agent answers nothing more.
    agent.stop();
    let joined = tokio::task::spawn_blocking(move || agent.join()).await;
    joined.map_err(|e| e.to_string())?.map(|_| ()).map_err(|e| e.to_string())
}

/// The smoke run's state source: placeholder joints (`qdd = tau`), one per robot, in lockstep.
#[derive(Debug, Clone)]
pub struct SmokePlant {
    pub team: String,
    pub robots: Vec<String>,
    pub joints: usize,
    pub ticks: u64,
    /// Control period, s.
    pub dt: f64,
    /// Initial joint velocity, rad/s.
    pub v0: f64,
}

/// The state source of a run: it numbers the ticks and ends the run (see `protocol::clock`).
#[derive(Debug, Clone)]
pub enum BridgeArgs {
    /// A MuJoCo scene (world, pushes, settle and run lengths) with the robots already loaded.
    Scene {
        scene: Box<Scene>,
        robots: Vec<Arc<Robot>>,
    },
    Smoke(SmokePlant),
}

impl BridgeArgs {
    /// `sim-bridge scene FILE ...` (the scene written to `dir/scene.toml`) or
    /// `sim-bridge smoke ...`.
    pub fn to_cli(&self, dir: &Path, zenoh: &ZenohArgs) -> Result<Vec<String>, LaunchError> {
        let mut args: Vec<String> = match self {
            BridgeArgs::Scene { scene, .. } => {
                let path = dir.join("scene.toml");
                scene.save(&path)?;
                vec!["scene".into(), path.display().to_string()]
            }
            BridgeArgs::Smoke(p) => vec![
                "smoke".into(),
                "--team".into(),
                p.team.clone(),
                "--robots".into(),
                p.robots.join(","),
                "--joints".into(),
                p.joints.to_string(),
                "--ticks".into(),
                p.ticks.to_string(),
                "--dt".into(),
                p.dt.to_string(),
                "--v0".into(),
                p.v0.to_string(),
            ],
        };
        args.extend(zenoh.to_cli());
        Ok(args)
    }
}

/// What the state source reported at the end of the run.
#[derive(Debug, Clone)]
pub enum BridgeOutcome {
    Scene(SceneReport),
    /// The smoke plant's lockstep report and each robot's final first-joint velocity.
    Smoke {
        report: LockstepReport,
        final_velocities: Vec<f64>,
    },
    /// A separate sim-bridge process ended successfully (its figures are in its log).
    Process,
}

/// A team to launch: its coordinator and its agents.
#[derive(Debug, Clone)]
pub struct Launch {
    pub coordinator: CoordinatorArgs,
    pub agents: Vec<AgentArgs>,
}

/// A started team: the session to observe it on, and its components.
pub struct Running {
    session: Session,
    stop_tx: watch::Sender<bool>,
    stop_rx: watch::Receiver<bool>,
    mode: RunMode,
    /// Distributed: the Zenoh arguments of the sim-bridge (the coordinator's endpoint, which
    /// the others connect to; on test hosts also the bridge host's own endpoint).
    connect: ZenohArgs,
    /// The coordinator, then each agent by robot id (what faults kill, stall and restart).
    components: Vec<(String, Component)>,
    /// Where a client on this machine reaches the team ([`Running::endpoint`]).
    endpoint: Option<String>,
}

/// The name [`Running::component`] gives the coordinator.
pub const COORDINATOR: &str = "coordinator";

type TaskHandle = JoinHandle<Result<(), String>>;
type TaskStarter = Box<
    dyn Fn(watch::Receiver<bool>, watch::Receiver<bool>) -> Result<TaskHandle, LaunchError> + Send,
>;

/// One component of a running team, the coordinator or an agent, as a task of this process or
/// as a child process, that a fault can kill, stall and start again ([`crate::faults`]). Cheap
/// to clone; every clone controls the same component.
#[derive(Clone)]
pub struct Component(Arc<std::sync::Mutex<ComponentState>>);

struct ComponentState {
    what: String,
    /// The run's stop signal: a component started again stops with the run.
    run_stop: watch::Receiver<bool>,
    starter: Starter,
    /// The running incarnation, if any.
    live: Option<Live>,
    /// Tasks of earlier incarnations that ended (killed): their results are still reported.
    ended: Vec<TaskHandle>,
}

/// How a component is started (again).
enum Starter {
    Task(TaskStarter),
    Process { mode: RunMode, host: String, bin: String, args: Vec<String> },
}

/// A running incarnation.
enum Live {
    /// A task with its own stop and stall signals.
    Task {
        handle: TaskHandle,
        stop: Arc<watch::Sender<bool>>,
        stall: watch::Sender<bool>,
    },
    Process(ChildGuard),
}

impl Component {
    fn new(
        what: &str,
        run_stop: &watch::Receiver<bool>,
        starter: Starter,
    ) -> Result<Self, LaunchError> {
        let c = Component(Arc::new(std::sync::Mutex::new(ComponentState {
            what: what.to_string(),
            run_stop: run_stop.clone(),
            starter,
            live: None,
            ended: Vec::new(),
        })));
        c.start()?;
        Ok(c)
    }

    fn state(&self) -> std::sync::MutexGuard<'_, ComponentState> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Start it (again); an error if it is running.
    pub fn start(&self) -> Result<(), LaunchError> {
        let mut st = self.state();
        if st.live.is_some() {
            return Err(LaunchError::Task {
                what: st.what.clone(),
                reason: "already running".into(),
            });
        }
        let live = match &st.starter {
            Starter::Task(start) => {
                let (stop, stop_rx) = own_stop(&st.run_stop);
                let (stall, stall_rx) = watch::channel(false);
                Live::Task { handle: start(stop_rx, stall_rx)?, stop, stall }
            }
            Starter::Process { mode, host, bin, args } => {
                Live::Process(mode.spawn(host, bin, args, &st.what)?)
            }
        };
        st.live = Some(live);
        Ok(())
    }

    /// Kill it: a task is told to stop, a process gets SIGKILL (no goodbye: its Zenoh session
    /// just ends). Nothing if it is not running.
    pub fn kill(&self) {
        let mut st = self.state();
        match st.live.take() {
            Some(Live::Task { handle, stop, .. }) => {
                let _ = stop.send(true);
                st.ended.push(handle);
            }
            // Dropping the guard kills the process and reaps it.
            Some(Live::Process(child)) => drop(child),
            None => {}
        }
    }

    /// Stall it (`true`) or let it go on (`false`): it stays alive, its liveliness token held,
    /// but handles nothing (a task pauses; a process gets SIGSTOP, then SIGCONT).
    pub fn stall(&self, on: bool) -> Result<(), LaunchError> {
        let st = self.state();
        match &st.live {
            Some(Live::Task { stall, .. }) => {
                let _ = stall.send(on);
                Ok(())
            }
            Some(Live::Process(child)) => {
                signal(child.child.id(), if on { "-STOP" } else { "-CONT" })
                    .map_err(|reason| LaunchError::Task { what: st.what.clone(), reason })
            }
            None => Err(LaunchError::Task { what: st.what.clone(), reason: "not running".into() }),
        }
    }

    /// Stop it for good, waiting for its tasks: the first task that failed is the error.
    async fn finish(&self) -> Result<(), String> {
        let (live, ended) = {
            let mut st = self.state();
            (st.live.take(), std::mem::take(&mut st.ended))
        };
        let mut handles = ended;
        match live {
            Some(Live::Task { handle, stop, .. }) => {
                let _ = stop.send(true);
                handles.push(handle);
            }
            Some(Live::Process(child)) => drop(child),
            None => {}
        }
        let mut first = Ok(());
        for h in handles {
            let outcome = h.await.map_err(|e| e.to_string()).and_then(|r| r);
            if first.is_ok() {
                first = outcome;
            }
        }
        first
    }
}

/// Send `sig` (`-STOP`, `-CONT`) to process `pid` with the system's `kill`.
fn signal(pid: u32, sig: &str) -> Result<(), String> {
    let status = std::process::Command::new("kill")
        .args([sig, &pid.to_string()])
        .status()
        .map_err(|e| format!("kill {sig} {pid}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("kill {sig} {pid}: {status}"))
    }
}

/// A stop signal of one component that also turns true with the run's (`all`).
fn own_stop(all: &watch::Receiver<bool>) -> (Arc<watch::Sender<bool>>, watch::Receiver<bool>) {
    let (tx, rx) = watch::channel(*all.borrow());
    let tx = Arc::new(tx);
    let (forward, mut all) = (tx.clone(), all.clone());
    tokio::spawn(async move {
        while !*all.borrow_and_update() {
            if all.changed().await.is_err() {
                break;
            }
        }
        let _ = forward.send(true);
    });
    (tx, rx)
}

impl Launch {
    /// Start the coordinator, then the agents.
    pub async fn start(&self, mode: &RunMode) -> Result<Running, LaunchError> {
        let (stop_tx, stop_rx) = watch::channel(false);
        match mode {
            RunMode::Embedded => self.start_embedded(mode, stop_tx, stop_rx).await,
            RunMode::Distributed { dir }
            | RunMode::Hosts { dir, .. }
            | RunMode::Tls { dir, .. }
            | RunMode::Site { dir, .. } => self.start_processes(mode, dir, stop_tx, stop_rx).await,
        }
    }

    /// Embedded: the coordinator and the agents as tasks of this process, on one session.
    async fn start_embedded(
        &self,
        mode: &RunMode,
        stop_tx: watch::Sender<bool>,
        stop_rx: watch::Receiver<bool>,
    ) -> Result<Running, LaunchError> {
        let (session, endpoint) =
            transport::open_discoverable(&ZenohArgs::default(), Role::Alone).await?;
        let c = (self.coordinator.clone(), session.clone());
        let mut components = vec![(
            COORDINATOR.to_string(),
            Component::new(
                COORDINATOR,
                &stop_rx,
                Starter::Task(Box::new(move |stop, stall| c.0.start_task(&c.1, stop, stall))),
            )?,
        )];
        for a in &self.agents {
            let s = (a.clone(), session.clone());
            let starter =
                Starter::Task(Box::new(move |stop, stall| s.0.start_task(&s.1, stop, stall)));
            components.push((
                a.id.clone(),
                Component::new(&format!("robot-agent {}", a.id), &stop_rx, starter)?,
            ));
        }
        Ok(Running {
            session,
            stop_tx,
            stop_rx,
            mode: mode.clone(),
            connect: ZenohArgs::default(),
            components,
            endpoint,
        })
    }

    /// The coordinator and the agents as processes (on their hosts in `mode`), their
    /// configurations written to `dir`; this process joins as a member.
    async fn start_processes(
        &self,
        mode: &RunMode,
        dir: &Path,
        stop_tx: watch::Sender<bool>,
        stop_rx: watch::Receiver<bool>,
    ) -> Result<Running, LaunchError> {
        let hub = mode.hub()?;
        let ids = TeamIds {
            team: self.coordinator.team.clone(),
            robots: self.agents.iter().map(|a| a.id.clone()).collect(),
        };
        let process = |host: &str, bin: &str, args: Vec<String>| Starter::Process {
            mode: mode.clone(),
            host: host.to_string(),
            bin: bin.to_string(),
            args,
        };
        let coordinator = process(
            COORDINATOR_HOST,
            "coordinator",
            self.coordinator.to_cli(dir, &mode.hub_args(&hub, &ids)?)?,
        );
        let mut components =
            vec![(COORDINATOR.to_string(), Component::new(COORDINATOR, &stop_rx, coordinator)?)];
        let (session, endpoint) = mode.open_driver(&hub, &ids).await?;
        for a in &self.agents {
            let starter =
                process(&a.id, "robot-agent", a.to_cli(&mode.zenoh_args(Some(&a.id), &hub, &ids)?));
            components.push((
                a.id.clone(),
                Component::new(&format!("robot-agent {}", a.id), &stop_rx, starter)?,
            ));
        }
        let connect = mode.zenoh_args(Some(SIM_HOST), &hub, &ids)?;
        Ok(Running { session, stop_tx, stop_rx, mode: mode.clone(), connect, components, endpoint })
    }
}

impl Drop for Running {
    /// A run abandoned on an early error still stops its tasks (the processes' guards kill
    /// them): nothing outlives the run.
    fn drop(&mut self) {
        let _ = self.stop_tx.send(true);
    }
}

impl Running {
    /// The session the caller observes the run on (the scenario driver declares its
    /// subscriptions here before [`Running::run_bridge`]).
    pub fn session(&self) -> &Session {
        &self.session
    }

    /// Robot `robot`'s agent, or the coordinator ([`COORDINATOR`]): what a fault kills, stalls
    /// and starts again (`None`: no such component).
    pub fn component(&self, name: &str) -> Option<Component> {
        self.components.iter().find(|(r, _)| r == name).map(|(_, c)| c.clone())
    }

    /// Where a tool on this machine reaches the running team: the tools' endpoint when this
    /// run holds it (`team echo` looks there without flags), else a distributed run's hub
    /// (`team echo --connect`); `None` for an embedded run beside a held port, and for runs
    /// whose configuration names their endpoints (test hosts, TLS, sites).
    pub fn endpoint(&self) -> Option<&str> {
        self.endpoint.as_deref()
    }

    /// Turns true when the run is being stopped.
    pub fn stop_signal(&self) -> watch::Receiver<bool> {
        self.stop_rx.clone()
    }

    /// Run the state source until it ends the run. An error stops every component.
    pub async fn run_bridge(&mut self, bridge: &BridgeArgs) -> Result<BridgeOutcome, LaunchError> {
        let result = match &self.mode {
            RunMode::Embedded => self.run_bridge_here(bridge).await,
            RunMode::Distributed { dir }
            | RunMode::Hosts { dir, .. }
            | RunMode::Tls { dir, .. }
            | RunMode::Site { dir, .. } => {
                let mut child = self.mode.spawn(
                    SIM_HOST,
                    "sim-bridge",
                    &bridge.to_cli(dir, &self.connect)?,
                    "sim-bridge",
                )?;
                tokio::task::spawn_blocking(move || child.wait_success())
                    .await
                    .map_err(|e| LaunchError::Task {
                        what: "waiting for the sim-bridge process".into(),
                        reason: e.to_string(),
                    })?
                    .map(|()| BridgeOutcome::Process)
                    .map_err(LaunchError::from)
            }
        };
        if result.is_err() {
            self.stop();
        }
        result
    }

    async fn run_bridge_here(&self, bridge: &BridgeArgs) -> Result<BridgeOutcome, LaunchError> {
        match bridge {
            BridgeArgs::Scene { scene, robots } => Ok(BridgeOutcome::Scene(
                sim_bridge::scene::run(&self.session, scene, robots, self.stop_signal()).await?,
            )),
            BridgeArgs::Smoke(p) => {
                let cfg = LockstepConfig::smoke(&p.team, p.ticks, Duration::from_secs(5));
                let mut plant = PlaceholderPlant::new(p.robots.clone(), p.joints, p.v0, p.dt);
                let report =
                    lockstep::run(&self.session, &cfg, &mut plant, self.stop_signal()).await?;
                let final_velocities =
                    (0..p.robots.len()).map(|i| plant.velocities(i)[0]).collect();
                Ok(BridgeOutcome::Smoke { report, final_velocities })
            }
        }
    }

    /// Tell every component (and the caller's tasks on [`Running::stop_signal`]) to stop.
    pub fn stop(&self) {
        let _ = self.stop_tx.send(true);
    }

    /// Stop every component, wait for the tasks, kill the processes and close the session.
    /// The first agent or coordinator task that failed is the error.
    pub async fn finish(mut self) -> Result<(), LaunchError> {
        self.stop();
        // With processes, the session is this process's own: it closes before they are killed.
        // Zenoh's TLS link reads and writes one rustls stream from two tasks without a lock
        // (eclipse-zenoh/zenoh#2557): a peer's close read while a write was in flight once
        // aborted the test process (a garbage `rustls::Error` cloned in the write).
        let shared = matches!(self.mode, RunMode::Embedded);
        if !shared {
            let _ = self.session.close().await;
        }
        let mut first_error = None;
        for (who, c) in std::mem::take(&mut self.components) {
            if let (Err(reason), None) = (c.finish().await, &first_error) {
                first_error = Some(if who == COORDINATOR {
                    LaunchError::Coordinator(reason)
                } else {
                    LaunchError::Agent { robot: who, reason }
                });
            }
        }
        if shared {
            let _ = self.session.close().await;
        }
        first_error.map_or(Ok(()), Err)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_lines_carry_every_typed_argument() {
        let dir = std::env::temp_dir().join(format!("launch-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let zenoh = ZenohArgs::connecting("tcp/127.0.0.1:7999");
        let c = CoordinatorArgs {
            team: "t1".into(),
            tick_deadline: Duration::from_millis(1500),
            reuse: Some(TermsReuse { after: Duration::from_micros(250), max_age: 25 }),
            expected: vec!["r1".into(), "r2".into()],
            controller: ControllerSpec::of_kind("pidc").unwrap(),
            robot_hz: Some(500.0),
            wait_for_references: Some(Duration::from_secs(2)),
            solve_budget: Some(Duration::from_micros(1000)),
        };
        let args = c.to_cli(&dir, &zenoh).unwrap();
        let written = std::fs::read_to_string(dir.join("controller.toml")).unwrap();
        assert_eq!(
            ControllerSpec::from_toml(&written).unwrap(),
            c.controller,
            "the file holds the spec"
        );
        for pair in [
            ["--team", "t1"],
            ["--tick-deadline-ms", "1500"],
            ["--reuse-after-us", "250"],
            ["--reuse-max-age", "25"],
            ["--expect", "r1,r2"],
            ["--robot-hz", "500"],
            ["--wait-for-references-ms", "2000"],
            ["--solve-budget-us", "1000"],
            ["--controller-config", &dir.join("controller.toml").display().to_string()],
        ] {
            assert!(
                args.windows(2).any(|w| w[0] == pair[0] && w[1] == pair[1]),
                "{pair:?} in {args:?}"
            );
        }
        assert!(args.iter().any(|a| a.contains("7999")), "{args:?}");
        let a = AgentArgs {
            team: "t1".into(),
            id: "r7".into(),
            model: AgentModel::Placeholder { joints: 5 },
            command_deadline: Duration::from_secs(3),
            command_deadline_ticks: 7,
            drive_gains: DriveGainsMode::Inertia,
            team_every: 4,
            team_delay: robot_agent::delay::TeamDelay::Ticks(2),
            answer_within: Some(Duration::from_micros(2500)),
        };
        let args = a.to_cli(&zenoh);
        for pair in [
            ["--id", "r7"],
            ["--placeholder-joints", "5"],
            ["--command-deadline-ms", "3000"],
            ["--command-deadline-ticks", "7"],
            ["--drive-gains", "inertia"],
            ["--team-every", "4"],
            ["--team-delay", "2"],
            ["--answer-within-us", "2500"],
        ] {
            assert!(
                args.windows(2).any(|w| w[0] == pair[0] && w[1] == pair[1]),
                "{pair:?} in {args:?}"
            );
        }
        let b = BridgeArgs::Smoke(SmokePlant {
            team: "t1".into(),
            robots: vec!["r1".into(), "r2".into()],
            joints: 4,
            ticks: 9,
            dt: 0.002,
            v0: 0.5,
        });
        let args = b.to_cli(&dir, &zenoh).unwrap();
        assert_eq!(args[0], "smoke");
        for pair in [["--robots", "r1,r2"], ["--joints", "4"], ["--ticks", "9"], ["--dt", "0.002"]]
        {
            assert!(
                args.windows(2).any(|w| w[0] == pair[0] && w[1] == pair[1]),
                "{pair:?} in {args:?}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
