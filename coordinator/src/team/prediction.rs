//! The state a delayed command meets (a Smith predictor).
//!
//! With the team's delay `d` the command answering the state of tick k applies at tick k + d
//! (`protocol::TorqueCommand::delay_ticks`). The commands of the ticks before it are still in
//! flight, and they act first: a loop that damps the state of tick k with a torque applied at
//! k + d is stable only for `D dt / I < 2 sin(pi / (2 (2d + 1)))` (1.0, 0.62, 0.45 for d = 1,
//! 2, 3), and S1's object damping sits at 1.0 already. The coordinator sent those commands and
//! knows what they accelerate (the controller's model, with the held object as a rigid body:
//! `crate::pidc::stages::acceleration`), so before a tick is solved each robot's measured
//! velocity is carried over the robot periods `k .. k + d - 1`:
//!
//! ```text
//! v(k + d) = v(k) + dt * sum_{t = k}^{k + d - 1} qdd(the command applying at t)
//! ```
//!
//! The command applying at robot tick t is the newest solved at a tick s with
//! `s + delay(s) <= t`; between team ticks (`team_hz` below the robots' rate) a robot keeps it.
//! Each frame's pose follows, as the simulator integrates (semi-implicit Euler: the velocity
//! first, then the pose with the new velocity), by its Jacobian at the measured state:
//!
//! ```text
//! p += dt J_lin v,   R = exp(dt J_ang v) R        (world-aligned rows [linear; angular])
//! ```
//!
//! The velocity is what a damping loop acts on, and what a delay destabilises; the poses take
//! out the lag, with the task references of tick k + d (the coordinator solves the tick with
//! them, `crate::service`). `M`, `h`, the Jacobians and `Jdot v` stay the measured ones: over a
//! few robot periods they change far less than the state.
//!
//! Hold orders and ticks not solved apply too, and carry nothing. A late member's reused
//! terms are carried from the state they came from (`state_tick`). The accelerations are
//! computed only while a delay is in use, so the first d ticks after a delay is first raised
//! (`auto`) carry nothing; and a command an agent already holds when the delay rises applies
//! later than its own delay says (the agent follows the newest command's delay).
//!
//! Each robot keeps the accelerations of its last [`SOLVES_KEPT`] solved ticks in slots
//! allocated when it is first seen; predicting and recording allocate nothing after that.

use std::collections::BTreeMap;

use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use protocol::{DynamicsTerms, FrameRole, Pose, MAX_TEAM_DELAY_TICKS};

use protocol::conventions::{quat_from_wxyz, quat_to_wxyz, rotation_from_row_major};

use crate::linalg::dot;
use crate::TeamController;

/// Solved ticks kept per robot: enough to find the command applying at every tick of the
/// longest delay, whatever the team's rate.
pub const SOLVES_KEPT: usize = MAX_TEAM_DELAY_TICKS as usize + 2;

/// A command older than this many robot ticks is not carried: a robot that waited that long
/// for its next one was holding its posture, not following it.
pub const OLDEST_CARRIED: u64 = 64;

/// The delay of a slot that holds no solved tick yet.
const NEVER: u64 = u64::MAX;

/// One solved tick's accelerations of a robot (`delay` [`NEVER`] for a slot not yet used).
#[derive(Debug, Clone)]
struct Slot {
    tick: u64,
    delay: u64,
    qdd: Vec<f64>,
}

/// A robot's last solved ticks, a ring in solving order.
#[derive(Debug, Clone)]
struct Solves {
    slots: Vec<Slot>,
    next: usize,
}

/// The accelerations of each robot's last solved ticks, and the prediction from them.
#[derive(Debug, Clone)]
pub struct DelayPredictor {
    period: f64,
    robots: BTreeMap<String, Solves>,
}

impl DelayPredictor {
    /// For robots ticking at `robot_hz` (finite and positive, checked by the caller).
    pub fn new(robot_hz: f64) -> Self {
        DelayPredictor { period: 1.0 / robot_hz, robots: BTreeMap::new() }
    }

