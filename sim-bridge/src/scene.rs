//! A scenario's run as the bridge sees it, in one file: the world (robots already placed,
//! hands already on the object), the timed pushes, how long to settle and how long to run.
//! The runner (`team run`) writes it into the report folder; `sim-bridge run --scene FILE`
//! reads it when the bridge runs as its own process, and the embedded run calls [`run`] with
//! the same value, so both modes simulate the same thing.
//!
//! The robots come loaded (`robot_model::Robot`, in the world's order): the embedded run
//! passes the runner's, the `sim-bridge scene` process loads them from the scene's
//! description paths ([`crate::world::load_robots`]).
//!
//! The run: build the world, settle `settle_ticks` lockstep ticks under the controller (the
//! scenario clock then restarts at 0, tick numbers continue), add the pushes (their `start`
//! is on the scenario clock), run `ticks` ticks, lockstep or against the wall clock
//! ([`Scene::realtime`]). Ground truth is published on
//! `team/{team}/ground-truth` after every tick of both phases (the runner records it and
//! drives its progress bar from it).

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use robot_model::Robot;
use serde::{Deserialize, Serialize};
use tokio::sync::watch;
use zenoh::Session;

use crate::lockstep::{self, BridgeError, BridgeIo, LockstepConfig, LoopDuties};
use crate::mujoco_plant::MujocoPlant;
use crate::perturbation::Perturbation;
use crate::plant::DriveLoss;
use crate::realtime::{RealtimeReport, Start};
use crate::world::{World, WorldError, WorldSpec};

/// Longest wait a scene may ask for, s (a day): every wait has a bound.
pub const MAX_TIMEOUT_S: f64 = 86_400.0;

/// Everything the bridge needs for a scenario run.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    pub team: String,
    pub world: WorldSpec,
    /// Pushes, `start` in seconds on the scenario clock.
    #[serde(default)]
    pub perturbations: Vec<Perturbation>,
    pub settle_ticks: u64,
    pub ticks: u64,
    /// Seconds a lockstep tick may wait for torques before the run fails naming the robot.
    pub command_timeout: f64,
    /// Seconds to wait for every robot to join.
    pub start_timeout: f64,
    /// Run the scenario phase against the wall clock, one control period per tick
    /// ([`Pace::RealTime`]: a robot whose torques are late keeps its last ones); settling stays
    /// lockstep.
    #[serde(default)]
    pub realtime: bool,
    /// What a robot's drives do when its agent leaves, or (real time) when its torques stop
    /// for the drive timeout.
    #[serde(default)]
    pub drive_loss: DriveLoss,
}

/// What a scene run did.
#[derive(Debug, Clone)]
pub struct SceneReport {
    pub settle: lockstep::LockstepReport,
    pub run: PhaseReport,
    pub perturbations_applied_steps: u64,
}

