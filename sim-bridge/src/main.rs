//! `sim-bridge`: the robots' state source and torque sink in simulation.

use std::time::Duration;

use anyhow::Result;
use clap::{Parser, Subcommand};
use protocol::transport::{self, Role, ZenohArgs};
use sim_bridge::lockstep::{self, LockstepConfig};
use sim_bridge::plant::PlaceholderPlant;

#[derive(Parser)]
#[command(version, about = "Simulated robots for the team, in lockstep over Zenoh")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Smoke run: placeholder joint dynamics for the given robots, in lockstep.
    Smoke {
        /// Robot ids, comma separated.
        #[arg(long, value_delimiter = ',', default_value = "r1,r2")]
        robots: Vec<String>,
        #[arg(long, default_value = "team")]
        team: String,
        #[arg(long, default_value_t = 18)]
        joints: usize,
        #[arg(long, default_value_t = 1000)]
        ticks: u64,
        /// Control period, s.
        #[arg(long, default_value_t = 0.001)]
        dt: f64,
        /// Seconds a tick may wait for torques before the run fails naming the robot.
        #[arg(long, default_value_t = 2.0)]
        command_timeout: f64,
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
        Command::Smoke { robots, team, joints, ticks, dt, command_timeout, zenoh } => {
            anyhow::ensure!(dt.is_finite() && dt > 0.0, "--dt must be a positive number of seconds");
            anyhow::ensure!(command_timeout.is_finite() && command_timeout > 0.0, "--command-timeout must be positive");
            let session = transport::open(&zenoh, Role::Member).await?;
            let cfg = LockstepConfig {
                team,
                ticks,
                start_timeout: Duration::from_secs(20),
                command_timeout: Duration::from_secs_f64(command_timeout),
                resend_every: Duration::from_millis(50),
                progress_every: (ticks / 10).max(1),
            };
            let mut plant = PlaceholderPlant::new(robots, joints, 0.5, dt);
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
            session.close().await.map_err(|e| anyhow::anyhow!("closing the session: {e}"))?;
        }
    }
    Ok(())
}