    /// Before `tick` is solved with the delay `delay`: each robot's velocity and frame poses
    /// in `terms` carried over the commands in flight (module docs). A robot without them (the
    /// team's first ticks, a robot just joined) keeps its measured velocity for those periods,
    /// and its frames move with it.
    pub fn predict(&self, tick: u64, delay: u64, terms: &mut [DynamicsTerms]) {
        for t in terms.iter_mut() {
            let solves = self.robots.get(t.header.robot_id());
            // A late member's reused terms are of an older state: carried from there.
            let from = t.state_tick.clamp(tick.saturating_sub(OLDEST_CARRIED), tick);
            for at in from..tick.saturating_add(delay) {
                if let Some(s) = solves
                    .and_then(|r| r.applying_at(at))
                    .filter(|s| s.qdd.len() == t.velocity.len())
                {
                    t.velocity.iter_mut().zip(&s.qdd).for_each(|(v, a)| *v += self.period * a);
                }
                move_frames(t, self.period);
            }
        }
    }

    /// After the commands of `tick` were sent with the delay `delay`: each robot's commanded
    /// accelerations kept, from `controller` when the tick was solved. Without them (hold
    /// orders, a controller that gives none, non-finite values) the command still applies, and
    /// nothing is carried over it.
    pub fn record(
        &mut self,
        tick: u64,
        delay: u64,
        terms: &[DynamicsTerms],
        controller: Option<&dyn TeamController>,
    ) {
        for t in terms {
            let id = t.header.robot_id();
            let slot = self.next_slot(id, t.velocity.len());
            (slot.tick, slot.delay) = (tick, delay);
            if let Some(qdd) = controller
                .and_then(|c| c.accelerations(id))
                .filter(|a| a.len() == t.velocity.len() && a.iter().all(|x| x.is_finite()))
            {
                slot.qdd.extend_from_slice(qdd);
            }
        }
    }

    /// A hold order sent to `robot` for `tick` with the delay `delay` (a robot outside the
    /// team's tick): nothing is carried over the periods it applies in.
    pub fn record_hold(&mut self, robot: &str, tick: u64, delay: u64) {
        if self.robots.contains_key(robot) {
            let slot = self.next_slot(robot, 0);
            (slot.tick, slot.delay) = (tick, delay);
        }
    }

    /// `robot`'s oldest slot, emptied (its ring made on first sight, slots sized for `nv`).
    fn next_slot(&mut self, robot: &str, nv: usize) -> &mut Slot {
        if !self.robots.contains_key(robot) {
            let slot = || Slot { tick: 0, delay: NEVER, qdd: Vec::with_capacity(nv) };
            self.robots.insert(
                robot.to_string(),
                Solves { slots: (0..SOLVES_KEPT).map(|_| slot()).collect(), next: 0 },
            );
        }
        let solves = self.robots.get_mut(robot).expect("inserted above");
        let k = solves.next;
        solves.next = (k + 1) % SOLVES_KEPT;
        let slot = &mut solves.slots[k];
        slot.qdd.clear();
        slot
    }
}

/// Each frame of `t` moved over `dt` with the velocity of `t` (module docs); a frame whose
/// Jacobian does not fit the velocity stays.
fn move_frames(t: &mut DynamicsTerms, dt: f64) {
    let v = &t.velocity;
    for f in &mut t.frames {
        let (rows, nv) = (f.jacobian.rows(), f.jacobian.cols());
        if nv != v.len() || f.jacobian.data.len() != rows * nv || rows < 3 {
            continue;
        }
        let rate = |i: usize| dt * dot(&f.jacobian.data[i * nv..(i + 1) * nv], v);
        let held = f.role == FrameRole::Hand && t.hand_in_grasp && rows >= 6;
        if let Some(object) = t.object_pose.as_mut().filter(|_| held) {
            // A held object moves rigidly with the hand.
            let step = Vector3::new(rate(0), rate(1), rate(2));
            let turn = Vector3::new(rate(3), rate(4), rate(5));
            move_with_hand(object, &Vector3::from(f.position), &step, &turn);
        }
        for i in 0..3 {
            f.position[i] += rate(i);
        }
        if rows >= 6 {
            let r = Rotation3::new(Vector3::new(rate(3), rate(4), rate(5)))
                * rotation_from_row_major(&f.rotation);
            for i in 0..3 {
                for j in 0..3 {
                    f.rotation[3 * i + j] = r[(i, j)];
                }
            }
        }
    }
}

/// `object` carried by a hand at `hand` that moves by `step` and turns by `turn` (a rotation
/// vector, world): the object's centre turns about the hand's point, its axes turn with it.
fn move_with_hand(
    object: &mut Pose,
    hand: &Vector3<f64>,
    step: &Vector3<f64>,
    turn: &Vector3<f64>,
) {
    let r = Rotation3::new(*turn);
    let p = Vector3::from(object.position);
    let moved = hand + step + r * (p - hand);
    let q = UnitQuaternion::from_rotation_matrix(&r) * quat_from_wxyz(object.orientation);
    object.position = moved.into();
    object.orientation = quat_to_wxyz(&q);
}

