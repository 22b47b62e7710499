//! `team run SCENARIO`: the whole stack on one scenario, through the one launcher
//! ([`crate::launcher`]): the coordinator with the scenario's controller, one robot-agent per
//! robot (the robot's own model, loaded once by the plan), the sim-bridge with the scene, and
//! this process's scenario driver (references out; ground truth, torques and diagnostics
//! recorded). Embedded or distributed, the same [`scenario::plan::Plan`] is simulated and every
//! message goes over Zenoh.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use thiserror::Error;

use crate::driver::Driver;
use crate::hosts::TestHosts;
use crate::launcher::{
    AgentArgs, AgentModel, BridgeArgs, BridgeOutcome, CoordinatorArgs, Launch, LaunchError,
    RunMode, Running,
};
use crate::record::{self, RecordError, RecordOptions, Recorder, RecordingSummary, RunFacts};
use evaluation::records::Records;
use scenario::plan::Plan;
use tokio::task::JoinHandle;

/// In lockstep, an agent waits this long for its command before it holds its posture: a tick
/// that is merely slow (a loaded machine) must not see safe-mode torques.
pub const AGENT_COMMAND_DEADLINE: Duration = Duration::from_secs(20);
/// The coordinator abandons a tick whose terms are incomplete after this long.
pub const COORDINATOR_TICK_DEADLINE: Duration = Duration::from_secs(20);

/// In real time ([`sim_bridge::scene::Scene::realtime`]) an agent holds its posture after this
/// long without a command, or as many state ticks (whichever comes first), and refuses a
/// command so many ticks behind its latest state: the agent's own default, a robot's real
/// deadline.
pub const REALTIME_AGENT_COMMAND_DEADLINE: Duration = Duration::from_millis(25);
/// In lockstep the tick deadline is the agent's default (5 ticks); no state comes while the
/// simulation waits for a command, so that it bounds only a robot that answers no tick.
pub const LOCKSTEP_DEADLINE_TICKS: u64 = 5;
/// In real time the coordinator abandons a tick whose terms are incomplete after this long
/// (its states are long gone by then; the tick only holds memory).
pub const REALTIME_COORDINATOR_TICK_DEADLINE: Duration = Duration::from_millis(50);

/// In real time the coordinator solves a tick a quarter of the control period after its first
/// terms arrived (half a period left too little of it for the solve, the agents and the
/// bridge: every robot missed its deadline while one stalled), with a late member's latest
/// terms (`coordinator::team::assembly::TermsReuse`), as long as they are at most
/// [`REALTIME_SILENCE`] old; a member silent for longer is left out.
pub fn realtime_reuse(clock: &protocol::RunClock) -> coordinator::team::assembly::TermsReuse {
    let period = clock.dt();
    coordinator::team::assembly::TermsReuse {
        after: Duration::from_secs_f64(period / 4.0),
        max_age: clock.ticks_lasting(REALTIME_SILENCE.as_secs_f64()).max(1),
    }
}

/// In real time a robot's drives take the answer to a state within half a control period of
/// its arrival at the agent (`robot_agent::core::AgentConfig::answer_within`): the simulator
/// waits for torques until the period ends, and the other half is the state's way to the agent
/// and the answer's way back. A team delay of `auto` rises when too many commands come later.
pub fn realtime_answer_within(clock: &protocol::RunClock) -> Duration {
    Duration::from_secs_f64(clock.dt() / 2.0)
}

/// In real time a tick's solve may take a quarter of the control period before the
/// controller's fallback answers (`coordinator::service::CoordinatorConfig::solve_budget`):
/// the tick is solved a quarter period after its first terms ([`realtime_reuse`]) and its
/// answer is due at the robot half a period after the state. A tick the QP cannot solve went
/// down the whole of "degrade, never collapse" (the motion's yield, Clarabel's certificate,
/// the QP again on saturated torques): 7-18 ms on S4 pushed beyond its grasp, three of
/// its 4 ms ticks, and the robots went without commands while their grasp was let go.
pub fn realtime_solve_budget(clock: &protocol::RunClock) -> Duration {
    Duration::from_secs_f64(clock.dt() / 4.0)
}

