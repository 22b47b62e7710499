//! The synchronous hardware loop with the in-memory mock robot (three unit-inertia joints at
//! 1 kHz) against a coordinator, as a lab's robot would run:
//!
//! ```sh
//! coordinator run --controller joint-damping --damping 5   # listens on tcp/127.0.0.1:7447
//! cargo run --release -p robot-agent --example mock_robot  # Ctrl-C stops it
//! ```
//!
//! It takes the agent's `--team`, `--id` and Zenoh flags (`--connect tcp/HOST:PORT`, ...).
//!
//! The mock's joint velocities decay as `(1 - dt d)^k`; stop the coordinator and the agent
//! enters safe mode within its deadline. A lab's robot replaces `MockHardware` with its own
//! `RobotHardware` and `PlaceholderDynamics` with its model (robot-agent README, "Plugging in
//! a robot").

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use clap::Parser;
use protocol::transport::{self, Qos, Role, ZenohArgs};
use robot_agent::core::{AgentConfig, AgentCore};
use robot_agent::dynamics_source::PlaceholderDynamics;
use robot_agent::hardware::{driver, DriverConfig, MockConfig, MockHardware, ZenohLink};

#[derive(Parser)]
struct Args {
    #[arg(long, default_value = "team")]
    team: String,
    #[arg(long, default_value = "r1")]
    id: String,
    #[command(flatten)]
    zenoh: ZenohArgs,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    protocol::logging::init(protocol::logging::Verbosity::Info);
    let joints = 3;
    let rate = DriverConfig::new(Duration::from_millis(1));
    let cfg = AgentConfig::new(&args.team, &args.id);
    let mut core = AgentCore::new(&cfg, PlaceholderDynamics { joints, nv: joints })?;
    let mut robot = MockHardware::new(MockConfig::new(joints, 0.5, rate.period.as_secs_f64()));

    let rt = tokio::runtime::Runtime::new()?;
    let session = rt.block_on(transport::open(&args.zenoh, Role::Member))?;
    let stop = Arc::new(AtomicBool::new(false));
    let on_signal = stop.clone();
    rt.spawn(async move {
        let _ = tokio::signal::ctrl_c().await;
        on_signal.store(true, Ordering::Release);
    });
    // A real robot's loop never waits on the network: what cannot go out at once is dropped.
    let mut link = ZenohLink::declare(&session, &cfg.team, &cfg.robot, Qos::NeverWait)?;
    let report = driver::run(&mut core, &mut robot, &mut link, &rate, &stop)?;
    println!("{report:?}\nfinal joint velocities {:?}", robot.velocities());
    Ok(())
}
