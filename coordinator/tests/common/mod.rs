//! Team states from the real default robot (robot_model's model, robot_agent's TermsBuilder).
#![allow(dead_code)]

use nalgebra::{DMatrix, DVector};
use protocol::{DynamicsTerms, Header, Pose, RobotDescription, RobotState};
use rand::{Rng, SeedableRng};
use robot_agent::dynamics_source::robot_description;
use robot_agent::terms::{empty_terms, ActiveContacts, TermsBuilder};
use robot_model::{default_robot_path, Robot};

pub const TEAM: &str = "t";

pub struct Fixture {
    pub robot: Robot,
    pub builder: TermsBuilder,
}

impl Fixture {
    pub fn new() -> Self {
        let robot = Robot::load(default_robot_path()).expect("default robot");
        let builder = TermsBuilder::new(&robot).expect("builder");
        Fixture { robot, builder }
    }

    pub fn description(&self, id: &str) -> RobotDescription {
        robot_description(&self.robot, TEAM, id)
    }

    /// Standing `q` of robot `k` of `count` placed on a circle facing the centre. For two
    /// robots: robot 0 at the origin facing +x, robot 1 at x = 2.3 m rotated 180° about z.
    pub fn standing_q(&self, k: usize, count: usize) -> DVector<f64> {
        let mut q = self.robot.standing_q.clone();
        let (x, y, yaw) = place(k, count);
        q[0] = x;
        q[1] = y;
        q[3] = (yaw / 2.0).cos();
        q[4] = 0.0;
        q[5] = 0.0;
        q[6] = (yaw / 2.0).sin();
        q
    }

    /// Terms of robot `id` at `(q, v)` with every foot in stance and the hand in grasp.
    pub fn terms(
        &mut self,
        id: &str,
        q: &DVector<f64>,
        v: &DVector<f64>,
        tick: u64,
    ) -> DynamicsTerms {
        self.terms_with(id, q, v, tick, &ActiveContacts::all_stance(&self.robot))
    }

    pub fn terms_with(
        &mut self,
        id: &str,
        q: &DVector<f64>,
        v: &DVector<f64>,
        tick: u64,
        contacts: &ActiveContacts,
    ) -> DynamicsTerms {
        let state = RobotState {
            header: Header::new(TEAM, Some(id), tick, 0),
            base_pose: Pose { position: [q[0], q[1], q[2]], orientation: [q[3], q[4], q[5], q[6]] },
            base_twist: [v[0], v[1], v[2], v[3], v[4], v[5]],
            joint_positions: q.as_slice()[7..].to_vec(),
            joint_velocities: v.as_slice()[6..].to_vec(),
            time: 0.0,
            foot_forces: Vec::new(),
            object_pose: None,
        };
        self.builder.load_state(&self.robot, &state).expect("state");
        let mut out = empty_terms(TEAM, id);
        out.header.tick = tick;
        self.builder.compute(&self.robot, contacts, &mut out).expect("terms");
        out
    }

    /// A static team of `count` robots at their standing pose.
    pub fn static_team(&mut self, count: usize) -> (Vec<DynamicsTerms>, Vec<RobotDescription>) {
        let nv = self.robot.model.nv;
        let mut terms = Vec::new();
        let mut descs = Vec::new();
        for k in 0..count {
            let id = robot_id(k);
            let q = self.standing_q(k, count);
            terms.push(self.terms(&id, &q, &DVector::zeros(nv), 1));
            descs.push(self.description(&id));
        }
        (terms, descs)
    }

    /// A randomly perturbed configuration (joints +-amp rad, base +-amp/10 m and rad).
    pub fn perturbed_q(
        &self,
        k: usize,
        count: usize,
        amp: f64,
        rng: &mut impl Rng,
    ) -> DVector<f64> {
        let q0 = self.standing_q(k, count);
        let nv = self.robot.model.nv;
        let mut dv = DVector::zeros(nv);
        for i in 0..nv {
            let a = if i < 6 { amp / 10.0 } else { amp };
            dv[i] = rng.random_range(-a..a);
        }
        self.robot.model.integrate(q0.as_slice(), dv.as_slice(), 1.0)
    }
}

pub fn robot_id(k: usize) -> String {
    format!("r{}", k + 1)
}

/// Robot `k` of `count` on a circle (radius 1.15 m) around the object at (1.15, 0), facing it.
pub fn place(k: usize, count: usize) -> (f64, f64, f64) {
    let theta = std::f64::consts::PI + 2.0 * std::f64::consts::PI * k as f64 / count as f64;
    let (cx, r) = (1.15, 1.15);
    let x = cx + r * theta.cos();
    let y = r * theta.sin();
    let yaw = theta - std::f64::consts::PI;
    // Clean up round-off so that the 2-robot team sits exactly at x = 0 and 2.3.
    let clean = |a: f64| if a.abs() < 1e-12 { 0.0 } else { a };
    (clean(x), clean(y), yaw)
}

