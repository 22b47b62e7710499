//! The controller shell: what every team controller of the paper keeps and does besides its own
//! control law, written once. [`Shell<L>`] holds the shared state ([`ShellState`]: the robots'
//! descriptions, the expected members, the task references and targets, the grasp tracker, the
//! release watch, the diagnostics) and implements [`TeamController`] for any law `L` that
//! implements [`ControlLaw`]; a controller adds only its law.
//!
//! * [`config`]: [`ShellConfig`], the parameters every controller shares, flat in its file.
//! * [`report`]: the tick's outputs every controller writes the same way (each robot's torque
//!   slice, the contact wrenches, the object estimate).
//! * [`tasks`]: the walk over a tick's tasks and their errors (object, torsos, swing feet, free
//!   hands) both laws stack in their own way.

pub mod config;
pub mod report;
pub mod tasks;

use std::collections::BTreeMap;

use protocol::{
    DynamicsTerms, FootLoad, RobotDescription, TaskReferences, TickDiagnostics, TorqueCommand,
};

pub use config::ShellConfig;

use crate::building_blocks::grasp::{GraspTerms, GraspTracker, RefitRule};
use crate::building_blocks::limits::torque_limits;
use crate::building_blocks::messages::set_note;
use crate::building_blocks::release::{GraspObservation, GraspWatch};
use crate::building_blocks::targets::Targets;
use crate::team::Team;
use crate::{ControllerError, TeamController};

/// What a team controller keeps besides its law, the same for every law.
#[derive(Default)]
pub struct ShellState {
    /// Limits and contact parameters of each robot (from its agent's description), by id.
    pub descriptions: BTreeMap<String, RobotDescription>,
    /// The robots every tick must contain (sorted ids); `None`: whoever is in the tick.
    pub expected: Option<Vec<String>>,
    /// The task references; tasks without a reference hold the pose they had when first seen.
    pub references: Option<TaskReferences>,
    /// Every task's target ([`crate::building_blocks::targets`]).
    pub targets: Targets,
    /// The rigid grasp's offsets and fit ([`crate::building_blocks::grasp`]).
    pub grasp: GraspTracker,
    /// When the team lets go of the object ([`crate::building_blocks::release`]).
    pub watch: GraspWatch,
    /// The last solved tick's diagnostics, its strings and vectors reused by the next.
    pub diagnostics: Option<TickDiagnostics>,
}

impl ShellState {
    /// The feet the references are unloading (none without references).
    pub fn foot_loads(&self) -> &[FootLoad] {
        self.references.as_ref().map_or(&[][..], |refs| &refs.foot_loads[..])
    }

    /// The diagnostics to overwrite with this tick's (made on the first tick).
    pub fn diagnostics_mut(&mut self) -> &mut TickDiagnostics {
        self.diagnostics.get_or_insert_with(|| TickDiagnostics::empty("", 0))
    }

    /// The tick's team (§III-A: `M`, `h`, `v`, `S` and the frames, in the order of `expected`),
    /// its torque limits (eq. original_torque_limit) and the rigid grasp (eqs. graspmatrix,
    /// jacobian_cee, obj_jacobian) into `out`, the release watch re-armed first and the late
    /// robots' free hands kept clear of the object after.
    pub fn assemble_tick(
        &mut self,
        tick: &[DynamicsTerms],
        cfg: &ShellConfig,
        fully_actuated: bool,
        out: TickTeam<'_>,
    ) -> Result<(), ControllerError> {
        let TickTeam { team, actuated, limits, grasp } = out;
        // Degrade, never collapse: once the team has let go of the object, every hand is free.
        self.watch.rearm(tick.iter().any(|t| t.hand_in_grasp));
        team.hands_released = self.watch.released().is_some();
        team.assemble_into(tick, self.expected.as_deref(), fully_actuated)?;
        torque_limits(team, &self.descriptions, fully_actuated, actuated, limits)?;
        let plan = (cfg.object_pose_at_grasp, &cfg.planned_grasp[..]);
        let refit = if self.watch.follows_slip() {
            cfg.release.refit(cfg.robot_period)
        } else {
            RefitRule::NEVER
        };
        self.grasp.update_refitting(team, plan, refit, grasp)?;
        // Late robots' free hands keep clear of the object the others hold.
        self.targets.keep_clear(
            team,
            grasp.as_ref().map(|g| &g.object.translation.vector),
            cfg.release.retreat,
        );
        Ok(())
    }

    /// Degrade, never collapse: after a tick (`fell_back`: its command came from the law's
    /// fallback), let go of an object the team cannot hold ([`crate::building_blocks::release`]);
    /// why
    /// the hands are free into `note` (`None` while the grasp holds). Whether the team let go
    /// on this tick.
    pub fn watch_release(
        &mut self,
        cfg: &ShellConfig,
        tick: &[DynamicsTerms],
        (team, grasp): (&Team, Option<&GraspTerms>),
        fell_back: bool,
        note: &mut Option<String>,
    ) -> bool {
        let now = tick[0].header.tick;
        let outcome = GraspObservation::of((now, cfg.robot_period), team, grasp, fell_back);
        let ShellState { targets, grasp: tracker, watch, .. } = self;
        set_note(note, watch.after_tick(&cfg.release, outcome, team, grasp, targets, tracker));
        watch.released().is_some_and(|r| r.tick == now)
    }

