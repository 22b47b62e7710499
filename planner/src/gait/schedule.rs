//! The timed crawl: waypoints to gait cycles and steps ([`GaitPlan::new`]), and the plan's
//! queries at any time (torso, object and swing-foot references, unloading ramps, planned
//! stance, contact changes).
//!
//! Segment `k` (waypoint `k` to `k + 1`) takes `N_k` cycles, the same for every robot: the
//! fewest with every foot moving at most `stride` per step and the torso turning at most
//! `max_turn_deg` per cycle. A cycle steps each foot once, in the order that needs the least
//! CoM shift for the segment's motion (forward: hind-left, front-left, hind-right, front-right,
//! the crawl; backwards the front feet lead; feet told apart by where each is in the torso
//! frame at the start). Each step: the torso
//! shifts (quintic blend, `t_shift`) to the path's next quarter cycle plus the shift that puts
//! the centre of pressure `margin` inside the other three feet's triangle (the robot's weight
//! and the load in its hand, [`super::support::centre_of_pressure`]); the foot is unloaded
//! (`t_unload`, its normal force bounded by a ramp to zero), swings (`t_swing`) to where the
//! path puts it at the end of the cycle, pressing `touchdown_depth` below it, and is loaded
//! again (`t_load`). A last shift brings each torso to its last waypoint.

use nalgebra::{Isometry3, Translation3, Vector2, Vector3};

use super::support::{along, centre_of_pressure, incentre, least_shift, margin, HandLoad};
use super::swing::{quintic, swing};
use super::{GaitError, GaitParams, ShiftRule, WalkingRobot};

/// A planned step: `robot`'s `foot` (description index) from `from` to `to` (foot centres),
/// lifting off at `liftoff` and touching down at `touchdown` (scenario time, s), with the
/// planned centre of pressure `margin` m inside the support triangle at lift-off.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    pub robot: usize,
    pub foot: usize,
    pub liftoff: f64,
    pub touchdown: f64,
    pub from: Vector3<f64>,
    pub to: Vector3<f64>,
    pub margin: f64,
    /// The planned centre of pressure's margin with the hand's load (`WalkingRobot::hand`)
    /// whether or not the planner kept it (`GaitParams::hand_load`); `None` without a load.
    pub cop_margin: Option<f64>,
}

/// A planned pose: pose, twist and acceleration (world, `[linear; angular]`).
pub type PlannedPose = (Isometry3<f64>, [f64; 6], [f64; 6]);
/// A planned point: position, velocity and acceleration (world).
pub type PlannedPoint = (Vector3<f64>, [f64; 3], [f64; 3]);

/// A blend from `from` to `to` over `[t0, t1]`.
#[derive(Debug, Clone)]
struct Move {
    t0: f64,
    t1: f64,
    from: Isometry3<f64>,
    to: Isometry3<f64>,
}

/// A pose over time: its start, then moves in time order (holding between them).
#[derive(Debug, Clone)]
struct Track {
    start: Isometry3<f64>,
    moves: Vec<Move>,
}

impl Track {
    fn current(&self) -> Isometry3<f64> {
        self.moves.last().map_or(self.start, |m| m.to)
    }

    fn push(&mut self, t0: f64, t1: f64, to: Isometry3<f64>) {
        let from = self.current();
        self.moves.push(Move { t0, t1, from, to });
    }

    fn at(&self, t: f64) -> PlannedPose {
        let k = self.moves.partition_point(|m| m.t0 <= t);
        let Some(m) = k.checked_sub(1).map(|k| &self.moves[k]) else {
            return (self.start, [0.0; 6], [0.0; 6]);
        };
        let dur = m.t1 - m.t0;
        let (s, ds, dds) = quintic((t - m.t0) / dur);
        let dp = m.to.translation.vector - m.from.translation.vector;
        let w = (m.to.rotation * m.from.rotation.inverse()).scaled_axis();
        let pose = Isometry3::from_parts(
            Translation3::from(m.from.translation.vector + dp * s),
            nalgebra::UnitQuaternion::from_scaled_axis(w * s) * m.from.rotation,
        );
        let (v, om) = (dp * (ds / dur), w * (ds / dur));
        let (a, al) = (dp * (dds / (dur * dur)), w * (dds / (dur * dur)));
        (pose, [v.x, v.y, v.z, om.x, om.y, om.z], [a.x, a.y, a.z, al.x, al.y, al.z])
    }
}

