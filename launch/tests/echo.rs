//! `team echo` against live sessions: a JSON key (the coordinator's status, published through
//! the project's transport on another session) prints as its JSON message, and the
//! coordinator's liveliness key prints the token's coming and going.

use std::time::Duration;

use launch::echo::{echo, EchoOptions};
use protocol::transport::{self, Qos, Role, TypedPublisher, ZenohArgs};
use protocol::{CoordinatorMode, CoordinatorStatus, Header};

const TEAM: &str = "echotest";

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

fn lines(out: &[u8]) -> Vec<serde_json::Value> {
    String::from_utf8_lossy(out)
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn echo_prints_messages_and_liveliness_tokens() {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let hub =
        transport::open(&ZenohArgs::listening(&endpoint), Role::Alone).await.expect("hub listens");
    let tool = transport::open(&ZenohArgs::connecting(&endpoint), Role::Alone)
        .await
        .expect("tool connects");

    // A status published every 20 ms until echo has two.
    let key = protocol::keys::coordinator_status(TEAM).unwrap();
    let mut publisher =
        TypedPublisher::<CoordinatorStatus>::declare(&hub, key.clone(), Qos::Telemetry)
            .await
            .unwrap();
    let publishing = tokio::spawn(async move {
        for tick in 0..500u64 {
            let st = CoordinatorStatus {
                header: Header::new(TEAM, None, tick, 0),
                mode: CoordinatorMode::Running,
                members: vec!["r1".into()],
                ticks: tick,
                commands_sent: 0,
                deadline_misses: 0,
                fallbacks: 0,
                detail: String::new(),
                stale: vec![],
                silent: vec![],
                late: vec![],
                reused_terms: 0,
                refused: 0,
                last_refusal: None,
            };
            publisher.put(&st).await.unwrap();
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    });
    let mut out = Vec::new();
    let opts = EchoOptions { key: key.clone(), count: Some(2), wait: Duration::from_secs(10) };
    assert_eq!(echo(&tool, &opts, &mut out).await.expect("echo of the status"), 2);
    publishing.abort();
    let got = lines(&out);
    assert_eq!(got.len(), 2);
    assert_eq!(got[0]["key"], key.as_str());
    assert_eq!(got[0]["message"]["mode"], "Running");
    assert!(
        got[0]["encoding"]
            .as_str()
            .unwrap()
            .contains(&format!("team.CoordinatorStatus/v{}", protocol::PROTOCOL_VERSION)),
        "{}",
        got[0]
    );

    // The coordinator's liveliness token: present (history), then gone.
    let token = transport::declare_coordinator(&hub, TEAM).await.unwrap();
    let alive_key = protocol::keys::coordinator_alive(TEAM).unwrap();
    let opts =
        EchoOptions { key: alive_key.clone(), count: Some(2), wait: Duration::from_secs(10) };
    let dropping = tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(1500)).await;
        drop(token);
    });
    let mut out = Vec::new();
    assert_eq!(echo(&tool, &opts, &mut out).await.expect("echo of the token"), 2);
    dropping.await.unwrap();
    let got = lines(&out);
    assert_eq!(got[0], serde_json::json!({ "key": alive_key, "alive": true }));
    assert_eq!(got[1], serde_json::json!({ "key": alive_key, "alive": false }));

    // Nothing on a key: an error naming it, after the wait.
    let opts = EchoOptions {
        key: format!("team/{TEAM}/references"),
        count: Some(1),
        wait: Duration::from_millis(300),
    };
    let err = echo(&tool, &opts, &mut Vec::new()).await.unwrap_err();
    assert!(err.to_string().contains("team/echotest/references"), "{err}");
}
