//! `sim-bridge`: the robots' state source and torque sink in simulation.

use std::time::Duration;

use anyhow::Result;
use clap::{Parser, Subcommand};
use protocol::transport::{self, Role, ZenohArgs};
use sim_bridge::lockstep::{self, LockstepConfig};
use sim_bridge::plant::PlaceholderPlant;
use sim_bridge::scene::{settle_then_run, Pace, PhaseReport};

#[derive(Parser)]
#[command(version, about = "Simulated robots for the team, in lockstep over Zenoh")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Smoke run: placeholder joint dynamics for the given robots, in lockstep.
    Smoke(SmokeArgs),
    /// Run the team in MuJoCo: robots from their description files, the object, lockstep
    /// (default) or real time, with the agents and the coordinator running elsewhere. The
    /// robots start at their standing pose (hands are put on the object by the runner's grasp
    /// planning: `team run`, or `scene` with the file it writes). Prints the real-time factor.
    Run(RunArgs),
    /// Run a scene file (world, pushes, settle and run lengths) as `team run --distributed`
    /// writes it into its report folder; lockstep, ground truth published every tick.
    Scene {
        /// The scene file (TOML, `sim_bridge::scene::Scene`).
        path: std::path::PathBuf,
        #[command(flatten)]
        zenoh: ZenohArgs,
    },
}

#[derive(clap::Args)]
struct SmokeArgs {
    /// Robot ids, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "r1,r2")]
    robots: Vec<String>,
    #[arg(long, default_value = "team")]
    team: String,
    #[arg(long, default_value_t = 18)]
    joints: usize,
    #[arg(long, default_value_t = 1000)]
    ticks: u64,
    /// Initial joint velocity of every placeholder joint, rad/s.
    #[arg(long, default_value_t = 0.5)]
    v0: f64,
    /// Control period, s.
    #[arg(long, default_value_t = 0.001)]
    dt: f64,
    /// Seconds a tick may wait for torques before the run fails naming the robot.
    #[arg(long, default_value_t = 2.0)]
    command_timeout: f64,
    #[command(flatten)]
    zenoh: ZenohArgs,
}

#[derive(clap::Args)]
struct RunArgs {
    /// Robot ids, comma separated; they stand on a circle of radius --spacing/2 around the
    /// object, facing it (two robots: the paper's pair, 2.3 m apart).
    #[arg(long, value_delimiter = ',', default_value = "r1,r2")]
    robots: Vec<String>,
    /// Robot description (TOML) used for every robot; default: the default robot.
    #[arg(long)]
    description: Option<std::path::PathBuf>,
    /// Distance between facing robots' bases, m.
    #[arg(long, default_value_t = 2.3)]
    spacing: f64,
    #[arg(long, default_value = "team")]
    team: String,
    /// No object in the world.
    #[arg(long)]
    no_object: bool,
    /// Object box edge lengths, m (x,y,z).
    #[arg(long, value_delimiter = ',', default_value = "0.6,0.6,0.6")]
    object_size: Vec<f64>,
    #[arg(long, default_value_t = 1.0)]
    object_mass: f64,
    /// Object centre, m (x,y,z).
    #[arg(long, value_delimiter = ',', default_value = "0,0,0.6")]
    object_position: Vec<f64>,
    #[arg(long, default_value_t = 1000.0)]
    control_hz: f64,
    #[arg(long, default_value_t = 1000.0)]
    physics_hz: f64,
    #[arg(long, default_value_t = 5000)]
    ticks: u64,
    /// Paced by the wall clock; a missing torque holds the last one and is counted.
    #[arg(long)]
    realtime: bool,
    /// What a robot's drives do when its agent leaves or its torques stop (`unpowered`,
    /// `freeze`).
    #[arg(long, value_enum, default_value = "unpowered")]
    drive_loss: sim_bridge::plant::DriveLoss,
    /// Seconds a lockstep tick may wait for torques before the run fails naming the robot.
    #[arg(long, default_value_t = 2.0)]
    command_timeout: f64,
    /// Seconds to wait for every robot to join.
    #[arg(long, default_value_t = 30.0)]
    start_timeout: f64,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Standard deviation of initial joint noise, rad.
    #[arg(long, default_value_t = 0.0)]
    joint_noise: f64,
    /// Write the recorded ground truth (every --record-every ticks) as CSV here.
    #[arg(long)]
    ground_truth_csv: Option<std::path::PathBuf>,
    #[arg(long, default_value_t = 10)]
    record_every: u64,
    /// Ticks of settling under the controller (lockstep) before the scenario clock starts at 0;
    /// tick numbers continue so that the agents keep accepting commands.
    #[arg(long, default_value_t = 0)]
    settle_ticks: u64,
    #[command(flatten)]
    zenoh: ZenohArgs,
}

#[tokio::main]
async fn main() -> Result<()> {
    protocol::logging::init(protocol::logging::Verbosity::Info);
    match Cli::parse().command {
        Command::Smoke(args) => smoke(args).await?,
        Command::Run(args) => run(args).await?,
        Command::Scene { path, zenoh } => scene(&path, &zenoh).await?,
    }
    Ok(())
}

