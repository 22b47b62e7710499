//! `team`: the main job. Runs the whole team in simulation.

use anyhow::Result;
use clap::{Parser, Subcommand};
use team_runner::smoke::{self, SmokeConfig};

#[derive(Parser)]
#[command(version, about = "Run the team of legged manipulators in simulation")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Smoke run of the whole stack: sim-bridge, agents and coordinator exchange real
    /// messages over Zenoh for N ticks (placeholder physics and controller).
    Smoke {
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
    },
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Smoke { robots, ticks, joints, distributed } => {
            anyhow::ensure!((1..=64).contains(&robots), "--robots must be between 1 and 64");
            anyhow::ensure!(joints > 0, "--joints must be positive");
            let cfg = SmokeConfig {
                team: "team".into(),
                robots: (1..=robots).map(|i| format!("r{i}")).collect(),
                joints,
                ticks,
                dt: 0.001,
                damping: 2.0,
                v0: 0.5,
            };
            if distributed {
                smoke::run_distributed(&cfg)?;
                println!("distributed smoke run finished: {} robots, {ticks} ticks", cfg.robots.len());
            } else {
                let rt = tokio::runtime::Runtime::new()?;
                let out = rt.block_on(smoke::run_embedded(&cfg))?;
                let r = &out.report;
                println!(
                    "embedded smoke run: {} robots, {} ticks, {:.3} s simulated in {:.3} s wall ({:.0} ticks/s, {:.0} us/tick)",
                    cfg.robots.len(),
                    r.ticks,
                    r.sim_time,
                    r.wall_time.as_secs_f64(),
                    r.ticks as f64 / r.wall_time.as_secs_f64(),
                    1e6 * r.wall_time.as_secs_f64() / r.ticks.max(1) as f64
                );
                println!(
                    "closed loop: joint velocity {:.6} rad/s, analytic {:.6} rad/s",
                    out.final_velocities[0],
                    cfg.expected_final_velocity()
                );
            }
        }
    }
    Ok(())
}
