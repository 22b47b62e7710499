//! The multi-robot QP baseline (MQP) in closed loop with MuJoCo: the whole stack (one agent
//! per robot, the coordinator running MQP over Zenoh) holds the constant pose of experiment
//! S3 within S4's bounds (object never dropped, palm slip < 5 mm, object position RMS < 1 cm,
//! orientation RMS < 2 deg, torso position RMS < 1 cm), with Clarabel solving (almost) every
//! tick and the hands squeezing. Short (2 s after 0.5 s of settling) so that CI stays fast.
//!
//! The report is written to `target/test-reports/s3-hold-mqp/`.

use std::path::{Path, PathBuf};

use evaluation::evaluate;
use launch::run::{self, RunOptions};
use scenario::file::Scenario;
use scenario::plan;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("repo root").to_path_buf()
}

#[test]
fn mqp_holds_the_constant_pose_in_mujoco() {
    let sets: Vec<String> =
        ["controller=mqp", "duration=2.0", "settle=0.5"].iter().map(|s| s.to_string()).collect();
    let scenario =
        Scenario::load(repo().join("scenarios/s3_hold.toml"), &sets).expect("scenario loads");
    let plan = plan::plan(&scenario, &repo()).expect("plan");
    assert_eq!(plan.controller.kind(), "mqp");
    let dir = repo().join("target/test-reports/s3-hold-mqp");
    std::fs::create_dir_all(&dir).expect("report dir");
    let records = run::run(
        &plan,
        &RunOptions { distributed: false, hosts: false, progress: false, loss: Vec::new() },
        &dir,
    )
    .expect("the run completes");
    let eval = evaluate::evaluate(&plan, &records, "embedded");
    evaluate::write_report(&plan, &eval, &dir).expect("report written");
    let m = &eval.metrics;
    println!("{}", evaluate::summary(m, &dir));
    for c in &m.checks {
        assert!(c.passed, "MQP hold: {} = {:.5} not below {}", c.name, c.value, c.bound);
    }
    assert!(m.passed && !m.drop.dropped);
    assert_eq!(m.samples as u64, plan.scene.ticks, "a ground-truth sample for every scenario tick");
    let solved = m.qp_status.get("Solved").copied().unwrap_or(0)
        + m.qp_status.get("AlmostSolved").copied().unwrap_or(0);
    let total: u64 = m.qp_status.values().sum();
    assert!(total as f64 >= 0.9 * plan.scene.ticks as f64, "diagnostics of {total} ticks");
    assert!(solved as f64 >= 0.99 * total as f64, "QP statuses {:?}", m.qp_status);
    for (r, f) in &m.mean_squeeze_n {
        assert!(*f > 0.8 * plan.scenario.min_hand_force, "{r} squeezes {f} N only");
    }
}
