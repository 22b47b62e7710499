//! `team`: the main job. Runs the whole team in simulation.

use anyhow::Result;
use clap::{Args, Parser, Subcommand};
use std::path::{Path, PathBuf};

use protocol::logging::{self, Verbosity};

use evaluation::evaluate;
use evaluation::plots;
use experiments::compare;
use experiments::simulated_capacity;
use launch::echo;
use launch::launcher::RunMode;
use launch::record::{self, RecordOptions, ScenarioSource};
use launch::run::{self as scenario_run, FailedRun, RunOptions};
use launch::smoke::{self, SmokeConfig};
use scenario::file::Scenario;
use scenario::plan::{self, repo_root};
use scenario::team_capacity as capacity;

#[derive(Parser)]
#[command(version, about = "Run the team of legged manipulators in simulation")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scenario (scenarios/*.toml) with the whole stack in the loop: MuJoCo, one agent
    /// per robot, the paper's coordinator. Writes a report folder (metrics.json, CSV time
    /// series, plots, report.html, the recording run.mcap) and prints a summary; exits with an
    /// error if an acceptance check fails. A run that fails midway is reported over the ticks
    /// it saw (its error in the report) and exits with its error.
    Run(RunArgs),
    /// Rebuild a run's report (metrics, time series, plots, report.html) from its recording
    /// alone (the run.mcap that `team run` wrote).
    Report {
        /// The recording (run.mcap).
        recording: PathBuf,
        /// Report folder (default: the recording's folder).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Print every message on a Zenoh key as JSON lines (wildcards allowed), like
    /// `ros2 topic echo`: e.g. `team echo team/team/coordinator/status --count 1`. Liveliness
    /// keys (team/team/member/*, team/team/coordinator/alive) print their tokens' comings and
    /// goings as {"key", "alive"}. Finds a running `team run` on this machine, or a hub
    /// started by hand, without flags (see --connect).
    Echo {
        /// Key expression, e.g. team/team/robot/*/state.
        key: String,
        /// Stop after this many messages.
        #[arg(long)]
        count: Option<u64>,
        /// Give up after this many seconds without a message.
        #[arg(long, default_value_t = 10.0)]
        wait: f64,
        #[command(flatten)]
        zenoh: protocol::transport::ZenohArgs,
    },
    /// Write every identity's Zenoh configuration (mutual TLS, the team's access control) into
    /// a folder: zenoh-coordinator.json5, zenoh-r1.json5, ..., zenoh-tool.json5, for any binary's
    /// --zenoh-config. Make the certificates first: scripts/make-test-certs.sh CERTS r1 r2.
    /// With --router, the team's configurations as clients of a site's router (certificates
    /// from scripts/make-test-certs.sh --ca SITE --team TEAM CERTS r1 r2).
    ZenohConfig {
        /// Folder of the certificates (ca.pem, IDENTITY.pem, IDENTITY.key); written into the
        /// files as given (a relative path is resolved from each component's working directory).
        certs: PathBuf,
        /// Robot ids, comma separated.
        #[arg(long, value_delimiter = ',', default_value = "r1,r2")]
        robots: Vec<String>,
        #[arg(long, default_value = "team")]
        team: String,
        /// The coordinator's endpoint: it listens there, the others connect to it.
        #[arg(long, default_value = "quic/127.0.0.1:7447", conflicts_with = "router")]
        hub: String,
        /// A site's router endpoint (quic/HOST:PORT): every identity is a client of it.
        #[arg(long)]
        router: Option<String>,
        /// Output folder.
        #[arg(long, default_value = "config/zenoh")]
        out: PathBuf,
    },
    /// Write a site router's Zenoh configuration: router mode, mutual TLS with the site's CA,
    /// and the access control that keeps each team to its own keys. Make the router's
    /// certificate first: scripts/make-test-certs.sh --router CERTS.
    RouterConfig {
        /// Folder of the site's CA and the router's certificate (ca.pem, router.pem, router.key).
        certs: PathBuf,
        /// A team of the site and its robots, NAME=ROBOT,ROBOT,...; once per team.
        #[arg(long = "team", value_name = "NAME=ROBOTS", required = true)]
        teams: Vec<String>,
        /// Endpoints the router listens on.
        #[arg(long, default_value = "quic/0.0.0.0:7447")]
        listen: Vec<String>,
        /// Output file.
        #[arg(long, default_value = "config/zenoh/site/router.json5")]
        out: PathBuf,
    },
    /// Run a site's Zenoh router (written by team router-config) until interrupted.
    Router {
        /// The router's configuration.
        config: PathBuf,
    },
    /// Run scenarios with several controllers side by side (experiment S3: `team compare
    /// scenarios/s3_hold.toml scenarios/s1_torso_and_object.toml --controllers pidc,mqp`):
    /// one folder with comparison.md / .json (tracking, drops, slip, contact forces against
    /// their limits, solve times, QP failures), the object-Z figure per scenario and each
    /// run's own report.
    Compare {
        /// Scenario files (TOML).
        #[arg(required = true)]
        scenarios: Vec<PathBuf>,
        /// Controller kinds, comma separated.
        #[arg(long, value_delimiter = ',', default_value = "pidc,mqp")]
        controllers: Vec<String>,
        /// Overrides for every run (as `team run --set`).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Report folder (default: reports/compare).
        #[arg(long)]
        out: Option<PathBuf>,
        #[arg(long)]
        quiet: bool,
    },
    /// Scale a scenario's motion amplitudes (or, with --speed, frequencies) by each factor and
    /// run it with each controller until it first misses an acceptance bound: where each
    /// controller stops meeting them.
    Sweep {
        scenario: PathBuf,
        #[arg(long, value_delimiter = ',', default_value = "pidc,mqp")]
        controllers: Vec<String>,
        /// Amplitude factors, ascending, comma separated.
        #[arg(long, value_delimiter = ',', default_value = "0.25,0.5,1,1.5,2,3")]
        scales: Vec<f64>,
        /// Scale the motions' speed (frequencies) instead of their amplitudes.
        #[arg(long)]
        speed: bool,
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Report folder (default: reports/sweep-<scenario>).
        #[arg(long)]
        out: Option<PathBuf>,
        #[arg(long)]
        quiet: bool,
    },
    /// The heaviest object the scenario's team can hold in its start configuration (the static
    /// team problem with the controller's limits and margins, bisection on the mass), and the
    /// limits that bind just above it.
    Capacity {
        /// Scenario file (TOML).
        scenario: PathBuf,
        /// Override any number of the scenario (as for `run`): --set friction_margin=1
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Width of the bisection's final bracket, kg.
        #[arg(long, default_value_t = coordinator::capacity::CAPACITY_TOLERANCE)]
        tolerance: f64,
        /// Also find the heaviest object held in MuJoCo (every acceptance check passed), by
        /// bisection on the mass in lockstep runs, and its ratio to the computed capacity.
        #[arg(long)]
        simulate: bool,
        /// Width of the simulated bisection's final bracket, kg (default: 2 % of the capacity).
        #[arg(long)]
        simulate_tolerance: Option<f64>,
        /// The simulated search's reports (default: reports/<scenario>-capacity).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Smoke run of the whole stack: sim-bridge, agents and coordinator exchange real
    /// messages over Zenoh for N ticks (placeholder physics and controller).
    Smoke(SmokeArgs),
}

#[derive(Args)]
struct RunArgs {
    /// Scenario file (TOML).
    scenario: PathBuf,
    /// Override any number of the scenario: --set duration=5 --set gains.object.stiffness=[...]
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Run every component as its own process on loopback instead of one process.
    #[arg(long)]
    distributed: bool,
    /// Run every component as its own process on its own test host (a Linux network
    /// namespace, made for the run by scripts/testhosts.sh and removed after it; root).
    #[arg(long)]
    hosts: bool,
    /// With --hosts, drop this share of a robot's packets, both ways, on its host's link for
    /// the whole run (nftables): --loss r1=5. Repeat for more robots.
    #[arg(long, value_name = "ROBOT=PERCENT", requires = "hosts")]
    loss: Vec<launch::run::LinkLoss>,
    /// Run the scenario against the wall clock: the sim-bridge paces physics at the
    /// control period, a robot whose torques are late keeps its last ones, agents keep
    /// their real deadlines (25 ms or 5 ticks), and the report adds the loop's timing.
    /// Settling stays lockstep. Combines with --distributed, --hosts and --tls.
    #[arg(long)]
    realtime: bool,
    /// Run distributed on loopback over mutual TLS with the team's access control, with the
    /// certificates in DIR (make them with scripts/make-test-certs.sh DIR r1 r2 ...). With
    /// --hosts, the test CA in DIR (ca.pem, ca.key) signs certificates for the hosts'
    /// addresses into the report folder's hosts-certs/.
    #[arg(long, value_name = "DIR")]
    tls: Option<PathBuf>,
    /// As a client of a site's Zenoh router at this endpoint (quic/HOST:PORT), every component
    /// its own process; needs --tls with the team's site certificates (docs/realtime.md,
    /// "A site").
    #[arg(long, value_name = "ENDPOINT", requires = "tls", conflicts_with = "hosts")]
    router: Option<String>,
    /// The team's name on the bus (team/NAME/...): teams that share a router differ by it.
    #[arg(long, default_value = scenario::TEAM)]
    team: String,
    /// Report folder (default: reports/<scenario file name>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the summary alone: no progress, and on stderr nothing but errors (a failed
    /// run's error among them).
    #[arg(long, short, conflicts_with = "verbose")]
    quiet: bool,
    /// The components' log on stderr: -v what an operator follows (joins, leaves, safe
    /// mode, phases), -vv per-tick events and Zenoh's own lines, -vvv everything. Without
    /// it, warnings and errors only; RUST_LOG, when set, overrides both flags.
    #[arg(long, short, action = clap::ArgAction::Count)]
    verbose: u8,
    /// Serve the run live to Foxglove (WebSocket on 127.0.0.1:PORT; open Foxglove and
    /// connect to ws://127.0.0.1:PORT). The run is recorded to run.mcap either way.
    #[arg(long, value_name = "PORT", num_args = 0..=1, default_missing_value = "8765")]
    live: Option<u16>,
    /// Do not record the run (no run.mcap): the report is written all the same.
    #[arg(long, conflicts_with = "live")]
    no_record: bool,
    /// Split the recording into files of about this many MB: run.mcap is closed and renamed
    /// run.0001.mcap, run.0002.mcap, ... as the run goes (team report reads them all).
    #[arg(long, value_name = "MB", conflicts_with = "no_record",
          value_parser = clap::value_parser!(u64).range(1..))]
    record_split_mb: Option<u64>,
    /// With --record-split-mb: keep only the newest N closed files (the disk a run takes is
    /// then bounded whatever its length; team report needs them all).
    #[arg(long, value_name = "N", requires = "record_split_mb",
          value_parser = clap::value_parser!(u64).range(1..))]
    record_keep: Option<u64>,
}

