//! [`PaperController`]: the team controller of the paper's §III, run every tick.
//!
//! `tau = [P S]^+ P tau_M + B J_c^T F_c` (eq. ua_solution with `(I - P) tau_C = J_c^T F_c`),
//! `F_c` from the QP of eq. wrench_optim2 (see [`crate::qp`]).
//!
//! **Object weight.** The object is not in the generalized coordinates. Its load on the
//! robots is modelled as the paper's external wrench `J_x^T F_x` (eq. js_dynamics) with
//! `J_x = J_o` and `F_x = -w_ff`, `w_ff = [m_o (a_d - g); I_o alpha_d + omega x I_o omega]`
//! (the object's gravity and inertial load at its reference acceleration, acting on the
//! rigid grasp), and compensated by the same feed-forward in the object's impedance task:
//! `F_o = (eq. control_law) + w_ff`. `J_o^T F_x = J_ee^T G^+ F_x`, so the real wrench the object
//! exerts on hand `i` is `lambda_ee,i + (G^+ F_x)_i` (the internal part from the constraint
//! plus the load distribution); that sum is what the diagnostics report and what the QP
//! constrains. The hands push the object with the negative of it, so their net wrench on the
//! object is `-G (G^+ F_x) = w_ff`: it balances the weight in a static hold.
//!
//! **Fallback.** When the QP is infeasible or fails (status other than Solved/AlmostSolved),
//! `F_c` comes from the least-violation relaxation ([`qp::solve_least_violation`]: every row
//! softened by a heavily penalised slack), which keeps the squeeze and the friction rows as
//! far as they can be kept; if even that fails, `F_c = 0` (plain projected inverse dynamics
//! `tau = [P S]^+ P tau_M`). Either way the torques are clamped to the limits. The
//! diagnostics keep the QP's status; [`TickReport::fallback`] says what was done. (`F_c = 0`
//! drops the internal wrench, hence the squeeze: one infeasible tick lost the object.)

use std::collections::BTreeMap;
use std::time::Instant;

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};
use protocol::{ContactWrench, DynamicsTerms, Header, PoseReference, QpStatus, RobotDescription, TaskReferences, TickDiagnostics, TorqueCommand};

use crate::grasp::{centroid_pose, GraspOffsets, GraspTerms};
use crate::impedance::{pose_error, Gains, MotionSpace, TaskError, TaskStack};
use crate::linalg::{quat_wxyz, rotation_from_wxyz};
use crate::projection::Projections;
use crate::qp::{self, ContactKind, QpInput};
use crate::team::Team;
use crate::{ControllerError, TeamController};

/// Gravity vector (world), protocol convention.
const GRAVITY: [f64; 3] = [0.0, 0.0, -9.81];

/// Parameters of the controller. A TOML file of these fields (any subset; the rest keep
/// their defaults) is what `coordinator run --controller paper --controller-config FILE` reads,
/// see [`ControllerConfig::from_toml`].
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ControllerConfig {
    pub object_gains: Gains,
    pub torso_gains: Gains,
    pub swing_gains: Gains,
    /// Carried object: mass, inertia about its centre in its own frame.
    pub object_mass: f64,
    pub object_inertia: Matrix3<f64>,
    /// Object pose when the grasp first closes; `None`: the hands' centroid, world axes.
    pub object_pose_at_grasp: Option<Isometry3<f64>>,
    /// Minimum normal force of every stance foot, N.
    pub f_min_foot: f64,
    /// Minimum normal force of every hand (the least squeeze), N. The torque-optimal grasp
    /// otherwise sits on the friction limit (weight / mu), where any disturbance slips it.
    pub f_min_hand: f64,
    /// Share of each contact's friction the QP may use (`mu` and `xi` are scaled by it). The
    /// paper's pyramid `|f_x|, |f_y| <= mu f_n` reaches `sqrt(2) mu f_n` at its corners, outside
    /// the real (circular) cone; `1/sqrt(2)` makes it the inscribed pyramid.
    pub friction_margin: f64,
    /// Share of the palm's half-sizes the centre of pressure may use (the tilt rows of eqn.
    /// moment_constraint). At 1 the optimal grasp puts the whole squeeze on one palm edge,
    /// where the palm starts to roll on the object (seen in MuJoCo: the palm rolled 27 deg
    /// about its top edge within 3 s).
    pub patch_margin: f64,
    /// Added to the diagonal of the semi-definite QP objective.
    pub regularisation: f64,
    pub qp_max_iter: u32,
    /// Solve the QP with the dense interior-point method first, Clarabel when it does not
    /// converge (or always Clarabel when false). See `qp::dense_ipm`.
    pub dense_qp: bool,
    /// `S = I` (treat the base as actuated): the [Lin2018] comparison only.
    pub fully_actuated: bool,
}