/// How long a member may send no terms in real time before the coordinator leaves it out of
/// the team (a team of two then lets go of the object). Long against a lossy link's gaps: with
/// 5 % of one agent's packets dropped, TCP's retransmissions held its torques for up to 72 ms
/// (18 ticks at 250 Hz), and leaving it out after 50 ms dropped the object a lossy link alone
/// did not. Meanwhile its drives apply its last torques, then (after their 50 ms timeout) hold
/// their joints, and the team is solved with its latest terms.
pub const REALTIME_SILENCE: Duration = Duration::from_millis(200);

/// After the bridge ended the run, how long the driver may take to record the last ticks.
pub const DRIVER_DRAIN: Duration = Duration::from_secs(5);

/// How long a run waits for its coordinator to come before the first tick (a process on a
/// loaded machine starts in seconds); then the run fails, naming the coordinator.
pub const COORDINATOR_WAIT: Duration = Duration::from_secs(60);

/// Errors of a run.
#[derive(Debug, Error)]
pub enum RunError {
    #[error(transparent)]
    Launch(#[from] LaunchError),
    #[error(transparent)]
    Transport(#[from] protocol::transport::TransportError),
    #[error("the run ended after {seen} of {expected} ticks")]
    Incomplete { seen: u64, expected: u64 },
    #[error("{what}: {reason}")]
    Task { what: String, reason: String },
    #[error(transparent)]
    Record(#[from] RecordError),
}

/// A run that ended in an error, with what its driver recorded until then: a failed run's
/// ticks can still be evaluated and reported. Its message is the error's.
pub struct FailedRun {
    pub error: RunError,
    /// The records of the ticks seen (`None`: the run failed before a tick was seen).
    pub records: Option<Box<Records>>,
    /// The run's recording, closed after the error (`None` without one, or if it could not be
    /// closed).
    pub recording: Option<Box<RecordingSummary>>,
}

impl FailedRun {
    /// `error` after the ticks in `records`, kept if a tick was seen.
    fn after(error: RunError, records: Option<Records>) -> FailedRun {
        let records = records.filter(|r| r.ticks_seen > 0).map(Box::new);
        FailedRun { error, records, recording: None }
    }

    /// The error alone, for a caller that only wants to know why.
    pub fn into_error(self) -> RunError {
        self.error
    }
}

impl std::fmt::Debug for FailedRun {
    /// The error and how many ticks the records hold, not the records (a run's samples).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FailedRun")
            .field("error", &self.error)
            .field("ticks_seen", &self.records.as_ref().map(|r| r.ticks_seen))
            .field("recording", &self.recording)
            .finish()
    }
}

impl std::fmt::Display for FailedRun {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Display::fmt(&self.error, f)
    }
}

impl std::error::Error for FailedRun {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.error.source()
    }
}

impl From<RunError> for FailedRun {
    /// A run that failed before a tick was seen.
    fn from(error: RunError) -> FailedRun {
        FailedRun { error, records: None, recording: None }
    }
}

/// How to run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub distributed: bool,
    /// Distributed across test hosts (`crate::hosts`), one per component, made for the run
    /// and removed after it.
    pub hosts: bool,
    /// A progress bar (terminal) or progress lines, on stdout.
    pub progress: bool,
    /// Packet loss on robots' links for the whole run (test hosts only, [`LinkLoss`]).
    pub loss: Vec<LinkLoss>,
}

/// A share of a robot's packets dropped, both ways, on its test host's link (nftables,
/// [`TestHosts::set_loss`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LinkLoss {
    pub robot: String,
    pub percent: u8,
}

impl std::str::FromStr for LinkLoss {
    type Err = String;

    /// `ROBOT=PERCENT`, the percentage a whole number from 0 to 100.
    fn from_str(s: &str) -> Result<Self, String> {
        let (robot, percent) =
            s.split_once('=').ok_or_else(|| format!("{s:?}: expected ROBOT=PERCENT, e.g. r1=5"))?;
        let percent: u8 = percent
            .trim()
            .parse()
            .map_err(|_| format!("{s:?}: the loss is a whole percentage from 0 to 100"))?;
        if robot.trim().is_empty() || percent > 100 {
            return Err(format!("{s:?}: expected ROBOT=PERCENT with a robot and 0 to 100 %"));
        }
        Ok(LinkLoss { robot: robot.trim().to_string(), percent })
    }
}

