//! A running team is found without flags: `team run`, embedded or `--distributed`, listens on
//! the default endpoint (`protocol::transport::DEFAULT_ENDPOINT`) when it is free and says so,
//! and `team echo` started with no Zenoh flag reads the coordinator's status there.
//!
//! Needs the release binaries: `cargo build --release --bins` (scripts/test.sh does it). Fails
//! when another process holds the default port (a team left running on this machine).

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{mpsc, Mutex};
use std::time::Duration;

use launch::processes::sibling_binary;
use protocol::transport::{DEFAULT_ENDPOINT, DEFAULT_PORT};

/// The tests take the default port in turn.
static PORT: Mutex<()> = Mutex::new(());

/// How long a run may take to say where it is.
const ANNOUNCED_WITHIN: Duration = Duration::from_secs(60);

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// S4 for long enough to be echoed, started in `mode` (extra flags), its stdout read line by
/// line into the returned channel.
fn start_run(name: &str, extra: &[&str]) -> (Child, mpsc::Receiver<String>, PathBuf) {
    let out = std::env::temp_dir().join(format!("team-discovery-{name}-{}", std::process::id()));
    let mut child = Command::new(sibling_binary("team"))
        .current_dir(repo())
        .args(["run", "scenarios/s4_object_circle.toml", "--set", "duration=20", "--no-record"])
        .arg("--out")
        .arg(&out)
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("the team binary runs (cargo build --release --bins)");
    let stdout = child.stdout.take().expect("piped stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    (child, rx, out)
}

/// The endpoint the run announced on stdout.
fn announced(lines: &mpsc::Receiver<String>) -> String {
    let deadline = std::time::Instant::now() + ANNOUNCED_WITHIN;
    loop {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        let line = lines.recv_timeout(left).expect("the run says where clients connect");
        if let Some(e) = line.strip_prefix("team: clients on this machine connect at ") {
            return e.trim().to_string();
        }
    }
}

/// `team echo` of the coordinator's status with no Zenoh flag: one message of team `team`.
fn echo_without_flags() -> serde_json::Value {
    let output = Command::new(sibling_binary("team"))
        .args(["echo", "team/team/coordinator/status", "--count", "1", "--wait", "20"])
        .output()
        .expect("team echo runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "team echo: {}\n{stdout}\n{}",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    let line = stdout.lines().find(|l| l.starts_with('{')).expect("a JSON message");
    serde_json::from_str(line).expect("the status as JSON")
}

fn found_without_flags(name: &str, extra: &[&str]) {
    assert!(
        std::net::TcpListener::bind(("127.0.0.1", DEFAULT_PORT)).is_ok(),
        "another process holds {DEFAULT_ENDPOINT}: stop it and run again"
    );
    let (mut child, lines, out) = start_run(name, extra);
    let endpoint = announced(&lines);
    let status = echo_without_flags();
    let _ = child.kill();
    let _ = child.wait();
    let _ = std::fs::remove_dir_all(out);
    assert_eq!(endpoint, DEFAULT_ENDPOINT, "the run listens where clients look");
    assert_eq!(status["message"]["header"]["team"], "team", "the coordinator's status: {status}");
}

#[test]
fn a_running_team_is_found_without_flags_embedded_and_distributed() {
    let _turn = PORT.lock().unwrap_or_else(|e| e.into_inner());
    found_without_flags("embedded", &[]);
    found_without_flags("distributed", &["--distributed"]);
}

/// A run while another process holds the default endpoint runs all the same, and says that no
/// client can reach it.
#[test]
fn a_second_run_while_the_port_is_taken_runs_and_says_so() {
    let _turn = PORT.lock().unwrap_or_else(|e| e.into_inner());
    let _port = std::net::TcpListener::bind(("127.0.0.1", DEFAULT_PORT));
    let output = Command::new(sibling_binary("team"))
        .current_dir(repo())
        .args(["run", "scenarios/s1_torso_and_object.toml", "--set", "duration=0.5"])
        .args(["--set", "settle=0.2", "--no-record", "--out"])
        .arg(std::env::temp_dir().join(format!("team-discovery-taken-{}", std::process::id())))
        .output()
        .expect("team run");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{}\n{stdout}", output.status);
    assert!(stdout.contains("no client can connect: another process holds"), "{stdout}");
    assert!(stdout.contains("acceptance: all"), "{stdout}");
}
