//! A walk measured from the ground truth: the steps each robot took (a foot out of contact
//! for at least [`MIN_AIRBORNE`] and back), how far stance feet slid, and how far each torso
//! ended from its goal. Contacts are the simulator's foot contacts; a foot's slide is the
//! velocity of its sphere's lowest point (`GroundTruth::feet`: centre velocity and spin)
//! integrated over each stance.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Translation3, Vector2, Vector3};
use protocol::GroundTruth;
use serde::Serialize;

use planner::gait::Step;
use planner::walk::Walk;

use crate::metrics;

/// A foot must be off the ground at least this long for a step to count, s.
pub const MIN_AIRBORNE: f64 = 0.03;
/// A stance foot's slide is measured from this long after its touchdown, s.
pub const SLIDE_AFTER_TOUCHDOWN: f64 = 0.03;
/// Acceptance bounds of a walk while holding.
pub const MAX_STANCE_SLIDE: f64 = 0.01;
pub const MAX_FINAL_TORSO_POSITION: f64 = 0.02;
pub const MAX_FINAL_TORSO_ANGLE_DEG: f64 = 3.0;
pub const MAX_WALKING_TORSO_POSITION_RMS: f64 = 0.02;

/// What a walk did, per robot.
#[derive(Debug, Clone, Default, Serialize)]
pub struct WalkReport {
    pub steps_planned: BTreeMap<String, usize>,
    pub steps_taken: BTreeMap<String, usize>,
    /// Least planned distance of the centre of pressure inside the support triangle at a
    /// lift-off, m.
    pub least_margin_m: f64,
    /// Per walking robot, the least measured distance of its centre of pressure (from the
    /// simulator's foot contact forces) inside the triangle of the three other feet as a
    /// foot's unloading starts (torso shifted, every foot down): the planned margin as the
    /// simulator realises it, m.
    pub cop_margin_m: BTreeMap<String, f64>,
    /// Per walking robot, at the same instants, the least share of its weight that one of the
    /// three other feet carries (the measured centre of pressure's least barycentric
    /// coordinate in their triangle; `walk.gait.min_share` plans it).
    pub cop_share: BTreeMap<String, f64>,
    /// Per walking robot, the longest a foot that should stand was off the ground while
    /// another swung (the robot rocked onto a diagonal), ms.
    pub stance_lift_ms: BTreeMap<String, f64>,
    /// Largest horizontal slide of a stance foot, per robot, m.
    pub stance_slide_m: BTreeMap<String, f64>,
    /// Each landing's first ground contact minus its planned touchdown, ms: the earliest and
    /// the latest (negative: early). The contact switch, not the plan, decides when a foot
    /// carries load.
    pub touchdown_offset_ms: [f64; 2],
    /// Final torso position and angle error against the last waypoint, per walking robot.
    pub final_torso_m: BTreeMap<String, f64>,
    pub final_torso_deg: BTreeMap<String, f64>,
    /// When the walk halted because the team let go of the object (scenario time, s): the
    /// steps planned are those that lifted off before, the goals the torsos held there.
    pub halted_at_s: Option<f64>,
}

/// One foot over the run, per ground-truth sample: in contact or not, and the horizontal
/// velocity of the sphere's material point at the ground (`v + omega x (-r e_z)`: zero while
/// it rolls without slipping).
struct FootTrack {
    contact: Vec<bool>,
    slip_velocity: Vec<Vector2<f64>>,
}

fn foot_track(
    truth: &[&GroundTruth],
    robot: &str,
    frame: &str,
    link: &str,
    radius: f64,
) -> FootTrack {
    let name = format!("{robot}/{frame}");
    let contact = truth
        .iter()
        .map(|g| g.foot_contacts.iter().any(|c| c.robot == robot && c.body == link))
        .collect();
    let slip = |t: &[f64; 6]| {
        let (v, w) = (Vector3::new(t[0], t[1], t[2]), Vector3::new(t[3], t[4], t[5]));
        (v + w.cross(&(-radius * Vector3::z()))).xy()
    };
    let slip_velocity = truth
        .iter()
        .map(|g| {
            g.feet.iter().find(|b| b.name == name).map_or(Vector2::zeros(), |b| slip(&b.twist))
        })
        .collect();
    FootTrack { contact, slip_velocity }
}