impl RunOptions {
    /// The name reports give the mode these options (and `tls`, [`run_recorded_secure`]'s)
    /// run in: [`RunMode::name`] of the mode that function makes.
    pub fn mode_name(&self, tls: bool) -> &'static str {
        match (self.hosts, tls, self.distributed) {
            (true, true, _) => "hosts-tls",
            (true, false, _) => "hosts",
            (false, true, _) => "distributed-tls",
            (false, false, true) => "distributed",
            (false, false, false) => "embedded",
        }
    }

    /// The mode as the report names it: [`RunOptions::mode_name`], and `", real time"` after
    /// it for a real-time run.
    pub fn mode_label(&self, tls: bool, realtime: bool) -> String {
        let name = self.mode_name(tls);
        if realtime {
            format!("{name}, real time")
        } else {
            name.to_string()
        }
    }
}

/// The report folder of a run of the scenario file `scenario` when none is given:
/// `reports/<file name without extension>` (`reports/scenario` for a path without one).
pub fn default_report_dir(scenario: &Path) -> PathBuf {
    let stem = scenario
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "scenario".into());
    PathBuf::from("reports").join(stem)
}

/// The components of a scenario run.
/// Lockstep runs wait long ([`AGENT_COMMAND_DEADLINE`], [`COORDINATOR_TICK_DEADLINE`]); real-time
/// runs (`plan.scene.realtime`) keep a robot's deadlines ([`REALTIME_AGENT_COMMAND_DEADLINE`],
/// [`REALTIME_COORDINATOR_TICK_DEADLINE`]).
pub fn launch_of(plan: &Plan) -> (Launch, BridgeArgs) {
    let clock = &plan.references.clock;
    let (tick_deadline, command_deadline, command_deadline_ticks, reuse) = if plan.scene.realtime {
        let ticks = clock.ticks_lasting(REALTIME_AGENT_COMMAND_DEADLINE.as_secs_f64()).max(1);
        (
            REALTIME_COORDINATOR_TICK_DEADLINE,
            REALTIME_AGENT_COMMAND_DEADLINE,
            ticks,
            Some(realtime_reuse(clock)),
        )
    } else {
        (COORDINATOR_TICK_DEADLINE, AGENT_COMMAND_DEADLINE, LOCKSTEP_DEADLINE_TICKS, None)
    };
    let expected = plan.robots.iter().map(|r| r.id.clone()).collect();
    let robot_hz = plan.scenario.predict_delay.then_some(plan.scenario.control_hz);
    // The driver sends references for every tick: a coordinator that starts inside the run (a
    // restart) holds the team until they come.
    let wait_for_references = Some(coordinator::service::REFERENCE_WAIT);
    let coordinator = CoordinatorArgs {
        team: plan.team().into(),
        tick_deadline,
        reuse,
        expected,
        controller: plan.controller.clone(),
        robot_hz,
        wait_for_references,
        solve_budget: plan.scene.realtime.then(|| realtime_solve_budget(clock)),
    };
    let agents = plan
        .robots
        .iter()
        .map(|r| AgentArgs {
            team: plan.team().into(),
            id: r.id.clone(),
            model: AgentModel::Robot { robot: r.robot.clone(), description: r.description.clone() },
            command_deadline,
            command_deadline_ticks,
            drive_gains: plan.scenario.drive_gains,
            // Checked when the scenario loaded.
            team_every: plan.scenario.team_every().unwrap_or(1),
            team_delay: plan.scenario.team_delay_ticks,
            answer_within: plan.scene.realtime.then(|| realtime_answer_within(clock)),
        })
        .collect();
    let bridge =
        BridgeArgs::Scene { scene: Box::new(plan.scene.clone()), robots: plan.loaded_robots() };
    (Launch { coordinator, agents }, bridge)
}

/// Run the plan; `out` is the report folder (the distributed run writes its component files
/// there). A failed run's error only ([`run_recorded`] keeps its records).
pub fn run(plan: &Plan, opts: &RunOptions, out: &Path) -> Result<Records, RunError> {
    run_recorded(plan, opts, out, None).map(|(records, _)| records).map_err(FailedRun::into_error)
}

/// [`run`], recording the run as MCAP (and serving it live) when `record` is given. A run that
/// fails after ticks were seen returns their records with the error ([`FailedRun`]).
pub fn run_recorded(
    plan: &Plan,
    opts: &RunOptions,
    out: &Path,
    record: Option<&RecordOptions>,
) -> Result<(Records, Option<RecordingSummary>), FailedRun> {
    run_recorded_secure(plan, opts, None, out, record)
}

