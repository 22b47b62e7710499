//! A scenario run as the integration tests make it: load the file with `--set` overrides, plan,
//! run the whole stack, evaluate on the ground truth, and write the report folder (with its
//! figures) under `target/test-reports/<name>/` for a look.

use std::path::{Path, PathBuf};

use evaluation::evaluate::{self, Metrics};
use evaluation::records::Records;
use launch::record::{RecordOptions, ScenarioSource};
use launch::run::{self, RunOptions};
use scenario::file::Scenario;
use scenario::plan::{self, Plan};

/// The repository's root.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("repo root").to_path_buf()
}

/// The report folder of the run called `name`: `target/test-reports/<name>/`.
pub fn report_dir(name: &str) -> PathBuf {
    repo().join("target/test-reports").join(name)
}

/// Run a plan embedded, evaluate it and write its report as `name`; its summary is printed.
pub fn run_plan(plan: &Plan, name: &str) -> Metrics {
    let dir = report_dir(name);
    std::fs::create_dir_all(&dir).expect("report dir");
    let records = run::run(
        plan,
        &RunOptions { distributed: false, hosts: false, progress: false, loss: Vec::new() },
        &dir,
    )
    .expect("the run completes");
    let eval = evaluate::evaluate(plan, &records, "embedded");
    evaluate::write_report(plan, &eval, &dir).expect("report written");
    println!("{}", evaluate::summary(&eval.metrics, &dir));
    eval.metrics
}

/// Run `scenarios/{file}` with `sets`, embedded or `distributed`; the plan and the metrics.
pub fn run_scenario(file: &str, sets: &[&str], distributed: bool, name: &str) -> (Plan, Metrics) {
    let (plan, metrics, _) = run_scenario_records(file, sets, distributed, name);
    (plan, metrics)
}

/// [`run_scenario`], with what the run recorded (the ground truth among it).
pub fn run_scenario_records(
    file: &str,
    sets: &[&str],
    distributed: bool,
    name: &str,
) -> (Plan, Metrics, Records) {
    run_with(file, sets, distributed, name, false)
}

/// [`run_scenario_records`] embedded, also writing the MCAP recording `team run` writes, to
/// `run.mcap` in [`report_dir`].
pub fn run_scenario_recorded(file: &str, sets: &[&str], name: &str) -> (Plan, Metrics, Records) {
    run_with(file, sets, false, name, true)
}

fn run_with(
    file: &str,
    sets: &[&str],
    distributed: bool,
    name: &str,
    mcap: bool,
) -> (Plan, Metrics, Records) {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let path = repo().join("scenarios").join(file);
    let scenario = Scenario::load(&path, &sets).expect("scenario loads");
    let plan = plan::plan(&scenario, &repo()).expect("plan");
    let dir = report_dir(name);
    std::fs::create_dir_all(&dir).expect("report dir");
    let opts = RunOptions { distributed, hosts: false, progress: false, loss: Vec::new() };
    let rec = mcap.then(|| RecordOptions {
        path: dir.join("run.mcap"),
        scenario: ScenarioSource::read(&path, &sets, scenario::Pacing::Lockstep)
            .expect("scenario file"),
        live: None,
        split: None,
    });
    let (records, summary) =
        run::run_recorded(&plan, &opts, &dir, rec.as_ref()).expect("the run completes");
    if let Some(s) = summary {
        assert_eq!(
            (s.dropped, s.failed, s.error.as_deref()),
            (0, 0, None),
            "the recording is complete: {s:?}"
        );
    }
    let eval = evaluate::evaluate(&plan, &records, opts.mode_name(false));
    evaluate::write_report(&plan, &eval, &dir).expect("report written");
    evaluation::plots::write_all(&plan, &eval, &records, &dir).expect("figures drawn");
    println!("{}", evaluate::summary(&eval.metrics, &dir));
    (plan, eval.metrics, records)
}