impl Solves {
    /// The newest command that applies at robot tick `at` (solved at `s`, applying from
    /// `s + delay`), if it is not older than [`OLDEST_CARRIED`]. Its accelerations are empty
    /// when the controller gave none: nothing is carried then.
    fn applying_at(&self, at: u64) -> Option<&Slot> {
        self.slots
            .iter()
            .filter(|s| {
                s.delay != NEVER
                    && s.tick.saturating_add(s.delay) <= at
                    && at - s.tick <= OLDEST_CARRIED
            })
            .max_by_key(|s| s.tick)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ControllerError;
    use protocol::{Header, Matrix, TorqueCommand};

    /// A controller whose every tick commands the accelerations it is told (a test double of
    /// the team's model: what is tested here is which command's accelerations are carried).
    struct Told(BTreeMap<String, Vec<f64>>);

    impl TeamController for Told {
        fn name(&self) -> &'static str {
            "told"
        }
        fn solve(
            &mut self,
            _tick: &[DynamicsTerms],
            _out: &mut Vec<TorqueCommand>,
        ) -> Result<(), ControllerError> {
            Ok(())
        }
        fn accelerations(&self, robot: &str) -> Option<&[f64]> {
            self.0.get(robot).map(Vec::as_slice)
        }
    }

    fn terms(robot: &str, tick: u64, v: &[f64]) -> DynamicsTerms {
        let nv = v.len();
        DynamicsTerms {
            header: Header::new("t", Some(robot), tick, 0),
            floating_base: false,
            nv: nv as u32,
            mass_matrix: Matrix { rows: nv as u32, cols: nv as u32, data: vec![0.0; nv * nv] },
            bias: vec![0.0; nv],
            velocity: v.to_vec(),
            frames: Vec::new(),
            hand_in_grasp: false,
            state_tick: tick,
            team_delay_ticks: 0,
            object_pose: None,
        }
    }

    fn told(robot: &str, qdd: &[f64]) -> Told {
        Told(BTreeMap::from([(robot.to_string(), qdd.to_vec())]))
    }

    /// Solve `ticks` in order, tick k commanding `qdd(k)` with the delay `delay`.
    fn solved(
        p: &mut DelayPredictor,
        ticks: impl Iterator<Item = u64>,
        delay: u64,
        qdd: impl Fn(u64) -> f64,
    ) {
        for k in ticks {
            p.record(
                k,
                delay,
                &[terms("r1", k, &[0.0, 0.0])],
                Some(&told("r1", &[qdd(k), -2.0 * qdd(k)])),
            );
        }
    }

    #[test]
    fn the_velocity_is_carried_over_the_commands_that_apply_before_the_new_one() {
        // 1 kHz, delay 3, tick k commanding qdd = k: solving tick 10, the commands of 7, 8, 9
        // apply at 10, 11, 12, so v(13) = v(10) + dt (7 + 8 + 9).
        let mut p = DelayPredictor::new(1000.0);
        solved(&mut p, 0..10, 3, |k| k as f64);
        let mut t = [terms("r1", 10, &[1.0, 1.0])];
        p.predict(10, 3, &mut t);
        let carried = 0.001 * 24.0;
        assert!(
            (t[0].velocity[0] - (1.0 + carried)).abs() < 1e-12
                && (t[0].velocity[1] - (1.0 - 2.0 * carried)).abs() < 1e-12,
            "{:?}",
            t[0].velocity
        );
        // Without a delay nothing is in flight.
        let mut t = [terms("r1", 10, &[1.0, 1.0])];
        p.predict(10, 0, &mut t);
        assert_eq!(t[0].velocity, vec![1.0, 1.0]);
    }

