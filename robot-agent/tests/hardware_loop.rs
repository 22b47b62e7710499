//! The synchronous hardware loop with the in-memory mock robot: first with the team in
//! memory (the coordinator's `JointDamping` controller called directly), then over a real
//! Zenoh session on loopback (its own port) to a real coordinator service.

#[path = "common/hold_law.rs"]
mod hold_law;
use hold_law::hold_kd;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use coordinator::service::{self, CoordinatorConfig};
use coordinator::{JointDamping, TeamController};
use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, Role, SampleQueue, TransportError, ZenohArgs};
use protocol::{
    AgentMode, AgentStatus, ContactSet, CoordinatorStatus, DynamicsTerms, RobotDescription,
    TorqueCommand,
};
use robot_agent::core::{AgentConfig, AgentCore};
use robot_agent::dynamics_source::PlaceholderDynamics;
use robot_agent::hardware::driver::{self, DriverConfig, DriverError, DriverExit};
use robot_agent::hardware::mock::Lifecycle;
use robot_agent::hardware::{
    HwStatus, Inbound, MockConfig, MockFault, MockHardware, Presence, TeamLink, ZenohLink,
};
use robot_agent::safe_mode::CommandDeadline;

const ID: &str = "r1";
const JOINTS: usize = 3;
const DT: f64 = 0.01;
const DAMPING: f64 = 5.0;
const V0: f64 = 0.5;

/// Unit-inertia joints: the mock robot's exact model.
fn unit_joints() -> PlaceholderDynamics {
    PlaceholderDynamics { joints: JOINTS, nv: JOINTS }
}

fn agent_config(team: &str, deadline: CommandDeadline) -> AgentConfig {
    let mut cfg = AgentConfig::new(team, ID);
    cfg.deadline = deadline;
    // Without a time deadline, no age limit that a loaded machine could trip either.
    cfg.max_command_age = deadline.time.unwrap_or(Duration::from_secs(10));
    // The hold law itself, applied at once: the blends between hold and commands (in robot
    // time, here the wall clock's) have their own tests in `agent_loop.rs`.
    cfg.takeover = Duration::ZERO;
    cfg
}

fn mock() -> MockHardware {
    MockHardware::new(MockConfig { record: true, ..MockConfig::new(JOINTS, V0, DT) })
}

/// `v_k = (1 - dt d)^k v0`: semi-implicit Euler of `qdd = -d qd` with each tick's own torque.
fn analytic(k: u64) -> f64 {
    V0 * (1.0 - DT * DAMPING).powi(k as i32)
}

fn assert_close(got: f64, want: f64, what: &str) {
    assert!((got - want).abs() <= 1e-12 * want.abs().max(1e-3), "{what}: {got} vs {want}");
}

/// The team in memory: the coordinator's controller answers every tick's terms at once
/// while `answering`; the loop stops after `ticks` terms.
struct TeamInMemory {
    controller: JointDamping,
    answering: Box<dyn Fn(u64) -> bool + Send>,
    commands: VecDeque<TorqueCommand>,
    out: Vec<TorqueCommand>,
    statuses: Vec<AgentStatus>,
    ticks: u64,
    stop: Arc<AtomicBool>,
    /// Times the loop withdrew the membership.
    left: u32,
    /// The coordinator's comings and goings, each reported once the loop has sent the terms
    /// of its tick.
    presence: VecDeque<(u64, Presence)>,
    /// The tick of the last terms sent.
    last_terms: Option<u64>,
    /// When the loop took the coordinator's going, and when each status was sent.
    went_at: Option<Instant>,
    status_at: Vec<Instant>,
}

impl TeamInMemory {
    fn new(ticks: u64, answering: impl Fn(u64) -> bool + Send + 'static) -> Self {
        TeamInMemory {
            controller: JointDamping { damping: DAMPING },
            answering: Box::new(answering),
            commands: VecDeque::new(),
            out: Vec::new(),
            statuses: Vec::new(),
            ticks,
            stop: Arc::new(AtomicBool::new(false)),
            left: 0,
            presence: VecDeque::new(),
            last_terms: None,
            went_at: None,
            status_at: Vec::new(),
        }
    }
}