impl Default for ControllerConfig {
    fn default() -> Self {
        // Gains of the paper's Table (simulations, torso and object motion).
        ControllerConfig {
            object_gains: Gains::new(&[1500.0, 1500.0, 1500.0, 400.0, 400.0, 400.0], &[150.0, 150.0, 150.0, 140.0, 140.0, 140.0]),
            torso_gains: Gains::new(&[4000.0, 4000.0, 4000.0, 3000.0, 3000.0, 3000.0], &[200.0, 200.0, 200.0, 125.0, 125.0, 125.0]),
            swing_gains: Gains::new(&[3500.0, 3500.0, 3500.0], &[20.0, 20.0, 20.0]),
            // The default scene's 0.6 m cube of 1 kg.
            object_mass: 1.0,
            object_inertia: Matrix3::identity() * (1.0 * (0.36 + 0.36) / 12.0),
            object_pose_at_grasp: None,
            f_min_foot: 5.0,
            f_min_hand: 30.0,
            friction_margin: std::f64::consts::FRAC_1_SQRT_2,
            patch_margin: 0.5,
            regularisation: 1e-6,
            qp_max_iter: 50,
            dense_qp: true,
            fully_actuated: false,
        }
    }
}

impl ControllerConfig {
    /// Parse a TOML controller configuration and check it.
    pub fn from_toml(text: &str) -> Result<Self, ControllerError> {
        let c: ControllerConfig = toml::from_str(text).map_err(|e| ControllerError::Config(e.to_string()))?;
        c.check()?;
        Ok(c)
    }

    /// The TOML text of this configuration.
    pub fn to_toml(&self) -> Result<String, ControllerError> {
        toml::to_string(self).map_err(|e| ControllerError::Config(e.to_string()))
    }

    /// Gains of the right sizes, finite and non-negative; masses, forces and limits sane.
    pub fn check(&self) -> Result<(), ControllerError> {
        let bad = |what: &str, why: String| Err(ControllerError::Config(format!("{what}: {why}")));
        for (what, g, n) in [("object_gains", &self.object_gains, 6), ("torso_gains", &self.torso_gains, 6), ("swing_gains", &self.swing_gains, 3)] {
            if let Err(why) = g.check(n) {
                return bad(what, why);
            }
        }
        if !(self.object_mass.is_finite() && self.object_mass >= 0.0) || self.object_inertia.iter().any(|x| !x.is_finite()) {
            return bad("object", "mass and inertia must be finite, mass non-negative".into());
        }
        for (what, x) in [("f_min_foot", self.f_min_foot), ("f_min_hand", self.f_min_hand), ("regularisation", self.regularisation)] {
            if !(x.is_finite() && x >= 0.0) {
                return bad(what, format!("{x} must be finite and non-negative"));
            }
        }
        for (what, x) in [("friction_margin", self.friction_margin), ("patch_margin", self.patch_margin)] {
            if !(x.is_finite() && x > 0.0 && x <= 1.0) {
                return bad(what, format!("{x} must be in (0, 1]"));
            }
        }
        if self.qp_max_iter == 0 {
            return bad("qp_max_iter", "must be positive".into());
        }
        Ok(())
    }
}

