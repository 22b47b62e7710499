//! `robot-agent run` refuses bad input before it starts: one error line, exit status 2.

use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_robot-agent")).args(args).output().expect("binary runs")
}

fn one_error_line(out: &Output, needle: &str) {
    assert_eq!(out.status.code(), Some(2), "stderr: {}", String::from_utf8_lossy(&out.stderr));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "more than one line: {err}");
    assert!(err.starts_with("error"), "{err}");
    assert!(err.contains(needle), "{needle:?} not in {err}");
}

#[test]
fn bad_input_is_one_error_line_and_exit_status_2() {
    one_error_line(
        &run(&["run", "--id", "r1", "--robot", "/nonexistent/robot.toml"]),
        "/nonexistent/robot.toml",
    );
    let dir = std::env::temp_dir().join(format!("robot-agent-run-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "[robot]\nname = \"x\"\nurdf = ").unwrap();
    one_error_line(
        &run(&["run", "--id", "r1", "--robot", bad.to_str().unwrap()]),
        "malformed robot description",
    );
    one_error_line(&run(&["run", "--id", "a/b"]), "invalid identifier robot");
    one_error_line(&run(&["run", "--id", "r1", "--team", "t*"]), "invalid identifier team");
    one_error_line(
        &run(&["run", "--id", "r1", "--placeholder-joints", "0"]),
        "--placeholder-joints",
    );
    one_error_line(&run(&["run"]), "--id");
}
