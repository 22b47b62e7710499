//! The force-closed grasp (paper §II-E, §III-A): grasp matrix `G` (eq. graspmatrix), the grasp
//! null-space projector, `J_c,ee` (eq. jacobian_cee), `J_o` (eq. obj_jacobian), their
//! `Jdot*v` ([`GraspTerms`]), and the object pose inferred from the hand poses
//! ([`GraspOffsets`], kept from tick to tick by [`GraspTracker`]).
//!
//! Frames: our Jacobians are world-aligned at the hand-contact origin, so the partial grasp
//! matrix is the paper's with `R_i = I`: `G_i = [[I, 0], [skew(r_i), I]]`, `r_i = p_i - p_o`
//! (object centre to contact, world). `G_i` maps a world-aligned wrench at contact i to the
//! object centre; `G_i^T` maps the object twist to contact i's twist.
//!
//! The object is NOT in the generalized coordinates: the grasp constraint only constrains
//! the hands' relative motion (`J_c,ee = (I - G^+ G) J_ee`, symmetric projector since
//! `G^T (G^+)^T = G^+ G`). The object's weight and inertia enter as a known external wrench
//! at the object centre (the paper's `J_x^T F_x` term with `J_x = J_o`), see `pidc::stages::tasks`.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

use crate::linalg::{mat, product, skew, zeros, zeros_v};
use crate::team::Team;
use crate::ControllerError;

/// Grasp offsets captured when the grasp closed: each hand's rotation to the object's, and
/// the object centre relative to the hands' centroid (in the object frame).
///
/// The estimate takes its position from the hands' centroid, not from each hand's pose times
/// its lever arm: a palm that rocks on its face by a small angle (soft contact, a moment near
/// the patch's limit) then moves the estimate by the rocking of the centroid only, not by
/// `angle x 0.3 m` as a per-hand estimate would. Opposite palms rock in opposite senses, so
/// their mean rotation cancels it too.
#[derive(Debug, Clone)]
pub struct GraspOffsets {
    /// (robot id, hand frame) of each hand in grasp, team order.
    pub hands: Vec<(String, String)>,
    /// `R_hand^T R_object` per hand.
    pub hand_to_object: Vec<UnitQuaternion<f64>>,
    /// `R_object^T (p_object - centroid(p_hand))`.
    pub centre_offset: Vector3<f64>,
}

impl GraspOffsets {
    /// Capture the offsets with the object at `object` (world).
    pub fn capture(team: &Team, object: &Isometry3<f64>) -> Self {
        let mut hands = Vec::new();
        let mut hand_to_object = Vec::new();
        for h in &team.hands {
            hands.push((team.robots[h.robot].id.clone(), h.name.clone()));
            hand_to_object.push(UnitQuaternion::from_rotation_matrix(&h.rotation).inverse() * object.rotation);
        }
        let centre_offset = object.rotation.inverse() * (object.translation.vector - hand_centroid(team));
        GraspOffsets { hands, hand_to_object, centre_offset }
    }

    /// Whether these offsets belong to the team's current set of grasping hands.
    pub fn matches(&self, team: &Team) -> bool {
        self.hands.len() == team.hands.len()
            && self.hands.iter().zip(&team.hands).all(|((r, f), h)| *r == team.robots[h.robot].id && *f == h.name)
    }