    #[test]
    fn between_team_ticks_a_robot_keeps_the_newest_command_that_applies() {
        // The team solves every 4th tick (0, 4, 8) with delay 2; solving tick 12, the command of
        // 8 applies from 10: at 12 and 13 it does, so v(14) = v(12) + 2 dt qdd(8).
        let mut p = DelayPredictor::new(500.0);
        solved(&mut p, (0..12).step_by(4), 2, |k| 10.0 + k as f64);
        let mut t = [terms("r1", 12, &[0.0, 0.0])];
        p.predict(12, 2, &mut t);
        assert!((t[0].velocity[0] - 2.0 * 0.002 * 18.0).abs() < 1e-12, "{:?}", t[0].velocity);
        // Solving tick 9 instead (as if a robot's terms came off the team's grid): the command
        // of 8 applies only from 10, so 9 and 10 get those of 4 (from 6) and 8.
        let mut t = [terms("r1", 9, &[0.0, 0.0])];
        p.predict(9, 2, &mut t);
        assert!((t[0].velocity[0] - 0.002 * (14.0 + 18.0)).abs() < 1e-12, "{:?}", t[0].velocity);
    }

    #[test]
    fn a_change_of_delay_carries_each_command_from_where_it_applies() {
        // Ticks 0-9 sent with delay 1 (qdd 1), 10-11 with delay 3 (qdd 5): solving 12 with delay
        // 3, ticks 12, 13, 14 get the newest command applying there: 9's (from 10) at 12,
        // 10's (from 13) at 13, 11's (from 14) at 14.
        let mut p = DelayPredictor::new(1000.0);
        solved(&mut p, 0..10, 1, |_| 1.0);
        solved(&mut p, 10..12, 3, |_| 5.0);
        let mut t = [terms("r1", 12, &[0.0, 0.0])];
        p.predict(12, 3, &mut t);
        assert!(
            (t[0].velocity[0] - 0.001 * (1.0 + 5.0 + 5.0)).abs() < 1e-12,
            "{:?}",
            t[0].velocity
        );
    }

    #[test]
    fn nothing_is_carried_for_robots_without_accelerations_old_commands_or_other_sizes() {
        let mut p = DelayPredictor::new(1000.0);
        solved(&mut p, 0..5, 2, |_| 1.0);
        // A robot never recorded, one of another size, and commands too old to apply.
        let mut t = [terms("r2", 5, &[1.0]), terms("r1", 5, &[1.0, 1.0, 1.0])];
        p.predict(5, 2, &mut t);
        assert_eq!(
            (t[0].velocity.clone(), t[1].velocity.clone()),
            (vec![1.0], vec![1.0, 1.0, 1.0])
        );
        let mut t = [terms("r1", 5 + OLDEST_CARRIED + 10, &[0.0, 0.0])];
        p.predict(5 + OLDEST_CARRIED + 10, 2, &mut t);
        assert_eq!(t[0].velocity, vec![0.0, 0.0], "a command older than {OLDEST_CARRIED} ticks");
        // A tick whose controller gave no accelerations (or non-finite ones) still applies: the
        // periods it covers carry nothing, not the older command's.
        p.record(5, 2, &[terms("r1", 5, &[0.0, 0.0])], Some(&Told(BTreeMap::new())));
        p.record(6, 2, &[terms("r1", 6, &[0.0, 0.0])], Some(&told("r1", &[f64::NAN, 0.0])));
        let mut t = [terms("r1", 7, &[0.0, 0.0])];
        p.predict(7, 2, &mut t);
        assert_eq!(t[0].velocity, vec![0.0, 0.0], "7 and 8 get 5's and 6's: no accelerations");
        let mut t = [terms("r1", 9, &[0.0, 0.0])];
        p.predict(9, 2, &mut t);
        assert_eq!(t[0].velocity, vec![0.0, 0.0], "9 and 10 still get 6's: no accelerations");
        // A tick not solved, and a hold order: their commands apply, and carry nothing.
        solved(&mut p, 7..9, 2, |_| 1.0);
        p.record(9, 2, &[terms("r1", 9, &[0.0, 0.0])], None);
        p.record_hold("r1", 10, 2);
        p.record_hold("r9", 10, 2);
        let mut t = [terms("r1", 11, &[0.0, 0.0])];
        p.predict(11, 2, &mut t);
        assert_eq!(
            t[0].velocity,
            vec![0.0, 0.0],
            "11 and 12 get 9's and 10's: a tick not solved, a hold"
        );
        let mut t = [terms("r1", 10, &[0.0, 0.0])];
        p.predict(10, 2, &mut t);
        assert!(
            (t[0].velocity[0] - 0.001).abs() < 1e-12,
            "10 gets 8's, 11 gets 9's: {:?}",
            t[0].velocity
        );
    }

