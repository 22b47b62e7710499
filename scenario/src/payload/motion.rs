//! The payload check along the whole motion: the team problem of [`coordinator::capacity`] at
//! poses sampled along the references, with the object's reference acceleration.
//!
//! The start pose alone says little: a beam carried around a circle takes the arms to poses
//! where their lever arms, and the palms' centres of pressure, are worse than at the start
//! (three robots at unequal spacing on a 1.8 m beam hold 2.32 kg at the start pose, and only
//! about 1.7 kg everywhere on a 4 cm circle). At each sample:
//!
//! * every robot's base is at its torso's reference; its feet stay where they stand
//!   (each leg solved for its foot's start position when the base moved,
//!   [`robot_model::ik::solve_position`]); its hand holds the object where the plan put it,
//!   at the object's reference pose (the arm solved by [`robot_model::ik::solve_hand`] from the
//!   configuration solved last);
//! * the team's terms come from the agents' own code ([`robot_agent::terms::TermsBuilder`]),
//!   with each robot's own inertia: its bias is the inverse dynamics `M qdd + C qd + g` at
//!   the velocity and acceleration that the configurations a step either side give
//!   ([`moving_terms`]). For a light object this matters: on a 28 mm circle at 0.48 Hz an arm's
//!   links weigh as much as the beam they accelerate;
//! * the object's rows are its Newton-Euler equations at the reference's acceleration and
//!   angular velocity ([`StaticProblem::with_object_motion`]).
//!
//! A walk moves the feet and changes the contact sets: along a walk each walking robot's feet
//! are where the gait plans them ([`planner::gait::GaitPlan::foot_position`]), only its stance
//! feet carry ([`planner::gait::GaitPlan::stance`]), and besides the regular samples every step
//! is sampled in the middle of its swing, on three feet (the unloading and loading ramps lie
//! between four feet and three).

use std::sync::Arc;

use coordinator::capacity::{BindingLimit, Capacity, CapacityError, StaticProblem, REACHED_TOL};
use coordinator::PidcConfig;
use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3, Vector6};
use planner::walk::Walk;
use protocol::{DynamicsTerms, Header, Pose, PoseReference, RobotDescription, RobotState};
use robot_agent::dynamics_source::robot_description;
use robot_agent::terms::{empty_terms, ActiveContacts, TermsBuilder};
use robot_model::ik::{self, IkOptions};
use robot_model::{Data, Robot};
use sim_bridge::world::WorldSpec;

use super::CheckError;
use crate::references::ReferencePlan;
use crate::TEAM;

/// Samples per second of scenario (a circle at 0.25 Hz is sampled 40 times a turn).
pub const SAMPLE_HZ: f64 = 10.0;
/// The most samples of one scenario (a longer one is sampled more sparsely).
pub const MAX_SAMPLES: usize = 300;

/// The team problem at one time of the motion.
#[derive(Debug, Clone)]
pub struct MotionSample {
    /// Scenario time, s.
    pub t: f64,
    /// The object's reference position then.
    pub object: Vector3<f64>,
    /// Each robot's configuration (the model's `q`) and which of its feet are in stance.
    pub robots: Vec<(Vec<f64>, Vec<bool>)>,
    pub problem: StaticProblem,
}

impl MotionSample {
    /// `source` at this sample.
    fn error(&self, source: CapacityError) -> CheckError {
        CheckError::AlongMotion { t: self.t, object: self.object.into(), source }
    }
}

/// The scenario times sampled: 0, then every `1 / SAMPLE_HZ` (at most [`MAX_SAMPLES`]), and
/// the end.
pub fn sample_times(duration: f64) -> Vec<f64> {
    if !(duration.is_finite() && duration > 0.0) {
        return vec![0.0];
    }
    let n = ((duration * SAMPLE_HZ).ceil() as usize).clamp(1, MAX_SAMPLES);
    (0..=n).map(|k| duration * k as f64 / n as f64).collect()
}

/// [`sample_times`], and with a walk the middle of every step's swing within the scenario.
pub fn walk_sample_times(duration: f64, walk: Option<&Walk>) -> Vec<f64> {
    let mut times = sample_times(duration);
    if let Some(w) = walk {
        times.extend(
            w.gait
                .steps()
                .iter()
                .map(|s| 0.5 * (s.liftoff + s.touchdown))
                .filter(|t| *t <= duration),
        );
        times.sort_by(f64::total_cmp);
        times.dedup();
    }
    times
}