pub fn rng(seed: u64) -> rand::rngs::StdRng {
    rand::rngs::StdRng::seed_from_u64(seed)
}

/// `min |A u - g|^2` over `u >= 0`: Lawson and Hanson's active-set method (least squares on
/// the free set, exact at its end; a bounded number of steps, a failure shows as a stationarity
/// residual, never as a false pass).
pub fn nonnegative_least_squares(a: &DMatrix<f64>, g: &DVector<f64>) -> DVector<f64> {
    let k = a.ncols();
    let tol = 1e-12 * (1.0 + (a.transpose() * g).amax());
    let ls = |free: &[bool]| {
        let cols: Vec<usize> = (0..k).filter(|&i| free[i]).collect();
        let a_f = DMatrix::from_fn(a.nrows(), cols.len(), |r, c| a[(r, cols[c])]);
        let s_f = a_f.svd(true, true).solve(g, 1e-14).expect("least squares");
        let mut s = DVector::zeros(k);
        cols.iter().zip(s_f.iter()).for_each(|(&i, &x)| s[i] = x);
        s
    };
    let (mut x, mut free) = (DVector::zeros(k), vec![false; k]);
    let mut rejected = None;
    for _ in 0..3 * k {
        let w = a.transpose() * (g - a * &x);
        let Some(j) = (0..k)
            .filter(|&i| !free[i] && Some(i) != rejected && w[i] > tol)
            .max_by(|&i, &j| w[i].total_cmp(&w[j]))
        else {
            break;
        };
        free[j] = true;
        rejected = None;
        for _ in 0..k {
            let s = ls(&free);
            if (0..k).filter(|&i| free[i]).all(|i| s[i] > 0.0) {
                x = s;
                break;
            }
            // The longest step from x towards s that keeps the free set non-negative (an x_i
            // already at zero with s_i <= 0 allows none).
            let alpha = (0..k)
                .filter(|&i| free[i] && s[i] <= 0.0)
                .map(|i| if x[i] <= 0.0 { 0.0 } else { x[i] / (x[i] - s[i]) })
                .fold(1.0, f64::min);
            x += (&s - &x) * alpha;
            let scale = x.amax().max(f64::MIN_POSITIVE);
            for i in 0..k {
                if free[i] && x[i] <= 1e-14 * scale {
                    free[i] = false;
                    x[i] = 0.0;
                    rejected = Some(i);
                }
            }
        }
    }
    x
}

/// How a random team of the oracle tests is set up.
#[derive(Clone, Copy, Debug)]
pub struct Case {
    pub robots: usize,
    pub seed: u64,
    /// Robot 0 lifts its first foot.
    pub swing: bool,
    /// Hands in grasp (else every hand is a free task).
    pub grasp: bool,
    pub fully_actuated: bool,
}

impl Case {
    /// Robot `k`'s contacts: every foot in stance but robot 0's first with `swing`, the hand
    /// in grasp with `grasp`.
    pub fn contacts(&self, fx: &Fixture, k: usize) -> ActiveContacts {
        let mut set = ActiveContacts::all_stance(&fx.robot);
        set.stance[0] = !(self.swing && k == 0);
        set.hand_in_grasp = self.grasp;
        set
    }
}

/// `ticks` consecutive ticks (1 ms apart) of `case`'s team, each robot's joints perturbed by
/// up to 0.1 and moving at random joint velocities within `speed` (the bases at rest at first).
pub fn moving_ticks(
    fx: &mut Fixture,
    case: Case,
    ticks: usize,
    speed: f64,
) -> Vec<Vec<DynamicsTerms>> {
    let mut rng = rng(case.seed);
    let nv = fx.robot.model.nv;
    let qs: Vec<DVector<f64>> =
        (0..case.robots).map(|k| fx.perturbed_q(k, case.robots, 0.1, &mut rng)).collect();
    let vs: Vec<DVector<f64>> = (0..case.robots)
        .map(|_| {
            DVector::from_fn(nv, |i, _| if i < 6 { 0.0 } else { rng.random_range(-speed..speed) })
        })
        .collect();
    (0..ticks)
        .map(|t| {
            (0..case.robots)
                .map(|k| {
                    let q = fx.robot.model.integrate(
                        qs[k].as_slice(),
                        vs[k].as_slice(),
                        1e-3 * t as f64,
                    );
                    let set = case.contacts(fx, k);
                    fx.terms_with(&robot_id(k), &q, &vs[k], 1 + t as u64, &set)
                })
                .collect()
        })
        .collect()
}
