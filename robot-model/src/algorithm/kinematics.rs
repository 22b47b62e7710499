//! Forward kinematics: body and frame placements, joint motion subspaces in the world frame,
//! body velocities and bias accelerations (Featherstone ch. 4; Pinocchio's
//! `forwardKinematics` + `computeJointJacobians` + `updateFramePlacements`, world-frame variant).

use nalgebra::{Rotation3, Unit, Vector3, Vector6};

use crate::data::Data;
use crate::error::DynamicsError;
use crate::model::{quaternion_to_matrix, FrameId, JointType, Model};
use crate::spatial::{Motion, SE3};

/// Placement of body `i` relative to its parent for the joint coordinates `q`
/// (`liMi = placement * XJ(q)`), and the joint motion subspace in the body frame.
#[inline]
fn joint_transform(jt: &JointType, placement: &SE3, q: &[f64]) -> SE3 {
    match jt {
        JointType::Fixed => *placement,
        JointType::Free => {
            let rot = quaternion_to_matrix(q[3], q[4], q[5], q[6]);
            placement.compose(&SE3::new(rot, Vector3::new(q[0], q[1], q[2])))
        }
        JointType::Revolute { axis } => {
            let r = Rotation3::from_axis_angle(&Unit::new_unchecked(*axis), q[0]).into_inner();
            SE3::new(placement.rot * r, placement.trans)
        }
        JointType::Prismatic { axis } => {
            SE3::new(placement.rot, placement.trans + placement.rot * (axis * q[0]))
        }
    }
}

/// Full kinematics pass for `q`, `v` and joint acceleration `a` (`None` = zero).
///
/// Writes `o_m_i`, `o_m_f`, `j` (S_k^0), `dj`, `ov`, `oa` and `o_inertia`.
/// Recursion (world frame): `V_i = V_p + S_i qd_i`, `A_i = A_p + S_i qdd_i + V_i x S_i qd_i`.
pub(crate) fn kinematics_pass(
    model: &Model,
    data: &mut Data,
    q: &[f64],
    v: Option<&[f64]>,
    a: Option<&[f64]>,
) {
    for (i, b) in model.bodies.iter().enumerate() {
        let nq = b.joint.nq();
        let l_m_i = joint_transform(&b.joint, &b.placement, &q[b.idx_q..b.idx_q + nq]);
        let (o_m_p, v_p, a_p) = match b.parent {
            Some(p) => (data.o_m_i[p], data.ov[p], data.oa[p]),
            None => (SE3::identity(), Motion::zero(), Motion::zero()),
        };
        let o_m_i = o_m_p.compose(&l_m_i);
        data.o_m_i[i] = o_m_i;
        data.o_inertia[i] = o_m_i.act_inertia(&b.inertia);

        // joint motion subspace in the world frame, and joint velocity / acceleration
        let mut vj = Motion::zero();
        let mut aj = Motion::zero();
        let nv = b.joint.nv();
        for k in 0..nv {
            let s = o_m_i.act_motion(&local_subspace(&b.joint, k));
            let col = b.idx_v + k;
            data.j.fixed_view_mut::<3, 1>(0, col).copy_from(&s.lin);
            data.j.fixed_view_mut::<3, 1>(3, col).copy_from(&s.ang);
            if let Some(v) = v {
                vj += s.scale(v[col]);
            }
            if let Some(a) = a {
                aj += s.scale(a[col]);
            }
        }
        let vi = v_p + vj;
        data.ov[i] = vi;
        // Featherstone eq. 7.7 in world coordinates: S-dot = V_i x S
        data.oa[i] = a_p + aj + vi.cross_motion(&vj);
        subspace_derivative(data, &vi, b.idx_v, nv);
    }
    update_frame_placements(model, data);
}

/// Column `k` of the joint's motion subspace, in the body frame.
#[inline]
fn local_subspace(jt: &JointType, k: usize) -> Motion {
    match *jt {
        JointType::Free => {
            Motion::from_vector6(&Vector6::from_fn(|r, _| if r == k { 1.0 } else { 0.0 }))
        }
        JointType::Revolute { axis } => Motion::new(Vector3::zeros(), axis),
        JointType::Prismatic { axis } => Motion::new(axis, Vector3::zeros()),
        JointType::Fixed => unreachable!("fixed joint has no velocity"),
    }
}

/// `dj` of the body's `nv` joint columns from `idx_v`: `S-dot = V_i x S` (Featherstone
/// eq. 7.7 in world coordinates), from the world-frame `j` already written.
#[inline]
fn subspace_derivative(data: &mut Data, vi: &Motion, idx_v: usize, nv: usize) {
    for k in 0..nv {
        let col = idx_v + k;
        let s = Motion::new(
            data.j.fixed_view::<3, 1>(0, col).into(),
            data.j.fixed_view::<3, 1>(3, col).into(),
        );
        let ds = vi.cross_motion(&s);
        data.dj.fixed_view_mut::<3, 1>(0, col).copy_from(&ds.lin);
        data.dj.fixed_view_mut::<3, 1>(3, col).copy_from(&ds.ang);
    }
}

/// `oMf = oMi * iMf` for every frame.
pub fn update_frame_placements(model: &Model, data: &mut Data) {
    for (f, fr) in model.frames.iter().enumerate() {
        data.o_m_f[f] = data.o_m_i[fr.body].compose(&fr.placement);
    }
}

/// Forward kinematics at `(q, v)` with zero joint acceleration: body and frame placements,
/// world-frame joint motion subspaces and their derivatives, body velocities and the bias
/// accelerations `Jdot v` of every body. Required before [`crate::frame_jacobian`],
/// [`crate::frame_jdot_v`], [`frame_velocity`], [`kinetic_energy`].
pub fn forward_kinematics(
    model: &Model,
    data: &mut Data,
    q: &[f64],
    v: &[f64],
) -> Result<(), DynamicsError> {
    model.check_state(q, Some(v))?;
    kinematics_pass(model, data, q, Some(v), None);
    Ok(())
}

/// Placement of a frame in the world (after forward kinematics).
pub fn frame_placement<'a>(
    model: &Model,
    data: &'a Data,
    frame: FrameId,
) -> Result<&'a SE3, DynamicsError> {
    check_frame(model, frame)?;
    Ok(&data.o_m_f[frame])
}

/// Spatial velocity of a frame, at its origin, world-aligned axes: `[v_origin; omega]`.
pub fn frame_velocity(model: &Model, data: &Data, frame: FrameId) -> Result<Motion, DynamicsError> {
    check_frame(model, frame)?;
    let vb = data.ov[model.frames[frame].body];
    let p = data.o_m_f[frame].trans;
    Ok(Motion::new(vb.lin + vb.ang.cross(&p), vb.ang))
}

/// Sum of the bodies' kinetic energies `sum 1/2 V_i . I_i V_i` (after forward kinematics).
pub fn kinetic_energy(model: &Model, data: &Data) -> f64 {
    (0..model.bodies.len()).map(|i| data.o_inertia[i].kinetic_energy(&data.ov[i])).sum()
}

/// Potential energy in the model's gravity field, `-sum m_i g . c_i` (after kinematics).
pub fn potential_energy(model: &Model, data: &Data) -> f64 {
    (0..model.bodies.len())
        .map(|i| -data.o_inertia[i].mass * model.gravity.dot(&data.o_inertia[i].com))
        .sum()
}

pub(crate) fn check_frame(model: &Model, frame: FrameId) -> Result<(), DynamicsError> {
    if frame >= model.frames.len() {
        return Err(DynamicsError::FrameOutOfRange { index: frame, count: model.frames.len() });
    }
    Ok(())
}