#[derive(Args)]
struct SmokeArgs {
    /// Number of robots (named r1, r2, ...).
    #[arg(long, default_value_t = 2)]
    robots: usize,
    #[arg(long, default_value_t = 2000)]
    ticks: u64,
    #[arg(long, default_value_t = 18)]
    joints: usize,
    /// Run every component as its own process on loopback instead of one process.
    #[arg(long)]
    distributed: bool,
    /// Distributed over mutual TLS with the team's access control, certificates in DIR.
    #[arg(long, value_name = "DIR")]
    tls: Option<PathBuf>,
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    logging::init(verbosity(&cli.command));
    match cli.command {
        Command::Run(a) => run_scenario(a),
        Command::Compare { scenarios, controllers, set, out, quiet } => {
            compare_controllers(&scenarios, &controllers, &set, out, quiet)
        }
        Command::Sweep { scenario, controllers, scales, speed, set, out, quiet } => {
            let what = if speed { compare::Scaling::Speed } else { compare::Scaling::Amplitude };
            sweep(&scenario, &controllers, (&scales, what), &set, out, quiet)
        }
        Command::Capacity { scenario, set, tolerance, simulate, simulate_tolerance, out } => {
            let simulate = simulate.then_some((simulate_tolerance, out));
            team_capacity(&scenario, set, tolerance, simulate)
        }
        Command::Report { recording, out } => report_from_recording(&recording, out),
        Command::Echo { key, count, wait, zenoh } => echo_key(key, count, wait, &zenoh),
        Command::ZenohConfig { certs, robots, team, hub, router, out } => {
            write_zenoh_configs(&certs, robots, team, &hub, router, &out)
        }
        Command::RouterConfig { certs, teams, listen, out } => {
            write_router_config(&certs, &teams, listen, &out)
        }
        Command::Router { config } => run_router(&config),
        Command::Smoke(a) => smoke_run(a),
    }
}