/// Waypoint interpolation: translation linear, rotation slerp.
fn interp(a: &Isometry3<f64>, b: &Isometry3<f64>, p: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(a.translation.vector.lerp(&b.translation.vector, p)),
        a.rotation.slerp(&b.rotation, p),
    )
}

/// The plan (see the module docs).
#[derive(Debug, Clone)]
pub struct GaitPlan {
    params: GaitParams,
    torsos: Vec<Track>,
    object: Option<Track>,
    steps: Vec<Step>,
    /// Per robot, per foot: its steps' indices in time order.
    swings: Vec<Vec<Vec<usize>>>,
    finals: Vec<Isometry3<f64>>,
    end: f64,
}

/// The feet in crawl order (hind-left, front-left, hind-right, front-right) from their offsets
/// in the torso frame.
fn crawl_order(r: &WalkingRobot, offsets: &[Vector3<f64>]) -> Result<[usize; 4], GaitError> {
    let bad = |reason: String| GaitError::Robot { robot: r.robot.clone(), reason };
    if offsets.len() != 4 {
        return Err(bad(format!("a crawl needs 4 feet, the robot has {}", offsets.len())));
    }
    let find = |front: bool, left: bool| {
        let mut it =
            offsets.iter().enumerate().filter(|(_, o)| (o.x > 0.0) == front && (o.y > 0.0) == left);
        match (it.next(), it.next()) {
            (Some((k, _)), None) => Ok(k),
            _ => Err(bad(format!(
                "no single {} {} foot in the torso frame",
                if front { "front" } else { "hind" },
                if left { "left" } else { "right" }
            ))),
        }
    };
    Ok([find(false, true)?, find(true, true)?, find(false, false)?, find(true, false)?])
}

/// Cycles of segment `k`: the fewest keeping every foot's step within `stride` and the turn
/// within `max_turn_deg` per cycle, over all robots (0 when nobody moves).
fn cycles(
    robots: &[WalkingRobot],
    offsets: &[Vec<Vector3<f64>>],
    k: usize,
    p: &GaitParams,
) -> usize {
    let mut n: f64 = 0.0;
    for (r, off) in robots.iter().zip(offsets) {
        let (a, b) = (&r.waypoints[k], &r.waypoints[k + 1]);
        let foot = off
            .iter()
            .map(|o| {
                ((b * nalgebra::Point3::from(*o)) - (a * nalgebra::Point3::from(*o))).xy().norm()
            })
            .fold(0.0, f64::max);
        let turn = a.rotation.angle_to(&b.rotation).to_degrees();
        if foot > 1e-9 || turn > 1e-9 {
            // A step of exactly `stride` is one step, whatever the rounding.
            n = n.max(((foot / p.stride).max(turn / p.max_turn_deg) - 1e-9).ceil().max(1.0));
        }
    }
    n as usize
}

fn check(robots: &[WalkingRobot], object: Option<&[Isometry3<f64>]>) -> Result<usize, GaitError> {
    let count = robots.first().map_or(0, |r| r.waypoints.len());
    for r in robots {
        let bad = |reason: String| GaitError::Robot { robot: r.robot.clone(), reason };
        if r.waypoints.is_empty() || r.waypoints.len() != count {
            return Err(bad(format!(
                "{} waypoints, the first robot has {count} (at least the start)",
                r.waypoints.len()
            )));
        }
        let finite = r.waypoints.iter().all(|w| {
            w.translation.vector.iter().chain(r.com_offset.iter()).all(|x| x.is_finite())
                && w.rotation.coords.iter().all(|x| x.is_finite())
        });
        if !finite
            || r.feet.iter().any(|(_, p)| p.iter().any(|x| !x.is_finite()))
            || !r.ground_z.is_finite()
            || r.hand.is_some_and(|h| !h.is_finite())
        {
            return Err(bad(
                "a non-finite waypoint, foot, centre of mass, ground height or hand load".into(),
            ));
        }
        if !(r.mass.is_finite() && r.mass > 0.0) {
            return Err(bad(format!("mass {} kg must be positive", r.mass)));
        }
        // The feet must carry some weight wherever the object takes the hand's load.
        let object_at = |k: usize| {
            object.map_or(Isometry3::identity(), |o| {
                o[k.min(o.len().saturating_sub(1))] * o[0].inverse()
            })
        };
        for k in 0..count {
            let load = r.hand.map(|h| h.moved(&object_at(k)));
            let com = r.waypoints[k] * nalgebra::Point3::from(r.com_offset);
            if centre_of_pressure(r.mass, &com.coords, load.as_ref(), r.ground_z).is_none() {
                return Err(bad(format!(
                    "its hand's load {:?} N lifts it off its feet at waypoint {k}",
                    load.map(|l| l.force)
                )));
            }
        }
    }
    match object {
        Some(o) if o.len() != count => {
            Err(GaitError::ObjectWaypoints { expected: count, got: o.len() })
        }
        _ => Ok(count),
    }
}