/// Steps of one foot: runs out of contact of at least `MIN_AIRBORNE` that end in contact.
fn steps(times: &[f64], contact: &[bool]) -> usize {
    let mut count = 0;
    let mut lifted: Option<f64> = None;
    for (t, c) in times.iter().zip(contact) {
        match (c, lifted) {
            (false, None) => lifted = Some(*t),
            (true, Some(t0)) => {
                if t - t0 >= MIN_AIRBORNE {
                    count += 1;
                }
                lifted = None;
            }
            _ => {}
        }
    }
    count
}

/// The landing after `after`: the first contact that ends at least `MIN_AIRBORNE` in the air
/// (a foot that scuffs the ground as it lifts off has not landed).
fn first_contact_after(times: &[f64], contact: &[bool], after: f64) -> Option<f64> {
    let mut lifted: Option<f64> = None;
    for (t, c) in times.iter().zip(contact).filter(|(t, _)| **t >= after) {
        match (c, lifted) {
            (false, None) => lifted = Some(*t),
            (true, Some(t0)) if t - t0 >= MIN_AIRBORNE => return Some(*t),
            (true, Some(_)) => lifted = None,
            _ => {}
        }
    }
    None
}

/// Largest horizontal slide of a foot while in stance: the slip velocity integrated from
/// `SLIDE_AFTER_TOUCHDOWN` after each touchdown (or the start) until it lifts; rolling on its
/// sphere is not sliding.
fn stance_slide(times: &[f64], foot: &FootTrack) -> f64 {
    let mut worst = 0.0_f64;
    let mut since: Option<f64> = Some(f64::NEG_INFINITY);
    let mut slid = Vector2::zeros();
    for (k, t) in times.iter().enumerate() {
        if !foot.contact[k] {
            (since, slid) = (None, Vector2::zeros());
            continue;
        }
        let t0 = *since.get_or_insert(*t);
        let dt = if k > 0 { t - times[k - 1] } else { 0.0 };
        if t - t0 >= SLIDE_AFTER_TOUCHDOWN {
            slid += foot.slip_velocity[k] * dt;
            worst = worst.max(slid.norm());
        }
    }
    worst
}

/// Robot `robot`'s centre of pressure in a ground-truth sample: its foot contacts' points
/// weighted by their normal forces (the ground is flat), `None` without load.
fn measured_cop(g: &GroundTruth, robot: &str) -> Option<Vector2<f64>> {
    let (mut sum, mut weight) = (Vector2::zeros(), 0.0);
    for c in g.foot_contacts.iter().filter(|c| c.robot == robot) {
        let fz = c.wrench[2].max(0.0);
        sum += fz * Vector2::new(c.position[0], c.position[1]);
        weight += fz;
    }
    (weight > 1e-6).then(|| sum / weight)
}

/// Robot `i`'s measured centre of pressure margin in the triangle of its other three feet
/// (their centres in the ground truth) as the unloading of `step`'s foot starts, and the
/// least share of the weight one of them carries there.
fn cop_at_unload(walk: &Walk, truth: &[&GroundTruth], i: usize, step: &Step) -> Option<(f64, f64)> {
    let id = &walk.robots[i];
    let start = step.liftoff - walk.gait.params().t_unload;
    let g = truth.iter().rev().find(|g| g.time <= start)?;
    let tri: Vec<Vector2<f64>> = (0..walk.feet[i].len())
        .filter(|f| *f != step.foot)
        .filter_map(|f| g.feet.iter().find(|b| b.name == format!("{id}/{}", walk.feet[i][f])))
        .map(|b| Vector2::new(b.pose.position[0], b.pose.position[1]))
        .collect();
    let [a, b, c] = tri.as_slice() else { return None };
    let (cop, tri) = (measured_cop(g, id)?, [*a, *b, *c]);
    let share =
        planner::gait::support::shares(&cop, &tri).into_iter().fold(f64::INFINITY, f64::min);
    Some((planner::gait::support::margin(&cop, &tri), share))
}