/// Robot `i`'s feet at scenario time `t` of a walk (`None`: where it started; every foot
/// without a walk or when the robot does not walk) and its contacts (then every foot in
/// stance).
fn planned_feet(
    walk: Option<&Walk>,
    i: usize,
    t: f64,
    robot: &Robot,
) -> (Vec<Option<Vector3<f64>>>, ActiveContacts) {
    match walk.filter(|w| w.walking.get(i).copied().unwrap_or(false)) {
        Some(w) => {
            let feet =
                (0..robot.foot_frames.len()).map(|k| w.gait.foot_position(i, k, t)).collect();
            (feet, ActiveContacts { stance: w.gait.stance(i, t).to_vec(), hand_in_grasp: true })
        }
        None => (vec![None; robot.foot_frames.len()], ActiveContacts::all_stance(robot)),
    }
}

/// A robot's configuration (the model's `q`: base pose, then joints) at its placement, with
/// the joints the plan solved.
pub(super) fn start_q(world: &WorldSpec, i: usize, robot: &Robot) -> Result<Vec<f64>, CheckError> {
    let placement = &world.robots[i];
    let mut q: Vec<f64> = robot.standing_q.iter().copied().collect();
    let off = robot.model.nq - robot.model.joint_names.len();
    for (j, v) in &placement.joint_overrides {
        let k = robot.model.joint_names.iter().position(|n| n == j).ok_or_else(|| {
            CheckError::UnknownJoint { robot: placement.id.clone(), joint: j.clone() }
        })?;
        q[off + k] = *v;
    }
    q[0..3].copy_from_slice(&placement.base_position);
    let yaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), placement.base_yaw);
    q[3..7].copy_from_slice(&[yaw.w, yaw.i, yaw.j, yaw.k]);
    Ok(q)
}

fn iso(p: &Pose) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(Vector3::from(p.position)),
        protocol::conventions::quat_from_wxyz(p.orientation),
    )
}

/// One robot followed along the motion: its feet's world positions and its hand's grasp on
/// the object (both from the start configuration), and its configuration at the last sample.
struct Follower {
    id: String,
    robot: Arc<Robot>,
    q: Vec<f64>,
    feet: Vec<(usize, Vector3<f64>)>,
    /// The hand's pose in the object's reference frame at the start.
    grasp: Isometry3<f64>,
    base: [f64; 7],
    /// The feet's positions the legs were last solved for.
    targets: Vec<Vector3<f64>>,
}

impl Follower {
    fn new(
        world: &WorldSpec,
        i: usize,
        robot: &Arc<Robot>,
        object0: &Isometry3<f64>,
    ) -> Result<Follower, CheckError> {
        let id = world.robots[i].id.clone();
        let kin = |e: &dyn std::fmt::Display| CheckError::Kinematics {
            robot: id.clone(),
            reason: e.to_string(),
        };
        let q = start_q(world, i, robot)?;
        let mut data = Data::new(&robot.model);
        robot_model::forward_kinematics(&robot.model, &mut data, &q, &vec![0.0; robot.model.nv])
            .map_err(|e| kin(&e))?;
        let mut feet = Vec::new();
        for f in &robot.foot_frames {
            let k = robot.model.frame_id(f).map_err(|e| kin(&e))?;
            feet.push((k, Vector3::from(data.o_m_f[k].trans)));
        }
        let hand = robot.model.frame_id(&robot.hand_frame).map_err(|e| kin(&e))?;
        let m = data.o_m_f[hand];
        let hand0 = Isometry3::from_parts(m.trans.into(), UnitQuaternion::from_matrix(&m.rot));
        let base = [q[0], q[1], q[2], q[3], q[4], q[5], q[6]];
        let targets = feet.iter().map(|(_, p)| *p).collect();
        Ok(Follower {
            id,
            robot: robot.clone(),
            q,
            feet,
            grasp: object0.inverse() * hand0,
            base,
            targets,
        })
    }

