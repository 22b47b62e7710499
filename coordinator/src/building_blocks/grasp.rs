//! The force-closed grasp (paper §II-E, §III-A): grasp matrix `G` (eq. graspmatrix), the grasp
//! null-space projector, `J_c,ee` (eq. jacobian_cee), `J_o` (eq. obj_jacobian), their
//! `Jdot*v` ([`GraspTerms`]), and the object pose fitted to the hand poses
//! ([`GraspOffsets::fit`], offsets kept from tick to tick by [`GraspTracker`]).
//!
//! Frames: our Jacobians are world-aligned at the hand-contact origin, so the partial grasp
//! matrix is the paper's with `R_i = I`: `G_i = [[I, 0], [skew(r_i), I]]`, `r_i = p_i - p_o`
//! (object centre to contact, world). `G_i` maps a world-aligned wrench at contact i to the
//! object centre; `G_i^T` maps the object twist to contact i's twist.
//!
//! The object is NOT in the generalized coordinates: the grasp constraint only constrains
//! the hands' relative motion (`J_c,ee = (I - G^+ G) J_ee`, symmetric projector since
//! `G^T (G^+)^T = G^+ G`). The object's weight and inertia enter as a known external wrench
//! at the object centre (the paper's `J_x^T F_x` term with `J_x = J_o`), see
//! [`crate::building_blocks::object_load`].

use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix6, Rotation3, Translation3, UnitQuaternion,
    Vector3, Vector6,
};

use faer::{MatMut, MatRef};

use robot_model::spatial::skew;

use crate::linalg::{gemm, mat, mat_mut, zeros, zeros_v};
use crate::team::Team;
use crate::ControllerError;

/// Grasp offsets captured when the grasp closed: each hand's rotation to the object's and its
/// contact point in the object's frame. Every tick [`GraspOffsets::fit`] finds the object pose
/// that best explains all hands' poses with these offsets.
#[derive(Debug, Clone)]
pub struct GraspOffsets {
    /// (robot id, hand frame) of each hand in grasp, team order.
    pub hands: Vec<(String, String)>,
    /// `R_hand^T R_object` per hand.
    pub hand_to_object: Vec<UnitQuaternion<f64>>,
    /// `R_object^T (p_hand - p_object)` per hand: where the hand holds the object, in its frame.
    pub contact_in_object: Vec<Vector3<f64>>,
}

/// One hand's grasp as the plan made it: where the hand holds the object and how it is turned
/// to it. With these a controller that starts while the team already holds the object (a
/// coordinator restarted mid-carry) fits the object from the hands where it is, instead of
/// taking it to be where the plan put it at the start ([`GraspTracker::update`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlannedHand {
    pub robot: String,
    /// The hand frame (the agent's `hand` frame name).
    pub frame: String,
    /// The hand's contact point in the object's frame, m.
    pub contact_in_object: [f64; 3],
    /// `R_hand^T R_object` as a unit quaternion `(w, x, y, z)`.
    pub hand_to_object: [f64; 4],
}

impl PlannedHand {
    /// The plan of a hand at `hand` (world pose of its frame) on the object at `object`.
    pub fn new(robot: &str, frame: &str, hand: &Isometry3<f64>, object: &Isometry3<f64>) -> Self {
        let c = object.inverse_transform_point(&hand.translation.vector.into()).coords;
        let q = hand.rotation.inverse() * object.rotation;
        PlannedHand {
            robot: robot.to_string(),
            frame: frame.to_string(),
            contact_in_object: [c.x, c.y, c.z],
            hand_to_object: [q.w, q.i, q.j, q.k],
        }
    }

    /// Finite numbers and a unit quaternion (within 1e-6).
    pub fn check(&self) -> Result<(), String> {
        let n2: f64 = self.hand_to_object.iter().map(|x| x * x).sum();
        if !self.contact_in_object.iter().chain(&self.hand_to_object).all(|x| x.is_finite())
            || (n2 - 1.0).abs() > 1e-6
        {
            return Err(format!(
                "planned hand {} of {}: contact and rotation must be finite, the rotation a unit \
                 quaternion",
                self.frame, self.robot
            ));
        }
        Ok(())
    }
}