/// The plan being built: the clock, each robot's feet where they stand now, the tracks.
struct Builder<'a> {
    robots: &'a [WalkingRobot],
    object: Option<&'a [Isometry3<f64>]>,
    p: &'a GaitParams,
    offsets: Vec<Vec<Vector3<f64>>>,
    /// Each robot's crawl order, and the order of the current segment.
    crawl: Vec<[usize; 4]>,
    order: Vec<[usize; 4]>,
    feet: Vec<Vec<Vector3<f64>>>,
    t: f64,
    torsos: Vec<Track>,
    object_track: Option<Track>,
    steps: Vec<Step>,
}

/// Where one step of a robot goes: the torso's target (the path's pose plus the shift), the
/// foothold, the shift and the centre of pressure's margin at lift-off.
struct Placement {
    target: Isometry3<f64>,
    to: Vector3<f64>,
    shift: f64,
    margin: f64,
    cop_margin: Option<f64>,
}

/// Where the path is: segment `k` (waypoint `k` to `k + 1`), `progress` of the way for the
/// torso and the object, `cycle_end` for the foothold.
#[derive(Clone, Copy)]
struct PathAt {
    k: usize,
    progress: f64,
    cycle_end: f64,
}

/// The hand's load of `r` with the object where the path puts it (`object`: its waypoints
/// when it moves with the team; else it holds where it started).
fn hand_load(r: &WalkingRobot, object: Option<&[Isometry3<f64>]>, at: PathAt) -> Option<HandLoad> {
    let h = r.hand?;
    Some(match object {
        Some(o) => h.moved(&(interp(&o[at.k], &o[at.k + 1], at.progress) * o[0].inverse())),
        None => h,
    })
}

/// Robot `r`'s step of `foot` with its feet at `feet`, the path at `at`; `None` when no shift
/// reaches the margin. The torso is shifted (towards the incentre of the other three feet, or
/// by the shortest shift: [`GaitParams::shift`]) until both the centre of mass and the centre
/// of pressure (its weight and the hand's load, which stays on the object) are `margin` inside
/// with every foot carrying `min_share`: the CoM so that the robot stands if the team lets go
/// mid-step, the centre of pressure while it holds. The reported margin is the lesser.
fn place(
    r: &WalkingRobot,
    offsets: &[Vector3<f64>],
    feet: &[Vector3<f64>],
    foot: usize,
    at: PathAt,
    object: Option<&[Isometry3<f64>]>,
    p: &GaitParams,
) -> Option<Placement> {
    let (a, b) = (&r.waypoints[at.k], &r.waypoints[at.k + 1]);
    let nominal = interp(a, b, at.progress);
    let mut to = interp(a, b, at.cycle_end) * nalgebra::Point3::from(offsets[foot]);
    to.z = r.feet[foot].1.z;
    let others: Vec<Vector2<f64>> = (0..4).filter(|f| *f != foot).map(|f| feet[f].xy()).collect();
    let tri = [others[0], others[1], others[2]];
    let com = (nominal * nalgebra::Point3::from(r.com_offset)).coords;
    let real = hand_load(r, object, at);
    let load = if p.hand_load { real } else { None };
    let (cop, gain) = centre_of_pressure(r.mass, &com, load.as_ref(), r.ground_z)?;
    // A shift `d` moves the CoM by that, the centre of pressure `gain` times as far.
    let d = match p.shift {
        ShiftRule::Incentre => {
            let dir = incentre(&tri).0 - com.xy();
            let (lo_com, hi_com) = along(&com.xy(), &dir, &tri, p.margin, p.min_share)?;
            let (lo_cop, hi_cop) = along(&cop, &(gain * dir), &tri, p.margin, p.min_share)?;
            let alpha = lo_com.max(lo_cop);
            if alpha > hi_com.min(hi_cop) {
                return None;
            }
            alpha * dir
        }
        ShiftRule::Least => {
            least_shift(&[(com.xy(), 1.0), (cop, gain)], &tri, p.margin, p.min_share)?
        }
    };
    let least = margin(&(com.xy() + d), &tri).min(margin(&(cop + gain * d), &tri));
    let shifted = com + Vector3::new(d.x, d.y, 0.0);
    let cop_margin = real
        .and_then(|l| centre_of_pressure(r.mass, &shifted, Some(&l), r.ground_z))
        .map(|(c, _)| margin(&c, &tri));
    Some(Placement {
        target: Translation3::new(d.x, d.y, 0.0) * nominal,
        to: to.coords,
        shift: d.norm(),
        margin: least,
        cop_margin,
    })
}

