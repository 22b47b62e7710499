//! The carried object in the MQP: a rigid body fixed to the hands (Bouyarmane et al. put it in
//! the QP as one more robot). The object is not in the team's coordinates (see
//! [`crate::building_blocks::grasp`]): its acceleration is `a_o = J_o qdd + Jdot_o v`, and its
//! Newton-Euler equation `M_o a_o + b_o = -F_x` gives the load `J_o^T F_x` it puts on the
//! robots (eq. js_dynamics' `J_x^T F_x`), now an affine function of the decision variable
//! `qdd` instead of PIDC's feed-forward at the reference acceleration:
//!
//! `M qdd + h - J_o^T F_x = (M + J_o^T M_o J_o) qdd + h + J_o^T (M_o Jdot_o v + b_o)`,
//!
//! with `M_o = diag(m I, R I_o R^T)` and `b_o = [-m g; omega x I omega]`. The real wrench on
//! hand `i` is `lambda_ee,i + (G^+ F_x)_i = lambda_ee,i - (G^+ M_o J_o qdd)_i - (G^+ c_o)_i`,
//! `c_o = M_o Jdot_o v + b_o` (see [`crate::building_blocks::object_load`] for the load's
//! distribution).

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, Vector6};

use crate::building_blocks::grasp::GraspTerms;
use crate::building_blocks::object_load::object_load;
use crate::linalg::{mat, product, zeros, zeros_v};

/// The object's terms of one tick (all zero-sized without a grasp).
#[derive(Debug, Clone, Default)]
pub struct ObjectTerms {
    /// `M_o` (6 x 6, world) and `c_o = M_o Jdot_o v + b_o` (6).
    pub m_o: Matrix6<f64>,
    pub c_o: Vector6<f64>,
    /// `J_o^T M_o J_o` (n x n) and `J_o^T c_o` (n): added to `M` and `h`.
    pub mass: DMatrix<f64>,
    pub bias: DVector<f64>,
    /// `G^+ M_o J_o` (6B x n) and `G^+ c_o` (6B): the hands' share of the object's load is
    /// `-(hand_qdd qdd + hand_const)`.
    pub hand_qdd: DMatrix<f64>,
    pub hand_const: DVector<f64>,
    /// Scratch: `M_o J_o` (6 x n).
    mo_jo: DMatrix<f64>,
}

impl ObjectTerms {
    /// For the tick's grasp (`None`: no object, the terms are zero of size n / 0).
    pub fn compute_into(
        &mut self,
        grasp: Option<&GraspTerms>,
        n: usize,
        mass: f64,
        inertia: &Matrix3<f64>,
    ) {
        let Some(g) = grasp else {
            zeros(&mut self.mass, n, n);
            zeros_v(&mut self.bias, n);
            zeros(&mut self.hand_qdd, 0, n);
            zeros_v(&mut self.hand_const, 0);
            self.m_o = Matrix6::zeros();
            self.c_o = Vector6::zeros();
            return;
        };
        let r = g.object.rotation.to_rotation_matrix();
        let i_w = r.matrix() * inertia * r.matrix().transpose();
        self.m_o = Matrix6::zeros();
        self.m_o.fixed_view_mut::<3, 3>(0, 0).copy_from(&(Matrix3::identity() * mass));
        self.m_o.fixed_view_mut::<3, 3>(3, 3).copy_from(&i_w);
        // b_o = [-m g; omega x I omega]: the load feed-forward at zero acceleration.
        let b_o = object_load(&g.object, &g.object_twist, &[0.0; 6], mass, inertia);
        self.c_o = self.m_o * Vector6::from_column_slice(g.jdv_o.as_slice()) + b_o;
        zeros(&mut self.mo_jo, 6, n);
        for j in 0..n {
            let col = self.m_o * g.j_o.fixed_view::<6, 1>(0, j);
            self.mo_jo.fixed_view_mut::<6, 1>(0, j).copy_from(&col);
        }
        product(&mut self.mass, mat(&g.j_o).transpose(), mat(&self.mo_jo));
        zeros_v(&mut self.bias, n);
        self.bias.gemv_tr(1.0, &g.j_o, &self.c_o, 0.0);
        product(&mut self.hand_qdd, mat(&g.g_pinv), mat(&self.mo_jo));
        zeros_v(&mut self.hand_const, g.g_pinv.nrows());
        self.hand_const.gemv(1.0, &g.g_pinv, &self.c_o, 0.0);
    }
}