/// Everything computed in the last tick (kept for tests and reports).
#[derive(Debug, Clone)]
pub struct TickReport {
    pub team: Team,
    pub grasp: Option<GraspTerms>,
    pub j_c: DMatrix<f64>,
    pub jdv_c: DVector<f64>,
    pub proj: Projections,
    /// Motion torque `tau_M` and `tau_0 = [P S]^+ P tau_M`.
    pub tau_m: DVector<f64>,
    pub tau0: DVector<f64>,
    /// `J_x^T F_x`: the object's load on the robots (n).
    pub load: DVector<f64>,
    /// `F_x` at the object centre.
    pub f_x: DVector<f64>,
    pub f_c: DVector<f64>,
    pub rho: DMatrix<f64>,
    /// `eta` of eq. relation_between_lambda_and_Fc (without the hand-load offset).
    pub eta: DVector<f64>,
    /// `lambda = rho F_c + eta`, and the real contact wrenches (hand rows + `G^+ F_x`).
    pub lambda: DVector<f64>,
    pub lambda_real: DVector<f64>,
    /// Full team torque (n) and the QP pieces.
    pub tau: DVector<f64>,
    pub y: DMatrix<f64>,
    pub contacts: Vec<(usize, ContactKind)>,
    pub limits: Vec<f64>,
    pub actuated: Vec<usize>,
    pub qp: qp::QpOutcome,
    pub fallback: Option<String>,
    pub timing: Timing,
}

/// Where the time of a tick went, µs.
#[derive(Debug, Clone, Default)]
pub struct Timing {
    pub assembly_us: f64,
    pub projections_us: f64,
    pub impedance_us: f64,
    pub qp_build_us: f64,
    pub qp_us: f64,
    pub total_us: f64,
}

/// The paper's team controller.
pub struct PaperController {
    pub config: ControllerConfig,
    descriptions: BTreeMap<String, RobotDescription>,
    expected: Option<Vec<String>>,
    references: Option<TaskReferences>,
    held_torsos: BTreeMap<String, Isometry3<f64>>,
    held_feet: BTreeMap<(String, String), Vector3<f64>>,
    held_object: Option<Isometry3<f64>>,
    offsets: Option<GraspOffsets>,
    last_object: Option<Isometry3<f64>>,
    last: Option<TickReport>,
    diagnostics: Option<TickDiagnostics>,
}

impl PaperController {
    pub fn new(config: ControllerConfig) -> Self {
        PaperController {
            config,
            descriptions: BTreeMap::new(),
            expected: None,
            references: None,
            held_torsos: BTreeMap::new(),
            held_feet: BTreeMap::new(),
            held_object: None,
            offsets: None,
            last_object: None,
            last: None,
            diagnostics: None,
        }
    }

    /// Limits and contact parameters of a robot (from its agent's description).
    pub fn set_description(&mut self, d: &RobotDescription) {
        self.descriptions.insert(d.header.robot_id().to_string(), d.clone());
    }

    pub fn has_description(&self, robot: &str) -> bool {
        self.descriptions.contains_key(robot)
    }

    /// The robots every tick must contain (sorted ids); `None`: whoever is in the tick.
    pub fn set_expected(&mut self, robots: Option<Vec<String>>) {
        self.expected = robots;
    }

    /// Task references. Tasks without a reference hold the pose they had when first seen.
    pub fn set_references(&mut self, r: &TaskReferences) {
        self.references = Some(r.clone());
    }

    /// Forget the grasp (offsets are captured again when the hands next close).
    pub fn release_grasp(&mut self) {
        self.offsets = None;
        self.held_object = None;
    }

    pub fn last(&self) -> Option<&TickReport> {
        self.last.as_ref()
    }