/// Placeholder joint dynamics for the given robots, in lockstep; prints the tick rate.
async fn smoke(a: SmokeArgs) -> Result<()> {
    let SmokeArgs { robots, team, joints, ticks, v0, dt, command_timeout, zenoh } = a;
    anyhow::ensure!(v0.is_finite(), "--v0 must be a finite number");
    anyhow::ensure!(dt.is_finite() && dt > 0.0, "--dt must be a positive number of seconds");
    anyhow::ensure!(
        command_timeout.is_finite() && command_timeout > 0.0,
        "--command-timeout must be positive"
    );
    let session = transport::open(&zenoh, Role::Member).await?;
    let cfg = LockstepConfig::smoke(&team, ticks, Duration::from_secs_f64(command_timeout));
    let mut plant = PlaceholderPlant::new(robots, joints, v0, dt);
    let (_tx, rx) = tokio::sync::watch::channel(false);
    let report = lockstep::run(&session, &cfg, &mut plant, rx).await?;
    println!(
        "{} ticks, {:.3} s simulated in {:.3} s wall ({:.0} ticks/s), {} resends",
        report.ticks,
        report.sim_time,
        report.wall_time.as_secs_f64(),
        report.ticks as f64 / report.wall_time.as_secs_f64(),
        report.resends
    );
    protocol::transport::close(session).await?;
    Ok(())
}

/// Runs a scene file: settle, then run; prints both phases and the real-time factor.
async fn scene(path: &std::path::Path, zenoh: &ZenohArgs) -> Result<()> {
    let scene = sim_bridge::scene::Scene::load(path)?;
    let robots = sim_bridge::world::load_robots(&scene.world)?;
    let session = transport::open(zenoh, Role::Member).await?;
    let (_tx, rx) = tokio::sync::watch::channel(false);
    let r = sim_bridge::scene::run(&session, &scene, &robots, rx).await?;
    println!(
        "scene {}: settled {} ticks in {:.3} s wall, ran {} ticks ({:.3} s simulated) \
         in {:.3} s wall: real-time factor {:.3}",
        path.display(),
        r.settle.ticks,
        r.settle.wall_time.as_secs_f64(),
        r.run.ticks(),
        r.run.sim_time(),
        r.run.wall_time().as_secs_f64(),
        r.run.sim_time() / r.run.wall_time().as_secs_f64()
    );
    if let PhaseReport::RealTime(rt) = &r.run {
        println!(
            "real time: ticks without their torques by the deadline {:?}, overruns {}, \
             schedule slipped {:.3} s",
            rt.missed,
            rt.overruns,
            rt.slipped.as_secs_f64()
        );
    }
    protocol::transport::close(session).await?;
    Ok(())
}

async fn run(a: RunArgs) -> Result<()> {
    let (spec, world) = build_world(&a)?;
    let n = spec.robots.len();
    run_world(a, world, n).await
}

/// Checks the numbers of `run`'s arguments before anything is loaded.
fn check_run_args(a: &RunArgs) -> Result<()> {
    anyhow::ensure!(!a.robots.is_empty(), "--robots must name at least one robot");
    anyhow::ensure!(
        a.spacing.is_finite() && a.spacing > 0.0,
        "--spacing must be a positive number"
    );
    anyhow::ensure!(
        a.command_timeout.is_finite() && a.command_timeout > 0.0,
        "--command-timeout must be positive"
    );
    anyhow::ensure!(
        a.start_timeout.is_finite() && a.start_timeout > 0.0,
        "--start-timeout must be positive"
    );
    anyhow::ensure!(
        a.object_size.len() == 3 && a.object_position.len() == 3,
        "--object-size and --object-position take three numbers"
    );
    Ok(())
}

/// The object box of `run`'s arguments: the paper's cube moved, resized and reweighed.
fn object_spec(a: &RunArgs) -> sim_bridge::world::ObjectSpec {
    let mut o = sim_bridge::world::ObjectSpec::paper_cube([
        a.object_position[0],
        a.object_position[1],
        a.object_position[2],
    ]);
    o.size = [a.object_size[0], a.object_size[1], a.object_size[2]];
    o.mass = a.object_mass;
    o
}

