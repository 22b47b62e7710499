//! A client in another language reads the tool-facing keys: `tests/python/decode_status.py`
//! (eclipse-zenoh from PyPI and the standard library, no project code) connects to a session
//! on which the coordinator's status and diagnostics are published through the project's
//! transport, and decodes both from their JSON. The script's Python environment is made once
//! under `target/py-client` by `scripts/setup-python-client.sh` (eclipse-zenoh pinned); without
//! python3 or PyPI the test fails and says so.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use protocol::transport::{self, Qos, Role, TypedPublisher, ZenohArgs};
use protocol::{
    ContactWrench, CoordinatorMode, CoordinatorStatus, Header, QpStatus, TickDiagnostics,
};

const TEAM: &str = "pyclient";

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("repo root").to_path_buf()
}

/// The venv's python with eclipse-zenoh: `scripts/setup-python-client.sh` makes it (scripts/test.sh
/// runs it first; here again, it returns at once when the pinned version is there).
fn python() -> PathBuf {
    let script = repo().join("scripts/setup-python-client.sh");
    let out = Command::new("bash").arg(&script).output().expect("bash runs");
    assert!(
        out.status.success(),
        "{} failed: {}",
        script.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    repo().join("target/py-client/bin/python")
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_python_client_decodes_status_and_diagnostics() {
    let py = python();
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let session = transport::open(&ZenohArgs::listening(&endpoint), Role::Alone)
        .await
        .expect("session listens");
    let mut status_pub = TypedPublisher::<CoordinatorStatus>::declare(
        &session,
        protocol::keys::coordinator_status(TEAM).unwrap(),
        Qos::Telemetry,
    )
    .await
    .unwrap();
    let mut diag_pub = TypedPublisher::<TickDiagnostics>::declare(
        &session,
        protocol::keys::diagnostics(TEAM).unwrap(),
        Qos::Telemetry,
    )
    .await
    .unwrap();
    let mut child = Command::new(&py)
        .arg(repo().join("tests/python/decode_status.py"))
        .args([&endpoint, TEAM, "30"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python starts");
    let started = Instant::now();
    let mut tick = 0u64;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "the Python client did not finish in 60 s"
        );
        let header = Header::new(TEAM, None, tick, protocol::wall_clock_ns());
        let st = CoordinatorStatus {
            header: header.clone(),
            mode: CoordinatorMode::Running,
            members: vec!["r1".into(), "r2".into()],
            ticks: tick,
            commands_sent: 2 * tick,
            deadline_misses: 0,
            fallbacks: 0,
            detail: String::new(),
            stale: vec![],
            silent: vec![],
            late: vec![],
            reused_terms: 0,
            refused: 0,
            last_refusal: None,
        };
        let contacts = vec![ContactWrench {
            robot: "r1".into(),
            frame: "hand".into(),
            wrench: vec![1.0, 2.0, 30.5, 0.0, 0.0, 0.0],
        }];
        let d = TickDiagnostics {
            header,
            qp_status: QpStatus::Solved,
            qp_iterations: 9,
            qp_solve_us: 123.5,
            assembly_us: 40.0,
            total_us: 210.0,
            contacts,
            constraint_residual: 1e-9,
            object_estimate: None,
            grasp_slip: 0.002,
            grasp_refits: 0,
            grasp_slip_since_closed: 0.0,
            fallback: None,
            motion_yield: None,
        };
        status_pub.put(&st).await.unwrap();
        diag_pub.put(&d).await.unwrap();
        tick += 1;
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let out = child.wait_with_output().unwrap();
    let (stdout, stderr) =
        (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(status.success(), "the Python client failed:\n{stdout}\n{stderr}");
    let schema =
        |name: &str| format!("application/json;team.{name}/v{}", protocol::PROTOCOL_VERSION);
    assert!(
        stdout.contains(&format!("status encoding={} mode=Running", schema("CoordinatorStatus"))),
        "{stdout}"
    );
    assert!(stdout.contains("members=['r1', 'r2']"), "{stdout}");
    assert!(
        stdout.contains(&format!("diagnostics encoding={}", schema("TickDiagnostics"))),
        "{stdout}"
    );
    assert!(
        stdout.contains(
            "qp_status=Solved qp_solve_us=123.5 contacts=1 grasp_slip=0.002 fallback=None"
        ),
        "{stdout}"
    );
}
