//! `robot-agent`: one robot of the team. A thin command-line front end; the logic lives in
//! the library.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Args, Parser, Subcommand};
use protocol::transport::{self, Role, ZenohArgs};
use robot_agent::agent::{self, AgentConfig, ModelDynamics, PlaceholderDynamics};
use robot_agent::inspect::{self, Attach, InspectArgs};
use robot_model::{default_robot_path, Robot};

#[derive(Parser)]
#[command(
    name = "robot-agent",
    version,
    about = "A robot's agent: model, dynamics terms, commands"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print a robot's model summary and dynamics terms at one state.
    Inspect(InspectCmd),
    /// Join the team and run the agent loop.
    Run(RunCmd),
}

#[derive(Args)]
struct RunCmd {
    /// Robot description (TOML beside its URDF); default: the project's legged manipulator.
    #[arg(long, value_name = "FILE.toml")]
    robot: Option<PathBuf>,
    /// Robot id (letters, digits, '_' and '-').
    #[arg(long)]
    id: String,
    /// Team id.
    #[arg(long, default_value = "team")]
    team: String,
    /// Without a valid command for this long the agent enters safe mode; commands stamped
    /// longer before the latest state are refused.
    #[arg(long, value_name = "MS", default_value_t = 25)]
    command_deadline_ms: u64,
    /// Without a valid command for this many state ticks the agent enters safe mode; commands
    /// more ticks behind the latest state are refused (0: neither). The first command may take
    /// up to 2 s from the first state.
    #[arg(long, value_name = "TICKS", default_value_t = 5)]
    command_deadline_ticks: u64,
    /// Hold posture when the coordinator's liveliness token has been gone this long (unless
    /// the command deadline comes first); a link that drops and comes back within it changes
    /// nothing. 0: hold at once.
    #[arg(
        long,
        value_name = "MS",
        default_value_t = robot_agent::core::COORDINATOR_GRACE.as_millis() as u64
    )]
    coordinator_grace_ms: u64,
    /// A swing foot counts as landed once its measured normal force reaches this, N (default:
    /// `contact_switch::SwitchConfig`'s, 20 N).
    #[arg(long, value_name = "N")]
    touchdown_force: Option<f64>,
    /// Gains sent to the drives with each command: `none` (the torque, the paper's loop) or
    /// `inertia` (per joint from its inertia at the first state: a critically damped 5 Hz
    /// loop; see `robot_agent::drive_gains`).
    #[arg(long, value_name = "GAINS", default_value = "none")]
    drive_gains: robot_agent::drive_gains::DriveGainsMode,
    /// The team answers every N-th state tick (the team loop at the robot's rate divided by N);
    /// the agent answers the states between alone, with the last command's torque and, with
    /// drive gains, the reference carried to each state.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 1,
        value_parser = clap::value_parser!(u64).range(1..)
    )]
    team_every: u64,
    /// The team's command for the state of tick k applies at tick k + N (the team has N robot
    /// periods to answer, 0 to 8); the states before the first command can apply get gravity
    /// compensation. `auto`: from 0, raised a tick at a time (up to 4, or N with `auto:N`)
    /// while commands come after the states they apply at, lowered when they have long come in
    /// time a tick sooner (robot_agent::delay).
    #[arg(long, value_name = "N|auto|auto:N", default_value = "0")]
    team_delay: robot_agent::delay::TeamDelay,
    /// The robot's drives take the answer to a state within this many microseconds of it (a
    /// real-time robot; unset: they wait for it). With `--team-delay auto`, a command at delay
    /// 0 that comes later counts as late.
    #[arg(long, value_name = "US", value_parser = clap::value_parser!(u64).range(1..))]
    answer_within_us: Option<u64>,
    /// Smoke run only: placeholder dynamics (unit mass matrix, no frames, no limits) of this
    /// many joints instead of a robot model.
    #[arg(long, value_name = "N", conflicts_with = "robot", hide = true)]
    placeholder_joints: Option<usize>,
    #[command(flatten)]
    zenoh: ZenohArgs,
}

