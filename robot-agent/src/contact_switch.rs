//! When the robot's contact set changes: [`ContactSwitch`].
//!
//! Contact sets arrive ahead of time (a gait planner publishes them with the state tick they
//! apply from, `ContactSet.header.tick`) and wait in a bounded schedule. At each state the
//! switch takes the newest due set as its *goal* and moves the *active* set (the one the
//! dynamics terms are computed for) towards it, foot by foot:
//!
//! * **Lift-off** (stance -> swing) happens at the set's tick once the foot is unloaded (its
//!   measured force at most [`SwitchConfig::liftoff_force`]), unless fewer than
//!   [`SwitchConfig::min_stance`] feet (or all but one) would stay in stance: else the foot stays
//!   down and the lift-off is deferred (tried again at every state while the goal asks for it).
//! * **Touchdown** (swing -> stance) needs the foot's measured normal force
//!   (`RobotState::foot_forces`) to reach [`SwitchConfig::touchdown_force`]: a foot that lands
//!   late stays in swing (tracking its reference, which presses it down) until it touches, one
//!   that lands early within the set's lead time is switched as soon as it touches. A robot
//!   that measures no foot forces (empty `foot_forces`) switches at the planned tick.
//! * The hand's grasp flag follows the goal at once.

use std::collections::VecDeque;

use crate::terms::ActiveContacts;

/// How contact sets are switched.
#[derive(Debug, Clone, PartialEq)]
pub struct SwitchConfig {
    /// A swing foot lands when its measured normal force reaches this, N.
    pub touchdown_force: f64,
    /// A stance foot lifts off only once its measured normal force is at most this, N (the
    /// unloading ramp has done its work).
    pub liftoff_force: f64,
    /// A lift-off that would leave fewer feet in stance is deferred (at most all feet but
    /// one are kept down: a robot with two feet may lift one).
    pub min_stance: usize,
    /// Most contact sets waiting for their tick; a set beyond this is refused.
    pub max_scheduled: usize,
}

impl Default for SwitchConfig {
    /// 20 N to confirm a touchdown, at most 20 N to lift off, three feet always down, 64 sets
    /// scheduled.
    fn default() -> Self {
        SwitchConfig {
            touchdown_force: 20.0,
            liftoff_force: 20.0,
            min_stance: 3,
            max_scheduled: 64,
        }
    }
}

/// What a state did to the active contact set.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SwitchEvents {
    pub liftoffs: u32,
    pub touchdowns: u32,
    /// Lift-offs the goal asks for that would leave too few feet down, or of a foot still
    /// loaded.
    pub deferred: u32,
    /// Feet the goal has in stance that have not touched down yet.
    pub awaiting_touchdown: u32,
}

impl SwitchEvents {
    pub fn changed(&self) -> bool {
        self.liftoffs + self.touchdowns > 0
    }
}

/// The schedule of contact sets and the active set (see the module docs).
#[derive(Debug, Clone)]
pub struct ContactSwitch {
    config: SwitchConfig,
    scheduled: VecDeque<(u64, ActiveContacts)>,
    goal: ActiveContacts,
    active: ActiveContacts,
}

/// The schedule is full: the set of `tick` is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScheduleFull {
    pub tick: u64,
    pub capacity: usize,
}

impl ContactSwitch {
    /// Starting with `initial` active (and as the goal).
    pub fn new(config: SwitchConfig, initial: ActiveContacts) -> Self {
        let scheduled = VecDeque::with_capacity(config.max_scheduled);
        ContactSwitch { config, scheduled, goal: initial.clone(), active: initial }
    }

    /// The set the dynamics terms are computed for.
    pub fn active(&self) -> &ActiveContacts {
        &self.active
    }

    /// The newest due set the active one moves towards.
    pub fn goal(&self) -> &ActiveContacts {
        &self.goal
    }

    /// Sets waiting for their tick.
    pub fn scheduled(&self) -> usize {
        self.scheduled.len()
    }

    /// Schedule `set` from state tick `tick` on. The newest message is the plan from its tick
    /// on: it replaces a set scheduled for the same tick and cancels every set scheduled for a
    /// later one (a planner that changes its mind, e.g. a walk halted when the team lets go,
    /// sends the set it wants from then on). A planner that sends its sets in tick order never
    /// cancels any.
    pub fn schedule(&mut self, tick: u64, set: ActiveContacts) -> Result<(), ScheduleFull> {
        let at = self.scheduled.partition_point(|(t, _)| *t < tick);
        if at >= self.config.max_scheduled {
            return Err(ScheduleFull { tick, capacity: self.config.max_scheduled });
        }
        self.scheduled.truncate(at);
        self.scheduled.push_back((tick, set));
        Ok(())
    }

    /// A state of `tick` with the feet's measured normal forces (empty: not measured): take
    /// the due sets, then switch feet towards the goal.
    pub fn on_state(&mut self, tick: u64, foot_forces: &[f64]) -> SwitchEvents {
        while self.scheduled.front().is_some_and(|(t, _)| *t <= tick) {
            if let Some((_, set)) = self.scheduled.pop_front() {
                self.goal = set;
            }
        }
        let mut ev = SwitchEvents::default();
        self.active.hand_in_grasp = self.goal.hand_in_grasp;
        let sensed = foot_forces.len() == self.active.stance.len();
        // Without a measurement a foot counts as landed and as unloaded.
        let force = |k: usize| if sensed { foot_forces[k] } else { f64::NAN };
        // Touchdowns first: a foot that lands lets another lift off in the same state.
        for k in 0..self.active.stance.len() {
            if !self.active.stance[k] && self.goal.stance.get(k).copied().unwrap_or(true) {
                if !sensed || force(k) >= self.config.touchdown_force {
                    self.active.stance[k] = true;
                    ev.touchdowns += 1;
                } else {
                    ev.awaiting_touchdown += 1;
                }
            }
        }
        let keep = self.config.min_stance.min(self.active.stance.len().saturating_sub(1));
        for k in 0..self.active.stance.len() {
            if self.active.stance[k] && !self.goal.stance.get(k).copied().unwrap_or(true) {
                let down = self.active.stance.iter().filter(|s| **s).count();
                let unloaded = !sensed || force(k) <= self.config.liftoff_force;
                if down > keep && unloaded {
                    self.active.stance[k] = false;
                    ev.liftoffs += 1;
                } else {
                    ev.deferred += 1;
                }
            }
        }
        ev
    }
}