/// The longest time any foot of robot `i` was off the ground during the swing of another
/// of its feet (from `MIN_AIRBORNE` after the lift-off to the landing set), s.
fn stance_lift(
    walk: &Walk,
    truth: &[&GroundTruth],
    times: &[f64],
    i: usize,
    planned: &[&Step],
) -> f64 {
    let window = walk.gait.params().touchdown_window;
    // The foot in mid-swing at each sample (one swings at a time): O(samples + steps).
    let mut swinging_foot: Vec<Option<usize>> = vec![None; times.len()];
    for s in planned.iter().filter(|s| s.robot == i) {
        let (from, to) = (
            times.partition_point(|t| *t < s.liftoff + MIN_AIRBORNE),
            times.partition_point(|t| *t <= s.touchdown - window),
        );
        swinging_foot[from..to.max(from)].fill(Some(s.foot));
    }
    let mut worst = 0.0_f64;
    for f in 0..walk.feet[i].len() {
        let track = foot_track(
            truth,
            &walk.robots[i],
            &walk.feet[i][f],
            &walk.foot_links[i][f],
            walk.foot_radius[i],
        );
        let mut since: Option<f64> = None;
        for (k, t) in times.iter().enumerate() {
            let swinging = swinging_foot[k].is_some_and(|g| g != f);
            since = if swinging && !track.contact[k] { Some(since.unwrap_or(*t)) } else { None };
            if let Some(t0) = since {
                worst = worst.max(t - t0);
            }
        }
    }
    worst
}

/// The walk's report from the run's ground truth (scenario samples, in time order), for a
/// walk halted at `halted_at` (s) if the team let go, judged `until` the run's end (s) if it
/// ended early (an error): the steps planned are then those that landed by then, and each
/// torso's goal its planned pose then.
pub fn evaluate(
    walk: &Walk,
    truth: &[&GroundTruth],
    halted_at: Option<f64>,
    until: Option<f64>,
) -> WalkReport {
    let times: Vec<f64> = truth.iter().map(|g| g.time).collect();
    let (end, landed_by) = (halted_at.unwrap_or(f64::INFINITY), until.unwrap_or(f64::INFINITY));
    let planned: Vec<&Step> =
        walk.gait.steps().iter().filter(|s| s.liftoff < end && s.touchdown <= landed_by).collect();
    let least_margin_m = planned.iter().map(|s| s.margin).fold(f64::INFINITY, f64::min);
    let mut rep = WalkReport {
        touchdown_offset_ms: [f64::INFINITY, f64::NEG_INFINITY],
        least_margin_m,
        halted_at_s: halted_at,
        ..WalkReport::default()
    };
    for (i, id) in walk.robots.iter().enumerate() {
        rep.steps_planned.insert(id.clone(), planned.iter().filter(|s| s.robot == i).count());
        let (mut taken, mut slide) = (0, 0.0_f64);
        for (frame, link) in walk.feet[i].iter().zip(&walk.foot_links[i]) {
            let track = foot_track(truth, id, frame, link, walk.foot_radius[i]);
            taken += steps(&times, &track.contact);
            slide = slide.max(stance_slide(&times, &track));
        }
        rep.steps_taken.insert(id.clone(), taken);
        let measured: Vec<(f64, f64)> = planned
            .iter()
            .filter(|s| s.robot == i)
            .filter_map(|s| cop_at_unload(walk, truth, i, s))
            .collect();
        let cop = measured.iter().map(|m| m.0).fold(f64::INFINITY, f64::min);
        if cop.is_finite() {
            rep.cop_margin_m.insert(id.clone(), cop);
            rep.cop_share
                .insert(id.clone(), measured.iter().map(|m| m.1).fold(f64::INFINITY, f64::min));
            rep.stance_lift_ms
                .insert(id.clone(), 1e3 * stance_lift(walk, truth, &times, i, &planned));
        }
        for dt in touchdown_offsets(walk, truth, &times, i, &planned) {
            let o = &mut rep.touchdown_offset_ms;
            (o[0], o[1]) = (o[0].min(dt), o[1].max(dt));
        }
        rep.stance_slide_m.insert(id.clone(), slide);
        let goal_at = halted_at.into_iter().chain(until).reduce(f64::min);
        if let Some((m, deg)) = final_torso_error(walk, truth, i, goal_at) {
            rep.final_torso_m.insert(id.clone(), m);
            rep.final_torso_deg.insert(id.clone(), deg);
        }
    }
    rep
}

