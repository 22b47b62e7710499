//! `robot-agent`: one robot of the team.

use anyhow::Result;
use clap::{Parser, Subcommand};
use protocol::transport::{self, Role, ZenohArgs};
use robot_agent::agent::{self, AgentConfig, PlaceholderDynamics};

#[derive(Parser)]
#[command(version, about = "A robot of the team: dynamics terms out, checked torques in")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Join the team and run the agent loop.
    Run {
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
    },
}

#[tokio::main]
async fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Run { id, team, joints, zenoh } => {
            let session = transport::open(&zenoh, Role::Member).await?;
            let cfg = AgentConfig { team, robot: id, joints, floating_base: true };
            let source = PlaceholderDynamics { joints, nv: cfg.nv() };
            let (tx, rx) = tokio::sync::watch::channel(false);
            tokio::spawn(async move {
                let _ = tokio::signal::ctrl_c().await;
                let _ = tx.send(true);
            });
            agent::run(&session, cfg, source, rx).await?;
            session.close().await.map_err(|e| anyhow::anyhow!("closing the session: {e}"))?;
        }
    }
    Ok(())
}
