//! Forged messages over mutual TLS with the access-control list: a team (coordinator, agents r1
//! and r2, the lockstep bridge; placeholder dynamics and plant) runs while sessions holding
//! valid certificates send well-formed messages that lie.
//!
//! * r2's identity publishes, on its own dynamics key (the ACL lets it): terms whose header
//!   says r1 (an impersonation), terms of a tick far ahead of the team, terms of the wrong size,
//!   a payload whose first length field is 2^64 - 1, and terms of ticks solved long ago.
//! * r2's identity publishes, on its own torque key, torques whose header says r1.
//! * A second session with the coordinator's identity publishes, on r1's command key, a command
//!   whose header says r2.
//!
//! Every forged message is refused where it arrives and counted: the coordinator's status
//! carries the count and the last refusal (what `team echo` prints), naming the key's sender and
//! the header's; r1's agent counts the command it rejected; the bridge counts the torques. The
//! team runs every tick. r2 publishing on r1's keys is denied by the ACL itself
//! (`access_control.rs`).

mod common;

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use coordinator::{ControllerError, JointDamping, TeamController};
use protocol::access::Identity;
use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample};
use protocol::{CoordinatorStatus, DynamicsTerms, Header, RobotState, TorqueCommand};
use robot_agent::dynamics_source::{DynamicsSource, PlaceholderDynamics};
use robot_agent::terms::{empty_terms, ActiveContacts};
use zenoh::Session;

use common::team::{agent, bridge, coordinator, stop, JOINTS};
use common::tls::{config, hub_endpoint, open};

/// Lockstep ticks of the run.
const TICKS: u64 = 600;

/// The smoke run's joint damping (`coordinator::JointDamping`), taking terms only with the
/// placeholder's size, written out: a floating base and `JOINTS` joints.
struct SizeChecked(JointDamping);

impl TeamController for SizeChecked {
    fn name(&self) -> &'static str {
        "joint damping, sizes checked"
    }

    fn solve(
        &mut self,
        tick: &[DynamicsTerms],
        out: &mut Vec<TorqueCommand>,
    ) -> Result<(), ControllerError> {
        self.0.solve(tick, out)
    }

    fn check_terms(&self, t: &DynamicsTerms) -> Result<(), ControllerError> {
        if t.nv() != 6 + JOINTS || t.velocity.len() != 6 + JOINTS {
            return Err(ControllerError::Dimension {
                what: format!("{}: terms", t.header.robot_id()),
                detail: format!("nv {} for a robot of {JOINTS} joints", t.nv()),
            });
        }
        Ok(())
    }
}

/// Whether to forge on `tick`: every 20th tick from tick 20 on (`last`: the last one forged on).
fn forge_on(tick: u64, last: &mut u64) -> bool {
    if tick < 20 || tick < *last + 20 {
        return false;
    }
    *last = tick;
    true
}

/// What the forgers sent, by kind.
#[derive(Default)]
struct Sent {
    impersonated_terms: AtomicU64,
    future_terms: AtomicU64,
    wrong_size_terms: AtomicU64,
    huge_length: AtomicU64,
    old_terms: AtomicU64,
    impersonated_torques: AtomicU64,
    impersonated_commands: AtomicU64,
}

impl Sent {
    fn count(n: &AtomicU64) -> u64 {
        n.load(Ordering::Relaxed)
    }

    /// The forged messages the coordinator must refuse (old ticks are stale, not refused).
    fn to_coordinator(&self) -> u64 {
        [&self.impersonated_terms, &self.future_terms, &self.wrong_size_terms, &self.huge_length]
            .iter()
            .map(|n| Self::count(n))
            .sum()
    }
}

/// Terms of the placeholder robot at `state`, under `robot`'s name and `tick`, with `joints`.
fn terms(state: &RobotState, robot: &str, tick: u64, joints: usize) -> DynamicsTerms {
    let mut source = PlaceholderDynamics::floating(joints);
    let mut s = state.clone();
    s.joint_positions.resize(joints, 0.0);
    s.joint_velocities.resize(joints, 0.0);
    let mut out = empty_terms(&state.header.team, robot);
    source
        .compute(&s, &ActiveContacts { stance: vec![], hand_in_grasp: false }, &mut out)
        .expect("placeholder terms");
    out.header = Header::new(&state.header.team, Some(robot), tick, protocol::wall_clock_ns());
    out.state_tick = tick;
    out
}

