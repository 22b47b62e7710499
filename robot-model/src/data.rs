//! The mutable, preallocated workspace (Pinocchio's `Data`).
//!
//! Everything the per-tick algorithms write lives here and is sized once by [`Data::new`];
//! after that the algorithms allocate nothing.

use nalgebra::{DMatrix, DVector, Matrix6xX};

use crate::model::Model;
use crate::spatial::{Force, Inertia, Motion, SE3};

/// World-frame quantities are "spatial at the world origin": a motion's linear part is the
/// velocity of the (body-fixed) point that currently coincides with the world origin.
#[derive(Debug, Clone)]
pub struct Data {
    /// Body placements in the world (`oMi`).
    pub o_m_i: Vec<SE3>,
    /// Frame placements in the world (`oMf`).
    pub o_m_f: Vec<SE3>,
    /// Body spatial velocities, world frame.
    pub ov: Vec<Motion>,
    /// Body spatial accelerations for the joint acceleration of the last pass (zero for
    /// [`crate::forward_kinematics`]: then these are the bias accelerations `Jdot v`), world
    /// frame, without gravity.
    pub oa: Vec<Motion>,
    /// Body inertias in the world frame.
    pub o_inertia: Vec<Inertia>,
    /// Composite rigid-body inertias (CRBA), world frame.
    pub ycrb: Vec<Inertia>,
    /// Body forces of the RNEA backward pass, world frame.
    pub of: Vec<Force>,
    /// Gravity-only body forces, world frame.
    pub of_g: Vec<Force>,
    /// Joint motion subspaces in the world frame, one column per velocity coordinate
    /// (the "spatial Jacobian" columns `S_k^0`).
    pub j: Matrix6xX<f64>,
    /// Their time derivatives `d/dt S_k^0 = V_body(k) x S_k^0`.
    pub dj: Matrix6xX<f64>,
    /// Joint-space mass matrix `M(q)` (full, symmetric).
    pub m: DMatrix<f64>,
    /// Bias `h(q, v) = C(q, v) v + g(q)`.
    pub h: DVector<f64>,
    /// Generalized gravity `g(q)`.
    pub g: DVector<f64>,
    /// Output of [`crate::rnea()`].
    pub tau: DVector<f64>,
    /// Coriolis matrix `C(q, v)` of [`crate::coriolis_matrix`] (`Mdot - 2C` skew).
    pub c: DMatrix<f64>,
}

impl Data {
    pub fn new(model: &Model) -> Self {
        let nb = model.bodies.len();
        let nf = model.frames.len();
        let nv = model.nv;
        Self {
            o_m_i: vec![SE3::identity(); nb],
            o_m_f: vec![SE3::identity(); nf],
            ov: vec![Motion::zero(); nb],
            oa: vec![Motion::zero(); nb],
            o_inertia: vec![Inertia::zero(); nb],
            ycrb: vec![Inertia::zero(); nb],
            of: vec![Force::zero(); nb],
            of_g: vec![Force::zero(); nb],
            j: Matrix6xX::zeros(nv),
            dj: Matrix6xX::zeros(nv),
            m: DMatrix::zeros(nv, nv),
            h: DVector::zeros(nv),
            g: DVector::zeros(nv),
            tau: DVector::zeros(nv),
            c: DMatrix::zeros(nv, nv),
        }
    }
}