impl TeamLink for TeamInMemory {
    fn send_terms(&mut self, terms: &DynamicsTerms) -> Result<(), TransportError> {
        let tick = terms.header.tick;
        self.last_terms = Some(tick);
        if (self.answering)(tick) {
            self.controller.solve(std::slice::from_ref(terms), &mut self.out).unwrap();
            self.commands.extend(self.out.drain(..));
        }
        if tick + 1 >= self.ticks {
            self.stop.store(true, Ordering::Release);
        }
        Ok(())
    }
    fn send_status(&mut self, status: &AgentStatus) -> Result<(), TransportError> {
        self.statuses.push(status.clone());
        self.status_at.push(Instant::now());
        Ok(())
    }
    fn send_description(&mut self, _: &RobotDescription) -> Result<(), TransportError> {
        Ok(())
    }
    fn wait(&mut self, deadline: Instant) {
        // Commands arrive as the terms go out: with none queued, nothing comes before the
        // deadline.
        if self.commands.is_empty() {
            std::thread::sleep(deadline.saturating_duration_since(Instant::now()));
        }
    }
    fn try_recv_command(&mut self) -> Inbound<TorqueCommand> {
        self.commands.pop_front().map_or(Inbound::Empty, Inbound::Message)
    }
    fn try_recv_contacts(&mut self) -> Inbound<ContactSet> {
        Inbound::Empty
    }
    fn try_recv_coordinator(&mut self) -> Option<Presence> {
        let due =
            self.presence.front().is_some_and(|(t, _)| self.last_terms.is_some_and(|l| l >= *t));
        let p = due.then(|| self.presence.pop_front().map(|(_, p)| p)).flatten();
        if p == Some(Presence::Went) {
            self.went_at = Some(Instant::now());
        }
        p
    }
    fn leave_team(&mut self) -> Result<(), TransportError> {
        self.left += 1;
        Ok(())
    }
}

fn fast() -> DriverConfig {
    DriverConfig::new(Duration::from_millis(1))
}

#[test]
fn in_memory_team_damps_the_mock_exactly_then_safe_mode_holds_when_it_goes_silent() {
    // Ticks 0..=49 answered; 50.. not. Tick deadline only, so that timing cannot interfere.
    let deadline = CommandDeadline { ticks: 5, time: None };
    let mut core = AgentCore::new(&agent_config("mem1", deadline), unit_joints()).unwrap();
    let mut link = TeamInMemory::new(80, |tick| tick < 50);
    let mut hw = mock();
    let stop = link.stop.clone();
    let report = driver::run(&mut core, &mut hw, &mut link, &fast(), &stop).unwrap();
    assert_eq!((report.exit, report.cycles), (DriverExit::Stopped, 80));
    assert_eq!(hw.lifecycle(), Lifecycle::Inactive, "deactivated when the loop stopped");

    let h = hw.history();
    for (k, step) in h.iter().enumerate().take(50) {
        let want = analytic(k as u64);
        assert_close(step.v[0], want, &format!("v at tick {k}"));
        // The torque written in the cycle of tick k is the coordinator's answer to tick k.
        assert_eq!(step.tau.as_deref(), Some(&[-DAMPING * step.v[0]; JOINTS][..]), "tick {k}");
    }
    // Ticks 50..53 repeat the last command (zero-order hold); tick 54 = 49 + 5 enters safe
    // mode: the hold at the posture of entry, zero gravity, carrying the last command:
    // -Kd v + tau_49.
    for step in &h[50..54] {
        assert_eq!(step.tau, h[49].tau, "tick {}", step.tick);
    }
    let kd = hold_kd(f64::INFINITY);
    let entry = &h[54];
    let carried = h[49].tau.as_deref().unwrap()[0];
    for t in entry.tau.as_deref().unwrap() {
        assert!(
            (t - (-kd * entry.v[0] + carried)).abs() < 1e-12,
            "{t} vs {}",
            -kd * entry.v[0] + carried
        );
    }
    assert!(h[55..].iter().all(|s| s.tau.is_some()), "the hold is written every cycle");
    let safe: Vec<&AgentStatus> =
        link.statuses.iter().filter(|s| s.mode == AgentMode::SafeMode).collect();
    assert_eq!((safe[0].header.tick, safe[0].last_applied_tick), (54, Some(49)));
    let c = &report.counters;
    assert_eq!(
        (c.states, c.dynamics, c.applied, c.rejected, c.safe_mode_entries, c.hold_torques),
        (80, 80, 50, 0, 1, 26)
    );
}