/// `msg` encoded, with the team name's length field (the first length of the header, after the
/// 6-byte envelope and the one-byte version) made 2^64 - 1.
fn with_huge_length(msg: &DynamicsTerms) -> Vec<u8> {
    let bytes = protocol::encode(msg).expect("encoded");
    let mut out = bytes[..7].to_vec();
    out.push(253);
    out.extend_from_slice(&u64::MAX.to_le_bytes());
    out.extend_from_slice(&bytes[8..]);
    out
}

/// As r2 (`r2`'s session): every 20th state of r2, the forged dynamics and torques.
async fn forge_as_r2(r2: Session, team: String, sent: Arc<Sent>) {
    let states = transport::subscribe(&r2, keys::robot(&team, "r2", RobotTopic::State).unwrap())
        .await
        .unwrap();
    let dynamics = keys::robot(&team, "r2", RobotTopic::Dynamics).unwrap();
    let torque = keys::robot(&team, "r2", RobotTopic::Torque).unwrap();
    let mut last = 0;
    while let Ok(sample) = states.recv_async().await {
        let Ok(state) = decode_sample::<RobotState>(&sample) else { continue };
        let k = state.header.tick;
        if !forge_on(k, &mut last) {
            continue;
        }
        let put = |key: &str, bytes: Vec<u8>| {
            let (r2, key) = (r2.clone(), key.to_string());
            async move { r2.put(key, bytes).await.expect("put") }
        };
        put(&dynamics, protocol::encode(&terms(&state, "r1", k, JOINTS)).unwrap()).await;
        sent.impersonated_terms.fetch_add(1, Ordering::Relaxed);
        put(&dynamics, protocol::encode(&terms(&state, "r2", k + 1_000_000, JOINTS)).unwrap())
            .await;
        sent.future_terms.fetch_add(1, Ordering::Relaxed);
        put(&dynamics, protocol::encode(&terms(&state, "r2", k, JOINTS + 2)).unwrap()).await;
        sent.wrong_size_terms.fetch_add(1, Ordering::Relaxed);
        put(&dynamics, with_huge_length(&terms(&state, "r2", k, JOINTS))).await;
        sent.huge_length.fetch_add(1, Ordering::Relaxed);
        put(&dynamics, protocol::encode(&terms(&state, "r2", k - 10, JOINTS)).unwrap()).await;
        sent.old_terms.fetch_add(1, Ordering::Relaxed);
        let tau = protocol::DriveCommand::torque(&team, "r1", k, vec![50.0; JOINTS]);
        put(&torque, protocol::encode(&tau).unwrap()).await;
        sent.impersonated_torques.fetch_add(1, Ordering::Relaxed);
    }
}

/// As a second coordinator (`c`'s session): every 20th state of r1, a command for r2 on r1's key.
async fn forge_as_coordinator(c: Session, team: String, sent: Arc<Sent>) {
    let states = transport::subscribe(&c, keys::robot(&team, "r1", RobotTopic::Dynamics).unwrap())
        .await
        .unwrap();
    let command = keys::robot(&team, "r1", RobotTopic::Command).unwrap();
    let mut last = 0;
    while let Ok(sample) = states.recv_async().await {
        let Ok(t) = decode_sample::<DynamicsTerms>(&sample) else { continue };
        let k = t.header.tick;
        if !forge_on(k, &mut last) {
            continue;
        }
        let cmd = TorqueCommand {
            header: Header::new(&team, Some("r2"), k, 0),
            tau: vec![50.0; JOINTS],
            hold: false,
            delay_ticks: 0,
            qdd: Vec::new(),
        };
        c.put(&command, protocol::encode(&cmd).unwrap()).await.expect("put");
        sent.impersonated_commands.fetch_add(1, Ordering::Relaxed);
    }
}

