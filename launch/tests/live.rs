//! `team run --live`: the recorder's Foxglove WebSocket server advertises the run's channels
//! to a client (a plain WebSocket client speaking Foxglove's `foxglove.sdk.v1` subprotocol).

use std::path::{Path, PathBuf};
use std::time::Duration;

use futures_util::StreamExt;
use launch::record::{RecordOptions, RecordedMessage, Recorder, RunFacts, ScenarioSource};
use scenario::file::Scenario;
use scenario::plan;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::Message as Ws;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("repo root").to_path_buf()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_websocket_client_sees_the_channels_advertised() {
    let plan = plan::plan(
        &Scenario::load(repo().join("scenarios/s4_object_circle.toml"), &["duration=0.1".into()])
            .unwrap(),
        &repo(),
    )
    .unwrap();
    let dir = std::env::temp_dir().join(format!("live-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let opts = RecordOptions {
        path: dir.join("run.mcap"),
        scenario: ScenarioSource::default(),
        live: Some(0),
        split: None,
    };
    let recorder = Recorder::start(&plan, &opts).await.expect("recorder with a live server");
    let port = recorder.live_port().expect("a port");
    let tap = recorder.tap();
    let mut g = sim_bridge::ground_truth::empty("team");
    g.header.tick = 0;
    tap.send("team/team/ground-truth", RecordedMessage::Truth(g));

    let mut req = format!("ws://127.0.0.1:{port}").into_client_request().unwrap();
    req.headers_mut().insert("sec-websocket-protocol", "foxglove.sdk.v1".parse().unwrap());
    let (mut ws, _) =
        tokio::time::timeout(Duration::from_secs(10), tokio_tungstenite::connect_async(req))
            .await
            .expect("connects in time")
            .expect("handshake");
    let mut advertised = Vec::new();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while !advertised.iter().any(|t: &String| t == "team/team/ground-truth") {
        let msg = tokio::time::timeout_at(deadline, ws.next()).await.unwrap_or_else(|_| {
            panic!("no advertisement of the ground truth in 10 s; saw {advertised:?}")
        });
        let Some(Ok(Ws::Text(text))) = msg else { continue };
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        if v["op"] == "advertise" {
            for c in v["channels"].as_array().unwrap() {
                assert!(c["schemaName"].as_str().is_some());
                advertised.push(c["topic"].as_str().unwrap().to_string());
            }
        }
    }
    drop(ws);
    drop(tap);
    let summary = tokio::task::block_in_place(|| recorder.finish(&RunFacts::default())).unwrap();
    assert_eq!((summary.messages, summary.dropped), (1, 0));
    std::fs::remove_dir_all(&dir).unwrap();
}