/// The foot order of robot `i` in segment `k` (`n` cycles): of the 24, the one whose first
/// cycle needs the least total torso shift (walking backwards, the front feet lead; sideways,
/// the feet away from the motion), the crawl order on a tie; `None` when none reaches the margin.
#[allow(clippy::too_many_arguments)]
fn best_order(
    r: &WalkingRobot,
    offsets: &[Vector3<f64>],
    feet: &[Vector3<f64>],
    crawl: [usize; 4],
    k: usize,
    n: usize,
    object: Option<&[Isometry3<f64>]>,
    p: &GaitParams,
) -> Option<[usize; 4]> {
    let mut best: Option<([usize; 4], f64)> = None;
    for perm in permutations(crawl) {
        let mut now = feet.to_vec();
        let mut total = 0.0;
        for (j, &foot) in perm.iter().enumerate() {
            let at =
                PathAt { k, progress: (j + 1) as f64 / 4.0 / n as f64, cycle_end: 1.0 / n as f64 };
            let Some(pl) = place(r, offsets, &now, foot, at, object, p) else {
                total = f64::INFINITY;
                break;
            };
            total += pl.shift;
            now[foot] = pl.to;
        }
        if total.is_finite() && best.is_none_or(|(_, b)| total < b - 1e-9) {
            best = Some((perm, total));
        }
    }
    best.map(|(o, _)| o)
}

/// The 24 orders of four feet, starting with `first` itself.
fn permutations(first: [usize; 4]) -> Vec<[usize; 4]> {
    let mut out = Vec::with_capacity(24);
    for a in 0..4 {
        for b in (0..4).filter(|b| *b != a) {
            for c in (0..4).filter(|c| *c != a && *c != b) {
                let d = 6 - a - b - c;
                out.push([first[a], first[b], first[c], first[d]]);
            }
        }
    }
    out
}

