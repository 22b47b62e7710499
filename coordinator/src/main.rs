//! `coordinator`: solves the team problem every tick.

use std::time::Duration;

use anyhow::Result;
use clap::{Parser, Subcommand};
use coordinator::service::{self, CoordinatorConfig};
use coordinator::JointDamping;
use protocol::transport::{self, Role, ZenohArgs};

#[derive(Parser)]
#[command(version, about = "The team controller: gathers dynamics terms, sends torque slices")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the coordinator service.
    Run {
        /// Team id.
        #[arg(long, default_value = "team")]
        team: String,
        /// How long a tick may wait for every member's dynamics terms, ms.
        #[arg(long, default_value_t = 200)]
        tick_deadline_ms: u64,
        /// Joint damping of the smoke controller, N·m·s/rad.
        #[arg(long, default_value_t = 2.0)]
        damping: f64,
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
        Command::Run { team, tick_deadline_ms, damping, zenoh } => {
            anyhow::ensure!(damping.is_finite() && damping >= 0.0, "--damping must be a finite non-negative number");
            let session = transport::open(&zenoh, Role::Hub).await?;
            let cfg = CoordinatorConfig { team, tick_deadline: Duration::from_millis(tick_deadline_ms) };
            let (tx, rx) = tokio::sync::watch::channel(false);
            tokio::spawn(async move {
                let _ = tokio::signal::ctrl_c().await;
                let _ = tx.send(true);
            });
            service::run(&session, cfg, JointDamping { damping }, rx).await?;
            session.close().await.map_err(|e| anyhow::anyhow!("closing the session: {e}"))?;
        }
    }
    Ok(())
}
