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

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3, Vector6};
use protocol::{ContactWrench, DynamicsTerms, Header, PoseReference, QpStatus, RobotDescription, TaskReferences, TickDiagnostics, TorqueCommand};

use crate::grasp::{centroid_pose, GraspOffsets, GraspTerms};
use crate::impedance::{point_error, pose_error, Gains, MotionSpace, TaskStack};
use crate::linalg::{add_product, mat, product, quat_wxyz, rotation_from_wxyz, zeros, zeros_v};
use crate::projection::{ProjectionWorkspace, Projections};
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
    /// converge (or always Clarabel when false). See `qp::DenseIpm`.
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

/// Everything computed in the last tick (kept for tests and reports). It is also the tick's
/// workspace: every matrix is overwritten in place by the next tick, so a tick allocates
/// nothing once the team's shape is set (see [`PaperController::compute`]).
#[derive(Debug, Clone, Default)]
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
    pub f_x: Vector6<f64>,
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

/// Scratch of a tick that the report does not keep: the decompositions' and solvers'
/// workspaces and the intermediate products.
#[derive(Default)]
struct Workspace {
    proj: ProjectionWorkspace,
    tasks: TaskStack,
    qp: qp::QpWorkspace,
    /// `M_c^{-1} P` and `M_c^{-1} (P h - Pdot v)`.
    mcinv_p: DMatrix<f64>,
    mcinv_bias: DVector<f64>,
    /// `S Y` and the products of `rho = (J_c^T)^+ (I - P)(Mbar P - I) S Y` (n x m).
    sy: DMatrix<f64>,
    t_a: DMatrix<f64>,
    t_b: DMatrix<f64>,
    /// Team-sized vectors.
    v1: DVector<f64>,
    v2: DVector<f64>,
    v3: DVector<f64>,
}

