//! Separate processes on loopback exchange states, dynamics and commands through Zenoh, and
//! the coordinator reports a robot leaving when that agent's process is killed.
//!
//! Needs the release binaries: `cargo build --release --bins` (scripts/test.sh does it).

use std::time::{Duration, Instant};

use launch::processes::{free_port, spawn, ChildGuard};
use launch::smoke::SMOKE_COMMAND_DEADLINE;
use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Role, ZenohArgs};
use protocol::{CoordinatorStatus, TorqueCommand};

fn team_args(team: &str) -> Vec<String> {
    vec!["--team".into(), team.into()]
}

/// A coordinator process listening on a free loopback port, and the arguments that reach it.
fn start_coordinator(team: &str) -> (ChildGuard, ZenohArgs) {
    let hub = format!("tcp/127.0.0.1:{}", free_port().unwrap());
    let mut args = vec!["run".to_string()];
    args.extend(team_args(team));
    args.extend(ZenohArgs::listening(&hub).to_cli());
    (spawn("coordinator", &args, "coordinator").unwrap(), ZenohArgs::connecting(&hub))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn processes_exchange_messages_and_a_killed_agent_is_reported_leaving() {
    let team = "proc1";
    let (_coordinator, connect) = start_coordinator(team);

    // The test watches from its own session, as any tool would.
    let session = transport::open(&connect, Role::Member).await.unwrap();
    let status =
        transport::subscribe(&session, keys::coordinator_status(team).unwrap()).await.unwrap();
    let commands =
        transport::subscribe(&session, keys::all_robots(team, RobotTopic::Command).unwrap())
            .await
            .unwrap();
    // Count the commands as they pass, as a tool watching the team would.
    let counter = tokio::spawn(async move {
        let mut seen = [0u64; 2];
        while let Ok(Ok(sample)) =
            tokio::time::timeout(Duration::from_secs(3), commands.recv_async()).await
        {
            let cmd: TorqueCommand = decode_sample(&sample).unwrap();
            assert_eq!(cmd.tau.len(), 6);
            seen[(cmd.header.robot_id() == "r2") as usize] += 1;
        }
        seen
    });

    let mut agents = Vec::new();
    for r in ["r1", "r2"] {
        let mut args = vec![
            "run".to_string(),
            "--id".into(),
            r.into(),
            "--placeholder-joints".into(),
            "6".into(),
        ];
        args.extend([
            "--command-deadline-ms".into(),
            SMOKE_COMMAND_DEADLINE.as_millis().to_string(),
        ]);
        args.extend(team_args(team));
        args.extend(connect.to_cli());
        agents.push(spawn("robot-agent", &args, r).unwrap());
    }
    let ticks = 300;
    let mut args =
        vec!["smoke".to_string(), "--robots".into(), "r1,r2".into(), "--joints".into(), "6".into()];
    args.extend(["--ticks".into(), ticks.to_string()]);
    args.extend(team_args(team));
    args.extend(connect.to_cli());
    let mut bridge = spawn("sim-bridge", &args, "sim-bridge").unwrap();
    let exit = tokio::task::spawn_blocking(move || bridge.child.wait()).await.unwrap().unwrap();
    assert!(exit.success(), "sim-bridge failed: {exit}");

    // Every tick produced one command per robot, each checked by its agent and applied.
    let seen = counter.await.unwrap();
    assert!(seen[0] >= ticks && seen[1] >= ticks, "commands seen: {seen:?}");

    // Both are members now; then kill r2: the coordinator must report it leaving.
    let mut both = false;
    while let Ok(Some(sample)) = status.try_recv() {
        let s: CoordinatorStatus = decode_sample(&sample).unwrap();
        both |= s.members == vec!["r1".to_string(), "r2".to_string()];
    }
    assert!(both, "the coordinator never listed both robots");
    let mut r2 = agents.pop().unwrap();
    r2.child.kill().unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        assert!(!left.is_zero(), "coordinator never reported r2 leaving");
        let Ok(Ok(sample)) = tokio::time::timeout(left, status.recv_async()).await else {
            continue;
        };
        let s: CoordinatorStatus = decode_sample(&sample).unwrap();
        if s.members == vec!["r1".to_string()] {
            assert_eq!(s.detail, "robot r2 left");
            break;
        }
    }
    session.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lockstep_names_the_robot_that_never_joined() {
    let team = "proc2";
    let (_coordinator, connect) = start_coordinator(team);
    let mut args = vec![
        "run".to_string(),
        "--id".into(),
        "r1".into(),
        "--placeholder-joints".into(),
        "3".into(),
    ];
    args.extend(team_args(team));
    args.extend(connect.to_cli());
    let _agent = spawn("robot-agent", &args, "r1").unwrap();

    // The bridge itself runs in-process, so that the error is a value to inspect.
    let session = transport::open(&connect, Role::Member).await.unwrap();
    let cfg = sim_bridge::lockstep::LockstepConfig {
        team: team.into(),
        ticks: 10,
        start_timeout: Duration::from_secs(3),
        command_timeout: Duration::from_secs(1),
        resend_every: Duration::from_millis(50),
        progress_every: 0,
        wait_for_coordinator: false,
        coordinator_grace_ticks: sim_bridge::lockstep::DEFAULT_COORDINATOR_GRACE_TICKS,
        agent_loss: sim_bridge::lockstep::AgentLoss::EndRun,
        drive_timeout: sim_bridge::lockstep::DEFAULT_DRIVE_TIMEOUT,
    };
    let mut plant =
        sim_bridge::plant::PlaceholderPlant::new(vec!["r1".into(), "ghost".into()], 3, 0.0, 0.001);
    let (_tx, rx) = tokio::sync::watch::channel(false);
    let err = sim_bridge::lockstep::run(&session, &cfg, &mut plant, rx).await.unwrap_err();
    match err {
        sim_bridge::lockstep::BridgeError::MembersMissing { missing, .. } => {
            assert_eq!(missing, vec!["ghost".to_string()])
        }
        other => panic!("expected MembersMissing, got {other}"),
    }
    session.close().await.unwrap();
}
