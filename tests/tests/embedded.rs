//! The embedded mode: every component in one process on one Zenoh session, closed loop.

use launch::launcher::{BridgeOutcome, RunMode};
use launch::smoke::{self, SmokeConfig};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn embedded_team_closes_the_loop_exactly() {
    let cfg = SmokeConfig {
        team: "embedded1".into(),
        robots: vec!["r1".into(), "r2".into(), "r3".into()],
        joints: 18,
        ticks: 400,
        dt: 0.001,
        damping: 5.0,
        v0: 0.5,
    };
    let BridgeOutcome::Smoke { report, final_velocities } =
        smoke::run(&cfg, &RunMode::Embedded).await.unwrap()
    else {
        panic!("an embedded smoke run reports the plant's figures")
    };
    assert_eq!(report.ticks, 400);
    assert!((report.sim_time - 0.4).abs() < 1e-9);
    // Every tick's torques came from that tick's state: the plant's velocity is exactly the
    // analytic discrete decay. A lost, repeated or out-of-order tick would change it.
    let expected = cfg.expected_final_velocity();
    assert_eq!(final_velocities.len(), 3);
    for v in final_velocities {
        assert!((v - expected).abs() < 1e-12, "v = {v}, expected {expected}");
    }
}
