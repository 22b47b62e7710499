//! A lockstep run never waits without bound (the teams issue): a controller that fails a
//! tick still commands every robot (hold orders, said in the diagnostics); an agent that
//! leaves ends the run at once, naming its robot; when the coordinator leaves, the agents hold
//! their posture after its grace (`COORDINATOR_GRACE`) and the run ends after a grace counted in simulated ticks; a member
//! whose token vanishes is waited for a bounded grace (its link may come back), one that says
//! it leaves is not.
//!
//! Every component runs in this process on one Zenoh session (the embedded mode), each with
//! its own stop signal so that one can be taken away mid-run. The plant is the placeholder
//! (the subject is the message flow, not the physics); the failing controller is a test
//! double of the controller only, the service around it is the real one.

use std::time::{Duration, Instant};

use coordinator::{ControllerError, TeamController};
use protocol::keys;
use protocol::transport::{self, decode_sample};
use protocol::{DynamicsTerms, TickDiagnostics, TorqueCommand};
use sim_bridge::lockstep::BridgeError;

mod common;
use common::team::{agent, bridge, coordinator, session, stop, JOINTS};

/// Joint damping that fails every `every`-th tick with a controller error.
struct FailsEvery {
    every: u64,
}

impl TeamController for FailsEvery {
    fn name(&self) -> &'static str {
        "fails every n-th tick"
    }

    fn solve(
        &mut self,
        tick: &[DynamicsTerms],
        out: &mut Vec<TorqueCommand>,
    ) -> Result<(), ControllerError> {
        let t = tick[0].header.tick;
        if t % self.every == self.every - 1 {
            return Err(ControllerError::NonFinite {
                robot: "team".into(),
                what: format!("torque (made to fail at tick {t})"),
            });
        }
        out.clear();
        for terms in tick {
            let v = &terms.velocity[terms.nv() - terms.actuated()..];
            out.push(TorqueCommand {
                header: protocol::Header::new(
                    &terms.header.team,
                    terms.header.robot.as_deref(),
                    t,
                    0,
                ),
                tau: v.iter().map(|qd| -2.0 * qd).collect(),
                hold: false,
                delay_ticks: 0,
                qdd: Vec::new(),
            });
        }
        Ok(())
    }
}

/// Joint damping that takes `pause` to solve tick `tick` (a coordinator busy with one tick);
/// `paused` turns true when that solve begins.
struct PausesAt {
    tick: u64,
    pause: Duration,
    paused: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

impl TeamController for PausesAt {
    fn name(&self) -> &'static str {
        "pauses at one tick"
    }