/// `team compare`: controllers side by side on the same scenarios.
fn compare_controllers(
    scenarios: &[PathBuf],
    controllers: &[String],
    set: &[String],
    out: Option<PathBuf>,
    quiet: bool,
) -> Result<()> {
    let dir = out.unwrap_or_else(|| PathBuf::from("reports/compare"));
    create_dir(&dir)?;
    let rows = compare::compare(scenarios, controllers, set, &dir, &repo_root(), !quiet)?;
    print!("{}", compare::markdown(&rows));
    println!("report: {}", dir.display());
    Ok(())
}

/// `team sweep`: one scenario's motion scaled, with each controller.
fn sweep(
    scenario: &Path,
    controllers: &[String],
    scales: (&[f64], compare::Scaling),
    set: &[String],
    out: Option<PathBuf>,
    quiet: bool,
) -> Result<()> {
    let dir = out.unwrap_or_else(|| compare::default_sweep_dir(scenario));
    create_dir(&dir)?;
    let (rows, limits) =
        compare::sweep(scenario, controllers, scales, set, &dir, &repo_root(), !quiet)?;
    print!("{}", compare::markdown(&rows));
    print!("{}", compare::limits_summary(&limits, scales.1, scales.0));
    println!("report: {}", dir.display());
    Ok(())
}