/// The object pose fitted to the hands, and how far the hands are from where it puts them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectFit {
    pub pose: Isometry3<f64>,
    /// Largest distance of a hand's contact point from where the fitted pose puts it, m: the
    /// controller's own slip signal (zero for a rigid grasp).
    pub residual: f64,
}

/// Weight of each hand's orientation in the fit, m^2: a hand's rotation counts like points
/// one metre from its contact. The palms' orientation is the better measurement of the
/// object's rotation on a soft contact (a palm rocking on its face moves its contact point's
/// rotation estimate by `angle x lever`; opposite palms rock in opposite senses, so their mean
/// orientation cancels it); the contact points then fix the centre, for two hands as for eight.
pub const ORIENTATION_WEIGHT: f64 = 1.0;

impl GraspOffsets {
    /// Capture the offsets with the object at `object` (world).
    pub fn capture(team: &Team, object: &Isometry3<f64>) -> Self {
        let mut hands = Vec::new();
        let mut hand_to_object = Vec::new();
        let mut contact_in_object = Vec::new();
        for h in &team.hands {
            hands.push((team.robots[h.robot].id.clone(), h.name.clone()));
            hand_to_object.push(
                UnitQuaternion::from_rotation_matrix(&h.rotation).inverse() * object.rotation,
            );
            contact_in_object.push(object.inverse_transform_point(&h.position.into()).coords);
        }
        GraspOffsets { hands, hand_to_object, contact_in_object }
    }

    /// The offsets of the team's grasping hands as `planned`, if every one of them is planned.
    pub fn planned(team: &Team, planned: &[PlannedHand]) -> Option<Self> {
        let mut out = GraspOffsets {
            hands: Vec::new(),
            hand_to_object: Vec::new(),
            contact_in_object: Vec::new(),
        };
        for h in &team.hands {
            let robot = &team.robots[h.robot].id;
            let p = planned.iter().find(|p| p.robot == *robot && p.frame == h.name)?;
            let [w, x, y, z] = p.hand_to_object;
            out.hands.push((robot.clone(), h.name.clone()));
            out.hand_to_object
                .push(UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z)));
            out.contact_in_object.push(Vector3::from(p.contact_in_object));
        }
        Some(out)
    }

    /// Whether these offsets belong to the team's current set of grasping hands.
    pub fn matches(&self, team: &Team) -> bool {
        self.hands.len() == team.hands.len()
            && self
                .hands
                .iter()
                .zip(&team.hands)
                .all(|((r, f), h)| *r == team.robots[h.robot].id && *f == h.name)
    }

    /// The object pose from the hands by weighted least squares over SE(3): the rotation `R`
    /// minimises `sum_i |(p_i - p_mean) - R (c_i - c_mean)|^2 + w sum_i |R - R_i Q_i|_F^2`
    /// (`c_i` the contact in the object frame, `R_i Q_i` hand i's estimate of the object's
    /// rotation, `w` = [`ORIENTATION_WEIGHT`]), which is Procrustes' problem: with
    /// `H = sum_i (p_i - p_mean)(c_i - c_mean)^T + w sum_i R_i Q_i = U S V^T`,
    /// `R = U diag(1, 1, det(U V^T)) V^T`; the position is then `p_mean - R c_mean`.
    pub fn fit(&self, team: &Team) -> ObjectFit {
        let b = team.hands.len().max(1) as f64;
        let p_mean = team.hands.iter().fold(Vector3::zeros(), |a, h| a + h.position) / b;
        let c_mean = self.contact_in_object.iter().fold(Vector3::zeros(), |a, c| a + c) / b;
        let mut h_mat = Matrix3::zeros();
        for ((h, c), q) in team.hands.iter().zip(&self.contact_in_object).zip(&self.hand_to_object)
        {
            h_mat += (h.position - p_mean) * (c - c_mean).transpose();
            h_mat += ORIENTATION_WEIGHT
                * (UnitQuaternion::from_rotation_matrix(&h.rotation) * q)
                    .to_rotation_matrix()
                    .into_inner();
        }
        let svd = h_mat.svd(true, true);
        let (u, v_t) =
            (svd.u.unwrap_or_else(Matrix3::identity), svd.v_t.unwrap_or_else(Matrix3::identity));
        let d = (u * v_t).determinant().signum();
        let r = u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t;
        let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
        let p = p_mean - rot * c_mean;
        let residual = team
            .hands
            .iter()
            .zip(&self.contact_in_object)
            .map(|(h, c)| (h.position - p - rot * c).norm())
            .fold(0.0, f64::max);
        ObjectFit { pose: Isometry3::from_parts(Translation3::from(p), rot), residual }
    }

    /// Largest distance of a hand's contact point from where these offsets put it on the
    /// object at `object`, m: how far the hands have slid on the measured object.
    pub fn slip_from(&self, team: &Team, object: &Isometry3<f64>) -> f64 {
        team.hands
            .iter()
            .zip(&self.contact_in_object)
            .map(|(h, c)| (h.position - object.transform_point(&(*c).into()).coords).norm())
            .fold(0.0, f64::max)
    }

    /// The offsets captured again, in place, with the object at `object` (the hands are the
    /// same: [`GraspOffsets::matches`]).
    pub fn refit(&mut self, team: &Team, object: &Isometry3<f64>) {
        let offsets = self.hand_to_object.iter_mut().zip(&mut self.contact_in_object);
        for (h, (q, c)) in team.hands.iter().zip(offsets) {
            *q = UnitQuaternion::from_rotation_matrix(&h.rotation).inverse() * object.rotation;
            *c = object.inverse_transform_point(&h.position.into()).coords;
        }
    }

    /// Largest distance of a hand's contact point on the object from `before` (the same
    /// hands' contacts), m.
    pub fn moved_from(&self, before: &[Vector3<f64>]) -> f64 {
        self.contact_in_object.iter().zip(before).map(|(c, b)| (c - b).norm()).fold(0.0, f64::max)
    }
}

