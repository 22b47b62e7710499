//! Where each task's target comes from ([`Targets`]): the task references when they name the
//! task, else the pose the task had when it was first seen (held, at rest); free hands hold
//! their pose, or the pose they backed away to when the team let go of the object. PIDC and
//! MQP share these rules.

use std::collections::BTreeMap;

use nalgebra::{DVector, Isometry3, Translation3, UnitQuaternion, Vector3, Vector6};
use protocol::{PoseReference, TaskReferences};

use crate::team::{Team, TeamFrame};
use protocol::conventions::quat_from_wxyz;

/// A pose target: pose, twist and acceleration (world, `[linear; angular]`).
pub type PoseTarget = (Isometry3<f64>, [f64; 6], [f64; 6]);
/// A point target: position, velocity and acceleration (world).
pub type PointTarget = (Vector3<f64>, [f64; 3], [f64; 3]);

/// Where each task's target comes from: the task references when they name the task, else
/// the pose the task had when it was first seen without one (held, at rest).
#[derive(Debug, Clone, Default)]
pub struct Targets {
    held_torsos: BTreeMap<String, Isometry3<f64>>,
    /// (robot, frame, position) of swing feet without a reference.
    held_feet: Vec<(String, String, Vector3<f64>)>,
    held_object: Option<Isometry3<f64>>,
    /// (robot, pose) of free hands: the pose each had when it became free.
    held_hands: Vec<(String, Isometry3<f64>)>,
    /// Robots that joined the running team, their hands out of the grasp ([`Targets::keep_clear`]).
    late: Vec<String>,
}

impl Targets {
    /// The object's target; without a reference, the object pose `object` of the first such tick.
    pub fn object(&mut self, refs: Option<&TaskReferences>, object: &Isometry3<f64>) -> PoseTarget {
        match refs.and_then(|r| r.object.as_ref()) {
            Some(r) => pose_ref(r),
            None => (*self.held_object.get_or_insert(*object), [0.0; 6], [0.0; 6]),
        }
    }

    /// Robot `id`'s torso target; without a reference, its pose `x` when first seen.
    pub fn torso(
        &mut self,
        refs: Option<&TaskReferences>,
        id: &str,
        x: &Isometry3<f64>,
    ) -> PoseTarget {
        match refs.and_then(|r| r.torsos.iter().find(|t| t.robot == id)) {
            Some(t) => pose_ref(&t.reference),
            None => match self.held_torsos.get(id) {
                Some(h) => (*h, [0.0; 6], [0.0; 6]),
                None => (*self.held_torsos.entry(id.to_string()).or_insert(*x), [0.0; 6], [0.0; 6]),
            },
        }
    }

    /// The target of robot `id`'s swing foot `frame`; without a reference, its position `p`
    /// when first seen.
    pub fn swing_foot(
        &mut self,
        refs: Option<&TaskReferences>,
        id: &str,
        frame: &str,
        p: &Vector3<f64>,
    ) -> PointTarget {
        match refs.and_then(|r| r.swing_feet.iter().find(|s| s.robot == id && s.frame == frame)) {
            Some(s) => (
                Vector3::from(s.reference.position),
                s.reference.velocity,
                s.reference.acceleration,
            ),
            None => match self.held_feet.iter().find(|(r, f, _)| r == id && f == frame) {
                Some((_, _, p)) => (*p, [0.0; 3], [0.0; 3]),
                None => {
                    self.held_feet.push((id.to_string(), frame.to_string(), *p));
                    (*p, [0.0; 3], [0.0; 3])
                }
            },
        }
    }

    /// Robot `id`'s free hand's target: its pose `x` when it became free (there are no hand
    /// references), at rest.
    pub fn free_hand(&mut self, id: &str, x: &Isometry3<f64>) -> PoseTarget {
        match self.held_hands.iter().find(|(r, _)| r == id) {
            Some((_, h)) => (*h, [0.0; 6], [0.0; 6]),
            None => {
                self.held_hands.push((id.to_string(), *x));
                (*x, [0.0; 6], [0.0; 6])
            }
        }
    }

