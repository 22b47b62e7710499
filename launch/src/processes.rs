//! The team's binaries as child processes on loopback or on test hosts: free ports, spawning
//! a sibling binary, and a guard that kills the child when dropped (the distributed runs and
//! tests).

use std::io::{BufRead, BufReader};
use std::net::{TcpListener, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};

use thiserror::Error;

/// Errors starting or waiting for a child process.
#[derive(Debug, Error)]
pub enum ProcessError {
    #[error("cannot start {what} ({path}): {reason}")]
    Spawn { what: String, path: PathBuf, reason: String },
    #[error("{what} exited with {status}")]
    Failed { what: String, status: String },
    #[error("no free loopback port: {0}")]
    NoPort(String),
}

/// A loopback port free for both TCP and UDP (tcp/ and quic/ endpoints), bound, then
/// released for the child to take.
pub fn free_port() -> Result<u16, ProcessError> {
    let no_port = |e: std::io::Error| ProcessError::NoPort(e.to_string());
    for _ in 0..16 {
        let tcp = TcpListener::bind("127.0.0.1:0").map_err(no_port)?;
        let port = tcp.local_addr().map_err(no_port)?.port();
        if UdpSocket::bind(("127.0.0.1", port)).is_ok() {
            return Ok(port);
        }
    }
    Err(ProcessError::NoPort("no port free for both TCP and UDP in 16 tries".into()))
}

/// The directory of this executable, where cargo also puts the other binaries.
pub fn sibling_binary(name: &str) -> PathBuf {
    let exe = std::env::current_exe().unwrap_or_default();
    let dir = exe.parent().map(Path::to_path_buf).unwrap_or_default();
    // Test executables live one level deeper, in deps/.
    let dir = if dir.ends_with("deps") {
        dir.parent().map(Path::to_path_buf).unwrap_or(dir)
    } else {
        dir
    };
    dir.join(name)
}

/// A child process that is killed when dropped.
pub struct ChildGuard {
    pub what: String,
    pub child: Child,
    /// The last `Error: ...` line the child wrote on stderr.
    last_error: Arc<Mutex<Option<String>>>,
}

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Start one of the team's binaries with arguments.
pub fn spawn(bin: &str, args: &[String], what: &str) -> Result<ChildGuard, ProcessError> {
    let path = sibling_binary(bin);
    spawn_with(Command::new(&path), path, args, what)
}

/// Start one of the team's binaries on a test host (`crate::hosts`).
pub fn spawn_on(
    hosts: &crate::hosts::TestHosts,
    host: &str,
    bin: &str,
    args: &[String],
    what: &str,
) -> Result<ChildGuard, ProcessError> {
    let path = sibling_binary(bin);
    let command = hosts.command(host, &path).map_err(|e| ProcessError::Spawn {
        what: what.to_string(),
        path: path.clone(),
        reason: e.to_string(),
    })?;
    spawn_with(command, path, args, what)
}

/// Start `command` (which runs the binary at `path`) with arguments.
fn spawn_with(
    mut command: Command,
    path: PathBuf,
    args: &[String],
    what: &str,
) -> Result<ChildGuard, ProcessError> {
    // The child logs as this process does (`team run -v`, `--quiet`).
    if let Some(directives) = protocol::logging::directives() {
        command.env(protocol::logging::LOG_ENV, directives);
    }
    let mut child = command
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::inherit())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| ProcessError::Spawn {
            what: what.to_string(),
            path,
            reason: format!("{e} (build the binaries first: cargo build --release --bins)"),
        })?;
    let last_error = Arc::new(Mutex::new(None));
    if let Some(stderr) = child.stderr.take() {
        let keep = last_error.clone();
        // The child's log goes on to ours, line by line; its `Error: ...` line is kept for
        // the error that reports its exit.
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("{line}");
                if let Some(e) = line.strip_prefix("Error: ") {
                    if let Ok(mut k) = keep.lock() {
                        *k = Some(e.to_string());
                    }
                }
            }
        });
    }
    Ok(ChildGuard { what: what.to_string(), child, last_error })
}

impl ChildGuard {
    /// Wait for the child to exit; an error unless it exited successfully.
    pub fn wait_success(&mut self) -> Result<(), ProcessError> {
        let status = self
            .child
            .wait()
            .map_err(|e| ProcessError::Failed { what: self.what.clone(), status: e.to_string() })?;
        if !status.success() {
            // The reader thread may still be passing the last lines on.
            std::thread::sleep(std::time::Duration::from_millis(50));
            let said = self.last_error.lock().ok().and_then(|e| e.clone());
            let status = said.map_or_else(|| status.to_string(), |e| format!("{status}: {e}"));
            return Err(ProcessError::Failed { what: self.what.clone(), status });
        }
        Ok(())
    }
}