fn hand_centroid(team: &Team) -> Vector3<f64> {
    let b = team.hands.len().max(1) as f64;
    team.hands.iter().fold(Vector3::zeros(), |a, h| a + h.position) / b
}

/// Default object pose when the grasp closes: the hands' centroid, world-aligned axes.
pub fn centroid_pose(team: &Team) -> Isometry3<f64> {
    let c = hand_centroid(team);
    Isometry3::translation(c.x, c.y, c.z)
}

/// The grasp from tick to tick: the offsets, captured again whenever the set of grasping
/// hands changes, and the last object pose estimate (where the object is taken to be when the
/// grasp next closes).
#[derive(Debug, Clone, Default)]
pub struct GraspTracker {
    offsets: Option<GraspOffsets>,
    /// Each hand's contact point on the object when the grasp closed (what slip is counted
    /// from), in the order of `offsets`.
    closed: Vec<Vector3<f64>>,
    last_object: Option<Isometry3<f64>>,
    /// The grasp was released: the object is no longer where the plan or the last estimate put it.
    released: bool,
    /// Re-fits to the measured object since the tracker was made.
    refits: u64,
    /// Ticks since the last re-fit (saturating; from the start before the first).
    since_refit: u32,
}

/// When the grasp model is re-fitted to the measured object ([`GraspTracker::update_refitting`];
/// the `release` policy's `refit_at` and `refit_min_interval`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RefitRule {
    /// A hand this far (m) from where the measured object puts its contact has slid (0: never).
    pub at: f64,
    /// Ticks at least from one re-fit to the next. Creep passes `at` every few seconds; a hand
    /// dragged along the object passes it every few ticks, and re-fitted that often the fit's
    /// residual, which the release watches, would never show it.
    pub min_ticks: u32,
}

impl RefitRule {
    /// Never re-fit.
    pub const NEVER: RefitRule = RefitRule { at: 0.0, min_ticks: 0 };
}

impl GraspTracker {
    /// This tick's grasp terms into `terms`: `None` without hands in grasp. Otherwise the
    /// offsets (captured when the grasping hands changed, with the object at the last estimate;
    /// before any estimate, the `planned` offsets if they cover every grasping hand, else with
    /// the object at `pose_at_grasp`, else at the hands' centroid with world axes), the object
    /// pose from the hands, and the terms of [`GraspTerms::compute_into`]. No re-fit to a
    /// measured object ([`GraspTracker::update_refitting`] with [`RefitRule::NEVER`]).
    pub fn update(
        &mut self,
        team: &Team,
        pose_at_grasp: Option<Isometry3<f64>>,
        planned: &[PlannedHand],
        terms: &mut Option<GraspTerms>,
    ) -> Result<(), ControllerError> {
        self.update_refitting(team, (pose_at_grasp, planned), RefitRule::NEVER, terms)
    }

