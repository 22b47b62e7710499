//! The `robot-agent inspect` binary: output checked against the library, bad input gives one
//! `error: ...` line and exit status 2.
#![allow(clippy::needless_range_loop)]

#[path = "../../robot-model/tests/common/mod.rs"]
mod common;

use std::path::PathBuf;
use std::process::{Command, Output};

use common::*;
use nalgebra::Matrix6xX;
use robot_model::*;
use serde_json::Value;

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_robot-agent")).args(args).output().expect("binary runs")
}

fn temp_file(name: &str, content: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("robot-agent-inspect-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, content).unwrap();
    p
}

fn json_of(out: &Output) -> Value {
    assert!(out.status.success(), "stderr: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("stdout is JSON")
}

fn vec_of(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

fn rows_of(v: &Value) -> Vec<Vec<f64>> {
    v.as_array().unwrap().iter().map(vec_of).collect()
}

#[test]
fn arm_at_neutral_state() {
    let arm = data_path("arm.urdf");
    let out = json_of(&run(&["inspect", "--urdf", &arm, "--frame", "tool0", "--json"]));
    let model = arm_model();
    assert_eq!(out["nq"], 6);
    assert_eq!(out["nv"], 6);
    assert_eq!(out["joint_names"], serde_json::json!(["j1", "j2", "j3", "j4", "j5", "j6"]));
    assert!((out["total_mass"].as_f64().unwrap() - model.total_mass).abs() < 1e-12);
    assert!(out["base_velocity_convention"].as_str().unwrap().contains("fixed base"));
    let mut data = Data::new(&model);
    let m = crba(&model, &mut data, model.neutral().as_slice()).unwrap().clone();
    let m_out = rows_of(&out["M"]);
    for r in 0..6 {
        for c in 0..6 {
            assert!((m_out[r][c] - m[(r, c)]).abs() < 1e-12);
            assert_eq!(m_out[r][c], m_out[c][r]);
        }
    }
    // zero velocity: h == g, and Jdot v == 0
    assert_eq!(vec_of(&out["h"]), vec_of(&out["g"]));
    let f = &out["frames"][0];
    assert_eq!(f["name"], "tool0");
    assert_eq!(rows_of(&f["jacobian"]).len(), 6);
    assert!(vec_of(&f["jdot_v"]).iter().all(|x| *x == 0.0));
}

#[test]
fn composed_robot_at_a_given_state_matches_the_library() {
    let model = composed_model();
    let (q, v) = random_state(&model, &mut rng(42));
    let state = temp_file(
        "state.json",
        &serde_json::json!({"q": q.as_slice(), "v": v.as_slice()}).to_string(),
    );
    let (quad, arm) = (data_path("quadruped.urdf"), data_path("arm.urdf"));
    let pose = format!(
        "{},{},{},{},{},{}",
        ATTACH_XYZ[0], ATTACH_XYZ[1], ATTACH_XYZ[2], ATTACH_RPY[0], ATTACH_RPY[1], ATTACH_RPY[2]
    );
    let out = json_of(&run(&[
        "inspect",
        "--urdf",
        &quad,
        "--floating-base",
        "--attach",
        &arm,
        "--at",
        ATTACH_AT,
        "--pose",
        &pose,
        "--prefix",
        PREFIX,
        "--state",
        state.to_str().unwrap(),
        "--frame",
        "arm_hand",
        "--frame",
        "RH_foot",
        "--json",
    ]));
    assert_eq!(out["nv"], 24);
    assert_eq!(out["nq"], 25);
    assert_eq!(out["velocity_names"][0], "base_vx");
    assert_eq!(out["joint_names"][12], "arm_j1");
    assert!(out["base_velocity_convention"].as_str().unwrap().contains("base frame"));
    let mut data = Data::new(&model);
    compute_all_terms(&model, &mut data, q.as_slice(), v.as_slice()).unwrap();
    let m_out = rows_of(&out["M"]);
    for r in 0..24 {
        for c in 0..24 {
            assert!((m_out[r][c] - data.m[(r, c)]).abs() < 1e-12);
        }
    }
    assert!(rel_err_v(&vec_of(&out["h"]), data.h.as_slice()) < 1e-14);
    assert!(rel_err_v(&vec_of(&out["g"]), data.g.as_slice()) < 1e-14);
    let mut j = Matrix6xX::zeros(24);
    for (k, name) in ["arm_hand", "RH_foot"].iter().enumerate() {
        let f = &out["frames"][k];
        let id = model.frame_id(name).unwrap();
        frame_jacobian(&model, &data, id, &mut j).unwrap();
        let j_out = rows_of(&f["jacobian"]);
        for r in 0..6 {
            for c in 0..24 {
                assert!((j_out[r][c] - j[(r, c)]).abs() < 1e-12);
            }
        }
        let jdv = frame_jdot_v(&model, &data, id).unwrap();
        assert!(rel_err_v(&vec_of(&f["jdot_v"]), jdv.as_slice()) < 1e-14);
        assert!(rel_err_v(&vec_of(&f["position"]), data.o_m_f[id].trans.as_slice()) < 1e-14);
        let rot = rows_of(&f["rotation"]);
        assert!((rot[0][1] - data.o_m_f[id].rot[(0, 1)]).abs() < 1e-15, "rotation rows are rows");
    }
}

fn assert_bad(args: &[&str], expect: &str) {
    let out = run(args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "args {args:?}: stderr {err}");
    assert_eq!(err.lines().count(), 1, "one error line, got {err:?}");
    assert!(err.starts_with("error: "), "{err}");
    assert!(err.contains(expect), "{err:?} should mention {expect:?}");
    assert!(out.stdout.is_empty());
}

#[test]
fn bad_input_gives_one_error_line_and_status_2() {
    let arm = data_path("arm.urdf");
    let quad = data_path("quadruped.urdf");
    assert_bad(&["inspect", "--urdf", "/nonexistent/robot.urdf"], "cannot read URDF");
    let garbage = temp_file("garbage.urdf", "<robot name=\"x\"><link name=\"a\"><inertial><mass value=\"heavy\"/></inertial></link></robot>");
    assert_bad(&["inspect", "--urdf", garbage.to_str().unwrap()], "malformed URDF");
    let two_roots = temp_file(
        "two_roots.urdf",
        "<robot name=\"x\"><link name=\"a\"/><link name=\"b\"/></robot>",
    );
    assert_bad(&["inspect", "--urdf", two_roots.to_str().unwrap()], "several root links");
    assert_bad(&["inspect", "--urdf", &arm, "--frame", "no_such_frame"], "unknown frame");
    let short = temp_file("short.json", r#"{"q": [0, 0, 0], "v": [0, 0, 0, 0, 0, 0]}"#);
    assert_bad(&["inspect", "--urdf", &arm, "--state", short.to_str().unwrap()], "expected 6");
    let inf = temp_file("inf.json", r#"{"q": [0, 0, 1e999, 0, 0, 0], "v": [0, 0, 0, 0, 0, 0]}"#);
    assert_bad(&["inspect", "--urdf", &arm, "--state", inf.to_str().unwrap()], "state file");
    let nan = temp_file("nan.json", r#"{"q": [0, 0, NaN, 0, 0, 0]}"#);
    assert_bad(&["inspect", "--urdf", &arm, "--state", nan.to_str().unwrap()], "state file");
    let not_json = temp_file("not.json", "q = 1");
    assert_bad(
        &["inspect", "--urdf", &arm, "--state", not_json.to_str().unwrap()],
        "malformed state",
    );
    assert_bad(
        &["inspect", "--urdf", &arm, "--state", "/nonexistent/state.json"],
        "cannot read state",
    );
    let quat = temp_file("quat.json", &serde_json::json!({"q": vec![0.0; 19]}).to_string());
    assert_bad(
        &["inspect", "--urdf", &quad, "--floating-base", "--state", quat.to_str().unwrap()],
        "quaternion",
    );
    assert_bad(
        &["inspect", "--urdf", &quad, "--attach", &arm, "--at", "trunk", "--pose", "1,2,x,0,0,0"],
        "--pose",
    );
    assert_bad(&["inspect", "--urdf", &quad, "--attach", &arm, "--at", "nope"], "unknown frame");
    assert_bad(&["inspect", "--urdf", &quad, "--at", "trunk"], "--attach");
    assert_bad(&["inspect"], "--urdf");
}