/// The first coordinator status on `statuses` that counts `refused` refusals, or the last one
/// seen when none does within `limit`.
async fn status_counting(
    statuses: &transport::SampleQueue,
    refused: u64,
    limit: Duration,
) -> CoordinatorStatus {
    let until = tokio::time::Instant::now() + limit;
    let mut last: Option<CoordinatorStatus> = None;
    while let Ok(Ok(sample)) = tokio::time::timeout_at(until, statuses.recv_async()).await {
        last = decode_sample(&sample).ok().or(last);
        if last.as_ref().is_some_and(|s| s.refused == refused) {
            break;
        }
    }
    last.expect("a coordinator status")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn forged_messages_are_refused_counted_and_named() {
    let (team, robots) = ("forged", vec!["r1".to_string(), "r2".to_string()]);
    let dir = common::certs::make("forged", &["r1", "r2"]);
    let hub = hub_endpoint();
    let any = &protocol::access::secure_endpoint("127.0.0.1", 0);
    let session = |who: Identity, listen: &str, connect: Option<&str>| {
        config(&dir, team, &robots, who, listen, connect, true)
    };
    let cs = open(&session(Identity::Coordinator, &hub, None)).await;
    let statuses =
        transport::subscribe(&cs, keys::coordinator_status(team).unwrap()).await.unwrap();
    let (a1, a2) = (
        open(&session(Identity::Agent("r1".into()), any, Some(&hub))).await,
        open(&session(Identity::Agent("r2".into()), any, Some(&hub))).await,
    );
    let r1_status = transport::subscribe(&a1, keys::robot(team, "r1", RobotTopic::Status).unwrap())
        .await
        .unwrap();
    let sim = open(&session(Identity::SimBridge, any, Some(&hub))).await;
    let (forger_r2, forger_c) = (
        open(&session(Identity::Agent("r2".into()), any, Some(&hub))).await,
        open(&session(Identity::Coordinator, any, Some(&hub))).await,
    );

    let c = coordinator(&cs, team, Box::new(SizeChecked(JointDamping { damping: 2.0 })));
    let agents = [agent(&a1, team, "r1"), agent(&a2, team, "r2")];
    let b = bridge(
        &sim,
        team,
        &["r1", "r2"],
        TICKS,
        sim_bridge::lockstep::DEFAULT_COORDINATOR_GRACE_TICKS,
    );
    let sent = Arc::new(Sent::default());
    let forgers = [
        tokio::spawn(forge_as_r2(forger_r2.clone(), team.into(), sent.clone())),
        tokio::spawn(forge_as_coordinator(forger_c.clone(), team.into(), sent.clone())),
    ];

    let report = tokio::time::timeout(Duration::from_secs(120), b.task)
        .await
        .expect("the run ends in time")
        .expect("bridge task")
        .expect("every tick ran");
    forgers.iter().for_each(|f| f.abort());
    // What was sent arrives (reliable links); the coordinator publishes its status at least every
    // second, so within three seconds a status counts every refusal.
    let status = status_counting(&statuses, sent.to_coordinator(), Duration::from_secs(3)).await;
    let [r1, r2] = agents;
    let (r1, r2) = (stop(r1).await, stop(r2).await);
    let counters = stop(c).await;
    let mut r1_last_rejection = None;
    while let Ok(Some(s)) = r1_status.try_recv() {
        if let Ok(st) = decode_sample::<protocol::AgentStatus>(&s) {
            r1_last_rejection = st.last_rejection.or(r1_last_rejection);
        }
    }
    println!("sent: {} terms as r1, {} ahead, {} of the wrong size, {} with a huge length, {} old; {} torques as r1; {} commands as r2", Sent::count(&sent.impersonated_terms), Sent::count(&sent.future_terms), Sent::count(&sent.wrong_size_terms), Sent::count(&sent.huge_length), Sent::count(&sent.old_terms), Sent::count(&sent.impersonated_torques), Sent::count(&sent.impersonated_commands));
    println!(
        "coordinator: {counters:?}\nlast status: refused {}, {:?}\nbridge: {report:?}\nr1: {r1:?}",
        status.refused, status.last_refusal
    );

    assert_eq!(report.ticks, TICKS, "the team ran every tick");
    assert!(
        Sent::count(&sent.impersonated_terms) >= 10
            && Sent::count(&sent.impersonated_commands) >= 10,
        "the forgers ran through the run"
    );
    assert_eq!(
        counters.refused,
        sent.to_coordinator(),
        "the coordinator refused every forged dynamics message and nothing else"
    );
    assert_eq!(status.refused, counters.refused, "the status carries the count");
    let named = status.last_refusal.as_deref().unwrap_or("");
    assert!(
        named.contains("team/forged/robot/r2/dynamics"),
        "the last refusal names the key: {named}"
    );
    assert_eq!(
        report.rejected_torques,
        Sent::count(&sent.impersonated_torques),
        "the bridge refused every torque forged for r1"
    );
    assert_eq!(
        r1.rejected,
        Sent::count(&sent.impersonated_commands),
        "r1's agent refused every command forged for r2 on its key"
    );
    assert!(
        r1_last_rejection.as_deref().is_some_and(
            |w| w.contains("robot r1 of team forged") && w.contains("robot r2 of team forged")
        ),
        "r1's status names both senders: {r1_last_rejection:?}"
    );
    println!("r2: {r2:?}");
    for s in [a1, a2, sim, forger_r2, forger_c, cs] {
        s.close().await.unwrap();
    }
    let _ = std::fs::remove_dir_all(&dir);
}