fn build_world(a: &RunArgs) -> Result<(sim_bridge::world::WorldSpec, sim_bridge::world::World)> {
    use sim_bridge::world::{World, WorldSpec};
    check_run_args(a)?;
    let mut spec = WorldSpec::single("r1");
    spec.robots.clear();
    let n = a.robots.len();
    let description = a.description.clone().unwrap_or_else(robot_model::default_robot_path);
    let robot = std::sync::Arc::new(
        robot_model::Robot::load(&description)
            .map_err(|e| anyhow::anyhow!("{}: {e}", description.display()))?,
    );
    for (id, (xy, yaw)) in
        a.robots.iter().zip(robot_model::spatial::facing_ring([0.0, 0.0], a.spacing / 2.0, n))
    {
        spec.robots.push(sim_bridge::world::RobotPlacement::standing(
            id,
            description.clone(),
            &robot,
            xy,
            yaw,
        )?);
    }
    if !a.no_object {
        spec.object = Some(object_spec(a));
    }
    spec.control_hz = a.control_hz;
    spec.physics_hz = a.physics_hz;
    spec.seed = a.seed;
    spec.initial_joint_noise = a.joint_noise;
    spec.substeps()?;
    // Every robot runs the same description: loaded once, shared.
    let robots = vec![robot; n];
    let world = World::build(&spec, &robots)?;
    tracing::info!(
        robots = n,
        nq = world.model.ffi().nq,
        nv = world.model.ffi().nv,
        substeps = world.substeps,
        "world built and checked against the robots' models"
    );
    Ok((spec, world))
}

/// The lockstep settings of `run`'s arguments.
fn lockstep_config(a: &RunArgs) -> LockstepConfig {
    LockstepConfig {
        team: a.team.clone(),
        ticks: a.ticks,
        start_timeout: Duration::from_secs_f64(a.start_timeout),
        command_timeout: Duration::from_secs_f64(a.command_timeout),
        resend_every: Duration::from_millis(50),
        progress_every: (a.ticks / 10).max(1),
        wait_for_coordinator: false,
        coordinator_grace_ticks: sim_bridge::lockstep::DEFAULT_COORDINATOR_GRACE_TICKS,
        agent_loss: sim_bridge::lockstep::AgentLoss::Drives(a.drive_loss),
        drive_timeout: sim_bridge::lockstep::DEFAULT_DRIVE_TIMEOUT,
    }
}

/// Prints the run phase's report; returns its simulated time and wall time.
fn print_run_phase(run: PhaseReport) -> (f64, Duration) {
    match run {
        PhaseReport::RealTime(r) => {
            println!(
                "real time: {} ticks, missed torques per robot {:?}, {} overruns, \
                 schedule slipped {:.3} s",
                r.ticks,
                r.missed,
                r.overruns,
                r.slipped.as_secs_f64()
            );
            (r.sim_time, r.wall_time)
        }
        PhaseReport::Lockstep(r) => {
            println!(
                "lockstep: {} ticks, {} resends, {} rejected torques",
                r.ticks, r.resends, r.rejected_torques
            );
            (r.sim_time, r.wall_time)
        }
    }
}

/// Writes the recorded ground truth as CSV when both a file and a record are there.
fn write_ground_truth(
    path: Option<&std::path::PathBuf>,
    log: Option<&sim_bridge::ground_truth::GroundTruthLog>,
) -> Result<()> {
    if let (Some(path), Some(rec)) = (path, log) {
        let f = std::fs::File::create(path)
            .map_err(|e| anyhow::anyhow!("creating {}: {e}", path.display()))?;
        rec.write_csv(std::io::BufWriter::new(f))?;
        println!("ground truth: {} records in {}", rec.records.len(), path.display());
    }
    Ok(())
}

async fn run_world(a: RunArgs, world: sim_bridge::world::World, n: usize) -> Result<()> {
    let mut plant = sim_bridge::mujoco_plant::MujocoPlant::new(world)?;
    let session = transport::open(&a.zenoh, Role::Member).await?;
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let cfg = lockstep_config(&a);
    let mut extras = lockstep::LoopDuties {
        publish_ground_truth: true,
        perturbation_key: true,
        truth_log: a
            .ground_truth_csv
            .as_ref()
            .map(|_| sim_bridge::ground_truth::GroundTruthLog::new(a.record_every)),
        ..Default::default()
    };
    let pace = if a.realtime {
        Pace::RealTime { period: Duration::from_secs_f64(1.0 / a.control_hz) }
    } else {
        Pace::Lockstep
    };
    let (settle, run) = settle_then_run(
        &session,
        &mut plant,
        &cfg,
        a.settle_ticks,
        pace,
        &[],
        &mut extras,
        stop_rx.clone(),
    )
    .await?;
    if settle.ticks > 0 {
        println!(
            "settled for {} ticks ({:.3} s wall); the scenario clock started then",
            settle.ticks,
            settle.wall_time.as_secs_f64()
        );
    }
    let (sim_time, wall) = print_run_phase(run);
    println!(
        "{:.3} s simulated in {:.3} s wall: real-time factor {:.2} ({:.0} ticks/s, {} robots, \
         control {} Hz, physics {} Hz)",
        sim_time,
        wall.as_secs_f64(),
        sim_time / wall.as_secs_f64(),
        a.ticks as f64 / wall.as_secs_f64(),
        n,
        a.control_hz,
        a.physics_hz
    );
    if extras.perturbations_taken + extras.perturbations_refused > 0 {
        println!(
            "perturbations: {} taken, {} refused",
            extras.perturbations_taken, extras.perturbations_refused
        );
    }
    stop_tx.send(true).ok();
    write_ground_truth(a.ground_truth_csv.as_ref(), extras.truth_log.as_ref())?;
    protocol::transport::close(session).await?;
    Ok(())
}
