//! What a run sends for a walk, per tick or ahead of time: torso, object and swing-foot
//! references with the feet's unloading ramps (into the tick's [`TaskReferences`]), and each
//! robot's contact sets ([`Walk::contact_sets`]).

use nalgebra::Isometry3;
use protocol::conventions::quat_to_wxyz;
use protocol::{
    ContactSet, FootLoad, Header, PointReference, Pose, PoseReference, RunClock,
    SwingFootReference, TaskReferences,
};

use super::Walk;

/// A pose target as a reference message.
fn pose_reference((x, twist, acc): (Isometry3<f64>, [f64; 6], [f64; 6])) -> PoseReference {
    PoseReference {
        pose: Pose {
            position: x.translation.vector.into(),
            orientation: quat_to_wxyz(&x.rotation),
        },
        twist,
        acceleration: acc,
    }
}

impl Walk {
    /// Robot `i`'s torso reference at scenario time `t`, if it walks.
    pub fn torso(&self, i: usize, t: f64) -> Option<PoseReference> {
        self.walking.get(i).copied().unwrap_or(false).then(|| pose_reference(self.gait.torso(i, t)))
    }

    /// The object's reference at scenario time `t`, if the team carries it along.
    pub fn object(&self, t: f64) -> Option<PoseReference> {
        self.gait.object(t).filter(|_| self.moves_object).map(pose_reference)
    }

    /// The swing-foot references and unloading ramps of scenario time `t` into `refs`.
    pub fn feet_into(&self, t: f64, refs: &mut TaskReferences) {
        for (i, id) in self.robots.iter().enumerate().filter(|(i, _)| self.walking[*i]) {
            for (k, frame) in self.feet[i].iter().enumerate() {
                if let Some((p, v, a)) = self.gait.swing_foot(i, k, t) {
                    let reference =
                        PointReference { position: p.into(), velocity: v, acceleration: a };
                    refs.swing_feet.push(SwingFootReference {
                        robot: id.clone(),
                        frame: frame.clone(),
                        reference,
                    });
                }
                if let Some(f) = self.gait.max_normal_force(i, k, t) {
                    refs.foot_loads.push(FootLoad {
                        robot: id.clone(),
                        frame: frame.clone(),
                        max_normal_force: f,
                    });
                }
            }
        }
    }

    /// The feet's references of scenario time `t` after a halt at `t_h` into `refs`: each foot
    /// where it stands, at rest ([`crate::gait::GaitPlan::foot_after_halt`]: a foot that lands
    /// late, or lifted before the halt reached its agent, is pressed down there), and the
    /// unloading ramps cut short at the halt undone
    /// ([`crate::gait::GaitPlan::max_normal_force_after_halt`]).
    pub fn feet_after_halt_into(&self, t_h: f64, t: f64, refs: &mut TaskReferences) {
        for (i, id) in self.robots.iter().enumerate().filter(|(i, _)| self.walking[*i]) {
            for (k, frame) in self.feet[i].iter().enumerate() {
                if let Some((p, v, a)) = self.gait.foot_after_halt(i, k, t_h) {
                    let reference =
                        PointReference { position: p.into(), velocity: v, acceleration: a };
                    refs.swing_feet.push(SwingFootReference {
                        robot: id.clone(),
                        frame: frame.clone(),
                        reference,
                    });
                }
                if let Some(f) = self.gait.max_normal_force_after_halt(i, k, t_h, t) {
                    refs.foot_loads.push(FootLoad {
                        robot: id.clone(),
                        frame: frame.clone(),
                        max_normal_force: f,
                    });
                }
            }
        }
    }

    /// Every contact set of the walk, by tick: each change of a robot's planned stance, from
    /// the first tick at or after its time (the agent lifts the foot off then, and lands a
    /// foot once its force confirms the touchdown).
    pub fn contact_sets(&self, team: &str, clock: &RunClock) -> Vec<ContactSet> {
        let mut sets: Vec<ContactSet> = self
            .gait
            .contact_changes()
            .into_iter()
            .map(|(t, i, stance)| self.contact_set(team, clock, t, i, stance))
            .collect();
        sets.sort_by_key(|c| c.header.tick);
        sets
    }

    /// The sets that halt the walk at scenario time `t` (a halt point,
    /// [`crate::gait::GaitPlan::halt_point`]): every walking robot on all its feet from then
    /// on. An agent takes a set for an earlier tick than those it has waiting as the new plan
    /// and drops the later ones (`robot_agent::contact_switch`), so the walk's remaining
    /// lift-offs never happen.
    pub fn halt_sets(&self, team: &str, clock: &RunClock, t: f64) -> Vec<ContactSet> {
        (0..self.robots.len())
            .filter(|i| self.walking[*i])
            .map(|i| self.contact_set(team, clock, t, i, [true; 4]))
            .collect()
    }

    /// Robot `i`'s set with `stance` from the first tick at or after scenario time `t`.
    fn contact_set(
        &self,
        team: &str,
        clock: &RunClock,
        t: f64,
        i: usize,
        stance: [bool; 4],
    ) -> ContactSet {
        let tick = clock.first_tick_at(t);
        let feet =
            self.feet[i].iter().zip(stance).filter(|(_, s)| *s).map(|(f, _)| f.clone()).collect();
        ContactSet {
            header: Header::new(team, Some(&self.robots[i]), tick, 0),
            stance_feet: feet,
            hand_in_grasp: true,
        }
    }
}