    /// [`GraspTracker::update`], and when the team measures the object
    /// ([`Team::object_measured`]) and a hand is more than `refit.at` from where the measured
    /// object puts its contact, the hands have slid on the object: the offsets are re-fitted to
    /// the measured object first ([`GraspOffsets::refit`]), at most once in `refit.min_ticks`.
    pub fn update_refitting(
        &mut self,
        team: &Team,
        grasp_plan: (Option<Isometry3<f64>>, &[PlannedHand]),
        refit: RefitRule,
        terms: &mut Option<GraspTerms>,
    ) -> Result<(), ControllerError> {
        let (pose_at_grasp, planned) = grasp_plan;
        if team.hands.is_empty() {
            self.offsets = None;
            *terms = None;
            return Ok(());
        }
        let offsets = match &mut self.offsets {
            Some(o) if o.matches(team) => o,
            slot => {
                let first = !self.released && self.last_object.is_none();
                let offsets = match first.then(|| GraspOffsets::planned(team, planned)).flatten() {
                    Some(o) => o,
                    None => {
                        let known =
                            if self.released { None } else { self.last_object.or(pose_at_grasp) };
                        GraspOffsets::capture(team, &known.unwrap_or_else(|| centroid_pose(team)))
                    }
                };
                self.released = false;
                self.closed.clone_from(&offsets.contact_in_object);
                slot.insert(offsets)
            }
        };
        self.since_refit = self.since_refit.saturating_add(1);
        let due = refit.at > 0.0 && self.since_refit >= refit.min_ticks;
        if let Some(measured) = team.object_measured.filter(|_| due) {
            if offsets.slip_from(team, &measured) > refit.at {
                offsets.refit(team, &measured);
                self.refits += 1;
                self.since_refit = 0;
            }
        }
        let fit = offsets.fit(team);
        self.last_object = Some(fit.pose);
        let g = terms.get_or_insert_with(GraspTerms::default);
        g.fit_residual = fit.residual;
        g.refits = self.refits;
        g.slip_since_closed = offsets.moved_from(&self.closed);
        g.compute_into(team, fit.pose)
            .ok_or_else(|| ControllerError::Singular { what: "grasp matrix".into() })
    }

    /// Forget the offsets and the object's pose: when the hands next close, the offsets are
    /// captured with the object at the hands' centroid (world axes).
    pub fn release(&mut self) {
        self.offsets = None;
        self.last_object = None;
        self.released = true;
    }
}

/// The grasp quantities of one tick.
#[derive(Debug, Clone, Default)]
pub struct GraspTerms {
    /// Object pose estimate and twist `J_o v` (world, at the object centre).
    pub object: Isometry3<f64>,
    /// The pose fit's residual ([`ObjectFit::residual`]), m.
    pub fit_residual: f64,
    /// Re-fits of the grasp to the measured object so far ([`GraspTracker::update`]).
    pub refits: u64,
    /// Largest distance a hand's contact has moved on the object since the grasp closed, m.
    pub slip_since_closed: f64,
    pub object_twist: Vector6<f64>,
    /// `G` (6 x 6B) and `G^+` (6B x 6).
    pub g: DMatrix<f64>,
    pub g_pinv: DMatrix<f64>,
    /// `N = I - G^T (G^+)^T` (6B x 6B), the internal-wrench projector.
    pub n: DMatrix<f64>,
    /// `J_c,ee v = N J_ee v` and `d/dt(J_c,ee) v = Ndot J_ee v + N Jdot_ee v` (eq.
    /// jacobian_cee), by the hands' sums. `J_c,ee` itself (6B x n) is formed only where `J_c`
    /// is ([`crate::building_blocks::contact_jacobian::contact_jacobian`]).
    pub jcee_v: DVector<f64>,
    pub jdv_cee: DVector<f64>,
    /// `J_o = (G^+)^T J_ee` (eq. obj_jacobian) and `d/dt(J_o) v`.
    pub j_o: DMatrix<f64>,
    pub jdv_o: DVector<f64>,
    /// Scratch: `J_ee v`.
    ee_twist: DVector<f64>,
}