/// Each landing of robot `i`'s `planned` steps: its first ground contact minus its planned
/// touchdown, ms (steps that never landed are left out).
fn touchdown_offsets(
    walk: &Walk,
    truth: &[&GroundTruth],
    times: &[f64],
    i: usize,
    planned: &[&Step],
) -> Vec<f64> {
    let id = &walk.robots[i];
    planned
        .iter()
        .filter(|s| s.robot == i)
        .filter_map(|s| {
            let (frame, link) = (&walk.feet[i][s.foot], &walk.foot_links[i][s.foot]);
            let track = foot_track(truth, id, frame, link, walk.foot_radius[i]);
            first_contact_after(times, &track.contact, s.liftoff).map(|t| 1e3 * (t - s.touchdown))
        })
        .collect()
}

/// Walking robot `i`'s torso at the end of the run against its goal (the gait's final pose,
/// or its pose at `goal_at`, where the walk halted or the run ended early): position error,
/// m, and angle error, deg.
fn final_torso_error(
    walk: &Walk,
    truth: &[&GroundTruth],
    i: usize,
    goal_at: Option<f64>,
) -> Option<(f64, f64)> {
    let id = &walk.robots[i];
    let last = truth.last().and_then(|g| g.torsos.iter().find(|b| &b.name == id));
    let (true, Some(b)) = (walk.walking[i], last) else { return None };
    let goal = goal_at.map_or(walk.gait.final_torso(i), |t| walk.gait.torso(i, t).0);
    let at = Isometry3::from_parts(
        Translation3::from(Vector3::from(b.pose.position)),
        protocol::conventions::quat_from_wxyz(b.pose.orientation),
    );
    Some((
        (at.translation.vector - goal.translation.vector).norm(),
        metrics::geodesic_angle(&at.rotation, &goal.rotation).to_degrees(),
    ))
}

/// The acceptance checks of a walk: every planned step taken (and no other), stance feet
/// that stay put, torsos that end at their goals. `(name, value, bound)`, passed when
/// `value < bound`.
pub fn checks(rep: &WalkReport) -> Vec<(String, f64, f64)> {
    let mut out = Vec::new();
    for (r, planned) in &rep.steps_planned {
        let taken = rep.steps_taken.get(r).copied().unwrap_or(0);
        out.push((
            format!("{r} steps taken minus planned ({taken} of {planned})"),
            (taken as f64 - *planned as f64).abs(),
            0.5,
        ));
    }
    for (r, s) in &rep.stance_slide_m {
        out.push((format!("{r} stance foot slide [m]"), *s, MAX_STANCE_SLIDE));
    }
    for (r, e) in &rep.final_torso_m {
        out.push((format!("{r} final torso position error [m]"), *e, MAX_FINAL_TORSO_POSITION));
    }
    for (r, e) in &rep.final_torso_deg {
        out.push((format!("{r} final torso angle error [deg]"), *e, MAX_FINAL_TORSO_ANGLE_DEG));
    }
    out
}