    #[test]
    fn reused_terms_are_carried_from_the_state_they_came_from() {
        // Terms of the state of tick 8 reused for tick 10 (a late member), delay 2: carried over
        // 8 .. 11, with the commands of 6 .. 9 (qdd = k).
        let mut p = DelayPredictor::new(1000.0);
        solved(&mut p, 0..10, 2, |k| k as f64);
        let mut t = [terms("r1", 10, &[0.0, 0.0])];
        t[0].state_tick = 8;
        p.predict(10, 2, &mut t);
        assert!(
            (t[0].velocity[0] - 0.001 * (6.0 + 7.0 + 8.0 + 9.0)).abs() < 1e-12,
            "{:?}",
            t[0].velocity
        );
    }

    #[test]
    fn frames_move_with_the_carried_velocity_as_the_simulator_integrates() {
        use protocol::{FrameRole, FrameTerms};
        // A robot of three velocities: a hand frame whose linear rows read v0, v1, 0 and whose
        // angular rows read (0, 0, v2) (a planar body); a foot frame that reads v0 only. Delay
        // 2, the commands in flight accelerating (1, 0, 2): semi-implicit Euler gives
        // v1 = v + dt a, v2 = v + 2 dt a and x += dt (v1 + v2).
        let dt = 0.001;
        let mut p = DelayPredictor::new(1.0 / dt);
        p.record(0, 2, &[terms("r1", 0, &[0.0; 3])], Some(&told("r1", &[1.0, 0.0, 2.0])));
        p.record(1, 2, &[terms("r1", 1, &[0.0; 3])], Some(&told("r1", &[1.0, 0.0, 2.0])));
        let jacobian = |rows: &[[f64; 3]]| Matrix {
            rows: rows.len() as u32,
            cols: 3,
            data: rows.iter().flatten().copied().collect(),
        };
        let (v, a) = ([0.5, -0.2, 3.0], [1.0, 0.0, 2.0]);
        let mut t = terms("r1", 2, &v);
        let hand = FrameTerms {
            name: "hand".into(),
            role: FrameRole::Hand,
            position: [1.0, 2.0, 3.0],
            rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            jacobian: jacobian(&[
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0],
                [0.0, 0.0, 0.0],
                [0.0, 0.0, 0.0],
                [0.0, 0.0, 1.0],
            ]),
            jdot_v: vec![0.0; 6],
        };
        let foot = FrameTerms {
            name: "foot".into(),
            role: FrameRole::StanceFoot,
            position: [0.0; 3],
            rotation: hand.rotation,
            jacobian: jacobian(&[[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
            jdot_v: vec![0.0; 3],
        };
        t.frames = vec![hand, foot];
        // The hand holds an object whose centre is 0.3 m along its x axis.
        t.hand_in_grasp = true;
        t.object_pose = Some(Pose { position: [1.3, 2.0, 3.0], orientation: [1.0, 0.0, 0.0, 0.0] });
        let mut ts = [t];
        p.predict(2, 2, &mut ts);
        let moved = |j: usize| dt * ((v[j] + dt * a[j]) + (v[j] + 2.0 * dt * a[j]));
        let f = &ts[0].frames;
        let close = |x: f64, y: f64| (x - y).abs() < 1e-12;
        assert!(
            close(f[0].position[0], 1.0 + moved(0))
                && close(f[0].position[1], 2.0 + moved(1))
                && close(f[0].position[2], 3.0),
            "{:?}",
            f[0].position
        );
        let yaw = moved(2);
        let r = &f[0].rotation;
        assert!(
            close(r[0], yaw.cos())
                && close(r[1], -yaw.sin())
                && close(r[3], yaw.sin())
                && close(r[4], yaw.cos())
                && close(r[8], 1.0),
            "a turn of {yaw} rad about z: {r:?}"
        );
        assert!(
            close(f[1].position[0], moved(0)) && f[1].position[1] == 0.0,
            "the foot: {:?}",
            f[1].position
        );
        assert!(close(ts[0].velocity[2], v[2] + 2.0 * dt * a[2]));
        // The held object moved rigidly with the hand: turned by the yaw about the hand's point.
        let o = ts[0].object_pose.expect("the object's pose");
        let (hx, hy) = (f[0].position[0], f[0].position[1]);
        assert!(
            close(o.position[0], hx + 0.3 * yaw.cos())
                && close(o.position[1], hy + 0.3 * yaw.sin())
                && close(o.position[2], 3.0),
            "{:?}",
            o.position
        );
        let half = yaw / 2.0;
        let q = o.orientation;
        assert!(close(q[0], half.cos()) && close(q[3], half.sin()) && q[1] == 0.0, "{q:?}");
    }
}