/// `team capacity`: the heaviest object the plan accepts and, with `simulate` (its bisection's
/// tolerance and report folder), the heaviest held in MuJoCo.
fn team_capacity(
    scenario: &Path,
    mut set: Vec<String>,
    tolerance: f64,
    simulate: Option<(Option<f64>, Option<PathBuf>)>,
) -> Result<()> {
    // The scenario's own mass may be beyond the capacity: plan without the check.
    set.push("capacity_check=false".into());
    let plan = plan::plan(&Scenario::load(scenario, &set)?, &repo_root())?;
    let t0 = std::time::Instant::now();
    let cap = capacity::capacity(&plan, tolerance)?;
    print!("{}", capacity::summary(&plan, &cap, tolerance, t0.elapsed().as_secs_f64()));
    let Some((simulate_tolerance, out)) = simulate else { return Ok(()) };
    let dir = out.unwrap_or_else(|| {
        PathBuf::from(format!("{}-capacity", scenario_run::default_report_dir(scenario).display()))
    });
    simulated(&plan, cap.mass(), simulate_tolerance, &dir)
}

/// `team capacity --simulate`: the searches over closed-loop runs, each trial printed.
fn simulated(plan: &plan::Plan, computed: f64, tolerance: Option<f64>, dir: &Path) -> Result<()> {
    let trial = |mass: f64| {
        let root = repo_root();
        let out = dir.join(format!("{mass:.3}kg"));
        let trial = simulated_capacity::run_trial(&plan.scenario, &root, mass, &out)?;
        let held = if trial.held { "held" } else { "not held" };
        println!("  {mass:.3} kg: {held}, the motion yielding on {} ticks", trial.yielded);
        Ok::<_, anyhow::Error>(trial)
    };
    let tolerance = tolerance.unwrap_or(0.02 * computed);
    let searches = simulated_capacity::held_and_tracked(computed, tolerance, 16, trial)?;
    for sim in &searches {
        print!("{}", simulated_capacity::summary(sim, computed));
    }
    Ok(())
}

/// `team report`: a run's report rebuilt from its recording.
fn report_from_recording(recording: &Path, out: Option<PathBuf>) -> Result<()> {
    let dir = out.unwrap_or_else(|| recording.parent().map(Path::to_path_buf).unwrap_or_default());
    create_dir(&dir)?;
    let (plan, records, eval) = record::replay::evaluate_recording(recording, &repo_root())?;
    write_report(&plan, &eval, &records, &dir)
}

/// `team zenoh-config`: each component's Zenoh configuration for mutual TLS, for a team's hub
/// or a site's router.
fn write_zenoh_configs(
    certs: &Path,
    robots: Vec<String>,
    team: String,
    hub: &str,
    router: Option<String>,
    out: &Path,
) -> Result<()> {
    let written = match router {
        Some(router) => protocol::site::write_clients(
            certs,
            &protocol::site::SiteTeam { team, robots },
            &router,
            out,
        )?,
        None => protocol::access::write_team(certs, &team, &robots, hub, out)?,
    };
    for path in written {
        println!("{}", path.display());
    }
    Ok(())
}

/// `team router-config`: a site router's configuration for the teams it serves.
fn write_router_config(
    certs: &Path,
    teams: &[String],
    listen: Vec<String>,
    out: &Path,
) -> Result<()> {
    let teams =
        teams.iter().map(|t| protocol::site::SiteTeam::parse(t)).collect::<Result<Vec<_>, _>>()?;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        create_dir(dir)?;
    }
    protocol::site::RouterConfig::in_dir(certs, teams, listen).write(out)?;
    println!("{}", out.display());
    Ok(())
}