    /// Why the controller cannot run `members` yet: the descriptions still missing, if any.
    pub fn missing_descriptions(&self, members: &[String]) -> Option<String> {
        let missing: Vec<&String> =
            members.iter().filter(|m| !self.descriptions.contains_key(*m)).collect();
        (!missing.is_empty()).then(|| format!("waiting for the descriptions of {missing:?}"))
    }
}

/// Where [`ShellState::assemble_tick`] writes the tick's team (a law's report fields).
pub struct TickTeam<'a> {
    pub team: &'a mut Team,
    /// The team's actuated coordinates and their torque limits.
    pub actuated: &'a mut Vec<usize>,
    pub limits: &'a mut Vec<f64>,
    pub grasp: &'a mut Option<GraspTerms>,
}

/// A controller's own law: from a tick's dynamics terms and the shared state to one torque
/// command per member (and the tick's diagnostics, in [`ShellState::diagnostics`]). The
/// methods' names differ from [`TeamController`]'s, which [`Shell`] implements with them.
pub trait ControlLaw: Send {
    /// What the controller calls itself ([`TeamController::name`]).
    fn law_name(&self) -> &'static str;

    /// One tick ([`TeamController::solve`]): the torque commands into `out` (messages reused),
    /// the diagnostics into `state` if the law makes any. Allocates nothing once the team's
    /// shape is set.
    fn control(
        &mut self,
        state: &mut ShellState,
        tick: &[DynamicsTerms],
        out: &mut Vec<TorqueCommand>,
    ) -> Result<(), ControllerError>;

    /// Whether the last tick's command came from the law's fallback.
    fn fell_back(&self) -> bool {
        false
    }

    /// Whether the ticks from now on compute what their torques accelerate; returns whether
    /// the law models them at all ([`TeamController::keep_accelerations`]).
    fn model_accelerations(&mut self, _keep: bool) -> bool {
        false
    }

    /// What the last tick's torques accelerate for `robot`, if kept
    /// ([`TeamController::accelerations`]).
    fn accelerations_of(&self, _robot: &str) -> Option<&[f64]> {
        None
    }

    /// How long a tick may take before its fallback answers; returns whether the law keeps
    /// such a budget ([`TeamController::set_solve_budget`]).
    fn solve_budget(&mut self, _budget: Option<std::time::Duration>) -> bool {
        false
    }
}

/// A team controller: the shared state with a law `L` ([`ControlLaw`]). PIDC and MQP are
/// `Shell<PidcLaw>` and `Shell<MqpLaw>` ([`crate::Pidc`], [`crate::Mqp`]).
pub struct Shell<L> {
    /// What every controller keeps.
    pub state: ShellState,
    /// The controller's own law, its parameters and its workspace.
    pub law: L,
}

impl<L> Shell<L> {
    /// The controller of `law`, with nothing received yet.
    pub fn with_law(law: L) -> Self {
        Shell { state: ShellState::default(), law }
    }

    /// Limits and contact parameters of a robot (from its agent's description).
    pub fn set_description(&mut self, d: &RobotDescription) {
        self.state.descriptions.insert(d.header.robot_id().to_string(), d.clone());
    }

    /// Whether robot `robot`'s description arrived.
    pub fn has_description(&self, robot: &str) -> bool {
        self.state.descriptions.contains_key(robot)
    }

    /// The robots every tick must contain (sorted ids); `None`: whoever is in the tick.
    pub fn set_expected(&mut self, robots: Option<Vec<String>>) {
        self.state.expected = robots;
    }

    /// Task references. Tasks without a reference hold the pose they had when first seen.
    pub fn set_references(&mut self, r: &TaskReferences) {
        match &mut self.state.references {
            Some(old) => old.clone_from(r),
            None => self.state.references = Some(r.clone()),
        }
    }
}

impl<L: ControlLaw> TeamController for Shell<L> {
    fn name(&self) -> &'static str {
        self.law.law_name()
    }

    fn solve(
        &mut self,
        tick: &[DynamicsTerms],
        out: &mut Vec<TorqueCommand>,
    ) -> Result<(), ControllerError> {
        self.law.control(&mut self.state, tick, out)
    }

    fn diagnostics(&self) -> Option<&TickDiagnostics> {
        self.state.diagnostics.as_ref()
    }

    fn used_fallback(&self) -> bool {
        self.law.fell_back()
    }

    fn released_at(&self) -> Option<u64> {
        self.state.watch.released().map(|r| r.tick)
    }

    fn set_description(&mut self, d: &RobotDescription) {
        Shell::set_description(self, d);
    }

    fn set_references(&mut self, r: &TaskReferences) {
        Shell::set_references(self, r);
    }

    fn set_members(&mut self, members: &[String]) {
        self.set_expected(Some(members.to_vec()));
    }

    fn set_late(&mut self, robots: &[String]) {
        self.state.targets.set_late(robots);
    }

    fn not_ready(&self, members: &[String]) -> Option<String> {
        self.state.missing_descriptions(members)
    }

    fn ready(&self, robot: &str) -> bool {
        self.has_description(robot)
    }

    fn check_terms(&self, terms: &DynamicsTerms) -> Result<(), ControllerError> {
        crate::team::terms_fit(terms, self.state.descriptions.get(terms.header.robot_id()))
    }

    fn keep_accelerations(&mut self, keep: bool) -> bool {
        self.law.model_accelerations(keep)
    }

    fn accelerations(&self, robot: &str) -> Option<&[f64]> {
        self.law.accelerations_of(robot)
    }

    fn set_solve_budget(&mut self, budget: Option<std::time::Duration>) -> bool {
        self.law.solve_budget(budget)
    }
}