/// The mode of a run on this computer's loopback (not on test hosts): over TLS when `tls`
/// names the certificates (distributed or not), else distributed or embedded.
fn loopback_mode(opts: &RunOptions, tls: Option<&Path>, out: &Path) -> RunMode {
    RunMode::on_loopback(opts.distributed, tls, out)
}

/// [`run_recorded`]; with `tls`, distributed on loopback over mutual TLS with the team's
/// access control ([`RunMode::Tls`]), the certificates in that folder
/// (`scripts/make-test-certs.sh DIR ROBOT...`; README "Access control (mutual TLS and ACL)").
/// With `tls` and test hosts, the test CA in that folder signs certificates for the hosts'
/// addresses into `out/hosts-certs` ([`TestHosts::issue_certs`]).
pub fn run_recorded_secure(
    plan: &Plan,
    opts: &RunOptions,
    tls: Option<&Path>,
    out: &Path,
    record: Option<&RecordOptions>,
) -> Result<(Records, Option<RecordingSummary>), FailedRun> {
    if let (true, Some(ca)) = (opts.hosts, tls) {
        // Before any host is made: the run's certificates need the test CA's key.
        TestHosts::check_ca(ca).map_err(|e| RunError::Task {
            what: "the run's certificates".into(),
            reason: e.to_string(),
        })?;
    }
    let ids: Vec<String> = plan.robots.iter().map(|r| r.id.clone()).collect();
    check_loss(opts, &ids)?;
    let mode =
        if opts.hosts { hosts_mode(opts, tls, out, &ids)? } else { loopback_mode(opts, tls, out) };
    let outcome = run_recorded_in(plan, opts, &mode, record);
    if let RunMode::Hosts { hosts, .. } = &mode {
        log_dropped(opts, hosts);
    }
    outcome
}

/// Packet loss only on robots of the team, and only on test hosts (a robot's own link).
fn check_loss(opts: &RunOptions, ids: &[String]) -> Result<(), RunError> {
    if let Some(l) = opts.loss.iter().find(|l| !ids.contains(&l.robot)) {
        return Err(RunError::Task {
            what: "packet loss".into(),
            reason: format!("no robot {} in the team ({})", l.robot, ids.join(", ")),
        });
    }
    if !opts.loss.is_empty() && !opts.hosts {
        return Err(RunError::Task {
            what: "packet loss".into(),
            reason: "needs test hosts (--hosts): a robot's own link is what loses packets".into(),
        });
    }
    Ok(())
}

/// The run on a new set of test hosts, one per robot, with the packet loss asked for; over
/// TLS, with certificates for the hosts' addresses.
fn hosts_mode(
    opts: &RunOptions,
    tls: Option<&Path>,
    out: &Path,
    ids: &[String],
) -> Result<RunMode, RunError> {
    let hosts = TestHosts::up(&crate::launcher::host_names(ids)).map_err(|e| RunError::Task {
        what: "making the test hosts".into(),
        reason: e.to_string(),
    })?;
    for l in &opts.loss {
        hosts.set_loss(&l.robot, l.percent).map_err(|e| RunError::Task {
            what: format!("packet loss on {}'s link", l.robot),
            reason: e.to_string(),
        })?;
    }
    // Over TLS, certificates for this set's addresses, signed by the test CA in `tls`.
    let certs = match tls {
        Some(ca) => {
            let dir = std::path::absolute(out.join("hosts-certs")).map_err(|e| RunError::Task {
                what: "the run's certificates".into(),
                reason: e.to_string(),
            })?;
            hosts.issue_certs(ca, ids, &dir).map_err(|e| RunError::Task {
                what: "the run's certificates".into(),
                reason: e.to_string(),
            })?;
            Some(dir)
        }
        None => None,
    };
    Ok(RunMode::Hosts { dir: out.to_path_buf(), hosts: std::sync::Arc::new(hosts), certs })
}

/// Log the packets each lossy robot link dropped during the run.
fn log_dropped(opts: &RunOptions, hosts: &TestHosts) {
    for l in &opts.loss {
        match hosts.dropped(&l.robot) {
            Ok(n) => {
                tracing::info!(
                    robot = %l.robot,
                    percent = l.percent,
                    dropped = n,
                    "packets dropped on the robot's link"
                )
            }
            Err(e) => {
                tracing::warn!(robot = %l.robot, "packets dropped on the robot's link: {e}")
            }
        }
    }
}

