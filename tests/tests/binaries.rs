//! The binaries at their edges: bad arguments and files give one clear error and a non-zero
//! status; `team run` exits non-zero when an acceptance check fails; a recording that cannot
//! be written leaves the run's control alone and is named at the end.
//!
//! Needs the release binaries (`cargo build --release --bins`). The full-disk case mounts a
//! 1 MiB tmpfs, which needs root: where it cannot be mounted the test fails, naming why.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use launch::processes::sibling_binary;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("repo root").to_path_buf()
}

/// `bin` with `args` from the repository's root, without backtraces in its errors.
fn run(bin: &str, args: &[&str]) -> Output {
    Command::new(sibling_binary(bin))
        .args(args)
        .current_dir(repo())
        .env_remove("RUST_BACKTRACE")
        .env_remove("RUST_LIB_BACKTRACE")
        .output()
        .unwrap_or_else(|e| panic!("{bin} runs: {e}"))
}

/// The run failed with an error on stderr that names `needle`.
fn refused(out: &Output, needle: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a non-zero status; stderr: {err}");
    assert!(err.to_lowercase().contains("error"), "an error is said: {err}");
    assert!(err.contains(needle), "{needle:?} is named: {err}");
    assert!(
        !err.contains("Stack backtrace") && !err.contains("panicked"),
        "an error, not a crash: {err}"
    );
}

#[test]
fn bad_arguments_and_files_are_one_clear_error() {
    refused(&run("team", &["run", "/nonexistent/scenario.toml"]), "/nonexistent/scenario.toml");
    refused(
        &run("team", &["run", "scenarios/s4_object_circle.toml", "--set", "nonsense=1"]),
        "nonsense",
    );
    refused(
        &run("team", &["run", "scenarios/s4_object_circle.toml", "--set", "duration=-1"]),
        "duration",
    );
    refused(&run("team", &["frobnicate"]), "frobnicate");
    refused(&run("team", &["echo", "team/t/coordinator/status", "--wait=-1"]), "--wait");
    refused(&run("coordinator", &["run", "--team", "t*"]), "t*");
    refused(&run("coordinator", &["run", "--controller", "nosuch"]), "nosuch");
    refused(&run("sim-bridge", &["scene", "/nonexistent/scene.toml"]), "/nonexistent/scene.toml");
    refused(&run("sim-bridge", &["frobnicate"]), "frobnicate");
    refused(
        &run(
            "team",
            &["run", "scenarios/s4_object_circle.toml", "--router", "quic/127.0.0.1:7448"],
        ),
        "--tls",
    );
    refused(&run("team", &["run", "scenarios/s4_object_circle.toml", "--team", "a/b"]), "a/b");
    refused(&run("team", &["router-config", "/nonexistent", "--team", "alpha"]), "alpha");
    refused(
        &run("team", &["router-config", "/nonexistent", "--team", "alpha=r1"]),
        "/nonexistent/ca.pem",
    );
    // A team's own (peer-mode) configuration is not a router's.
    refused(&run("team", &["router", "config/zenoh/zenoh-coordinator.json5"]), "not a router");
    refused(&run("team", &["router", "/nonexistent/router.json5"]), "/nonexistent/router.json5");
    // Mutual TLS on Zenoh's tls/ link (unsound under load) or on plain TCP is refused by name.
    let shipped = std::fs::read_to_string(repo().join("config/zenoh/site/router.json5"))
        .expect("the shipped router configuration");
    let on_tls = std::env::temp_dir().join(format!("router-on-tls-{}.json5", std::process::id()));
    std::fs::write(&on_tls, shipped.replace("\"quic/", "\"tls/")).unwrap();
    refused(
        &run("team", &["router", on_tls.to_str().unwrap()]),
        "\"tls/127.0.0.1:7448\" is not a secure link",
    );
    let _ = std::fs::remove_file(&on_tls);
    refused(
        &run("team", &["zenoh-config", "/nonexistent", "--hub", "tcp/127.0.0.1:7447"]),
        "\"tcp/127.0.0.1:7447\" is not a secure link",
    );
}

/// A push of 60 N on the object for 0.2 s: the palms slip and the object leaves its reference;
/// the run completes, names the failed checks and exits non-zero.
#[test]
fn team_run_exits_non_zero_when_a_check_fails() {
    let out_dir = std::env::temp_dir().join(format!("team-check-fails-{}", std::process::id()));
    let push =
        "perturbations=[{on=\"object\",start=0.1,duration=0.2,wrench=[60.0,0.0,0.0,0.0,0.0,0.0]}]";
    let out = run(
        "team",
        &[
            "run",
            "scenarios/s4_object_circle.toml",
            "--set",
            push,
            "--set",
            "duration=0.6",
            "--set",
            "settle=0.2",
            "--quiet",
            "--out",
            out_dir.to_str().unwrap(),
        ],
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("acceptance FAILED"), "the failed checks are listed: {stdout}");
    refused(&out, "acceptance checks failed");
    assert!(out_dir.join("metrics.json").is_file(), "the report is written all the same");
    let _ = std::fs::remove_dir_all(&out_dir);
}

/// `team run --no-record`: no recording, the report whole, the summary says so; `--live` needs
/// a recording and is refused with it.
#[test]
fn team_run_without_a_recording_writes_the_report_only() {
    let out_dir = std::env::temp_dir().join(format!("team-no-record-{}", std::process::id()));
    let out = run(
        "team",
        &[
            "run",
            "scenarios/s4_object_circle.toml",
            "--set",
            "duration=0.3",
            "--set",
            "settle=0.2",
            "--quiet",
            "--no-record",
            "--out",
            out_dir.to_str().unwrap(),
        ],
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("recording: none (--no-record)"), "{stdout}");
    assert!(
        out_dir.join("metrics.json").is_file() && out_dir.join("timeseries.csv").is_file(),
        "the report is written"
    );
    assert!(!out_dir.join("run.mcap").exists(), "no recording");
    let _ = std::fs::remove_dir_all(&out_dir);
    refused(
        &run("team", &["run", "scenarios/s4_object_circle.toml", "--no-record", "--live"]),
        "--live",
    );
}

/// The report folder on a 1 MiB tmpfs: the recording (about 4 MB for this run) fills it. The
/// run completes every tick and its checks pass (the summary says so); the status is non-zero
/// and the error names the recording.
#[test]
fn a_recording_that_cannot_be_written_leaves_the_run_alone_and_is_named() {
    let mount = std::env::temp_dir().join(format!("team-full-disk-{}", std::process::id()));
    std::fs::create_dir_all(&mount).expect("mount point");
    let mounted = Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=1m", "tmpfs"])
        .arg(&mount)
        .output()
        .expect("mount runs");
    assert!(
        mounted.status.success(),
        "a 1 MiB tmpfs is needed (root): {}",
        String::from_utf8_lossy(&mounted.stderr)
    );
    let out = run(
        "team",
        &[
            "run",
            "scenarios/s4_object_circle.toml",
            "--set",
            "duration=0.5",
            "--set",
            "settle=0.2",
            "--quiet",
            "--out",
            mount.join("run").to_str().unwrap(),
        ],
    );
    let _ = Command::new("umount").arg(&mount).status();
    let _ = std::fs::remove_dir(&mount);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("acceptance: all"), "the run's control was unaffected: {stdout}");
    refused(&out, "run.mcap");
}