    /// Object pose from the hands: orientation the sign-aligned normalised mean of each hand's
    /// estimate, position the hands' centroid plus the captured centre offset.
    pub fn object_pose(&self, team: &Team) -> Isometry3<f64> {
        let mut q = nalgebra::Vector4::zeros();
        let mut first: Option<nalgebra::Vector4<f64>> = None;
        for (h, off) in team.hands.iter().zip(&self.hand_to_object) {
            let c = (UnitQuaternion::from_rotation_matrix(&h.rotation) * off).coords;
            let f = *first.get_or_insert(c);
            q += if f.dot(&c) < 0.0 { -c } else { c };
        }
        let rot = UnitQuaternion::from_quaternion(nalgebra::Quaternion::from(q));
        let p = hand_centroid(team) + rot * self.centre_offset;
        Isometry3::from_parts(Translation3::from(p), rot)
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
    last_object: Option<Isometry3<f64>>,
}

impl GraspTracker {
    /// This tick's grasp terms into `terms`: `None` without hands in grasp. Otherwise the
    /// offsets (captured when the grasping hands changed, with the object at the last estimate,
    /// else at `pose_at_grasp`, else at the hands' centroid with world axes), the object pose
    /// from the hands, and the terms of [`GraspTerms::compute_into`].
    pub fn update(&mut self, team: &Team, pose_at_grasp: Option<Isometry3<f64>>, terms: &mut Option<GraspTerms>) -> Result<(), ControllerError> {
        if team.hands.is_empty() {
            self.offsets = None;
            *terms = None;
            return Ok(());
        }
        let offsets = match &mut self.offsets {
            Some(o) if o.matches(team) => o,
            slot => {
                let at = self.last_object.or(pose_at_grasp).unwrap_or_else(|| centroid_pose(team));
                slot.insert(GraspOffsets::capture(team, &at))
            }
        };
        let pose = offsets.object_pose(team);
        self.last_object = Some(pose);
        let g = terms.get_or_insert_with(GraspTerms::default);
        g.compute_into(team, pose).ok_or_else(|| ControllerError::Singular { what: "grasp matrix".into() })
    }

    /// Forget the offsets: they are captured again when the hands next close.
    pub fn release(&mut self) {
        self.offsets = None;
    }
}


/// The grasp quantities of one tick.
#[derive(Debug, Clone, Default)]
pub struct GraspTerms {
    /// Object pose estimate and twist `J_o v` (world, at the object centre).
    pub object: Isometry3<f64>,
    pub object_twist: Vector6<f64>,
    /// `G` (6 x 6B) and `G^+` (6B x 6).
    pub g: DMatrix<f64>,
    pub g_pinv: DMatrix<f64>,
    /// `N = I - G^T (G^+)^T` (6B x 6B), the internal-wrench projector.
    pub n: DMatrix<f64>,
    /// `J_c,ee = N J_ee` (eq. jacobian_cee) and `d/dt(J_c,ee) v = Ndot J_ee v + N Jdot_ee v`.
    pub j_cee: DMatrix<f64>,
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
        let n = team.n;
        let po = object.translation.vector;
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
        let j_ee = &team.j_ee;
        zeros_v(&mut self.ee_twist, 6 * b);
        self.ee_twist.gemv(1.0, j_ee, &team.velocity, 0.0);
        product(&mut self.j_o, mat(&self.g_pinv).transpose(), mat(j_ee));
        self.object_twist.gemv(1.0, &self.j_o, &team.velocity, 0.0);
        self.object = object;
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
        zeros_v(&mut self.jdv_cee, 6 * b);
        zeros_v(&mut self.jdv_o, 6);
        for i in 0..b {
            let gp_i: Matrix6<f64> = self.g_pinv.fixed_view::<6, 6>(6 * i, 0).into_owned();
            let dgp_i = dgp(i);
            let mut acc = Vector6::zeros();
            for j in 0..b {
                let ndot_ij = -(dgp_i * gi(j) + gp_i * gdot(j));
                acc += ndot_ij * self.ee_twist.fixed_rows::<6>(6 * j) + self.n.fixed_view::<6, 6>(6 * i, 6 * j) * team.jdv_ee.fixed_rows::<6>(6 * j);
            }
            self.jdv_cee.fixed_rows_mut::<6>(6 * i).copy_from(&acc);
            let ee_i = self.ee_twist.fixed_rows::<6>(6 * i);
            let jdv_i = team.jdv_ee.fixed_rows::<6>(6 * i);
            let mut o = self.jdv_o.fixed_rows_mut::<6>(0);
            o += dgp_i.transpose() * ee_i + gp_i.transpose() * jdv_i;
        }
        product(&mut self.j_cee, mat(&self.n), mat(j_ee));
        debug_assert_eq!(self.j_cee.ncols(), n);
        Some(())
    }
}