    fn solve(
        &mut self,
        tick: &[DynamicsTerms],
        out: &mut Vec<TorqueCommand>,
    ) -> Result<(), ControllerError> {
        if tick[0].header.tick == self.tick {
            self.paused.store(true, std::sync::atomic::Ordering::Release);
            std::thread::sleep(self.pause);
        }
        FailsEvery { every: u64::MAX }.solve(tick, out)
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failing_controller_still_commands_every_robot() {
    let team = "hang1";
    let s = session().await;
    let diags = transport::subscribe(&s, keys::diagnostics(team).unwrap()).await.unwrap();
    let c = coordinator(&s, team, Box::new(FailsEvery { every: 10 }));
    let agents = [agent(&s, team, "r1"), agent(&s, team, "r2")];
    let started = Instant::now();
    let b = bridge(&s, team, &["r1", "r2"], 200, 500);
    let report = tokio::time::timeout(Duration::from_secs(60), b.task)
        .await
        .expect("bounded")
        .unwrap()
        .expect("the run completes");
    assert_eq!(report.ticks, 200);
    assert!(
        started.elapsed() < Duration::from_secs(30),
        "no deadline was waited out: {:?}",
        started.elapsed()
    );
    // Agents first: the coordinator's leaving would put them in safe mode.
    for a in agents {
        let counters = stop(a).await;
        assert_eq!(counters.hold_torques, 20, "a hold for each failed tick");
        assert_eq!(counters.safe_mode_entries, 0, "no robot was left without a command");
    }
    let coordinator = stop(c).await;
    assert_eq!(coordinator.controller_errors, 20, "ticks 9, 19, ... failed");
    assert_eq!(
        coordinator.commands_sent, 400,
        "every robot commanded on every tick, failed ticks included"
    );
    let mut holds = 0;
    while let Ok(Some(sample)) = diags.try_recv() {
        let d: TickDiagnostics = decode_sample(&sample).unwrap();
        if let Some(f) = &d.fallback {
            assert!(f.contains("controller error") && f.contains("holds its posture"), "{f}");
            assert_eq!(d.header.tick % 10, 9);
            holds += 1;
        }
    }
    assert_eq!(holds, 20, "the diagnostics say so for each failed tick");
    s.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_agent_that_leaves_ends_the_run_at_once_naming_it() {
    let team = "hang2";
    let s = session().await;
    let c = coordinator(&s, team, Box::new(FailsEvery { every: u64::MAX }));
    let r1 = agent(&s, team, "r1");
    let r2 = agent(&s, team, "r2");
    let b = bridge(&s, team, &["r1", "r2"], 1_000_000, 500);
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert!(!b.task.is_finished(), "the run is going");
    let left = Instant::now();
    stop(r2).await;
    let err = tokio::time::timeout(Duration::from_secs(10), b.task)
        .await
        .expect("bounded")
        .unwrap()
        .expect_err("the run ends");
    let waited = left.elapsed();
    match err {
        BridgeError::RobotLeft { robot, tick } => {
            assert_eq!(robot, "r2");
            assert!(tick > 0);
        }
        other => panic!("expected RobotLeft, got {other}"),
    }
    // The command timeout is 60 s: the run ended on the liveliness event, not on a deadline.
    assert!(waited < Duration::from_secs(5), "took {waited:?}");
    stop(r1).await;
    stop(c).await;
    s.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn when_the_coordinator_leaves_the_robots_hold_and_the_run_ends_after_the_grace_in_ticks() {
    let team = "hang3";
    let grace = 300;
    let s = session().await;
    let c = coordinator(&s, team, Box::new(FailsEvery { every: u64::MAX }));
    let agents = [agent(&s, team, "r1"), agent(&s, team, "r2")];
    let b = bridge(&s, team, &["r1", "r2"], 1_000_000, grace);
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let gone = Instant::now();
    stop(c).await;
    let err = tokio::time::timeout(Duration::from_secs(30), b.task)
        .await
        .expect("bounded")
        .unwrap()
        .expect_err("the run ends");
    match err {
        BridgeError::CoordinatorLost { since, ticks } => {
            assert!(since > 0);
            assert_eq!(ticks, grace, "the grace is counted in ticks");
        }
        other => panic!("expected CoordinatorLost, got {other}"),
    }
    assert!(gone.elapsed() < Duration::from_secs(20), "took {:?}", gone.elapsed());
    // The outage runs at the wall clock's pace: the grace's 300 ticks of 1 ms took at least
    // about 0.3 s (the last is not paced; the holds alone ran at several thousand a second).
    assert!(
        gone.elapsed() >= Duration::from_millis(grace * 9 / 10),
        "the outage's ticks were paced: {:?}",
        gone.elapsed()
    );
    for a in agents {
        let counters = stop(a).await;
        assert_eq!(
            counters.safe_mode_entries, 1,
            "safe mode once, the coordinator's grace after its token went"
        );
        // Every tick of the grace but possibly the one on which the bridge saw the token go
        // (the agent may have applied the coordinator's last command for it).
        assert!(
            counters.hold_torques >= grace - 1,
            "the robots held their posture through the grace: {}",
            counters.hold_torques
        );
    }
    s.close().await.unwrap();
}

/// The terms of robot `robot` for `tick` (a fixed-base 3-joint arm at rest).
fn terms(team: &str, robot: &str, tick: u64) -> DynamicsTerms {
    let mut mass_matrix = protocol::Matrix::zeros(JOINTS, JOINTS);
    for i in 0..JOINTS {
        mass_matrix.data[i * JOINTS + i] = 1.0;
    }
    DynamicsTerms {
        header: protocol::Header::new(team, Some(robot), tick, protocol::wall_clock_ns()),
        floating_base: false,
        nv: JOINTS as u32,
        mass_matrix,
        bias: vec![0.0; JOINTS],
        velocity: vec![0.0; JOINTS],
        frames: Vec::new(),
        hand_in_grasp: false,
        state_tick: tick,
        team_delay_ticks: 0,
        object_pose: None,
    }
}

/// The first command on `queue` within 10 s (resending `terms` every 50 ms meanwhile: the
/// coordinator's subscriber may not be matched yet).
async fn first_command(
    queue: &transport::SampleQueue,
    publisher: &mut transport::TypedPublisher<DynamicsTerms>,
    terms: &DynamicsTerms,
) -> TorqueCommand {
    let until = Instant::now() + Duration::from_secs(10);
    while Instant::now() < until {
        publisher.put(terms).await.unwrap();
        tokio::time::sleep(Duration::from_millis(50)).await;
        if let Ok(Some(sample)) = queue.try_recv() {
            return decode_sample(&sample).unwrap();
        }
    }
    panic!("no command for {} within 10 s", terms.header.robot_id());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn terms_that_beat_their_robots_token_are_answered_with_a_hold() {
    // Before, such a tick was dropped and the robot waited out its time deadline (30 s).
    let team = "hang4";
    let s = session().await;
    let c = coordinator(&s, team, Box::new(FailsEvery { every: u64::MAX }));
    let commands =
        transport::subscribe(&s, keys::robot(team, "r7", keys::RobotTopic::Command).unwrap())
            .await
            .unwrap();
    let mut publisher = transport::TypedPublisher::declare(
        &s,
        keys::robot(team, "r7", keys::RobotTopic::Dynamics).unwrap(),
        transport::Qos::HotPath,
    )
    .await
    .unwrap();
    let cmd = first_command(&commands, &mut publisher, &terms(team, "r7", 7)).await;
    assert!(cmd.hold, "a hold order: {cmd:?}");
    assert_eq!((cmd.header.robot_id(), cmd.header.tick), ("r7", 7));
    let counters = stop(c).await;
    assert!(counters.rejected_terms >= 1, "the terms were not a tick of the team");
    assert_eq!(counters.ticks, 0, "no tick was solved with them");
    s.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_controller_that_is_not_ready_still_commands_the_tick() {
    // PIDC needs every member's description; r8 is a member (its token) that never sent one.
    let team = "hang5";
    let s = session().await;
    let diags = transport::subscribe(&s, keys::diagnostics(team).unwrap()).await.unwrap();
    let c =
        coordinator(&s, team, Box::new(coordinator::Pidc::new(coordinator::PidcConfig::default())));
    let _token = transport::declare_member(&s, team, "r8").await.unwrap();
    let commands =
        transport::subscribe(&s, keys::robot(team, "r8", keys::RobotTopic::Command).unwrap())
            .await
            .unwrap();
    let mut publisher = transport::TypedPublisher::declare(
        &s,
        keys::robot(team, "r8", keys::RobotTopic::Dynamics).unwrap(),
        transport::Qos::HotPath,
    )
    .await
    .unwrap();
    // Until the token is seen the terms are answered as a non-member's; then as a member's.
    let mut tick = 0;
    let cmd = loop {
        tick += 1;
        let cmd = first_command(&commands, &mut publisher, &terms(team, "r8", tick)).await;
        assert!(cmd.hold, "a hold order: {cmd:?}");
        if tokio::time::timeout(Duration::from_millis(200), async {
            loop {
                if let Ok(Some(sample)) = diags.try_recv() {
                    return decode_sample::<TickDiagnostics>(&sample).unwrap();
                }
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
        })
        .await
        .is_ok_and(|d| {
            d.fallback.as_deref().is_some_and(|f| f.contains("not ready") && f.contains("r8"))
        }) {
            break cmd;
        }
        assert!(tick < 50, "the coordinator never took r8's terms as a member's");
    };
    assert_eq!(cmd.header.robot_id(), "r8");
    let counters = stop(c).await;
    assert!(counters.not_ready >= 1 && counters.commands_sent >= 1, "{counters:?}");
    s.close().await.unwrap();
}

/// The latest coordinator status on `queue` within 5 s that `pred` accepts.
async fn status_where(
    queue: &transport::SampleQueue,
    pred: impl Fn(&protocol::CoordinatorStatus) -> bool,
    what: &str,
) -> protocol::CoordinatorStatus {
    let until = Instant::now() + Duration::from_secs(5);
    while Instant::now() < until {
        match tokio::time::timeout(Duration::from_millis(50), queue.recv_async()).await {
            Ok(Ok(sample)) => {
                let st: protocol::CoordinatorStatus = decode_sample(&sample).unwrap();
                if pred(&st) {
                    return st;
                }
            }
            Ok(Err(_)) => break,
            Err(_) => {}
        }
    }
    panic!("no coordinator status within 5 s: {what}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_vanished_token_is_waited_for_and_an_announced_leave_is_not() {
    use coordinator::team::membership::DEPARTURE_GRACE;
    let team = "hang6";
    let s = session().await;
    let statuses = transport::subscribe(&s, keys::coordinator_status(team).unwrap()).await.unwrap();
    let c = coordinator(&s, team, Box::new(FailsEvery { every: u64::MAX }));
    let mut tokens = member_tokens(&s, team).await.map(Some);
    let (queues, mut pubs) = both_members(&s, team, &statuses).await;
    // Tick 1, the team's first: both commanded.
    put_terms(&mut pubs, team, 1).await;
    for q in &queues {
        let cmd: TorqueCommand = decode_sample(
            &tokio::time::timeout(Duration::from_secs(5), q.recv_async())
                .await
                .expect("a command")
                .unwrap(),
        )
        .unwrap();
        assert_eq!((cmd.header.tick, cmd.hold), (1, false), "{cmd:?}");
    }
    // r2's token vanishes and comes back (a link that dropped): tick 2 waits for r2's terms and
    // is solved with both; no status leaves r2 out.
    tokens[1].take().unwrap().undeclare().await.unwrap();
    pubs[0].put(&terms(team, "r1", 2)).await.unwrap();
    tokens[1] = Some(transport::declare_member(&s, team, "r2").await.unwrap());
    pubs[1].put(&terms(team, "r2", 2)).await.unwrap();
    for q in &queues {
        let cmd: TorqueCommand = decode_sample(
            &tokio::time::timeout(Duration::from_secs(5), q.recv_async())
                .await
                .expect("a command")
                .unwrap(),
        )
        .unwrap();
        assert_eq!((cmd.header.tick, cmd.hold), (2, false), "tick 2 solved with both: {cmd:?}");
    }
    // The statuses said the token vanished, then came back, and never left r2 out.
    let vanished = status_where(
        &statuses,
        |st| st.detail.starts_with("robot r2's token vanished"),
        "r2's token vanished",
    )
    .await;
    let back =
        status_where(&statuses, |st| st.detail == "robot r2 joined", "r2's token back").await;
    for st in [&vanished, &back] {
        assert!(
            st.late.is_empty() && st.silent.is_empty() && st.members.len() == 2,
            "r2 never left: {st:?}"
        );
    }
    // r2 says it leaves (its dynamics key deleted) with its token still held: out at once.
    pubs[1].delete().await.unwrap();
    let st = status_where(&statuses, |st| st.detail == "robot r2 left", "r2 leaves").await;
    assert_eq!(st.silent, vec!["r2".to_string()], "left out until its token goes: {st:?}");
    pubs[0].put(&terms(team, "r1", 3)).await.unwrap();
    let cmd: TorqueCommand = decode_sample(
        &tokio::time::timeout(Duration::from_secs(5), queues[0].recv_async())
            .await
            .expect("a command")
            .unwrap(),
    )
    .unwrap();
    assert_eq!((cmd.header.tick, cmd.hold), (3, false), "tick 3 solved without r2: {cmd:?}");
    // r1's token vanishes for good: it has left once the grace has passed, not before.
    let gone = Instant::now();
    tokens[0].take().unwrap().undeclare().await.unwrap();
    let st =
        status_where(&statuses, |st| st.detail == "robot r1 left", "r1 leaves after the grace")
            .await;
    assert!(
        gone.elapsed() >= DEPARTURE_GRACE,
        "r1 left {:?} after its token vanished, before the grace {DEPARTURE_GRACE:?}",
        gone.elapsed()
    );
    assert_eq!(
        st.members,
        vec!["r2".to_string()],
        "r1 gone, r2 (its token held) still listed: {st:?}"
    );
    stop(c).await;
    s.close().await.unwrap();
}

/// A command lost on the way (a link that dropped just after the coordinator sent it): the
/// agent's terms of that tick come again (the bridge republishes the state it waits on, or the
/// coordinator reappears), and the coordinator sends that robot's command of the tick again,
/// not the other's; terms of an older tick get nothing; a robot that joined after the tick was
/// solved gets a hold order for it. Without the repeat a lockstep run
/// waited out the agents' 20 s deadline (found resetting a robot's link across test hosts).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn terms_sent_again_for_the_tick_last_solved_get_its_command_again() {
    let team = "hang7";
    let s = session().await;
    let statuses = transport::subscribe(&s, keys::coordinator_status(team).unwrap()).await.unwrap();
    let c = coordinator(&s, team, Box::new(FailsEvery { every: u64::MAX }));
    let _tokens = member_tokens(&s, team).await;
    let (queues, mut pubs) = both_members(&s, team, &statuses).await;
    for tick in [1, 2] {
        put_terms(&mut pubs, team, tick).await;
        for q in &queues {
            let cmd = next_command(q).await.expect("a command");
            assert_eq!((cmd.header.tick, cmd.hold), (tick, false), "{cmd:?}");
        }
    }
    // r1's terms of tick 2 again: its command of tick 2 again, the same torques; none for r2.
    pubs[0].put(&terms(team, "r1", 2)).await.unwrap();
    let again = next_command(&queues[0]).await.expect("r1's command of tick 2 sent again");
    assert_eq!((again.header.tick, again.hold, again.tau.len()), (2, false, JOINTS));
    assert!(next_command(&queues[1]).await.is_none(), "r2 asked nothing");
    // Terms of tick 1, older than the last solved: dropped, nothing sent.
    pubs[0].put(&terms(team, "r1", 1)).await.unwrap();
    assert!(
        next_command(&queues[0]).await.is_none(),
        "no command for a tick older than the last solved"
    );
    // r3 joins after tick 2 was solved without it and sends its terms of tick 2 (a restarted
    // agent's first state; the lockstep bridge waits for its torques of that tick): a hold order
    // for tick 2, not silence (before: lockstep waited out the 20 s deadline,
    // faults.rs an_agent_restarted...).
    let (q3, mut p3) = robot_keys(&s, team, "r3").await;
    let _t3 = transport::declare_member(&s, team, "r3").await.unwrap();
    status_where(&statuses, |st| st.members.len() == 3, "r3 a member").await;
    p3.put(&terms(team, "r3", 2)).await.unwrap();
    let held = next_command(&q3).await.expect("r3 answered for tick 2");
    assert_eq!(
        (held.header.tick, held.hold),
        (2, true),
        "a hold order for the tick solved without it: {held:?}"
    );
    let counters = stop(c).await;
    assert_eq!(counters.repeated_commands, 1, "{counters:?}");
    s.close().await.unwrap();
}

/// Terms of a tick sent twice while the coordinator is busy with the tick before (in lockstep
/// the bridge republishes the states it waits on and each agent answers them): when the tick
/// completes, the copies are still queued and are read before it is solved. They get nothing;
/// the solve answers both robots once. Before, each copy got a hold order for the tick, which
/// reached the robot before its command: it held its posture mid-step and refused the command
/// as not newer (walking.rs a_team_that_lets_go... fell in 3 of 4 runs).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn terms_sent_again_before_their_tick_is_solved_get_only_its_command() {
    let team = "hang8";
    let s = session().await;
    let statuses = transport::subscribe(&s, keys::coordinator_status(team).unwrap()).await.unwrap();
    let paused = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let c = coordinator(
        &s,
        team,
        Box::new(PausesAt { tick: 1, pause: Duration::from_secs(1), paused: paused.clone() }),
    );
    let _tokens = member_tokens(&s, team).await;
    let (queues, mut pubs) = both_members(&s, team, &statuses).await;
    put_terms(&mut pubs, team, 1).await;
    // Once the coordinator is inside tick 1's solve (for 1 s), tick 2's terms and their copies
    // queue.
    let until = Instant::now() + Duration::from_secs(10);
    while !paused.load(std::sync::atomic::Ordering::Acquire) {
        assert!(Instant::now() < until, "tick 1 not solved within 10 s");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    for _ in 0..2 {
        put_terms(&mut pubs, team, 2).await;
    }
    for (q, r) in queues.iter().zip(["r1", "r2"]) {
        for tick in [1, 2] {
            let cmd =
                next_command(q).await.unwrap_or_else(|| panic!("{r}: no command for tick {tick}"));
            assert_eq!(
                (cmd.header.tick, cmd.hold),
                (tick, false),
                "{r}: the solved command of tick {tick}, nothing before it: {cmd:?}"
            );
        }
        assert!(next_command(q).await.is_none(), "{r}: one command per tick");
    }
    let counters = stop(c).await;
    assert_eq!(
        (counters.held, counters.repeated_commands, counters.ticks),
        (0, 0, 2),
        "{counters:?}"
    );
    s.close().await.unwrap();
}

/// The next command on `queue`, if one comes within 2 s.
async fn next_command(queue: &transport::SampleQueue) -> Option<TorqueCommand> {
    let sample = tokio::time::timeout(Duration::from_secs(2), queue.recv_async()).await.ok()?;
    Some(decode_sample(&sample.expect("the queue is open")).expect("a command"))
}

/// The membership tokens of stand-in robots r1 and r2 in `team` (members while kept).
async fn member_tokens(s: &zenoh::Session, team: &str) -> [zenoh::liveliness::LivelinessToken; 2] {
    [
        transport::declare_member(s, team, "r1").await.unwrap(),
        transport::declare_member(s, team, "r2").await.unwrap(),
    ]
}

/// Stand-in robots r1 and r2, members of `team` (their tokens declared): their command queues
/// and terms publishers ([`robot_keys`]), once the coordinator's status lists both.
async fn both_members(
    s: &zenoh::Session,
    team: &str,
    statuses: &transport::SampleQueue,
) -> (Vec<transport::SampleQueue>, Vec<transport::TypedPublisher<DynamicsTerms>>) {
    let (mut queues, mut pubs) = (Vec::new(), Vec::new());
    for r in ["r1", "r2"] {
        let (q, p) = robot_keys(s, team, r).await;
        queues.push(q);
        pubs.push(p);
    }
    status_where(statuses, |st| st.members.len() == 2, "both members").await;
    (queues, pubs)
}

/// [`both_members`]' terms of `tick`, r1's then r2's.
async fn put_terms(pubs: &mut [transport::TypedPublisher<DynamicsTerms>], team: &str, tick: u64) {
    for (p, r) in pubs.iter_mut().zip(["r1", "r2"]) {
        p.put(&terms(team, r, tick)).await.unwrap();
    }
}

/// A stand-in robot's two keys: the queue of its commands and the publisher of its terms.
async fn robot_keys(
    s: &zenoh::Session,
    team: &str,
    robot: &str,
) -> (transport::SampleQueue, transport::TypedPublisher<DynamicsTerms>) {
    let commands =
        transport::subscribe(s, keys::robot(team, robot, keys::RobotTopic::Command).unwrap())
            .await
            .unwrap();
    let dynamics = transport::TypedPublisher::declare(
        s,
        keys::robot(team, robot, keys::RobotTopic::Dynamics).unwrap(),
        transport::Qos::HotPath,
    )
    .await
    .unwrap();
    (commands, dynamics)
}

/// The team's delay is the team's: r1 asks for 1 tick and r2 for 3, and both robots' commands
/// of the tick come with 3 (each robot's own would have them apply the team's answers of
/// different ticks at once); when r2 asks for none, the next tick's come with r1's 1.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_command_of_a_tick_carries_the_longest_delay_its_robots_asked_for() {
    let team = "hang9";
    let s = session().await;
    let statuses = transport::subscribe(&s, keys::coordinator_status(team).unwrap()).await.unwrap();
    let c = coordinator(&s, team, Box::new(FailsEvery { every: u64::MAX }));
    let _tokens = member_tokens(&s, team).await;
    let (queues, mut pubs) = both_members(&s, team, &statuses).await;
    for (tick, asked, team_delay) in [(1, [1, 3], 3), (2, [1, 0], 1)] {
        for ((p, r), d) in pubs.iter_mut().zip(["r1", "r2"]).zip(asked) {
            p.put(&DynamicsTerms { team_delay_ticks: d, ..terms(team, r, tick) }).await.unwrap();
        }
        for (q, r) in queues.iter().zip(["r1", "r2"]) {
            let cmd =
                next_command(q).await.unwrap_or_else(|| panic!("{r}: no command for tick {tick}"));
            assert_eq!(
                (cmd.header.tick, cmd.delay_ticks),
                (tick, team_delay),
                "{r}, asked {asked:?}: {cmd:?}"
            );
        }
    }
    let _ = stop(c).await;
    s.close().await.unwrap();
}

/// A lockstep coordinator configured to wait for the first task references (what `team run`
/// gives it, so that a coordinator started inside a run never commands the tasks toward the
/// poses they happened to have), with joint damping as its controller.
fn coordinator_waiting_for_references(
    s: &zenoh::Session,
    team: &str,
    wait: Duration,
) -> common::team::Component<coordinator::service::CoordinatorCounters> {
    let (stop, rx) = tokio::sync::watch::channel(false);
    let mut cfg = coordinator::service::CoordinatorConfig::lockstep(team, Duration::from_secs(5));
    cfg.wait_for_references = Some(wait);
    let s = s.clone();
    common::team::Component {
        stop,
        task: tokio::spawn(async move {
            coordinator::service::run(&s, cfg, Box::new(FailsEvery { every: u64::MAX }), rx)
                .await
                .expect("coordinator runs")
        }),
    }
}

/// The ticks robot r1 was told to hold and those it was commanded (its command key; joint
/// damping has no diagnostics), read until `done` says they are enough (at most 20 s); every
/// held tick's diagnostics must say it waited for the references.
async fn held_for_references(
    commands: &transport::SampleQueue,
    diags: &transport::SampleQueue,
    done: impl Fn(&[u64], &[u64]) -> bool,
) -> (Vec<u64>, Vec<u64>) {
    let (mut held, mut solved) = (Vec::new(), Vec::new());
    let until = Instant::now() + Duration::from_secs(20);
    while !done(&held, &solved) && Instant::now() < until {
        let Ok(Ok(sample)) =
            tokio::time::timeout(Duration::from_secs(1), commands.recv_async()).await
        else {
            continue;
        };
        let c: TorqueCommand = decode_sample(&sample).unwrap();
        if c.hold {
            held.push(c.header.tick)
        } else {
            solved.push(c.header.tick)
        }
    }
    while let Ok(Some(sample)) = diags.try_recv() {
        let d: TickDiagnostics = decode_sample(&sample).unwrap();
        let f = d.fallback.unwrap_or_default();
        assert!(
            f.contains("waiting for the task references") && f.contains("holds its posture"),
            "tick {}: only the references were waited for: {f}",
            d.header.tick
        );
    }
    (held, solved)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_coordinator_waiting_for_references_holds_the_team_until_they_come() {
    let team = "hang-refs";
    let s = session().await;
    let diags = transport::subscribe(&s, keys::diagnostics(team).unwrap()).await.unwrap();
    let commands =
        transport::subscribe(&s, keys::robot(team, "r1", keys::RobotTopic::Command).unwrap())
            .await
            .unwrap();
    let mut refs = transport::TypedPublisher::declare(
        &s,
        keys::references(team).unwrap(),
        transport::Qos::Telemetry,
    )
    .await
    .unwrap();
    let c = coordinator_waiting_for_references(&s, team, Duration::from_secs(60));
    let agents = [agent(&s, team, "r1"), agent(&s, team, "r2")];
    let b = bridge(&s, team, &["r1", "r2"], 1_000_000, 500);
    // Without references every tick is answered with hold orders, saying why.
    let (held, solved) =
        held_for_references(&commands, &diags, |h, s| h.len() >= 50 || !s.is_empty()).await;
    assert!(
        held.len() >= 50 && solved.is_empty(),
        "held {} ticks for the references, solved {solved:?}",
        held.len()
    );
    // The first references end the wait: every tick from then on is solved.
    let r = protocol::TaskReferences {
        header: protocol::Header::new(team, None, 0, 0),
        object: None,
        torsos: Vec::new(),
        swing_feet: Vec::new(),
        foot_loads: Vec::new(),
    };
    refs.put(&r).await.unwrap();
    let (held_after, solved) = held_for_references(&commands, &diags, |_, s| s.len() >= 50).await;
    assert!(solved.len() >= 50, "solved {} ticks after the references came", solved.len());
    let first = solved[0];
    assert!(
        held_after.iter().all(|t| *t < first),
        "no tick is held for the references once one is solved: held {held_after:?} from {first}"
    );
    stop(b).await.ok();
    for a in agents {
        let counters = stop(a).await;
        assert_eq!(
            counters.safe_mode_entries, 0,
            "every robot was commanded every tick, holds included"
        );
    }
    stop(c).await;
    s.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn references_that_never_come_are_waited_for_no_longer_than_the_limit() {
    let team = "hang-norefs";
    let s = session().await;
    let diags = transport::subscribe(&s, keys::diagnostics(team).unwrap()).await.unwrap();
    let commands =
        transport::subscribe(&s, keys::robot(team, "r1", keys::RobotTopic::Command).unwrap())
            .await
            .unwrap();
    let c = coordinator_waiting_for_references(&s, team, Duration::from_millis(1500));
    let agents = [agent(&s, team, "r1"), agent(&s, team, "r2")];
    let b = bridge(&s, team, &["r1", "r2"], 1_000_000, 500);
    let (held, solved) = held_for_references(&commands, &diags, |_, s| s.len() >= 50).await;
    assert!(!held.is_empty(), "the ticks before the limit were held for the references");
    assert!(
        solved.len() >= 50,
        "after the limit the ticks are solved without references: {} solved",
        solved.len()
    );
    assert!(held.iter().all(|t| *t < solved[0]), "held {held:?}, solved from {}", solved[0]);
    stop(b).await.ok();
    for a in agents {
        stop(a).await;
    }
    stop(c).await;
    s.close().await.unwrap();
}