/// The coordinator's token, as the hardware loop sees it: with a zero grace, its going puts the
/// robot in safe mode in that very cycle (the hold written at that tick; the next tick's
/// command takes over again); with a grace, a token gone for the grace holds the robot, one
/// that comes back within it changes nothing. Before, the hardware loop did
/// not watch the token at all and only the command deadline could hold the robot.
#[test]
fn the_hardware_loop_watches_the_coordinators_token() {
    let deadline = CommandDeadline { ticks: 5, time: None };
    let kd = hold_kd(f64::INFINITY);

    let mut cfg = agent_config("mem-token0", deadline);
    cfg.coordinator_grace = Duration::ZERO;
    let mut core = AgentCore::new(&cfg, unit_joints()).unwrap();
    let mut link = TeamInMemory::new(60, |_| true);
    link.presence.push_back((30, Presence::Went));
    let mut hw = mock();
    let stop = link.stop.clone();
    let report = driver::run(&mut core, &mut hw, &mut link, &fast(), &stop).unwrap();
    let h = hw.history();
    let carried = -DAMPING * h[30].v[0];
    for t in h[30].tau.as_deref().unwrap() {
        assert!(
            (t - (-kd * h[30].v[0] + carried)).abs() < 1e-12,
            "tick 30 writes the hold carrying tick 30's command: {t}"
        );
    }
    for step in h.iter().filter(|s| s.tick != 30) {
        assert_eq!(
            step.tau.as_deref(),
            Some(&[-DAMPING * step.v[0]; JOINTS][..]),
            "tick {}: its command",
            step.tick
        );
    }
    let safe: Vec<u64> = link
        .statuses
        .iter()
        .filter(|s| s.mode == AgentMode::SafeMode)
        .map(|s| s.header.tick)
        .collect();
    assert_eq!(safe.first(), Some(&30), "safe mode said at tick 30: {safe:?}");
    assert_eq!(
        (report.counters.safe_mode_entries, report.counters.applied),
        (1, 60),
        "{:?}",
        report.counters
    );

    // A grace of 200 ms, 400 cycles of at least 1 ms: the token gone from tick 30 on holds the
    // robot 200 ms later (by the wall clock: an overrun slips the loop's schedule); gone at
    // tick 30 and back at tick 32, never.
    for (back, entries) in [(None, 1), (Some(32), 0)] {
        let mut cfg = agent_config("mem-token1", deadline);
        cfg.coordinator_grace = cfg_grace();
        let mut core = AgentCore::new(&cfg, unit_joints()).unwrap();
        let mut link = TeamInMemory::new(400, |_| true);
        link.presence.push_back((30, Presence::Went));
        link.presence.extend(back.map(|t| (t, Presence::Came)));
        let mut hw = mock();
        let stop = link.stop.clone();
        let report = driver::run(&mut core, &mut hw, &mut link, &fast(), &stop).unwrap();
        assert_eq!(
            report.counters.safe_mode_entries, entries,
            "back at {back:?}: {:?}",
            report.counters
        );
        if entries == 1 {
            let (i, safe) = link
                .statuses
                .iter()
                .enumerate()
                .find(|(_, s)| s.mode == AgentMode::SafeMode)
                .expect("safe mode said");
            let after = link.status_at[i].duration_since(link.went_at.expect("the token went"));
            assert!(
                safe.header.tick > 30 && after >= cfg_grace(),
                "safe mode at tick {}, {after:?} after the token went at tick 30",
                safe.header.tick
            );
        }
    }
}

fn cfg_grace() -> Duration {
    Duration::from_millis(200)
}

