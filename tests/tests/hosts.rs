//! The team across test hosts (`scripts/testhosts.sh`, `launch::hosts`): the coordinator,
//! each agent and the sim-bridge each in its own Linux network namespace, joined by veth pairs
//! to one bridge, this process (the scenario driver) on the bridge. Where namespaces cannot be
//! made here (not root, no nftables), each test fails naming the reason, unless
//! `TEAM_TESTS_SKIP_HOSTS=1` says to skip it (`common::hosts`). Over mutual TLS, the team across hosts uses certificates that the test CA signs
//! for the hosts' addresses (`TestHosts::issue_certs`).

mod common;

use std::sync::{Arc, Mutex};

use evaluation::evaluate;
use launch::hosts::TestHosts;
use launch::launcher::RunMode;
use launch::run::{self, RunOptions};
use scenario::file::Scenario;
use scenario::plan::{self, Plan};

/// The tests run one at a time: each counts the machine's namespaces.
static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

fn s4(duration: f64) -> Plan {
    let sets = [format!("duration={duration}"), "settle=0.5".into()];
    let s = Scenario::load(common::scenario::repo().join("scenarios/s4_object_circle.toml"), &sets)
        .expect("scenario");
    plan::plan(&s, &common::scenario::repo()).expect("plan")
}

fn report_dir(name: &str) -> std::path::PathBuf {
    let dir = common::scenario::repo().join("target/test-reports").join(name);
    std::fs::create_dir_all(&dir).expect("report dir");
    dir
}

/// Test hosts for `plan`'s team (`common::hosts`: a failure where they cannot be made, unless
/// the skip variable is set).
fn hosts_for(plan: &Plan, test: &str) -> Option<Arc<TestHosts>> {
    let ids: Vec<String> = plan.robots.iter().map(|r| r.id.clone()).collect();
    common::hosts::hosts_or_skip(&ids, test)
}

fn namespaces() -> Vec<String> {
    let out = std::process::Command::new("ip")
        .args(["netns", "list"])
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).to_string())
        .unwrap_or_default();
    out.lines().filter_map(|l| l.split_whitespace().next()).map(str::to_string).collect()
}

fn run_on(
    plan: &Plan,
    hosts: &Arc<TestHosts>,
    name: &str,
) -> Result<evaluation::records::Records, run::RunError> {
    let dir = report_dir(name);
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    let mode = RunMode::Hosts { dir, hosts: hosts.clone(), certs: None };
    rt.block_on(run::run_in(
        plan,
        &RunOptions { distributed: true, hosts: true, progress: false, loss: Vec::new() },
        &mode,
        None,
    ))
}

/// S4 with every component on its own host passes its checks, and `team run --hosts`'s hosts
/// are gone after the run.
#[test]
fn s4_holds_with_every_component_on_its_own_host() {
    let _one = serial();
    let plan = s4(2.0);
    let before = namespaces();
    if !common::hosts::available_or_skip("hosts::s4_holds_with_every_component_on_its_own_host") {
        return;
    }
    let dir = report_dir("hosts_s4");
    let records = run::run(
        &plan,
        &RunOptions { distributed: true, hosts: true, progress: false, loss: Vec::new() },
        &dir,
    )
    .expect("the run completes");
    let eval = evaluate::evaluate(&plan, &records, "hosts");
    println!("{}", evaluate::summary(&eval.metrics, &dir));
    for c in &eval.metrics.checks {
        assert!(c.passed, "{} = {} not below {}", c.name, c.value, c.bound);
    }
    assert_eq!(namespaces(), before, "the run's hosts were removed");
}

/// 5 % of the packets to and from robot r1's host dropped (nftables): TCP carries the lockstep
/// through, the team holds, and the rule did drop packets.
#[test]
fn the_team_holds_with_five_percent_of_one_agents_packets_dropped() {
    let _one = serial();
    let plan = s4(2.0);
    let Some(hosts) =
        hosts_for(&plan, "hosts::the_team_holds_with_five_percent_of_one_agents_packets_dropped")
    else {
        return;
    };
    hosts.set_loss("r1", 5).expect("loss rule");
    let records = run_on(&plan, &hosts, "hosts_loss").expect("the run completes");
    let eval = evaluate::evaluate(&plan, &records, "hosts");
    for c in &eval.metrics.checks {
        assert!(c.passed, "{} = {} not below {}", c.name, c.value, c.bound);
    }
    let dropped = hosts.dropped("r1").expect("counter");
    println!("r1's host dropped {dropped} packets");
    assert!(dropped > 10, "the loss rule dropped packets: {dropped}");
}

