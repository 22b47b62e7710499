//! Composite Rigid Body Algorithm: the joint-space mass matrix `M(q)`
//! (Featherstone, *RBDA* §6.2, Table 6.2; world-frame variant as in Pinocchio).

use nalgebra::DMatrix;

use super::kinematics::kinematics_pass;
use crate::data::Data;
use crate::error::DynamicsError;
use crate::model::Model;
use crate::spatial::Motion;

/// Computes `M(q)` into `data.m` and returns it.
pub fn crba<'a>(
    model: &Model,
    data: &'a mut Data,
    q: &[f64],
) -> Result<&'a DMatrix<f64>, DynamicsError> {
    model.check_state(q, None)?;
    kinematics_pass(model, data, q, None, None);
    crba_from_kinematics(model, data);
    Ok(&data.m)
}

/// CRBA backward pass on the placements of the last kinematics pass.
/// `I^c_i = I_i + sum_children I^c_c`, `M[l, k] = S_l^T I^c_i S_k` for `l` in support(i).
pub(crate) fn crba_from_kinematics(model: &Model, data: &mut Data) {
    data.m.fill(0.0);
    for i in 0..model.bodies.len() {
        data.ycrb[i] = data.o_inertia[i];
    }
    for i in (0..model.bodies.len()).rev() {
        let b = &model.bodies[i];
        for k in b.idx_v..b.idx_v + b.joint.nv() {
            let s = Motion::new(
                data.j.fixed_view::<3, 1>(0, k).into(),
                data.j.fixed_view::<3, 1>(3, k).into(),
            );
            let f = data.ycrb[i].mul_motion(&s);
            for &l in &b.support {
                if l > k {
                    break;
                }
                let sl = Motion::new(
                    data.j.fixed_view::<3, 1>(0, l).into(),
                    data.j.fixed_view::<3, 1>(3, l).into(),
                );
                let mlk = sl.dot(&f);
                data.m[(l, k)] = mlk;
                data.m[(k, l)] = mlk;
            }
        }
        if let Some(p) = b.parent {
            data.ycrb[p] = data.ycrb[p].add(&data.ycrb[i]);
        }
    }
}