    /// The configurations at `t - h`, `t` and `t + h` ([`DIFFERENCE_STEP`]) of robot `i` along
    /// the plan's references; the follower is left at `t`.
    fn follow_around(
        &mut self,
        refs: &ReferencePlan,
        walk: Option<&Walk>,
        i: usize,
        t: f64,
    ) -> Result<[Vec<f64>; 3], CheckError> {
        let at = |f: &mut Follower, s: f64| -> Result<Vec<f64>, CheckError> {
            let (feet, _) = planned_feet(walk, i, s, &f.robot);
            let object = iso(&refs.object_at(Some(s)).pose);
            Ok(f.follow(s, &refs.torso_at(i, Some(s)).pose, &object, &feet)?.to_vec())
        };
        let before = at(self, t - DIFFERENCE_STEP)?;
        let after = at(self, t + DIFFERENCE_STEP)?;
        let now = at(self, t)?;
        Ok([before, now, after])
    }

    /// The configuration at scenario time `t`: base at `torso`, each foot at its target in
    /// `feet` (one per foot; where it started when `None`), hand on the object at `object`.
    fn follow(
        &mut self,
        t: f64,
        torso: &Pose,
        object: &Isometry3<f64>,
        feet: &[Option<Vector3<f64>>],
    ) -> Result<&[f64], CheckError> {
        let reach = |source| CheckError::Reach { robot: self.id.clone(), t, source };
        let base = [
            torso.position[0],
            torso.position[1],
            torso.position[2],
            torso.orientation[0],
            torso.orientation[1],
            torso.orientation[2],
            torso.orientation[3],
        ];
        let model = &self.robot.model;
        let opts = IkOptions::default();
        let targets: Vec<Vector3<f64>> =
            self.feet.iter().zip(feet).map(|((_, p0), p)| p.unwrap_or(*p0)).collect();
        let moved = base.iter().zip(&self.base).any(|(a, b)| (a - b).abs() > 1e-12);
        if moved || targets.iter().zip(&self.targets).any(|(a, b)| (a - b).norm() > 1e-12) {
            self.q[0..7].copy_from_slice(&base);
            self.base = base;
            for ((frame, _), p) in self.feet.iter().zip(&targets) {
                self.q = ik::solve_position(model, *frame, &self.q, p, &opts, |_| true)
                    .map_err(reach)?
                    .q;
            }
            self.targets = targets;
        }
        let target = object * self.grasp;
        let r = target.rotation.to_rotation_matrix().into_inner();
        self.q = ik::solve_hand(&self.robot, &self.q, &target.translation.vector, &r, &opts)
            .map_err(reach)?
            .q;
        Ok(&self.q)
    }
}

/// The step of the central differences that give a robot's velocity and acceleration along
/// the references, s.
pub const DIFFERENCE_STEP: f64 = 0.02;

/// The model's velocity `v` that moves `q0` to `q1` in `dt`: the joints' differences, and the
/// floating base's body twist (`q1 = q0 (+) v dt`, [`robot_model::Model::integrate`], to first
/// order in `dt`).
fn velocity_between(robot: &Robot, q0: &[f64], q1: &[f64], dt: f64) -> Vec<f64> {
    let m = &robot.model;
    let nj = m.joint_names.len();
    let (oq, ov) = (m.nq - nj, m.nv - nj);
    let mut v = vec![0.0; m.nv];
    if m.floating_base {
        let quat = |q: &[f64]| {
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[3], q[4], q[5], q[6]))
        };
        let (r0, r1) = (quat(q0), quat(q1));
        let lin = r0.inverse()
            * (Vector3::new(q1[0], q1[1], q1[2]) - Vector3::new(q0[0], q0[1], q0[2]))
            / dt;
        let ang = (r0.inverse() * r1).scaled_axis() / dt;
        v[0..3].copy_from_slice(lin.as_slice());
        v[3..6].copy_from_slice(ang.as_slice());
    }
    for k in 0..nj {
        v[ov + k] = (q1[oq + k] - q0[oq + k]) / dt;
    }
    v
}