impl Builder<'_> {
    /// Each moving robot's foot order for segment `k` of `n` cycles ([`best_order`]).
    fn choose_orders(&mut self, k: usize, n: usize) {
        for (i, r) in self.robots.iter().enumerate() {
            if r.waypoints[k] == r.waypoints[k + 1] {
                continue;
            }
            match best_order(
                r,
                &self.offsets[i],
                &self.feet[i],
                self.crawl[i],
                k,
                n,
                self.object,
                self.p,
            ) {
                Some(o) => self.order[i] = o,
                None => self.order[i] = self.crawl[i],
            }
        }
    }

    /// The crawl's cycles along each of the `count - 1` segments between the waypoints.
    fn walk_segments(&mut self, count: usize) -> Result<(), GaitError> {
        for k in 0..count.saturating_sub(1) {
            let n = cycles(self.robots, &self.offsets, k, self.p);
            if n > 0 {
                self.choose_orders(k, n);
            }
            for c in 0..n {
                for j in 0..4 {
                    self.step(k, c, j, n)?;
                }
            }
        }
        Ok(())
    }

    /// Step `j` of cycle `c` of `n` in segment `k`: shift, unload, swing, load.
    fn step(&mut self, k: usize, c: usize, j: usize, n: usize) -> Result<(), GaitError> {
        let at = PathAt {
            k,
            progress: (c as f64 + (j + 1) as f64 / 4.0) / n as f64,
            cycle_end: (c + 1) as f64 / n as f64,
        };
        let (t_shift_end, liftoff) =
            (self.t + self.p.t_shift, self.t + self.p.t_shift + self.p.t_unload);
        let touchdown = liftoff + self.p.t_swing;
        for (i, r) in self.robots.iter().enumerate() {
            if r.waypoints[k] == r.waypoints[k + 1] {
                continue;
            }
            let foot = self.order[i][j];
            let Some(pl) = place(r, &self.offsets[i], &self.feet[i], foot, at, self.object, self.p)
            else {
                let others: Vec<Vector2<f64>> =
                    (0..4).filter(|f| *f != foot).map(|f| self.feet[i][f].xy()).collect();
                let inradius = super::support::incentre(&[others[0], others[1], others[2]]).1;
                return Err(GaitError::Margin {
                    robot: r.robot.clone(),
                    step: self.steps.len(),
                    foot: r.feet[foot].0.clone(),
                    margin: self.p.margin,
                    min_share: self.p.min_share,
                    inradius,
                });
            };
            self.torsos[i].push(self.t, t_shift_end, pl.target);
            self.steps.push(Step {
                robot: i,
                foot,
                liftoff,
                touchdown,
                from: self.feet[i][foot],
                to: pl.to,
                margin: pl.margin,
                cop_margin: pl.cop_margin,
            });
            self.feet[i][foot] = pl.to;
        }
        if let (Some(track), Some(o)) = (self.object_track.as_mut(), self.object) {
            track.push(self.t, t_shift_end, interp(&o[k], &o[k + 1], at.progress));
        }
        self.t = touchdown + self.p.t_load;
        Ok(())
    }

    /// The last shift: every torso to its last waypoint, the object to its own.
    fn finish(&mut self) -> f64 {
        let end = self.t + self.p.t_shift;
        for (track, r) in self.torsos.iter_mut().zip(self.robots) {
            let last = *r.waypoints.last().expect("checked: at least the start");
            if track.current() != last {
                track.push(self.t, end, last);
            }
        }
        if let (Some(track), Some(o)) = (self.object_track.as_mut(), self.object) {
            track.push(self.t, end, *o.last().expect("checked"));
        }
        end
    }
}

/// Each robot's foot positions in the frame of its torso's first waypoint.
fn foot_offsets(robots: &[WalkingRobot]) -> Vec<Vec<Vector3<f64>>> {
    robots
        .iter()
        .map(|r| {
            r.feet
                .iter()
                .map(|(_, p)| r.waypoints[0].inverse_transform_point(&(*p).into()).coords)
                .collect()
        })
        .collect()
}

/// The indices into `steps` of each robot's (of `n`) four feet's swings, in time order.
fn swings_by_foot(steps: &[Step], n: usize) -> Vec<Vec<Vec<usize>>> {
    let mut swings = vec![vec![Vec::new(); 4]; n];
    for (s, step) in steps.iter().enumerate() {
        swings[step.robot][step.foot].push(s);
    }
    swings
}

/// How long before a lift-off a release still halts a walk at once, s
/// ([`GaitPlan::halt_point`]): the release's way from the coordinator through the scenario
/// driver to the agents, with room for a loaded machine (a few ticks in the runs measured).
pub const HALT_GUARD: f64 = 0.05;