/// How much a command logs: `team run`'s from its flags, the other commands' what an operator
/// follows.
fn verbosity(command: &Command) -> Verbosity {
    match command {
        Command::Run(a) => Verbosity::from_flags(a.quiet, a.verbose),
        _ => Verbosity::Info,
    }
}

/// `team run`: plan, run (recorded), evaluate, report; an error if a check failed. A run that
/// fails after ticks were seen is evaluated and reported over them; its error is then the
/// command's.
fn run_scenario(a: RunArgs) -> Result<()> {
    let opts = RunOptions {
        distributed: a.distributed,
        hosts: a.hosts,
        progress: !a.quiet,
        loss: a.loss.clone(),
    };
    let mode_name = mode_name(&opts, a.router.is_some(), a.tls.is_some(), a.realtime);
    let pace = if a.realtime { scenario::Pacing::Realtime } else { scenario::Pacing::Lockstep };
    let s = Scenario::load_paced(&a.scenario, &a.set, pace)?;
    let dir = a.out.clone().unwrap_or_else(|| scenario_run::default_report_dir(&a.scenario));
    create_dir(&dir)?;
    if !a.quiet {
        println!("{}: planning (hands placed on the object by IK)...", s.name);
    }
    let mut plan = plan::plan(&s, &repo_root())?;
    plan.scene.realtime = a.realtime;
    plan.set_team(&a.team)?;
    if !a.quiet {
        println!(
            "{}: settling {:.1} s, then {:.1} s of scenario at {} Hz ({} mode)",
            s.name, s.settle, s.duration, s.control_hz, mode_name
        );
    }
    let source = ScenarioSource::read(&a.scenario, &a.set, pace)
        .map_err(|e| anyhow::anyhow!("reading {}: {e}", a.scenario.display()))?;
    let split = a
        .record_split_mb
        .map(|mb| record::segments::Split { bytes: mb << 20, keep: a.record_keep });
    let rec = RecordOptions { path: dir.join("run.mcap"), scenario: source, live: a.live, split };
    let rec = (!a.no_record).then_some(&rec);
    let ran = run_team(&a, &plan, &opts, &dir, rec)?;
    report_run(&plan, &ran, &mode_name, &dir, a.no_record)
}

/// The run's evaluation (over the ticks it saw if it failed), its summary and report folder;
/// the run's error first, then whatever could not be written, then failed checks.
fn report_run(
    plan: &plan::Plan,
    ran: &Ran,
    mode_name: &str,
    dir: &Path,
    no_record: bool,
) -> Result<()> {
    let eval = match &ran.error {
        Some(e) => evaluate::evaluate_failed(plan, &ran.records, mode_name, &e.to_string()),
        None => evaluate::evaluate(plan, &ran.records, mode_name),
    };
    // Whatever could not be written is named at the end, after the run's summary.
    let mut errors = Vec::new();
    if let Err(e) = write_report(plan, &eval, &ran.records, dir) {
        errors.push(format!("the report could not be written: {e:#}"));
    }
    if no_record {
        println!("  recording: none (--no-record)");
    }
    if let Some(r) = &ran.recording {
        errors.extend(recording_summary(r));
    }
    match &ran.error {
        Some(e) => errors.insert(
            0,
            format!(
                "{e} (the report of the {} ticks it saw is in {})",
                ran.records.ticks_seen,
                dir.display()
            ),
        ),
        None if !eval.metrics.passed => errors
            .push(format!("acceptance checks failed (see {})", dir.join("metrics.json").display())),
        None => {}
    }
    anyhow::ensure!(errors.is_empty(), "{}", errors.join("; "));
    Ok(())
}

/// How a run ended: its records, its recording, and the error it ended in after them.
struct Ran {
    records: evaluation::records::Records,
    recording: Option<record::RecordingSummary>,
    error: Option<scenario_run::RunError>,
}