fn run_agent(cmd: RunCmd) -> anyhow::Result<String> {
    // Bad input is refused before anything starts: one error line, exit status 2.
    protocol::validate_id("robot", &cmd.id)?;
    protocol::validate_id("team", &cmd.team)?;
    anyhow::ensure!(cmd.command_deadline_ms > 0, "--command-deadline-ms must be positive");
    anyhow::ensure!(
        cmd.touchdown_force.is_none_or(|f| f.is_finite() && f > 0.0),
        "--touchdown-force must be a positive force (N)"
    );
    enum Source {
        Model(Box<ModelDynamics>),
        Placeholder(PlaceholderDynamics),
    }
    let source = match cmd.placeholder_joints {
        Some(0) => anyhow::bail!("--placeholder-joints must be positive"),
        Some(n) => Source::Placeholder(PlaceholderDynamics::floating(n)),
        None => {
            let path = cmd.robot.clone().unwrap_or_else(default_robot_path);
            Source::Model(Box::new(ModelDynamics::new(Robot::load(&path)?)?))
        }
    };
    protocol::logging::init(protocol::logging::Verbosity::Info);
    let mut cfg = AgentConfig::new(&cmd.team, &cmd.id)
        .with_deadline_time(Duration::from_millis(cmd.command_deadline_ms))
        .with_deadline_ticks(cmd.command_deadline_ticks);
    cfg.coordinator_grace = Duration::from_millis(cmd.coordinator_grace_ms);
    cfg.drive_gains = cmd.drive_gains;
    cfg.team_every = cmd.team_every;
    cfg.team_delay = cmd.team_delay;
    cfg.answer_within = cmd.answer_within_us.map(Duration::from_micros);
    if let Some(f) = cmd.touchdown_force {
        cfg.contacts.touchdown_force = f;
    }
    let rt = tokio::runtime::Runtime::new()?;
    let session = rt.block_on(transport::open(&cmd.zenoh, Role::Member))?;
    let agent = match source {
        Source::Model(s) => agent::spawn(&session, cfg, *s)?,
        Source::Placeholder(s) => agent::spawn(&session, cfg, s)?,
    };
    // Until Ctrl-C, or until the loop ends on its own (a hardware error, the session gone).
    rt.block_on(async {
        let mut poll = tokio::time::interval(Duration::from_millis(100));
        loop {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => break,
                _ = poll.tick() => if agent.is_finished() { break },
            }
        }
    });
    agent.join()?;
    rt.block_on(protocol::transport::close(session))?;
    Ok(String::new())
}

#[derive(Args)]
struct InspectCmd {
    /// URDF of the robot.
    #[arg(long)]
    urdf: PathBuf,
    /// Give the root link a 6-DoF floating joint.
    #[arg(long)]
    floating_base: bool,
    /// URDF to attach (e.g. an arm).
    #[arg(long, requires = "at")]
    attach: Option<PathBuf>,
    /// Frame (link) of the first robot to attach to.
    #[arg(long, requires = "attach")]
    at: Option<String>,
    /// Pose of the attached root in that frame: x,y,z,roll,pitch,yaw.
    #[arg(long, requires = "attach", allow_hyphen_values = true, default_value = "0,0,0,0,0,0")]
    pose: String,
    /// Prefix for the attached robot's joint and frame names.
    #[arg(long, requires = "attach", default_value = "")]
    prefix: String,
    /// State file {"q": [...], "v": [...]}; default neutral configuration, zero velocity.
    #[arg(long)]
    state: Option<PathBuf>,
    /// Frame to report (repeatable).
    #[arg(long = "frame")]
    frames: Vec<String>,
    /// Print the full report as JSON.
    #[arg(long)]
    json: bool,
}

fn run_inspect(cmd: InspectCmd) -> anyhow::Result<String> {
    let attach = match (cmd.attach, cmd.at) {
        (Some(urdf), Some(at)) => {
            Some(Attach { urdf, at, pose: inspect::parse_pose(&cmd.pose)?, prefix: cmd.prefix })
        }
        _ => None,
    };
    let args = InspectArgs {
        urdf: cmd.urdf,
        floating_base: cmd.floating_base,
        attach,
        state: cmd.state,
        frames: cmd.frames,
    };
    let report = inspect::inspect(&args)?;
    Ok(if cmd.json {
        serde_json::to_string_pretty(&report)? + "\n"
    } else {
        inspect::summary(&report)
    })
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if !e.use_stderr() => {
            let _ = e.print(); // --help, --version
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            // one line: clap's message up to its usage section, which starts "error: ..."
            let msg = e.to_string();
            let lines: Vec<&str> = msg
                .lines()
                .take_while(|l| !l.starts_with("Usage:"))
                .map(str::trim)
                .filter(|l| !l.is_empty())
                .collect();
            eprintln!("{}", lines.join(" "));
            return ExitCode::from(2);
        }
    };
    let result = match cli.command {
        Command::Inspect(cmd) => run_inspect(cmd),
        Command::Run(cmd) => run_agent(cmd),
    };
    match result {
        Ok(out) => {
            print!("{out}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {}", e.to_string().replace('\n', " "));
            ExitCode::from(2)
        }
    }
}