/// The paper's team controller.
pub struct PaperController {
    pub config: ControllerConfig,
    descriptions: BTreeMap<String, RobotDescription>,
    expected: Option<Vec<String>>,
    references: Option<TaskReferences>,
    held_torsos: BTreeMap<String, Isometry3<f64>>,
    /// (robot, frame, position) of swing feet without a reference.
    held_feet: Vec<(String, String, Vector3<f64>)>,
    held_object: Option<Isometry3<f64>>,
    offsets: Option<GraspOffsets>,
    last_object: Option<Isometry3<f64>>,
    report: TickReport,
    /// Whether `report` holds a completed tick.
    valid: bool,
    ws: Workspace,
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
            held_feet: Vec::new(),
            held_object: None,
            offsets: None,
            last_object: None,
            report: TickReport::default(),
            valid: false,
            ws: Workspace::default(),
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
        match &mut self.references {
            Some(old) => old.clone_from(r),
            None => self.references = Some(r.clone()),
        }
    }

    /// Forget the grasp (offsets are captured again when the hands next close).
    pub fn release_grasp(&mut self) {
        self.offsets = None;
        self.held_object = None;
    }

    /// The last tick, if it completed (a tick that ended in an error leaves none).
    pub fn last(&self) -> Option<&TickReport> {
        self.valid.then_some(&self.report)
    }

    /// Run one tick: the full team torque and every intermediate.
    ///
    /// **Allocations.** Every matrix and vector of the tick lives in the report or in the
    /// controller's workspace and is overwritten in place: once a team's shape (robots, stance
    /// feet, grasp) has been seen, a tick allocates nothing (`tests/allocations.rs` counts).
    /// What still allocates: a change of shape (buffers are resized), capturing a new grasp,
    /// errors and fallback messages, and Clarabel when it has to finish a tick the dense
    /// interior-point method did not.
    pub fn compute(&mut self, tick: &[DynamicsTerms]) -> Result<&TickReport, ControllerError> {
        self.valid = false;
        let t_start = Instant::now();
        let PaperController { config: cfg, descriptions, expected, references, held_torsos, held_feet, held_object, offsets, last_object, report: r, ws, valid, .. } = self;
        r.team.assemble_into(tick, expected.as_deref(), cfg.fully_actuated)?;
        let team = &r.team;
        let n = team.n;
        // Limits and contact parameters.
        r.limits.clear();
        r.actuated.clear();
        for rb in &team.robots {
            let d = descriptions.get(&rb.id).ok_or_else(|| ControllerError::MissingDescription { robot: rb.id.clone() })?;
            if d.torque_limits.len() != rb.actuated.len() || d.nv as usize != rb.nv {
                return Err(ControllerError::Dimension {
                    what: format!("{}: description", rb.id),
                    detail: format!("{} limits / nv {} vs {} actuated joints / nv {}", d.torque_limits.len(), d.nv, rb.actuated.len(), rb.nv),
                });
            }
            if cfg.fully_actuated {
                let base = rb.nv - rb.actuated.len();
                r.actuated.extend(rb.offset..rb.offset + base);
                r.limits.extend(std::iter::repeat_n(1e9, base));
            }
            r.actuated.extend(&rb.actuated);
            r.limits.extend(&d.torque_limits);
        }
        // Grasp: offsets captured when the set of grasping hands changes.
        if team.hands.is_empty() {
            *offsets = None;
            r.grasp = None;
        } else {
            if !offsets.as_ref().is_some_and(|o| o.matches(team)) {
                let at = last_object.or(cfg.object_pose_at_grasp).unwrap_or_else(|| centroid_pose(team));
                *offsets = Some(GraspOffsets::capture(team, &at));
            }
            let pose = offsets.as_ref().expect("set above").object_pose(team);
            *last_object = Some(pose);
            let g = r.grasp.get_or_insert_with(GraspTerms::default);
            g.compute_into(team, pose).ok_or_else(|| ControllerError::Singular { what: "grasp matrix".into() })?;
        }
        // J_c = [J_cf; J_c,ee] (eq. jacobian_c).
        let nf = team.feet.len();
        let m = team.contact_rows();
        zeros(&mut r.j_c, m, n);
        zeros_v(&mut r.jdv_c, m);
        r.j_c.rows_mut(0, 3 * nf).copy_from(&team.j_cf);
        r.jdv_c.rows_mut(0, 3 * nf).copy_from(&team.jdv_cf);
        if let Some(g) = &r.grasp {
            r.j_c.rows_mut(3 * nf, g.j_cee.nrows()).copy_from(&g.j_cee);
            r.jdv_c.rows_mut(3 * nf, g.j_cee.nrows()).copy_from(&g.jdv_cee);
        }
        let t_asm = t_start.elapsed().as_secs_f64() * 1e6;

        r.proj.compute_into(&mut ws.proj, team, &r.j_c, &r.jdv_c)?;
        let proj = &r.proj;
        product(&mut ws.mcinv_p, mat(&proj.mc_inv), mat(&proj.p));
        zeros_v(&mut ws.v1, n);
        ws.v1.copy_from(&proj.pdot_v);
        ws.v1.gemv(1.0, &proj.p, &team.bias, -1.0); // P h - Pdot v
        zeros_v(&mut ws.mcinv_bias, n);
        ws.mcinv_bias.gemv(1.0, &proj.mc_inv, &ws.v1, 0.0);
        let t_proj = t_start.elapsed().as_secs_f64() * 1e6;

        // tau_M: superposition of the impedance tasks (eqn. joint_space_tau_M), with the
        // operational-space inertia and non-linear terms of eq. control_law computed for the
        // team's task space as a whole (every task's rows stacked; see `impedance`).
        let k_rows = r.grasp.as_ref().map_or(0, |g| g.j_o.nrows()) + team.torsos.iter().chain(&team.swing_feet).map(|t| t.jacobian.nrows()).sum::<usize>();
        ws.tasks.begin(k_rows, n);
        zeros_v(&mut r.load, n);
        r.f_x = Vector6::zeros();
        let refs = references.as_ref();
        if let Some(g) = &r.grasp {
            let (x_d, tw_d, acc_d) = match refs.and_then(|r| r.object.as_ref()) {
                Some(r) => pose_ref(r),
                None => (*held_object.get_or_insert(g.object), [0.0; 6], [0.0; 6]),
            };
            let err = pose_error(&g.object, &g.object_twist, &x_d, &tw_d, &acc_d);
            // Object load feed-forward w_ff and the load F_x = -w_ff on the robots.
            let r_o = g.object.rotation.to_rotation_matrix();
            let i_w = r_o.matrix() * cfg.object_inertia * r_o.matrix().transpose();
            let w = g.object_twist.fixed_rows::<3>(3).into_owned();
            let alpha = Vector3::new(acc_d[3], acc_d[4], acc_d[5]);
            let force = cfg.object_mass * (Vector3::new(acc_d[0], acc_d[1], acc_d[2]) - Vector3::from(GRAVITY));
            let moment = i_w * alpha + w.cross(&(i_w * w));
            let w_ff = Vector6::new(force.x, force.y, force.z, moment.x, moment.y, moment.z);
            r.f_x = -w_ff;
            ws.tasks.push(&g.j_o, &g.jdv_o, &err, &cfg.object_gains, Some(&w_ff))?;
            r.load.gemv_tr(1.0, &g.j_o, &r.f_x, 0.0);
        }
        for tf in &team.torsos {
            let id = &team.robots[tf.robot].id;
            let x = Isometry3::from_parts(Translation3::from(tf.position), UnitQuaternion::from_rotation_matrix(&tf.rotation));
            let (x_d, tw_d, acc_d) = match refs.and_then(|r| r.torsos.iter().find(|t| &t.robot == id)) {
                Some(t) => pose_ref(&t.reference),
                None => match held_torsos.get(id) {
                    Some(h) => (*h, [0.0; 6], [0.0; 6]),
                    None => (*held_torsos.entry(id.clone()).or_insert(x), [0.0; 6], [0.0; 6]),
                },
            };
            let mut twist = Vector6::zeros();
            twist.gemv(1.0, &tf.jacobian, &team.velocity, 0.0);
            let err = pose_error(&x, &twist, &x_d, &tw_d, &acc_d);
            ws.tasks.push(&tf.jacobian, &tf.jdot_v, &err, &cfg.torso_gains, None)?;
        }
        for tf in &team.swing_feet {
            let id = &team.robots[tf.robot].id;
            let (p_d, v_d, a_d) = match refs.and_then(|r| r.swing_feet.iter().find(|s| &s.robot == id && s.frame == tf.name)) {
                Some(s) => (Vector3::from(s.reference.position), s.reference.velocity, s.reference.acceleration),
                None => match held_feet.iter().find(|(r, f, _)| r == id && *f == tf.name) {
                    Some((_, _, p)) => (*p, [0.0; 3], [0.0; 3]),
                    None => {
                        held_feet.push((id.clone(), tf.name.clone(), tf.position));
                        (tf.position, [0.0; 3], [0.0; 3])
                    }
                },
            };
            let mut vel = Vector3::zeros();
            vel.gemv(1.0, &tf.jacobian, &team.velocity, 0.0);
            let err = point_error(&tf.position, &vel, &p_d, &v_d, &a_d);
            ws.tasks.push(&tf.jacobian, &tf.jdot_v, &err, &cfg.swing_gains, None)?;
        }
        let ms = MotionSpace { mcinv_p: &ws.mcinv_p, mcinv_bias: &ws.mcinv_bias };
        ws.tasks.joint_torque(&ms, &mut r.tau_m)?;
        ws.v1.gemv(1.0, &proj.p, &r.tau_m, 0.0);
        zeros_v(&mut r.tau0, n);
        r.tau0.gemv(1.0, &proj.ps_pinv, &ws.v1, 0.0);
        let t_imp = t_start.elapsed().as_secs_f64() * 1e6;

        // eq. relation_between_lambda_and_Fc: lambda = rho F_c + eta, with
        // K = (I - P)(Mbar P - I), rho = (J_c^T)^+ K S Y and
        // eta = (J_c^T)^+ [K (S tau_0 + J_x^T F_x) + (I - P)(Mbar (Pdot v - P h) + h)]
        // (see `Projections::contact_wrench`). rho is formed right to left, without K.
        product(&mut r.y, mat(&proj.b), mat(&r.j_c).transpose()); // Y = B J_c^T
        zeros(&mut ws.sy, n, m);
        ws.sy.copy_from(&r.y);
        for i in 0..n {
            ws.sy.row_mut(i).scale_mut(team.s_diag[i]);
        }
        product(&mut ws.t_a, mat(&proj.p), mat(&ws.sy)); // P S Y
        zeros(&mut ws.t_b, n, m);
        ws.t_b -= &ws.sy;
        add_product(&mut ws.t_b, 1.0, mat(&proj.mbar), mat(&ws.t_a)); // (Mbar P - I) S Y
        product(&mut ws.t_a, mat(&proj.ip), mat(&ws.t_b)); // K S Y
        product(&mut r.rho, mat(&proj.jct_pinv), mat(&ws.t_a));
        zeros_v(&mut ws.v1, n);
        ws.v1.copy_from(&r.tau0);
        ws.v1.component_mul_assign(&team.s_diag);
        ws.v1 += &r.load; // S tau_0 + J_x^T F_x
        proj.contact_wrench(&team.bias, &ws.v1, &mut r.eta, &mut ws.v2, &mut ws.v3);
        // eta_real: the hand rows carry the object's load distribution G^+ F_x.
        zeros_v(&mut r.lambda_real, m);
        r.lambda_real.copy_from(&r.eta);
        if let Some(g) = &r.grasp {
            let mut rows = r.lambda_real.rows_mut(3 * nf, g.g_pinv.nrows());
            rows.gemv(1.0, &g.g_pinv, &r.f_x, 1.0);
        }
        // Contacts for the QP.
        r.contacts.clear();
        for (k, f) in team.feet.iter().enumerate() {
            let d = &descriptions[&team.robots[f.robot].id];
            r.contacts.push((3 * k, ContactKind::Foot { mu: d.foot_mu * cfg.friction_margin, f_min: cfg.f_min_foot }));
        }
        for (k, h) in team.hands.iter().enumerate() {
            let d = &descriptions[&team.robots[h.robot].id];
            let rot = h.rotation.matrix();
            r.contacts.push((
                3 * nf + 6 * k,
                ContactKind::Hand {
                    tx: rot.column(0).into(),
                    ty: rot.column(1).into(),
                    n: rot.column(2).into(),
                    mu: d.hand_mu * cfg.friction_margin,
                    xi: d.hand_xi * cfg.friction_margin,
                    half: [d.hand_half_size[0] * cfg.patch_margin, d.hand_half_size[1] * cfg.patch_margin],
                    f_min: cfg.f_min_hand,
                },
            ));
        }
        let t_build = t_start.elapsed().as_secs_f64() * 1e6;
        // lambda_real holds eta_real here: the QP constrains the real wrenches.
        let input = QpInput {
            y: &r.y,
            rho: &r.rho,
            eta: &r.lambda_real,
            contacts: &r.contacts,
            actuated: &r.actuated,
            limits: &r.limits,
            tau0: &r.tau0,
            regularisation: cfg.regularisation,
            dense_first: cfg.dense_qp,
        };
        r.qp = qp::solve(&mut ws.qp, &input, cfg.qp_max_iter, &mut r.f_c);
        let t_qp = t_start.elapsed().as_secs_f64() * 1e6;
        r.fallback = match r.qp.status {
            QpStatus::Solved | QpStatus::AlmostSolved => None,
            s => match qp::solve_least_violation(&mut ws.qp, &input, cfg.qp_max_iter, &mut r.f_c) {
                Some(worst) => Some(format!("QP {s:?}: least-violation F_c (worst row violated by {worst:.3}), torques clamped to the limits")),
                None => {
                    r.f_c.fill(0.0);
                    Some(format!("QP {s:?}: F_c = 0, tau = [P S]^+ P tau_M clamped to the torque limits"))
                }
            },
        };
        zeros_v(&mut r.tau, n);
        r.tau.copy_from(&r.tau0);
        r.tau.gemv(1.0, &r.y, &r.f_c, 1.0);
        if r.fallback.is_some() {
            for (&j, &lim) in r.actuated.iter().zip(&r.limits) {
                r.tau[j] = r.tau[j].clamp(-lim, lim);
            }
        }
        if !r.tau.iter().all(|x| x.is_finite()) {
            return Err(ControllerError::NonFinite { robot: "team".into(), what: "torque".into() });
        }
        zeros_v(&mut r.lambda, m);
        if r.fallback.is_some() {
            // The clamped torque is not tau_0 + Y F_c: predict lambda from the torque actually
            // sent (eq. constraint_force).
            ws.v1.copy_from(&r.tau);
            ws.v1.component_mul_assign(&team.s_diag);
            ws.v1 += &r.load; // S tau + J_x^T F_x
            proj.contact_wrench(&team.bias, &ws.v1, &mut r.lambda, &mut ws.v2, &mut ws.v3);
        } else {
            r.lambda.copy_from(&r.eta);
            r.lambda.gemv(1.0, &r.rho, &r.f_c, 1.0);
        }
        // lambda_real = lambda + (eta_real - eta).
        r.lambda_real -= &r.eta;
        r.lambda_real += &r.lambda;
        r.timing = Timing {
            assembly_us: t_asm,
            projections_us: t_proj - t_asm,
            impedance_us: t_imp - t_proj,
            qp_build_us: t_build - t_imp,
            qp_us: t_qp - t_build,
            total_us: t_start.elapsed().as_secs_f64() * 1e6,
        };
        *valid = true;
        Ok(&self.report)
    }

    /// Each robot's torque slice into `out` and the tick's diagnostics, reusing the previous
    /// tick's messages (their strings and vectors) when the team is the same.
    fn fill_outputs(&mut self, tick: &[DynamicsTerms], out: &mut Vec<TorqueCommand>) {
        if !self.valid {
            return;
        }
        let rep = &self.report;
        let (team_id, tick_no) = match tick.first() {
            Some(t) => (t.header.team.as_str(), t.header.tick),
            None => ("", 0),
        };
        out.truncate(rep.team.robots.len());
        for (k, (r, t)) in rep.team.robots.iter().zip(tick).enumerate() {
            if k == out.len() {
                out.push(TorqueCommand { header: Header::new(&t.header.team, Some(&r.id), 0, 0), tau: Vec::new() });
            }
            let cmd = &mut out[k];
            set_header(&mut cmd.header, &t.header.team, Some(&r.id), t.header.tick, 0);
            cmd.tau.clear();
            cmd.tau.extend(r.actuated.iter().map(|&j| rep.tau[j]));
        }
        let d = self.diagnostics.get_or_insert_with(|| TickDiagnostics {
            header: Header::new("", None, 0, 0),
            qp_status: QpStatus::NotRun,
            qp_iterations: 0,
            qp_solve_us: 0.0,
            assembly_us: 0.0,
            total_us: 0.0,
            contacts: Vec::new(),
            constraint_residual: 0.0,
            object_estimate: None,
        });
        set_header(&mut d.header, team_id, None, tick_no, protocol::wall_clock_ns());
        let nf = rep.team.feet.len();
        let frames = rep.team.feet.iter().map(|f| (f, 3)).chain(rep.team.hands.iter().map(|h| (h, 6)));
        d.contacts.truncate(nf + rep.team.hands.len());
        let mut row = 0;
        for (k, (f, dim)) in frames.enumerate() {
            if k == d.contacts.len() {
                d.contacts.push(ContactWrench { robot: String::new(), frame: String::new(), wrench: Vec::new() });
            }
            let c = &mut d.contacts[k];
            set_string(&mut c.robot, &rep.team.robots[f.robot].id);
            set_string(&mut c.frame, &f.name);
            c.wrench.clear();
            c.wrench.extend(rep.lambda_real.rows(row, dim).iter());
            row += dim;
        }
        // |J_c v|, without forming J_c v.
        let v = &rep.team.velocity;
        let residual = (0..rep.j_c.nrows()).map(|i| (0..v.len()).map(|j| rep.j_c[(i, j)] * v[j]).sum::<f64>().powi(2)).sum::<f64>().sqrt();
        d.qp_status = rep.qp.status;
        d.qp_iterations = rep.qp.iterations;
        d.qp_solve_us = rep.qp.solve_us;
        d.assembly_us = rep.timing.assembly_us;
        d.total_us = rep.timing.total_us;
        d.constraint_residual = if residual.is_finite() { residual } else { f64::MAX };
        d.object_estimate = rep.grasp.as_ref().map(|g| protocol::Pose {
            position: g.object.translation.vector.into(),
            orientation: quat_wxyz(&g.object.rotation.to_rotation_matrix()),
        });
    }
}

/// `s = value`, keeping `s`'s buffer.
fn set_string(s: &mut String, value: &str) {
    if s != value {
        s.clear();
        s.push_str(value);
    }
}

/// A header's fields set in place (no new strings when they are unchanged).
fn set_header(h: &mut Header, team: &str, robot: Option<&str>, tick: u64, stamp_ns: u64) {
    h.version = protocol::PROTOCOL_VERSION;
    set_string(&mut h.team, team);
    match (robot, &mut h.robot) {
        (Some(r), Some(old)) => set_string(old, r),
        (r, old) => *old = r.map(str::to_string),
    }
    h.tick = tick;
    h.stamp_ns = stamp_ns;
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
        self.last().is_some_and(|l| l.fallback.is_some())
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