#[test]
fn the_loop_stops_on_deactivate_and_on_hardware_error_in_safe_mode() {
    let deadline = CommandDeadline { ticks: 5, time: None };
    // Deactivate asked by the first write of tick 10 (the latest command, written again after
    // the read): safe mode, deactivated, a normal exit. Written before: tick 0's command, then
    // at ticks 1..=9 the latest command after the read and the tick's own: 19 writes.
    let mut core = AgentCore::new(&agent_config("mem2", deadline), unit_joints()).unwrap();
    let mut link = TeamInMemory::new(1000, |_| true);
    let mut hw =
        mock().with_fault(MockFault { tick: 10, on_write: true, status: HwStatus::Deactivate });
    let report =
        driver::run(&mut core, &mut hw, &mut link, &fast(), &AtomicBool::new(false)).unwrap();
    assert_eq!((report.exit, report.cycles), (DriverExit::Deactivated { tick: 10 }, 11));
    assert_eq!(
        (core.mode(), hw.lifecycle(), hw.writes()),
        (AgentMode::SafeMode, Lifecycle::Inactive, 19)
    );
    assert_eq!(link.statuses.last().unwrap().mode, AgentMode::SafeMode);

    // A failed read at tick 3: safe mode, deactivated, a typed error.
    let mut core = AgentCore::new(&agent_config("mem3", deadline), unit_joints()).unwrap();
    let mut link = TeamInMemory::new(1000, |_| true);
    let mut hw = mock().with_fault(MockFault { tick: 3, on_write: false, status: HwStatus::Error });
    let e =
        driver::run(&mut core, &mut hw, &mut link, &fast(), &AtomicBool::new(false)).unwrap_err();
    assert!(matches!(e, DriverError::Hardware { op: "read", tick: 3 }), "{e}");
    assert_eq!((core.mode(), hw.lifecycle()), (AgentMode::SafeMode, Lifecycle::Inactive));
    assert_eq!(link.statuses.last().unwrap().mode, AgentMode::SafeMode);

    // A robot of another size is refused before it is configured.
    let mut core = AgentCore::new(&agent_config("mem4", deadline), unit_joints()).unwrap();
    let mut hw = MockHardware::new(MockConfig::new(JOINTS + 1, 0.0, DT));
    let e =
        driver::run(&mut core, &mut hw, &mut link, &fast(), &AtomicBool::new(false)).unwrap_err();
    assert!(matches!(e, DriverError::JointCount { hardware: 4, model: 3 }), "{e}");
    assert_eq!(hw.lifecycle(), Lifecycle::Unconfigured);
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

async fn next_where<M: protocol::Message>(
    q: &SampleQueue,
    within: Duration,
    pred: impl Fn(&M) -> bool,
) -> M {
    let deadline = tokio::time::Instant::now() + within;
    loop {
        let left = deadline.saturating_duration_since(tokio::time::Instant::now());
        let sample = tokio::time::timeout(left, q.recv_async())
            .await
            .expect("no matching message in time")
            .unwrap();
        if let Ok(m) = decode_sample::<M>(&sample) {
            if pred(&m) {
                return m;
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mock_robot_with_a_real_coordinator_over_zenoh() {
    let team = "hwloop1";
    let hub = format!("tcp/127.0.0.1:{}", free_port());
    let coordinator_session =
        transport::open(&ZenohArgs::listening(&hub), Role::Hub).await.unwrap();
    let (stop_coordinator, rx) = tokio::sync::watch::channel(false);
    let coordinator = {
        let s = coordinator_session.clone();
        let cfg = CoordinatorConfig::lockstep(team, Duration::from_millis(200));
        tokio::spawn(async move {
            service::run(&s, cfg, Box::new(JointDamping { damping: DAMPING }), rx).await
        })
    };
    let session = transport::open(&ZenohArgs::connecting(&hub), Role::Member).await.unwrap();
    let status = transport::subscribe(&session, keys::robot(team, ID, RobotTopic::Status).unwrap())
        .await
        .unwrap();
    let coordinator_status =
        transport::subscribe(&session, keys::coordinator_status(team).unwrap()).await.unwrap();

    // The link joins the team on the loop's thread; the loop starts once the coordinator has
    // seen the robot join, so that it answers from tick 0.
    let deadline = CommandDeadline { ticks: 5, time: Some(Duration::from_secs(5)) };
    let stop = Arc::new(AtomicBool::new(false));
    let (joined_tx, joined_rx) = std::sync::mpsc::channel();
    let (go_tx, go_rx) = std::sync::mpsc::channel::<()>();
    let driver = {
        let (session, stop) = (session.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut link = ZenohLink::declare(&session, team, ID, Qos::NeverWait).unwrap();
            joined_tx.send(()).unwrap();
            go_rx.recv().unwrap();
            let mut core = AgentCore::new(&agent_config(team, deadline), unit_joints()).unwrap();
            let mut hw = mock();
            // Period 10 ms; each command is written to the robot as soon as it arrives (it
            // comes back in well under a millisecond on an idle machine).
            let cfg = DriverConfig::new(Duration::from_millis(10));
            let report = driver::run(&mut core, &mut hw, &mut link, &cfg, &stop);
            (report, hw)
        })
    };
    tokio::task::spawn_blocking(move || joined_rx.recv().unwrap()).await.unwrap();
    next_where::<CoordinatorStatus>(&coordinator_status, Duration::from_secs(10), |s| {
        s.members.iter().any(|m| m == ID)
    })
    .await;
    go_tx.send(()).unwrap();

    // 150 ticks commanded, then the coordinator stops: safe mode at the tick deadline or when
    // its token has been gone for the agent's grace (100 ms), whichever is first (at 10 ms a
    // tick, the tick deadline usually is).
    next_where::<AgentStatus>(&status, Duration::from_secs(30), |s| s.commands_applied >= 150)
        .await;
    stop_coordinator.send(true).unwrap();
    coordinator.await.unwrap().unwrap();
    coordinator_session.close().await.unwrap();
    let stopped = Instant::now();
    let safe = next_where::<AgentStatus>(&status, Duration::from_secs(10), |s| {
        s.mode == AgentMode::SafeMode
    })
    .await;
    let last = safe.last_applied_tick.unwrap();
    assert!(
        safe.header.tick > last && safe.header.tick <= last + deadline.ticks,
        "safe mode by the deadline, 5 ticks after the last command: {safe:?}"
    );
    assert!(
        stopped.elapsed() < deadline.time.unwrap(),
        "safe mode {:?} after the coordinator stopped",
        stopped.elapsed()
    );
    assert_eq!(safe.safe_mode_entries, 1, "no safe mode while the coordinator answered");

    stop.store(true, Ordering::Release);
    let (report, hw) = tokio::task::spawn_blocking(move || driver.join().unwrap()).await.unwrap();
    let report = report.unwrap();
    assert_eq!(report.exit, DriverExit::Stopped);
    assert_eq!(report.counters.rejected, 0, "{report:?}");

    // Every tick up to the last command: that tick's damping torque, and the velocity the
    // analytic discrete decay predicts.
    let h = hw.history();
    // 150 commands applied, from tick 0: the last commanded tick is 149 or later (the bound was
    // `>= 150`, off by one: it failed on a loaded machine where the coordinator stopped right
    // after the 150th command).
    assert!(last + 1 >= 150, "150 ticks commanded, the last at tick {last}");
    for step in &h[..=last as usize] {
        assert_close(step.v[0], analytic(step.tick), &format!("v at tick {}", step.tick));
        assert_eq!(
            step.tau.as_deref(),
            Some(&[-DAMPING * step.v[0]; JOINTS][..]),
            "tick {}",
            step.tick
        );
    }
    let kd = hold_kd(f64::INFINITY);
    let entry = &h[safe.header.tick as usize];
    // The hold carries the last command applied (the damping torque of tick `last`).
    let carried = h[last as usize].tau.as_deref().unwrap()[0];
    for t in entry.tau.as_deref().unwrap() {
        assert!(
            (t - (-kd * entry.v[0] + carried)).abs() < 1e-12,
            "the posture hold after the coordinator stopped: {t}"
        );
    }
    session.close().await.unwrap();
}

/// The hardware loop with a floating-base robot that tips over at tick 20 (its base reported
/// rolled by 90 degrees): the agent falls at that state, the link leaves the team once, no terms go out
/// after it, and every torque written from then on is the limp law `-K_d qdot` of that tick's
/// velocity (the posture hold's `K_d`), not the safe mode's posture hold; the loop runs on until
/// the hardware asks to stop.
#[test]
fn a_robot_that_tips_over_is_limp_and_leaves_the_team_in_the_hardware_loop() {
    let deadline = CommandDeadline { ticks: 5, time: None };
    // A floating base (a fixed one cannot fall); no commands: the agent holds its posture in
    // safe mode (the first command's deadline is 5 ticks too) until it falls.
    let mut cfg = agent_config("mem-fall", deadline);
    cfg.first_command = deadline;
    let mut core = AgentCore::new(&cfg, PlaceholderDynamics::floating(JOINTS)).unwrap();
    let mut link = TeamInMemory::new(1000, |_| false);
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let rolled = protocol::Pose { position: [0.0, 0.0, 0.0], orientation: [h, h, 0.0, 0.0] };
    let mut hw = mock().tipped_at(20, rolled).with_fault(MockFault {
        tick: 40,
        on_write: true,
        status: HwStatus::Deactivate,
    });
    let stop = link.stop.clone();
    let report = driver::run(&mut core, &mut hw, &mut link, &fast(), &stop).unwrap();
    assert_eq!(report.exit, DriverExit::Deactivated { tick: 40 });
    assert_eq!(
        (core.mode(), core.fallen().map(|f| f.tick), link.left),
        (AgentMode::Fallen, Some(20), 1)
    );
    assert_eq!(report.counters.dynamics, 20, "terms for ticks 0..19 only");
    let kd: Vec<f64> = robot_agent::dynamics_source::DynamicsSource::torque_limits(
        &PlaceholderDynamics::floating(JOINTS),
    )
    .iter()
    .map(|l| hold_kd(*l))
    .collect();
    for step in hw.history().iter().filter(|s| s.tick >= 20 && s.tick < 40) {
        let tau = step.tau.as_ref().expect("a torque written every cycle");
        assert!(
            (tau[0] - (-kd[0] * step.v[0])).abs() <= 1e-12,
            "tick {}: {} vs -K_d v {}",
            step.tick,
            tau[0],
            -kd[0] * step.v[0]
        );
    }
    assert!(link.statuses.iter().any(|s| s.mode == AgentMode::Fallen), "the status says so");
}