    /// Run one tick: the full team torque and every intermediate.
    pub fn compute(&mut self, tick: &[DynamicsTerms]) -> Result<&TickReport, ControllerError> {
        let t_start = Instant::now();
        let cfg = self.config.clone();
        let team = Team::assemble(tick, self.expected.as_deref(), cfg.fully_actuated)?;
        let n = team.n;
        // Limits and contact parameters.
        let mut limits = Vec::new();
        let mut actuated = Vec::new();
        for r in &team.robots {
            let d = self.descriptions.get(&r.id).ok_or_else(|| ControllerError::MissingDescription { robot: r.id.clone() })?;
            if d.torque_limits.len() != r.actuated.len() || d.nv as usize != r.nv {
                return Err(ControllerError::Dimension {
                    what: format!("{}: description", r.id),
                    detail: format!("{} limits / nv {} vs {} actuated joints / nv {}", d.torque_limits.len(), d.nv, r.actuated.len(), r.nv),
                });
            }
            if cfg.fully_actuated {
                let base = r.nv - r.actuated.len();
                actuated.extend(r.offset..r.offset + base);
                limits.extend(std::iter::repeat_n(1e9, base));
            }
            actuated.extend(&r.actuated);
            limits.extend(&d.torque_limits);
        }
        // Grasp: offsets captured when the set of grasping hands changes.
        let grasp = if team.hands.is_empty() {
            self.offsets = None;
            None
        } else {
            if !self.offsets.as_ref().is_some_and(|o| o.matches(&team)) {
                let at = self.last_object.or(cfg.object_pose_at_grasp).unwrap_or_else(|| centroid_pose(&team));
                self.offsets = Some(GraspOffsets::capture(&team, &at));
            }
            let pose = self.offsets.as_ref().expect("set above").object_pose(&team);
            self.last_object = Some(pose);
            Some(GraspTerms::compute(&team, pose).ok_or_else(|| ControllerError::Singular { what: "grasp matrix".into() })?)
        };
        // J_c = [J_cf; J_c,ee] (eq. jacobian_c).
        let nf = team.feet.len();
        let m = team.contact_rows();
        let mut j_c = DMatrix::zeros(m, n);
        let mut jdv_c = DVector::zeros(m);
        j_c.rows_mut(0, 3 * nf).copy_from(&team.j_cf);
        jdv_c.rows_mut(0, 3 * nf).copy_from(&team.jdv_cf);
        if let Some(g) = &grasp {
            j_c.rows_mut(3 * nf, g.j_cee.nrows()).copy_from(&g.j_cee);
            jdv_c.rows_mut(3 * nf, g.j_cee.nrows()).copy_from(&g.jdv_cee);
        }
        let t_asm = t_start.elapsed().as_secs_f64() * 1e6;

        let proj = Projections::compute(&team.mass, &team.s_diag, &j_c, &jdv_c)?;
        let mcinv_p = &proj.mc_inv * &proj.p;
        let mcinv_bias = &proj.mc_inv * (&proj.p * &team.bias - &proj.pdot_v);
        let t_proj = t_start.elapsed().as_secs_f64() * 1e6;

        // tau_M: superposition of the impedance tasks (eqn. joint_space_tau_M), with the
        // operational-space inertia and non-linear terms of eq. control_law computed for the
        // team's task space as a whole (every task's rows stacked; see `impedance`).
        let ms = MotionSpace { mcinv_p: &mcinv_p, mcinv_bias: &mcinv_bias };
        let mut tasks = TaskStack::with_capacity(n);
        let mut load = DVector::zeros(n);
        let mut f_x = DVector::zeros(6);
        let refs = self.references.clone();
        if let Some(g) = &grasp {
            let (x_d, tw_d, acc_d) = match refs.as_ref().and_then(|r| r.object.as_ref()) {
                Some(r) => pose_ref(r),
                None => (*self.held_object.get_or_insert(g.object), [0.0; 6], [0.0; 6]),
            };
            let err = pose_error(&g.object, &g.object_twist, &x_d, &tw_d, &acc_d);
            // Object load feed-forward w_ff and the load F_x = -w_ff on the robots.
            let r_o = g.object.rotation.to_rotation_matrix();
            let i_w = r_o.matrix() * cfg.object_inertia * r_o.matrix().transpose();
            let w = Vector3::new(g.object_twist[3], g.object_twist[4], g.object_twist[5]);
            let alpha = Vector3::new(acc_d[3], acc_d[4], acc_d[5]);
            let force = cfg.object_mass * (Vector3::new(acc_d[0], acc_d[1], acc_d[2]) - Vector3::from(GRAVITY));
            let moment = i_w * alpha + w.cross(&(i_w * w));
            for i in 0..3 {
                f_x[i] = -force[i];
                f_x[3 + i] = -moment[i];
            }
            let mut ff = f_x.clone();
            ff.neg_mut();
            tasks.push(&g.j_o, &g.jdv_o, &err, &cfg.object_gains, Some(ff));
            load = g.j_o.transpose() * &f_x;
        }
        for tf in &team.torsos {
            let id = &team.robots[tf.robot].id;
            let x = Isometry3::from_parts(Translation3::from(tf.position), UnitQuaternion::from_rotation_matrix(&tf.rotation));
            let (x_d, tw_d, acc_d) = match refs.as_ref().and_then(|r| r.torsos.iter().find(|t| &t.robot == id)) {
                Some(t) => pose_ref(&t.reference),
                None => (*self.held_torsos.entry(id.clone()).or_insert(x), [0.0; 6], [0.0; 6]),
            };
            let twist = &tf.jacobian * &team.velocity;
            let err = pose_error(&x, &twist, &x_d, &tw_d, &acc_d);
            tasks.push(&tf.jacobian, &tf.jdot_v, &err, &cfg.torso_gains, None);
        }
        for tf in &team.swing_feet {
            let id = &team.robots[tf.robot].id;
            let key = (id.clone(), tf.name.clone());
            let (p_d, v_d, a_d) = match refs.as_ref().and_then(|r| r.swing_feet.iter().find(|s| &s.robot == id && s.frame == tf.name)) {
                Some(s) => (Vector3::from(s.reference.position), s.reference.velocity, s.reference.acceleration),
                None => (*self.held_feet.entry(key).or_insert(tf.position), [0.0; 3], [0.0; 3]),
            };
            let vel = &tf.jacobian * &team.velocity;
            let err = TaskError {
                e: DVector::from_iterator(3, (tf.position - p_d).iter().cloned()),
                edot: DVector::from_iterator(3, (0..3).map(|i| vel[i] - v_d[i])),
                acc_d: DVector::from_row_slice(&a_d),
            };
            tasks.push(&tf.jacobian, &tf.jdot_v, &err, &cfg.swing_gains, None);
        }
        let tau_m = tasks.joint_torque(&ms, n)?;
        let tau0 = &proj.ps_pinv * (&proj.p * &tau_m);
        let t_imp = t_start.elapsed().as_secs_f64() * 1e6;

        // eq. relation_between_lambda_and_Fc: lambda = rho F_c + eta.
        let y = &proj.b * j_c.transpose(); // B J_c^T
        let s_scale = |mut x: DMatrix<f64>| {
            for i in 0..n {
                x.row_mut(i).scale_mut(team.s_diag[i]);
            }
            x
        };
        let mut mbar_p_i = &proj.mbar * &proj.p;
        for i in 0..n {
            mbar_p_i[(i, i)] -= 1.0;
        }
        let k = &proj.ip * &mbar_p_i; // (I - P)(Mbar P - I)
        let rho = &proj.jct_pinv * (&k * s_scale(y.clone()));
        let s_tau0 = tau0.component_mul(&team.s_diag);
        let eta_inner = &k * (s_tau0 + &load) + &proj.ip * (&proj.mbar * (&proj.pdot_v - &proj.p * &team.bias) + &team.bias);
        let eta = &proj.jct_pinv * eta_inner;
        let mut eta_real = eta.clone();
        if let Some(g) = &grasp {
            let dist = &g.g_pinv * &f_x;
            { let mut rows = eta_real.rows_mut(3 * nf, dist.len()); rows += &dist; }
        }
        // Contacts for the QP.
        let mut contacts = Vec::with_capacity(nf + team.hands.len());
        for (k, f) in team.feet.iter().enumerate() {
            let d = &self.descriptions[&team.robots[f.robot].id];
            contacts.push((3 * k, ContactKind::Foot { mu: d.foot_mu * cfg.friction_margin, f_min: cfg.f_min_foot }));
        }
        for (k, h) in team.hands.iter().enumerate() {
            let d = &self.descriptions[&team.robots[h.robot].id];
            let r = h.rotation.matrix();
            contacts.push((
                3 * nf + 6 * k,
                ContactKind::Hand { tx: r.column(0).into(), ty: r.column(1).into(), n: r.column(2).into(), mu: d.hand_mu * cfg.friction_margin,
                    xi: d.hand_xi * cfg.friction_margin,
                    half: [d.hand_half_size[0] * cfg.patch_margin, d.hand_half_size[1] * cfg.patch_margin],
                    f_min: cfg.f_min_hand,
                },
            ));
        }
        let t_build = t_start.elapsed().as_secs_f64() * 1e6;
        let input = QpInput {
            y: &y,
            rho: &rho,
            eta: &eta_real,
            contacts: &contacts,
            actuated: &actuated,
            limits: &limits,
            tau0: &tau0,
            regularisation: cfg.regularisation,
            dense_first: cfg.dense_qp,
        };
        let qp = qp::solve(&input, cfg.qp_max_iter);
        let t_qp = t_start.elapsed().as_secs_f64() * 1e6;
        let (f_c, fallback) = match qp.status {
            QpStatus::Solved | QpStatus::AlmostSolved => (qp.f.clone(), None),
            s => match qp::solve_least_violation(&input, cfg.qp_max_iter) {
                Some((f, worst)) => (f, Some(format!("QP {s:?}: least-violation F_c (worst row violated by {worst:.3}), torques clamped to the limits"))),
                None => (DVector::zeros(m), Some(format!("QP {s:?}: F_c = 0, tau = [P S]^+ P tau_M clamped to the torque limits"))),
            },
        };
        let mut tau = &tau0 + &y * &f_c;
        if fallback.is_some() {
            for (&j, &lim) in actuated.iter().zip(&limits) {
                tau[j] = tau[j].clamp(-lim, lim);
            }
        }
        if !tau.iter().all(|x| x.is_finite()) {
            return Err(ControllerError::NonFinite { robot: "team".into(), what: "torque".into() });
        }
        let (lambda, lambda_real) = if fallback.is_some() {
            // The clamped torque is not tau_0 + Y F_c: predict lambda from the torque actually
            // sent (eq. constraint_force).
            let s_tau = tau.component_mul(&team.s_diag);
            let inner = &proj.ip * (&proj.mbar * (&proj.p * &s_tau - &proj.p * &team.bias + &proj.pdot_v) + &team.bias - &s_tau)
                + &k * &load;
            let lambda = &proj.jct_pinv * inner;
            let real = &lambda + (&eta_real - &eta);
            (lambda, real)
        } else {
            (&rho * &f_c + &eta, &rho * &f_c + &eta_real)
        };
        let timing = Timing {
            assembly_us: t_asm,
            projections_us: t_proj - t_asm,
            impedance_us: t_imp - t_proj,
            qp_build_us: t_build - t_imp,
            qp_us: t_qp - t_build,
            total_us: t_start.elapsed().as_secs_f64() * 1e6,
        };
        self.last = Some(TickReport {
            team, grasp, j_c, jdv_c, proj, tau_m, tau0, load, f_x, f_c, rho, eta, lambda, lambda_real, tau, y, contacts, limits, actuated, qp, fallback, timing,
        });
        Ok(self.last.as_ref().expect("set above"))
    }

