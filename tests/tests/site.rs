//! A site: two teams, `alpha` (2 robots) and `beta` (3 robots), on one Zenoh router that the
//! product runs (`team router`, router mode, the configuration `team router-config` writes),
//! over mutual TLS with the site's certificates (`scripts/make-test-certs.sh --router`,
//! `--team`).
//!
//! * Both teams carry their objects at once through the router: `team run --router` of S4
//!   (alpha) and the three-robot cube (beta), each a process per component, both all checks
//!   passed (S4's bounds), and each team's time series and torques are, to the last bit, those
//!   of its embedded run: the other team's traffic changes nothing.
//! * The router keeps each team to its keys. A client holding a valid alpha certificate but
//!   configured to speak for beta (so that its own access control lets everything through)
//!   publishes beta's terms and commands and subscribes to beta's states: beta receives
//!   nothing of it and it receives nothing of beta, while beta's own identities, in the same
//!   loop, do reach each other.
//!
//! Needs the release binaries (`cargo build --release --bins`) and openssl.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use launch::processes::{free_port, sibling_binary, spawn, ChildGuard};
use protocol::access::Identity;
use protocol::site::ClientConfig;
use protocol::transport::{self, Role, ZenohArgs};
use zenoh::Session;

/// A site's router running, with the certificates of the site and of both teams.
struct Site {
    dir: PathBuf,
    endpoint: String,
    _router: ChildGuard,
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("repo root").to_path_buf()
}