/// Robot r2's link down from the start: the run ends with an error that names r2, within the
/// lockstep's bounded wait for the team to join.
#[test]
fn a_robot_whose_link_is_down_is_named() {
    let _one = serial();
    let plan = s4(1.0);
    let Some(hosts) = hosts_for(&plan, "hosts::a_robot_whose_link_is_down_is_named") else {
        return;
    };
    hosts.set_link("r2", false).expect("link down");
    let started = std::time::Instant::now();
    let err = run_on(&plan, &hosts, "hosts_link_down").expect_err("the run fails");
    let text = err.to_string();
    println!("after {:.1} s: {text}", started.elapsed().as_secs_f64());
    assert!(text.contains("r2") && !text.contains("\"r1\""), "the error names r2 only: {text}");
    assert!(started.elapsed().as_secs() < 120, "bounded: {:?}", started.elapsed());
}

/// Robot r1's TCP connections to the coordinator's host reset mid-run, every 0.8 s (`ss -K` on
/// r1's host: both ends see the link drop, and Zenoh reopens it within milliseconds, as after
/// the drop that once failed CI). Each time the coordinator waits for r1's token to come back
/// (`DEPARTURE_GRACE`) instead of letting go of the object: every check passes, the grasp is
/// never released, and no coordinator status after the team's first tick leaves r1 out. (Before
/// the grace, this run let go of the object at the first reset.) r1's agent waits for the
/// coordinator's token the same way (`COORDINATOR_GRACE`), a lost command is sent again, and
/// the object stays within 1 mm of its reference.
#[test]
fn the_team_holds_through_a_robots_link_to_the_coordinator_reset() {
    let _one = serial();
    let plan = s4(3.0);
    let Some(hosts) =
        hosts_for(&plan, "hosts::the_team_holds_through_a_robots_link_to_the_coordinator_reset")
    else {
        return;
    };
    let done = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let cutter = {
        let (hosts, done) = (hosts.clone(), done.clone());
        std::thread::spawn(move || {
            // Every 0.8 s from 1.5 s after the start until the run is over, at most 8 times:
            // (wall clock in ns, connections reset).
            let mut cuts = Vec::new();
            std::thread::sleep(std::time::Duration::from_millis(1500));
            while !done.load(std::sync::atomic::Ordering::Relaxed) && cuts.len() < 8 {
                cuts.push((
                    protocol::wall_clock_ns(),
                    hosts
                        .cut("r1", launch::launcher::COORDINATOR_HOST)
                        .expect("reset r1's connections"),
                ));
                std::thread::sleep(std::time::Duration::from_millis(800));
            }
            cuts
        })
    };
    let records = run_on(&plan, &hosts, "hosts_reset");
    done.store(true, std::sync::atomic::Ordering::Relaxed);
    let cuts = cutter.join().expect("the cutter");
    let records = records.expect("the run completes");
    // Resets that struck the running team: after its first status as running, before its last.
    let running = records
        .statuses
        .iter()
        .find(|s| s.mode == protocol::CoordinatorMode::Running)
        .map(|s| s.header.stamp_ns)
        .expect("the team ran");
    let end = records.statuses.last().map(|s| s.header.stamp_ns).unwrap_or(0);
    let struck: Vec<_> =
        cuts.iter().filter(|(at, n)| *n > 0 && *at > running && *at < end).collect();
    println!("connections of r1 to the coordinator reset (wall ns, count): {cuts:?}; {} while the team ran", struck.len());
    assert!(struck.len() >= 2, "r1's connections to the coordinator were reset at least twice while the team ran: {cuts:?}");
    let eval = evaluate::evaluate(&plan, &records, "hosts");
    println!("{}", evaluate::summary(&eval.metrics, &report_dir("hosts_reset")));
    for c in &eval.metrics.checks {
        assert!(c.passed, "{} = {} not below {}", c.name, c.value, c.bound);
    }
    assert_eq!(records.released_at, None, "the grasp was never let go of");
    // The resets do not show: r1's agent rides through its coordinator's token going and
    // coming back (COORDINATOR_GRACE; holding its posture at each reset moved the object
    // 1.5-2.3 mm), and a command lost in a reset is sent again when r1's terms of its tick
    // come again (before, the run waited out the agents' 20 s deadline).
    // A deadline waited out stops the lockstep for the agents' 20 s: judged by the largest
    // wall-clock gap between the ground truths of consecutive ticks, not by the run's length.
    let gap_ns = records
        .truth
        .windows(2)
        .map(|w| w[1].header.stamp_ns.saturating_sub(w[0].header.stamp_ns))
        .max()
        .unwrap_or(0);
    assert!(
        gap_ns < 5_000_000_000,
        "no deadline waited out: the longest wait between two ticks was {:.3} s",
        gap_ns as f64 * 1e-9
    );
    assert!(
        eval.metrics.object.position_max_m < 0.001,
        "the object within 1 mm of its reference through the resets: {} m",
        eval.metrics.object.position_max_m
    );
    let first = records
        .statuses
        .iter()
        .position(|s| s.mode == protocol::CoordinatorMode::Running)
        .expect("the team ran");
    // (As the run ends, the agents stop and leave.)
    for s in records.statuses[first..].iter().filter(|s| s.header.tick + 5 < plan.total_ticks()) {
        let out = !s.members.iter().any(|m| m == "r1")
            || s.silent.iter().any(|m| m == "r1")
            || s.late.iter().any(|m| m == "r1");
        assert!(!out, "tick {}: r1 left out of the team ({:?})", s.header.tick, s.detail);
    }
}