/// [`run_recorded`] in a given mode (e.g. [`RunMode::Site`], a client of a site's router).
pub fn run_recorded_in(
    plan: &Plan,
    opts: &RunOptions,
    mode: &RunMode,
    record: Option<&RecordOptions>,
) -> Result<(Records, Option<RecordingSummary>), FailedRun> {
    let rt = tokio::runtime::Runtime::new().map_err(|e| RunError::Task {
        what: "starting the async runtime".into(),
        reason: e.to_string(),
    })?;
    let recorder = match record {
        Some(r) => Some(rt.block_on(Recorder::start(plan, r)).map_err(RunError::from)?),
        None => None,
    };
    if let Some(port) = recorder.as_ref().and_then(Recorder::live_port) {
        println!("live: open Foxglove and connect to ws://127.0.0.1:{port}");
    }
    let result = rt.block_on(run_in_keeping(plan, opts, mode, recorder.as_ref()));
    let recording = close_recording(recorder, &result, mode);
    checked(plan, result, recording)
}

/// Close the recording whatever happened (a failed run's recording shows why), with the wall
/// times of the ticks the run saw.
fn close_recording(
    recorder: Option<Recorder>,
    result: &Result<Records, FailedRun>,
    mode: &RunMode,
) -> Result<Option<RecordingSummary>, RecordError> {
    let Some(rec) = recorder else { return Ok(None) };
    let records = match result {
        Ok(r) => Some(r),
        Err(f) => f.records.as_deref(),
    };
    let error = result.as_ref().err().map(|f| f.error.to_string());
    let facts = records
        .map(|r| RunFacts {
            mode: mode.name().to_string(),
            settle_wall: r.settle_wall,
            run_wall: r.run_wall,
            machine: r.machine,
            error: error.clone(),
        })
        .unwrap_or(RunFacts { error, ..RunFacts::default() });
    rec.finish(&facts).map(Some)
}

/// The run's outcome with its recording. A run that saw fewer ticks than planned failed
/// ([`RunError::Incomplete`]); a recording that could not be closed fails a run that did not
/// (its records kept); a failed run's error stays its own.
fn checked(
    plan: &Plan,
    result: Result<Records, FailedRun>,
    recording: Result<Option<RecordingSummary>, RecordError>,
) -> Result<(Records, Option<RecordingSummary>), FailedRun> {
    let (records, recording) = match (result, recording) {
        (Err(mut failed), recording) => {
            if let Err(e) = &recording {
                tracing::warn!("the failed run's recording could not be closed: {e}");
            }
            failed.recording = recording.ok().flatten().map(Box::new);
            return Err(failed);
        }
        (Ok(records), Err(e)) => return Err(FailedRun::after(e.into(), Some(records))),
        (Ok(records), Ok(recording)) => (records, recording),
    };
    if records.ticks_seen < plan.total_ticks() {
        let error = RunError::Incomplete { seen: records.ticks_seen, expected: plan.total_ticks() };
        let recording = recording.map(Box::new);
        return Err(FailedRun { recording, ..FailedRun::after(error, Some(records)) });
    }
    Ok((records, recording))
}

/// Launch the team in `mode`, drive the scenario until the bridge ends it, stop everything.
/// With a `recorder`, the driver and the recorder's subscriptions feed it.
pub async fn run_in(
    plan: &Plan,
    opts: &RunOptions,
    mode: &RunMode,
    recorder: Option<&Recorder>,
) -> Result<Records, RunError> {
    run_in_keeping(plan, opts, mode, recorder).await.map_err(FailedRun::into_error)
}

