//! The latency cost of mutual TLS and the ACL on the hot path: a state goes from the
//! sim-bridge's identity to robot r1's, which answers with a torque command, between two Zenoh
//! sessions on loopback: over plain TCP, over mutual TLS alone (QUIC links, as every secure
//! run), and over mutual TLS with the
//! team's access control, in alternating blocks of one run (so all see the same machine load).
//! Prints percentiles of the round trip.
//!
//! `cargo run --release -p team-tests --example tls_round_trip [-- ROUNDS_PER_BLOCK BLOCKS FLOATS]`
//! (FLOATS: the size of both messages in f64s, 18 by default, a 24-DoF dynamics message is
//! about 1000)
//! (needs openssl; certificates are made into a temporary folder).

#[path = "../tests/common/certs.rs"]
mod certs;

use std::path::Path;
use std::time::{Duration, Instant};

use launch::processes::free_port;
use protocol::access::{secure_endpoint, Identity, SecureConfig};
use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, Role, SampleQueue, TypedPublisher, ZenohArgs};
use protocol::{DriveCommand, Header, Pose, RobotState};
use zenoh::Session;

const TEAM: &str = "rtt";
const JOINTS: usize = 18;

/// One pair of sessions: the bridge's side (publishes states, receives torques) and r1's
/// (answers each state with a torque), with r1's answering task.
struct Pair {
    name: &'static str,
    bridge: Session,
    r1: Session,
    states: TypedPublisher<RobotState>,
    torques: SampleQueue,
    samples: Vec<f64>,
}

/// Mutual TLS, with the ACL or without it.
#[derive(Clone, Copy)]
enum Link {
    Tcp,
    Tls,
    TlsAcl,
}

fn secure(
    certs: &Path,
    who: Identity,
    listen: &str,
    connect: Option<&str>,
    acl: bool,
) -> ZenohArgs {
    let mut cfg = SecureConfig::in_dir(certs, TEAM, &["r1".to_string()], who);
    cfg.listen = vec![listen.to_string()];
    cfg.connect = connect.map(|c| vec![c.to_string()]).unwrap_or_default();
    let mut json = cfg.to_json().expect("configuration");
    if !acl {
        json.as_object_mut().expect("an object").remove("access_control");
    }
    let path = certs.join(format!("{}-{acl}.json5", cfg.identity.name()));
    std::fs::write(&path, json.to_string()).expect("configuration written");
    ZenohArgs { config: Some(path), ..Default::default() }
}

async fn pair(name: &'static str, link: Link, certs: &Path, floats: usize) -> Pair {
    let port = free_port().expect("a free port");
    let (bridge_args, r1_args) = match link {
        Link::Tls | Link::TlsAcl => {
            let (hub, acl) = (secure_endpoint("127.0.0.1", port), matches!(link, Link::TlsAcl));
            let any = secure_endpoint("127.0.0.1", 0);
            (
                secure(certs, Identity::SimBridge, &hub, None, acl),
                secure(certs, Identity::Agent("r1".into()), &any, Some(&hub), acl),
            )
        }
        Link::Tcp => {
            let hub = format!("tcp/127.0.0.1:{port}");
            (ZenohArgs::listening(&hub), ZenohArgs::connecting(&hub))
        }
    };
    let bridge = transport::open(&bridge_args, Role::Member).await.expect("bridge session");
    let r1 = transport::open(&r1_args, Role::Member).await.expect("r1 session");
    let torques =
        transport::subscribe(&bridge, keys::robot(TEAM, "r1", RobotTopic::Torque).unwrap())
            .await
            .unwrap();
    let states = TypedPublisher::declare(
        &bridge,
        keys::robot(TEAM, "r1", RobotTopic::State).unwrap(),
        Qos::HotPath,
    )
    .await
    .unwrap();
    let incoming = transport::subscribe(&r1, keys::robot(TEAM, "r1", RobotTopic::State).unwrap())
        .await
        .unwrap();
    let mut out = TypedPublisher::<DriveCommand>::declare(
        &r1,
        keys::robot(TEAM, "r1", RobotTopic::Torque).unwrap(),
        Qos::HotPath,
    )
    .await
    .unwrap();
    tokio::spawn(async move {
        while let Ok(sample) = incoming.recv_async().await {
            let Ok(state) = decode_sample::<RobotState>(&sample) else { continue };
            let cmd = DriveCommand::torque(TEAM, "r1", state.header.tick, vec![0.1; floats]);
            let _ = out.put(&cmd).await;
        }
    });
    Pair { name, bridge, r1, states, torques, samples: Vec::new() }
}

