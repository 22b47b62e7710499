//! The force-closed grasp (paper §II-E, §III-A): grasp matrix `G` (eq. graspmatrix), the grasp
//! null-space projector, `J_c,ee` (eq. jacobian_cee), `J_o` (eq. obj_jacobian), their
//! `Jdot*v`, and the object pose inferred from the hand poses.
//!
//! Frames: our Jacobians are world-aligned at the hand-contact origin, so the partial grasp
//! matrix is the paper's with `R_i = I`: `G_i = [[I, 0], [skew(r_i), I]]`, `r_i = p_i - p_o`
//! (object centre to contact, world). `G_i` maps a world-aligned wrench at contact i to the
//! object centre; `G_i^T` maps the object twist to contact i's twist.
//!
//! The object is NOT in the generalized coordinates: the grasp constraint only constrains
//! the hands' relative motion (`J_c,ee = (I - G^+ G) J_ee`, symmetric projector since
//! `G^T (G^+)^T = G^+ G`). The object's weight and inertia enter as a known external wrench
//! at the object centre (the paper's `J_x^T F_x` term with `J_x = J_o`), see `controller.rs`.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3};

use crate::linalg::skew;
use crate::team::Team;

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


/// The grasp quantities of one tick.
#[derive(Debug, Clone)]
pub struct GraspTerms {
    /// Object pose estimate and twist `J_o v` (world, at the object centre).
    pub object: Isometry3<f64>,
    pub object_twist: DVector<f64>,
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
}

/// Partial grasp matrices side by side (eq. graspmatrix), world-aligned contact frames.
pub fn grasp_matrix(r: &[Vector3<f64>]) -> DMatrix<f64> {
    let mut g = DMatrix::zeros(6, 6 * r.len());
    for (i, ri) in r.iter().enumerate() {
        let mut gi = Matrix6::identity();
        gi.fixed_view_mut::<3, 3>(3, 0).copy_from(&skew(ri));
        g.view_mut((0, 6 * i), (6, 6)).copy_from(&gi);
    }
    g
}

/// `G^+ = G^T (G G^T)^{-1}` (G has full row rank 6 for B >= 1: its blocks contain I).
fn g_pinv_of(g: &DMatrix<f64>) -> Option<(DMatrix<f64>, DMatrix<f64>)> {
    let w = (g * g.transpose()).try_inverse()?;
    Some((g.transpose() * &w, w))
}

impl GraspTerms {
    /// Compute for the hands of `team` (B >= 1) with the object at `object`.
    pub fn compute(team: &Team, object: Isometry3<f64>) -> Option<GraspTerms> {
        let b = team.hands.len();
        if b == 0 {
            return None;
        }
        let po = object.translation.vector;
        let r: Vec<Vector3<f64>> = team.hands.iter().map(|h| h.position - po).collect();
        let g = grasp_matrix(&r);
        let (g_pinv, w) = g_pinv_of(&g)?;
        let n = DMatrix::identity(6 * b, 6 * b) - &g_pinv * &g;
        let j_ee = &team.j_ee;
        let ee_twist = j_ee * &team.velocity;
        let j_o = g_pinv.transpose() * j_ee;
        let object_twist = &j_o * &team.velocity;
        // rdot_i = v_i - v_o; Gdot_i = [[0, 0], [skew(rdot_i), 0]].
        let vo = Vector3::new(object_twist[0], object_twist[1], object_twist[2]);
        let mut gdot = DMatrix::zeros(6, 6 * b);
        for i in 0..b {
            let vi = Vector3::new(ee_twist[6 * i], ee_twist[6 * i + 1], ee_twist[6 * i + 2]);
            let s: Matrix3<f64> = skew(&(vi - vo));
            gdot.view_mut((3, 6 * i), (3, 3)).copy_from(&s);
        }
        // d(G^+) = Gdot^T W - G^T W (Gdot G^T + G Gdot^T) W;  Ndot = -(d(G^+) G + G^+ Gdot).
        let gt = g.transpose();
        let dgp = gdot.transpose() * &w - &gt * &w * (&gdot * &gt + &g * gdot.transpose()) * &w;
        let ndot = -(&dgp * &g + &g_pinv * &gdot);
        let j_cee = &n * j_ee;
        let jdv_cee = &ndot * &ee_twist + &n * &team.jdv_ee;
        let jdv_o = dgp.transpose() * &ee_twist + g_pinv.transpose() * &team.jdv_ee;
        Some(GraspTerms { object, object_twist, g, g_pinv, n, j_cee, jdv_cee, j_o, jdv_o })
    }
}