/// The run in the mode `a` asks for: over a site's router, or on loopback or test hosts. A run
/// that failed after ticks were seen comes back with its error; one that failed before any is
/// the error.
fn run_team(
    a: &RunArgs,
    plan: &plan::Plan,
    opts: &RunOptions,
    dir: &Path,
    rec: Option<&RecordOptions>,
) -> Result<Ran> {
    let outcome = match (&a.router, &a.tls) {
        (Some(router), Some(certs)) => {
            let mode = RunMode::Site {
                dir: dir.to_path_buf(),
                certs: std::path::absolute(certs)?,
                router: router.clone(),
            };
            scenario_run::run_recorded_in(plan, opts, &mode, rec)
        }
        _ => scenario_run::run_recorded_secure(plan, opts, a.tls.as_deref(), dir, rec),
    };
    match outcome {
        Ok((records, recording)) => Ok(Ran { records, recording, error: None }),
        Err(FailedRun { error, records: Some(records), recording }) => {
            Ok(Ran { records: *records, recording: recording.map(|r| *r), error: Some(error) })
        }
        Err(failed) => Err(failed.into_error().into()),
    }
}

/// The run's mode as the summary names it.
fn mode_name(opts: &RunOptions, site: bool, tls: bool, realtime: bool) -> String {
    let mut name = match site {
        true if realtime => "site, real time".to_string(),
        true => "site".to_string(),
        false => opts.mode_label(tls, realtime),
    };
    for l in &opts.loss {
        name.push_str(&format!(", {} % loss on {}", l.percent, l.robot));
    }
    name
}

/// The recording's line on stdout, or why it is incomplete.
fn recording_summary(r: &record::RecordingSummary) -> Option<String> {
    if let Some(e) = &r.error {
        return Some(format!("the recording {} is incomplete: {e}", r.path.display()));
    }
    let files = match r.segments {
        0 => String::new(),
        n => format!(" in {} files", n + 1),
    };
    println!(
        "  recording: {} ({:.1} MB{files}, {} messages, {} dropped)",
        r.path.display(),
        r.bytes as f64 / 1e6,
        r.messages,
        r.dropped
    );
    None
}

/// The summary on stdout, then the report folder (data, figures, report.html).
fn write_report(
    plan: &plan::Plan,
    eval: &evaluate::Evaluation,
    records: &evaluation::records::Records,
    dir: &Path,
) -> Result<()> {
    print!("{}", evaluate::summary(&eval.metrics, dir));
    evaluate::write_report(plan, eval, dir)?;
    plots::write_all(plan, eval, records, dir)?;
    Ok(())
}

/// `team router`: the site's router until Ctrl-C (or SIGTERM's default end).
fn run_router(config: &Path) -> Result<()> {
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async {
        let router = launch::router::open_router(config).await?;
        println!("router {} listening on {:?}", router.session.zid(), router.listen);
        tokio::signal::ctrl_c().await?;
        router.session.close().await.map_err(|e| anyhow::anyhow!("closing the router: {e}"))?;
        Ok(())
    })
}

/// `team echo`: the messages on `key` as JSON lines.
fn echo_key(
    key: String,
    count: Option<u64>,
    wait: f64,
    zenoh: &protocol::transport::ZenohArgs,
) -> Result<()> {
    anyhow::ensure!(wait.is_finite() && wait > 0.0, "--wait must be a positive number of seconds");
    let rt = tokio::runtime::Runtime::new()?;
    let opts = echo::EchoOptions { key, count, wait: std::time::Duration::from_secs_f64(wait) };
    rt.block_on(async {
        let session = protocol::transport::open(zenoh, protocol::transport::Role::Tool).await?;
        let result = echo::echo(&session, &opts, &mut std::io::stdout().lock()).await;
        let _ = session.close().await;
        result.map(|_| ()).map_err(anyhow::Error::from)
    })
}

/// `team smoke`: the placeholder team, embedded or as processes (in a temporary folder).
fn smoke_run(a: SmokeArgs) -> Result<()> {
    anyhow::ensure!((1..=64).contains(&a.robots), "--robots must be between 1 and 64");
    anyhow::ensure!(a.joints > 0, "--joints must be positive");
    let cfg = SmokeConfig::of_team(a.robots, a.joints, a.ticks);
    let dir = std::env::temp_dir().join(format!("team-smoke-{}", std::process::id()));
    let distributed = a.distributed || a.tls.is_some();
    let mode = RunMode::on_loopback(distributed, a.tls.as_deref(), &dir);
    if distributed {
        create_dir(&dir)?;
    }
    let rt = tokio::runtime::Runtime::new()?;
    let outcome = rt.block_on(smoke::run(&cfg, &mode));
    if distributed {
        let _ = std::fs::remove_dir_all(&dir);
    }
    println!("{}", smoke::summary(&cfg, &mode, &outcome?));
    Ok(())
}

fn create_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| anyhow::anyhow!("creating {}: {e}", dir.display()))
}