fn state(tick: u64, floats: usize) -> RobotState {
    RobotState {
        header: Header::new(TEAM, Some("r1"), tick, protocol::wall_clock_ns()),
        base_pose: Pose::IDENTITY,
        base_twist: [0.0; 6],
        joint_positions: vec![0.0; floats / 2],
        joint_velocities: vec![0.0; floats / 2],
        time: 0.0,
        foot_forces: vec![0.0; 4],
        object_pose: None,
    }
}

/// One round trip (state out, the torque of that tick back), seconds; `None` after 2 s.
async fn round_trip(p: &mut Pair, tick: u64, floats: usize) -> Option<f64> {
    let t0 = Instant::now();
    p.states.put(&state(tick, floats)).await.ok()?;
    loop {
        let s = tokio::time::timeout(Duration::from_secs(2), p.torques.recv_async())
            .await
            .ok()?
            .ok()?;
        let cmd: DriveCommand = decode_sample(&s).ok()?;
        if cmd.header.tick == tick {
            return Some(t0.elapsed().as_secs_f64());
        }
    }
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let args: Vec<u64> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let (rounds, blocks) =
        (args.first().copied().unwrap_or(500), args.get(1).copied().unwrap_or(6));
    let floats = args.get(2).map_or(JOINTS, |&f| f as usize);
    let certs = certs::make("tls-rtt", &["r1"]);
    let mut pairs = [
        pair("tcp", Link::Tcp, &certs, floats).await,
        pair("mtls", Link::Tls, &certs, floats).await,
        pair("mtls+acl", Link::TlsAcl, &certs, floats).await,
    ];
    let mut tick = 0;
    // Links and declarations first: the first answered state on each pair.
    for p in pairs.iter_mut() {
        let deadline = Instant::now() + Duration::from_secs(10);
        while round_trip(p, tick, floats).await.is_none() {
            assert!(Instant::now() < deadline, "{}: no answer within 10 s", p.name);
            tick += 1;
        }
        tick += 1;
    }
    for b in 0..blocks * 3 {
        let p = &mut pairs[(b % 3) as usize];
        for _ in 0..rounds {
            tick += 1;
            if let Some(s) = round_trip(p, tick, floats).await {
                p.samples.push(s * 1e6);
            }
        }
    }
    println!("state -> torque round trip between two sessions on loopback, {floats} f64 each way, {rounds} x {blocks} rounds each, alternating blocks:");
    for p in pairs.iter_mut() {
        p.samples.sort_by(f64::total_cmp);
        let s = &p.samples;
        if s.is_empty() {
            println!("  {:8} no round trip completed", p.name);
            continue;
        }
        let mean = s.iter().sum::<f64>() / s.len().max(1) as f64;
        println!(
            "  {:8} n={:5}  p50 {:6.0} us  p90 {:6.0} us  p99 {:6.0} us  max {:6.0} us  mean {:6.0} us",
            p.name,
            s.len(),
            percentile(s, 0.5),
            percentile(s, 0.9),
            percentile(s, 0.99),
            s[s.len() - 1],
            mean
        );
    }
    for p in pairs {
        let _ = p.r1.close().await;
        let _ = p.bridge.close().await;
    }
    let _ = std::fs::remove_dir_all(&certs);
}