/// The agents' terms of robot `id` moving through `around` (its configurations at `t - h`,
/// `t`, `t + h`, [`DIFFERENCE_STEP`]) with `contacts`: the terms at rest at `t`
/// ([`rest_terms`]) whose bias is what the contacts and joints must supply to move the robot
/// so, `M(q) qdd + C(q, qd) qd + g(q)` (eq. js_dynamics) with `qd`, `qdd` the central
/// differences.
pub fn moving_terms(
    robot: &Robot,
    id: &str,
    around: &[Vec<f64>; 3],
    contacts: &ActiveContacts,
) -> Result<DynamicsTerms, CheckError> {
    let h = DIFFERENCE_STEP;
    let [before, now, after] = around;
    let mut out = rest_terms(robot, id, now, contacts)?;
    let (v0, v1) =
        (velocity_between(robot, before, now, h), velocity_between(robot, now, after, h));
    let v: Vec<f64> = v0.iter().zip(&v1).map(|(a, b)| 0.5 * (a + b)).collect();
    let a: Vec<f64> = v0.iter().zip(&v1).map(|(a, b)| (b - a) / h).collect();
    let mut data = Data::new(&robot.model);
    let tau = robot_model::rnea(&robot.model, &mut data, now, &v, &a)
        .map_err(|e| CheckError::Kinematics { robot: id.to_string(), reason: e.to_string() })?;
    out.bias.clear();
    out.bias.extend_from_slice(tau.as_slice());
    Ok(out)
}

/// The agents' terms of robot `id` at configuration `q` (the model's: base pose, then joints),
/// at rest, with `contacts` (the feet in stance, the hand in grasp): what the coordinator gets
/// in a run.
pub(super) fn rest_terms(
    robot: &Robot,
    id: &str,
    q: &[f64],
    contacts: &ActiveContacts,
) -> Result<DynamicsTerms, CheckError> {
    let terms_err = |source| CheckError::Terms { robot: id.to_string(), source };
    let joints = q[robot.model.nq - robot.model.joint_names.len()..].to_vec();
    let state = RobotState {
        header: Header::new(TEAM, Some(id), 0, 0),
        base_pose: Pose { position: [q[0], q[1], q[2]], orientation: [q[3], q[4], q[5], q[6]] },
        base_twist: [0.0; 6],
        joint_velocities: vec![0.0; joints.len()],
        joint_positions: joints,
        time: 0.0,
        foot_forces: Vec::new(),
        object_pose: None,
    };
    let mut builder = TermsBuilder::new(robot).map_err(terms_err)?;
    builder.load_state(robot, &state).map_err(terms_err)?;
    let mut out = empty_terms(TEAM, id);
    builder.compute(robot, contacts, &mut out).map_err(terms_err)?;
    Ok(out)
}

/// The team problem at every sample of the motion (see the module docs), with the
/// controller's margins `cfg`; `unit_inertia` is the object's principal inertia per kilogram.
pub fn motion_samples(
    world: &WorldSpec,
    robots: &[Arc<Robot>],
    refs: &ReferencePlan,
    cfg: &PidcConfig,
    unit_inertia: [f64; 3],
) -> Result<Vec<MotionSample>, CheckError> {
    if robots.len() != world.robots.len() {
        return Err(CheckError::RobotCount(robots.len(), world.robots.len()));
    }
    let object0 = iso(&refs.object_at(Some(0.0)).pose);
    let mut team = world
        .robots
        .iter()
        .enumerate()
        .map(|(i, _)| Follower::new(world, i, &robots[i], &object0))
        .collect::<Result<Vec<_>, _>>()?;
    let descs: Vec<RobotDescription> =
        team.iter().map(|f| robot_description(&f.robot, TEAM, &f.id)).collect();
    let inertia = Matrix3::from_diagonal(&Vector3::from(unit_inertia));
    let walk = refs.walk.as_deref();
    let mut out = Vec::new();
    for t in walk_sample_times(refs.clock.scenario_duration(), walk) {
        let object: PoseReference = refs.object_at(Some(t));
        let x_o = iso(&object.pose);
        let mut terms = Vec::with_capacity(team.len());
        let mut configs = Vec::with_capacity(team.len());
        for (i, f) in team.iter_mut().enumerate() {
            let (_, contacts) = planned_feet(walk, i, t, &f.robot);
            let around = f.follow_around(refs, walk, i, t)?;
            terms.push(moving_terms(&f.robot, &f.id, &around, &contacts)?);
            configs.push((f.q.clone(), contacts.stance));
        }
        let centre = x_o.translation.vector;
        let r = x_o.rotation.to_rotation_matrix();
        let unit = r.matrix() * inertia * r.matrix().transpose();
        let omega = Vector3::new(object.twist[3], object.twist[4], object.twist[5]);
        let problem = StaticProblem::build(&terms, &descs, &cfg.contact_margins(), centre)
            .map_err(|source| CheckError::AlongMotion { t, object: centre.into(), source })?
            .with_object_motion(&Vector6::from_row_slice(&object.acceleration), &omega, &unit);
        out.push(MotionSample { t, object: centre, robots: configs, problem });
    }
    Ok(out)
}

