//! `robot-agent`: one robot of the team. A thin command-line front end; the logic lives in
//! the library.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use protocol::transport::{self, Role, ZenohArgs};
use robot_agent::agent::{self, AgentConfig, PlaceholderDynamics};
use robot_agent::inspect::{self, Attach, InspectArgs};

#[derive(Parser)]
#[command(name = "robot-agent", version, about = "A robot's agent: model, dynamics terms, commands")]
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
    /// Robot id (letters, digits, '_' and '-').
    #[arg(long)]
    id: String,
    /// Team id.
    #[arg(long, default_value = "team")]
    team: String,
    /// Actuated joints (smoke run: placeholder dynamics of this size).
    #[arg(long, default_value_t = 18)]
    joints: usize,
    #[command(flatten)]
    zenoh: ZenohArgs,
}

fn run_agent(cmd: RunCmd) -> anyhow::Result<String> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .init();
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async move {
        let session = transport::open(&cmd.zenoh, Role::Member).await?;
        let cfg = AgentConfig { team: cmd.team, robot: cmd.id, joints: cmd.joints, floating_base: true };
        let source = PlaceholderDynamics { joints: cmd.joints, nv: cfg.nv() };
        let (tx, rx) = tokio::sync::watch::channel(false);
        tokio::spawn(async move {
            let _ = tokio::signal::ctrl_c().await;
            let _ = tx.send(true);
        });
        agent::run(&session, cfg, source, rx).await?;
        session.close().await.map_err(|e| anyhow::anyhow!("closing the session: {e}"))?;
        Ok(String::new())
    })
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
        (Some(urdf), Some(at)) => Some(Attach { urdf, at, pose: inspect::parse_pose(&cmd.pose)?, prefix: cmd.prefix }),
        _ => None,
    };
    let args = InspectArgs { urdf: cmd.urdf, floating_base: cmd.floating_base, attach, state: cmd.state, frames: cmd.frames };
    let report = inspect::inspect(&args)?;
    Ok(if cmd.json { serde_json::to_string_pretty(&report)? + "\n" } else { inspect::summary(&report) })
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
            let lines: Vec<&str> = msg.lines().take_while(|l| !l.starts_with("Usage:")).map(str::trim).filter(|l| !l.is_empty()).collect();
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