impl Scene {
    /// Read a scene file (TOML).
    pub fn load(path: &Path) -> Result<Scene, WorldError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| WorldError::Invalid(format!("reading scene {}: {e}", path.display())))?;
        let s: Scene = toml::from_str(&text)
            .map_err(|e| WorldError::Invalid(format!("scene {}: {e}", path.display())))?;
        s.check()?;
        Ok(s)
    }

    /// Write it as TOML.
    pub fn save(&self, path: &Path) -> Result<(), WorldError> {
        let text = toml::to_string(self).map_err(|e| WorldError::Invalid(format!("scene: {e}")))?;
        std::fs::write(path, text)
            .map_err(|e| WorldError::Invalid(format!("writing scene {}: {e}", path.display())))
    }

    fn check(&self) -> Result<(), WorldError> {
        protocol::validate_id("team", &self.team)
            .map_err(|e| WorldError::Invalid(format!("scene team: {e}")))?;
        for (what, x) in
            [("command_timeout", self.command_timeout), ("start_timeout", self.start_timeout)]
        {
            if !(x.is_finite() && x > 0.0 && x <= MAX_TIMEOUT_S) {
                return Err(WorldError::Invalid(format!(
                    "scene {what} = {x} must be positive and at most {MAX_TIMEOUT_S} s"
                )));
            }
        }
        if self.ticks == 0 {
            return Err(WorldError::Invalid("scene ticks must be positive".into()));
        }
        self.world.substeps()?;
        Ok(())
    }

    /// The run's ticks: settling, then the scenario, at the world's control rate
    /// (`protocol::clock`: tick numbers continue, the scenario clock starts after settling).
    pub fn clock(&self) -> protocol::RunClock {
        protocol::RunClock {
            control_hz: self.world.control_hz,
            settle_ticks: self.settle_ticks,
            ticks: self.ticks,
        }
    }

    /// How the scenario phase is paced: [`Pace::RealTime`] at the control period if
    /// [`Scene::realtime`], else lockstep.
    pub fn pace(&self) -> Pace {
        if self.realtime {
            Pace::RealTime { period: Duration::from_secs_f64(1.0 / self.world.control_hz) }
        } else {
            Pace::Lockstep
        }
    }

    fn lockstep(&self, ticks: u64) -> LockstepConfig {
        LockstepConfig {
            team: self.team.clone(),
            ticks,
            start_timeout: Duration::from_secs_f64(self.start_timeout),
            command_timeout: Duration::from_secs_f64(self.command_timeout),
            resend_every: Duration::from_millis(50),
            progress_every: 0,
            wait_for_coordinator: true,
            coordinator_grace_ticks: crate::lockstep::DEFAULT_COORDINATOR_GRACE_TICKS,
            agent_loss: crate::lockstep::AgentLoss::Drives(self.drive_loss),
            drive_timeout: crate::lockstep::DEFAULT_DRIVE_TIMEOUT,
        }
    }
}

/// Errors of a scene run.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error(transparent)]
    World(#[from] WorldError),
    #[error(transparent)]
    Bridge(#[from] BridgeError),
}

/// Build the world from `robots` (the scene's, in its order) and run the scene in lockstep
/// (see the module docs).
pub async fn run(
    session: &Session,
    scene: &Scene,
    robots: &[Arc<Robot>],
    stop: watch::Receiver<bool>,
) -> Result<SceneReport, SceneError> {
    scene.check()?;
    let world = World::build(&scene.world, robots)?;
    let mut plant = MujocoPlant::new(world)?;
    let mut extras =
        LoopDuties { publish_ground_truth: true, perturbation_key: true, ..Default::default() };
    let cfg = scene.lockstep(scene.ticks);
    let (settle, run) = settle_then_run(
        session,
        &mut plant,
        &cfg,
        scene.settle_ticks,
        scene.pace(),
        &scene.perturbations,
        &mut extras,
        stop,
    )
    .await?;
    Ok(SceneReport { settle, run, perturbations_applied_steps: plant.perturbations.applied_steps })
}

/// How the scenario phase is paced; settling is always lockstep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// A tick advances when every robot's torques for it have arrived.
    Lockstep,
    /// The wall clock paces the ticks at `period`; a missing torque holds the last one.
    RealTime { period: Duration },
}

/// What the scenario phase did.
#[derive(Debug, Clone, PartialEq)]
pub enum PhaseReport {
    Lockstep(lockstep::LockstepReport),
    RealTime(RealtimeReport),
}

impl PhaseReport {
    pub fn ticks(&self) -> u64 {
        match self {
            PhaseReport::Lockstep(r) => r.ticks,
            PhaseReport::RealTime(r) => r.ticks,
        }
    }

    /// Simulated time at the end, s.
    pub fn sim_time(&self) -> f64 {
        match self {
            PhaseReport::Lockstep(r) => r.sim_time,
            PhaseReport::RealTime(r) => r.sim_time,
        }
    }

    pub fn wall_time(&self) -> Duration {
        match self {
            PhaseReport::Lockstep(r) => r.wall_time,
            PhaseReport::RealTime(r) => r.wall_time,
        }
    }
}