impl GaitPlan {
    /// The crawl of `robots` along their waypoints (and the object's, moved with the same
    /// progress), starting at `t0` (scenario time, s).
    pub fn new(
        robots: &[WalkingRobot],
        object: Option<&[Isometry3<f64>]>,
        params: &GaitParams,
        t0: f64,
    ) -> Result<GaitPlan, GaitError> {
        params.check()?;
        let count = check(robots, object)?;
        let offsets = foot_offsets(robots);
        let order = robots
            .iter()
            .zip(&offsets)
            .map(|(r, o)| crawl_order(r, o))
            .collect::<Result<Vec<_>, _>>()?;
        let mut b = Builder {
            robots,
            object,
            p: params,
            feet: robots.iter().map(|r| r.feet.iter().map(|(_, p)| *p).collect()).collect(),
            offsets,
            crawl: order.clone(),
            order,
            t: t0,
            torsos: robots
                .iter()
                .map(|r| Track { start: r.waypoints[0], moves: Vec::new() })
                .collect(),
            object_track: object.map(|o| Track { start: o[0], moves: Vec::new() }),
            steps: Vec::new(),
        };
        b.walk_segments(count)?;
        let end = b.finish();
        let swings = swings_by_foot(&b.steps, robots.len());
        let finals = robots.iter().map(|r| *r.waypoints.last().expect("checked")).collect();
        Ok(GaitPlan {
            params: params.clone(),
            torsos: b.torsos,
            object: b.object_track,
            steps: b.steps,
            swings,
            finals,
            end,
        })
    }

    pub fn params(&self) -> &GaitParams {
        &self.params
    }

    /// Every step, in time order.
    pub fn steps(&self) -> &[Step] {
        &self.steps
    }

    /// When the last torso reaches its last waypoint, s.
    pub fn end_time(&self) -> f64 {
        self.end
    }

    /// Robot `i`'s last waypoint.
    pub fn final_torso(&self, i: usize) -> Isometry3<f64> {
        self.finals[i]
    }

    /// Robot `i`'s torso target at `t`.
    pub fn torso(&self, i: usize, t: f64) -> PlannedPose {
        self.torsos[i].at(t)
    }

    /// The object's target at `t`, when the plan moves it.
    pub fn object(&self, t: f64) -> Option<PlannedPose> {
        self.object.as_ref().map(|o| o.at(t))
    }

    /// The step of robot `i`'s foot `k` that lifted off last at or before `t`.
    fn last_step(&self, i: usize, k: usize, t: f64) -> Option<&Step> {
        let list = self.swings.get(i)?.get(k)?;
        let n = list.partition_point(|&s| self.steps[s].liftoff <= t);
        n.checked_sub(1).map(|n| &self.steps[list[n]])
    }

    /// Robot `i`'s foot `k` target at `t`, from its first lift-off on: the swing, then the
    /// pressed touchdown point at rest (for a foot that lands late).
    pub fn swing_foot(&self, i: usize, k: usize, t: f64) -> Option<PlannedPoint> {
        let s = self.last_step(i, k, t)?;
        let pressed = s.to - Vector3::z() * self.params.touchdown_depth;
        if t >= s.touchdown {
            return Some((pressed, [0.0; 3], [0.0; 3]));
        }
        let (p, v, a) = swing(
            &s.from,
            &pressed,
            self.params.lift_height,
            s.touchdown - s.liftoff,
            t - s.liftoff,
        );
        Some((p, v.into(), a.into()))
    }

    /// Where robot `i`'s foot `k` is planned at `t`: on its swing while it swings, where it
    /// landed once down (the contact point's frame, not pressed); `None` before its first
    /// lift-off (it stands where it started) and for a foot that never steps.
    pub fn foot_position(&self, i: usize, k: usize, t: f64) -> Option<Vector3<f64>> {
        let s = self.last_step(i, k, t)?;
        if t >= s.touchdown {
            return Some(s.to);
        }
        Some(
            swing(&s.from, &s.to, self.params.lift_height, s.touchdown - s.liftoff, t - s.liftoff)
                .0,
        )
    }

    /// The bound on robot `i`'s foot `k` normal force at `t`: a ramp from `unload_force` to 0
    /// over `t_unload` before each lift-off, and back up over `t_load` after each touchdown.
    pub fn max_normal_force(&self, i: usize, k: usize, t: f64) -> Option<f64> {
        let p = &self.params;
        self.swings.get(i)?.get(k)?.iter().map(|&s| &self.steps[s]).find_map(|s| {
            if (s.liftoff - p.t_unload..s.liftoff).contains(&t) {
                Some(p.unload_force * (s.liftoff - t) / p.t_unload)
            } else if (s.touchdown..s.touchdown + p.t_load).contains(&t) {
                Some(p.unload_force * (t - s.touchdown) / p.t_load)
            } else {
                None
            }
        })
    }