    fn fill_outputs(&mut self, tick: &[DynamicsTerms], out: &mut Vec<TorqueCommand>) {
        let Some(rep) = &self.last else { return };
        out.clear();
        for (r, t) in rep.team.robots.iter().zip(tick) {
            out.push(TorqueCommand {
                header: Header::new(&t.header.team, Some(&r.id), t.header.tick, 0),
                tau: r.actuated.iter().map(|&j| rep.tau[j]).collect(),
            });
        }
        let team_id = tick.first().map(|t| t.header.team.clone()).unwrap_or_default();
        let tick_no = tick.first().map(|t| t.header.tick).unwrap_or(0);
        let mut contacts = Vec::new();
        for (k, f) in rep.team.feet.iter().enumerate() {
            contacts.push(ContactWrench { robot: rep.team.robots[f.robot].id.clone(), frame: f.name.clone(), wrench: rep.lambda_real.rows(3 * k, 3).iter().cloned().collect() });
        }
        let nf = rep.team.feet.len();
        for (k, h) in rep.team.hands.iter().enumerate() {
            contacts.push(ContactWrench { robot: rep.team.robots[h.robot].id.clone(), frame: h.name.clone(), wrench: rep.lambda_real.rows(3 * nf + 6 * k, 6).iter().cloned().collect() });
        }
        let residual = (&rep.j_c * &rep.team.velocity).norm();
        self.diagnostics = Some(TickDiagnostics {
            header: Header::new(&team_id, None, tick_no, protocol::wall_clock_ns()),
            qp_status: rep.qp.status,
            qp_iterations: rep.qp.iterations,
            qp_solve_us: rep.qp.solve_us,
            assembly_us: rep.timing.assembly_us,
            total_us: rep.timing.total_us,
            contacts,
            constraint_residual: if residual.is_finite() { residual } else { f64::MAX },
            object_estimate: rep.grasp.as_ref().map(|g| protocol::Pose {
                position: g.object.translation.vector.into(),
                orientation: quat_wxyz(&g.object.rotation.to_rotation_matrix()),
            }),
        });
    }
}

