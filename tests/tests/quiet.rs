//! `team run`'s output: quiet by default. A successful run with `--quiet` writes nothing on
//! stderr; without it, stderr holds warnings and errors only: no ERROR line (Zenoh's among
//! them) and no line over and over. Embedded and distributed (the children log as `team`).
//!
//! Needs the release binaries: `cargo build --release --bins` (scripts/test.sh does it).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use launch::processes::sibling_binary;

/// The most times one line (its time stamp left out) may appear on stderr.
const MAX_REPEATS: usize = 3;
/// How many quiet embedded runs in a row must write nothing on stderr: an event of one run in
/// six (a Zenoh declaration race that logged an ERROR) passes 20 runs with a chance of 3e-2.
const QUIET_RUNS: usize = 20;

/// The repository, where `team run` finds the scenarios and the robots.
fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// A short S1 run (`team run` with `extra` flags) into a fresh report folder named `name`.
fn team_run(name: &str, extra: &[&str]) -> Output {
    let out = std::env::temp_dir().join(format!("team-quiet-{name}-{}", std::process::id()));
    let output = Command::new(sibling_binary("team"))
        .current_dir(repo())
        .args([
            "run",
            "scenarios/s1_torso_and_object.toml",
            "--set",
            "duration=0.5",
            "--set",
            "settle=0.2",
            "--out",
        ])
        .arg(&out)
        .args(extra)
        .env_remove("RUST_LOG")
        .output()
        .expect("the team binary runs (cargo build --release --bins)");
    let _ = std::fs::remove_dir_all(&out);
    output
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// A run that succeeded with `--quiet`: its summary on stdout and nothing on stderr.
fn assert_quiet(output: &Output) {
    let (stdout, stderr) = (text(&output.stdout), text(&output.stderr));
    assert!(output.status.success(), "{}\nstdout:\n{stdout}\nstderr:\n{stderr}", output.status);
    assert!(stderr.is_empty(), "stderr of a quiet run:\n{stderr}");
    assert!(stdout.contains("acceptance: all"), "the summary on stdout:\n{stdout}");
    assert!(!stdout.contains("progress"), "no progress with --quiet:\n{stdout}");
}

/// A run that succeeded without `--quiet`: no ERROR line on stderr, no line there more than
/// [`MAX_REPEATS`] times.
fn assert_calm(output: &Output) {
    let (stdout, stderr) = (text(&output.stdout), text(&output.stderr));
    assert!(output.status.success(), "{}\nstdout:\n{stdout}\nstderr:\n{stderr}", output.status);
    assert!(stdout.contains("acceptance: all"), "the summary on stdout:\n{stdout}");
    let mut seen: BTreeMap<&str, usize> = BTreeMap::new();
    for line in stderr.lines() {
        assert!(!line.contains("ERROR"), "an ERROR line on stderr:\n{stderr}");
        // A log line starts with its time stamp.
        let body = line.split_once(' ').map_or(line, |(_, rest)| rest);
        *seen.entry(body).or_default() += 1;
    }
    for (line, n) in seen {
        assert!(n <= MAX_REPEATS, "{n} times on stderr: {line}\n{stderr}");
    }
}

#[test]
fn quiet_embedded_runs_print_their_summary_alone_every_time() {
    for k in 0..QUIET_RUNS {
        let output = team_run(&format!("embedded-quiet-{k}"), &["--quiet"]);
        assert_quiet(&output);
    }
}

#[test]
fn a_quiet_distributed_run_prints_its_summary_alone() {
    assert_quiet(&team_run("distributed-quiet", &["--quiet", "--distributed"]));
}

#[test]
fn a_default_run_logs_no_error_and_nothing_over_and_over() {
    assert_calm(&team_run("embedded", &[]));
    assert_calm(&team_run("distributed", &["--distributed"]));
}
