//! Access control with Zenoh mutual TLS and the team's ACL (`protocol::access`,
//! README "Access control (mutual TLS and ACL)"): real Zenoh sessions over TLS on loopback,
//! certificates made by `scripts/make-test-certs.sh` into a temporary folder, and a real
//! `robot-agent` process.
//!
//! * A component without a certificate from the team's CA (plain TCP, TLS without a client
//!   certificate, a certificate from another CA) cannot open a link: nothing it puts arrives,
//!   while the same put from a certified, allowed identity does.
//! * A component with a valid certificate but no right to publish `.../robot/r1/command` (the
//!   `tool` identity, running with no ACL of its own) sends well-formed commands for r1: r1's
//!   agent never applies them (no torque with their values, its status counts none applied);
//!   the same command from the coordinator's identity is applied.
//! * Agent r2's identity cannot publish r1's state, torque or dynamics, while its own keys
//!   arrive.
//! * The grants are enough for a whole team: a distributed smoke run over TLS with the ACL
//!   (`team smoke --tls`, the launcher's `RunMode::Tls`) completes every tick.
//!
//! Needs the release binaries (`cargo build --release --bins`) and openssl. Each test has its
//! own ports and folder; every wait is bounded.

mod common;
use common::tls::{config, hub_endpoint, open};

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use launch::processes::spawn;
use protocol::access::Identity;
use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, SampleQueue, TypedPublisher, ZenohArgs};
use protocol::{AgentStatus, DriveCommand, Header, Pose, RobotState, TorqueCommand};
use zenoh::Session;

/// How long a put that must not arrive is given to arrive anyway.
const NEVER_WAIT: Duration = Duration::from_millis(1500);
/// How long a put that must arrive may take (links, declarations).
const ARRIVE_WAIT: Duration = Duration::from_secs(10);

/// A fresh folder with test certificates for these robots (`common::certs`).
fn certificates(test: &str, robots: &[&str]) -> PathBuf {
    common::certs::make(&format!("acl-{test}"), robots)
}

fn robots(list: &[&str]) -> Vec<String> {
    list.iter().map(|r| r.to_string()).collect()
}