/// Partial grasp matrix `G_i = [[I, 0], [skew(r_i), I]]` (eq. graspmatrix), world-aligned.
fn partial_grasp(r: &Vector3<f64>) -> Matrix6<f64> {
    let mut gi = Matrix6::identity();
    gi.fixed_view_mut::<3, 3>(3, 0).copy_from(&skew(r));
    gi
}

impl GraspTerms {
    /// Compute for the hands of `team` (B >= 1) with the object at `object`, into this value's
    /// buffers. `None` without hands or when `G G^T` is singular.
    ///
    /// Everything is done by 6 x 6 blocks (hand `i`'s block `G_i` of `G`):
    /// `G^+ = G^T W` with `W = (G G^T)^{-1}` (G has full row rank 6 for B >= 1: its blocks
    /// contain I), `rdot_i = v_i - v_o`, `Gdot_i = [[0, 0], [skew(rdot_i), 0]]`,
    /// `d(G^+) = Gdot^T W - G^T W (Gdot G^T + G Gdot^T) W`, `Ndot = -(d(G^+) G + G^+ Gdot)`.
    pub fn compute_into(&mut self, team: &Team, object: Isometry3<f64>) -> Option<()> {
        let b = team.hands.len();
        if b == 0 {
            return None;
        }
        let po = object.translation.vector;
        let w = self.grasp_matrices(team, &po)?;
        zeros_v(&mut self.ee_twist, 6 * b);
        for (i, h) in team.hands.iter().enumerate() {
            self.ee_twist.fixed_rows_mut::<6>(6 * i).copy_from(&h.velocity(&team.velocity));
        }
        zeros(&mut self.j_o, 6, team.n);
        times_hand_jacobians(team, mat(&self.g_pinv).transpose(), mat_mut(&mut self.j_o));
        self.object_twist.gemv(1.0, &self.j_o, &team.velocity, 0.0);
        self.object = object;
        self.drift_terms(team, &po, &w);
        Some(())
    }

    /// `G`, `G^+ = G^T W` and `N = I - G^+ G` for the object's centre at `po`; returns
    /// `W = (G G^T)^{-1}`, `None` when `G G^T` is singular.
    fn grasp_matrices(&mut self, team: &Team, po: &Vector3<f64>) -> Option<Matrix6<f64>> {
        let b = team.hands.len();
        let gi = |i: usize| partial_grasp(&(team.hands[i].position - po));
        let mut ggt = Matrix6::zeros();
        for i in 0..b {
            let g = gi(i);
            ggt += g * g.transpose();
        }
        let w = ggt.try_inverse()?;
        zeros(&mut self.g, 6, 6 * b);
        zeros(&mut self.g_pinv, 6 * b, 6);
        for i in 0..b {
            let g = gi(i);
            self.g.fixed_view_mut::<6, 6>(0, 6 * i).copy_from(&g);
            self.g_pinv.fixed_view_mut::<6, 6>(6 * i, 0).copy_from(&(g.transpose() * w));
        }
        // N = I - G^+ G.
        zeros(&mut self.n, 6 * b, 6 * b);
        for i in 0..b {
            let gp_i: Matrix6<f64> = self.g_pinv.fixed_view::<6, 6>(6 * i, 0).into_owned();
            for j in 0..b {
                let mut blk = -(gp_i * gi(j));
                if i == j {
                    blk += Matrix6::identity();
                }
                self.n.fixed_view_mut::<6, 6>(6 * i, 6 * j).copy_from(&blk);
            }
        }
        Some(w)
    }

