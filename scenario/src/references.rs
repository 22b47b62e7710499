//! The references of a run: the scenario's motions about each task's start pose, or the
//! walk, as a function of the tick ([`ReferencePlan`]).

use std::sync::Arc;

use nalgebra::{UnitQuaternion, Vector3};
use planner::reference::PoseMotion;
use protocol::conventions::quat_to_wxyz;
use protocol::{Header, Pose, PoseReference, RunClock, TaskReferences, TorsoReference};
use sim_bridge::scene::Scene;

use crate::file::Scenario;

/// The references of the run: the scenario's motions about each task's start pose, or the walk.
pub fn reference_plan(
    s: &Scenario,
    scene: &Scene,
    walk: Option<Arc<planner::walk::Walk>>,
) -> ReferencePlan {
    let torso_start = |i: usize| {
        let p = &scene.world.robots[i];
        (
            Vector3::from(p.base_position),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), p.base_yaw),
        )
    };
    ReferencePlan {
        clock: scene.clock(),
        ramp: s.references.ramp,
        object: s.references.object.clone(),
        object_start: (Vector3::from(s.object.position), UnitQuaternion::identity()),
        torsos: s
            .robots
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let motion = s
                    .references
                    .torsos
                    .iter()
                    .find(|t| t.robot == r.id)
                    .map(|t| t.motion.clone())
                    .unwrap_or_default();
                let (p, q) = torso_start(i);
                (r.id.clone(), motion, p, q)
            })
            .collect(),
        walk,
        walk_halted_at: None,
    }
}

/// The scenario's references as a function of the tick: during settling every task holds its
/// start pose (the pose the world starts in, which the controller also holds before any
/// reference arrives); afterwards `motion(t)` about the start pose, `t` on the scenario clock.
#[derive(Debug, Clone)]
pub struct ReferencePlan {
    /// The run's ticks and scenario clock (the scene's; `protocol::clock`).
    pub clock: RunClock,
    /// Fade-in of every motion, s.
    pub ramp: f64,
    pub object: PoseMotion,
    pub object_start: (Vector3<f64>, UnitQuaternion<f64>),
    /// Robot id, motion, start position and orientation of each torso.
    pub torsos: Vec<(String, PoseMotion, Vector3<f64>, UnitQuaternion<f64>)>,
    /// The walk, if the scenario has one: it gives the walking torsos', the carried object's
    /// and the swing feet's references.
    pub walk: Option<Arc<planner::walk::Walk>>,
    /// Scenario time at which the walk was halted ([`ReferencePlan::halt_walk`]): from then on
    /// its torso and object references hold their poses of then at rest, each foot holds where
    /// it stands, and an unloading cut short is undone (`Walk::feet_after_halt_into`).
    pub walk_halted_at: Option<f64>,
}

fn hold(p: &Vector3<f64>, q: &UnitQuaternion<f64>) -> PoseReference {
    PoseReference {
        pose: Pose { position: (*p).into(), orientation: quat_to_wxyz(q) },
        twist: [0.0; 6],
        acceleration: [0.0; 6],
    }
}

impl ReferencePlan {
    /// Scenario time of a tick's state (`None` while settling).
    pub fn time_of_tick(&self, tick: u64) -> Option<f64> {
        self.clock.scenario_time(tick)
    }

    /// When a walk stops if the team lets go after `released_tick`: at once before a lift-off,
    /// else at the walk's first quiet point from then on ([`planner::gait::GaitPlan::halt_point`];
    /// `None` without a walk).
    pub fn walk_halt_time(&self, released_tick: u64) -> Option<f64> {
        let t = self.time_of_tick(released_tick).unwrap_or(0.0);
        self.walk.as_ref().map(|w| w.gait.halt_point(t))
    }

    /// Halt the walk for a release after `released_tick` ([`ReferencePlan::walk_halt_time`]),
    /// once; the halt time when this call halted it.
    pub fn halt_walk(&mut self, released_tick: u64) -> Option<f64> {
        if self.walk_halted_at.is_some() {
            return None;
        }
        self.walk_halted_at = self.walk_halt_time(released_tick);
        self.walk_halted_at
    }

    /// The walk and the time to ask it for at scenario time `t` (held at the halt).
    fn walk_at(&self, t: Option<f64>) -> Option<(f64, &planner::walk::Walk)> {
        let t = t?.min(self.walk_halted_at.unwrap_or(f64::INFINITY));
        self.walk.as_deref().map(|w| (t, w))
    }

    /// The halt time if the walk is held at scenario time `t` (halted before `t`).
    fn held_since(&self, t: Option<f64>) -> Option<f64> {
        self.walk_halted_at.filter(|h| t.is_some_and(|t| t > *h))
    }

    /// A walk's pose reference, at rest once the walk is held (a halt before a lift-off stops
    /// a torso in its shift).
    fn walk_pose(&self, t: Option<f64>, r: PoseReference) -> PoseReference {
        match self.held_since(t) {
            Some(_) => PoseReference { twist: [0.0; 6], acceleration: [0.0; 6], ..r },
            None => r,
        }
    }

    /// Object reference at scenario time `t` (`None`: the settling hold).
    pub fn object_at(&self, t: Option<f64>) -> PoseReference {
        if let Some(r) = self.walk_at(t).and_then(|(t, w)| w.object(t)) {
            return self.walk_pose(t, r);
        }
        let (p, q) = &self.object_start;
        self.pose_at(&self.object, p, q, t)
    }

    /// Reference of torso `i` at scenario time `t`.
    pub fn torso_at(&self, i: usize, t: Option<f64>) -> PoseReference {
        if let Some(r) = self.walk_at(t).and_then(|(t, w)| w.torso(i, t)) {
            return self.walk_pose(t, r);
        }
        let (_, m, p, q) = &self.torsos[i];
        self.pose_at(m, p, q, t)
    }

    fn pose_at(
        &self,
        m: &PoseMotion,
        p: &Vector3<f64>,
        q: &UnitQuaternion<f64>,
        t: Option<f64>,
    ) -> PoseReference {
        match t {
            Some(t) => m.reference(p, q, t, self.ramp),
            None => hold(p, q),
        }
    }

    /// The TaskReferences message of `tick`.
    pub fn for_tick(&self, team: &str, tick: u64) -> TaskReferences {
        let t = self.time_of_tick(tick);
        let mut refs = TaskReferences {
            header: Header::new(team, None, tick, protocol::wall_clock_ns()),
            object: Some(self.object_at(t)),
            torsos: (0..self.torsos.len())
                .map(|i| TorsoReference {
                    robot: self.torsos[i].0.clone(),
                    reference: self.torso_at(i, t),
                })
                .collect(),
            swing_feet: Vec::new(),
            foot_loads: Vec::new(),
        };
        match (self.walk_at(t), self.held_since(t)) {
            (Some((t_h, w)), Some(_)) => w.feet_after_halt_into(t_h, t.unwrap_or(t_h), &mut refs),
            (Some((t, w)), None) => w.feet_into(t, &mut refs),
            (None, _) => {}
        }
        refs
    }
}