/// [`run_in`], keeping what the driver recorded when the run fails after it started (the
/// bridge, a component or the driver's own link ended it): the error comes with the records
/// of the ticks seen.
pub async fn run_in_keeping(
    plan: &Plan,
    opts: &RunOptions,
    mode: &RunMode,
    recorder: Option<&Recorder>,
) -> Result<Records, FailedRun> {
    if plan.scene.realtime {
        crate::priority::raise_for_realtime();
    }
    let (launch, bridge) = launch_of(plan);
    let started = Instant::now();
    let mut running = launch.start(mode).await.map_err(RunError::from)?;
    if opts.progress {
        match (running.endpoint(), mode) {
            (Some(e), _) => println!("team: tools on this machine connect at {e}"),
            (None, RunMode::Embedded) => println!(
                "team: no tool can connect: another process holds {}",
                protocol::transport::TOOLS_ENDPOINT
            ),
            _ => {}
        }
    }
    let beside = start_beside(plan, opts, &running, recorder).await?;
    let driver_task = tokio::spawn(beside.driver.run(running.stop_signal()));
    let bridge_result = running.run_bridge(&bridge).await;
    // The driver ends by itself at the ground truth of the last tick (which may still be
    // crossing a process boundary); after a failed run, or if that sample never comes, it is
    // stopped.
    let drain = if bridge_result.is_ok() { DRIVER_DRAIN } else { Duration::ZERO };
    let records = join_driver(&running, driver_task, drain).await?;
    let _ = beside.record_stop.send(true);
    for t in beside.fault_tasks {
        t.abort();
    }
    for t in beside.record_tasks {
        let _ = t.await;
    }
    let finished = running.finish().await;
    tracing::debug!(wall = ?started.elapsed(), mode = mode.name(), "run ended");
    ended(bridge_result, finished, records)
}

/// What runs beside the bridge: the driver (its first window of references sent), the
/// recorder's subscriptions and how to stop them, the armed faults.
struct Beside {
    driver: Driver,
    record_stop: tokio::sync::watch::Sender<bool>,
    record_tasks: Vec<JoinHandle<()>>,
    fault_tasks: Vec<JoinHandle<()>>,
}

/// Start what runs beside the bridge on the running team; an error if the coordinator did not
/// come within [`COORDINATOR_WAIT`].
async fn start_beside(
    plan: &Plan,
    opts: &RunOptions,
    running: &Running,
    recorder: Option<&Recorder>,
) -> Result<Beside, RunError> {
    let mut driver = start_driver(plan, opts, running).await?;
    let (record_stop, record_stopped) = tokio::sync::watch::channel(false);
    let mut record_tasks = Vec::new();
    if let Some(rec) = recorder {
        driver = driver.with_tap(rec.tap());
        record_tasks =
            record::subscribe(running.session(), plan.team(), &rec.tap(), &record_stopped).await?;
    }
    let fault_tasks = arm_faults(plan, running).await?;
    if !driver.send_first_window(COORDINATOR_WAIT).await? {
        return Err(RunError::Task {
            what: "starting the run".into(),
            reason: format!("the coordinator did not come within {COORDINATOR_WAIT:?}"),
        });
    }
    Ok(Beside { driver, record_stop, record_tasks, fault_tasks })
}

/// The run's outcome: the driver's records, or the first error (the bridge's, a component's,
/// then the driver's own) with the records of the ticks seen.
fn ended(
    bridge: Result<BridgeOutcome, LaunchError>,
    finished: Result<(), LaunchError>,
    (records, driven): (Records, Result<(), protocol::transport::TransportError>),
) -> Result<Records, FailedRun> {
    let error = bridge.err().or(finished.err()).map(RunError::from);
    match error.or(driven.err().map(RunError::from)) {
        None => Ok(records),
        Some(error) => Err(FailedRun::after(error, Some(records))),
    }
}

/// The scenario driver on the running team's session, paced in a real-time run.
async fn start_driver(
    plan: &Plan,
    opts: &RunOptions,
    running: &Running,
) -> Result<Driver, RunError> {
    let driver = Driver::start(running.session(), plan.team(), plan, opts.progress).await?;
    Ok(if plan.scene.realtime { driver.paced(plan.scenario.control_hz) } else { driver })
}

/// The scenario's faults armed on the running team: one task each, which injects its fault at
/// its tick.
async fn arm_faults(plan: &Plan, running: &Running) -> Result<Vec<JoinHandle<()>>, RunError> {
    let mut fault_tasks = Vec::new();
    for f in &plan.scenario.faults {
        let who = f.robot().unwrap_or(crate::launcher::COORDINATOR);
        let fault = |reason: &str| RunError::Task {
            what: format!("fault on {who}"),
            reason: reason.to_string(),
        };
        if f.kind == scenario::file::FaultKind::AgentStalls && !plan.scene.realtime {
            return Err(fault(
                "agent-stalls needs a real-time run (--realtime): \
                 in lockstep the team waits for the stalled agent",
            ));
        }
        let component =
            running.component(who).ok_or_else(|| fault("no such component in the run"))?;
        let armed =
            crate::faults::Armed::new(f, &plan.references.clock, component, &plan.robots[0].id);
        fault_tasks.push(
            crate::faults::inject(running.session(), plan.team(), armed, running.stop_signal())
                .await?,
        );
    }
    Ok(fault_tasks)
}