    /// The velocity-dependent terms from the hands' twists and the object's: `J_c,ee v`,
    /// `d/dt(J_c,ee) v` and `Jdot_o v` (`w`: `(G G^T)^{-1}`).
    fn drift_terms(&mut self, team: &Team, po: &Vector3<f64>, w: &Matrix6<f64>) {
        let (b, w) = (team.hands.len(), *w);
        let gi = |i: usize| partial_grasp(&(team.hands[i].position - po));
        let vo = self.object_twist.fixed_rows::<3>(0).into_owned();
        let gdot = |i: usize| {
            let vi = self.ee_twist.fixed_rows::<3>(6 * i).into_owned();
            let mut gd = Matrix6::zeros();
            gd.fixed_view_mut::<3, 3>(3, 0).copy_from(&skew(&(vi - vo)));
            gd
        };
        // X = W (Gdot G^T + G Gdot^T) W, so d(G^+)_i = Gdot_i^T W - G_i^T X.
        let mut x = Matrix6::zeros();
        for i in 0..b {
            let (g, gd) = (gi(i), gdot(i));
            x += gd * g.transpose() + g * gd.transpose();
        }
        let x = w * x * w;
        let dgp = |i: usize| gdot(i).transpose() * w - gi(i).transpose() * x;
        // jdv_cee = Ndot (J_ee v) + N Jdot_ee v; jdv_o = d(G^+)^T (J_ee v) + (G^+)^T Jdot_ee v.
        // With Ndot_ij = -(d(G^+)_i G_j + G^+_i Gdot_j) and N_ij = delta_ij I - G^+_i G_j, hand
        // i's rows are -(d(G^+)_i (G ee) + G^+_i (Gdot ee)) + jd_i - G^+_i (G jd) (ee = J_ee v,
        // jd = Jdot_ee v): three 6-vectors summed over the hands once, not B^2 blocks.
        let (mut g_ee, mut gdot_ee, mut g_jd) =
            (Vector6::zeros(), Vector6::zeros(), Vector6::zeros());
        for j in 0..b {
            let (g, ee, jd) =
                (gi(j), self.ee_twist.fixed_rows::<6>(6 * j), team.jdv_ee.fixed_rows::<6>(6 * j));
            g_ee += g * ee;
            gdot_ee += gdot(j) * ee;
            g_jd += g * jd;
        }
        zeros_v(&mut self.jdv_cee, 6 * b);
        zeros_v(&mut self.jcee_v, 6 * b);
        zeros_v(&mut self.jdv_o, 6);
        for i in 0..b {
            let gp_i: Matrix6<f64> = self.g_pinv.fixed_view::<6, 6>(6 * i, 0).into_owned();
            // (N J_ee v)_i = ee_i - G^+_i (G ee).
            let cee_v = self.ee_twist.fixed_rows::<6>(6 * i) - gp_i * g_ee;
            self.jcee_v.fixed_rows_mut::<6>(6 * i).copy_from(&cee_v);
            let dgp_i = dgp(i);
            let acc =
                -(dgp_i * g_ee + gp_i * gdot_ee) + team.jdv_ee.fixed_rows::<6>(6 * i) - gp_i * g_jd;
            self.jdv_cee.fixed_rows_mut::<6>(6 * i).copy_from(&acc);
            let ee_i = self.ee_twist.fixed_rows::<6>(6 * i);
            let jdv_i = team.jdv_ee.fixed_rows::<6>(6 * i);
            let mut o = self.jdv_o.fixed_rows_mut::<6>(0);
            o += dgp_i.transpose() * ee_i + gp_i.transpose() * jdv_i;
        }
    }
}

/// `out += X J_ee` (X: rows x 6B, `out`: rows x n) by the hands' blocks: hand `i`'s six rows
/// of `J_ee` are its robot's frame Jacobian, zero outside that robot's columns, so column
/// block `i` of `X` meets only those columns (`6 B x 6 x k` per hand instead of
/// `6 B x 6 B x n`).
pub fn times_hand_jacobians(team: &Team, x: MatRef<'_, f64>, mut out: MatMut<'_, f64>) {
    for (i, h) in team.hands.iter().enumerate() {
        let rb = &team.robots[h.robot];
        let dst = out.as_mut().submatrix_mut(0, rb.offset, x.nrows(), rb.nv);
        gemm(
            dst,
            1.0,
            1.0,
            x.subcols(6 * i, 6),
            mat(&team.j_ee).submatrix(6 * i, rb.offset, 6, rb.nv),
        );
    }
}