fn certs(args: &[&str]) {
    let script = repo().join("scripts/make-test-certs.sh");
    let out = Command::new(&script)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", script.display()));
    assert!(
        out.status.success(),
        "make-test-certs.sh {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The site's CA, the router's certificate, alpha's and beta's certificates; the router's
/// configuration by `team router-config`; `team router` started and listening.
fn site(tag: &str) -> Site {
    let dir = std::env::temp_dir().join(format!("{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = dir.to_str().unwrap();
    certs(&["--router", d]);
    certs(&["--ca", d, "--team", "alpha", &format!("{d}/alpha"), "r1", "r2"]);
    certs(&["--ca", d, "--team", "beta", &format!("{d}/beta"), "r1", "r2", "r3"]);
    let port = free_port().unwrap();
    let endpoint = protocol::access::secure_endpoint("127.0.0.1", port);
    let config = format!("{d}/router.json5");
    let out = Command::new(sibling_binary("team"))
        .args([
            "router-config",
            d,
            "--team",
            "alpha=r1,r2",
            "--team",
            "beta=r1,r2,r3",
            "--listen",
            &endpoint,
            "--out",
            &config,
        ])
        .output()
        .expect("team router-config runs");
    assert!(out.status.success(), "team router-config: {}", String::from_utf8_lossy(&out.stderr));
    let router =
        spawn("team", &["router".to_string(), config], "site router").expect("team router starts");
    let deadline = Instant::now() + Duration::from_secs(20);
    // QUIC is UDP: the router listens once its port can no longer be bound.
    while std::net::UdpSocket::bind(("127.0.0.1", port)).is_ok() {
        assert!(Instant::now() < deadline, "the router did not listen on {endpoint} within 20 s");
        std::thread::sleep(Duration::from_millis(50));
    }
    Site { dir, endpoint, _router: router }
}

impl Site {
    /// A session of `who` with the certificate of team `cert_team`, configured as a client of
    /// team `team` (a different team: a client that speaks for another team than its own).
    async fn client(&self, cert_team: &str, team: &str, who: Identity) -> Session {
        let cfg = ClientConfig::in_dir(&self.dir.join(cert_team), team, who, &self.endpoint);
        let path = self.dir.join(format!("{cert_team}-as-{team}-{}.json5", cfg.identity.name()));
        cfg.write(&path).expect("client configuration written");
        let args = ZenohArgs { config: Some(path), ..Default::default() };
        tokio::time::timeout(Duration::from_secs(10), transport::open(&args, Role::Member))
            .await
            .expect("session opened in time")
            .expect("session")
    }
}

/// Samples a subscriber received within a bounded drain.
fn drained(sub: &transport::SampleQueue) -> usize {
    let mut n = 0;
    while let Ok(Some(_)) = sub.try_recv() {
        n += 1;
    }
    n
}

#[test]
fn the_router_keeps_each_team_to_its_own_keys() {
    let site = site("site-acl");
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        use Identity::*;
        let beta_coordinator = site.client("beta", "beta", Coordinator).await;
        let beta_r1 = site.client("beta", "beta", Agent("r1".into())).await;
        let beta_bridge = site.client("beta", "beta", SimBridge).await;
        // alpha's certificates, configured for beta: their own ACL lets beta's keys through.
        let forged_r1 = site.client("alpha", "beta", Agent("r1".into())).await;
        let forged_coordinator = site.client("alpha", "beta", Coordinator).await;
        let forged_runner = site.client("alpha", "beta", Runner).await;

        let dynamics =
            protocol::keys::robot("beta", "r1", protocol::keys::RobotTopic::Dynamics).unwrap();
        let command =
            protocol::keys::robot("beta", "r1", protocol::keys::RobotTopic::Command).unwrap();
        let state = protocol::keys::robot("beta", "r1", protocol::keys::RobotTopic::State).unwrap();
        let at_coordinator = transport::subscribe(
            &beta_coordinator,
            protocol::keys::all_robots("beta", protocol::keys::RobotTopic::Dynamics).unwrap(),
        )
        .await
        .unwrap();
        let at_r1 = transport::subscribe(&beta_r1, command.clone()).await.unwrap();
        let r1_states = transport::subscribe(&beta_r1, state.clone()).await.unwrap();
        let spied_states = transport::subscribe(
            &forged_runner,
            protocol::keys::all_robots("beta", protocol::keys::RobotTopic::State).unwrap(),
        )
        .await
        .unwrap();

        let (mut own, mut forged) = ([0usize; 3], [0usize; 3]);
        let started = Instant::now();
        while started.elapsed() < Duration::from_secs(3) {
            // Beta's own: r1's terms to the coordinator, the coordinator's command to r1, the
            // bridge's state to r1 (the controls: these must arrive).
            beta_r1.put(&dynamics, b"own terms".to_vec()).await.unwrap();
            beta_coordinator.put(&command, b"own command".to_vec()).await.unwrap();
            beta_bridge.put(&state, b"own state".to_vec()).await.unwrap();
            // Alpha's identities on beta's keys.
            forged_r1.put(&dynamics, b"forged terms".to_vec()).await.unwrap();
            forged_coordinator.put(&command, b"forged command".to_vec()).await.unwrap();
            tokio::time::sleep(Duration::from_millis(50)).await;
            for (i, (sub, forged_text)) in [
                (&at_coordinator, &b"forged terms"[..]),
                (&at_r1, b"forged command"),
                (&r1_states, b"none"),
            ]
            .into_iter()
            .enumerate()
            {
                while let Ok(Some(s)) = sub.try_recv() {
                    if s.payload().to_bytes().as_ref() == forged_text {
                        forged[i] += 1
                    } else {
                        own[i] += 1
                    }
                }
            }
        }
        let spied = drained(&spied_states);
        assert!(
            own.iter().all(|&n| n > 10),
            "beta's own messages reach beta (terms, command, state): {own:?}"
        );
        assert_eq!(forged[0], 0, "alpha's r1 published terms into beta");
        assert_eq!(forged[1], 0, "alpha's coordinator published a command into beta");
        assert_eq!(spied, 0, "alpha's runner read beta's states");
        for s in
            [beta_coordinator, beta_r1, beta_bridge, forged_r1, forged_coordinator, forged_runner]
        {
            let _ = s.close().await;
        }
    });
    let _ = std::fs::remove_dir_all(&site.dir);
}

/// `team run` of `scenario` as `team` through the site's router, shortened; killed after
/// `limit`.
fn team_run(
    site: &Site,
    scenario: &str,
    team: &str,
    limit: Duration,
) -> (Child, Instant, Duration, PathBuf) {
    let (out, certs) = (site.dir.join(format!("run-{team}")), site.dir.join(team));
    let through_router = [
        "--router",
        &site.endpoint,
        "--team",
        team,
        "--tls",
        certs.to_str().expect("a UTF-8 path"),
    ];
    start_run(scenario, &out, &through_router, limit)
}

/// `team run` of `scenario`, shortened to 2 s, into `out`, with `extra` flags (none: embedded);
/// killed after `limit`.
fn start_run(
    scenario: &str,
    out: &Path,
    extra: &[&str],
    limit: Duration,
) -> (Child, Instant, Duration, PathBuf) {
    let child = Command::new(sibling_binary("team"))
        .args(["run", scenario, "--set", "duration=2", "--quiet", "--out"])
        .arg(out)
        .args(extra)
        .current_dir(repo())
        .env_remove("RUST_BACKTRACE")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("team run starts");
    (child, Instant::now(), limit, out.to_path_buf())
}

/// Wait for a run (bounded), then its status and output.
fn finish(
    (mut child, started, limit, out): (Child, Instant, Duration, PathBuf),
) -> (bool, String, PathBuf) {
    while child.try_wait().expect("the run's status").is_none() {
        if started.elapsed() > limit {
            let _ = child.kill();
            let text = child
                .wait_with_output()
                .map(|o| String::from_utf8_lossy(&o.stderr).to_string())
                .unwrap_or_default();
            panic!("the run in {} did not end within {limit:?}: {text}", out.display());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let o = child.wait_with_output().expect("the run's output");
    (
        o.status.success(),
        format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr)),
        out,
    )
}

#[test]
fn two_teams_carry_their_objects_through_one_router() {
    let site = site("site-teams");
    let limit = Duration::from_secs(600);
    let scenarios =
        [("alpha", "scenarios/s4_object_circle.toml"), ("beta", "scenarios/team3_cube.toml")];
    let alpha = team_run(&site, scenarios[0].1, "alpha", limit);
    let beta = team_run(&site, scenarios[1].1, "beta", limit);
    let runs = [("alpha", finish(alpha)), ("beta", finish(beta))];
    for (team, (ok, text, out)) in &runs {
        assert!(ok, "team {team}'s run failed: {text}");
        assert!(
            text.contains("site mode") && text.contains("checks passed"),
            "team {team}: {text}"
        );
        let metrics: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join("metrics.json")).expect("metrics.json"),
        )
        .unwrap();
        assert_eq!(metrics["passed"], true, "team {team}: {metrics}");
        assert_eq!(metrics["mode"], "site", "team {team}");
        assert_eq!(metrics["drop"]["dropped"], false, "team {team} holds its object");
        let rms = metrics["object"]["position_rms_m"].as_f64().expect("the object's RMS");
        assert!(rms < 5e-3, "team {team}: the object within S4's 5 mm RMS: {rms}");
    }
    // Neither team disturbed the other: each run is, to the last bit, the team's embedded run.
    for ((team, scenario), (_, (_, _, out))) in scenarios.iter().zip(&runs) {
        let alone = site.dir.join(format!("embedded-{team}"));
        let (ok, text, _) = finish(start_run(scenario, &alone, &[], limit));
        assert!(ok, "the embedded run of {scenario} failed: {text}");
        for file in ["timeseries.csv", "torques.csv"] {
            let read = |dir: &PathBuf| {
                std::fs::read(dir.join(file))
                    .unwrap_or_else(|e| panic!("{}: {e}", dir.join(file).display()))
            };
            assert!(
                read(out) == read(&alone),
                "team {team}: {file} through the router differs from the embedded run's"
            );
        }
    }
    let _ = std::fs::remove_dir_all(&site.dir);
}

