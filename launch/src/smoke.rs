//! The smoke run: every component, real messages, placeholder physics, through the one
//! launcher ([`crate::launcher`]): the joint-damping controller, placeholder agents and the
//! placeholder plant, so that the closed loop has an analytic answer.

use std::time::Duration;

use coordinator::joint_damping::JointDampingConfig;
use coordinator::ControllerSpec;
use robot_agent::drive_gains::DriveGainsMode;
use thiserror::Error;

use crate::launcher::{
    AgentArgs, AgentModel, BridgeArgs, BridgeOutcome, CoordinatorArgs, Launch, LaunchError,
    RunMode, SmokePlant,
};
use crate::run::LOCKSTEP_DEADLINE_TICKS;

/// The smoke run's agents wait as long as the bridge does for a command before they hold
/// their posture: a lockstep tick that is merely slow must not see safe-mode torques.
pub const SMOKE_COMMAND_DEADLINE: Duration = Duration::from_secs(5);
/// The smoke coordinator abandons a tick whose terms are incomplete after this long.
pub const SMOKE_TICK_DEADLINE: Duration = Duration::from_millis(500);

/// Errors of a smoke run.
#[derive(Debug, Error)]
pub enum SmokeError {
    #[error(transparent)]
    Launch(#[from] LaunchError),
}

/// What to run.
#[derive(Debug, Clone)]
pub struct SmokeConfig {
    pub team: String,
    pub robots: Vec<String>,
    pub joints: usize,
    pub ticks: u64,
    pub dt: f64,
    /// Joint damping of the placeholder controller.
    pub damping: f64,
    /// Initial joint velocity of the placeholder plant.
    pub v0: f64,
}

impl SmokeConfig {
    /// `team smoke`'s run: team `team`, robots `r1` to `rN` with `joints` joints each, `ticks`
    /// ticks of 1 ms, damping 2 s^-1 from 0.5 rad/s.
    pub fn of_team(robots: usize, joints: usize, ticks: u64) -> SmokeConfig {
        SmokeConfig {
            team: "team".into(),
            robots: (1..=robots).map(|i| format!("r{i}")).collect(),
            joints,
            ticks,
            dt: 0.001,
            damping: 2.0,
            v0: 0.5,
        }
    }

    /// The joint velocity the closed loop must end at: the plant integrates
    /// `v <- v - dt * d * v` once per tick (semi-implicit Euler of `qdd = -d qd`).
    pub fn expected_final_velocity(&self) -> f64 {
        self.v0 * (1.0 - self.dt * self.damping).powi(self.ticks as i32)
    }

    /// The components of the smoke run.
    pub fn launch(&self) -> (Launch, BridgeArgs) {
        let coordinator = CoordinatorArgs {
            team: self.team.clone(),
            tick_deadline: SMOKE_TICK_DEADLINE,
            reuse: None,
            expected: Vec::new(),
            controller: ControllerSpec::JointDamping(JointDampingConfig { damping: self.damping }),
            robot_hz: None,
            wait_for_references: None,
            solve_budget: None,
        };
        let agents = self
            .robots
            .iter()
            .map(|r| AgentArgs {
                team: self.team.clone(),
                id: r.clone(),
                model: AgentModel::Placeholder { joints: self.joints },
                command_deadline: SMOKE_COMMAND_DEADLINE,
                command_deadline_ticks: LOCKSTEP_DEADLINE_TICKS,
                drive_gains: DriveGainsMode::None,
                team_every: 1,
                team_delay: robot_agent::delay::TeamDelay::Ticks(0),
                answer_within: None,
            })
            .collect();
        let plant = SmokePlant {
            team: self.team.clone(),
            robots: self.robots.clone(),
            joints: self.joints,
            ticks: self.ticks,
            dt: self.dt,
            v0: self.v0,
        };
        (Launch { coordinator, agents }, BridgeArgs::Smoke(plant))
    }
}

/// What a finished smoke run in `mode` prints: an embedded run's lockstep figures and its
/// closed loop against the analytic answer, else that it finished.
pub fn summary(cfg: &SmokeConfig, mode: &RunMode, outcome: &BridgeOutcome) -> String {
    match outcome {
        BridgeOutcome::Smoke { report: r, final_velocities } => format!(
            "embedded smoke run: {} robots, {} ticks, {:.3} s simulated in {:.3} s wall \
             ({:.0} ticks/s, {:.0} us/tick)\n\
             closed loop: joint velocity {:.6} rad/s, analytic {:.6} rad/s",
            cfg.robots.len(),
            r.ticks,
            r.sim_time,
            r.wall_time.as_secs_f64(),
            r.ticks as f64 / r.wall_time.as_secs_f64(),
            1e6 * r.wall_time.as_secs_f64() / r.ticks.max(1) as f64,
            final_velocities[0],
            cfg.expected_final_velocity()
        ),
        _ => format!(
            "{} smoke run finished: {} robots, {} ticks",
            mode.name(),
            cfg.robots.len(),
            cfg.ticks
        ),
    }
}

/// Run the smoke run in `mode`; embedded runs report the plant's lockstep figures and final
/// joint velocities, distributed ones only that the sim-bridge process succeeded.
pub async fn run(cfg: &SmokeConfig, mode: &RunMode) -> Result<BridgeOutcome, SmokeError> {
    let (launch, bridge) = cfg.launch();
    let mut running = launch.start(mode).await?;
    let outcome = running.run_bridge(&bridge).await;
    running.finish().await?;
    Ok(outcome?)
}
