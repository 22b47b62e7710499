//! A running team is found without flags: `team run`, embedded or `--distributed`, listens on
//! the tools' endpoint (`protocol::transport::TOOLS_ENDPOINT`) when it is free and says so,
//! and `team echo` started with no Zenoh flag reads the coordinator's status there.
//!
//! Needs the release binaries: `cargo build --release --bins` (scripts/test.sh does it). Fails
//! when another process holds the tools' port (a team left running on this machine).

use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{mpsc, Mutex};
use std::time::Duration;

use launch::processes::sibling_binary;
use protocol::transport::{TOOLS_ENDPOINT, TOOLS_PORT};

/// The tests take the default port in turn.
static PORT: Mutex<()> = Mutex::new(());

/// How long a run may take to say where it is.
const ANNOUNCED_WITHIN: Duration = Duration::from_secs(60);
/// How long a run may take to end by itself once echoed.
const ENDED_WITHIN: Duration = Duration::from_secs(180);

/// A `team run` in a process group of its own, the group killed if the run is still going
/// when this drops (a failed assertion): its coordinator, agents and bridge go with it.
struct Run {
    child: Child,
    lines: mpsc::Receiver<String>,
    out: PathBuf,
}

impl Run {
    /// Wait, up to [`ENDED_WITHIN`], for the run to end by itself; whether it succeeded.
    fn ended(&mut self) -> bool {
        let deadline = std::time::Instant::now() + ENDED_WITHIN;
        while std::time::Instant::now() < deadline {
            if let Ok(Some(status)) = self.child.try_wait() {
                return status.success();
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        false
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let group = format!("-{}", self.child.id());
            let _ = Command::new("kill").args(["-KILL", "--", &group]).status();
            let _ = self.child.wait();
        }
        let _ = std::fs::remove_dir_all(&self.out);
    }
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// S4 for long enough to be echoed, started with `extra` flags, its stdout read line by line.
fn start_run(name: &str, extra: &[&str]) -> Run {
    let out = std::env::temp_dir().join(format!("team-discovery-{name}-{}", std::process::id()));
    let mut child = Command::new(sibling_binary("team"))
        .current_dir(repo())
        .args(["run", "scenarios/s4_object_circle.toml", "--set", "duration=6", "--no-record"])
        .arg("--out")
        .arg(&out)
        .args(extra)
        .process_group(0)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("the team binary runs (cargo build --release --bins)");
    let stdout = child.stdout.take().expect("piped stdout");
    let (tx, lines) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    Run { child, lines, out }
}

/// The endpoint the run announced on stdout.
fn announced(lines: &mpsc::Receiver<String>) -> String {
    let deadline = std::time::Instant::now() + ANNOUNCED_WITHIN;
    loop {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        let line = lines.recv_timeout(left).expect("the run says where clients connect");
        if let Some(e) = line.strip_prefix("team: tools on this machine connect at ") {
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
        std::net::TcpListener::bind(("127.0.0.1", TOOLS_PORT)).is_ok(),
        "another process holds {TOOLS_ENDPOINT}: stop it and run again"
    );
    let mut run = start_run(name, extra);
    let endpoint = announced(&run.lines);
    assert_eq!(endpoint, TOOLS_ENDPOINT, "the run listens where tools look");
    let status = echo_without_flags();
    assert_eq!(status["message"]["header"]["team"], "team", "the coordinator's status: {status}");
    assert!(run.ended(), "the {name} run ends by itself, and succeeds");
}

#[test]
fn a_running_team_is_found_without_flags_embedded_and_distributed() {
    let _turn = PORT.lock().unwrap_or_else(|e| e.into_inner());
    found_without_flags("embedded", &[]);
    found_without_flags("distributed", &["--distributed"]);
}

/// A run while another process holds the tools' endpoint runs all the same, and says that
/// no tool can reach it.
#[test]
fn a_run_beside_a_held_port_runs_and_says_so() {
    let _turn = PORT.lock().unwrap_or_else(|e| e.into_inner());
    let _held = std::net::TcpListener::bind(("127.0.0.1", TOOLS_PORT));
    let out = std::env::temp_dir().join(format!("team-discovery-held-{}", std::process::id()));
    let output = Command::new(sibling_binary("team"))
        .current_dir(repo())
        .args(["run", "scenarios/s1_torso_and_object.toml", "--set", "duration=0.5"])
        .args(["--set", "settle=0.2", "--no-record", "--out"])
        .arg(&out)
        .output()
        .expect("team run");
    let _ = std::fs::remove_dir_all(&out);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{}\n{stdout}", output.status);
    assert!(stdout.contains("no tool can connect: another process holds"), "{stdout}");
    assert!(stdout.contains("acceptance: all"), "{stdout}");
}