/// Whether `mass` is held at every sample: the first sample where it is not, named with its
/// binding limits ([`CheckError::AlongMotion`]).
pub fn check_along(samples: &[MotionSample], mass: f64) -> Result<(), CheckError> {
    for s in samples {
        s.problem.solve(mass).map_err(|e| s.error(e))?;
    }
    Ok(())
}

/// The heaviest object held at every sample, within `tolerance` kg, and where along the motion
/// the limit is.
#[derive(Debug, Clone)]
pub struct MotionCapacity {
    pub capacity: Capacity,
    /// The sample that limits it: its time (s) and the object's position.
    pub at_s: f64,
    pub object: Vector3<f64>,
    /// Samples checked.
    pub samples: usize,
}

/// [`MotionCapacity`] by bisection on the mass; a mass is held when every sample holds it
/// (the sample that refused the last mass is tried first, so a refusal costs one solve).
pub fn capacity_along(
    samples: &[MotionSample],
    tolerance: f64,
) -> Result<MotionCapacity, CheckError> {
    let first = samples.first().ok_or(CheckError::NoObject)?;
    // The start pose's capacity bounds the motion's from above.
    let start = first.problem.capacity(tolerance)?;
    let mut order: Vec<usize> = (0..samples.len()).collect();
    let mut solves = start.solves;
    let holds = |mass: f64,
                 order: &mut Vec<usize>,
                 solves: &mut usize|
     -> Result<Option<usize>, CheckError> {
        for k in 0..order.len() {
            *solves += 1;
            let s = &samples[order[k]];
            if !s.problem.relaxed(mass).map_err(|e| s.error(e))?.feasible() {
                let i = order.remove(k);
                order.insert(0, i);
                return Ok(Some(i));
            }
        }
        Ok(None)
    };
    let (mut lo, mut hi, mut limiting) = (0.0, start.infeasible_at, 0);
    if let Some(i) = holds(0.0, &mut order, &mut solves)? {
        let s = &samples[i];
        let binding = s.problem.relaxed(0.0).map_err(|e| s.error(e))?.binding(&s.problem);
        return Err(CheckError::AlongMotion {
            t: s.t,
            object: s.object.into(),
            source: CapacityError::Infeasible { mass: 0.0, binding },
        });
    }
    match holds(start.mass, &mut order, &mut solves)? {
        None => lo = start.mass,
        Some(i) => (hi, limiting) = (start.mass, i),
    }
    while hi - lo > tolerance {
        let mid = 0.5 * (lo + hi);
        match holds(mid, &mut order, &mut solves)? {
            None => lo = mid,
            Some(i) => (hi, limiting) = (mid, i),
        }
    }
    let s = &samples[limiting];
    let binding: Vec<BindingLimit> =
        s.problem.relaxed(hi).map_err(|e| s.error(e))?.binding(&s.problem);
    let reached =
        s.problem.reached(&s.problem.solve(lo).map_err(|e| s.error(e))?.lambda, REACHED_TOL);
    Ok(MotionCapacity {
        capacity: Capacity { mass: lo, infeasible_at: hi, binding, reached, solves },
        at_s: s.t,
        object: s.object,
        samples: samples.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_cover_the_run_from_start_to_end() {
        let t = sample_times(10.0);
        assert_eq!((t.first(), t.last(), t.len()), (Some(&0.0), Some(&10.0), 101));
        let long = sample_times(1000.0);
        assert_eq!(long.len(), MAX_SAMPLES + 1);
        assert!(long.windows(2).all(|w| w[1] > w[0]));
        assert_eq!(sample_times(0.0), vec![0.0]);
        assert_eq!(sample_times(f64::NAN), vec![0.0]);
    }

    fn robot() -> Robot {
        Robot::load(robot_model::default_robot_path()).expect("default robot")
    }

    /// The robot's standing configuration with its base turned about every axis, so that a
    /// world-frame quantity would not pass for a body-frame one.
    fn turned_standing_q(r: &Robot) -> Vec<f64> {
        let mut q: Vec<f64> = r.standing_q.iter().copied().collect();
        let turned = UnitQuaternion::from_euler_angles(0.2, 0.3, 0.7);
        q[3..7].copy_from_slice(&[turned.w, turned.i, turned.j, turned.k]);
        q
    }

    #[test]
    fn a_constant_body_twist_is_the_velocity_between_its_ends() {
        // Oracle: the model's own integration along a known twist.
        let r = robot();
        let q0 = turned_standing_q(&r);
        let v: Vec<f64> = (0..r.model.nv).map(|k| 0.3 * ((k as f64) * 0.7).sin()).collect();
        let h = DIFFERENCE_STEP;
        let q1 = r.model.integrate(&q0, &v, h);
        let got = velocity_between(&r, &q0, q1.as_slice(), h);
        let joints = r.model.nv - r.model.joint_names.len();
        for k in 0..r.model.nv {
            // The base to first order in h: the exponential couples its rotation and
            // translation by O(h |w| |v|) = 2e-3 m/s here; the joints exactly.
            let tol = if k < joints { 3e-3 } else { 1e-12 };
            assert!((got[k] - v[k]).abs() < tol, "v[{k}]: {} against {}", got[k], v[k]);
        }
    }

    #[test]
    fn a_moving_robots_bias_is_its_inverse_dynamics_along_the_motion() {
        // Joints on a parabola, the base turned and still: the central differences are exact,
        // and the bias must be `M a + h` at the parabola's velocity and acceleration (the
        // composite-rigid-body mass matrix and the bias of `compute_all_terms`, not the RNEA the
        // code calls), not gravity alone.
        let r = robot();
        let q = turned_standing_q(&r);
        let (nq, nv, nj) = (r.model.nq, r.model.nv, r.model.joint_names.len());
        let vd: Vec<f64> = (0..nv)
            .map(|k| if k < nv - nj { 0.0 } else { 0.4 * ((k as f64) * 1.3).cos() })
            .collect();
        let ad: Vec<f64> = (0..nv)
            .map(|k| if k < nv - nj { 0.0 } else { 2.0 * ((k as f64) * 0.9).sin() })
            .collect();
        let at = |t: f64| -> Vec<f64> {
            let mut x = q.clone();
            for k in 0..nj {
                x[nq - nj + k] += vd[nv - nj + k] * t + 0.5 * ad[nv - nj + k] * t * t;
            }
            x
        };
        let h = DIFFERENCE_STEP;
        let terms =
            moving_terms(&r, "r1", &[at(-h), at(0.0), at(h)], &ActiveContacts::all_stance(&r))
                .expect("terms");
        let mut data = Data::new(&r.model);
        robot_model::compute_all_terms(&r.model, &mut data, &q, &vd).expect("terms");
        let want = &data.m * nalgebra::DVector::from_column_slice(&ad) + &data.h;
        let g =
            robot_model::gravity(&r.model, &mut Data::new(&r.model), &q).expect("gravity").clone();
        assert!(
            terms.velocity.iter().all(|v| *v == 0.0),
            "the terms stay at rest for the static problem"
        );
        let mut moved = 0.0_f64;
        for k in 0..nv {
            assert!(
                (terms.bias[k] - want[k]).abs() < 1e-8 * (1.0 + want[k].abs()),
                "bias[{k}]: {} against {}",
                terms.bias[k],
                want[k]
            );
            moved = moved.max((want[k] - g[k]).abs());
        }
        assert!(moved > 0.1, "the motion's inertia shows in the bias ({moved} N m at most)");
    }
}