    /// Robot `i`'s planned stance at `t`: a foot is in swing from its lift-off until the
    /// contact set that lands it is due (`touchdown_window` before its touchdown).
    pub fn stance(&self, i: usize, t: f64) -> [bool; 4] {
        let mut out = [true; 4];
        for (k, o) in out.iter_mut().enumerate() {
            *o = !self
                .last_step(i, k, t)
                .is_some_and(|s| t < s.touchdown - self.params.touchdown_window);
        }
        out
    }

    /// The first time at or after `t` when no robot is stepping: every foot down at full load
    /// and every torso at rest. That is `t` itself before the walk, between two steps and after
    /// it; otherwise the end of the step (shift, unload, swing, load) or of the last shift in
    /// progress. A walk halted there stops without cutting a step short.
    pub fn quiet_point(&self, t: f64) -> f64 {
        let p = &self.params;
        let mut at = t;
        // Steps run one after another in time order; one ends where the next one starts.
        for s in &self.steps {
            let (start, end) = (s.liftoff - p.t_unload - p.t_shift, s.touchdown + p.t_load);
            if at > start && at < end {
                at = end;
            }
        }
        if at > self.end - p.t_shift && at < self.end {
            at = self.end;
        }
        at
    }

    /// When a walk halts for a release at `t` (the runner's `ReferencePlan::halt_walk`): at
    /// once while the step in progress is still [`HALT_GUARD`] or more from lifting its foot
    /// (its torso shift or its foot's unloading: the step is cancelled with every foot still
    /// down), else at the [`GaitPlan::quiet_point`] (a lifted foot lands first). The guard
    /// covers the time the release takes to reach the agents, whose lift-offs were sent ahead:
    /// a lift-off due before the halt arrives would still happen.
    pub fn halt_point(&self, t: f64) -> f64 {
        let p = &self.params;
        if self
            .steps
            .iter()
            .any(|s| t > s.liftoff - p.t_unload - p.t_shift && t + HALT_GUARD < s.liftoff)
        {
            t
        } else {
            self.quiet_point(t)
        }
    }

    /// Where robot `i`'s foot `k` stands after a halt at `t_h` ([`GaitPlan::halt_point`]), at
    /// rest: its last step's pressed landing point, or, for a foot whose first step the halt
    /// cancelled, its start pressed. A foot that lifted anyway (a lift-off the halt did not
    /// reach in time) is brought back down there. `None` for a foot that never steps.
    pub fn foot_after_halt(&self, i: usize, k: usize, t_h: f64) -> Option<PlannedPoint> {
        let down = Vector3::z() * self.params.touchdown_depth;
        if let Some((p, _, _)) = self.swing_foot(i, k, t_h) {
            return Some((p, [0.0; 3], [0.0; 3]));
        }
        let first = self.swings.get(i)?.get(k)?.first().map(|&s| &self.steps[s])?;
        Some((first.from - down, [0.0; 3], [0.0; 3]))
    }

    /// The bound on robot `i`'s foot `k` normal force at `t` after a halt at `t_h`
    /// ([`GaitPlan::halt_point`]): an unloading cut short at `t_h` is undone at the load ramp's
    /// rate (`unload_force` over `t_load`); `None` once back at full load, and for a foot that
    /// was not unloading at `t_h`.
    pub fn max_normal_force_after_halt(&self, i: usize, k: usize, t_h: f64, t: f64) -> Option<f64> {
        let p = &self.params;
        let f = self.max_normal_force(i, k, t_h)? + p.unload_force * (t - t_h).max(0.0) / p.t_load;
        (f < p.unload_force).then_some(f)
    }

    /// Every change of a robot's planned stance: `(time, robot, stance)`, in time order.
    pub fn contact_changes(&self) -> Vec<(f64, usize, [bool; 4])> {
        let mut out = Vec::with_capacity(2 * self.steps.len());
        for s in &self.steps {
            let mut lifted = [true; 4];
            lifted[s.foot] = false;
            out.push((s.liftoff, s.robot, lifted));
            out.push((s.touchdown - self.params.touchdown_window, s.robot, [true; 4]));
        }
        out.sort_by(|a, b| a.0.total_cmp(&b.0));
        out
    }
}
