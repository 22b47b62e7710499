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
        /// Minimum normal force of every stance foot (paper controller), N.
        #[arg(long, default_value_t = 5.0)]
        min_foot_force: f64,
        /// Minimum normal force of every hand in grasp, the least squeeze (paper controller), N.
        #[arg(long, default_value_t = 30.0)]
        min_hand_force: f64,
        /// Mass of the carried object (paper controller), kg.
        #[arg(long, default_value_t = 1.0)]
        object_mass: f64,
        /// Paper controller configuration (TOML: gains, object, minimum forces, see
        /// `ControllerConfig`); replaces --min-foot-force, --min-hand-force and --object-mass.
        #[arg(long)]
        controller_config: Option<std::path::PathBuf>,
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
        Command::Run { team, tick_deadline_ms, controller, damping, min_foot_force, min_hand_force, object_mass, controller_config, zenoh } => {
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
                    anyhow::ensure!(min_foot_force.is_finite() && min_foot_force >= 0.0, "--min-foot-force must be >= 0");
                    anyhow::ensure!(min_hand_force.is_finite() && min_hand_force >= 0.0, "--min-hand-force must be >= 0");
                    anyhow::ensure!(object_mass.is_finite() && object_mass >= 0.0, "--object-mass must be >= 0");
                    let pc = match &controller_config {
                        Some(path) => {
                            let text = std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("reading {}: {e}", path.display()))?;
                            ControllerConfig::from_toml(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?
                        }
                        None => {
                            let mut pc = ControllerConfig { f_min_foot: min_foot_force, f_min_hand: min_hand_force, ..ControllerConfig::default() };
                            pc.object_inertia *= if pc.object_mass > 0.0 { object_mass / pc.object_mass } else { 0.0 };
                            pc.object_mass = object_mass;
                            pc
                        }
                    };
                    service::run(&session, cfg, PaperController::new(pc), rx).await?;
                }
            }
            session.close().await.map_err(|e| anyhow::anyhow!("closing the session: {e}"))?;
        }
    }
    Ok(())
}