/// Put `payload` on `key` from `session` every 50 ms until `until` says stop or `wait` ends.
async fn put_until(
    session: &Session,
    key: &str,
    payload: &[u8],
    wait: Duration,
    mut until: impl FnMut() -> bool,
) {
    let deadline = Instant::now() + wait;
    while Instant::now() < deadline && !until() {
        let _ = session.put(key, payload.to_vec()).await;
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// The samples that arrived on `queue` so far, as (key, payload).
fn drain(queue: &SampleQueue) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    while let Ok(Some(s)) = queue.try_recv() {
        out.push((s.key_expr().to_string(), s.payload().to_bytes().to_vec()));
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_component_without_a_certificate_cannot_connect() {
    let (team, rs) = ("acl1", robots(&["r1"]));
    let dir = certificates("nocert", &["r1"]);
    let other_ca = certificates("otherca", &["r1"]);
    let hub = hub_endpoint();
    let plain_hub = hub.replacen("quic/", "tcp/", 1);
    let coordinator = open(&config(&dir, team, &rs, Identity::Coordinator, &hub, None, true)).await;
    let references =
        transport::subscribe(&coordinator, keys::references(team).unwrap()).await.unwrap();
    let key = keys::references(team).unwrap();

    // Plain TCP to the hub's port (it takes QUIC only); TLS with the CA but no certificate of its own; a runner
    // certificate from another CA.
    let plain = open(&ZenohArgs::connecting(&plain_hub)).await;
    let anonymous_cfg = dir.join("anonymous.json5");
    let anonymous_json = serde_json::json!({
        "mode": "peer", "scouting": { "multicast": { "enabled": false } },
        "listen": { "endpoints": [] }, "connect": { "endpoints": [hub] },
        "transport": { "link": { "tls": { "root_ca_certificate": dir.join("ca.pem").display().to_string() } } },
    });
    std::fs::write(&anonymous_cfg, anonymous_json.to_string()).unwrap();
    let anonymous = open(&ZenohArgs { config: Some(anonymous_cfg), ..Default::default() }).await;
    let foreign = open(&config(
        &other_ca,
        team,
        &rs,
        Identity::Runner,
        &protocol::access::secure_endpoint("127.0.0.1", 0),
        Some(&hub),
        false,
    ))
    .await;

    let intruders = [
        ("plain tcp", &plain),
        ("tls without a certificate", &anonymous),
        ("a certificate from another CA", &foreign),
    ];
    let started = Instant::now();
    while started.elapsed() < NEVER_WAIT {
        for (_, s) in &intruders {
            let _ = s.put(&key, b"intruder".to_vec()).await;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    for (what, s) in &intruders {
        let peers: Vec<_> = s.info().peers_zid().await.collect();
        assert!(peers.is_empty(), "{what}: a link was opened to {peers:?}");
    }
    let got = drain(&references);
    assert!(got.is_empty(), "puts without a team certificate arrived: {got:?}");

    // The control: the runner's certificate from the team's CA, allowed to put references.
    let runner = open(&config(
        &dir,
        team,
        &rs,
        Identity::Runner,
        &protocol::access::secure_endpoint("127.0.0.1", 0),
        Some(&hub),
        true,
    ))
    .await;
    let mut arrived = Vec::new();
    put_until(&runner, &key, b"runner", ARRIVE_WAIT, || {
        arrived.extend(drain(&references));
        !arrived.is_empty()
    })
    .await;
    assert!(
        arrived.iter().any(|(_, p)| p == b"runner"),
        "the certified runner's put never arrived: the test proves nothing"
    );
    assert!(arrived.iter().all(|(_, p)| p == b"runner"), "{arrived:?}");
    for s in [plain, anonymous, foreign, runner, coordinator] {
        s.close().await.unwrap();
    }
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&other_ca);
}

const JOINTS: usize = 3;

fn state(team: &str, robot: &str, tick: u64) -> RobotState {
    RobotState {
        header: Header::new(team, Some(robot), tick, protocol::wall_clock_ns()),
        base_pose: Pose::IDENTITY,
        base_twist: [0.0; 6],
        joint_positions: vec![0.0; JOINTS],
        joint_velocities: vec![0.0; JOINTS],
        time: tick as f64 * 0.005,
        foot_forces: Vec::new(),
        object_pose: None,
    }
}

/// The torques every test command carries: no posture hold computes them.
const TAU: [f64; JOINTS] = [0.25, -0.5, 0.75];

fn command(team: &str, robot: &str, tick: u64) -> TorqueCommand {
    TorqueCommand {
        header: Header::new(team, Some(robot), tick, 0),
        tau: TAU.to_vec(),
        hold: false,
        delay_ticks: 0,
        qdd: Vec::new(),
    }
}

/// Publish r1's state for `tick` until r1's agent answers with its dynamics for that tick.
async fn state_answered(
    sim: &mut TypedPublisher<RobotState>,
    dynamics: &SampleQueue,
    team: &str,
    tick: u64,
) {
    let deadline = Instant::now() + ARRIVE_WAIT;
    loop {
        assert!(Instant::now() < deadline, "r1's agent never answered the state of tick {tick}");
        sim.put(&state(team, "r1", tick)).await.unwrap();
        let Ok(Ok(s)) =
            tokio::time::timeout(Duration::from_millis(200), dynamics.recv_async()).await
        else {
            continue;
        };
        let terms: protocol::DynamicsTerms = decode_sample(&s).unwrap();
        if terms.header.tick == tick {
            return;
        }
    }
}

/// The torques with [`TAU`] that reached the sim-bridge, by tick.
fn commanded_torques(torques: &SampleQueue) -> Vec<u64> {
    let mut ticks = Vec::new();
    while let Ok(Some(s)) = torques.try_recv() {
        let t: DriveCommand = decode_sample(&s).unwrap();
        if t.tau_ff == TAU {
            ticks.push(t.header.tick);
        }
    }
    ticks
}

/// r1's latest status within `wait` that satisfies `ok` (or the last one seen).
async fn status_where(
    status: &SampleQueue,
    wait: Duration,
    ok: impl Fn(&AgentStatus) -> bool,
) -> Option<AgentStatus> {
    let deadline = Instant::now() + wait;
    let mut last = None;
    while let Some(left) = deadline.checked_duration_since(Instant::now()) {
        let Ok(Ok(s)) = tokio::time::timeout(left, status.recv_async()).await else { break };
        let st: AgentStatus = decode_sample(&s).unwrap();
        let done = ok(&st);
        last = Some(st);
        if done {
            break;
        }
    }
    last
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_the_coordinator_commands_a_robot() {
    let (team, rs) = ("acl2", robots(&["r1"]));
    let dir = certificates("command", &["r1"]);
    let hub = hub_endpoint();
    let any = &protocol::access::secure_endpoint("127.0.0.1", 0);
    let coordinator = open(&config(&dir, team, &rs, Identity::Coordinator, &hub, None, true)).await;
    let members = transport::watch_members(&coordinator, team).await.unwrap();
    let dynamics =
        transport::subscribe(&coordinator, keys::robot(team, "r1", RobotTopic::Dynamics).unwrap())
            .await
            .unwrap();
    let sim = open(&config(&dir, team, &rs, Identity::SimBridge, any, Some(&hub), true)).await;
    let torques = transport::subscribe(&sim, keys::robot(team, "r1", RobotTopic::Torque).unwrap())
        .await
        .unwrap();
    let mut states = TypedPublisher::<RobotState>::declare(
        &sim,
        keys::robot(team, "r1", RobotTopic::State).unwrap(),
        Qos::HotPath,
    )
    .await
    .unwrap();
    // The forger: a valid certificate (tool), and no ACL of its own.
    let tool = open(&config(&dir, team, &rs, Identity::Tool, any, Some(&hub), false)).await;
    let status = transport::subscribe(&tool, keys::robot(team, "r1", RobotTopic::Status).unwrap())
        .await
        .unwrap();

    let agent_cfg = config(&dir, team, &rs, Identity::Agent("r1".into()), any, Some(&hub), true);
    let mut args: Vec<String> = [
        "run",
        "--id",
        "r1",
        "--team",
        team,
        "--placeholder-joints",
        "3",
        "--command-deadline-ms",
        "5000",
    ]
    .map(String::from)
    .to_vec();
    args.extend(["--command-deadline-ticks".into(), "0".into()]);
    args.extend(agent_cfg.to_cli());
    let _agent = spawn("robot-agent", &args, "robot-agent r1").unwrap();
    let joined = tokio::time::timeout(ARRIVE_WAIT, members.recv_async()).await;
    assert!(matches!(joined, Ok(Ok(_))), "r1's agent never joined over TLS");

    // Forged commands for tick 1, from the tool's identity, after r1 has tick 1's state.
    state_answered(&mut states, &dynamics, team, 1).await;
    let command_key = keys::robot(team, "r1", RobotTopic::Command).unwrap();
    let forged = protocol::encode(&command(team, "r1", 1)).unwrap();
    put_until(&tool, &command_key, &forged, NEVER_WAIT, || false).await;
    assert_eq!(
        commanded_torques(&torques),
        Vec::<u64>::new(),
        "a command from the tool's identity was applied"
    );
    let st = status_where(&status, ARRIVE_WAIT, |s| s.states_received >= 1)
        .await
        .expect("the tool reads r1's status");
    assert_eq!(
        (st.commands_applied, st.commands_rejected),
        (0, 0),
        "the forged commands reached the agent: {st:?}"
    );

    // The same command from the coordinator's identity, for tick 2: applied.
    state_answered(&mut states, &dynamics, team, 2).await;
    let mut publisher =
        TypedPublisher::<TorqueCommand>::declare(&coordinator, command_key, Qos::HotPath)
            .await
            .unwrap();
    publisher.put(&command(team, "r1", 2)).await.unwrap();
    let deadline = Instant::now() + ARRIVE_WAIT;
    let mut applied = Vec::new();
    while applied.is_empty() && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
        applied = commanded_torques(&torques);
    }
    assert_eq!(
        applied,
        vec![2],
        "the coordinator's command was not applied: the test proves nothing"
    );
    let st = status_where(&status, ARRIVE_WAIT, |s| s.commands_applied >= 1).await.unwrap();
    assert_eq!(st.commands_applied, 1, "{st:?}");
    for s in [tool, sim, coordinator] {
        s.close().await.unwrap();
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_agent_cannot_publish_another_robots_keys() {
    let (team, rs) = ("acl3", robots(&["r1", "r2"]));
    let dir = certificates("impersonate", &["r1", "r2"]);
    let hub = hub_endpoint();
    let any = &protocol::access::secure_endpoint("127.0.0.1", 0);
    let coordinator = open(&config(&dir, team, &rs, Identity::Coordinator, &hub, None, true)).await;
    let dynamics =
        transport::subscribe(&coordinator, keys::all_robots(team, RobotTopic::Dynamics).unwrap())
            .await
            .unwrap();
    let sim = open(&config(&dir, team, &rs, Identity::SimBridge, any, Some(&hub), true)).await;
    let torques = transport::subscribe(&sim, keys::all_robots(team, RobotTopic::Torque).unwrap())
        .await
        .unwrap();
    let r1 =
        open(&config(&dir, team, &rs, Identity::Agent("r1".into()), any, Some(&hub), true)).await;
    let r1_states = transport::subscribe(&r1, keys::robot(team, "r1", RobotTopic::State).unwrap())
        .await
        .unwrap();
    // r2 runs without the ACL: only the others' rules stand between it and r1's keys.
    let r2 =
        open(&config(&dir, team, &rs, Identity::Agent("r2".into()), any, Some(&hub), false)).await;

    let key = |robot, topic| keys::robot(team, robot, topic).unwrap();
    let forged = [
        key("r1", RobotTopic::State),
        key("r1", RobotTopic::Torque),
        key("r1", RobotTopic::Dynamics),
    ];
    let own = [key("r2", RobotTopic::Torque), key("r2", RobotTopic::Dynamics)];
    let mut seen: Vec<(String, Vec<u8>)> = Vec::new();
    let deadline = Instant::now() + ARRIVE_WAIT;
    let mut controls_at = None;
    // Until the controls (r2's own keys at the bridge and the coordinator, the bridge's state
    // at r1) have arrived, and NEVER_WAIT longer.
    while Instant::now() < deadline && controls_at.is_none_or(|t: Instant| t.elapsed() < NEVER_WAIT)
    {
        for k in forged.iter().chain(&own) {
            r2.put(k, b"from r2".to_vec()).await.unwrap();
        }
        sim.put(&forged[0], b"from sim-bridge".to_vec()).await.unwrap();
        tokio::time::sleep(Duration::from_millis(50)).await;
        for q in [&dynamics, &torques, &r1_states] {
            seen.extend(drain(q));
        }
        let arrived = |k: &String, p: &[u8]| seen.iter().any(|(sk, sp)| sk == k && sp == p);
        if controls_at.is_none()
            && own.iter().all(|k| arrived(k, b"from r2"))
            && arrived(&forged[0], b"from sim-bridge")
        {
            controls_at = Some(Instant::now());
        }
    }
    assert!(controls_at.is_some(), "the controls never arrived (r2's own keys, the bridge's state): the test proves nothing; seen {seen:?}");
    let mut leaked: Vec<&String> = seen
        .iter()
        .filter(|(k, p)| forged.contains(k) && p == b"from r2")
        .map(|(k, _)| k)
        .collect();
    leaked.sort();
    leaked.dedup();
    assert!(leaked.is_empty(), "r2 published r1's keys: {leaked:?}");
    for s in [r2, r1, sim, coordinator] {
        s.close().await.unwrap();
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `config/zenoh/` is what `team zenoh-config certs` writes (team `team`, robots r1 and r2,
/// the hub on quic/127.0.0.1:7447): the shipped files follow the rules.
#[test]
fn the_shipped_configurations_are_the_generated_ones() {
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/zenoh");
    let configs = protocol::access::team_configs(
        Path::new("certs"),
        "team",
        &robots(&["r1", "r2"]),
        "quic/127.0.0.1:7447",
    );
    assert_eq!(configs.len(), 6);
    for cfg in configs {
        let path = shipped.join(protocol::access::file_name(&cfg.identity));
        let text =
            std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let file: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(
            file,
            cfg.to_json().unwrap(),
            "{} differs from the generator (team zenoh-config certs)",
            path.display()
        );
    }
}

/// Every process of a team (coordinator, two agents, the sim-bridge, the runner) over mutual
/// TLS with the ACL: the lockstep runs every tick (a missing grant would leave a robot out).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_whole_team_runs_over_tls_with_the_acl() {
    use launch::launcher::{BridgeOutcome, RunMode};
    use launch::smoke::{self, SmokeConfig};
    let dir = certificates("smoke", &["r1", "r2"]);
    let run_dir = dir.join("run");
    std::fs::create_dir_all(&run_dir).unwrap();
    let cfg = SmokeConfig {
        team: "team".into(),
        robots: robots(&["r1", "r2"]),
        joints: 6,
        ticks: 300,
        dt: 0.001,
        damping: 2.0,
        v0: 0.5,
    };
    let mode = RunMode::Tls { dir: run_dir.clone(), certs: dir.clone() };
    let outcome = tokio::time::timeout(Duration::from_secs(60), smoke::run(&cfg, &mode))
        .await
        .expect("the run ends in time");
    assert!(
        matches!(outcome, Ok(BridgeOutcome::Process)),
        "the TLS smoke run failed: {:?}",
        outcome.err()
    );
    for who in ["coordinator", "r1", "r2", "sim-bridge", "runner"] {
        assert!(run_dir.join(format!("zenoh-{who}.json5")).is_file(), "no configuration for {who}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
