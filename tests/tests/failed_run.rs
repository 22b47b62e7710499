//! A run that ends in an error after some ticks still reports them. S4 whose two agents both
//! die 0.5 s into the scenario (no restart): a robot whose agent dies goes on unpowered, and
//! once every agent has left the bridge ends the run ("robot ..'s agent left the team at tick
//! .."). The run returns that error with the records of the ticks it saw; evaluated over them,
//! the report names the error and never passes, and so does its recording read back (`team
//! report run.mcap`). `team run` writes that report and exits with the error.
//!
//! The second test runs the `team` binary: it needs the release binaries
//! (`cargo build --release --bins`).

use std::path::{Path, PathBuf};
use std::process::Command;

use evaluation::evaluate;
use launch::processes::sibling_binary;
use launch::record::{RecordOptions, ScenarioSource};
use launch::run::{self, RunOptions};
use scenario::file::Scenario;
use scenario::plan::{self, Plan};

mod common;
use common::scenario::{repo, report_dir};

/// Both agents die at 0.5 s: the run ends in an error 0.5 s before its end.
const FAULTS: &str = "faults=[{kind=\"agent-stops\",robot=\"r1\",at=0.5},\
                      {kind=\"agent-stops\",robot=\"r2\",at=0.5}]";
const SETS: [&str; 3] = ["duration=1.0", "settle=0.5", FAULTS];
const SCENARIO: &str = "scenarios/s4_object_circle.toml";
/// What the bridge's error says.
const LEFT: &str = "agent left the team";

fn losing_every_agent() -> Plan {
    let sets: Vec<String> = SETS.iter().map(|s| s.to_string()).collect();
    let scenario = Scenario::load(repo().join(SCENARIO), &sets).expect("scenario loads");
    plan::plan(&scenario, &repo()).expect("plan")
}

/// An empty report folder for the run called `name`.
fn fresh(name: &str) -> PathBuf {
    let dir = report_dir(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("report dir");
    dir
}

/// The report folder's `metrics.json`.
fn metrics(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("metrics.json")).expect("metrics.json written");
    serde_json::from_str(&text).expect("metrics.json is JSON")
}

/// The metrics name the error, never pass, and count the ticks seen: into the scenario, short
/// of the plan's end.
fn assert_failed_report(json: &serde_json::Value, plan: &Plan) {
    let error = json["error"].as_str().unwrap_or_default();
    assert!(error.contains(LEFT), "the error in metrics.json: {error:?}");
    assert_eq!(json["passed"].as_bool(), Some(false), "a run with an error never passes");
    let seen = json["ticks_seen"].as_u64().expect("ticks_seen");
    let settle = plan.references.clock.settle_ticks;
    assert!(
        seen > settle && seen < plan.total_ticks(),
        "{seen} ticks seen: past the {settle} of settling, short of {}",
        plan.total_ticks()
    );
    assert_eq!(json["ticks_planned"].as_u64(), Some(plan.total_ticks()));
    assert!(json["samples"].as_u64().unwrap_or(0) > 0, "the scenario ticks before the error");
    let checks = json["checks"].as_array().expect("checks");
    assert!(
        checks
            .iter()
            .any(|c| c["passed"] == false && c["name"].as_str().unwrap_or("").contains(LEFT)),
        "a failed check names the error: {checks:?}"
    );
}

#[test]
fn a_run_that_loses_every_agent_returns_its_error_with_the_ticks_it_saw() {
    let plan = losing_every_agent();
    let dir = fresh("failed-run");
    let opts = RunOptions { distributed: false, hosts: false, progress: false, loss: Vec::new() };
    let sets: Vec<String> = SETS.iter().map(|s| s.to_string()).collect();
    let rec = RecordOptions {
        path: dir.join("run.mcap"),
        scenario: ScenarioSource::read(&repo().join(SCENARIO), &sets, scenario::Pacing::Lockstep)
            .expect("scenario file"),
        live: None,
        split: None,
    };
    let failed =
        run::run_recorded(&plan, &opts, &dir, Some(&rec)).expect_err("the run ends in an error");
    let error = failed.error.to_string();
    assert!(error.contains(LEFT), "the bridge's error: {error}");
    assert_eq!(failed.to_string(), error, "a failed run reads as its error");
    let records = failed.records.expect("the records of the ticks seen are kept");
    println!("{error}; {} of {} ticks seen", records.ticks_seen, plan.total_ticks());
    assert!(!records.truth.is_empty(), "ground truth of the scenario ticks before the error");
    let eval = evaluate::evaluate_failed(&plan, &records, "embedded", &error);
    evaluate::write_report(&plan, &eval, &dir).expect("report written");
    evaluation::plots::write_all(&plan, &eval, &records, &dir).expect("figures drawn");
    println!("{}", evaluate::summary(&eval.metrics, &dir));
    let json = metrics(&dir);
    assert_failed_report(&json, &plan);
    assert_eq!(json["ticks_seen"].as_u64(), Some(records.ticks_seen));
    // `team report run.mcap` reads the recording as the failed run it was.
    let mcap = failed.recording.expect("the failed run's recording is closed").path;
    let (_, replayed, eval) =
        launch::record::replay::evaluate_recording(&mcap, &repo()).expect("the recording reads");
    assert_eq!(replayed.ticks_seen, records.ticks_seen, "the ticks the run saw");
    assert_eq!(eval.metrics.error.as_deref(), Some(error.as_str()), "the run's error, replayed");
    assert!(!eval.metrics.passed, "a failed run's recording never passes");
}

#[test]
fn team_run_that_fails_midway_writes_its_report_and_exits_with_the_error() {
    let plan = losing_every_agent();
    let dir = fresh("failed-run-cli");
    let out_dir = dir.display().to_string();
    let mut args = vec!["run", SCENARIO, "--quiet", "--no-record", "--out", &out_dir];
    for s in SETS {
        args.extend(["--set", s]);
    }
    let out = Command::new(sibling_binary("team"))
        .args(&args)
        .current_dir(repo())
        .env_remove("RUST_BACKTRACE")
        .env_remove("RUST_LIB_BACKTRACE")
        .output()
        .expect("team runs (cargo build --release --bins)");
    let (stdout, stderr) =
        (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    println!("{stdout}\n{stderr}");
    assert!(!out.status.success(), "a non-zero status");
    assert!(
        stderr.contains(LEFT) && stderr.contains(&out_dir),
        "the error and the report's folder are named: {stderr}"
    );
    assert!(stdout.contains("RUN FAILED") && stdout.contains(LEFT), "the summary says so");
    assert_failed_report(&metrics(&dir), &plan);
    let html = std::fs::read_to_string(dir.join("report.html")).expect("report.html written");
    assert!(html.contains("ended in an error") && html.contains(LEFT), "report.html says so");
    for f in ["timeseries.csv", "torques.csv", "object_error.png"] {
        assert!(dir.join(f).is_file(), "{f} written");
    }
}