    /// The team lets go of the object centred at `centre`: each hand in grasp will hold its
    /// pose moved `retreat` away from the centre (horizontally) once it is free.
    pub fn let_go(&mut self, team: &Team, centre: &Vector3<f64>, retreat: f64) {
        for h in &team.hands {
            let pose = away_from(h, centre, retreat);
            let id = &team.robots[h.robot].id;
            match self.held_hands.iter_mut().find(|(r, _)| r == id) {
                Some((_, held)) => *held = pose,
                None => self.held_hands.push((id.clone(), pose)),
            }
        }
    }

    /// The late robots (sorted ids): they joined a team that holds the object, their hands out
    /// of the grasp (`crate::team::membership::Roster`).
    pub fn set_late(&mut self, robots: &[String]) {
        self.late.clear();
        self.late.extend_from_slice(robots);
    }

    /// The free hands of late robots ([`Targets::set_late`]) keep clear of the object centred at
    /// `centre`: the first time such a hand is seen free it will hold its pose moved `retreat`
    /// away from the centre (horizontally), as a hand the team let go of does. Without an object
    /// (`None`) they hold their pose.
    pub fn keep_clear(&mut self, team: &Team, centre: Option<&Vector3<f64>>, retreat: f64) {
        let Some(centre) = centre else { return };
        for h in &team.free_hands {
            let id = &team.robots[h.robot].id;
            if !self.late.contains(id) || self.held_hands.iter().any(|(r, _)| r == id) {
                continue;
            }
            self.held_hands.push((id.clone(), away_from(h, centre, retreat)));
        }
    }

    /// Forget the held positions of feet that are no longer in swing (they landed): a foot
    /// that swings again without a reference holds where it lifts off next time, not where it
    /// lifted off first.
    pub fn keep_swing_feet(&mut self, team: &Team) {
        self.held_feet.retain(|(r, f, _)| {
            team.swing_feet.iter().any(|s| s.name == *f && team.robots[s.robot].id == *r)
        });
    }

    /// Forget the held poses of hands that are no longer free (they closed on the object).
    pub fn keep_free_hands(&mut self, team: &Team) {
        self.held_hands
            .retain(|(r, _)| team.free_hands.iter().any(|h| team.robots[h.robot].id == *r));
    }

    /// Forget the held object pose (the grasp was released).
    pub fn release_object(&mut self) {
        self.held_object = None;
    }
}

/// Hand `h`'s pose moved `retreat` away from `centre`, horizontally.
fn away_from(h: &TeamFrame, centre: &Vector3<f64>, retreat: f64) -> Isometry3<f64> {
    let mut away = h.position - centre;
    away.z = 0.0;
    let step = away.try_normalize(1e-9).map_or(Vector3::zeros(), |d| d * retreat);
    Isometry3::from_parts(
        Translation3::from(h.position + step),
        UnitQuaternion::from_rotation_matrix(&h.rotation),
    )
}

/// A pose reference as a target.
fn pose_ref(r: &PoseReference) -> PoseTarget {
    let rot = UnitQuaternion::from_rotation_matrix(
        &quat_from_wxyz(r.pose.orientation).to_rotation_matrix(),
    );
    (
        Isometry3::from_parts(Translation3::from(Vector3::from(r.pose.position)), rot),
        r.twist,
        r.acceleration,
    )
}

/// A 6-row frame's pose and twist `J v` (world, `[linear; angular]`).
pub fn frame_pose(tf: &TeamFrame, velocity: &DVector<f64>) -> (Isometry3<f64>, Vector6<f64>) {
    let x = Isometry3::from_parts(
        Translation3::from(tf.position),
        UnitQuaternion::from_rotation_matrix(&tf.rotation),
    );
    (x, tf.velocity(velocity))
}