/// The driver's outcome: within `drain` if it ends by itself, else after stopping the run.
async fn join_driver<T>(
    running: &Running,
    mut driver_task: JoinHandle<T>,
    drain: Duration,
) -> Result<T, RunError> {
    let records = match tokio::time::timeout(drain, &mut driver_task).await {
        Ok(records) => records,
        Err(_) => {
            running.stop();
            driver_task.await
        }
    };
    records
        .map_err(|e| RunError::Task { what: "the scenario driver".into(), reason: e.to_string() })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The report's mode name, chosen before the run, is the name of the mode the run picks
    /// ([`RunMode::name`], which the recording keeps) on loopback; the hosts' modes (a
    /// `RunMode::Hosts` needs hosts made) by their names.
    #[test]
    fn the_reported_mode_is_the_mode_that_runs() {
        let (out, certs) = (Path::new("out"), Path::new("certs"));
        for distributed in [false, true] {
            let opts = RunOptions { distributed, hosts: false, progress: false, loss: Vec::new() };
            for tls in [None, Some(certs)] {
                assert_eq!(
                    opts.mode_name(tls.is_some()),
                    loopback_mode(&opts, tls, out).name(),
                    "distributed {distributed}, tls {tls:?}"
                );
            }
        }
        assert_eq!(
            loopback_mode(
                &RunOptions { distributed: false, hosts: false, progress: false, loss: Vec::new() },
                Some(certs),
                out
            )
            .name(),
            "distributed-tls",
            "TLS runs distributed"
        );
        let hosts =
            RunOptions { distributed: false, hosts: true, progress: false, loss: Vec::new() };
        assert_eq!((hosts.mode_name(false), hosts.mode_name(true)), ("hosts", "hosts-tls"));
        assert_eq!(hosts.mode_label(true, true), "hosts-tls, real time");
        assert_eq!(hosts.mode_label(false, false), "hosts");
    }

    #[test]
    fn a_link_loss_reads_as_robot_and_whole_percent() {
        assert_eq!("r1=5".parse::<LinkLoss>(), Ok(LinkLoss { robot: "r1".into(), percent: 5 }));
        assert_eq!(" r2 = 100".parse::<LinkLoss>().map(|l| l.percent), Ok(100));
        for bad in ["r1", "r1=", "=5", "r1=101", "r1=-1", "r1=2.5", "r1=NaN"] {
            assert!(bad.parse::<LinkLoss>().is_err(), "{bad} refused");
        }
    }

    /// Loss is refused before anything starts: on an unknown robot, and without test hosts.
    #[test]
    fn a_link_loss_names_a_robot_of_the_team_and_needs_test_hosts() {
        let repo = scenario::plan::repo_root();
        let s = scenario::file::Scenario::load(repo.join("scenarios/s4_object_circle.toml"), &[])
            .expect("scenario");
        let plan = scenario::plan::plan(&s, &repo).expect("plan");
        let out = std::env::temp_dir().join("team-runner-link-loss");
        let loss = |robot: &str, hosts| RunOptions {
            distributed: true,
            hosts,
            progress: false,
            loss: vec![LinkLoss { robot: robot.into(), percent: 5 }],
        };
        let e = run_recorded_secure(&plan, &loss("r9", true), None, &out, None)
            .expect_err("unknown robot")
            .to_string();
        assert!(e.contains("no robot r9") && e.contains("r1, r2"), "{e}");
        let e = run_recorded_secure(&plan, &loss("r1", false), None, &out, None)
            .expect_err("no hosts")
            .to_string();
        assert!(e.contains("needs test hosts"), "{e}");
    }

    #[test]
    fn a_run_reports_into_a_folder_named_after_its_scenario() {
        assert_eq!(
            default_report_dir(Path::new("scenarios/s4_object_circle.toml")),
            Path::new("reports/s4_object_circle")
        );
        assert_eq!(default_report_dir(Path::new("/")), Path::new("reports/scenario"));
    }
}