/// The two phases of a run (`protocol::clock`): `settle_ticks` lockstep ticks under the
/// controller, then the physics clock restarts (scenario time 0), the timed `pushes` are added
/// (their `start` is on the scenario clock), and `cfg.ticks` ticks run at `pace`; tick numbers
/// continue across. `extras` serve both phases (ground truth is published while settling
/// too); its ground-truth log keeps the scenario phase only.
///
/// Both phases run on one [`BridgeIo`], opened (and the team waited for) once: the scenario's
/// first tick follows the last settling step at once. A real-time phase after no settle waits
/// at its first tick for every robot's torques ([`Start::WaitForFirstTorques`]).
#[allow(clippy::too_many_arguments)]
pub async fn settle_then_run(
    session: &Session,
    plant: &mut MujocoPlant,
    cfg: &LockstepConfig,
    settle_ticks: u64,
    pace: Pace,
    pushes: &[Perturbation],
    extras: &mut LoopDuties,
    stop: watch::Receiver<bool>,
) -> Result<(lockstep::LockstepReport, PhaseReport), SceneError> {
    let robots = crate::plant::Plant::robots(plant).to_vec();
    let mut io = BridgeIo::open(session, cfg, &robots, extras, &stop).await?;
    let settle = if settle_ticks > 0 {
        let truth_log = extras.truth_log.take();
        let settle_cfg = LockstepConfig { ticks: settle_ticks, progress_every: 0, ..cfg.clone() };
        let r = lockstep::run_on(session, &mut io, &settle_cfg, plant, extras, stop.clone()).await;
        extras.truth_log = truth_log;
        plant.restart_clock();
        r?
    } else {
        lockstep::LockstepReport {
            ticks: 0,
            sim_time: 0.0,
            wall_time: Duration::ZERO,
            resends: 0,
            rejected_torques: 0,
        }
    };
    for p in pushes {
        plant.perturbations.add(&plant.world, p.clone())?;
    }
    extras.first_tick += settle_ticks;
    io.drain_torques();
    let run = match pace {
        Pace::Lockstep => PhaseReport::Lockstep(
            lockstep::run_on(session, &mut io, cfg, plant, extras, stop).await?,
        ),
        Pace::RealTime { period } => {
            let start = if settle_ticks > 0 { Start::Driven } else { Start::WaitForFirstTorques };
            PhaseReport::RealTime(
                crate::realtime::run_on(&mut io, cfg, period, plant, extras, start, stop).await?,
            )
        }
    };
    Ok((settle, run))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::WorldSpec;

    fn scene() -> Scene {
        Scene {
            team: "team".into(),
            world: WorldSpec::paper_pair(),
            perturbations: Vec::new(),
            settle_ticks: 10,
            ticks: 20,
            command_timeout: 1.0,
            start_timeout: 1.0,
            realtime: false,
            drive_loss: DriveLoss::Freeze,
        }
    }

    #[test]
    fn a_scene_file_round_trips_and_broken_ones_say_why() {
        let dir = std::env::temp_dir().join(format!("scene-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("scene.toml");
        let mut s = scene();
        s.perturbations.push(Perturbation {
            target: protocol::PerturbationTarget::Object,
            wrench: [0.0, 0.0, 10.0, 0.0, 0.0, 0.0],
            start: 1.0,
            duration: 0.3,
        });
        s.save(&path).unwrap();
        let back = Scene::load(&path).unwrap();
        assert_eq!(back.perturbations, s.perturbations);
        assert_eq!(back.world.robots.len(), 2);
        assert_eq!(back.world.robots[1].base_position, s.world.robots[1].base_position);
        assert_eq!(back.world.object, s.world.object);
        assert_eq!((back.settle_ticks, back.ticks), (10, 20));
        // Broken files: each error names what is wrong.
        let text = std::fs::read_to_string(&path).unwrap();
        for (bad, says) in [
            (text.replace("ticks = 20", "ticks = 0"), "ticks"),
            (text.replace("command_timeout = 1.0", "command_timeout = -1.0"), "command_timeout"),
            (text.replace("team = \"team\"", "team = \"a/b\""), "team"),
            (text.replacen("control_hz = 1000.0", "control_hz = 0.0", 1), "rates"),
            (text.replace("settle_ticks = 10", "settle_ticks = 10\nsurprise = 1"), "surprise"),
            ("not toml [".to_string(), "scene"),
        ] {
            std::fs::write(&path, &bad).unwrap();
            let e = Scene::load(&path).unwrap_err().to_string();
            assert!(e.contains(says), "{says}: {e}");
        }
        assert!(Scene::load(&dir.join("missing.toml"))
            .unwrap_err()
            .to_string()
            .contains("missing.toml"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