/// `config/zenoh/site/` is what `team router-config site --team alpha=r1,r2 --team
/// beta=r1,r2,r3 --listen quic/127.0.0.1:7448` and `team zenoh-config site/TEAM --team TEAM
/// --robots ... --router quic/127.0.0.1:7448` write.
#[test]
fn the_shipped_site_configurations_are_the_generated_ones() {
    let shipped = repo().join("config/zenoh/site");
    let read = |path: PathBuf| -> serde_json::Value {
        let text =
            std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        serde_json::from_str(&text).unwrap()
    };
    let router = "quic/127.0.0.1:7448";
    let teams = [("alpha", vec!["r1", "r2"]), ("beta", vec!["r1", "r2", "r3"])];
    let site: Vec<protocol::site::SiteTeam> = teams
        .iter()
        .map(|(t, r)| protocol::site::SiteTeam {
            team: t.to_string(),
            robots: r.iter().map(|s| s.to_string()).collect(),
        })
        .collect();
    let generated =
        protocol::site::RouterConfig::in_dir(Path::new("site"), site.clone(), vec![router.into()])
            .to_json()
            .unwrap();
    assert_eq!(
        read(shipped.join("router.json5")),
        generated,
        "router.json5 differs from team router-config"
    );
    for t in &site {
        let certs = Path::new("site").join(&t.team);
        let identities = Identity::all(&t.robots);
        assert_eq!(identities.len(), 4 + t.robots.len());
        for who in identities {
            let path = shipped.join(&t.team).join(protocol::access::file_name(&who));
            let cfg = ClientConfig::in_dir(&certs, &t.team, who, router);
            assert_eq!(
                read(path.clone()),
                cfg.to_json().unwrap(),
                "{} differs from team zenoh-config --router",
                path.display()
            );
        }
    }
}