/// A fresh test CA with certificates for r1 and r2 (`common::certs`); with `keep_key` false,
/// the CA's key is removed (a folder an operator's site CA would give).
fn test_ca(name: &str, keep_key: bool) -> std::path::PathBuf {
    let dir = common::certs::make(&format!("hosts-{name}"), &["r1", "r2"]);
    if !keep_key {
        std::fs::remove_file(dir.join("ca.key")).expect("remove ca.key");
    }
    dir
}

/// S4 across hosts over mutual TLS with the access control (`team run --hosts --tls`): every
/// check passes; the coordinator listens on `quic/` at its host's address and every component
/// connects to it there; the run's certificates, signed for the hosts' addresses, are in the
/// report folder without the CA's key; the hosts are gone after the run. (Certificates naming
/// only 127.0.0.1 were refused by the TLS clients across hosts: no robot joined. Checked by
/// hand; the run then ends at the bridge's 60 s join wait.)
#[test]
fn s4_holds_across_hosts_over_mutual_tls() {
    let _one = serial();
    let plan = s4(1.5);
    let ca = test_ca("tls", true);
    if !common::hosts::available_or_skip("hosts::s4_holds_across_hosts_over_mutual_tls") {
        return;
    }
    let before = namespaces();
    let dir = report_dir("hosts_tls");
    // No configuration of an earlier run may stand in for this one's.
    std::fs::remove_dir_all(&dir)
        .and_then(|_| std::fs::create_dir_all(&dir))
        .expect("a fresh report folder");
    let (records, _) = run::run_recorded_secure(
        &plan,
        &RunOptions { distributed: true, hosts: true, progress: false, loss: Vec::new() },
        Some(&ca),
        &dir,
        None,
    )
    .expect("the run completes");
    let eval = evaluate::evaluate(&plan, &records, "hosts-tls");
    println!("{}", evaluate::summary(&eval.metrics, &dir));
    for c in &eval.metrics.checks {
        assert!(c.passed, "{} = {} not below {}", c.name, c.value, c.bound);
    }
    assert_eq!(namespaces(), before, "the run's hosts were removed");
    let config = |who: &str| {
        std::fs::read_to_string(dir.join(format!("zenoh-{who}.json5")))
            .unwrap_or_else(|e| panic!("zenoh-{who}.json5: {e}"))
    };
    let coordinator = config("coordinator");
    let hub = coordinator
        .split('"')
        .find(|t| {
            t.starts_with("quic/") && t.ends_with(":7447") || t.starts_with("quic/127.0.0.1:")
        })
        .expect("the coordinator listens on quic/")
        .to_string();
    for who in ["coordinator", "r1", "r2", "sim-bridge", "runner"] {
        let text = config(who);
        assert!(text.contains(&hub), "{who} reaches the coordinator at {hub}");
        assert!(!text.contains("tcp/"), "{who}: no plain TCP endpoint");
    }
    {
        assert!(!hub.starts_with("quic/127."), "across hosts, not on loopback: {hub}");
        let certs = dir.join("hosts-certs");
        assert!(
            certs.join("coordinator.pem").is_file() && certs.join("r2.key").is_file(),
            "the run's certificates"
        );
        assert!(!certs.join("ca.key").exists(), "the CA's key is not left in the report folder");
        let text = std::process::Command::new("openssl")
            .args(["x509", "-noout", "-ext", "subjectAltName", "-in"])
            .arg(certs.join("coordinator.pem"))
            .output()
            .expect("openssl");
        let addr = hub.trim_start_matches("quic/").trim_end_matches(":7447");
        assert!(
            String::from_utf8_lossy(&text.stdout).contains(&format!("IP Address:{addr}")),
            "the coordinator's certificate names its host's address {addr}"
        );
    }
    let _ = std::fs::remove_dir_all(&ca);
}

/// Test hosts over TLS with a certificate folder that has no CA key: the run is refused with
/// an error that names `ca.key`, before any host is made (so also where namespaces cannot be
/// made), and no host is left behind.
#[test]
fn hosts_over_tls_without_the_ca_key_are_refused_by_name() {
    let _one = serial();
    let plan = s4(0.5);
    let ca = test_ca("nokey", false);
    let before = namespaces();
    let err = run::run_recorded_secure(
        &plan,
        &RunOptions { distributed: true, hosts: true, progress: false, loss: Vec::new() },
        Some(&ca),
        &report_dir("hosts_tls_nokey"),
        None,
    )
    .expect_err("refused");
    let text = err.to_string();
    assert!(
        text.contains("ca.key") && text.contains("certificates"),
        "names the missing key: {text}"
    );
    assert_eq!(namespaces(), before, "no host left behind");
    let _ = std::fs::remove_dir_all(&ca);
}