fn pose_ref(r: &PoseReference) -> (Isometry3<f64>, [f64; 6], [f64; 6]) {
    let rot = UnitQuaternion::from_rotation_matrix(&rotation_from_wxyz(&r.pose.orientation));
    (Isometry3::from_parts(Translation3::from(Vector3::from(r.pose.position)), rot), r.twist, r.acceleration)
}

impl TeamController for PaperController {
    fn name(&self) -> &'static str {
        "paper (PIDC + contact-force QP)"
    }

    fn solve(&mut self, tick: &[DynamicsTerms], out: &mut Vec<TorqueCommand>) -> Result<(), ControllerError> {
        self.compute(tick)?;
        self.fill_outputs(tick, out);
        Ok(())
    }

    fn diagnostics(&self) -> Option<&TickDiagnostics> {
        self.diagnostics.as_ref()
    }

    fn used_fallback(&self) -> bool {
        self.last.as_ref().is_some_and(|l| l.fallback.is_some())
    }

    fn set_description(&mut self, d: &RobotDescription) {
        PaperController::set_description(self, d);
    }

    fn set_references(&mut self, r: &TaskReferences) {
        PaperController::set_references(self, r);
    }

    fn set_members(&mut self, members: &[String]) {
        self.set_expected(Some(members.to_vec()));
    }

    fn not_ready(&self, members: &[String]) -> Option<String> {
        let missing: Vec<&String> = members.iter().filter(|m| !self.descriptions.contains_key(*m)).collect();
        (!missing.is_empty()).then(|| format!("waiting for the descriptions of {missing:?}"))
    }
}
