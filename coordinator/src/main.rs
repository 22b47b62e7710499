//! `coordinator`: solves the team problem every tick.

use std::time::Duration;

use anyhow::Result;
use clap::{Parser, Subcommand};
use coordinator::service::{self, CoordinatorConfig};
use coordinator::{ControllerConfig, JointDamping, PaperController};
use protocol::transport::{self, Role, ZenohArgs};

#[derive(Parser)]
#[command(version, about = "The team controller: gathers dynamics terms, sends torque slices")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum ControllerKind {
    Smoke,
    Paper,
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
        /// Team controller: `smoke` (joint damping, the smoke run) or `paper` (PIDC with the
        /// contact-force QP; runs once every member's description is known).
        #[arg(long, value_enum, default_value_t = ControllerKind::Smoke)]
        controller: ControllerKind,
        /// Joint damping of the smoke controller, N·m·s/rad.
        #[arg(long, default_value_t = 2.0)]
        damping: f64,
        /// Minimum normal force of every contact (paper controller), N.
        #[arg(long, default_value_t = 5.0)]
        min_normal_force: f64,
        /// Mass of the carried object (paper controller), kg.
        #[arg(long, default_value_t = 1.0)]
        object_mass: f64,
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
        Command::Run { team, tick_deadline_ms, controller, damping, min_normal_force, object_mass, zenoh } => {
            anyhow::ensure!(damping.is_finite() && damping >= 0.0, "--damping must be a finite non-negative number");
            let session = transport::open(&zenoh, Role::Hub).await?;
            let cfg = CoordinatorConfig { team, tick_deadline: Duration::from_millis(tick_deadline_ms) };
            let (tx, rx) = tokio::sync::watch::channel(false);
            tokio::spawn(async move {
                let _ = tokio::signal::ctrl_c().await;
                let _ = tx.send(true);
            });
            match controller {
                ControllerKind::Smoke => {
                    service::run(&session, cfg, JointDamping { damping }, rx).await?;
                }
                ControllerKind::Paper => {
                    anyhow::ensure!(min_normal_force.is_finite() && min_normal_force >= 0.0, "--min-normal-force must be >= 0");
                    anyhow::ensure!(object_mass.is_finite() && object_mass >= 0.0, "--object-mass must be >= 0");
                    let mut pc = ControllerConfig { f_min: min_normal_force, ..ControllerConfig::default() };
                    pc.object_inertia *= if pc.object_mass > 0.0 { object_mass / pc.object_mass } else { 0.0 };
                    pc.object_mass = object_mass;
                    service::run(&session, cfg, PaperController::new(pc), rx).await?;
                }
            }
            session.close().await.map_err(|e| anyhow::anyhow!("closing the session: {e}"))?;
        }
    }
    Ok(())
}
